"""A constant Jacobian is factored once per run (petsoft.dynamics.implicit.SolverReuse).

A linear material without contact, quadratic drag or dry friction has a step matrix that
depends on the step and the parameters only; the integrators then keep their SNES (and its
factorisation) from step to step, and ``assemble_combination(..., reuse=True)`` leaves the
matrix untouched. Checked here:

1. The trajectory with reuse equals the one with a fresh solver every step (reuse switched off
   by declaring the Jacobian non-constant) to round-off, for be, si, midpoint and alpha.
2. The SNES is kept within a run for a linear bar, and for a corotated one under a
   preconditioner whose set-up depends on the matrix alone (the direct default), where the
   trajectory is bitwise the one with a new SNES per step; renewed every step under GAMG.
3. Changed parameters between runs of one forward model are seen: a second run at another E
   equals a fresh forward model's run at that E, and so do its sensitivities (a stale matrix
   would still give the trajectory -- Newton converges on the residual -- but not them).
"""

from __future__ import annotations

import numpy as np
import pytest

from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.dynamics.system import DynamicSystem
from petsoft.experiment import experiment_from_dict, with_parameters

MARKERS = np.array([[0.3, 0.04, 0.04], [0.15, 0.0, 0.02]])
FRAMES = np.array([0.004, 0.01, 0.02])


def _experiment(method: str, model: str = "linear", cells=(6, 1, 1)):
    return experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": list(cells)}},
        "material": {"model": model, "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "damping": {"mass": 0.5, "stiffness": 1e-3},
        "drag": {"linear": 5.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"velocity": ["0", "0", "2*x"]},
        "time": {"end": 0.02, "step": 0.002, "integrator": method},
    }, source="test_solver_reuse")


def _forward(exp, names=("material.youngs_modulus",)):
    return ForwardModel(exp, list(names), lambda s: MarkerObserver(s, MARKERS), FRAMES)


@pytest.mark.parametrize("method", ["be", "si", "alpha"])
def test_reused_factorisation_gives_the_same_trajectory(method, monkeypatch):
    fm = _forward(_experiment(method))
    try:
        assert fm.system.jacobian_is_constant
        kept = fm.simulate(fm.p0)
        monkeypatch.setattr(DynamicSystem, "jacobian_is_constant", property(lambda self: False))
        fresh = fm.simulate(fm.p0)
    finally:
        fm.destroy()
    scale = np.abs(kept - MARKERS[None]).max()
    assert np.abs(kept - fresh).max() <= 1e-10 * scale, np.abs(kept - fresh).max()


@pytest.mark.parametrize("model, pc", [("linear", None), ("corotated", None),
                                       ("corotated", "gamg"), ("linear", "gamg"),
                                       ("corotated", "jacobi")])
def test_snes_is_kept_unless_a_changing_matrix_meets_multigrid(model, pc):
    """Kept within a run: for a constant Jacobian (whatever the solver), and for a changing
    one under a preconditioner whose set-up depends on the matrix alone (the default direct
    solve: LU on one rank, a redundant LU on several; Jacobi); renewed every step for a
    changing matrix under GAMG (random set-up)."""
    from petsc4py import PETSc

    default = PETSc.PC.Type.LU if PETSc.COMM_WORLD.getSize() == 1 else PETSc.PC.Type.REDUNDANT
    kept = model == "linear" or (pc or default) != PETSc.PC.Type.GAMG

    from petsoft.dynamics.alpha import GeneralizedAlpha
    from petsoft.physics.model import build_model
    from petsoft.solvers.options import scoped_defaults

    exp = _experiment("alpha", model)
    system = DynamicSystem(build_model(exp), exp.damping.mass, exp.damping.stiffness)
    assert system.jacobian_is_constant == (model == "linear")
    with scoped_defaults(**({"reuse_pc_type": pc} if pc else {})):
        integrator = GeneralizedAlpha(system, radius=0.9, prefix="reuse_")
        q, v = system.create_vec(), system.create_vec()
        q.zeroEntries()
        v.zeroEntries()
        q1, v1 = q.duplicate(), v.duplicate()
        solvers = []     # the petsc4py objects themselves: a freed handle's address is reused
        for n in range(3):
            report = integrator.step(n * 0.002, q, v, 0.002, q1, v1)
            assert report.converged
            solvers.append(integrator.snes)
            q1.copy(q)
            v1.copy(v)
    assert integrator.snes.getKSP().getPC().getType() == (pc or default)
    # the first step of a run sets a solver up
    assert (solvers[1] is solvers[2]) == kept


@pytest.mark.parametrize("method", ["be", "alpha"])
def test_a_kept_solver_computes_what_a_new_one_would(method, monkeypatch):
    """A corotated bar (the matrix changes every Newton iteration) with the default direct
    solve: the trajectory with the SNES kept equals, bit for bit, the one with a new SNES every
    step (what a run restarted from a checkpoint does at its first step)."""
    import petsoft.dynamics.implicit as implicit

    fm = _forward(_experiment(method, "corotated"))
    fm.keeps_factors = False      # every step factors (else a kept SNES lends its factors on)
    try:
        kept = fm.simulate(fm.p0)
        monkeypatch.setattr(implicit, "repeatable_setup", lambda ksp: False)
        fresh = fm.simulate(fm.p0)
    finally:
        fm.destroy()
    np.testing.assert_array_equal(kept, fresh)


@pytest.mark.parametrize("method", ["be", "alpha"])
def test_parameters_changed_between_runs_are_seen(method):
    E2 = 1.3e5
    fm = _forward(_experiment(method))
    fresh = _forward(with_parameters(_experiment(method), {"material.youngs_modulus": E2}))
    try:
        # both matrices (the integrator's and the sensitivities') filled at the first E
        first, _ = fm.jacobian(fm.p0)
        sim, jac = fm.jacobian(np.array([E2]))
        ref_sim, ref_jac = fresh.jacobian(np.array([E2]))
    finally:
        fm.destroy()
        fresh.destroy()
    scale = np.abs(ref_sim - MARKERS[None]).max()
    assert np.abs(first - ref_sim).max() > 1e-3 * scale      # E matters at this size
    assert np.abs(sim - ref_sim).max() <= 1e-10 * scale
    assert np.abs(jac - ref_jac).max() <= 1e-8 * np.abs(ref_jac).max()


def _multigrid_run(method: str, keep: bool, steps: int = 6, **options):
    """``steps`` steps of a corotated bar (24 x 3 x 3 cells: a hierarchy of several levels)
    under CG + GAMG; returns (the SNES of each step, the final state on rank 0's view)."""
    from petsoft.dynamics.alpha import GeneralizedAlpha
    from petsoft.dynamics.implicit import ImplicitIntegrator
    from petsoft.physics.model import build_model
    from petsoft.solvers.options import scoped_defaults

    exp = _experiment(method, "corotated", cells=(24, 3, 3))
    system = DynamicSystem(build_model(exp), exp.damping.mass, exp.damping.stiffness)
    settings = {"mg_ksp_type": "cg", "mg_pc_type": "gamg",
                **{"mg_" + k: v for k, v in options.items()}}
    with scoped_defaults(**settings):
        if method == "alpha":
            integrator = GeneralizedAlpha(system, radius=0.9, prefix="mg_")
        else:
            integrator = ImplicitIntegrator(system, method, prefix="mg_")
        integrator.keep_factors(keep)
        q, v = system.create_vec(), system.create_vec()
        q.zeroEntries()
        v.zeroEntries()
        q1, v1 = q.duplicate(), v.duplicate()
        solvers = []
        for n in range(steps):
            report = integrator.step(n * 0.002, q, v, 0.002, q1, v1)
            assert report.converged
            solvers.append(integrator.snes)
            q1.copy(q)
            v1.copy(v)
        assert integrator.snes.getKSP().getPC().getType() == "gamg"
    final = system.model.dmesh.gather_global(q)
    return solvers, final


@pytest.mark.parametrize("method", ["be", "alpha"])
def test_a_run_that_keeps_factors_keeps_its_multigrid_until_renewed(method):
    """With keep_factors (petsoft simulate, ForwardModel.simulate) a GAMG solver is kept from
    step to step (its set-up on each new matrix keeps the interpolation); without, a new one
    every step. Both trajectories meet the same Newton tolerance: they agree to ~1e-9."""
    kept, q_kept = _multigrid_run(method, True)
    fresh, q_fresh = _multigrid_run(method, False)
    assert all(s is kept[0] for s in kept)
    assert len({id(s) for s in fresh}) == len(fresh)
    if q_kept is not None:
        scale = np.abs(q_fresh).max()
        assert 0 < np.abs(q_kept - q_fresh).max() <= 1e-8 * scale


def test_a_stale_or_unreused_hierarchy_is_set_up_anew(monkeypatch):
    """The kept hierarchy is renewed at the step after one whose linear iterations exceed
    twice the first kept step's plus MULTIGRID_SLACK (here made negative: every step), and
    never kept when the options ask GAMG not to reuse its interpolation (its set-up would
    then draw new random numbers: a restart could not repeat it)."""
    import petsoft.dynamics.implicit as implicit

    unreused, _ = _multigrid_run("be", True, steps=4, pc_gamg_reuse_interpolation="false")
    assert len({id(s) for s in unreused}) == 4
    monkeypatch.setattr(implicit, "MULTIGRID_SLACK", -1000)
    stale, _ = _multigrid_run("be", True, steps=5)
    # step 1 keeps the first solver (measuring its first step's iterations), step 2 finds
    # them exceeded and sets up anew, step 3 keeps that one, step 4 renews again
    assert stale[0] is stale[1] and stale[2] is stale[3]
    assert stale[1] is not stale[2] and stale[3] is not stale[4]
