"""How long a diagnosis may run: :class:`TimeBudget`.

A diagnosis of a long record on a fine mesh can take far longer than a person waits: a
tapered cantilever with a hidden payload (issue 40, 711 tets, 1 s at 2 ms) spent 20 minutes
fitting its added mass's sphere and a second round of physics, and gave no report when it was
stopped. The budget bounds that: once it is spent, the diagnosis starts no new piece of work
(a round of candidates, a sphere search, a numerics check, a reconsideration); the work under
way is finished, the report is written from the model reached so far, and every piece left out
is said in the report's ``skipped`` list with what it risks. The budget is checked between
pieces of work, and between the polls of a sphere search (which then keeps its best sphere so
far), so a run ends after it by at most one piece: a round's candidate fits, or a poll and the
calibration that ends a search (a minute or two on such a case).

Every rank of the diagnosis must take the same decision at the same point (the pieces are
collective), so the first rank's clock decides and the decision is broadcast; once spent, a
budget stays spent.
"""

from __future__ import annotations

import time

#: The default budget of ``petsoft diagnose`` (seconds): issue 40's bound for its largest
#: realistic case (a 5,000-tet mesh), beyond which a person wants a report more than more work.
DEFAULT_BUDGET = 900.0


class TimeBudget:
    """The wall time a diagnosis may spend before it starts no new work.

    Parameters
    ----------
    seconds : float or None
        The budget from ``start`` (> 0); None: no budget (every piece of work is done).
    start : float
        A ``time.perf_counter()`` value the budget counts from (the run's log clock).
    comm : PETSc.Comm
        The diagnosis' communicator: :meth:`spent` is collective on it.
    """

    def __init__(self, seconds: float | None, start: float, comm):
        if seconds is not None and not (float(seconds) > 0.0 and float(seconds) < float("inf")):
            raise ValueError(f"a time budget is a number of seconds > 0 (or None for no "
                             f"budget), got {seconds!r}")
        self.seconds = None if seconds is None else float(seconds)
        self.start = float(start)
        self.comm = comm
        self._spent = False
        #: when the budget was found spent (seconds from ``start``), None while it is not
        self.spent_at: float | None = None
        #: report.json ``skipped`` entries of the work left out
        self.skipped: list[dict] = []

    def elapsed(self) -> float:
        """Seconds since ``start`` on this rank."""
        return time.perf_counter() - self.start

    def spent(self) -> bool:
        """Whether the budget is spent (collective on ``comm``: the first rank's clock
        decides). Call it only where every rank of ``comm`` calls it."""
        if self._spent or self.seconds is None:
            return self._spent
        over = self.elapsed() >= self.seconds
        if self.comm.getSize() > 1:
            over = bool(self.comm.tompi4py().bcast(over, root=0))
        if over:
            self._spent = True
            self.spent_at = self.elapsed()
        return self._spent

    def stops(self, check: str, risk: str, tell=None, when: bool = True) -> bool:
        """Whether the budget is spent (collective, as :meth:`spent`); if so and ``when``,
        ``check`` is recorded as left out with ``risk`` (:meth:`skip`) and, with ``tell``, said
        (``time budget: <check> not started (<why>)``). ``when`` False: the piece would not
        run anyway, so nothing is recorded."""
        if not self.spent():
            return False
        if when:
            entry = self.skip(check, risk)
            if tell is not None:
                tell(f"time budget: {check} not started ({entry['why']})")
        return True

    def skip(self, check: str, risk: str) -> dict:
        """Record ``check`` as left out for the budget (report.json ``skipped``), with the
        ``risk`` a reader takes by it; returns the entry."""
        entry = {"check": check,
                 "why": f"the time budget ({self.seconds:g} s, petsoft diagnose --budget) was "
                        f"spent at {self.spent_at:.0f} s",
                 "risk": risk}
        self.skipped.append(entry)
        return entry

    def summary(self) -> dict:
        """report.json ``budget``: the budget, whether and when it was spent, what was left
        out (the checks' names)."""
        return {"seconds": self.seconds, "spent": self._spent,
                "spent_at": None if self.spent_at is None else round(self.spent_at, 1),
                "left_out": [k["check"] for k in self.skipped]}
