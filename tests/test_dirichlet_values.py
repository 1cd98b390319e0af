"""Prescribed displacements (petsoft.fem.boundary.DirichletConditions.values): supports that do
not move are evaluated once and handed out as fresh arrays; moving ones at every time asked."""

from __future__ import annotations

import numpy as np

from petsoft.dynamics.system import DynamicSystem
from petsoft.experiment import experiment_from_dict
from petsoft.physics.model import build_model


def _system(displacement):
    exp = experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [6, 1, 1]}},
        "material": {"model": "linear", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "boundary": [{"kind": "prescribed", "where": "x < 1e-9", "displacement": displacement}],
        "time": {"end": 0.01, "step": 0.002, "integrator": "be"},
    }, source="test_dirichlet_values")
    return DynamicSystem(build_model(exp))


def test_a_support_that_does_not_move_is_evaluated_once_and_copied_out():
    s = _system(["0.001*y", "0", "0.002"])
    clamp = s.dmesh.points[:, 0] < 1e-9
    first = s.prescribed(0.0)
    np.testing.assert_allclose(first[clamp, 0], 0.001 * s.dmesh.points[clamp, 1])
    np.testing.assert_allclose(first[clamp, 2], 0.002)
    assert not first[~clamp].any()
    first[:] = 7.0                       # the caller's array is its own
    again = s.prescribed(5.0)
    np.testing.assert_allclose(again[clamp, 2], 0.002)
    assert not again[~clamp].any()
    np.testing.assert_allclose(s.dirichlet.values(0.0, scale=0.5)[clamp, 2], 0.001)
    assert not s.moving_boundary


def test_a_moving_support_is_evaluated_at_every_time():
    s = _system(["0", "0", "0.01*t"])
    clamp = s.dmesh.points[:, 0] < 1e-9
    assert s.moving_boundary
    for t in (0.0, 0.5, 2.0):
        np.testing.assert_allclose(s.prescribed(t)[clamp, 2], 0.01 * t)
