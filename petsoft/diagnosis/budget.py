"""How long a diagnosis may run: :class:`TimeBudget`.

A diagnosis of a long record on a fine mesh can take far longer than a person waits: a
tapered cantilever with a hidden payload (issue 40, 711 tets, 1 s at 2 ms) spent 20 minutes
fitting its added mass's sphere and a second round of physics, and gave no report when it was
stopped. The budget bounds that: once it is spent, the diagnosis starts no new piece of work
(a round of candidates, a candidate's fit, a sphere search, a numerics check, a
reconsideration), the report is written from the model reached so far, and every piece left
out is said in the report's ``skipped`` list with what it risks. The budget is checked between
pieces of work, between the polls of a sphere search (which then keeps its best sphere so far),
and inside a round of candidate fits, so a run ends after it by at most a piece under way, or
an iteration of each candidate fit under way (a minute or two on such a case); a sphere's poll
and search are not started unless they are foreseen to end inside it (below).

**A round's candidate fits.** Measured before this rule: the realistic payload case with
``--reduced-trials`` entered its second round inside its 900 s budget, and that round's fits
ran 485 s past it. Now each fit checks the budget on its own group of ranks
(:meth:`TimeBudget.spent` with the group's communicator): before it starts (once the budget is
spent it does not start) and at each iteration boundary, where
:class:`~petsoft.diagnosis.pace.CannotWin` cuts a fit that cannot win (:class:`FitStop`: a fit
under way stops at the iterate reached). Such a candidate is *unfinished*: it is neither added
nor rejected, a fit cut short keeps its chi2 only as an upper bound on what it would have
reached, and it is a ``skipped`` entry (``round N: candidate fit of PHYSICS``) with what it
risks. The round then adds a term only when no unfinished candidate could have been chosen in
its place: a finished fit that passes both tests predicts the held-out data to the noise with
fewer parameters than every unfinished candidate; otherwise it adds nothing and says so (a
``round N's choice`` entry naming the finished fits that passed both tests), and the model is
the one the round started from (:mod:`petsoft.diagnosis.partial_round`).

**A piece that cannot finish.** Checking only whether the budget is spent lets a piece
started just before it ends run its whole length past it: the realistic payload case (issue 40)
started a sphere poll (~35 s) at 881 s and then the search's closing calibration (~84 s), and
ended at 995 s of a 900 s budget. A piece whose cost can be foreseen is therefore not started
when what is left of the budget is less than that cost (:meth:`TimeBudget.stops` with
``needs``); the costs are learnt from the pieces of the same kind already made in this run
(:meth:`TimeBudget.record`, :meth:`TimeBudget.cost`: each rank measures its own, the first
rank's decide). Such a piece is a ``skipped`` entry too, whose ``why`` says what was left and
what the piece needed; the budget is then *not* spent (``spent`` stays false in the report
until the clock reaches it): a shorter piece may still fit. The sphere search
(:mod:`petsoft.diagnosis.geometry`) uses it for its polls and its searches.

**A round of candidate physics, the final numerics check.** A round started inside the
budget used to run its scoring whole (~37 s on the payload case) and its fits' first
iterations past it, and the final numerics check (35-85 s on realistic cases) started
whenever the budget was not spent. Both are now foreseen (:func:`round_needs`,
:func:`final_check_needs`) from the pieces of their kind this run made: a round by round 1's
scoring and its shortest finished candidate fit, the final check by the refined runs of the
numerics checks made before it. Round 1 always starts (unless the budget is spent): nothing
of its kind has been made yet, and without it the diagnosis names no physics at all.

Every rank of the diagnosis must take the same decision at the same point (the pieces are
collective), so the first rank's clock decides and the decision is broadcast; once spent, a
budget stays spent. A candidate fit runs on its own group of ranks, side by side with the
others' (:meth:`~petsoft.diagnosis.placement.Placement.on_groups`), so inside it the group's
first rank decides for the group; once the round's fits are gathered (the same outcomes on
every rank), a fit left unfinished makes the budget spent on every rank
(:meth:`TimeBudget.settle`), at the time that group found it spent.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

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
        #: seconds per unit of the pieces made, by kind (:meth:`record`; this rank's clock)
        self._costs: dict[str, list[float]] = {}

    def elapsed(self) -> float:
        """Seconds since ``start`` on this rank."""
        return time.perf_counter() - self.start

    def spent(self, comm=None) -> bool:
        """Whether the budget is spent (collective on ``comm``: its first rank's clock
        decides). Call it only where every rank of ``comm`` calls it.

        ``comm`` None: the budget's own communicator, whose decision stays (every rank holds
        it). A group of its ranks (a candidate fit's, petsc4py or mpi4py): the group's
        decision, for the group's work only; it leaves the budget unspent until
        :meth:`settle` (the other groups decide at their own points)."""
        if self._spent or self.seconds is None:
            return self._spent
        mpi = _mpi(self.comm if comm is None else comm)
        over = self.elapsed() >= self.seconds
        if mpi.Get_size() > 1:
            over = bool(mpi.bcast(over, root=0))
        if over and comm is None:
            self._spent = True
            self.spent_at = self.elapsed()
        return over

    def settle(self, found_at: float | None) -> None:
        """After work on groups of ranks (collective; ``found_at`` None on every rank or on
        none: the groups' gathered outcomes): when a group found the budget spent
        (``found_at``, seconds from ``start``; None: none did), it is spent on every rank,
        from the first rank's ``found_at`` (a group of all the ranks gives each its own)."""
        if found_at is None or self._spent:
            return
        mpi = _mpi(self.comm)
        self._spent = True
        self.spent_at = float(mpi.bcast(found_at, root=0) if mpi.Get_size() > 1 else found_at)

    def short(self, needs: float) -> tuple[bool, float, float]:
        """Whether a piece of work of ``needs`` seconds, started now, would end past the
        budget (collective on the budget's communicator: call it on every rank at the same
        point). The first rank's clock and ``needs`` decide (each rank may have measured
        its own costs): ``(short, at, needs)``, the first rank's on every rank, ``at`` its
        seconds from ``start``. No budget: never short. It does not spend the budget."""
        if self.seconds is None:
            return False, self.elapsed(), float(needs)
        at = self.elapsed()
        decision = (at + float(needs) > self.seconds, at, float(needs))
        mpi = _mpi(self.comm)
        return tuple(mpi.bcast(decision, root=0)) if mpi.Get_size() > 1 else decision

    def stops(self, check: str, risk: str, tell=None, when: bool = True,
              needs: float | None = None, needs_for: str = "") -> bool:
        """Whether ``check`` is not to start: the budget is spent (collective, as
        :meth:`spent`) or, with ``needs`` (seconds), what is left of it is less than that
        (:meth:`short`). If so and ``when``, ``check`` is recorded as left out with ``risk``
        (:meth:`skip`; ``needs_for`` says in its ``why`` what the seconds are) and, with
        ``tell``, said (``time budget: <check> not started (<why>)``). ``when`` False: the
        piece would not run anyway, so nothing is recorded. ``needs`` must be given on every
        rank or on none (it decides whether the ranks meet in :meth:`short`)."""
        if self.spent():
            why = None
        elif needs is None:
            return False
        else:
            short, at, needs = self.short(needs)
            if not short:
                return False
            why = (f"the time budget ({self.seconds:g} s, petsoft diagnose --budget) had "
                   f"{max(self.seconds - at, 0.0):.0f} s left at {at:.0f} s, less than the "
                   f"~{needs:.0f} s " + (needs_for or "the piece needs"))
        if when:
            entry = self.skip(check, risk, why=why)
            if tell is not None:
                tell(f"time budget: {check} not started ({entry['why']})")
        return True

    def skip(self, check: str, risk: str, detail: str = "", why: str | None = None) -> dict:
        """Record ``check`` as left out for the budget (report.json ``skipped``), with the
        ``risk`` a reader takes by it and, in its ``why``, the ``detail`` of what was done of
        it; returns the entry. ``why`` None: the budget was spent (when); else the ``why``
        itself (a piece left out because it would not have fitted, :meth:`stops`)."""
        if why is None:
            why = (f"the time budget ({self.seconds:g} s, petsoft diagnose --budget) was "
                   f"spent at {self.spent_at:.0f} s")
        entry = {"check": check, "why": why + (f": {detail}" if detail else ""), "risk": risk}
        self.skipped.append(entry)
        return entry

    def record(self, kind: str, seconds: float, units: float = 1.0) -> None:
        """A piece of work of ``kind`` was made: it took ``seconds`` (this rank's clock,
        :meth:`elapsed` differences) for ``units`` of it (e.g. rounds of runs side by side), so
        that :meth:`cost` foresees the next of its kind. Rank-local: no communication."""
        if units > 0:
            self._costs.setdefault(kind, []).append(float(seconds) / float(units))

    def cost(self, kind: str) -> float | None:
        """The seconds a unit of ``kind`` took at most so far on this rank (:meth:`record`:
        the longest, since the machine's load varies and the budget is a bound), None before
        any was made."""
        made = self._costs.get(kind)
        return max(made) if made else None

    def made(self, kind: str) -> int:
        """How many records of ``kind`` :meth:`record` took on this rank (0 before any)."""
        return len(self._costs.get(kind, ()))

    def summary(self) -> dict:
        """report.json ``budget``: the budget, whether and when it was spent, what was left
        out (the checks' names)."""
        return {"seconds": self.seconds, "spent": self._spent,
                "spent_at": None if self.spent_at is None else round(self.spent_at, 1),
                "left_out": [k["check"] for k in self.skipped]}


#: :meth:`TimeBudget.record` kinds: a round's scoring (the misfit's maps and the candidates'
#: scores, one unit a round), a round's shortest finished candidate fit (one a round), and
#: the refined runs of a numerics check (each refinement at the current parameters, one
#: unit a check's runs)
ROUND_SCORING = "round scoring"
CANDIDATE_FIT = "shortest candidate fit"
REFINED_RUNS = "numerics refined runs"


def round_needs(budget: TimeBudget) -> tuple[float | None, str]:
    """(seconds, what they are) a round of candidate physics needs at least, for
    :meth:`TimeBudget.stops`; ``(None, "")`` before a round's scoring was made (round 1: not
    foreseen, module docstring).

    A round is its scoring (:data:`ROUND_SCORING`, as long as the longest so far: the
    scoring runs the same maps and scores on a model a term larger) and its candidate fits,
    costed at the *shortest* finished candidate fit of the rounds so far
    (:data:`CANDIDATE_FIT`). The shortest, not the longest: the fits run side by side and the
    budget cuts each at its next iteration (:class:`FitStop`), so the least a round must have
    to add a term is one finished fit of the simplest kind, the one
    :func:`~petsoft.diagnosis.selection.fit_simplest_first` makes first; foreseeing the longest
    would leave out rounds whose quick fit could name the physics. The cost is a bound from
    below: a round that starts may still run its longer fits to the budget."""
    scoring = budget.cost(ROUND_SCORING)
    if scoring is None:
        return None, ""
    fit = budget.cost(CANDIDATE_FIT)
    words = f"the round's scoring (~{scoring:.0f} s, as the last rounds')"
    if fit is None:
        return scoring, words + " needs"
    return scoring + fit, (words + f" and one candidate fit (~{fit:.0f} s, as the shortest "
                           "finished fit of the last rounds) need")


def final_check_needs(budget: TimeBudget) -> tuple[float | None, str]:
    """(seconds, what they are) the numerics check of the final model needs, for
    :meth:`TimeBudget.stops`; ``(None, "")`` when no numerics check ran before (nothing
    foresees it: it starts unless the budget is spent).

    The final check simulates the final model once under each refinement, at its parameters
    (no refit): the runs a numerics check makes first (:data:`REFINED_RUNS`), at the longest
    they took (the later checks' models are the finer, so the nearer)."""
    runs = budget.cost(REFINED_RUNS)
    if runs is None:
        return None, ""
    return runs, ("the check's refined runs (as the longest of the numerics checks' so far) "
                  "need")


@dataclass
class Unfinished:
    """A candidate fit the budget left unfinished (what its group returns in place of the
    fit): ``why`` (not started, or :attr:`FitStop.why`), and when its group found the budget
    spent (``found_at``, seconds from the budget's start)."""

    why: str
    found_at: float


class FitStop:
    """A candidate fit's ``stop`` (:func:`petsoft.calibration.optimize.minimize`): the fit's
    own ``then`` (a :class:`~petsoft.diagnosis.pace.CannotWin`) and the time budget, checked
    on the fit's group of ranks at every iteration (module docstring). Called at the same
    iterations on every rank of ``comm`` (the records are identical there), as the budget's
    check must be.

    Parameters
    ----------
    budget : TimeBudget
    comm : petsc4py or mpi4py communicator
        The fit's ranks.
    then : callable(IterationRecord) -> bool, optional
        The fit's other stop; decides first (a fit it ends is finished: it could not win).
    """

    def __init__(self, budget: TimeBudget, comm, then=None):
        self.budget, self.comm, self.then = budget, comm, then
        self.why = ""
        #: (iteration, chi2 there, seconds from the budget's start) where the budget cut the
        #: fit; None while it has not
        self.cut: tuple[int, float, float] | None = None

    def __call__(self, rec) -> bool:
        if self.then is not None and self.then(rec):
            self.why = self.then.why
            return True
        if not self.budget.spent(self.comm):
            return False
        self.cut = (int(rec.iteration), 2.0 * float(rec.f), self.budget.elapsed())
        self.why = (f"cut short by the time budget at iteration {rec.iteration}: its chi2 "
                    f"{2.0 * rec.f:.6g} there only bounds a converged fit's from above")
        return True


def _mpi(comm):
    """The mpi4py communicator of a petsc4py or mpi4py one."""
    return comm.tompi4py() if hasattr(comm, "tompi4py") else comm
