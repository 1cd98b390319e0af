"""The time budget's foresight (petsoft.diagnosis.budget): a piece of work that would end past
the budget is not started, the costs it is foreseen by are learnt from the pieces made, and the
first rank decides for every rank.

The clock is a fake (each rank's own, set by the test): what is decided does not depend on the
machine's speed. Run serially and on 2 ranks.
"""

import pytest
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.diagnosis.budget import TimeBudget


class _Clocked(TimeBudget):
    """A TimeBudget whose clock reads ``now`` (seconds from its start), set by the test."""

    now = 0.0

    def elapsed(self) -> float:
        return self.now


def _budget(seconds: float | None, now: float) -> _Clocked:
    budget = _Clocked(seconds, 0.0, PETSc.COMM_WORLD)
    budget.now = now
    return budget


def test_a_piece_that_would_end_past_the_budget_is_not_started():
    """100 s budget at 60 s: a 30 s piece starts; a 50 s one is a skipped entry saying what
    was left and what it needed, the budget is not spent (a shorter piece may still fit)."""
    budget = _budget(100.0, 60.0)
    said = []
    assert not budget.stops("short piece", "nothing", said.append, needs=30.0)
    assert budget.skipped == [] and said == []
    assert budget.stops("long piece", "its risk", said.append, needs=50.0,
                        needs_for="a poll and a calibration need")
    [entry] = budget.skipped
    assert entry == {"check": "long piece", "risk": "its risk",
                     "why": "the time budget (100 s, petsoft diagnose --budget) had 40 s left "
                            "at 60 s, less than the ~50 s a poll and a calibration need"}
    assert said == [f"time budget: long piece not started ({entry['why']})"]
    assert budget.summary() == {"seconds": 100.0, "spent": False, "spent_at": None,
                                "left_out": ["long piece"]}
    # ``when`` False: not started, nothing recorded
    assert budget.stops("another", "r", needs=50.0, when=False)
    assert len(budget.skipped) == 1
    # the same 30 s piece still starts: being short for one piece spends nothing
    assert not budget.stops("short piece", "nothing", needs=30.0)


def test_a_spent_budget_stops_whatever_the_needs():
    budget = _budget(100.0, 120.0)
    assert budget.stops("piece", "risk", needs=0.0)
    assert budget.skipped[0]["why"] == ("the time budget (100 s, petsoft diagnose --budget) "
                                        "was spent at 120 s")
    assert budget.summary()["spent"]
    # without ``needs``, as before: only a spent budget stops a piece
    fresh = _budget(100.0, 99.0)
    assert not fresh.stops("piece", "risk")
    assert not fresh.spent()


def test_no_budget_never_stops_a_piece():
    budget = _budget(None, 1e9)
    assert not budget.stops("piece", "risk", needs=1e9)
    assert budget.short(1e9)[0] is False and budget.skipped == []


def test_the_first_ranks_clock_and_needs_decide():
    """Each rank measures its own costs and reads its own clock; the first rank's decide, on
    every rank, with the same words (a rank deciding alone would leave the others waiting in
    the piece's collective runs)."""
    comm = MPI.COMM_WORLD
    first = comm.rank == 0
    # the first rank is short (10 s left, needs 50 s); the others have all the time
    budget = _budget(100.0, 90.0 if first else 0.0)
    assert budget.stops("piece", "risk", needs=50.0 if first else 1.0)
    assert comm.allgather(budget.skipped) == [budget.skipped] * comm.size
    assert "had 10 s left at 90 s, less than the ~50 s" in budget.skipped[0]["why"]
    # the first rank has the time: no rank stops, however short its own clock says it is
    other = _budget(100.0, 0.0 if first else 99.0)
    assert not other.stops("piece", "risk", needs=1.0 if first else 50.0)
    assert comm.allgather(other.skipped) == [[]] * comm.size


def test_costs_are_the_longest_unit_so_far():
    """A kind's cost per unit is the longest recorded (the load varies; the budget is a
    bound), None before any; a record of no units is none."""
    budget = _budget(100.0, 0.0)
    assert budget.cost("poll") is None and budget.made("poll") == 0
    budget.record("poll", 30.0, 3)
    budget.record("poll", 50.0, 4)
    budget.record("poll", 10.0, 0)
    budget.record("other", 100.0)
    assert budget.cost("poll") == pytest.approx(12.5)
    assert budget.cost("other") == pytest.approx(100.0)
    assert (budget.made("poll"), budget.made("other")) == (2, 1)


# -- a round of candidate physics, the final numerics check (issue 40) -------------------------
class _Diag:
    """What the diagnosis' budget decisions read of a Diagnosis: its budget and its log."""

    def __init__(self, budget):
        self.budget, self.said = budget, []

    def tell(self, line: str) -> None:
        self.said.append(line)


def _ev(verdict: str = "inconsistent", chi2: float = 3.0):
    """What round_stops reads of the evidence (records.Evidence): its verdict and noise test."""
    from types import SimpleNamespace

    return SimpleNamespace(verdict=verdict, noise_test=SimpleNamespace(chi2_per_dof=chi2))


def _contender(seconds: float, stopped: str = "", unfinished: str | None = None,
               fitted: bool = True):
    from types import SimpleNamespace

    fit = SimpleNamespace(seconds=seconds, stopped=stopped) if fitted else None
    return SimpleNamespace(fit=fit, unfinished=unfinished), None


def _after_round_1(budget, scoring: float = 40.0, fits=(60.0, 20.0)) -> _Diag:
    """``budget``'s diagnosis after a round 1 whose scoring took ``scoring`` s and whose
    finished fits ``fits`` s (and a fit stopped as unable to win, one cut by the budget, one
    not fitted: none of them says what a finished fit takes)."""
    from petsoft.diagnosis.budget import ROUND_SCORING
    from petsoft.diagnosis.diagnose import record_shortest_fit

    diag = _Diag(budget)
    budget.record(ROUND_SCORING, scoring)
    record_shortest_fit(diag, [_contender(s) for s in fits]
                        + [_contender(1.0, stopped="it cannot win"),
                           _contender(2.0, unfinished="cut short"),
                           _contender(0.0, fitted=False)])
    return diag


def test_round_1_always_starts_inside_the_budget():
    """Nothing foresees round 1 (no round was scored yet): 1 s before the budget it starts;
    a spent budget stops it."""
    from petsoft.diagnosis.diagnose import round_stops

    diag = _Diag(_budget(100.0, 99.0))
    assert not round_stops(diag, 1, _ev())
    assert diag.budget.skipped == [] and diag.said == []
    spent = _Diag(_budget(100.0, 100.0))
    assert round_stops(spent, 1, _ev())
    assert spent.budget.skipped[0]["check"] == "round 1 of candidate physics"


@pytest.mark.parametrize("left, starts", [(59.0, False), (61.0, True)])
def test_a_round_that_cannot_end_inside_the_budget_is_not_started(left, starts):
    """Round 2 is foreseen at round 1's scoring (40 s) and its shortest finished candidate
    fit (20 s, not the 1 s of a fit stopped as unable to win nor the 2 s of one cut short):
    60 s. With 59 s left it is not started (a skipped entry with the round's risk, saying what
    was left and needed; the budget not spent); with 61 s it starts. The other ranks' clocks
    have all the time: the first rank's decides for every rank."""
    from petsoft.diagnosis.diagnose import round_stops

    comm = MPI.COMM_WORLD
    now = 100.0 - left if comm.rank == 0 else 0.0
    diag = _after_round_1(_budget(100.0, now))
    assert round_stops(diag, 2, _ev(chi2=3.0)) is not starts
    assert comm.allgather(diag.budget.skipped) == [diag.budget.skipped] * comm.size
    if starts:
        assert diag.budget.skipped == []
        return
    [entry] = diag.budget.skipped
    assert entry["check"] == "round 2 of candidate physics"
    assert entry["risk"].startswith("the model's verdict is inconsistent (chi2/dof 3)")
    assert entry["why"] == (
        "the time budget (100 s, petsoft diagnose --budget) had 59 s left at 41 s, less than "
        "the ~60 s the round's scoring (~40 s, as the last rounds') and one candidate fit "
        "(~20 s, as the shortest finished fit of the last rounds) need")
    assert not diag.budget.summary()["spent"]


def test_a_round_without_a_finished_fit_is_foreseen_by_its_scoring():
    """A round 1 whose fits were none finished: round 2 needs its scoring at least (40 s)."""
    from petsoft.diagnosis.diagnose import round_stops

    diag = _after_round_1(_budget(100.0, 61.0), fits=())
    assert round_stops(diag, 2, _ev())
    assert "less than the ~40 s the round's scoring (~40 s, as the last rounds') need" in \
        diag.budget.skipped[0]["why"]
    assert not round_stops(_after_round_1(_budget(100.0, 59.0), fits=()), 2, _ev())


@pytest.mark.parametrize("left, starts", [(29.0, False), (31.0, True)])
def test_a_final_numerics_check_that_cannot_end_inside_the_budget_is_not_started(left, starts):
    """The final check is foreseen at the longest refined runs of the numerics checks before
    it (30 s here; a round's scoring of 80 s does not count): with 29 s left it is not started
    (the numerics risk, what was left and needed; the budget not spent), with 31 s it starts.
    The first rank's clock decides for every rank."""
    from petsoft.diagnosis.budget import REFINED_RUNS
    from petsoft.diagnosis.diagnose import final_check_stops
    from petsoft.diagnosis.story import NUMERICS_RISK

    comm = MPI.COMM_WORLD
    now = 100.0 - left if comm.rank == 0 else 0.0
    diag = _after_round_1(_budget(100.0, now), scoring=80.0)
    diag.budget.record(REFINED_RUNS, 12.0)
    diag.budget.record(REFINED_RUNS, 30.0)
    assert final_check_stops(diag) is not starts
    assert comm.allgather(diag.budget.skipped) == [diag.budget.skipped] * comm.size
    if starts:
        assert diag.budget.skipped == []
        return
    [entry] = diag.budget.skipped
    assert entry == {"check": "numerics check of the final model", "risk": NUMERICS_RISK,
                     "why": "the time budget (100 s, petsoft diagnose --budget) had 29 s left "
                            "at 71 s, less than the ~30 s the check's refined runs (as the "
                            "longest of the numerics checks' so far) need"}
    assert not diag.budget.summary()["spent"]


def test_a_final_numerics_check_not_foreseen_starts_until_the_budget_is_spent():
    """No numerics check before it (nothing foresees it): 1 s before the budget it starts."""
    from petsoft.diagnosis.diagnose import final_check_stops

    assert not final_check_stops(_after_round_1(_budget(100.0, 99.0)))
    assert final_check_stops(_after_round_1(_budget(100.0, 100.0)))
