"""Progress lines of long runs: times as a person reads them, and what an iteration loop has left.

This module owns the wording and the estimates; the commands print the lines (rank 0 only).
"""

from __future__ import annotations

import math
import time

__all__ = ["IterationPace", "duration"]


def duration(seconds: float) -> str:
    """A time as a person reads it: 42 s, 3.5 min, 1.2 h."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


class IterationPace:
    """Elapsed time, time per iteration and a bound on what is left of an optimiser's run.

    The bound follows the relative decrease of the objective per iteration, d_k = (f_{k-1} -
    f_k) / f_{k-1}, which a converging fit drives below ``ftol`` (where Gauss-Newton stops): when
    it shrinks by a factor q < 1 per iteration, about log(ftol / d_k) / log(q) iterations are
    left. Faster (quadratic) convergence only shortens that, so it is said as "at most"; without
    a shrinking d_k nothing is promised.

    Parameters
    ----------
    ftol : float
        The relative decrease at which the optimiser stops.
    """

    def __init__(self, ftol: float = 1e-10):
        self.ftol = float(ftol)
        self.t0 = time.perf_counter()
        self._f: list[float] = []

    def update(self, iteration: int, f: float) -> str:
        """The progress text after ``iteration`` with objective ``f``."""
        elapsed = time.perf_counter() - self.t0
        self._f.append(float(f))
        text = duration(elapsed)
        if iteration <= 0:
            return text
        per = elapsed / iteration
        text += f", {duration(per)}/iteration"
        d = [(a - b) / a for a, b in zip(self._f[:-1], self._f[1:], strict=True) if a > 0]
        if len(d) >= 2 and d[-1] > 0 and 0 < d[-1] < d[-2]:
            q = d[-1] / d[-2]
            left = max(0, math.ceil(math.log(self.ftol / d[-1]) / math.log(q))) \
                if d[-1] > self.ftol else 0
            text += f", at most ~{left} more ({duration(left * per)}) at this rate"
        return text
