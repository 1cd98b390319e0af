"""Where a diagnosis spends its time: :class:`PhaseClock`.

A diagnosis of a realistic record takes minutes, and what it spends them on (the numerics check,
the score tests, the candidate fits, the final check and report) decides what to make faster.
report.json carries the split (``timings``, formats.md section 3) so that a benchmark reads it
instead of guessing from the log.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

#: the phases of a diagnosis, in the order they first run (report.json ``timings`` keys)
PHASES = ("base_fit", "numerics", "scoring", "fits", "final")


class PhaseClock:
    """Wall time per phase of one diagnosis (seconds, every rank keeps its own).

    Phases do not nest: entering one while another runs charges the time to the inner one only
    (the numerics check that a round runs first is numerics, not scoring), so the phases add up
    to at most the total.
    """

    def __init__(self, start: float | None = None):
        # ``start``: a ``time.perf_counter()`` value the run's log counts from (the total then
        # agrees with the log's stamps)
        self.start = time.perf_counter() if start is None else float(start)
        self.spent = dict.fromkeys(PHASES, 0.0)
        self._running: list[str] = []
        self._since = self.start

    def _charge(self) -> None:
        now = time.perf_counter()
        if self._running:
            self.spent[self._running[-1]] += now - self._since
        self._since = now

    @contextmanager
    def phase(self, name: str):
        """Charge the time spent inside the block to ``name`` (one of :data:`PHASES`)."""
        if name not in self.spent:
            raise ValueError(f"unknown diagnosis phase {name!r}; known: {', '.join(PHASES)}")
        self._charge()
        self._running.append(name)
        try:
            yield
        finally:
            self._charge()
            self._running.pop()

    def switch(self, name: str | None) -> None:
        """Charge the time from now on to ``name`` (None: to no phase) until the next switch,
        beneath any :meth:`phase` block entered meanwhile: for the stretches of a loop that
        follow one another."""
        if name is not None and name not in self.spent:
            raise ValueError(f"unknown diagnosis phase {name!r}; known: {', '.join(PHASES)}")
        self._charge()
        self._running = [name] if name is not None else []

    def seconds(self) -> dict[str, float]:
        """Seconds per phase, ``other`` (outside every phase) and ``total`` so far."""
        self._charge()
        total = time.perf_counter() - self.start
        out = {k: round(v, 3) for k, v in self.spent.items()}
        out["other"] = round(max(total - sum(self.spent.values()), 0.0), 3)
        out["total"] = round(total, 3)
        return out
