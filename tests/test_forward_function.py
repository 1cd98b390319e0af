"""The forward model is a function of the parameters (issue 38, item 4): what ``simulate``,
``jacobian`` and ``gradient`` return at p depends on p alone, not on the values earlier calls
set in its system (the model sets them per call; the in-place ``set_parameters`` is its
system's, not its interface). Checked for be, si and alpha by calling at p0, then at another
p1 through every entry point, then at p0 again: the answers at p0 are the same to the bit.
"""

from __future__ import annotations

import numpy as np
import pytest

from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.experiment import experiment_from_dict

NAMES = ["material.youngs_modulus", "damping.mass", "damping.stiffness",
         "gravity.acceleration.z"]
MARKERS = np.array([[0.3, 0.04, 0.04], [0.15, 0.02, 0.04]])


def _forward(method):
    exp = experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [4, 1, 1]}},
        "material": {"model": "corotated", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "damping": {"mass": 0.5, "stiffness": 0.002},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"displacement": ["0", "0", "0.3*x**2"]},
        "time": {"end": 0.01, "step": 2e-3, "integrator": method}})
    return ForwardModel(exp, NAMES, lambda s: MarkerObserver(s, MARKERS), [0.004, 0.01])


@pytest.mark.parametrize("method", ["be", "si", "alpha"])
def test_answers_at_p_do_not_depend_on_earlier_calls(method):
    fm = _forward(method)
    p0 = fm.p0.copy()
    p1 = p0 * np.array([1.3, 2.0, 0.5, 1.1])

    def dphi(sim):
        return 0.5 * float(np.sum(sim * sim)), sim

    first = fm.simulate(p0), fm.jacobian(p0), fm.gradient(p0, dphi)
    fm.simulate(p1)
    fm.jacobian(p1)
    fm.gradient(p1, dphi)
    again = fm.simulate(p0), fm.jacobian(p0), fm.gradient(p0, dphi)
    np.testing.assert_array_equal(first[0], again[0])
    for a, b in zip(first[1], again[1], strict=True):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(first[2], again[2], strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(fm.simulate(p1), first[0])
    fm.destroy()
