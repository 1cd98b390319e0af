"""Cost of one gradient (forward sensitivities, discrete adjoint) relative to one forward run.

What is measured
----------------
A neo-Hookean bar (box ``--cells`` hexahedra x 6 tets, 0.3 x 0.04 x 0.04 m, E = 1e5 Pa,
nu = 0.3, rho = 1000 kg/m^3, light Rayleigh damping, gravity, clamped at x = 0) released from a
bend, observed by 8 markers (reference points on the tip face and the side) at ``--frames``
frame times spread over the run (not aligned with the steps). For each integrator (be, si,
alpha) and each number of parameters P:

* P = 2: ``material.youngs_modulus``, ``material.poisson_ratio``;
* P = 10, 100: a stiffness field, ``material.youngs_modulus#k`` multipliers on P Morton-chunk
  cell groups (see :mod:`petsoft.dynamics.parameters`);

the table gives the wall time of

* ``forward``: :meth:`ForwardModel.simulate` (one run, Newton to rtol 1e-12);
* ``sens``: :meth:`ForwardModel.jacobian`, the forward run plus P tangent solves per step with
  the step's Jacobian (reassembled at the converged state) -> the full dsim/dp;
* ``adjoint``: :meth:`ForwardModel.gradient` of a least-squares misfit, the forward run with the
  trajectory kept plus one backward sweep (one Jacobian assembly and solve per step, P dot
  products);

and the ratios sens/forward and adjoint/forward from the same run. Expect sens/forward to grow
~linearly in P (one linear solve per parameter and step; the Jacobian and its preconditioner are
set up once per step) and adjoint/forward to stay ~constant (about 1 + the cost of one linear
solve and one assembly per step relative to a Newton step); SI is cheapest forward (one linear
solve per step) so its ratios are the largest. ``agree`` is max_j |g_adj - g_sens|_j / max |g|
(scaled by the parameter values): the two gradients are the same number.

Timing: each entry is the best of ``--repeat`` calls (barrier before, max over ranks) of wall time
or, with ``--clock cpu``, of the process's CPU time (much less noisy for a serial run on a shared,
overloaded machine; with MPI it includes busy-waiting); ratios are more meaningful than absolute
times.

Run
---
    .venv/bin/python scripts/benchmarks/bench_gradient.py                  # ~20 s, default sizes
    .venv/bin/python scripts/benchmarks/bench_gradient.py --quick  # smoke run, a few seconds
    mpiexec -n 2 .venv/bin/python scripts/benchmarks/bench_gradient.py     # 2 ranks (same table)

Things to try
-------------
* a bigger mesh and run: ``--cells 40 6 6 --steps 40`` (sens/forward grows with P; adjoint/forward
  does not);
* one integrator, more parameters: ``--integrators alpha --params 2 10 100 400``;
* a direct solver for the sensitivity/adjoint solves (options go after the script's arguments):
  ``-fm_grad_ksp_type preonly -fm_grad_pc_type lu`` (serial) -- the Jacobian factored once per
  step makes each of the P sensitivity solves two triangular solves;
* ``-log_view`` to see where the time goes (KSPSolve, MatAssembly, PCSetUp).
"""

from __future__ import annotations

import argparse
import os
import sys

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

_parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                  epilog="Unknown arguments are passed to PETSc.")
_parser.add_argument("--cells", type=int, nargs=3, default=[20, 4, 4],
                     help="box cells (x, y, z); default 20 4 4 (1920 tets, 1575 dofs)")
_parser.add_argument("--steps", type=int, default=20, help="time steps (default 20)")
_parser.add_argument("--step", type=float, default=2e-3, help="time step in s (default 2e-3)")
_parser.add_argument("--frames", type=int, default=7, help="observed frames (default 7)")
_parser.add_argument("--params", type=int, nargs="+", default=[2, 10, 100],
                     help="numbers of parameters (default 2 10 100)")
_parser.add_argument("--integrators", nargs="+", default=["be", "si", "alpha"],
                     choices=["be", "si", "alpha"])
_parser.add_argument("--repeat", type=int, default=2, help="timed calls per entry (default 2)")
_parser.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                     help="wall time (default) or CPU time of the process (max over ranks): on a "
                          "shared, overloaded machine CPU time of a serial run is far less noisy")
_parser.add_argument("--quick", action="store_true",
                     help="smoke run: 10 x 2 x 2 cells, 4 steps, 1 repeat")
ARGS, _petsc_args = _parser.parse_known_args()

import petsc4py  # noqa: E402

import petsoft  # noqa: E402, F401  before petsc4py.init: one BLAS thread (petsoft/__init__.py)

petsc4py.init([sys.argv[0]] + _petsc_args)
import time  # noqa: E402

from _bench_common import COMM, NRANKS, progress, say, wall  # noqa: E402

from petsoft.calibration.forward import ForwardModel  # noqa: E402
from petsoft.calibration.observation import MarkerObserver  # noqa: E402
from petsoft.experiment import experiment_from_dict  # noqa: E402

if ARGS.quick:
    ARGS.cells, ARGS.steps, ARGS.repeat, ARGS.frames = [10, 2, 2], 4, 1, 3

L = (0.3, 0.04, 0.04)
MARKERS = np.array([[0.3, 0.0, 0.0], [0.3, 0.04, 0.0], [0.3, 0.0, 0.04], [0.3, 0.04, 0.04],
                    [0.3, 0.02, 0.02], [0.15, 0.0, 0.02], [0.15, 0.04, 0.02], [0.075, 0.02, 0.04]])


def experiment(integrator: str):
    return experiment_from_dict({
        "mesh": {"box": {"size": list(L), "cells": list(ARGS.cells)}},
        "material": {"model": "neohookean", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "damping": {"mass": 0.5, "stiffness": 1e-3},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"displacement": ["0", "0", "0.5*x**2"]},
        "time": {"end": ARGS.steps * ARGS.step, "step": ARGS.step, "integrator": integrator},
    }, source="bench_gradient")


def names_for(P: int) -> list[str]:
    if P == 2:
        return ["material.youngs_modulus", "material.poisson_ratio"]
    return [f"material.youngs_modulus#{k}" for k in range(P)]


def cpu(fn) -> float:
    """CPU time of one collective call (barrier before, max over ranks)."""
    from mpi4py import MPI

    COMM.Barrier()
    t0 = time.process_time()
    fn()
    return COMM.allreduce(time.process_time() - t0, op=MPI.MAX)


def best(fn) -> float:
    clock = cpu if ARGS.clock == "cpu" else wall
    return min(clock(fn) for _ in range(ARGS.repeat))


def main() -> None:
    T = ARGS.steps * ARGS.step
    # frames strictly inside steps (0.37 of a step past a step time), the last at the end
    frames = np.linspace(0.0, T, ARGS.frames + 1)[1:]
    frames[:-1] -= 0.63 * ARGS.step
    ntets = 6 * int(np.prod(ARGS.cells))
    say(f"bench_gradient: neo-Hookean bar, {ntets} tets, "
        f"{3 * int(np.prod(np.array(ARGS.cells) + 1))} dofs, {ARGS.steps} steps of "
        f"{ARGS.step:g} s, {len(MARKERS)} markers x {len(frames)} frames; {NRANKS} MPI rank(s); "
        f"best of {ARGS.repeat}, {ARGS.clock} time")
    say(f"{'integrator':>10} {'P':>4} {'forward s':>10} {'sens s':>9} {'adjoint s':>10} "
        f"{'sens/fwd':>9} {'adj/fwd':>8} {'agree':>9}")
    rng = np.random.default_rng(0)
    for method in ARGS.integrators:
        for P in ARGS.params:
            progress(f"{method}, P = {P}")
            fm = ForwardModel(experiment(method), names_for(P),
                              lambda s: MarkerObserver(s, MARKERS), frames)
            p = fm.p0.copy()
            sim0 = fm.simulate(p)
            target = sim0 + 1e-3 * rng.standard_normal(sim0.shape)

            def dphi(sim, target=target):
                r = sim - target
                return 0.5 * float(np.sum(r * r)), r

            out = {}
            t_fwd = best(lambda: out.__setitem__("sim", fm.simulate(p)))     # noqa: B023
            t_sens = best(lambda: out.__setitem__("jac", fm.jacobian(p)))    # noqa: B023
            t_adj = best(lambda: out.__setitem__("grad", fm.gradient(p, dphi)))  # noqa: B023
            sim, jac = out["jac"]
            g_sens = np.einsum("kmc,kmcp->p", sim - target, jac)
            g_adj = out["grad"][1]
            scale = np.where(p != 0, np.abs(p), 1.0)
            agree = np.abs((g_adj - g_sens) * scale).max() / np.abs(g_sens * scale).max()
            say(f"{method:>10} {P:>4} {t_fwd:>10.3f} {t_sens:>9.3f} {t_adj:>10.3f} "
                f"{t_sens / t_fwd:>9.2f} {t_adj / t_fwd:>8.2f} {agree:>9.1e}")
            fm.destroy()


if __name__ == "__main__":
    main()
