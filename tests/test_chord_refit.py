"""A halved step's refit by forward runs on the current model's sensitivities (issue 40, item 3).

:func:`petsoft.diagnosis.chord_refit.chord_refit` replaces the calibration of the step/2
refinement in the numerics check: Gauss-Newton whose Jacobian is the current model's
sensitivities, one forward run (no sensitivity run) an iteration. Checked against the real
calibration of the same refined model: the tapered cantilever (tests/_taper.py) recorded at
1 ms by its own model, the user's model at 8 ms, where halving the step moves the simulation
by many times the noise and E with it.
"""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from _taper import CALIBRATE, taper, taper_diagnosis
from mpi4py import MPI

import petsoft.diagnosis.chord_refit as chord_refit_module
from petsoft.diagnosis.chord_refit import broyden_update, chord_refit
from petsoft.diagnosis.context import evidence_of
from petsoft.diagnosis.numerics import model_sensitivities, refined, resolve_numerics

NOISE = 2e-5


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """The taper's fit at 8 ms, its sensitivities and its step/2 run at the fitted E."""
    d = Path(MPI.COMM_WORLD.bcast(str(tmp_path_factory.mktemp("chord"))))
    said = []
    diag, exp = taper_diagnosis(d, taper(2.0e7, step=0.001),
                                taper(1.8e7, step=0.008, calibrate=CALIBRATE), seed=3,
                                noise=NOISE, say=said.append)
    fit = diag.calibrate(exp)
    half = refined(fit.experiment, "step/2")
    moved = diag.simulate_identification(half)
    return diag, fit, half, moved, model_sensitivities(diag, fit), said


def test_the_chord_refit_finds_the_calibrations_minimum(case):
    diag, fit, half, moved, cols, _ = case
    seen = np.isfinite(diag.data[diag.ident])
    change = np.sqrt(np.mean((moved[diag.ident][seen] - fit.sim[diag.ident][seen]) ** 2))
    assert change > 5.0 * diag.sigma          # the case needs a refit: E moves
    chord = chord_refit(diag, half, cols, moved)
    full = diag.calibrate(half)
    assert chord is not None and chord.by.startswith("chord Gauss-Newton")
    e_chord, e_full, e_fit = chord.values[0], full.values[0], fit.values[0]
    # E moved by many of its standard deviations, and the chord found the calibration's E to a
    # small fraction of that move and of E's standard deviation
    assert abs(e_full - e_fit) > 10.0 * full.std[0]
    assert abs(e_chord - e_full) < 0.2 * full.std[0]
    assert abs(e_chord - e_full) < 0.01 * abs(e_full - e_fit)
    # chi2 at the chord's point: above the minimum by at most 1 (the calibration stops within
    # about FIT_DTOL x dof of it), far below the excess that decides a refinement
    dof = diag.dof(1)
    assert chord.chi2 == pytest.approx(full.chi2, abs=max(1.0, 1e-3 * dof))
    assert chord.std[0] == pytest.approx(full.std[0], rel=0.2)
    # the whole record simulated at the refit, like a calibration's fit
    assert np.isfinite(chord.sim[diag.held]).any() and chord.heldout_rms is not None
    assert chord.heldout_rms == pytest.approx(full.heldout_rms, rel=0.05)


def test_a_last_small_step_is_checked_by_the_run_of_the_whole_record(case, monkeypatch):
    """After its first run, a step whose linear model lowers chi2 by at most
    CHECKED_BY_FINAL_RUN is taken without a run of its own; when the whole record's run shows
    it did not lower chi2, the point before it is the refit."""
    diag, fit, half, moved, cols, _ = case
    taken = chord_refit(diag, half, cols, moved)
    monkeypatch.setattr(chord_refit_module, "CHECKED_BY_FINAL_RUN", 0.0)
    checked = chord_refit(diag, half, cols, moved)
    assert "checked by the run of the whole record" in taken.by
    assert "checked by the run" not in checked.by
    # one identification run fewer, the same fit to a fraction of E's deviation and of chi2 1
    assert taken.evaluations == checked.evaluations - 1
    assert abs(taken.values[0] - checked.values[0]) < 0.2 * checked.std[0]
    assert taken.chi2 == pytest.approx(checked.chi2, abs=1.0)
    # a last step that makes the fit worse (here: the step turned around and made far larger,
    # taken unchecked whatever its size) is undone by the point before it
    monkeypatch.setattr(chord_refit_module, "CHECKED_BY_FINAL_RUN", np.inf)
    steps = []
    real_step = chord_refit_module.refit_step

    def turned(c, r):
        step = real_step(c, r)
        steps.append(step)
        return step if len(steps) < 2 else -20.0 * step

    monkeypatch.setattr(chord_refit_module, "refit_step", turned)
    undone = chord_refit(diag, half, cols, moved)
    assert undone.iterations == 1 and undone.evaluations == 1 + 2
    assert undone.values[0] == pytest.approx(fit.values[0] + steps[0][0], rel=1e-12)
    assert undone.chi2 <= checked.chi2 + 0.1 * (fit.chi2 - checked.chi2)


def test_a_chord_that_does_not_converge_in_its_runs_gives_up(case, monkeypatch):
    """The caller calibrates instead (None) rather than reporting a point that is not a fit:
    this refit needs more than two runs."""
    diag, fit, half, moved, cols, _ = case
    monkeypatch.setattr(chord_refit_module, "MAX_RUNS", 2)
    assert chord_refit(diag, half, cols, moved) is None


def test_the_secant_update_is_what_converges(case, monkeypatch):
    """Without Broyden's update (the current model's columns kept) the same refit creeps
    (its steps shrink by about a third a run) and gives up within MAX_RUNS."""
    diag, fit, half, moved, cols, _ = case
    monkeypatch.setattr(chord_refit_module, "broyden_update", lambda c, step, change: c)
    assert chord_refit(diag, half, cols, moved) is None


def test_broyden_update_is_the_secant():
    rng = np.random.default_rng(0)
    cols = rng.normal(size=(50, 2)) * [1.0, 1e-6]
    step = np.array([0.3, -2e5])
    change = rng.normal(size=50)
    new = broyden_update(cols, step, change)
    assert np.allclose(new @ step, change, rtol=1e-12, atol=1e-12)
    # unchanged across the step (in unit-column variables)
    scale = np.linalg.norm(cols, axis=0)
    across = np.array([step[1] * scale[1], -step[0] * scale[0]]) / scale
    assert np.allclose(new @ across, cols @ across, rtol=1e-12, atol=1e-12)
    one = broyden_update(cols[:, :1], step[:1], change)
    assert np.allclose(one[:, 0], change / step[0])


def test_a_chord_that_leaves_the_bounds_gives_up(case):
    diag, fit, half, moved, cols, _ = case
    e = fit.values[0]
    # the bounds end between the fit's E and the refit's (the step/2 refit lowers or raises E)
    full_e = chord_refit(diag, half, cols, moved).values[0]
    lo, hi = (0.5 * e, 0.5 * (e + full_e)) if full_e > e else (0.5 * (e + full_e), 2.0 * e)
    tight = dataclasses.replace(half, calibrate={"material.youngs_modulus": (lo, hi)})
    assert chord_refit(diag, tight, cols, moved) is None


def test_the_numerics_check_refits_the_step_by_the_chord_at_a_quarter(case):
    """Halving the 8 ms step moves the simulation by many times the noise, so half the step
    would still leave an error to measure (Richardson: a third of that change): the step is
    refitted at a quarter (2 ms) at once, by the chord, from Richardson's estimate of the
    quarter step's run; the refit is the calibration's at 2 ms."""
    diag, fit, half, moved, _, said = case
    diag.model_error["step/2"] = 0.5 * diag.sigma     # as an earlier round would have booked
    _, _, rounds = resolve_numerics(diag, fit, evidence_of(diag, fit), max_rounds=1)
    options = rounds[0].options
    assert "step/2" not in options
    # the quarter step measured the step's error afresh: the halved step's estimate is out of
    # the verdict's noise budget (else counted twice)
    assert "step/2" not in diag.model_error
    step = options["step/4"]
    assert step.refit.startswith("chord Gauss-Newton")
    assert step.matters and rounds[0].adopted == "step/4"
    assert step.same_parameters_from == "step/2"
    assert step.how == "step 0.008 s -> 0.002 s"
    if MPI.COMM_WORLD.rank == 0:
        assert any("numerics step/4: it" in line and "run(s)" in line for line in said), said
        assert any("refitting at a quarter of the step" in line for line in said), said
    MPI.COMM_WORLD.Barrier()
    # the same point as the calibration of the model at 2 ms, to a fraction of E's deviation
    quarter = refined(half, "step/2")
    assert quarter.time.step == pytest.approx(0.002)
    full = diag.calibrate(quarter)
    assert abs(step.parameters["material.youngs_modulus"] - full.values[0]) \
        < 0.2 * full.std[0]
    # the estimated same-parameter change against the quarter step's real run at the fit's E
    seen = np.isfinite(diag.data[diag.ident])
    real = diag.simulate_identification(quarter)
    actual = np.sqrt(np.mean((real[diag.ident][seen] - fit.sim[diag.ident][seen]) ** 2))
    assert step.change_same_parameters == pytest.approx(actual, rel=0.1)


def test_a_fits_own_sensitivities_are_its_models_and_cost_no_run(case, monkeypatch):
    """A calibration's fit carries its Jacobian run at the optimum (Fit.sensitivities): equal
    to a fresh forward sensitivity run of its model at its values, taken by
    model_sensitivities with no run; a copy of the fit at other values does not carry it."""
    import petsoft.calibration.calibrate as calibrate_module
    from petsoft.diagnosis.context import petsc_comm, sensitivities_key
    from petsoft.diagnosis.numerics import has_sensitivities

    diag, fit, _, _, cols, _ = case
    assert fit.sensitivities is not None and fit.sensitivities[0] == sensitivities_key(fit)
    fm = calibrate_module.build_forward(fit.experiment, fit.names, diag.recording,
                                        diag.times[diag.ident], petsc_comm(diag.comm),
                                        diag.integrator)
    fresh = fm.jacobian(np.asarray(fit.values, dtype=float))[1]
    fm.destroy()
    assert fresh.shape == cols.shape == diag.data[diag.ident].shape + (len(fit.names),)
    np.testing.assert_allclose(cols, fresh, rtol=0, atol=1e-9 * np.abs(fresh).max())

    def no_run(*args, **kwargs):
        raise AssertionError("a Jacobian run was made")

    monkeypatch.setattr(calibrate_module, "build_forward", no_run)
    diag.measured_meshes.pop(sensitivities_key(fit), None)
    assert has_sensitivities(diag, fit)
    np.testing.assert_array_equal(model_sensitivities(diag, fit), cols)
    moved = dataclasses.replace(fit, values=fit.values * 1.01)
    assert not has_sensitivities(diag, moved)
    with pytest.raises((AssertionError, RuntimeError), match="a Jacobian run"):   # 2 ranks: wrapped
        model_sensitivities(diag, moved)
