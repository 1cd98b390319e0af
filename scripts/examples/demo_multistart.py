"""Non-convex fit: a single gradient start lands in a wrong basin, multi-start finds the global one.

Run (1 or 2 ranks; about a second)::

    .venv/bin/python scripts/examples/demo_multistart.py [--out out/multistart] [--starts 12]
    mpiexec -n 2 .venv/bin/python scripts/examples/demo_multistart.py

The lecture's shifted-oscillation example: data ``q_t = sin(w (t - s))`` sampled at 200 times in
[0, 10] from (w, s) = (2, 0.3) with 5 % noise, fitted over w in [0.5, 4] (log-scaled) and s in
[-1, 1] (affine), as ``ShiftedOscillation`` of ``optimization_problems.py`` beside this script.
Every optimizer of
``petsoft.calibration.optimize`` is local, and the misfit has a local minimum in nearly every
interval of w of width ~ 2 pi / 10, so:

1. one start at (w, s) = (1.2, 0) with the chosen method (default L-BFGS) stops in a wrong
   basin (f ~ 79 instead of ~ 0.19);
2. ``multistart`` from ``--starts`` random starts (uniform in the scaled box, log-uniform in w;
   seeded) runs them on groups of ranks (one group per rank) and keeps the best.

It prints both results and the starts' outcomes and writes ``multistart.png`` (rank 0): the
objective landscape over (w, s) with every start's path (the best in red, the single start in
white) -- the valleys are the bands where w (t - s) matches the data's phase.

Things to try:

* ``--method gauss-newton`` / ``brgn`` / ``newton`` / ``gd``: the same wrong basin from one
  start;
* ``--method nelder-mead``: the simplex (size 1 in z) spans several basins and happens to find
  the global one here -- the lecture's "could search methods skip local minima?";
* ``--starts 4 --seed 3``: too few starts can all miss the global basin;
* ``-cal_tao_max_it 5``: PETSc options under the prefix ``cal_`` reach the optimizer;
* ``mpiexec -n 2``: two groups, same best answer.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import petsc4py
from mpi4py import MPI

import petsoft  # noqa: F401  before petsc4py.init: one BLAS thread (petsoft/__init__.py)

METHODS = ("gd", "newton", "lbfgs", "gauss-newton", "brgn", "nelder-mead")


def main(argv=None) -> dict:
    """Run the demo; returns the single-start and multi-start results (for tests)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="out/multistart")
    ap.add_argument("--starts", type=int, default=12)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--method", default="lbfgs", choices=METHODS)
    ap.add_argument("--no-plot", action="store_true")
    args, petsc_args = ap.parse_known_args(argv)  # unknown arguments are PETSc options
    petsc4py.init([sys.argv[0], *petsc_args])  # before anything imports PETSc
    from optimization_problems import ShiftedOscillation

    from petsoft.calibration.multistart import multistart, random_starts
    from petsoft.calibration.optimize import minimize

    comm = MPI.COMM_WORLD
    rank = comm.Get_rank()

    problem = ShiftedOscillation(comm)
    sc = problem.scaling
    bounds = sc.bounds()
    single = minimize(problem, np.zeros(2), args.method, bounds=bounds, scaling=sc)
    starts = random_starts(*bounds, args.starts, seed=args.seed)
    multi = multistart(ShiftedOscillation, starts, comm, method=args.method, bounds=bounds,
                       scaling=sc)
    f_truth = 0.5 * float(np.sum((problem.model(problem.truth) - problem.y) ** 2))
    if rank == 0:
        print(f"truth          w = {problem.truth[0]:.5f}  s = {problem.truth[1]:+.5f}  "
              f"f = {f_truth:.5f} (noise only)")
        print(f"single start   w = {single.p[0]:.5f}  s = {single.p[1]:+.5f}  f = {single.f:.5f}"
              f"  ({single.reason}, {single.iterations} it)")
        print(f"multistart     w = {multi.p[0]:.5f}  s = {multi.p[1]:+.5f}  f = {multi.f:.5f}"
              f"  (start {multi.best.index} of {len(starts)}, {multi.groups} group(s))")
        for s in multi.starts:
            r = s.result
            p0 = sc.to_physical(s.start)
            print(f"  start {s.index:2d} (group {s.group}) from w = {p0[0]:.3f}"
                  f" s = {p0[1]:+.3f} -> w = {r.p[0]:.4f} s = {r.p[1]:+.4f}"
                  f" f = {r.f:9.4f}  {r.iterations:3d} it")
        if not args.no_plot:
            _plot(problem, single, multi, Path(args.out))
    sys.stdout.flush()
    return {"single": single, "multi": multi, "f_truth": f_truth}


def _plot(problem, single, multi, out: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w = np.exp(np.linspace(np.log(0.5), np.log(4.0), 400))
    s = np.linspace(-1.0, 1.0, 200)
    F = problem.landscape(w, s)
    fig, ax = plt.subplots(figsize=(8, 5.5))
    cs = ax.contourf(w, s, np.log10(F.T), levels=40, cmap="viridis")
    fig.colorbar(cs, ax=ax, label="log10 f(w, s)")
    for st in multi.starts:
        path = np.array([rec.p for rec in st.result.history])
        best = st is multi.best
        ax.plot(path[:, 0], path[:, 1], "-", color="red" if best else "orange", lw=2 if best else 1)
        ax.plot(path[0, 0], path[0, 1], "o", color="red" if best else "orange", ms=4)
        ax.plot(path[-1, 0], path[-1, 1], "x", color="red" if best else "k", ms=6)
    path = np.array([rec.p for rec in single.history])
    ax.plot(path[:, 0], path[:, 1], "w-", lw=2, label="single start (1.2, 0)")
    ax.plot(path[-1, 0], path[-1, 1], "wx", ms=9)
    ax.plot(*problem.truth, "r*", ms=14, label="truth")
    ax.set_xscale("log")
    ax.set_xlabel("frequency w (log scale)")
    ax.set_ylabel("shift s")
    ax.set_title(f"shifted oscillation: {len(multi.starts)} starts ({multi.best.result.method}); "
                 f"best f = {multi.f:.3f}, single start f = {single.f:.1f}")
    ax.legend(loc="lower right")
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "multistart.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    print(f"wrote {out / 'multistart.png'}")


if __name__ == "__main__":
    main()
