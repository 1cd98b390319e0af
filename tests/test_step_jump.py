"""The numerics check refits at a quarter of the step where half would still leave an error
(issue 40, item 3: "the step/2 test only where the time step can matter").

:func:`petsoft.diagnosis.numerics.step_jump` decides from the halved step's run at the current
parameters (Richardson: a scheme of order p leaves 1 / (2^p - 1) of that change at half the
step); :func:`petsoft.diagnosis.numerics.quartered_run` extrapolates the quarter step's run.
Both against trajectories whose step error is exactly C h^p. The refit itself is checked
against a calibration in tests/test_chord_refit.py.
"""

import numpy as np
import pytest

from petsoft.calibration.refinement import STEP_HALVED, STEP_QUARTERED, refinement
from petsoft.diagnosis.numerics import ESTIMATE_FINAL_BELOW, quartered_run, step_jump
from petsoft.experiment import experiment_from_dict

SIGMA = 1e-4


def _experiment(integrator="alpha", step=0.002):
    return experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [6, 1, 1]}},
        "material": {"model": "linear", "youngs_modulus": 2e7, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "time": {"end": 0.1, "step": step, "integrator": integrator}}, source="test")


@pytest.mark.parametrize("integrator, order", [("alpha", 2), ("midpoint", 2), ("be", 1),
                                               ("si", 1)])
def test_the_jump_is_where_half_the_step_leaves_the_final_checks_threshold(integrator, order):
    exp = _experiment(integrator)
    # half the step leaves 1 / (2^p - 1) of the halving's change (Richardson)
    at = ESTIMATE_FINAL_BELOW * SIGMA * (2 ** order - 1)
    assert step_jump(exp, integrator, 1.001 * at, SIGMA)
    assert not step_jump(exp, integrator, 0.999 * at, SIGMA)
    # the integrator given wins over the experiment's (diagnose's --integrator)
    other = "be" if order == 2 else "alpha"
    assert step_jump(_experiment(other), integrator, 1.001 * at, SIGMA)


def test_no_jump_with_colliders():
    """A penalty contact's default stiffness follows the step (k = 4 m / h^2): halving the step
    changes the model, and Richardson's h^p does not hold."""
    plain = _experiment()
    data = plain.to_dict()
    data["collider"] = [{"kind": "plane", "point": [0.0, 0.0, -0.05], "normal": [0.0, 0.0, 1.0]}]
    touching = experiment_from_dict(data, source="test")
    assert touching.colliders
    large = 100.0 * SIGMA
    assert step_jump(plain, "alpha", large, SIGMA)
    assert not step_jump(touching, "alpha", large, SIGMA)


@pytest.mark.parametrize("order", [1, 2])
def test_the_quarter_steps_run_is_richardsons_extrapolation(order):
    rng = np.random.default_rng(order)
    exact = rng.normal(size=(40, 6, 3))
    error = rng.normal(size=exact.shape)
    h = 0.004

    def run(step):
        return exact + error * step ** order

    exp = _experiment("alpha" if order == 2 else "be", step=h)
    est = quartered_run(exp, None, run(h), run(h / 2))
    assert np.allclose(est, run(h / 4), rtol=0, atol=1e-14)
    # not the halved run, and not the limit
    assert not np.allclose(est, run(h / 2), atol=1e-9)
    assert not np.allclose(est, exact, atol=1e-9)


def test_the_quarter_step_refinement():
    exp = _experiment(step=0.002)
    assert refinement("step/4") is STEP_QUARTERED
    assert STEP_QUARTERED.kind == "step"
    assert STEP_QUARTERED.make(exp).time.step == pytest.approx(0.0005)
    assert STEP_QUARTERED.describe(exp) == "step 0.002 s -> 0.0005 s"
    # Richardson over a ratio of 4 in the step: k = 16 for a second-order scheme
    assert STEP_QUARTERED.error_factors(exp, "alpha") == pytest.approx((16 / 15, 1 / 15))
    assert STEP_QUARTERED.error_factors(exp, "be") == pytest.approx((4 / 3, 1 / 3))
    assert STEP_HALVED.error_factors(exp, "alpha") == pytest.approx((4 / 3, 1 / 3))
