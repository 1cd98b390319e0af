"""Binomial checkpointing of the adjoint sweep (petsoft.calibration.checkpointing).

1. The schedule on integers (a state is its step number): every adjoint step n = N-1, ..., 0 is
   taken once, in order, with the states n and n+1; the states held at once never exceed the
   snapshots + 2; no step is recomputed more than r + 1 times, r the repetition number (the least
   r with C(s + r, s) >= N); the first run's spine snapshots are used, not recomputed.
2. The forward model's adjoint with 3 snapshots (be, si, alpha; corotated bar, 20 steps, also
   observed accelerations and a static initial state) gives the gradient of the stored-trajectory
   adjoint to 1e-12 relative, with fewer states held and recomputed steps counted.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_sensitivity import MARKERS, NAMES, _bar, _misfit, light_forward_solver  # noqa: F401

from petsoft.calibration.checkpointing import (
    SweepStats,
    beta,
    repetitions,
    reverse_sweep,
    spine,
)
from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver


def _sweep(steps, snapshots, use_spine=True):
    """Run the schedule on integers; returns (adjoint steps taken, advances, stats)."""
    taken, advances, live = [], [], set()

    def advance(state, n0, n1):
        assert state == n0 and state in live
        advances.append((n0, n1))
        live.add(n1)
        return n1

    def adjoint_step(n, s0, s1):
        assert (s0, s1) == (n, n + 1) and {s0, s1} <= live
        taken.append(n)

    def free(state):
        live.discard(state)

    stored = {m: m for m in spine(steps, snapshots)} if use_spine else {}
    live.update(stored)
    live.add(0)
    stats = SweepStats()
    stats.hold(len(stored) + 1)
    reverse_sweep(steps, snapshots, 0, stored, advance, adjoint_step, free, stats)
    return taken, advances, stats


@pytest.mark.parametrize("steps,snapshots", [(1, 2), (2, 2), (7, 2), (10, 3), (55, 3), (100, 4),
                                             (1000, 10), (30, 40)])
def test_schedule_reverses_every_step_within_its_bounds(steps, snapshots):
    taken, advances, stats = _sweep(steps, snapshots)
    assert taken == list(range(steps - 1, -1, -1))
    assert stats.peak_states <= snapshots + 2
    r = repetitions(steps, max(snapshots - 1, 1))
    # the first run took every step once; the sweep at most r + 1 more times each (r to place
    # the snapshots, one to reach the end state of the step being reversed, as revolve's
    # "youturn" does)
    assert stats.recomputed_steps <= (r + 1) * steps
    assert stats.recomputed_steps == sum(n1 - n0 for n0, n1 in advances)
    assert stats.held == 1              # everything freed but state 0 (the caller's)


def test_binomial_numbers_and_spine():
    assert [beta(2, r) for r in range(4)] == [1, 3, 6, 10]
    assert repetitions(10, 2) == 3 and repetitions(11, 2) == 4 and repetitions(1, 1) == 0
    assert spine(10, 1) == []
    sp = spine(1000, 5)
    assert len(sp) == 4 and sp == sorted(sp) and 0 < sp[0] and sp[-1] < 1000
    # using the first run's snapshots saves exactly the steps up to the last of them
    _, _, with_spine = _sweep(1000, 5)
    _, _, without = _sweep(1000, 5, use_spine=False)
    assert without.recomputed_steps - with_spine.recomputed_steps == sp[-1]


def test_schedule_with_many_snapshots_recomputes_little_and_with_few_more():
    _, _, many = _sweep(200, 50)
    _, _, few = _sweep(200, 3)
    assert many.recomputed_steps < few.recomputed_steps
    assert few.peak_states < many.peak_states


CASES = [("be", "position", False), ("si", "position", False), ("alpha", "position", False),
         ("be", "acceleration", False), ("alpha", "position", True)]


@pytest.mark.usefixtures("light_forward_solver")
@pytest.mark.parametrize("method,observe,static", CASES)
def test_checkpointed_adjoint_equals_the_stored_one(method, observe, static):
    extra = {"time": {"end": 0.04, "step": 2e-3, "integrator": method}}
    if static:
        extra["initial"] = {"from": "static"}
    exp = _bar("corotated", method, **extra)
    frames = [0.0031, 0.017, 0.029, 0.04]
    results = {}
    for snaps in (None, 3):
        fm = ForwardModel(exp, NAMES[:3], lambda s: MarkerObserver(s, MARKERS), frames,
                          observe=observe, checkpoints=snaps)
        sim = fm.simulate(fm.p0)
        target = sim + 1e-3 * np.random.default_rng(2).standard_normal(sim.shape)
        value, grad = fm.gradient(fm.p0, _misfit(target))
        results[snaps] = value, grad, dict(fm.stats["adjoint"])
        fm.destroy()
    (v0, g0, s0), (v1, g1, s1) = results[None], results[3]
    assert s0["steps"] == s1["steps"] == 20
    assert s0["snapshots"] is None and s0["recomputed_steps"] == 0 and s0["peak_states"] == 21
    assert s1["snapshots"] == 3 and s1["peak_states"] <= 5
    assert 20 <= s1["recomputed_steps"] <= (repetitions(20, 2) + 1) * 20
    assert v1 == pytest.approx(v0, rel=1e-14)
    np.testing.assert_allclose(g1, g0, rtol=1e-12, atol=1e-12 * np.abs(g0).max())
