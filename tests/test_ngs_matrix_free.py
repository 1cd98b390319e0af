"""Nonlinear Gauss-Seidel / Jacobi (SNES ngs) and the matrix-free Jacobian for the BE step.

Checked on a clamped neo-Hookean bar under gravity (6x1x1 box, linear drag, Rayleigh damping)
and a cloth (6x6 nodes, bending springs, dashpots, a sphere collider it rests in):

1. The MatShell's product and diagonal equal the assembled Jacobian's (a M + b K(q) + c K0 +
   the velocity terms, prescribed rows identity) times a random vector to 1e-12 relative.
2. The backward-Euler step by nonlinear Gauss-Seidel, by nonlinear Jacobi and by Newton-CG on
   the MatShell equals the Newton + LU step to 1e-8 relative (all converged tightly).
3. On 2 ranks each of them equals the same solver on one rank (COMM_SELF) to 1e-10.
4. The colouring is proper (no element or spring joins two nodes of one colour); wrong option
   values are refused.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from petsc4py import PETSc

from petsoft.dynamics.implicit import ImplicitIntegrator
from petsoft.dynamics.mass_spring import MassSpringSystem, build_mass_spring_model, cloth_mesh
from petsoft.dynamics.matrix_free import StepOperator
from petsoft.dynamics.nonlinear_gs import greedy_colouring, node_graph
from petsoft.dynamics.system import DynamicSystem
from petsoft.experiment import experiment_from_dict
from petsoft.mesh.springs import write_spring_mesh
from petsoft.physics.model import build_model
from petsoft.solvers.options import clear_options

PREFIX = "ngsmf_"
STEP = {"bar": 0.002, "cloth": 0.01}
TIGHT = {"snes_rtol": "1e-13", "snes_atol": "1e-14"}
SOLVERS = {
    "newton-lu": {"ksp_type": "preonly", "pc_type": "lu", "snes_rtol": "1e-14",
                  "snes_atol": "1e-14"},
    "gauss-seidel": {"snes_type": "ngs", **TIGHT},
    "jacobi": {"snes_type": "ngs", "petsoft_ngs": "jacobi", **TIGHT},
    "shell-cg": {"petsoft_jacobian": "shell", "ksp_rtol": "1e-12", **TIGHT},
}


def bar(comm=None) -> DynamicSystem:
    exp = experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.05, 0.05], "cells": [6, 1, 1]}},
        "material": {"model": "neohookean", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "drag": {"linear": 5.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "time": {"end": 0.02, "step": STEP["bar"], "integrator": "be"},
    }, source="bar")
    return DynamicSystem(build_model(exp, comm), damping_mass=0.5, damping_stiffness=1e-3)


@pytest.fixture(scope="module", autouse=True)
def cloth_file(tmp_path_factory):
    """The cloth's mesh file (rank 0 writes it, every rank gets its path)."""
    mpi = PETSc.COMM_WORLD.tompi4py()
    path = tmp_path_factory.mktemp("cloth") / "cloth.vtu" if mpi.rank == 0 else None
    path = mpi.bcast(str(path) if path else None, root=0)
    if mpi.rank == 0:
        mesh = cloth_mesh(6, 6, 0.5, 0.5)
        write_spring_mesh(path, mesh.points, mesh.lines, mesh.triangles)
    mpi.barrier()
    CLOTH_FILE[:] = [path]
    return path


CLOTH_FILE: list[str] = []


def cloth(comm=None) -> MassSpringSystem:
    exp = experiment_from_dict({
        "mesh": {"file": CLOTH_FILE[0]},
        "springs": {"stiffness": 50.0, "node_mass": 0.005, "bending": 1.0, "damping": 0.01},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "boundary": [{"kind": "fixed", "where": "x < 1e-6 and y > 0.49"}],
        "collider": [{"kind": "sphere", "center": [0.25, 0.25, -0.3], "radius": 0.29}],
        "time": {"end": 0.1, "step": STEP["cloth"], "integrator": "be"},
    }, source="cloth")
    model = build_mass_spring_model(exp, comm)
    return MassSpringSystem(model, damping_mass=0.1)


SYSTEMS = {"bar": bar, "cloth": cloth}


def _field(system, fn) -> PETSc.Vec:
    """A global vector from a function of the (N, 3) reference points (file numbering)."""
    pts = system.dmesh.mesh.points
    return system.dmesh.from_file_field(fn(pts))


def _initial(system):
    q0 = _field(system, lambda X: 0.002 * np.sin(7 * X))
    v0 = _field(system, lambda X: np.column_stack([0 * X[:, 0], 0.3 * X[:, 0], 2.0 * X[:, 0]]))
    system.apply_prescribed(q0, 0.0)
    system.zero_prescribed(v0)
    return q0, v0


def be_step(system, solver: str):
    """(q1 in file numbering on every rank, report, sweeps) of one BE step from a fixed state."""
    opts = {PREFIX + k: v for k, v in SOLVERS[solver].items()}
    o = PETSc.Options()
    for k, v in opts.items():
        o.setValue(k, v)
    try:
        integ = ImplicitIntegrator(system, "be", prefix=PREFIX)
        q0, v0 = _initial(system)
        q1, v1 = system.create_vec(), system.create_vec()
        name = "bar" if isinstance(system, DynamicSystem) else "cloth"
        report = integ.step(0.0, q0, v0, STEP[name], q1, v1)
        sweeps = integ.ngs.sweeps if integ.ngs is not None else None
        integ.destroy()
    finally:
        clear_options(opts)
    full = system.dmesh.gather_global(q1, root=0)
    full = system.comm.tompi4py().bcast(full, root=0)
    return full, report, sweeps


@pytest.mark.parametrize("name", ["bar", "cloth"])
def test_shell_product_and_diagonal_equal_the_assembled_jacobian(name):
    s = SYSTEMS[name]()
    rng = np.random.default_rng(3 + s.comm.rank)
    q = s.create_vec()
    q.getArray()[:] = 0.002 * rng.standard_normal(q.getLocalSize())
    v = s.create_vec()
    v.getArray()[:] = rng.standard_normal(v.getLocalSize())
    s.damping_apply(v, s.create_vec())          # the velocity the drag is linearised at
    coef = (2500.0, 1.0, 0.3, 100.0)
    A = s.create_matrix()
    s.assemble_combination(q, *coef[:3], A, velocity=coef[3])
    op = StepOperator(s)
    op.update(q, *coef)
    S = op.create_mat()
    x = s.create_vec()
    x.getArray()[:] = rng.standard_normal(x.getLocalSize())
    y_assembled, y_shell = s.create_vec(), s.create_vec()
    A.mult(x, y_assembled)
    S.mult(x, y_shell)
    assert (y_shell - y_assembled).norm() <= 1e-12 * y_assembled.norm()
    d_shell = s.create_vec()
    S.getDiagonal(d_shell)
    d = A.getDiagonal()
    assert (d_shell - d).norm() <= 1e-12 * d.norm()
    # the bound the round-off test uses is one
    assert op.norm() >= A.norm(PETSc.NormType.INFINITY) * (1 - 1e-12)
    S.destroy()
    A.destroy()


@pytest.mark.parametrize("solver", ["gauss-seidel", "jacobi", "shell-cg"])
@pytest.mark.parametrize("name", ["bar", "cloth"])
def test_be_step_equals_the_newton_lu_step(name, solver):
    s = SYSTEMS[name]()
    ref, rep_ref, _ = be_step(s, "newton-lu")
    q, rep, sweeps = be_step(s, solver)
    assert rep_ref.converged and rep.converged, rep.reason
    dq = np.linalg.norm(q - ref) / np.linalg.norm(ref)
    assert dq < 1e-8, (name, solver, dq, rep.newton_iterations)
    if solver == "shell-cg":
        assert rep.linear_iterations > 0 and sweeps is None
    else:
        assert sweeps == rep.newton_iterations > 1    # one sweep per SNES iteration


@pytest.mark.parametrize("solver", ["gauss-seidel", "jacobi", "shell-cg"])
@pytest.mark.parametrize("name", ["bar", "cloth"])
def test_serial_equals_parallel(name, solver):
    """Under mpiexec -n 2: the distributed solve equals the same solver on one rank."""
    q, rep, _ = be_step(SYSTEMS[name](), solver)
    q_self, rep_self, _ = be_step(SYSTEMS[name](PETSc.COMM_SELF), solver)
    assert rep.converged and rep_self.converged
    assert np.linalg.norm(q - q_self) <= 1e-10 * np.linalg.norm(q_self)
    if solver != "shell-cg":        # the sweeps are the same on any number of ranks
        assert rep.newton_iterations == rep_self.newton_iterations


@pytest.mark.parametrize("name", ["bar", "cloth"])
def test_colouring_is_proper(name):
    n, src, dst = node_graph(SYSTEMS[name](PETSc.COMM_SELF))
    colour = greedy_colouring(n, src, dst)
    assert (colour >= 0).all()
    keep = src != dst
    assert (colour[src[keep]] != colour[dst[keep]]).all()
    # far fewer colours than nodes (a 6x6 cloth with bending springs: about 10)
    assert colour.max() + 1 <= 16


@pytest.mark.parametrize("key, value, message", [
    ("petsoft_ngs", "sor", "gs, jacobi"),
    ("petsoft_jacobian", "matfree", "assembled, shell"),
])
def test_wrong_option_values_are_refused(key, value, message):
    s = bar(PETSc.COMM_SELF)
    opts = {PREFIX + "snes_type": "ngs", PREFIX + key: value}
    o = PETSc.Options()
    for k, v in opts.items():
        o.setValue(k, v)
    try:
        with pytest.raises(ValueError, match=message):
            ImplicitIntegrator(s, "be", prefix=PREFIX)
    finally:
        clear_options(opts)


@pytest.mark.serial_only
def test_benchmark_script_quick():
    """``bench_be_solvers.py --quick`` exits 0 and every solver converges to the MUMPS step."""
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run(
        [sys.executable, str(root / "scripts" / "benchmarks" / "bench_be_solvers.py"), "--quick"],
        cwd=root, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for solver in ("ngs-gs", "ngs-jacobi", "shell-cg", "newton-mumps", "newton-gamg"):
        assert proc.stdout.count(solver) >= 4, proc.stdout      # 2 tables, 2 winner lines
    assert "False" not in proc.stdout, proc.stdout                # all converged
