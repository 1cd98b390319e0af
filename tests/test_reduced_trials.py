"""A sphere search's trials scored by a reduced model (petsoft.diagnosis.reduced_trials).

The case of tests/test_sphere_fit.py: a 288-tet cantilever whose truth has a 5x denser sphere
near its tip, the user's model the same term placed a cell towards the clamp, its density
calibrated. The reduced model of the fitted model (trained on its full run and the density's
tangent trajectory) scores trial spheres -- moved along each axis, the radius scaled (the
density rescaled to keep the added mass) -- with the chi2 and linearised step of the full
trials to within 1 % (chi2, relative; the step, of the largest step among the trials), and its
marker error on each is below the target. A deliberately poor reduced model falls back to full
trials: at the build (too few modes to meet the target) or at the first verification (a build
whose check was made to pass); either way the search still moves the sphere and says so. With
the option off, fit_sphere never builds a reduced model and runs every trial on the full model.
"""

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc
from test_sphere_fit import NAME, TRUE_CENTRE, _start, recording  # noqa: F401 - the fixture

import petsoft.diagnosis.reduced_trials as rt_module
from petsoft.diagnosis.geometry import _polls, _Sphere, fit_sphere, refit_added_sphere
from petsoft.diagnosis.records import AddedTerm
from petsoft.diagnosis.reduced_trials import ReducedTrials
from petsoft.reduced.error import TARGET, ReducedError

MISPLACED = (0.225, 0.02, 0.02)
#: chi2 of a reduced trial within this share of the full trial's; its linearised step within
#: this share of the largest step of the trials compared
CHI2_REL, STEP_REL = 1e-2, 1e-2


def _said(diag) -> list:
    said = []
    diag.say = said.append
    return said


def _everywhere(made: list) -> set:
    """The regions of the full trials made on any rank (a small model's trials are shared
    out one per rank; a larger one's run on all of them)."""
    return {(tuple(r["center"]), r["radius"]) for part in MPI.COMM_WORLD.allgather(made)
            for r in part}


def _full_trials(monkeypatch) -> list:
    """The regions of every full trial (_Sphere.trial) this rank makes from now on."""
    made = []
    original = _Sphere.trial

    def trial(self, region, comm):
        made.append(region)
        return original(self, region, comm)

    monkeypatch.setattr(_Sphere, "trial", trial)
    return made


def test_reduced_trials_score_as_the_full_model(recording):  # noqa: F811
    diag, fit, cand = _start(recording, MISPLACED, "reduced.toml")
    search = _Sphere(diag, fit, cand)
    trials = ReducedTrials.start(diag, search)
    assert trials.active, trials.why
    assert 0 < trials.size and trials.built_error <= TARGET
    # the training run's columns (one more tangent: the surrounding density's) are the
    # search's current-model columns, as their own run makes them (to round-off)
    kept = search.cols
    diag.measured_meshes.clear()
    np.testing.assert_allclose(kept, _Sphere(diag, fit, cand).cols, rtol=0.0,
                               atol=1e-12 * np.abs(kept).max())
    regions = _polls(cand.region, 0.015, 1.4)
    reduced = trials.score(regions)
    full = [search.trial(r, PETSc.COMM_WORLD) for r in regions]
    top = max(abs(f[1][0]) for f in full)
    for region, red, (chi2, step, values) in zip(regions, reduced, full, strict=True):
        assert red.ok, red.error
        r_chi2, r_step, r_values = red.value[:3]
        assert r_values == values          # the same start (the density rescaled alike)
        assert r_chi2 == pytest.approx(chi2, rel=CHI2_REL), region
        assert abs(r_step[0] - step[0]) <= STEP_REL * top, region
    # the radius-scaled trials keep the added mass: their densities differ from the fit's
    assert {full[-1][2][f"material.{NAME}.density"], full[-2][2][f"material.{NAME}.density"]} \
        .isdisjoint({float(search.value)})
    # a verification measures each trial's reduced-vs-full marker error, below the target
    for poll, (region, red) in enumerate(zip(regions[:2], reduced[:2], strict=True), 1):
        chi2, step, values = trials.verify(poll, region, red.value)
        assert chi2 == pytest.approx(full[poll - 1][0], rel=1e-12)
        assert 0.0 < trials.verified[-1][1] <= TARGET
    assert trials.active
    trials.destroy()


def test_the_search_with_reduced_trials_moves_the_sphere(recording, monkeypatch):  # noqa: F811
    """The whole search with the option on: at most one full run a poll, made only where the
    poll's best reduced trial would move the sphere (here 5 of its 8 polls: polls 3, 5 and 6
    keep the sphere, as the full search's do); the sphere ends where the full search ends
    it, nearer the truth, with the same calibrated fit; the reduced trials' note in the
    evidence."""
    full_diag, full_fit, full_cand = _start(recording, MISPLACED, "full_search.toml")
    full = fit_sphere(full_diag, full_fit, full_cand)
    diag, fit, cand = _start(recording, MISPLACED, "reduced_search.toml")
    diag.reduced_trials = True
    said = _said(diag)
    made = _full_trials(monkeypatch)
    runs = []
    verify = ReducedTrials.verify
    monkeypatch.setattr(ReducedTrials, "verify",
                        lambda self, poll, *a: (runs.append(poll), verify(self, poll, *a))[1])
    entry = AddedTerm(physics="mass.added", parameters={}, std={}, score=1.0,
                      rms_after=fit.rms, evidence="score test", region=cand.region)
    new_entry, new_fit, new_cand = refit_added_sphere(diag, entry, fit, cand, searches=1)
    assert new_cand.region == full.region, (new_cand.region, full.region)
    assert new_fit.chi2 == pytest.approx(full.fit.chi2, rel=1e-9)
    assert abs(new_cand.region["center"][0] - TRUE_CENTRE[0]) < \
        0.5 * abs(MISPLACED[0] - TRUE_CENTRE[0])
    assert fit.chi2 - new_fit.chi2 > 13.3
    assert made == []                   # the verifications are full runs, not full trials
    assert runs == [1, 2, 4, 7, 8], runs
    evidence = new_entry.evidence
    assert "sphere fitted" in evidence
    assert "sphere trials scored by a reduced model" in evidence
    assert "each poll's best verified on the full model" in evidence
    assert "3 poll(s) whose best would not move the sphere not verified" in evidence
    if MPI.COMM_WORLD.rank == 0:
        polls = [line for line in said if ": poll " in line]
        verified = [line for line in polls if "the best verified on the full model: chi2 "
                    in line and "reduced-model error" in line]
        kept = [line for line in polls if "not verified, the sphere stays" in line]
        assert len(verified) == len(runs) and len(kept) == 3 and len(polls) == 8, said
        assert any("reduced trials: build" in line for line in said), said


def test_a_poor_reduced_model_is_not_used(recording, monkeypatch):  # noqa: F811
    """Too few modes to meet the target: the search runs full trials from the start."""
    diag, fit, cand = _start(recording, MISPLACED, "poor_build.toml")
    diag.reduced_trials = True
    said = _said(diag)
    made = _full_trials(monkeypatch)
    monkeypatch.setattr(rt_module, "ENERGIES", (0.5,))
    notes = []
    moved = fit_sphere(diag, fit, cand, notes=notes)
    assert moved is not None and _everywhere(made)      # the full search ran
    [note] = notes
    assert "sphere trials on the full model" in note and "above the target" in note
    if MPI.COMM_WORLD.rank == 0:
        assert any("full trials: the reduced model's error" in line for line in said), said


def test_no_reduced_trials_for_a_stiffness_region(recording):  # noqa: F811
    """A stiffness region's moves change the mode shapes beyond the basis: full trials, and
    why, before any run."""
    diag, fit, cand = _start(recording, MISPLACED, "stiffness.toml")
    search = _Sphere(diag, fit, cand)
    search.parameter = f"material.{NAME}.youngs_modulus"
    trials = ReducedTrials.start(diag, search)
    assert not trials.active and "stiffness region" in trials.why
    assert trials.fm is None and trials.model is None
    assert trials.note().startswith("sphere trials on the full model: a moved stiffness region")


def test_a_reduced_model_failing_its_verification_falls_back(recording, monkeypatch):  # noqa: F811
    """A poor model whose build check was made to pass: the first poll's verification finds
    its error above the target, and that poll's other trials and every later one run on the
    full model."""
    diag, fit, cand = _start(recording, MISPLACED, "poor_verified.toml")
    diag.reduced_trials = True
    said = _said(diag)
    made = _full_trials(monkeypatch)
    monkeypatch.setattr(rt_module, "ENERGIES", (0.5,))
    build = rt_module.build_reduced

    def passing(*args, **kw):
        model, _ = build(*args, **kw)
        return model, ReducedError(0.0, 0.0, {"fitted": {"rms": 0.0, "max": 0.0}})

    monkeypatch.setattr(rt_module, "build_reduced", passing)
    notes = []
    moved = fit_sphere(diag, fit, cand, notes=notes)
    assert moved is not None
    assert abs(moved.region["center"][0] - TRUE_CENTRE[0]) < abs(MISPLACED[0] - TRUE_CENTRE[0])
    [note] = notes
    assert "full trials from poll 1 on" in note and "above the target" in note
    # poll 1: its 8 trials less the verified one on the full model, then full polls
    assert len(_everywhere(made)) >= 7
    if MPI.COMM_WORLD.rank == 0:
        polls = [line for line in said if ": poll " in line]
        assert "full trials from here on" in polls[0], polls
        assert all("reduced-model error" not in line for line in polls[1:]), polls


def test_option_off_runs_every_trial_on_the_full_model(recording, monkeypatch):  # noqa: F811
    """Off (the default): no reduced model is built, every poll's new cell sets are full
    trials, and the result and evidence are the full search's."""
    diag, fit, cand = _start(recording, MISPLACED, "off.toml")
    assert diag.reduced_trials is False
    said = _said(diag)
    made = _full_trials(monkeypatch)

    def refuse(*args, **kw):
        raise AssertionError("a reduced model was built with the option off")

    monkeypatch.setattr(ReducedTrials, "start", refuse)
    notes = []
    moved = fit_sphere(diag, fit, cand, notes=notes)
    assert moved is not None and notes == []
    assert "reduced" not in moved.summary
    made = _everywhere(made)
    if MPI.COMM_WORLD.rank == 0:
        counts = [int(line.split(": poll ")[1].split(": ")[1].split(" new")[0])
                  for line in said if ": poll " in line]
        assert sum(counts) == len(made) > 0
        assert all("reduced" not in line for line in said), said


def test_jacobian_watch_sees_every_state_and_tangent(recording):  # noqa: F811
    """ForwardModel.jacobian's watch: every step's state and displacement tangents, from the
    initial state; the last tangent observed is the last frame's sensitivity."""
    from petsoft.calibration.calibrate import build_forward

    diag, fit, _ = _start(recording, MISPLACED, "watch.toml")
    fm = build_forward(fit.experiment, fit.names, diag.recording, diag.times[diag.ident],
                       PETSc.COMM_WORLD, None)
    seen = []

    def watch(n, state, dq):
        # (observe(x) = X + B x: the tangent's markers are B dq)
        seen.append((n, np.asarray(fm.observer.observe(dq[0])).reshape(-1, 3) - fm.reference))

    _, jac = fm.jacobian(np.asarray(fit.values), watch=watch)
    assert [n for n, _ in seen] == list(range(fm.nsteps + 1))
    last = seen[-1][1]
    # (to the round-off of X + B dq less X)
    atol = 1e-14 * np.abs(fm.reference).max()
    assert np.allclose(last, jac[-1, :, :, 0], rtol=1e-9, atol=atol)
    assert not np.allclose(last, 0.0, atol=1e3 * atol)
    fm.destroy()



def test_the_cli_option_reaches_run_diagnose(monkeypatch, tmp_path):
    """``petsoft diagnose --reduced-trials`` sets run_diagnose's ``reduced_trials`` (off
    without it)."""
    from petsoft.cli import commands
    from petsoft.cli.main import _parser

    args = _parser().parse_args(["diagnose", "a.toml", "b.h5"])
    assert args.reduced_trials is False
    args = _parser().parse_args(["diagnose", "a.toml", "b.h5", "--reduced-trials"])
    assert args.reduced_trials is True
    seen = {}

    class Stop(Exception):
        pass

    def run_diagnose(*_, **kw):
        seen.update(kw)
        raise Stop

    monkeypatch.setattr(commands, "run_diagnose", run_diagnose)
    monkeypatch.setattr(commands, "load_experiment", lambda path: type(
        "E", (), {"output": type("O", (), {"directory": tmp_path})()})())
    monkeypatch.setattr(commands, "read_recording_on_all_ranks", lambda path: None)
    with pytest.raises(Stop):
        commands.run(args)
    assert seen["reduced_trials"] is True
