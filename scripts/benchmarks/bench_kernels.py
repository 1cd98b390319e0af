"""Throughput of the elastic element kernels: C vs the numpy reference, in tets/s.

Run (single core, no MPI needed)::

    .venv/bin/python scripts/benchmarks/bench_kernels.py [--n 100000] [--repeat 5]

For each material model it times gradient + Hessian into preallocated buffers (what the
assembly does every Newton step), with and without SPD projection, plus the C energy alone.
The numpy reference is timed on a tenth of the elements (it is linear in n) to keep the run
short. Deformations are random and moderately large (|grad u| ~ 0.2, det F > 0).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from petsoft.fem.kernels import elastic
from petsoft.fem.kernels.tet import shape_gradients


def make_elements(n: int, seed: int = 0):
    """Well-shaped random tets with a random displacement keeping det F > 0.2."""
    rng = np.random.default_rng(seed)
    base = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    X = base + 0.1 * rng.standard_normal((n, 4, 3))
    dN, vol = shape_gradients(X)
    X[vol < 0] = X[vol < 0][:, [0, 2, 1, 3]]
    dN, vol = shape_gradients(X)
    u = 0.2 * rng.standard_normal((n, 4, 3))
    F = np.eye(3) + np.einsum("eai,eaj->eij", u, dN)
    bad = np.linalg.det(F) < 0.2
    u[bad] *= 0.1  # keeps the count at n and J > 0 for the neo-Hookean model
    mu, lam = elastic.lame_parameters(np.full(n, 1e5), np.full(n, 0.3))
    return dN, vol, u, mu, lam


def best_time(fn, repeat: int) -> float:
    """Smallest wall time of ``repeat`` calls (after one warm-up call)."""
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100_000, help="number of tetrahedra")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    n = args.n
    dN, vol, u, mu, lam = make_elements(n)
    g = np.empty((n, 12))
    H = np.empty((n, 12, 12))
    m = max(n // 10, 1)
    sub = (dN[:m], vol[:m], u[:m], mu[:m], lam[:m])
    gs, Hs = np.empty((m, 12)), np.empty((m, 12, 12))

    print(f"{n} tets, best of {args.repeat}; rates in tets/s")
    header = f"{'model':<11} {'C g+H':>10} {'C g+H proj':>11} {'C energy':>10}"
    print(header + f" {'numpy g+H':>10} {'numpy proj':>10}  C/numpy")
    for model in elastic.MODELS:

        def c_gh(model=model, proj=False):
            elastic.element_gradient_hessian_into(model, dN, vol, u, mu, lam, g, H, proj)

        def c_energy(model=model):
            elastic.element_energy(model, dN, vol, u, mu, lam)

        def np_gh(model=model, proj=False):
            elastic.element_gradient_hessian_into(model, *sub, gs, Hs, proj, backend="numpy")

        rates = [
            n / best_time(c_gh, args.repeat),
            n / best_time(lambda model=model: c_gh(model, True), args.repeat),
            n / best_time(c_energy, args.repeat),
            m / best_time(np_gh, max(args.repeat // 2, 1)),
            m / best_time(lambda model=model: np_gh(model, True), max(args.repeat // 2, 1)),
        ]
        cells = " ".join(f"{r:>10.3g}" for r in rates[:1]) + f" {rates[1]:>11.3g}"
        cells += " ".join(f" {r:>10.3g}" for r in rates[2:])
        print(f"{model:<11} {cells}  {rates[0] / rates[3]:7.0f}x")


if __name__ == "__main__":
    main()
