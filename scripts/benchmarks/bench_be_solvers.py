"""Iterations and wall time of one backward-Euler step by five solvers, on a bar and a cloth.

What is measured
----------------
One BE step ``ImplicitIntegrator(system, "be")`` from a fixed state (the state is not advanced:
every timed step starts from the same q0, v0), with the solver chosen by options only:

* ``ngs-gs``: ``-snes_type ngs`` (petsoft's nonlinear Gauss-Seidel: one 3x3 Newton update per
  node, colour by colour, :mod:`petsoft.dynamics.nonlinear_gs`);
* ``ngs-jacobi``: ``-snes_type ngs -petsoft_ngs jacobi`` (all nodes from the old iterate,
  relaxation 0.95 min(1, 2/k));
* ``shell-cg``: ``-petsoft_jacobian shell`` (Newton; CG + Jacobi on the unassembled Jacobian,
  :mod:`petsoft.dynamics.matrix_free`);
* ``newton-mumps``: ``-ksp_type preonly -pc_type lu -pc_factor_mat_solver_type mumps``;
* ``newton-gamg``: ``-ksp_type cg -pc_type gamg`` (rigid-body near-nullspace on the bar).

All stop at petsoft's SNES tolerances (||R|| < 1e-10 ||R0|| or 1e-12), the CG variants with
``-ksp_rtol 1e-8``; the NGS sweeps are capped at ``--max-sweeps`` (a capped solve is reported
as not converged; a solver whose warm-up step exceeds ``--budget`` seconds is timed by that
step alone). Cases:

* bar: 0.4 x 0.04 x 0.04 m neo-Hookean, E = 1e6 Pa, nu = 0.3, rho = 1100, clamped at x = 0,
  gravity, v0 = (0, 0, 2x) (a bending swing), P1 tetrahedra of a box of m x m/10 x m/10 cells
  x 6; step ``--bar-step`` (default 1e-3 s: c h / dx = 30 m/s x 1e-3 / cell size);
* cloth: 1 x 1 m, n x n nodes (structural, shear and bending springs), total mass 0.2 kg,
  stiffness 200 N/m, bending 2 N/m, held at two corners, gravity, from rest; step
  ``--cloth-step`` (default 1/100 s).

Every case also runs at its step / ``--small`` (default 10): the sweeps of Gauss-Seidel and
Jacobi grow with the ratio of stiffness to mass in the step matrix (k h^2 / m, (c h / dx)^2),
so small steps are where they can compete.

Timing: one untimed warm-up step per solver, then ``--repeat`` rounds each timing every solver
once in turn (so a slow phase of a shared machine hits all alike); best time reported, ratios
are to newton-mumps's best time of the same run. ``agree`` is ||q1 - q1_mumps|| / ||q1_mumps||.
The machine's load average is printed first: timings taken while other jobs run are not
meaningful (the iteration counts are).

Run
---
    .venv/bin/python scripts/benchmarks/bench_be_solvers.py           # 3 sizes each
    .venv/bin/python scripts/benchmarks/bench_be_solvers.py --quick   # tiny, for a smoke test
    mpiexec -n 2 .venv/bin/python scripts/benchmarks/bench_be_solvers.py
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import petsc4py

petsc4py.init(sys.argv[:1])

import numpy as np  # noqa: E402
from petsc4py import PETSc  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _bench_common import COMM, say, timed_interleaved, wall  # noqa: E402

from petsoft.dynamics.implicit import ImplicitIntegrator  # noqa: E402
from petsoft.dynamics.mass_spring import (  # noqa: E402
    MassSpringSystem,
    build_mass_spring_model,
    cloth_mesh,
)
from petsoft.dynamics.system import DynamicSystem  # noqa: E402
from petsoft.experiment import experiment_from_dict  # noqa: E402
from petsoft.mesh.springs import write_spring_mesh  # noqa: E402
from petsoft.physics.model import build_model  # noqa: E402

SOLVERS = {
    "ngs-gs": {"snes_type": "ngs"},
    "ngs-jacobi": {"snes_type": "ngs", "petsoft_ngs": "jacobi"},
    "shell-cg": {"petsoft_jacobian": "shell", "ksp_rtol": "1e-8"},
    "newton-mumps": {"ksp_type": "preonly", "pc_type": "lu",
                     "pc_factor_mat_solver_type": "mumps"},
    "newton-gamg": {"ksp_type": "cg", "pc_type": "gamg", "ksp_rtol": "1e-8"},
}
REFERENCE = "newton-mumps"


def bar_system(m: int) -> DynamicSystem:
    k = max(1, m // 10)
    exp = experiment_from_dict({
        "mesh": {"box": {"size": [0.4, 0.04, 0.04], "cells": [m, k, k]}},
        "material": {"model": "neohookean", "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                     "density": 1100.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
    }, source=f"bar {m}x{k}x{k}")
    return DynamicSystem(build_model(exp))


def cloth_system(n: int, directory: str) -> MassSpringSystem:
    path = str(Path(directory) / f"cloth{n}.vtu")
    if COMM.rank == 0:
        mesh = cloth_mesh(n, n, 1.0, 1.0)
        write_spring_mesh(path, mesh.points, mesh.lines, mesh.triangles)
    COMM.barrier()
    exp = experiment_from_dict({
        "mesh": {"file": path},
        "springs": {"stiffness": 200.0, "bending": 2.0, "node_mass": 0.2 / n**2},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "boundary": [{"kind": "fixed", "where": "y > 0.999 and (x < 1e-6 or x > 0.999)"}],
    }, source=f"cloth {n}x{n}")
    return MassSpringSystem(build_mass_spring_model(exp))


def initial_state(system):
    q0, v0 = system.create_vec(), system.create_vec()
    q0.zeroEntries()
    pts = system.dmesh.mesh.points
    if isinstance(system, DynamicSystem):
        v = np.column_stack([0 * pts[:, 0], 0 * pts[:, 0], 2.0 * pts[:, 0]])
    else:
        v = np.zeros_like(pts)
    system.dmesh.from_file_field(v, v0)
    system.zero_prescribed(v0)
    return q0, v0


class Run:
    """One solver on one system: an integrator with its options under its own prefix."""

    def __init__(self, system, solver: str, h: float, max_sweeps: int):
        self.system, self.solver, self.h = system, solver, h
        self.prefix = f"bbs_{solver.replace('-', '_')}_"
        opts = dict(SOLVERS[solver])
        if solver.startswith("ngs"):
            opts["snes_max_it"] = str(max_sweeps)
        o = PETSc.Options()
        for k, v in opts.items():
            o.setValue(self.prefix + k, v)
        self.integ = ImplicitIntegrator(system, "be", prefix=self.prefix)
        self.q0, self.v0 = initial_state(system)
        self.q1, self.v1 = system.create_vec(), system.create_vec()
        self.report = None

    def __call__(self) -> None:
        self.report = self.integ.step(0.0, self.q0, self.v0, self.h, self.q1, self.v1)

    def iterations(self) -> str:
        r = self.report
        if self.solver.startswith("ngs"):
            return f"{r.newton_iterations} sweeps"
        return f"{r.newton_iterations} N / {r.linear_iterations} L"


def run_case(label: str, system, h: float, args) -> list[dict]:
    dofs = system.create_vec().getSize()
    runs = {name: Run(system, name, h, args.max_sweeps) for name in SOLVERS}
    warm = {n: wall(r) for n, r in runs.items()}   # warm-up (set-up, first factorisation)
    # a solver whose warm-up took longer than --budget is not repeated: its warm-up is its
    # (single, set-up included) time; thousands of sweeps at 1e4 dofs take minutes
    names = [n for n in runs if warm[n] <= args.budget or n == REFERENCE]
    times = timed_interleaved([runs[n] for n in names], args.repeat)
    best = {n: float(t.min()) for n, t in zip(names, times, strict=True)}
    once = [n for n in runs if n not in best]
    best.update({n: warm[n] for n in once})
    names = list(runs)
    ref = runs[REFERENCE].q1
    rows = []
    say(f"\n{label}: {dofs} dofs, h = {h:g} s")
    say(f"{'solver':14s} {'iterations':>16s} {'ms/step':>10s} {'x mumps':>8s} "
        f"{'agree':>9s}  converged")
    for n in names:
        r = runs[n]
        agree = (r.q1 - ref).norm() / ref.norm()
        row = {"case": label, "dofs": dofs, "solver": n, "its": r.iterations(),
               "ms": 1e3 * best[n], "ratio": best[n] / best[REFERENCE], "agree": agree,
               "converged": r.report.converged}
        rows.append(row)
        say(f"{n:14s} {row['its']:>16s} {row['ms']:10.2f} {row['ratio']:8.2f} "
            f"{agree:9.1e}  {row['converged']} {'' if r.report.converged else r.report.reason}"
            + ("  (warm-up only: over --budget)" if n in once else ""))
    ok = [row for row in rows if row["converged"] and row["agree"] < 1e-6]
    if ok:
        win = min(ok, key=lambda row: row["ms"])
        say(f"fastest (converged, agreeing): {win['solver']} ({win['ms']:.2f} ms)")
    for r in runs.values():
        r.integ.destroy()
    return rows


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="tiny sizes, one round")
    p.add_argument("--bar-cells", type=int, nargs="*", default=[20, 40, 80],
                   help="cells along the bar (x m/10 x m/10); none: no bar")
    p.add_argument("--cloth-nodes", type=int, nargs="*", default=[16, 32, 64],
                   help="nodes per side of the cloth; none: no cloth")
    p.add_argument("--bar-step", type=float, default=1e-3)
    p.add_argument("--cloth-step", type=float, default=1e-2)
    p.add_argument("--small", type=float, default=10.0,
                   help="also run every case at step / SMALL (1: only the given steps)")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--max-sweeps", type=int, default=2000)
    p.add_argument("--budget", type=float, default=30.0,
                   help="seconds: a solver whose warm-up step took longer is not repeated")
    args = p.parse_args(argv)
    if args.quick:
        args.bar_cells, args.cloth_nodes, args.repeat = [10], [6], 1
    load = os.getloadavg()
    say(f"ranks {COMM.size}; load average {load[0]:.2f} on {os.cpu_count()} cpus"
        + ("  (BUSY: the timings are not meaningful, the iterations are)"
           if load[0] > 0.5 else ""))
    rows = []
    # each case at its step and at step / --small (mass-dominated: few sweeps)
    steps = lambda h: [h] + ([h / args.small] if args.small > 1 else [])  # noqa: E731
    for m in args.bar_cells:
        system = bar_system(m)
        for h in steps(args.bar_step):
            rows += run_case(f"bar {m} h={h:g}", system, h, args)
    directory = COMM.bcast(tempfile.mkdtemp() if COMM.rank == 0 else None, root=0)
    for n in args.cloth_nodes:
        system = cloth_system(n, directory)
        for h in steps(args.cloth_step):
            rows += run_case(f"cloth {n}x{n} h={h:g}", system, h, args)
    say("\nwinner per case (converged solvers only):")
    for case in dict.fromkeys(r["case"] for r in rows):
        ok = [r for r in rows if r["case"] == case and r["converged"] and r["agree"] < 1e-6]
        if ok:
            order = sorted(ok, key=lambda r: r["ms"])
            say(f"  {case:24s} " + " < ".join(f"{r['solver']} {r['ms']:.1f}" for r in order))


if __name__ == "__main__":
    main()
