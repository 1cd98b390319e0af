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
    assert budget.cost("poll") is None
    budget.record("poll", 30.0, 3)
    budget.record("poll", 50.0, 4)
    budget.record("poll", 10.0, 0)
    budget.record("other", 100.0)
    assert budget.cost("poll") == pytest.approx(12.5)
    assert budget.cost("other") == pytest.approx(100.0)
