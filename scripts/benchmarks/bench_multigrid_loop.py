"""A backward-Euler time loop under CG + GAMG: the multigrid kept across steps vs a new one a step.

What is measured
----------------
``bench_step.py`` times one step from the same state again and again, so a kept multigrid
interpolation is always the one of the very matrix being solved. This benchmark runs what a user
runs: a time loop whose state moves. The bar of ``bench_step.py`` (0.4 x 0.04 x 0.04 m,
neo-Hookean, E = 1 MPa, nu = 0.45, rho = 1100, clamped at x = 0) falls from rest under gravity
and swings far (finite rotations), ``--steps`` backward-Euler steps of h = 1/60 s, CG + GAMG
(the rigid-body near-nullspace, as the integrator sets it), in two ways:

* ``kept``: ``integrator.keep_factors(True)``, as ``petsoft simulate`` does: the solver lives
  across steps and each step sets GAMG up on its new matrix with the interpolation kept
  (PETSc's default ``-pc_gamg_reuse_interpolation``), renewed after a step that needs more than
  twice the CG iterations of the first kept step plus 10;
* ``new``: a new solver, so a new hierarchy, at every step (what petsoft did before 88a798e).

The two runs alternate ``--repeat`` times (noise on a shared machine hits both alike); each
prints its wall time (max over ranks), Newton and CG iterations, and the final displacement
norm, which must agree to the Newton tolerance.

Run
---
    .venv/bin/python scripts/benchmarks/bench_multigrid_loop.py              # ~27k dofs, 30 steps
    mpiexec -n 2 .venv/bin/python scripts/benchmarks/bench_multigrid_loop.py --cells 90 9 9
"""

from __future__ import annotations

import argparse
import sys

import petsc4py

_parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
_parser.add_argument("--cells", type=int, nargs=3, default=[90, 9, 9],
                     help="box cells (x 6 tets; default 90 9 9: 27,300 dofs)")
_parser.add_argument("--steps", type=int, default=30, help="time steps (default 30)")
_parser.add_argument("--repeat", type=int, default=2, help="runs of each way (default 2)")
ARGS, _rest = _parser.parse_known_args()

import petsoft  # noqa: E402, F401  one BLAS thread before PETSc starts

petsc4py.init([sys.argv[0], "-ksp_type", "cg", "-pc_type", "gamg"] + _rest)
import numpy as np  # noqa: E402
from _bench_common import say, wall  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from petsoft.dynamics.implicit import ImplicitIntegrator  # noqa: E402
from petsoft.dynamics.system import DynamicSystem  # noqa: E402
from petsoft.experiment import experiment_from_dict  # noqa: E402
from petsoft.physics.model import build_model  # noqa: E402

H = 1.0 / 60.0


def run(system: DynamicSystem, keep: bool, steps: int) -> dict:
    """``steps`` steps from rest; returns wall time, iteration counts and |q| at the end."""
    integ = ImplicitIntegrator(system, "be")
    integ.keep_factors(keep)
    q, v = system.create_vec(), system.create_vec()
    q.zeroEntries()
    v.zeroEntries()
    q1, v1 = q.duplicate(), v.duplicate()
    counts = {"newton": 0, "cg": 0, "solvers": 0}
    last = None

    def loop() -> None:
        nonlocal last
        for n in range(steps):
            report = integ.step(n * H, q, v, H, q1, v1)
            if not report.converged:
                raise RuntimeError(f"step {n + 1} did not converge: {report.reason}")
            counts["newton"] += report.newton_iterations
            counts["cg"] += report.linear_iterations
            counts["solvers"] += integ.snes is not last
            last = integ.snes
            q1.copy(q)
            v1.copy(v)

    seconds = wall(loop)
    out = {"seconds": seconds, "norm": q.norm(), **counts}
    for x in (q, v, q1, v1):
        x.destroy()
    integ.destroy()
    return out


def main() -> None:
    exp = experiment_from_dict({
        "mesh": {"box": {"size": [0.4, 0.04, 0.04], "cells": ARGS.cells}},
        "material": {"model": "neohookean", "youngs_modulus": 1e6, "poisson_ratio": 0.45,
                     "density": 1100.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}]}, source="bench_multigrid_loop")
    system = DynamicSystem(build_model(exp))
    dofs = system.create_vec().getSize()
    say(f"backward Euler, h = 1/60 s, {ARGS.steps} steps from rest under gravity; {dofs} dofs, "
        f"{PETSc.COMM_WORLD.getSize()} rank(s); CG + GAMG")
    rows = {"kept": [], "new": []}
    for i in range(ARGS.repeat):
        for way in rows:
            r = run(system, way == "kept", ARGS.steps)
            rows[way].append(r)
            say(f"  run {i + 1} {way:4}: {r['seconds']:.2f} s, Newton {r['newton']}, "
                f"CG {r['cg']}, hierarchies {r['solvers']}, |q| {r['norm']:.12e}")
    best = {w: min(r["seconds"] for r in rs) for w, rs in rows.items()}
    gap = abs(rows["kept"][0]["norm"] - rows["new"][0]["norm"]) / rows["new"][0]["norm"]
    say(f"\nbest of {ARGS.repeat}: kept {best['kept']:.2f} s, new {best['new']:.2f} s, "
        f"kept / new = {best['kept'] / best['new']:.2f}; CG its kept / new = "
        f"{rows['kept'][0]['cg'] / rows['new'][0]['cg']:.2f}; |q| agree to {gap:.1e}")
    if not np.isfinite(gap) or gap > 1e-8:
        raise SystemExit("the two ways end in different states")


if __name__ == "__main__":
    main()
