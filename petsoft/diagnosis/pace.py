"""When a candidate's fit can no longer win its round: :class:`CannotWin`.

A round fits its shortlisted candidates one after another on each group of ranks, and the one
that predicts the held-out window best is added. A fit that creeps -- a contact plane's kinked
misfit moved by 0.004 of chi2 over its last 14 iterations at five times the round's best chi2
(the independent suite's damping+mass bracket: 1199 s of a 3000 s budget) -- cannot become
the best however long it runs; it is stopped and reported as such.
"""

from __future__ import annotations

from petsoft.calibration.optimize import LM_MAX_IT, IterationRecord

#: the last iterations whose decreases of the misfit give a fit's pace
PACE_WINDOW = 3
#: a fit is stopped only while its misfit exceeds this multiple of the round's best (chi2
#: twice the best's: decisively worse on any record, whatever it predicts)
BEHIND = 2.0


class CannotWin:
    """A candidate fit's ``stop`` (:func:`petsoft.calibration.optimize.minimize`).

    True once the fit's objective f (half its chi2) exceeds :data:`BEHIND` times ``best_f``,
    the best finished fit's of the round, and, at the largest decrease of its last
    :data:`PACE_WINDOW` iterations, the iterations it has left could not bring it down to
    ``best_f`` (Levenberg-Marquardt's decreases shrink as it converges, so that pace is
    generous). Every rank of the fit's group decides the same: the records are identical.

    Parameters
    ----------
    best_f : float
        Half the chi2 of the best fit finished in the round so far (``inf``: none yet).
    best_name : str
        Whose it is (for :attr:`why`).
    max_it : int
        The fit's iteration limit.
    """

    def __init__(self, best_f: float, best_name: str = "", max_it: int = LM_MAX_IT):
        self.best_f = float(best_f)
        self.best_name = best_name
        self.max_it = int(max_it)
        self.f: list[float] = []
        self.why = ""

    def __call__(self, rec: IterationRecord) -> bool:
        self.f.append(rec.f)
        if len(self.f) <= PACE_WINDOW or not rec.f > BEHIND * self.best_f:
            return False
        recent = self.f[-PACE_WINDOW - 1:]
        pace = max(a - b for a, b in zip(recent[:-1], recent[1:], strict=True))
        left = max(self.max_it - rec.iteration, 0)
        gap = rec.f - self.best_f
        if pace * left >= gap:
            return False
        self.why = (f"stopped at iteration {rec.iteration}: its chi2 {2.0 * rec.f:.6g} is "
                    f"{rec.f / self.best_f:.3g}x {self.best_name}'s {2.0 * self.best_f:.6g}, "
                    f"and at the pace of its last {PACE_WINDOW} iterations (chi2 down by at "
                    f"most {2.0 * pace:.3g} an iteration) its {left} remaining iterations "
                    "could not close the gap: it could not have been preferred")
        return True
