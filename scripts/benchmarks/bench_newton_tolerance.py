"""What a looser Newton tolerance saves in diagnose's forward runs, and what it costs in accuracy.

Every time step of a forward run is solved by Newton's chord to a relative residual tolerance
(``-fm_snes_rtol``): the forward model's default 1e-12, diagnose's ``NEWTON_RTOL`` (1e-6,
:mod:`petsoft.diagnosis.context`). This runs one forward run and one forward-sensitivity run
(the unit of a Gauss-Newton iteration) of a recorded case's model over its identification window
at several tolerances, side by side in one process, and prints per tolerance: residual
evaluations and back-substitutions per step (PETSc's event counts: these, not seconds, are what
the tolerance changes; the seconds are printed too, from the same run), and the largest change
of the simulated markers against the tightest tolerance, in units of the recording's noise.

Run (one rank; nothing else running if the seconds are to mean anything)::

    .venv/bin/python scripts/benchmarks/bench_newton_tolerance.py \\
        [--case scripts/benchmarks/independent/cases/control-plate] [--order 2] \\
        [--rtol 1e-12,1e-8,1e-6]

Things to try: ``--order 1`` (4-node elements: fewer dofs, the same iteration counts),
``--case`` any folder with ``user.toml`` and ``recording.h5`` (the realistic cases in
scripts/benchmarks/realistic/cases).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import petsc4py

petsc4py.init(sys.argv[:1])
import numpy as np  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from petsoft.calibration.calibrate import build_forward  # noqa: E402
from petsoft.calibration.forward import forward_defaults  # noqa: E402
from petsoft.calibration.refinement import refinement  # noqa: E402
from petsoft.experiment.parameters import get_parameter  # noqa: E402
from petsoft.experiment.reader import load_experiment  # noqa: E402
from petsoft.io.recording import read_recording  # noqa: E402

HERE = Path(__file__).resolve().parent
EVENTS = ("SNESFunctionEval", "MatSolve", "MatCholFctrNum", "MatLUFactorNum")


def counts() -> dict[str, int]:
    return {e: int(PETSc.Log.Event(e).getPerfInfo().get("count", 0)) for e in EVENTS}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default=str(HERE / "independent" / "cases" / "control-plate"))
    ap.add_argument("--order", type=int, default=2)
    ap.add_argument("--rtol", default="1e-12,1e-8,1e-6")
    ap.add_argument("--fraction", type=float, default=0.7,
                    help="identification window (share of the record), as diagnose's")
    args = ap.parse_args()
    PETSc.Log.begin()
    case = Path(args.case)
    exp = load_experiment(case / "user.toml")
    if args.order == 2 and exp.mesh.order == 1:
        exp = refinement("P2").make(exp)
    rec = read_recording(case / "recording.h5")
    t = rec.times
    ident = t <= t[0] + args.fraction * (t[-1] - t[0]) + 1e-12
    names = list(exp.calibrate)
    values = np.array([get_parameter(exp, n) for n in names])
    noise = rec.noise.get("position_std")
    print(f"{case.name}: {exp.mesh.order}-order elements, {int(ident.sum())} frames, "
          f"step {exp.time.step} s, parameters {dict(zip(names, values, strict=True))}")
    rows, ref = [], None
    for rtol in [float(x) for x in args.rtol.split(",")]:
        with forward_defaults(snes_rtol=repr(rtol)):
            fm = build_forward(exp, names, rec, t[ident], PETSc.COMM_WORLD)
            before = counts()
            t0 = time.perf_counter()
            sim = fm.simulate(values)
            t1 = time.perf_counter()
            fm.jacobian(values)
            t2 = time.perf_counter()
            after = counts()
            steps = fm.nsteps
            fm.destroy()
        n = {e: (after[e] - before[e]) / (2 * steps) for e in EVENTS}
        if ref is None:
            ref = sim
        change = float(np.max(np.abs(sim - ref)))
        rows.append((rtol, n, t1 - t0, t2 - t1, change))
    unit = "x noise" if noise else "m"
    scale = noise or 1.0
    print(f"\n| rtol | residuals / step | back-substitutions / step | factorisations / step | "
          f"simulate s | sensitivities s | max change ({unit}) |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for rtol, n, ts, tj, change in rows:
        print(f"| {rtol:.0e} | {n['SNESFunctionEval']:.2f} | {n['MatSolve']:.2f} | "
              f"{n['MatCholFctrNum'] + n['MatLUFactorNum']:.2f} | {ts:.2f} | {tj:.2f} | "
              f"{change / scale:.2e} |")
    print("\n(per step: the forward run's and the sensitivity run's steps together; the "
          "sensitivity run's back-substitutions include its tangent solves)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
