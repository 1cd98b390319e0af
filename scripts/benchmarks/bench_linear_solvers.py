"""Which linear solver a forward run should use by default, by problem size.

What is measured
----------------
One :meth:`ForwardModel.simulate` (generalized-alpha, Newton to rtol 1e-12, one Jacobian
factorisation or multigrid set-up per Newton iteration) of a cantilever bar (0.3 x 0.04 x 0.04 m,
E = 1e6 Pa, clamped at x = 0, released from a bend) on box meshes of growing size, with each of
the forward Newton's linear solvers chosen by PETSc options:

* ``mumps``: ``-fm_ksp_type preonly -fm_pc_type lu -fm_pc_factor_mat_solver_type mumps``;
* ``petsc-lu``: PETSc's own LU (its default nested-dissection ordering), serial only;
* ``cg-gamg``: CG + algebraic multigrid (rtol 1e-12, the rigid-body near-nullspace);
* ``default``: what petsoft picks with no options (:func:`petsoft.solvers.linear.linear_defaults`:
  direct up to ``DIRECT_DOFS`` dofs, ``DIRECT_DOFS_QUADRATIC`` for 10-node elements);
* ``direct``: the default's direct solve at every size (``direct_solve_up_to``, one rank: the
  factor is kept across a step's Newton iterations, which naming ``-fm_pc_type`` turns off).

The table gives milliseconds per time step (best of ``--repeat``, interleaved so a slow phase of
a shared machine hits all solvers alike) and each solver's time relative to CG + GAMG from the
same run. The crossover where multigrid wins is what ``DIRECT_DOFS`` should follow.

Run
---
    .venv/bin/python scripts/benchmarks/bench_linear_solvers.py             # ~2 minutes
    .venv/bin/python scripts/benchmarks/bench_linear_solvers.py --quick     # smoke run
    mpiexec -n 2 .venv/bin/python scripts/benchmarks/bench_linear_solvers.py

Things to try: ``--material neohookean`` (Newton takes several iterations per step);
``--order 2`` (10-node tetrahedra: denser rows, a different crossover);
``--sizes 12 24 48`` (cells along the bar; the section has a sixth of them, at least 2).
"""

from __future__ import annotations

import argparse
import sys

_parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                  epilog="Unknown arguments are passed to PETSc.")
_parser.add_argument("--sizes", type=int, nargs="+", default=[12, 24, 36, 48],
                     help="cells along the bar (default 12 24 36 48)")
_parser.add_argument("--steps", type=int, default=20, help="time steps (default 20)")
_parser.add_argument("--material", default="linear", choices=["linear", "neohookean"])
_parser.add_argument("--order", type=int, default=1, choices=[1, 2],
                    help="element order (default 1: 4-node tetrahedra)")
_parser.add_argument("--repeat", type=int, default=2, help="timed runs per entry (default 2)")
_parser.add_argument("--quick", action="store_true", help="smoke run: one small size, 3 steps")
ARGS, _petsc_args = _parser.parse_known_args()

import petsc4py  # noqa: E402

import petsoft  # noqa: E402, F401  before petsc4py.init: one BLAS thread (petsoft/__init__.py)

petsc4py.init([sys.argv[0]] + _petsc_args)

import numpy as np  # noqa: E402
from _bench_common import NRANKS, progress, say, timed_interleaved  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from petsoft.calibration.forward import ForwardModel  # noqa: E402
from petsoft.calibration.observation import MarkerObserver  # noqa: E402
from petsoft.experiment import experiment_from_dict  # noqa: E402
from petsoft.solvers.linear import direct_limit, direct_solve_up_to  # noqa: E402

SOLVERS = {
    "default": {},
    "mumps": {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"},
    "petsc-lu": {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "petsc"},
    "direct": None,
    "cg-gamg": {"ksp_type": "cg", "pc_type": "gamg"},
}
MARKERS = np.array([[0.3, 0.0, 0.0], [0.3, 0.04, 0.04], [0.15, 0.02, 0.04]])
STEP = 2e-3


def experiment(nx: int):
    ny = max(2, nx // 6)
    return experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [nx, ny, ny]},
                 "order": ARGS.order},
        "material": {"model": ARGS.material, "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"displacement": ["0", "0", "0.05*x**2"]},
        "time": {"end": ARGS.steps * STEP, "step": STEP, "integrator": "alpha"},
    }, source="bench_linear_solvers")


def with_options(opts: dict | None, fn):
    """Call ``fn`` with the forward Newton's linear-solver options set (prefix ``fm_``); None:
    the default's direct solve whatever the size."""
    if opts is None:
        with direct_solve_up_to(10**9):
            return fn()
    db = PETSc.Options()
    for k, v in opts.items():
        db.setValue("fm_" + k, v)
    try:
        return fn()
    finally:
        for k in opts:
            db.delValue("fm_" + k)


def main() -> None:
    if ARGS.quick:
        ARGS.sizes, ARGS.steps, ARGS.repeat = [6], 3, 1
    solvers = [s for s in SOLVERS if not (s in ("petsc-lu", "direct") and NRANKS > 1)]
    if not PETSc.Sys.hasExternalPackage("mumps"):
        solvers.remove("mumps")
    say(f"bench_linear_solvers: {ARGS.material} bar, order {ARGS.order}, generalized-alpha, "
        f"{ARGS.steps} steps; "
        f"{NRANKS} rank(s); ms per step, best of {ARGS.repeat}; ratio = time / cg-gamg's; "
        f"petsoft's default is direct up to {direct_limit(ARGS.order)} dofs")
    say(f"{'tets':>7} {'dofs':>7} " + " ".join(f"{s:>16}" for s in solvers))
    frames = np.array([ARGS.steps * STEP])
    for nx in ARGS.sizes:
        exp = experiment(nx)
        fm = ForwardModel(exp, ["material.youngs_modulus"],
                          lambda s: MarkerObserver(s, MARKERS), frames)
        dofs = fm.system.create_vec().getSize()
        progress(f"{nx} cells along, {dofs} dofs")
        p = fm.p0.copy()
        ref = fm.simulate(p)
        results = {}

        def run(name, fm=fm, p=p, results=results):
            def go():
                results[name] = with_options(SOLVERS[name], lambda: fm.simulate(p))
            return go

        times = timed_interleaved([run(s) for s in solvers], ARGS.repeat)
        best = {s: float(t.min()) / ARGS.steps * 1e3 for s, t in zip(solvers, times, strict=True)}
        for s in solvers:
            # every solver computes the same trajectory (to the Newton tolerance)
            err = float(np.abs(results[s] - ref).max())
            if err > 1e-8:
                say(f"  {s}: trajectory differs from the default's by {err:.2e} m")
        ntets = 6 * nx * max(2, nx // 6) ** 2
        say(f"{ntets:>7} {dofs:>7} " + " ".join(
            f"{best[s]:>8.1f} ({best[s] / best['cg-gamg']:>4.2f}x)" for s in solvers))
        fm.destroy()


if __name__ == "__main__":
    main()
