"""Newton's chord on the forward sensitivities' factors (petsoft.solvers.borrowed_chord).

In a forward-sensitivity run of backward Euler or generalized-alpha each step's Newton chord
iterates on the factorisation the previous step's tangent solves made (the exact step Jacobian
at its end), instead of assembling and factoring its own at the predictor:

1. one factorisation a step instead of two (PETSc's event counts), and the same answer: the
   run's trajectory equals ``simulate``'s to the Newton tolerance, its sensitivities equal
   central differences of ``simulate``; si (one Newton step is its method) borrows nothing:
   its run equals ``simulate``'s bit for bit;
2. lent factors the chord cannot converge on (those of a matrix 1000x too small) leave the step
   to the stepper's own solver: the step ends where a step that borrowed nothing ends.
3. with the tangent solves on factors kept across steps (``ForwardModel.lags_factors``, the
   default; petsoft.solvers.lagged_factors) the chord borrows the kept factors: far fewer
   factorisations than steps, few GMRES iterations a tangent solve, the same trajectory to the
   Newton tolerance and the same sensitivities to 1e-8; a chord that fails on the kept factors
   has them renewed at once (else the next steps' chords fail on them too).
"""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.dynamics.alpha import GeneralizedAlpha
from petsoft.dynamics.implicit import ImplicitIntegrator
from petsoft.dynamics.system import DynamicSystem
from petsoft.experiment import experiment_from_dict
from petsoft.physics.model import build_model

MARKERS = np.array([[0.3, 0.04, 0.04], [0.3, 0.0, 0.0], [0.15, 0.02, 0.04]])
NAMES = ["material.youngs_modulus", "damping.mass"]
STEPS = 12
H = 2e-3


def _bar():
    return experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [6, 2, 2]}},
        "material": {"model": "neohookean", "youngs_modulus": 2e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "damping": {"mass": 0.5},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"velocity": ["0", "2*x", "6*x*x"]},
        "time": {"end": STEPS * H, "step": H, "integrator": "alpha"},
    })


def _factorisations() -> int:
    return sum(PETSc.Log.Event(name).getPerfInfo()["count"]
               for name in ("MatLUFactorNum", "MatCholFctrNum"))


@pytest.mark.parametrize("method", ["be", "alpha"])
def test_one_factorisation_a_step_and_the_same_answer(method):
    PETSc.Log.begin()
    fm = ForwardModel(_bar(), NAMES, lambda s: MarkerObserver(s, MARKERS),
                      np.arange(1, STEPS + 1) * H, integrator=method)
    fm.lags_factors = False     # every step factors for its tangent solves (kept: below)
    p = fm.p0.copy()
    sim0 = fm.simulate(p)
    before = _factorisations()
    sim, dsim = fm.jacobian(p)
    count = _factorisations() - before
    print(f"{method}: factorisations in a {STEPS}-step sensitivity run: {count}")
    # the tangent solves' one a step, the first step's own chord, the initial mass solve
    assert count <= STEPS + 2, count
    scale = np.abs(sim0).max()
    assert np.abs(sim - sim0).max() <= 1e-12 * scale
    for j in range(len(NAMES)):
        step = 1e-4 * p[j]
        plus, minus = p.copy(), p.copy()
        plus[j] += step
        minus[j] -= step
        central = (fm.simulate(plus) - fm.simulate(minus)) / (2 * step)
        err = np.abs(dsim[..., j] - central).max() / np.abs(central).max()
        print(f"{NAMES[j]}: sensitivities vs central differences {err:.1e}")
        assert err < 1e-6
    fm.destroy()


def test_si_borrows_nothing():
    fm = ForwardModel(_bar(), NAMES, lambda s: MarkerObserver(s, MARKERS),
                      np.arange(1, STEPS + 1) * H, integrator="si")
    sim0 = fm.simulate(fm.p0)
    sim, _ = fm.jacobian(fm.p0)
    assert np.array_equal(sim, sim0)
    fm.destroy()


@pytest.mark.parametrize("stepper", [lambda s: GeneralizedAlpha(s, 0.5),
                                     lambda s: ImplicitIntegrator(s, "be")],
                         ids=["alpha", "be"])
def test_factors_the_chord_cannot_use_leave_the_step_to_the_own_solver(stepper):
    exp = _bar()
    model = build_model(exp)
    s = DynamicSystem(model, exp.damping.mass, exp.damping.stiffness)
    q0, v0 = s.initial_state()
    ends = []
    for lend in (False, True):
        integ = stepper(s)
        q1, v1 = q0.duplicate(), v0.duplicate()
        assert integ.step(0.0, q0, v0, H, q1, v1).converged     # J is the step's Jacobian now
        wrong = integ.J.copy()
        wrong.scale(1e-3)
        ksp = PETSc.KSP().create(comm=s.comm)
        ksp.setOperators(wrong)
        ksp.setType(PETSc.KSP.Type.PREONLY)
        ksp.getPC().setType(PETSc.PC.Type.LU)
        ksp.setUp()
        if lend:
            integ.borrow_chord(ksp)
        q2, v2 = q0.duplicate(), v0.duplicate()
        report = integ.step(H, q1, v1, H, q2, v2)
        assert report.converged, report.reason
        if lend:    # the borrowed chord was tried, and failed
            assert integ._chord.snes.getConvergedReason() < 0
        assert integ.borrowed_failed == lend
        ends.append(q2.getArray().copy())
        for obj in (ksp, wrong, q1, v1, q2, v2):
            obj.destroy()
        integ.destroy()
    # explicitly, on every rank at the same point: left to Python's cyclic collector, the
    # system's parallel objects were freed on one rank only before exit, and the two ranks
    # hung in PetscFinalize's garbage clean-up (after a later test's forward run)
    for obj in (q0, v0, s):
        obj.destroy()
    assert np.abs(ends[1] - ends[0]).max() <= 1e-13 * np.abs(ends[0]).max()


@pytest.mark.parametrize("method", ["be", "alpha"])
def test_a_forward_run_keeps_its_factors_across_steps(method):
    """``ForwardModel.simulate`` iterates each step's chord on an earlier step's factors until a
    step needs LAG_SLACK more iterations: far fewer factorisations than steps, the trajectory
    of a run that factors every step (the sensitivity run's) to the Newton tolerance, and
    the same numbers every time (the refactoring follows iteration counts, not clocks)."""
    steps = 40
    PETSc.Log.begin()
    fm = ForwardModel(_bar(), NAMES, lambda s: MarkerObserver(s, MARKERS),
                      np.arange(1, steps + 1) * H, integrator=method)
    fm.lags_factors = False
    p = fm.p0.copy()
    every_step, _ = fm.jacobian(p)
    before = _factorisations()
    sim = fm.simulate(p)
    count = _factorisations() - before
    print(f"{method}: factorisations in a {steps}-step forward run: {count}")
    assert 1 <= count <= steps // 3, count
    assert np.abs(sim - every_step).max() <= 1e-12 * np.abs(every_step).max()
    assert np.array_equal(fm.simulate(p), sim)
    fm.destroy()


@pytest.mark.parametrize("method", ["be", "alpha"])
def test_a_sensitivity_run_keeps_its_factors_across_steps(method):
    """``ForwardModel.jacobian`` with its tangent solves on kept factors (the default) against
    the same run factoring every step: at most half the factorisations (on this bar ~1 in 4
    steps), GMRES averaging no more iterations a solve than the refactoring threshold, the
    trajectory to the Newton tolerance and the sensitivities to 1e-8."""
    from petsoft.solvers.lagged_factors import REFACTOR_ITERATIONS

    steps = 40
    PETSc.Log.begin()
    fm = ForwardModel(_bar(), NAMES, lambda s: MarkerObserver(s, MARKERS),
                      np.arange(1, steps + 1) * H, integrator=method)
    p = fm.p0.copy()
    count, sim, dsim = {}, {}, {}
    for lag in (False, True):
        fm.lags_factors = lag
        before = _factorisations()
        sim[lag], dsim[lag] = fm.jacobian(p)
        count[lag] = _factorisations() - before
    stats = fm.stats["tangent_solves"]
    if PETSc.COMM_WORLD.getRank() == 0:
        print(f"{method}: factorisations in a {steps}-step sensitivity run {count[False]} -> "
              f"{count[True]}; tangent solves {stats}")
    assert count[False] >= steps            # one a step for the tangent solves
    assert 1 <= count[True] <= count[False] // 2, count
    assert stats["solves"] == steps * len(NAMES)
    assert stats["iterations"] <= REFACTOR_ITERATIONS * stats["solves"], stats
    assert np.abs(sim[True] - sim[False]).max() <= 1e-12 * np.abs(sim[False]).max()
    rel = np.abs(dsim[True] - dsim[False]).max() / np.abs(dsim[False]).max()
    assert rel <= 1e-8, rel
    fm.destroy()


def test_a_chord_failing_on_kept_factors_renews_them(monkeypatch):
    """With the refactoring thresholds out of reach (``REFACTOR_ITERATIONS = MAX_IT``, no
    amortisation: ``FACTOR_IN_ITERATIONS`` huge) the kept
    factors age until a borrowed chord fails on them (backward Euler on this bar: chord
    iterations 5 -> 25 over 36 steps, then a failure); that step renews them, so the failure
    does not repeat at every later step (it did, 4 times in a row, before the renewal): one
    factorisation at the start and one per failed chord. The answer is unchanged."""
    import petsoft.solvers.lagged_factors as lf

    steps = 40
    fm = ForwardModel(_bar(), NAMES, lambda s: MarkerObserver(s, MARKERS),
                      np.arange(1, steps + 1) * H, integrator="be")
    p = fm.p0.copy()
    fm.lags_factors = False
    sim0, dsim0 = fm.jacobian(p)
    fm.lags_factors = True
    monkeypatch.setattr(lf, "REFACTOR_ITERATIONS", lf.MAX_IT)
    monkeypatch.setattr(lf, "FACTOR_IN_ITERATIONS", 10 ** 9)
    sim, dsim = fm.jacobian(p)
    stats = fm.stats["tangent_solves"]
    if PETSc.COMM_WORLD.getRank() == 0:
        print(f"factors kept until a chord fails: {stats}")
    assert stats["failed_chords"] >= 1, stats
    assert stats["factorisations"] == 1 + stats["failed_chords"], stats
    assert np.abs(sim - sim0).max() <= 1e-12 * np.abs(sim0).max()
    assert np.abs(dsim - dsim0).max() <= 1e-8 * np.abs(dsim0).max()
    fm.destroy()
