"""When a candidate's fit can no longer win its round (:class:`petsoft.diagnosis.pace.CannotWin`).

The creeping fit is a recorded one: the contact plane's Levenberg-Marquardt objective, iteration
by iteration, on the independent suite's damping+mass bracket (664ef78), whose round's best
finished fit (a quadratic drag) ended at f = 2.596546e4; that fit crept for 1199 s.
"""

import numpy as np
import pytest

from petsoft.calibration.optimize import IterationRecord
from petsoft.diagnosis.pace import BEHIND, CannotWin

CONTACT_PLANE_F = [2.342090e+05, 1.782660e+05, 1.467951e+05, 1.286482e+05, 1.273379e+05,
                   1.272218e+05, 1.271461e+05, 1.270919e+05, 1.270405e+05, 1.270098e+05,
                   1.269468e+05, 1.267473e+05, 1.267415e+05, 1.267233e+05, 1.267102e+05,
                   1.267093e+05, 1.267080e+05, 1.267080e+05, 1.267078e+05, 1.267077e+05]
BEST_F = 2.596546e4


def _first_stop(fs, best_f, max_it=200):
    """The iteration at which CannotWin stops a fit with objectives ``fs`` (None: never)."""
    stop = CannotWin(best_f, "drag.quadratic", max_it=max_it)
    for it, f in enumerate(fs):
        if stop(IterationRecord(it, f, 1.0, np.zeros(2), np.zeros(2), it + 1)):
            return it, stop.why
    return None, stop.why


def test_the_recorded_creeping_fit_is_stopped_once_its_pace_cannot_close_the_gap():
    it, why = _first_stop(CONTACT_PLANE_F, BEST_F)
    # at iteration 6 the largest of the last three decreases (1310) x 194 iterations left still
    # covers the gap (1.01e5); at 7 (116 x 193 = 2.2e4) it does not
    assert it == 7, it
    assert "4.89x drag.quadratic's" in why and "could not have been preferred" in why
    # with 1000 iterations left it would still have had a chance at 7 (116 x 993 > 1.01e5)
    assert _first_stop(CONTACT_PLANE_F, BEST_F, max_it=1000)[0] > 7


def test_a_fit_within_reach_of_the_best_is_never_stopped():
    # the same creep, but the best is within BEHIND x: a close race is decided by the
    # held-out prediction, not here
    assert _first_stop(CONTACT_PLANE_F, CONTACT_PLANE_F[-1] / BEHIND * 1.01)[0] is None
    # no finished fit yet
    assert _first_stop(CONTACT_PLANE_F, np.inf)[0] is None


def test_a_fit_far_behind_but_converging_goes_on_while_it_could_still_catch_up():
    # the excess over a floor below the best halves every iteration: its pace always covers
    # the gap, and it would end below the best
    fast = [1.0e3 + 1.0e6 * 0.5 ** k for k in range(40)]
    assert _first_stop(fast, 2.0e3)[0] is None
    # a slow linear rate (0.99 an iteration) closes the gap in ~690 iterations, more than its
    # 200: it is stopped once even its pace would not do (~100 iterations left), not before
    slow = [1.0e3 + 1.0e6 * 0.99 ** k for k in range(200)]
    it, _ = _first_stop(slow, 2.0e3)
    assert it is not None and 95 <= it <= 110, it
    assert slow[it] - 2.0e3 > slow[it] * (1.0 - 0.99 ** (200 - it))


@pytest.mark.parametrize("window", [1, 2])
def test_the_pace_needs_a_full_window_of_decreases(window):
    # fewer than PACE_WINDOW + 1 records: never stopped, however far behind
    assert _first_stop(CONTACT_PLANE_F[:window + 1], 1.0)[0] is None
