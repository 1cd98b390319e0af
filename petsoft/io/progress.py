"""Progress lines of long runs: times as a person reads them, and what an iteration loop has left.

This module owns the wording and the estimates; the commands print the lines (rank 0 only).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from contextlib import contextmanager

__all__ = ["IterationPace", "beat", "doing", "duration", "heartbeat", "touch"]


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


class _Heart:
    """Who listens to :func:`beat` (None: nobody), how often, when the last line was said, and
    the labels of what is being done (innermost last)."""

    def __init__(self):
        self.say: Callable[[str], None] | None = None
        self.interval = 10.0
        self.last = 0.0
        self.labels: list[str] = []


_HEART = _Heart()


@contextmanager
def heartbeat(say: Callable[[str], None], interval: float = 10.0):
    """Inside the block, the long loops that call :func:`beat` (every time step of a forward
    run, of its adjoint and of its sensitivities) say where they are through ``say`` once
    ``interval`` seconds passed without a line (:func:`touch` marks a line said elsewhere), so
    that a long run is never silent for longer. Nested blocks: the innermost listens."""
    before = (_HEART.say, _HEART.interval, _HEART.last)
    _HEART.say, _HEART.interval, _HEART.last = say, float(interval), time.perf_counter()
    try:
        yield
    finally:
        _HEART.say, _HEART.interval, _HEART.last = before


def touch() -> None:
    """A progress line was just said: the next beat waits a whole interval."""
    _HEART.last = time.perf_counter()


@contextmanager
def doing(label: str):
    """Name what the beats inside the block belong to (e.g. ``"candidate drag.linear"``)."""
    _HEART.labels.append(label)
    try:
        yield
    finally:
        _HEART.labels.pop()


def beat(what: str | Callable[[], str]) -> None:
    """Say ``what`` (a text, or a function making it: called only when said) if a
    :func:`heartbeat` listens and its interval has passed since the last line; costs a clock
    read otherwise. Local: no communication, so any rank may call it at any time."""
    if _HEART.say is None:
        return
    now = time.perf_counter()
    if now - _HEART.last < _HEART.interval:
        return
    _HEART.last = now
    text = what() if callable(what) else what
    _HEART.say(f"{_HEART.labels[-1]}: {text}" if _HEART.labels else text)
