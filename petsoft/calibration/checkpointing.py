"""Binomial checkpointing (revolve) for the discrete adjoint's backward sweep.

The adjoint of step n -> n+1 needs the forward states n and n+1, visited for n = N-1, ..., 0.
Keeping all N+1 states costs (N+1) state vectors; with ``s`` snapshots the states are recomputed
from the nearest stored one instead. Griewank's binomial schedule is optimal: with ``s`` snapshots
and ``r`` repetitions (no forward step is taken more than ``r + 1`` times in all) it reverses up to

    beta(s, r) = (s + r)! / (s! r!)

steps, and it places the first snapshot of a range of ``l`` steps ``min(beta(s, r - 1), l - 1)``
steps in (the left part then has ``r - 1`` repetitions left, the right part one snapshot fewer:
beta(s, r) = beta(s, r - 1) + beta(s - 1, r)).

This module knows nothing of PETSc or of the integrators: :func:`reverse_sweep` drives three
callbacks (advance a state, take one adjoint step, free a state), so the schedule is tested on
integers (``tests/test_checkpointing.py``) and used on vectors by
:class:`~petsoft.calibration.forward.ForwardModel`.

Reference: A. Griewank and A. Walther, "Algorithm 799: revolve", ACM TOMS 26 (2000) 19-45.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from math import comb

__all__ = ["SweepStats", "beta", "repetitions", "reverse_sweep", "spine"]


def beta(snapshots: int, reps: int) -> int:
    """How many steps ``snapshots`` snapshots reverse with ``reps`` repetitions: C(s + r, s)."""
    if snapshots < 0 or reps < 0:
        return 0
    return comb(snapshots + reps, snapshots)


def repetitions(steps: int, snapshots: int) -> int:
    """The least r with beta(snapshots, r) >= steps (the repetition number of the schedule)."""
    if steps <= 1:
        return 0
    if snapshots < 1:
        raise ValueError("reversing more than one step needs at least one snapshot")
    r = 0
    while beta(snapshots, r) < steps:
        r += 1
    return r


def _split(steps: int, snapshots: int) -> int:
    """Where (steps from the range's start) the next snapshot of a binomial schedule goes."""
    r = repetitions(steps, snapshots)
    return max(1, min(beta(snapshots, r - 1), steps - 1))


def spine(steps: int, snapshots: int) -> list[int]:
    """The steps at which the first forward run stores its snapshots (besides step 0).

    They are the schedule's right-most chain: the range [0, N) is split at m1, [m1, N) with one
    snapshot fewer at m2, ... . Storing them while the objective's forward run passes by saves
    recomputing them in the sweep.
    """
    out, lo, free = [], 0, snapshots - 1      # one snapshot holds state 0
    while steps - lo > 1 and free > 0:
        lo += _split(steps - lo, free)
        out.append(lo)
        free -= 1
    return out


@dataclass
class SweepStats:
    """What a sweep cost: forward steps recomputed, and the most states held at once."""

    recomputed_steps: int = 0
    peak_states: int = 0
    held: int = field(default=0, repr=False)

    def hold(self, k: int = 1) -> None:
        self.held += k
        self.peak_states = max(self.peak_states, self.held)

    def release(self, k: int = 1) -> None:
        self.held -= k


def reverse_sweep(steps: int, snapshots: int, start, stored: dict,
                  advance: Callable, adjoint_step: Callable, free: Callable,
                  stats: SweepStats | None = None) -> SweepStats:
    """Call ``adjoint_step(n, state_n, state_n1)`` for n = steps-1, ..., 0 (binomial schedule).

    Parameters
    ----------
    steps : int
        N, the number of forward steps.
    snapshots : int
        States the schedule may hold at once besides the two of the step being reversed (>= 1;
        the state 0 snapshot counts).
    start :
        State 0 (the caller keeps and frees it).
    stored : dict[int, state]
        States the first forward run kept (at :func:`spine` positions); taken over (freed) here.
    advance : callable(state, n0, n1) -> state
        A new state n1 computed from ``state`` at n0 (n1 > n0), ``state`` left intact.
    adjoint_step : callable(n, state_n, state_n1)
    free : callable(state)
    stats : SweepStats, optional
        Accumulates into this (e.g. the first run's holdings already counted).
    """
    stats = stats or SweepStats()
    if steps < 1:
        return stats

    def reach(state, n0: int, n1: int):
        if n1 in stored:
            return stored.pop(n1)
        stats.recomputed_steps += n1 - n0
        stats.hold()
        return advance(state, n0, n1)

    def drop(state) -> None:
        stats.release()
        free(state)

    def reverse(lo: int, hi: int, free_snaps: int, state_lo) -> None:
        length = hi - lo
        if length == 1:
            nxt = reach(state_lo, lo, hi)
            adjoint_step(lo, state_lo, nxt)
            drop(nxt)
            return
        if free_snaps == 0:
            # no snapshot left: recompute each step's start from lo (quadratic, as revolve does
            # only when told to use no snapshots)
            for n in range(hi - 1, lo - 1, -1):
                mid = reach(state_lo, lo, n) if n > lo else state_lo
                nxt = reach(mid, n, n + 1)
                adjoint_step(n, mid, nxt)
                drop(nxt)
                if mid is not state_lo:
                    drop(mid)
            return
        m = lo + _split(length, free_snaps)
        state_m = reach(state_lo, lo, m)
        reverse(m, hi, free_snaps - 1, state_m)
        drop(state_m)
        reverse(lo, m, free_snaps, state_lo)

    reverse(0, steps, max(snapshots - 1, 0), start)
    for leftover in stored.values():   # (a caller that stored more than the spine)
        drop(leftover)
    stored.clear()
    return stats
