"""diagnose fits an added spatial term's sphere (petsoft.diagnosis.geometry).

A cantilever of 12 x 2 x 2 box cells (288 tets) carries a sphere of denser material (5x) near
its tip; ``petsoft synth`` records it. The user's model has the sphere's term but placed a
cell towards the clamp, and calibrates the sphere's density (E is the truth's: on this bar a
lower E trades off against the mass' place): the compass search must move the sphere towards
the truth, lower chi2 significantly and predict the held-out window better. Placed at the
truth, no move passes the tests.
"""

from pathlib import Path

import numpy as np
import pytest
from _cantilever import cantilever
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.calibration.synth import SynthOptions, synth
from petsoft.diagnosis.candidates import REGION, Candidate, sphere_condition
from petsoft.diagnosis.context import Diagnosis
from petsoft.diagnosis.geometry import _polls, _Sphere, fit_sphere, refit_added_sphere
from petsoft.diagnosis.records import AddedTerm
from petsoft.experiment import load_experiment

NAME = REGION["mass.added"]
TRUE_CENTRE, RADIUS = (0.25, 0.02, 0.02), 0.03
CALIBRATE = f'[calibrate]\n"material.{NAME}.density" = [1000.0, 10000.0]\n'


def _model(centre, density: float, calibrate: str = "") -> str:
    extra = (f"[material.{NAME}]\ndensity = {density}\n\n[region.{NAME}]\n"
             f'where = "{sphere_condition(centre, RADIUS)}"\n')
    text = cantilever(2.0e7, extra=extra, calibrate=calibrate, end=0.16)
    return text.replace("cells = [6, 1, 1]", "cells = [12, 2, 2]")


def record_truth(d: Path) -> None:
    """The truth's model and recording (``truth.h5``) in ``d`` (collective; the first rank
    writes). Also scripts/benchmarks/sphere_search_work.py's case."""
    comm = MPI.COMM_WORLD
    if comm.rank == 0:
        (d / "truth.toml").write_text(_model(TRUE_CENTRE, 5000.0))
    comm.Barrier()
    synth(load_experiment(d / "truth.toml"), SynthOptions(out=d / "truth.h5", noise=2e-5,
                                                          markers=12, dropout=0.0, refine=1,
                                                          seed=7))
    comm.Barrier()


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    comm = MPI.COMM_WORLD
    d = Path(comm.bcast(str(tmp_path_factory.mktemp("sphere")) if comm.rank == 0 else None))
    record_truth(d)
    return d


def _start(d: Path, centre, name: str):
    """The user's calibrated model with the sphere at ``centre`` and its Diagnosis."""
    if MPI.COMM_WORLD.rank == 0:
        (d / name).write_text(_model(centre, 3000.0, CALIBRATE))
    MPI.COMM_WORLD.Barrier()
    exp = load_experiment(d / name)
    diag = Diagnosis(exp, str(d / "truth.h5"), fraction=0.7, alpha=0.01,
                     method="gauss-newton", gradient="sensitivity", integrator=None,
                     noise=None, comm=PETSc.COMM_WORLD, say=None)
    cand = Candidate("mass.added", [f"material.{NAME}.density"], [(1000.0, 10000.0)],
                     region={"center": list(centre), "radius": RADIUS})
    return diag, diag.calibrate(exp), cand


def test_polls_move_each_axis_and_scale_the_radius():
    polls = _polls({"center": [1.0, 2.0, 3.0], "radius": 0.5}, 0.1, 2.0)
    centres = np.array([p["center"] for p in polls[:6]])
    assert np.allclose(np.sort(np.abs(centres - [1.0, 2.0, 3.0]).sum(axis=1)), 0.1)
    assert [p["radius"] for p in polls] == [0.5] * 6 + [1.0, 0.25]


def test_a_trial_keeps_the_added_mass(recording):
    """An added mass's trial sphere keeps its extra mass (radius and density trade off)."""
    diag, fit, cand = _start(recording, (0.2, 0.02, 0.02), "keep.toml")
    search = _Sphere(diag, fit, cand)
    bigger = {"center": [0.2, 0.02, 0.02], "radius": 0.045}
    exp = search.experiment(bigger)
    rho = exp.material[NAME].density
    before = search.volumes[search.cells(cand.region)].sum()
    after = search.volumes[search.cells(bigger)].sum()
    assert after > before
    assert (rho - 1000.0) * after == pytest.approx((search.value - 1000.0) * before, rel=1e-12)


def test_the_search_moves_a_misplaced_sphere_towards_the_truth(recording):
    diag, fit, cand = _start(recording, (0.225, 0.02, 0.02), "misplaced.toml")
    said = []
    diag.say = said.append
    moved = fit_sphere(diag, fit, cand)
    assert moved is not None
    if MPI.COMM_WORLD.rank == 0:
        # its scale (where a second search starts) is the step of the last poll that moved it
        polls = [line for line in said if ": poll " in line]
        best = [f"{np.round(cand.region['center'], 4).tolist()} r {RADIUS:.4g}"] + [
            line.split("best centre ", 1)[1].split(", chi2", 1)[0] for line in polls]
        last = max(i for i in range(len(polls)) if best[i + 1] != best[i])
        h, f = moved.scale
        assert f"(centre step {h:.3g} m, radius x {f:.3g})" in polls[last], (polls, last)
    # along the bar (what its motion tells apart; across, a wider sphere of less density
    # holds much the same mass) the sphere moves towards the truth's
    assert abs(moved.region["center"][0] - TRUE_CENTRE[0]) < 0.5 * abs(0.225 - TRUE_CENTRE[0])
    assert fit.chi2 - moved.fit.chi2 > 13.3                 # chi2(4) at p = 0.01
    assert moved.fit.heldout_rms < 0.5 * fit.heldout_rms
    assert moved.candidate.region == moved.region
    assert moved.candidate.regions[NAME] == sphere_condition(moved.region["center"],
                                                             moved.region["radius"])
    # the report entry follows the fitted sphere
    entry = AddedTerm(physics="mass.added", parameters={}, std={}, score=1.0,
                      rms_after=fit.rms, evidence="score test", region=cand.region)
    new_entry, new_fit, new_cand = refit_added_sphere(diag, entry, fit, cand, searches=1)
    assert new_entry.region == new_cand.region == moved.region
    assert "sphere fitted" in new_entry.evidence
    assert new_entry.parameters[f"material.{NAME}.density"] == pytest.approx(
        new_fit.values[new_fit.names.index(f"material.{NAME}.density")])


def test_a_sphere_placed_at_the_truth_stays(recording):
    diag, fit, cand = _start(recording, TRUE_CENTRE, "placed.toml")
    assert fit_sphere(diag, fit, cand) is None


def test_no_sphere_search_without_exact_sensitivities(recording, monkeypatch):
    """With a viscoelastic branch the integrator cannot differentiate, a trial could not be
    scored: the placed sphere stays and the log says why."""
    diag, fit, cand = _start(recording, (0.225, 0.02, 0.02), "branch.toml")
    said = []
    diag.say = said.append
    monkeypatch.setattr(diag, "all_differenced", lambda experiment: True)
    entry = AddedTerm(physics=cand.physics, parameters={}, std={}, score=1.0,
                      rms_after=fit.rms, evidence="score test", region=cand.region)
    assert refit_added_sphere(diag, entry, fit, cand) == (entry, fit, cand)
    if MPI.COMM_WORLD.rank == 0:                # the first rank says the progress lines
        assert any("not fitted (no exact sensitivities" in line for line in said)


def test_no_sphere_search_once_the_time_budget_is_spent(recording):
    """A spent time budget: the misplaced sphere stays where it was placed (no trial is run),
    the search is a skipped check of the report with what it risks, and the log says so."""
    import time

    from petsoft.diagnosis.budget import TimeBudget

    diag, fit, cand = _start(recording, (0.225, 0.02, 0.02), "budget.toml")
    said = []
    diag.say = said.append
    diag.budget = TimeBudget(5.0, time.perf_counter() - 6.0, PETSc.COMM_WORLD)
    entry = AddedTerm(physics=cand.physics, parameters={}, std={}, score=1.0,
                      rms_after=fit.rms, evidence="score test", region=cand.region)
    assert refit_added_sphere(diag, entry, fit, cand) == (entry, fit, cand)
    [skipped] = diag.budget.skipped
    assert skipped["check"] == "mass.added's sphere search 1 of 2"
    assert "time budget (5 s" in skipped["why"] and "first guess" in skipped["risk"]
    if MPI.COMM_WORLD.rank == 0:
        assert any("time budget: mass.added's sphere search 1 of 2 not "
                   "started" in line for line in said), said


def test_a_sphere_search_stops_polling_once_the_budget_is_spent(recording):
    """A search already under way when the budget is found spent (fit_sphere called directly:
    refit_added_sphere would not start it): it stops after its first poll, says so, and keeps
    what that poll found."""
    import time

    from petsoft.diagnosis.budget import TimeBudget

    diag, fit, cand = _start(recording, (0.225, 0.02, 0.02), "polls.toml")
    said = []
    diag.say = said.append
    diag.budget = TimeBudget(5.0, time.perf_counter() - 6.0, PETSc.COMM_WORLD)
    moved = fit_sphere(diag, fit, cand)
    if MPI.COMM_WORLD.rank == 0:
        polls = [line for line in said if ": poll " in line]
        assert len(polls) == 1 and ": poll 1:" in polls[0], said
        assert any("stopped after poll 1 of at most 8: the time budget is spent" in line
                   for line in said), said
    # the first poll already moved the sphere along the bar, towards the truth
    assert moved is not None
    assert abs(moved.region["center"][0] - TRUE_CENTRE[0]) < abs(0.225 - TRUE_CENTRE[0])
    # the report names the polls left out
    [left] = diag.budget.skipped
    assert left["check"] == "mass.added sphere's polls 2-8" and "best of the polls" in left["risk"]


# -- the time budget's foresight (issue 40) ---------------------------------------------------
TRIAL_SECONDS, CALIBRATION_SECONDS = 10.0, 30.0


class _FakeClock:
    """A TimeBudget of ``seconds`` whose clock (each rank's own) advances TRIAL_SECONDS a trial
    run on the rank that ran it, and CALIBRATION_SECONDS a calibration of the diagnosis (on
    the first rank, where a small model's calibration runs): what the budget decides does not
    depend on the machine's speed. ``lag``: the other ranks' clocks start that far behind (the
    first rank's decides)."""

    def __new__(cls, seconds: float, monkeypatch, diag, lag: float = 0.0):
        from petsoft.diagnosis import geometry
        from petsoft.diagnosis.budget import TimeBudget

        class Clocked(TimeBudget):
            now = 0.0 if MPI.COMM_WORLD.rank == 0 else -lag

            def elapsed(self):
                return self.now

        budget = Clocked(seconds, 0.0, PETSc.COMM_WORLD)
        trial = geometry._Sphere.trial

        def timed_trial(self, region, comm):
            budget.now += TRIAL_SECONDS
            return trial(self, region, comm)

        calibrate = diag.calibrate

        def timed_calibrate(*args, comm=None, **kwargs):
            if comm is not None:            # (the ranks' own call: placement.alone's task)
                budget.now += CALIBRATION_SECONDS
            return calibrate(*args, comm=comm, **kwargs)

        monkeypatch.setattr(geometry._Sphere, "trial", timed_trial)
        monkeypatch.setattr(diag, "calibrate", timed_calibrate)
        return budget


def _timed(fit):
    """``fit`` as if its calibration took CALIBRATION_SECONDS over 3 runs (TRIAL_SECONDS a
    run): the closing calibration's and, before any poll, a trial round's foreseen cost."""
    import dataclasses

    return dataclasses.replace(fit, seconds=CALIBRATION_SECONDS, evaluations=3)


def _first_poll_trials(diag, fit, cand) -> int:
    """The new cell sets of a fresh search's first poll around ``cand``'s sphere."""
    from petsoft.diagnosis.geometry import RADIUS_FACTOR

    search = _Sphere(diag, fit, cand)
    h0 = max(0.5 * RADIUS, search.cell)
    keys = {search.cells(r).tobytes() for r in _polls(cand.region, h0, RADIUS_FACTOR)
            if search.cells(r).any()}
    return len(keys - {search.cells(cand.region).tobytes()})


@pytest.mark.parametrize("kept", [False, True])
def test_a_search_that_cannot_end_inside_the_budget_is_not_started(recording, monkeypatch,
                                                                    kept):
    """A search is costed at the model's sensitivities it runs before its first poll (a run
    of the last calibration's; nothing when they are ``kept``: the calibration's own, which
    its fit carries), its first poll (8 trials, in rounds side by side on the ranks, a run
    each as the last calibration's) and its closing calibration: 5 s short of that it is not
    started (a skipped entry saying what it needed, the budget not spent); 5 s more than
    that, it starts."""
    import dataclasses

    from petsoft.diagnosis import geometry

    diag, fit, cand = _start(recording, (0.225, 0.02, 0.02), "foresee.toml")
    fit = _timed(fit)
    assert fit.sensitivities is not None           # a calibration's fit carries its own
    if not kept:
        fit = dataclasses.replace(fit, sensitivities=None)
    rounds = -(-8 // MPI.COMM_WORLD.size)
    sensitivities = 0.0 if kept else TRIAL_SECONDS
    needs = sensitivities + TRIAL_SECONDS * rounds + CALIBRATION_SECONDS
    started = []
    monkeypatch.setattr(geometry, "fit_sphere", lambda *a, **k: started.append(k) or None)
    entry = AddedTerm(physics=cand.physics, parameters={}, std={}, score=1.0,
                      rms_after=fit.rms, evidence="score test", region=cand.region)
    diag.budget = _FakeClock(needs - 5.0, monkeypatch, diag, lag=1000.0)
    assert refit_added_sphere(diag, entry, fit, cand) == (entry, fit, cand)
    assert started == []
    [skipped] = diag.budget.skipped
    assert skipped["check"] == "mass.added's sphere search 1 of 2"
    assert "first guess" in skipped["risk"]
    first = ("" if kept else f"the model's sensitivities (~{TRIAL_SECONDS:.0f} s, a run as the "
             "last calibration's), ")
    assert (f"had {needs - 5.0:.0f} s left at 0 s, less than the ~{needs:.0f} s {first}a poll "
            f"of 8 trial run(s) (~{TRIAL_SECONDS * rounds:.0f} s, {rounds} round(s)"
            in skipped["why"]), skipped
    assert "closing calibration (~30 s" in skipped["why"]
    assert not diag.budget.summary()["spent"]
    diag.budget = _FakeClock(needs + 5.0, monkeypatch, diag)
    assert refit_added_sphere(diag, entry, fit, cand) == (entry, fit, cand)
    assert len(started) == 1 and diag.budget.skipped == []


def test_a_poll_that_cannot_end_inside_the_budget_is_not_made(recording, monkeypatch):
    """A budget that holds the first poll and the closing calibration with 5 s to spare: the
    second poll (a round at least, at the first's cost a round) is not made, the report says
    why, the search keeps what the first poll found and its closing calibration ends inside
    the budget. The other ranks' clocks lag by 1000 s: the first rank's decides for all."""
    diag, fit, cand = _start(recording, (0.225, 0.02, 0.02), "foresee_polls.toml")
    fit = _timed(fit)
    first = TRIAL_SECONDS * -(-_first_poll_trials(diag, fit, cand) // MPI.COMM_WORLD.size)
    seconds = first + CALIBRATION_SECONDS + 5.0
    said = []
    diag.say = said.append
    diag.budget = _FakeClock(seconds, monkeypatch, diag, lag=1000.0)
    moved = fit_sphere(diag, fit, cand)
    # (as test_a_sphere_search_stops_polling_once_the_budget_is_spent: poll 1 moved it)
    assert moved is not None
    assert abs(moved.region["center"][0] - TRUE_CENTRE[0]) < abs(0.225 - TRUE_CENTRE[0])
    [left] = diag.budget.skipped
    assert left["check"] == "mass.added sphere's polls 2-8" and "best of the polls" in left["risk"]
    assert f"had 35 s left at {first:.0f} s, less than the ~" in left["why"], left
    assert "round(s) side by side, as the polls so far)" in left["why"], left
    assert MPI.COMM_WORLD.allgather(diag.budget.skipped) == [diag.budget.skipped] * \
        MPI.COMM_WORLD.size
    assert not diag.budget.summary()["spent"]
    if MPI.COMM_WORLD.rank == 0:
        polls = [line for line in said if ": poll " in line]
        assert len(polls) == 1 and ": poll 1:" in polls[0], said
        assert any("stopped after poll 1 of at most 8: the next poll and the closing "
                   "calibration would end past the time budget" in line for line in said), said
        # the poll and the calibration (on this rank) ended inside the budget
        assert diag.budget.elapsed() == pytest.approx(first + CALIBRATION_SECONDS)
        assert diag.budget.elapsed() <= seconds


def test_a_poll_is_costed_by_its_rounds_at_the_longest_round_so_far():
    """What a poll and the closing calibration are foreseen to need: before any poll, a round
    at a run of the last calibration's (its wall time over its runs); then at the longest
    round so far; a poll's trials run in rounds side by side, one a rank."""
    from types import SimpleNamespace

    from petsoft.diagnosis.budget import TimeBudget
    from petsoft.diagnosis.geometry import TRIAL_ROUND, _poll_needs

    ranks = MPI.COMM_WORLD.size
    diag = SimpleNamespace(budget=TimeBudget(100.0, 0.0, PETSc.COMM_WORLD),
                           comm=PETSc.COMM_WORLD)
    fit = SimpleNamespace(seconds=60.0, evaluations=6)
    rounds = -(-7 // ranks)
    needs, words = _poll_needs(diag, fit, 7)
    assert needs == pytest.approx(10.0 * rounds + 60.0)
    assert "a run each as the last calibration's" in words
    diag.budget.record(TRIAL_ROUND, 48.0, 4)
    diag.budget.record(TRIAL_ROUND, 20.0, 2)
    needs, words = _poll_needs(diag, fit, 7)
    assert needs == pytest.approx(12.0 * rounds + 60.0)
    assert f"{rounds} round(s) side by side, as the polls so far" in words


def test_a_second_search_starts_from_the_step_that_last_moved_the_sphere(recording,
                                                                           monkeypatch):
    """refit_added_sphere starts its second search at the first's last moving step
    (SphereFit.scale); fit_sphere given a step starts its polls there, at most at a fresh
    search's."""
    import dataclasses

    from petsoft.diagnosis import geometry
    from petsoft.diagnosis.geometry import RADIUS_FACTOR, SphereFit

    diag, fit, cand = _start(recording, (0.225, 0.02, 0.02), "scale.toml")
    said = []
    diag.say = said.append
    fit_sphere(diag, fit, cand, max_polls=1, scale=(0.011, 1.2))
    fit_sphere(diag, fit, cand, max_polls=1, scale=(1.0, 3.0))
    if MPI.COMM_WORLD.rank == 0:
        polls = [line for line in said if ": poll 1:" in line]
        assert "(centre step 0.011 m, radius x 1.2)" in polls[0], said
        h0 = max(0.5 * RADIUS, _Sphere(diag, fit, cand).cell)
        assert f"(centre step {h0:.3g} m, radius x {RADIUS_FACTOR:.3g})" in polls[1], said
    scales = []
    first = SphereFit(cand, fit, cand.region, "sphere fitted: here", scale=(0.011, 1.2))

    def searched(*args, scale=None, **kwargs):
        scales.append(scale)
        return first if len(scales) == 1 else None

    monkeypatch.setattr(geometry, "fit_sphere", searched)
    entry = AddedTerm(physics=cand.physics, parameters={}, std={}, score=1.0,
                      rms_after=fit.rms, evidence="score test", region=cand.region)
    refit_added_sphere(diag, entry, dataclasses.replace(fit), cand)
    assert scales == [None, (0.011, 1.2)]
