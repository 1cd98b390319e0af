"""Each solver-owning object reads its options under its own prefix (petsoft.solvers.options).

For every object that owns a KSP/SNES/TS/TAO/EPS, the solver types read back after set-up (and
after it solved) are the experiment's ``[petsc]`` table's under that object's prefix, a
command-line option with the prefix wins over the table, and an object with another prefix --
built while the first one's options are in the database -- sees none of them. The experiment's
options are never left in PETSc's options database. (Under the old global scope, which put the
``[petsc]`` table's keys unprefixed into the database for the whole command, the checks marked
"leak" failed: an object without a prefix built inside the scope took ``ksp_type``.)
"""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

from petsoft.calibration.forward import ForwardModel, forward_defaults, forward_options
from petsoft.calibration.observation import MarkerObserver
from petsoft.calibration.optimize import LeastSquares, minimize
from petsoft.dynamics.alpha import AlphaTSIntegrator, GeneralizedAlpha
from petsoft.dynamics.implicit import ImplicitIntegrator
from petsoft.dynamics.system import DynamicSystem
from petsoft.experiment import experiment_from_dict
from petsoft.physics.model import build_model
from petsoft.solvers.modes import compute_modes
from petsoft.solvers.options import SolverOptions, clear_options
from petsoft.solvers.static import StaticSolver

BAR = {
    "mesh": {"box": {"size": [0.2, 0.04, 0.04], "cells": [4, 1, 1]}},
    "material": {"model": "linear", "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                 "density": 1000.0},
    "gravity": {"acceleration": [0.0, 0.0, -9.81]},
    "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
    "initial": {"velocity": ["0", "0", "x"]},
    "time": {"end": 0.004, "step": 0.002, "integrator": "be"},
}
MARKERS = np.array([[0.2, 0.04, 0.04]])
FRAMES = np.array([0.002, 0.004])


def _types(ksp: PETSc.KSP) -> tuple[str, str]:
    return ksp.getType(), ksp.getPC().getType()


def _clean(*keys: str) -> None:
    """Nothing an object pushed is left in the options database."""
    opts = PETSc.Options()
    left = [k for k in keys if opts.hasName(k)]
    assert not left, f"left in the options database: {left}"


@pytest.fixture
def command_line():
    """Options as the command line sets them (removed after the test)."""
    placed = []

    def put(**options):
        for k, v in options.items():
            PETSc.Options().setValue(k, v)
            placed.append(k)
    yield put
    clear_options(placed)


@pytest.fixture
def system():
    exp = experiment_from_dict(BAR, source="test_solver_options")
    s = DynamicSystem(build_model(exp), 0.0, 0.0)
    yield s
    s.destroy()


def _step(integrator, system) -> None:
    q0, v0 = system.create_vec(), system.create_vec()
    q0.zeroEntries()
    v0.set(0.1)
    system.apply_prescribed(q0, 0.0)
    q1, v1 = q0.duplicate(), v0.duplicate()
    report = integrator.step(0.0, q0, v0, 2e-3, q1, v1)
    assert report.converged, report.reason
    for x in (q0, v0, q1, v1):
        x.destroy()


TABLE = {"ksp_type": "gmres", "pc_type": "jacobi", "ksp_rtol": "1e-12"}


@pytest.mark.parametrize("kind", ["be", "si", "alpha", "alpha-ts"])
def test_integrators_take_the_table_and_the_command_line(kind, system, command_line):
    def build(options=None):
        if kind == "alpha":
            return GeneralizedAlpha(system, 0.5, options=options)
        if kind == "alpha-ts":
            return AlphaTSIntegrator(system, 0.5, options=options)
        return ImplicitIntegrator(system, kind, options=options)

    plain = build()
    default = _types(plain.ksp)
    plain.destroy()
    assert default != ("gmres", "jacobi")
    integrator = build(SolverOptions("", TABLE))
    try:
        assert _types(integrator.ksp) == ("gmres", "jacobi")
        _clean(*TABLE)
        _step(integrator, system)           # (a step may set a new solver up)
        assert _types(integrator.ksp) == ("gmres", "jacobi")
        _clean(*TABLE)
    finally:
        integrator.destroy()
    # a half-chosen solver keeps the iterative default for the other half (linear_defaults
    # sees the table)
    integrator = build(SolverOptions("", {"ksp_type": "gmres"}))
    try:
        assert _types(integrator.ksp) == ("gmres", "gamg")
    finally:
        integrator.destroy()
    command_line(pc_type="sor")
    integrator = build(SolverOptions("", TABLE))
    try:
        _step(integrator, system)
        assert _types(integrator.ksp) == ("gmres", "sor")
    finally:
        integrator.destroy()


def test_static_solver_and_its_lifting_solve(command_line):
    model = build_model(experiment_from_dict(BAR))
    table = {"ksp_type": "gmres", "pc_type": "jacobi", "lift_ksp_type": "cg",
             "lift_pc_type": "sor"}
    solver = StaticSolver(model, options=SolverOptions("", table))
    try:
        assert _types(solver.ksp) == ("gmres", "jacobi")
        assert _types(solver.lift_ksp) == ("cg", "sor")
        solver.solve()
        assert _types(solver.ksp) == ("gmres", "jacobi")
    finally:
        solver.destroy()
    _clean(*table)
    solver = StaticSolver(model, options=SolverOptions("", {"pc_type": "jacobi"}))
    try:
        assert _types(solver.ksp) == ("cg", "jacobi")      # the iterative default's CG
    finally:
        solver.destroy()
    command_line(lift_pc_type="jacobi")
    solver = StaticSolver(model, options=SolverOptions("", table))
    try:
        assert _types(solver.ksp) == ("gmres", "jacobi")
        assert _types(solver.lift_ksp) == ("cg", "jacobi")
    finally:
        solver.destroy()


def _forward(table):
    exp = experiment_from_dict({**BAR, "petsc": table}, source="test_solver_options")
    return ForwardModel(exp, ["material.youngs_modulus"], lambda s: MarkerObserver(s, MARKERS),
                        FRAMES, solver_options=exp.petsc)


def test_forward_model_steps_and_gradient_solves_have_their_own_prefixes(command_line):
    """``[petsc] ksp_type`` reaches fm_ and fm_grad_; ``fm_grad_pc_type`` only the gradient
    solves; ``-fm_ksp_type`` on the command line only the steps."""
    fm = _forward({"ksp_type": "gmres", "pc_type": "jacobi", "fm_grad_pc_type": "sor"})
    try:
        assert _types(fm.integrator.ksp) == ("gmres", "jacobi")
        grad = fm._solver()
        assert _types(grad) == ("gmres", "sor")
        grad.destroy()
        fm.simulate(fm.p0)
        assert _types(fm.integrator.ksp) == ("gmres", "jacobi")
    finally:
        fm.destroy()
    _clean("ksp_type", "pc_type", "fm_ksp_type", "fm_pc_type", "fm_grad_ksp_type",
           "fm_grad_pc_type", "fm_snes_rtol")
    command_line(fm_ksp_type="bcgs")
    fm = _forward({"ksp_type": "gmres", "pc_type": "jacobi"})
    try:
        fm.simulate(fm.p0)
        assert _types(fm.integrator.ksp) == ("bcgs", "jacobi")
        grad = fm._solver()
        assert _types(grad) == ("gmres", "jacobi")
        grad.destroy()
    finally:
        fm.destroy()


def test_objects_with_other_prefixes_do_not_see_the_options(system):
    """leak: an object without a prefix (and one with fm_grad_) built while the forward run's
    options are pushed keeps its own defaults."""
    default = ImplicitIntegrator(system, "be")
    expected = _types(default.ksp)
    default.destroy()
    options = forward_options({"ksp_type": "gmres", "pc_type": "jacobi"})
    with options.pushed():
        assert PETSc.Options().getString("fm_ksp_type") == "gmres"
        assert not PETSc.Options().hasName("ksp_type")
        other = ImplicitIntegrator(system, "be")
        grad = ImplicitIntegrator(system, "be", prefix="fm_grad_")
        mine = ImplicitIntegrator(system, "be", options=options)
    try:
        assert _types(other.ksp) == expected
        assert _types(grad.ksp) == expected
        assert _types(mine.ksp) == ("gmres", "jacobi")
    finally:
        for x in (other, grad, mine):
            x.destroy()
    _clean("fm_ksp_type", "fm_pc_type", "fm_snes_rtol")


def test_a_callers_forward_default_is_below_the_table_and_the_command_line(command_line):
    assert forward_options().defaults["snes_rtol"] == "1e-12"
    with forward_defaults(snes_rtol="1e-06"):
        assert forward_options().defaults["snes_rtol"] == "1e-06"
        table = forward_options({"fm_snes_rtol": "1e-8"})
        with table.pushed():
            assert PETSc.Options().getReal("fm_snes_rtol") == 1e-8
        command_line(fm_snes_rtol="1e-9")
        with forward_options().pushed():
            assert PETSc.Options().getReal("fm_snes_rtol") == 1e-9
    assert forward_options().defaults["snes_rtol"] == "1e-12"


def test_modes_eigensolver(command_line):
    model = build_model(experiment_from_dict(BAR))
    table = {"eps_type": "arnoldi", "ksp_type": "gmres"}
    result = compute_modes(model, 2, options=SolverOptions("", table))
    try:
        assert result.solver["eps_type"] == "arnoldi"
    finally:
        result.destroy()
    _clean(*table)
    command_line(eps_type="krylovschur")
    result = compute_modes(model, 2, options=SolverOptions("", table))
    try:
        assert result.solver["eps_type"] == "krylovschur"
    finally:
        result.destroy()


def test_optimizer_takes_cal_keys_only(command_line):
    """The optimizer's TAO under cal_: ``cal_tao_type`` reaches it, ``tao_type`` (no prefix)
    does not; ``-cal_tao_type`` on the command line wins over the table."""
    problem = LeastSquares(lambda p: np.array([p[0] - 1.0, 2.0 * (p[1] + 0.5)]), 2,
                           jacobian=lambda p: np.diag([1.0, 2.0]))
    z0 = np.zeros(2)
    plain = minimize(problem, z0, method="lbfgs",
                     solver_options=SolverOptions("cal_", {"tao_type": "nm"}))
    assert plain.tao_type == "blmvm"
    chosen = minimize(problem, z0, method="lbfgs",
                      solver_options=SolverOptions("cal_", {"cal_tao_type": "bncg"}))
    assert chosen.tao_type == "bncg"
    np.testing.assert_allclose(chosen.z, [1.0, -0.5], atol=1e-6)
    _clean("cal_tao_type", "tao_type")
    command_line(cal_tao_type="bqnls")
    user = minimize(problem, z0, method="lbfgs",
                    solver_options=SolverOptions("cal_", {"cal_tao_type": "bncg"}))
    assert user.tao_type == "bqnls"


def test_ere_mass_solve_takes_its_own_keys_only(system, command_line):
    """ERE's consistent-mass KSP (prefix ere_mass_) takes ``ere_mass_ksp_type``, not the
    table's unprefixed ``ksp_type`` (which is simulate's own solver's)."""
    from petsoft.dynamics.ere import EREIntegrator

    table = {"ksp_type": "bcgs", "ere_mass_ksp_type": "gmres"}
    ere = EREIntegrator(system, mass="consistent", options=SolverOptions("ere_", table))
    try:
        assert _types(ere.ksp) == ("gmres", "jacobi")
    finally:
        ere.destroy()
    _clean(*table)
    command_line(ere_mass_pc_type="none")
    ere = EREIntegrator(system, mass="consistent", options=SolverOptions("ere_", table))
    try:
        assert _types(ere.ksp) == ("gmres", "none")
    finally:
        ere.destroy()


def test_imex_fast_step(system):
    from petsoft.dynamics.imex import ModalImexIntegrator

    imex = ModalImexIntegrator(system, slow_modes=2, options=SolverOptions("", TABLE))
    try:
        assert _types(imex.fast.ksp) == ("gmres", "jacobi")
    finally:
        imex.destroy()
    _clean(*TABLE)


def test_rest_shape_solver(command_line):
    from petsoft.solvers.rest_shape import RestShapeSolver

    model = build_model(experiment_from_dict(BAR))
    table = {"ksp_type": "cg", "rest_shape_ksp_type": "bcgs", "rest_shape_pc_type": "jacobi"}
    solver = RestShapeSolver(model, options=SolverOptions("rest_shape_", table))
    try:
        assert _types(solver.snes.getKSP()) == ("bcgs", "jacobi")
    finally:
        solver.destroy()
    _clean(*table)
    command_line(rest_shape_ksp_type="gmres")
    solver = RestShapeSolver(model, options=SolverOptions("rest_shape_", table))
    try:
        assert _types(solver.snes.getKSP()) == ("gmres", "jacobi")
    finally:
        solver.destroy()


def test_options_read_at_the_solve_reach_it(system, capfd):
    """``ksp_converged_reason`` is read when a solve ends (and ``mat_mumps_icntl_*``,
    ``mg_levels_*`` when it sets the preconditioner up), after ``setFromOptions()``: the table
    is pushed around the step too."""
    integrator = ImplicitIntegrator(system, "be",
                                    options=SolverOptions("", {"ksp_converged_reason": ""}))
    try:
        capfd.readouterr()
        _step(integrator, system)
        out = capfd.readouterr().out
    finally:
        integrator.destroy()
    if system.comm.rank == 0:
        assert "solve converged due to" in out
    _clean("ksp_converged_reason")
