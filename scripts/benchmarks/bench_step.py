"""Wall time of one backward-Euler step (full Newton) of a neo-Hookean bar: petsoft vs DOLFINx.

What is measured
----------------
The lecture's bar, 0.4 x 0.04 x 0.04 m, neo-Hookean

    psi(F) = mu/2 (tr C - 3) - mu ln J + lam/2 (ln J)^2,   E = 1e6 Pa, nu = 0.45, rho = 1100,

clamped at x = 0, under gravity (0, 0, -9.81), P1 tetrahedra (box of 10m x m x m hexahedra x 6
tets, 3 dofs per vertex; sizes are dof counts, rounded to the nearest such box). From rest in a
smooth bend (pure bending: the axis bent up into a circular arc of curvature 0.5/m, the tip
rotated by 0.2 rad and lifted 4 cm, axial strains +-1 %, sections deformed as Poisson's ratio
asks; finite rotations, so Newton iterates several times) one backward-Euler step of h = 1/60 s,

    R(q1) = M (q1 - q0 - h v0)/h^2 + dW/dq(q1) - f_grav = 0,     M the consistent mass,

solved by full Newton from the predictor q0 + h v0, Newton tolerance ||R|| < 1e-10 ||R_0||
(or < 1e-12), with two linear solvers per Newton iteration, both in the same run:

* ``gamg``:  CG + GAMG with the rigid-body near-nullspace, KSP rtol 1e-12 (petsoft's default above
  100,000 dofs on one rank and 6000 on several; named by options here);
* ``mumps``: ``-ksp_type preonly -pc_type lu -pc_factor_mat_solver_type mumps``.

* petsoft: ``build_model`` + ``DynamicSystem`` + ``ImplicitIntegrator(system, "be")`` built once
  (set-up, printed separately); the linear solver is chosen by putting its PETSc options in the
  database while that solver's steps run. With ``gamg`` the integrator keeps its solver across
  steps as ``petsoft simulate``'s time loop does (``keep_factors(True)``): each step sets the
  hierarchy up on its new matrix with the interpolation kept (PETSc's default
  ``-pc_gamg_reuse_interpolation``), as DOLFINx's kept KSP does. With ``mumps`` it does not (the
  timed steps all start from the same state, so factors kept from the warm-up would be exact
  and skip the factorisation DOLFINx's steps do): MUMPS keeps its symbolic analysis and
  refactors numerically. Timed: ``integrator.step(0, q0, v0, h, q1, v1)``
  (which starts from q0, v0 every time: the state is not advanced).
* DOLFINx (only when ``import dolfinx`` works, e.g. Debian's python3-dolfinx-real; otherwise
  skipped, saying so): the same residual in UFL (energy differentiated by ``ufl.derivative``;
  mass and gravity forms integrated exactly: quadrature degree 2 and 1), Jacobian by
  ``ufl.derivative``, ``fem.petsc.NonlinearProblem`` with the clamp as a ``dirichletbc``, solved
  by ``dolfinx.nls.petsc.NewtonSolver`` with SNES's stopping test ||R|| < max(1e-12,
  1e-10 ||R_0||) given as its absolute tolerance (DOLFINx 0.5.2's "relative" residual divides by
  the norm of the first Newton update, not by ||R_0||). Its KSP gets the same types, tolerances
  and options (from the same database, no prefix), the same near-nullspace
  (``NullSpace.createRigidBody`` of the dof coordinates) and the same ``MAT_SYMMETRIC`` flag as
  petsoft's. The DOLFINx mesh is built from petsoft's points and tetrahedra (``create_mesh``;
  DOLFINx partitions and renumbers it itself). Timed: reset u to the predictor +
  ``solver.solve(u)``; its KSP (and so MUMPS's symbolic factorisation) lives across steps, as in
  a DOLFINx time loop.

Timing: one untimed warm-up step per code and solver (JIT, MUMPS symbolic factorisation, GAMG
first set-up; printed as set-up), then ``--repeat`` rounds, each timing one petsoft step and one
DOLFINx step in turn (so noise on this shared machine hits both alike); every step is bracketed by
an MPI barrier and its time is the max over ranks. The table reports the BEST step time and the
ratio of the best times of the same run; medians are in the details. Newton and KSP iteration
counts of both are printed (the comparison is per step, not per iteration). Where the time goes:
PETSc log stages per code/solver/size give per-step averages of residual assembly, Jacobian
assembly, PCSetUp (GAMG hierarchy or LU factorisation), KSPSolve (CG iterations or triangular
solves) and the rest.

Correctness (smallest size, each solver): q1 of both, DOLFINx's dofs matched to petsoft's
vertices by coordinates. Both take the same Newton iterates (the residual norms agree to ~1e-9),
so ||q1_petsoft - q1_dolfinx|| / ||q1_petsoft - q0|| is ~1e-12 with GAMG (the KSP tolerance)
and round-off with MUMPS.

Run
---
    .venv/bin/python scripts/benchmarks/bench_step.py  # 1 rank, ~1e4, 1e5, 1e6 dofs
    export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 \\
           OMPI_MCA_rmaps_base_oversubscribe=1
    mpiexec -n 2 .venv/bin/python scripts/benchmarks/bench_step.py        # 2 ranks
    .venv/bin/python scripts/benchmarks/bench_step.py --quick  # tiny smoke run (~ seconds)

The 1e6-dof size takes about an hour (GAMG only: MUMPS is skipped above ``--mumps-max-dofs``,
default 3e5; its 3D LU at 1e5 dofs already takes ~7 s and ~2 GB per factorisation, and both grow
about like n^2 and n^(4/3)); ``--sizes 1e4 1e5`` skips it, ``--solvers gamg`` skips MUMPS.

Things to try
-------------
* ``--sizes 3e4 3e5 --repeat 5``, ``--solvers mumps``, ``--no-dolfinx``.
* PETSc options go after the script's own arguments and apply to BOTH codes' linear solvers
  (petsoft's SNES reads the rest): ``-log_view`` (per code/solver/size stages: MatLUFactorNum,
  PCSetUp, KSPSolve, MatZeroRowsColumns, SNESFunctionEval), ``-ksp_converged_reason``,
  ``-pc_gamg_threshold 0.01``, ``-pc_gamg_reuse_interpolation`` (keep the GAMG hierarchy across
  Newton iterations), ``-mg_levels_ksp_max_it 1``, ``-ksp_rtol 1e-8`` (the 1e-12 default is far
  tighter than Newton needs), ``-mat_mumps_icntl_7 5`` (METIS ordering),
  ``-mat_mumps_icntl_14 50``, ``-snes_monitor`` (petsoft only).
  The solver choice itself is ``--solvers``; do not pass ``-ksp_type``/``-pc_type``.
* ``--dolfinx-cflags "-O2 -g0"`` (DOLFINx's default JIT flags; the default here is petsoft's
  kernel flags ``-O3 -fno-math-errno``), ``--bend 0.2`` (fewer Newton iterations).
* ``taskset -c 0`` to pin a serial run; on this 2-core shared machine 2-rank runs are noisy.
* ``OPENBLAS_NUM_THREADS=2`` (threaded BLAS inside MUMPS; the script sets 1 unless the
  environment sets it).
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
from contextlib import contextmanager

# One BLAS (OpenBLAS is threaded on Debian; MUMPS uses it) / OpenMP thread per rank unless the
# environment says otherwise: ranks = cores, and a serial run is serial. Before numpy and PETSc.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

SOLVERS = {
    # CG + GAMG named (on one rank petsoft's default is a direct solve up to 100,000 dofs, so
    # an empty table measured MUMPS here since da75222); the near-nullspace from the integrator
    "gamg": {"ksp_type": "cg", "pc_type": "gamg"},
    "mumps": {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"},
}

# PETSc must see its options (everything argparse does not know) before it is initialised.
_parser = argparse.ArgumentParser(
    description=__doc__.splitlines()[0],
    epilog="Unknown arguments are passed to PETSc (e.g. -log_view).")
_parser.add_argument("--sizes", type=float, nargs="+", default=[1e4, 1e5, 1e6],
                     help="target numbers of dofs (default 1e4 1e5 1e6)")
_parser.add_argument("--repeat", type=int, default=3, help="timed steps per code (default 3)")
_parser.add_argument("--solvers", nargs="+", choices=list(SOLVERS), default=list(SOLVERS),
                     help="linear solvers (default: gamg mumps)")
_parser.add_argument("--mumps-max-dofs", type=float, default=3e5,
                     help="skip MUMPS above this many dofs (default 3e5: a 3D LU of 1e6 dofs "
                          "needs far more memory and time than this machine has)")
_parser.add_argument("--quick", action="store_true",
                     help="smoke run: ~1.5e3 and ~3e3 dofs, 2 repeats")
_parser.add_argument("--no-dolfinx", action="store_true", help="time petsoft only")
_parser.add_argument("--bend", type=float, default=0.5,
                     help="curvature (1/m) of the initial bend (default 0.5: tip rotated 0.2 "
                          "rad, lifted 4 cm)")
_parser.add_argument("--dolfinx-cflags", default="-O3 -fno-math-errno",
                     help="FFCx JIT compiler flags (default: petsoft's kernel flags)")
ARGS, _petsc_args = _parser.parse_known_args()

import petsc4py  # noqa: E402

import petsoft  # noqa: E402, F401  before petsc4py.init: one BLAS thread (petsoft/__init__.py)

petsc4py.init([sys.argv[0]] + _petsc_args)
from _bench_common import (  # noqa: E402
    COMM,
    NRANKS,
    RANK,
    gather_owned,
    import_dolfinx,
    match_points,
    progress,
    say,
    setup_clock,
    timed_interleaved,
    wall,
)
from petsc4py import PETSc  # noqa: E402

from petsoft.dynamics.implicit import ImplicitIntegrator  # noqa: E402
from petsoft.dynamics.system import DynamicSystem  # noqa: E402
from petsoft.experiment import experiment_from_dict  # noqa: E402
from petsoft.fem.kernels.materials import lame_parameters  # noqa: E402
from petsoft.physics.model import build_model  # noqa: E402
from petsoft.solvers.options import clear_options  # noqa: E402

LENGTH, WIDTH = 0.4, 0.04
E_MOD, NU, RHO = 1e6, 0.45, 1100.0
GRAVITY = (0.0, 0.0, -9.81)
H = 1.0 / 60.0
MU, LAM = (float(v) for v in lame_parameters(E_MOD, NU))
NEWTON_RTOL, NEWTON_ATOL, NEWTON_MAXIT = 1e-10, 1e-12, 25   # petsoft's ImplicitIntegrator
KSP_RTOL, KSP_ATOL, KSP_MAXIT = 1e-12, 1e-50, 2000          # petsoft.solvers.linear.linear_defaults

PETSc.Log.begin()  # per-stage event times for the phase breakdown


def bend(x: np.ndarray) -> np.ndarray:
    """The initial displacement at points ``x`` of shape (3, n); returns (3, n). Zero at x = 0.

    Pure bending of curvature kappa = ``--bend`` (Saint-Venant's solution made finite): the axis
    z = WIDTH/2 bent upwards into a circular arc, each section rotated with it and deformed as
    Poisson's ratio asks (anticlastic: lateral strain -nu times the axial strain -kappa zeta), so
    the lateral faces are nearly traction-free; near the clamp, where the section stays
    undeformed, the section deformation fades in over about one width. Without it (a plain arc)
    the bent state carries lateral stresses of order lam kappa WIDTH/2 and its tangent turns
    indefinite (a mode localised at a compressed edge, growing with refinement): CG then fails.
    """
    kappa, nu = ARGS.bend, NU
    zeta, eta = x[2] - WIDTH / 2, x[1] - WIDTH / 2      # section coordinates from the axis
    # the clamp holds the section at x = 0: its deformation fades in over ~ one width
    nu_k = nu * kappa * (1.0 - np.exp(-((x[0] / WIDTH) ** 2)))
    eta1 = eta * (1.0 + nu_k * zeta)
    zeta1 = zeta + 0.5 * nu_k * (zeta**2 - eta**2)
    phi, radius = kappa * x[0], 1.0 / kappa            # rotation of the section at x
    return np.stack([(radius - zeta1) * np.sin(phi) - x[0],
                     eta1 - eta,
                     WIDTH / 2 + radius - (radius - zeta1) * np.cos(phi) - x[2]])


def cells_for(dofs: float) -> tuple[int, int, int]:
    """Box cells (10m, m, m) whose 3 (10m+1)(m+1)^2 dofs are closest to ``dofs`` (log scale)."""
    m = np.arange(1, 200)
    n = 3 * (10 * m + 1) * (m + 1) ** 2
    best = int(m[np.argmin(np.abs(np.log(n / dofs)))])
    return (10 * best, best, best)


@contextmanager
def solver_options(name: str):
    """The linear solver's PETSc options in the database for the block (objects built inside
    read them in ``setFromOptions``); previous values are restored afterwards."""
    opts = PETSc.Options()
    table = SOLVERS[name]
    saved = {k: opts.getString(k) for k in table if opts.hasName(k)}
    for k, v in table.items():
        opts.setValue(k, v)
    try:
        yield
    finally:
        clear_options(list(table))
        for k, v in saved.items():
            opts.setValue(k, v)


def _max(value: float) -> float:
    from mpi4py import MPI
    return COMM.allreduce(float(value), op=MPI.MAX)


# -- petsoft --------------------------------------------------------------------------------------
class PetsoftCase:
    """The bar as a petsoft experiment: model and system once, an integrator per solver."""

    def __init__(self, cells):
        self.setup = {}
        exp = experiment_from_dict({
            "mesh": {"box": {"size": [LENGTH, WIDTH, WIDTH], "cells": list(cells)}},
            "material": {"model": "neohookean", "youngs_modulus": E_MOD, "poisson_ratio": NU,
                         "density": RHO},
            "gravity": {"acceleration": list(GRAVITY)},
            "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        })
        stop = setup_clock()
        self.model = build_model(exp)
        self.setup["model"] = stop()
        stop = setup_clock()
        self.system = DynamicSystem(self.model)
        self.setup["system"] = stop()
        dm = self.dmesh = self.model.dmesh
        self.q0 = dm.from_file_field(bend(dm.mesh.points.T).T)
        self.system.apply_prescribed(self.q0, 0.0)
        self.v0 = dm.create_global_vec()
        self.v0.zeroEntries()
        self.q1, self.v1 = self.q0.duplicate(), self.v0.duplicate()
        self.dofs = self.q0.getSize()
        self.integ = None
        self.report = None

    def make_solver(self, name: str) -> None:
        stop = setup_clock()
        self.integ = ImplicitIntegrator(self.system, "be")
        if name == "gamg":
            # as petsoft simulate's time loop: the steps keep the multigrid solver and set it up
            # on each new matrix with the interpolation kept, as DOLFINx's kept KSP does. Not
            # for MUMPS: every timed step starts from the same state, so factors kept from the
            # warm-up would be exact and the timed steps would skip the factorisation that
            # DOLFINx's steps do.
            self.integ.keep_factors(True)
        self.setup[f"{name}: integrator"] = stop()

    def step(self) -> None:
        self.report = self.integ.step(0.0, self.q0, self.v0, H, self.q1, self.v1)

    def check_report(self) -> None:
        if not self.report.converged:
            raise RuntimeError(f"petsoft's step did not converge: {self.report.reason}")

    def its(self) -> tuple[int, int]:
        return self.report.newton_iterations, self.report.linear_iterations

    def pc(self) -> PETSc.PC:
        return self.integ.ksp.getPC()

    def solution(self):
        """(q1, q0) gathered on rank 0 as (N, 3) arrays in the mesh's vertex numbering."""
        return self.dmesh.gather_global(self.q1), self.dmesh.gather_global(self.q0)

    def drop_solver(self) -> None:
        self.integ.destroy()
        self.integ = None

    def destroy(self) -> None:
        for v in (self.q0, self.v0, self.q1, self.v1):
            v.destroy()
        self.system.destroy()
        self.model.external.destroy()


# -- DOLFINx --------------------------------------------------------------------------------------
class DolfinxCase:
    """The same step as a DOLFINx NonlinearProblem on the same points and tetrahedra."""

    def __init__(self, mods, mesh, cflags: list[str]):
        dolfinx, ufl = mods
        fem = self.fem = dolfinx.fem
        self.dolfinx = dolfinx
        self.setup = {}
        stop = setup_clock()
        domain = ufl.Mesh(ufl.VectorElement("Lagrange", ufl.tetrahedron, 1))
        if RANK == 0:
            cells, x = mesh.tets.astype(np.int64), mesh.points
        else:
            cells, x = np.zeros((0, 4), np.int64), np.zeros((0, 3))
        # Cell integrals only: no ghost cells needed.
        self.msh = msh = dolfinx.mesh.create_mesh(COMM, cells, x, domain,
                                                  ghost_mode=dolfinx.mesh.GhostMode.none)
        self.V = V = fem.VectorFunctionSpace(msh, ("Lagrange", 1))
        self.u, self.q0, v0 = fem.Function(V), fem.Function(V), fem.Function(V)
        self.q0.interpolate(bend)
        v0.x.array[:] = 0.0
        # u at the predictor q0 + h v0
        self.predictor = self.q0.x.array + H * v0.x.array
        dofs = fem.locate_dofs_geometrical(V, lambda p: p[0] < 1e-9)
        self.bc = fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType), dofs, V)
        self.setup["mesh+space"] = stop()

        u, v, du = self.u, ufl.TestFunction(V), ufl.TrialFunction(V)
        c = lambda value: fem.Constant(msh, PETSc.ScalarType(value))  # noqa: E731
        mu, lam, rho, h = c(MU), c(LAM), c(RHO), c(H)
        g = fem.Constant(msh, np.array(GRAVITY, dtype=PETSc.ScalarType))
        F = ufl.Identity(3) + ufl.grad(u)
        J = ufl.det(F)
        psi = mu / 2 * (ufl.tr(F.T * F) - 3) - mu * ufl.ln(J) + lam / 2 * ufl.ln(J) ** 2
        dx1 = ufl.dx(metadata={"quadrature_degree": 1})   # exact: constant on a P1 tet
        dx2 = ufl.dx(metadata={"quadrature_degree": 2})   # exact for the P1 mass
        residual = (rho / h**2 * ufl.inner(u - self.q0 - h * v0, v) * dx2
                    + ufl.derivative(psi * dx1, u, v)
                    - rho * ufl.inner(g, v) * dx1)
        jacobian = ufl.derivative(residual, u, du)
        stop = setup_clock()
        self.problem = make_timed_problem(fem)(residual, u, [self.bc], J=jacobian,
                                               jit_params={"cffi_extra_compile_args": cflags})
        self.setup["FFCx JIT (cached after 1st run)"] = stop()

        # Rigid-body near-nullspace from the owned dof coordinates, as petsoft builds its own.
        nown = V.dofmap.index_map.size_local
        coords = self.q0.vector.copy()
        coords.setBlockSize(3)
        coords.getArray()[:] = V.tabulate_dof_coordinates()[:nown].ravel()
        self.modes = PETSc.NullSpace().createRigidBody(coords)
        coords.destroy()
        # ||R_0||, the residual at the predictor (for the Newton tolerance, see make_solver)
        self.u.x.array[:] = self.predictor
        r0 = fem.petsc.create_vector(self.problem.L)
        self.problem.form(self.u.vector)
        self.problem.F(self.u.vector, r0)
        self.r0_norm = r0.norm()
        r0.destroy()
        self.solver = None
        self.result = (0, False)

    def make_solver(self, name: str) -> None:
        stop = setup_clock()
        solver = self.dolfinx.nls.petsc.NewtonSolver(COMM, self.problem)
        # SNES's test ||R|| < max(atol, rtol ||R_0||) as an absolute tolerance: DOLFINx 0.5.2's
        # "relative" residual divides by ||dx_1||, the first Newton update, not by ||R_0||.
        solver.convergence_criterion = "residual"
        solver.rtol, solver.atol = 0.0, max(NEWTON_ATOL, NEWTON_RTOL * self.r0_norm)
        solver.max_it = NEWTON_MAXIT
        solver.error_on_nonconvergence = False
        solver.report = False
        solver.A.setNearNullSpace(self.modes)
        solver.A.setOption(PETSc.Mat.Option.SYMMETRIC, True)   # as petsoft's matrices
        ksp = solver.krylov_solver
        ksp.setOptionsPrefix("")                               # the same options as petsoft
        ksp.setType(PETSc.KSP.Type.CG)
        ksp.getPC().setType(PETSc.PC.Type.GAMG)
        ksp.setTolerances(rtol=KSP_RTOL, atol=KSP_ATOL, max_it=KSP_MAXIT)
        ksp.setFromOptions()
        self.problem.ksp = ksp
        self.solver = solver
        self.setup[f"{name}: NewtonSolver"] = stop()

    def step(self) -> None:
        self.u.x.array[:] = self.predictor
        self.problem.reset()
        self.result = self.solver.solve(self.u)

    def check_report(self) -> None:
        if not self.result[1]:
            raise RuntimeError(f"DOLFINx's Newton did not converge in {self.result[0]} "
                               "iterations")

    def its(self) -> tuple[int, int]:
        return self.result[0], self.problem.ksp_its

    def pc(self) -> PETSc.PC:
        return self.solver.krylov_solver.getPC()

    def solution(self, points: np.ndarray):
        """q1 gathered on rank 0 as an (N, 3) array in petsoft's vertex numbering."""
        vert = match_points(points, self.V.tabulate_dof_coordinates())
        nown = self.V.dofmap.index_map.size_local
        return gather_owned(vert[:nown], self.u.x.array[: 3 * nown].reshape(-1, 3), len(points))

    def drop_solver(self) -> None:
        self.problem.ksp = None
        self.solver = None
        gc.collect()

    def destroy(self) -> None:
        self.modes.destroy()


def make_timed_problem(fem):
    """NonlinearProblem whose residual/Jacobian callbacks are PETSc log events and which counts
    the KSP iterations of a solve (the NewtonSolver has no counter for them)."""
    ev_f = PETSc.Log.Event("bench:DOLFINx F")
    ev_j = PETSc.Log.Event("bench:DOLFINx J")

    class TimedProblem(fem.petsc.NonlinearProblem):
        ksp, calls, ksp_its = None, 0, 0

        def reset(self) -> None:
            self.calls, self.ksp_its = 0, 0

        def F(self, x, b):
            # every call after a solve's first follows a linear solve
            if self.calls and self.ksp is not None:
                self.ksp_its += self.ksp.getIterationNumber()
            self.calls += 1
            ev_f.begin()
            super().F(x, b)
            ev_f.end()

        def J(self, x, A):
            ev_j.begin()
            super().J(x, A)
            ev_j.end()
            # What SNES does before every linear solve (petsoft): without it the PC notices the
            # new matrix inside KSPSolve and its set-up is logged within KSPSolve. No extra work.
            if self.ksp is not None:
                self.ksp.setOperators(A, A)

    return TimedProblem


# PETSc 3.18 logs PCSetUp outside KSPSolve (KSPSolve_Private sets up before its event begins).
_LINEAR = {"PCSetUp": "PCSetUp", "(of it LU symbolic)": "MatLUFactorSym", "KSPSolve": "KSPSolve"}
PHASES = {
    "petsoft": {"residual": "SNESFunctionEval", "Jacobian": "SNESJacobianEval", **_LINEAR},
    "DOLFINx": {"residual": "bench:DOLFINx F", "Jacobian": "bench:DOLFINx J", **_LINEAR},
}


def staged(stage: PETSc.LogStage, fn):
    def run():
        stage.push()
        try:
            fn()
        finally:
            stage.pop()
    return run


def phases_text(stage, code: str, repeat: int, total: float) -> str:
    """Per-step mean times of the phases in a stage, with 'rest' = mean step - the others."""
    t = {k: _max(PETSc.Log.Event(ev).getPerfInfo(stage.id)["time"]) / repeat
         for k, ev in PHASES[code].items()}
    rest = total - t["residual"] - t["Jacobian"] - t["PCSetUp"] - t["KSPSolve"]
    parts = [f"{k} {v:.3f}" for k, v in t.items()] + [f"rest {rest:.3f}"]
    return ", ".join(parts)


MUMPS_ORDERINGS = {0: "AMD", 2: "AMF", 3: "SCOTCH", 4: "PORD", 5: "METIS", 6: "QAMD",
                   7: "auto"}


def mumps_text(pc: PETSc.PC) -> str:
    """The ordering MUMPS used and the size and cost of its last factorisation."""
    try:
        F = pc.getFactorMatrix()
        order = MUMPS_ORDERINGS.get(F.getMumpsInfog(7), str(F.getMumpsInfog(7)))
        par = {1: "sequential", 2: "parallel"}.get(F.getMumpsInfog(32), "?")
        entries = F.getMumpsInfog(29)              # effective entries in the factors
        entries = entries if entries >= 0 else -entries * 1e6
        return (f"; MUMPS: {par} {order} ordering, {entries:.3g} factor entries, "
                f"{F.getMumpsRinfog(3):.3g} flop per factorisation")
    except Exception as exc:  # an older petsc4py or another solver package
        return f"; MUMPS statistics unavailable ({type(exc).__name__})"


def check(pets: PetsoftCase, dolf: DolfinxCase, solver: str) -> None:
    """Print the relative difference of both codes' q1."""
    qp, q0 = pets.solution()
    qd = dolf.solution(pets.dmesh.mesh.points)
    if RANK != 0:
        return
    diff = float(np.linalg.norm(qp - qd))
    say(f"correctness ({solver}, {pets.dofs} dofs): ||q1_p - q1_d|| / ||q1_p - q0|| = "
        f"{diff / np.linalg.norm(qp - q0):.1e}, / ||q1_p|| = {diff / np.linalg.norm(qp):.1e}  "
        f"(Newton its {pets.its()[0]} vs {dolf.its()[0]})")


def run_solver(cases, solver: str, repeat: int, dofs: int):
    """Build every code's solver, one warm-up step each, then ``repeat`` interleaved timed
    steps (each code's in its own PETSc log stage); returns (times, stages)."""
    fns, stages = [], []
    for code, case in cases:
        case.make_solver(solver)
        t = case.setup[f"{solver}: warm-up step"] = wall(case.step)
        case.check_report()
        progress(f"{dofs} dofs, {solver}: {code} warm-up step {t:.2f} s")
        stage = PETSc.Log.Stage(f"{code} {solver} {dofs}")
        stages.append(stage)
        fns.append(staged(stage, case.step))

    def report(i: int, k: int, t: float) -> None:
        progress(f"{dofs} dofs, {solver}: {cases[k][0]} step {i + 1}/{repeat} {t:.2f} s")

    times = timed_interleaved(fns, repeat, report)
    for _, case in cases:
        case.check_report()
    return times, stages


# -- driver ---------------------------------------------------------------------------------------
def main() -> None:
    sizes = [1.5e3, 3e3] if ARGS.quick else ARGS.sizes
    repeat = 2 if ARGS.quick else max(1, ARGS.repeat)
    mods, why_not = (None, "--no-dolfinx") if ARGS.no_dolfinx else import_dolfinx()
    cflags = ARGS.dolfinx_cflags.split()

    say(f"backward-Euler step (full Newton), neo-Hookean bar {LENGTH} x {WIDTH} x {WIDTH} m, "
        f"E={E_MOD:g} nu={NU} rho={RHO:g}, gravity, h=1/60 s, initial bend curvature "
        f"{ARGS.bend:g}/m; "
        f"{NRANKS} MPI rank(s), PETSc {'.'.join(map(str, PETSc.Sys.getVersion()))}")
    say(f"Newton: rtol {NEWTON_RTOL:g} atol {NEWTON_ATOL:g}; gamg: CG+GAMG (rigid-body "
        f"near-nullspace) ksp rtol {KSP_RTOL:g}; mumps: preonly + LU (MUMPS)")
    if mods is None:
        say(f"DOLFINx: skipped ({why_not})")
    else:
        say(f"DOLFINx {mods[0].__version__}: same mesh (create_mesh from petsoft's points/tets), "
            f"NewtonSolver, JIT flags {' '.join(cflags)}")
    say(f"times: best of {repeat} steps per code (interleaved), max over ranks; set-up and a "
        "warm-up step excluded\n")

    rows, details = [], []
    for k, target in enumerate(sizes):
        cells = cells_for(target)
        pets = PetsoftCase(cells)
        dolf = DolfinxCase(mods, pets.dmesh.mesh, cflags) if mods is not None else None
        ntets = 6 * cells[0] * cells[1] * cells[2]
        progress(f"{pets.dofs} dofs ({ntets} tets): models built")
        details.append(f"{pets.dofs} dofs ({ntets} tets, cells {cells}):")
        for solver in ARGS.solvers:
            if solver == "mumps" and pets.dofs > ARGS.mumps_max_dofs:
                details.append(f"  mumps   skipped: {pets.dofs} dofs > --mumps-max-dofs "
                               f"{ARGS.mumps_max_dofs:g}")
                continue
            cases = [("petsoft", pets)] + ([("DOLFINx", dolf)] if dolf is not None else [])
            # petsoft builds a fresh SNES/KSP/PC every step: the options stay for the timing
            with solver_options(solver):
                times, stages = run_solver(cases, solver, repeat, pets.dofs)
                if k == 0 and dolf is not None:
                    check(pets, dolf, solver)
                its = []
                for (code, case), t, stage in zip(cases, times, stages, strict=True):
                    its.append(case.its())
                    n_it = max(1, case.its()[0])
                    details.append(
                        f"  {solver:5} {code:7} best {t.min():.4f} median {np.median(t):.4f} "
                        f"s/step, {t.min() / n_it:.4f} s/Newton it; per step: "
                        f"{phases_text(stage, code, repeat, t.mean())}"
                        + (mumps_text(case.pc()) if solver == "mumps" else ""))
                rows.append((pets.dofs, solver, times, its))
                for _, case in cases:
                    case.drop_solver()
        for code, case in (("petsoft", pets), ("DOLFINx", dolf)):
            if case is not None:
                setup = ", ".join(f"{k} {v:.2f}" for k, v in case.setup.items())
                details.append(f"  set-up {code} (s): {setup}")
        if dolf is not None:
            dolf.destroy()
        pets.destroy()
        del pets, dolf
        gc.collect()

    say(f"\n{'':17}{'petsoft':>25} {'DOLFINx':>25}")
    say(f"{'dofs':>8} {'ranks':>5} {'solver':>6} {'s/step':>10} {'Newton':>6} {'KSP':>6}  "
        f"{'s/step':>10} {'Newton':>6} {'KSP':>6}  {'DOLFINx/petsoft':>15}")
    for dofs, solver, times, its in rows:
        line = (f"{dofs:>8} {NRANKS:>5} {solver:>6} {times[0].min():>10.4f} {its[0][0]:>6} "
                f"{its[0][1]:>6}  ")
        if len(times) > 1:
            line += (f"{times[1].min():>10.4f} {its[1][0]:>6} {its[1][1]:>6}  "
                     f"{times[1].min() / times[0].min():>15.2f}")
        else:
            line += f"{'skipped':>10} {'-':>6} {'-':>6}  {'-':>15}"
        say(line)
    say("\ndetails (s; per-step phases are means over the timed steps, each the max over ranks: "
        "residual and Jacobian assembly (callbacks), PCSetUp = GAMG hierarchy or LU "
        "factorisation, KSPSolve = CG iterations or triangular solves, rest = step - the four):")
    for line in details:
        say(line)


if __name__ == "__main__":
    main()
