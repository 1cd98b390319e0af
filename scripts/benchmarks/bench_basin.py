"""Basin of attraction: l2 against the spectral (phase-robust) misfit, from random starts.

Two problems, each from the same random starts, minimised by L-BFGS-B (bounds) with l2 alone and
with the spectral misfit followed by an l2 polish (what ``petsoft calibrate --misfit spectral``
does); a start "reaches the global minimum" when its final parameters are within 1 % of the
truth. Printed side by side:

1. the lecture's shifted oscillation sin(w (t - s)) on t in [0, 10] (scripts/examples/
   optimization_problems.py, 5 % noise): starts w in [0.5, 4] log-uniform, s in [-1, 1];
2. a soft cantilever (36 tets, linear law) ringing after a kick, E unknown, noise-free:
   starts E / E_true in [1/3, 3] log-uniform (2x off is inside), gradients by the adjoint.

Run:
    python scripts/benchmarks/bench_basin.py [--starts 20] [--body-starts 8]

Things to try: more starts; ``--noise`` on the body recording.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.optimize import minimize as sp_minimize

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts" / "examples"))
sys.path.insert(0, str(ROOT / "tests"))

from optimization_problems import ShiftedOscillation  # noqa: E402

from petsoft.calibration.misfit import SpectralMisfit  # noqa: E402


def _lbfgs(fun_grad, z0, bounds):
    res = sp_minimize(fun_grad, z0, jac=True, method="L-BFGS-B", bounds=bounds,
                      options={"maxiter": 200, "gtol": 1e-12, "ftol": 1e-15})
    return res.x


def oscillation_fractions(starts: int = 20, seed: int = 0):
    """(fraction l2, fraction spectral + polish, starts) on the shifted oscillation."""
    prob = ShiftedOscillation()
    t, y = prob.t, prob.y
    spec = SpectralMisfit(y[:, None])

    def model(p):
        return np.sin(p[0] * (t - p[1])), np.column_stack(
            [np.cos(p[0] * (t - p[1])) * (t - p[1]), -p[0] * np.cos(p[0] * (t - p[1]))])

    def l2(p):
        q, dq = model(p)
        r = q - y
        return 0.5 * r @ r, dq.T @ r

    def spectral(p):
        q, dq = model(p)
        f, g = spec.value_gradient(q[:, None])
        return f, dq.T @ g[:, 0]

    bounds = [(0.5, 4.0), (-1.0, 1.0)]
    best = _lbfgs(l2, prob.truth, bounds)          # the global minimum of the noisy data
    rng = np.random.default_rng(seed)
    hits = np.zeros(2, int)
    for _ in range(starts):
        p0 = np.array([np.exp(rng.uniform(np.log(0.5), np.log(4.0))), rng.uniform(-1, 1)])
        a = _lbfgs(l2, p0, bounds)
        b = _lbfgs(l2, _lbfgs(spectral, p0, bounds), bounds)
        hits += [np.all(np.abs(a - best) <= 0.01 * np.abs(best) + 1e-3),
                 np.all(np.abs(b - best) <= 0.01 * np.abs(best) + 1e-3)]
    return hits[0] / starts, hits[1] / starts, starts


BODY = """
[mesh]
box = {{ size = [0.3, 0.04, 0.04], cells = [6, 1, 1] }}
[material]
model = "linear"
youngs_modulus = {E}
poisson_ratio = 0.3
density = 1000.0
[gravity]
acceleration = [0.0, 0.0, 0.0]
[[boundary]]
kind = "fixed"
where = "x < 1e-9"
[initial]
velocity = ["0", "0", "3*x*x"]
[time]
end = {end}
step = 0.01
integrator = "alpha"
alpha_radius = 0.95
[calibrate]
"material.youngs_modulus" = [{lo}, {hi}]
"""


def body_problem(E_true: float = 1e6, noise: float = 0.0, end: float = 2.0):
    """(l2 MarkerMisfit, spectral MarkerMisfit, scaling, E_true) of the ringing cantilever."""
    from petsc4py import PETSc

    from petsoft.calibration.calibrate import build_forward
    from petsoft.calibration.objective import MarkerMisfit
    from petsoft.calibration.scaling import ParameterScaling
    from petsoft.experiment import load_experiment
    from petsoft.io.recording import Recording

    tmp = Path(tempfile.mkdtemp())
    path = tmp / "body.toml"
    path.write_text(BODY.format(E=E_true, lo=E_true / 4, hi=E_true * 4, end=end))
    exp = load_experiment(path)
    times = np.arange(0.0, end + 1e-9, 0.01)
    ref = np.array([[0.3, 0.02, 0.04], [0.15, 0.0, 0.0], [0.3, 0.0, 0.0]])
    rec = Recording(reference=ref, names=["a", "b", "c"], times=times,
                    positions=np.zeros((len(times), 3, 3)))
    fm = build_forward(exp, ["material.youngs_modulus"], rec, times, PETSc.COMM_WORLD)
    data = fm.simulate(np.array([E_true]))
    if noise:
        data = data + np.random.default_rng(1).normal(0, noise, data.shape)
    scaling = ParameterScaling(["material.youngs_modulus"], [E_true], [E_true / 4],
                               [E_true * 4])
    l2 = MarkerMisfit(fm, data, scaling, sigma=1e-3)
    spec = MarkerMisfit(fm, data, scaling, sigma=1e-3, misfit=SpectralMisfit(data))
    return l2, spec, scaling, E_true


def body_case(E_true: float = 1e6, end: float = 2.0):
    """(experiment file text with E = E_true, recording) of the ringing cantilever."""
    from petsoft.io.recording import Recording

    l2, _, _, _ = body_problem(E_true, end=end)
    data = l2.data
    times = np.arange(0.0, end + 1e-9, 0.01)
    ref = np.array([[0.3, 0.02, 0.04], [0.15, 0.0, 0.0], [0.3, 0.0, 0.0]])
    l2.forward.destroy()
    return (BODY.format(E=E_true, lo=E_true / 4, hi=E_true * 4, end=end),
            Recording(reference=ref, names=["a", "b", "c"], times=times, positions=data))


def body_fractions(starts: int = 8, seed: int = 0):
    l2, spec, scaling, E_true = body_problem()
    lo, hi = scaling.bounds()
    bounds = list(zip(lo, hi, strict=True))
    rng = np.random.default_rng(seed)
    hits, ends = np.zeros(2, int), []
    for _ in range(starts):
        E0 = E_true * np.exp(rng.uniform(np.log(1 / 3), np.log(3)))
        z0 = scaling.to_scaled(np.array([E0]))
        a = scaling.to_physical(_lbfgs(l2.value_gradient, z0, bounds))[0]
        zs = _lbfgs(spec.value_gradient, z0, bounds)
        b = scaling.to_physical(_lbfgs(l2.value_gradient, zs, bounds))[0]
        ends.append((E0 / E_true, a / E_true, b / E_true))
        hits += [abs(a / E_true - 1) < 0.01, abs(b / E_true - 1) < 0.01]
    return hits[0] / starts, hits[1] / starts, starts, ends


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--starts", type=int, default=20)
    parser.add_argument("--body-starts", type=int, default=8)
    args, _ = parser.parse_known_args()
    a, b, n = oscillation_fractions(args.starts)
    print(f"{'problem':<34} {'starts':>6} {'l2':>6} {'spectral+l2':>12}")
    print(f"{'shifted oscillation (w, s)':<34} {n:6d} {a:6.0%} {b:12.0%}")
    a, b, n, ends = body_fractions(args.body_starts)
    print(f"{'cantilever E, start E/E* in [1/3,3]':<34} {n:6d} {a:6.0%} {b:12.0%}")
    for e0, ea, eb in ends:
        print(f"    start {e0:6.3f} E*:  l2 -> {ea:.6f} E*,  spectral+l2 -> {eb:.6f} E*")


if __name__ == "__main__":
    main()
