"""The diagnosis's phase clock (petsoft.diagnosis.clock): time goes to the innermost phase, the
phases never add up to more than the total, and an unknown phase is refused."""

import time

import pytest

from petsoft.diagnosis.clock import PHASES, PhaseClock


def test_time_is_charged_to_the_innermost_phase_and_adds_up():
    clock = PhaseClock()
    clock.switch("scoring")
    time.sleep(0.05)
    with clock.phase("numerics"):          # beneath the switched phase: numerics only
        time.sleep(0.1)
    time.sleep(0.05)
    clock.switch(None)
    time.sleep(0.03)                        # outside every phase: "other"
    s = clock.seconds()
    assert set(PHASES) | {"other", "total"} == set(s)
    assert 0.09 <= s["numerics"] < 0.09 + 0.08
    assert 0.09 <= s["scoring"] < 0.09 + 0.08   # the two 0.05 s stretches, not the nested 0.1
    assert s["other"] >= 0.025
    assert sum(s[k] for k in PHASES) + s["other"] == pytest.approx(s["total"], abs=2e-3)
    assert s["fits"] == 0.0


def test_an_unknown_phase_is_refused():
    clock = PhaseClock()
    with pytest.raises(ValueError, match="unknown diagnosis phase 'fitting'.*base_fit"):
        with clock.phase("fitting"):
            pass
    with pytest.raises(ValueError, match="unknown diagnosis phase"):
        clock.switch("report")
