"""Gravity turned at its stated size (``[gravity] tilt_a``, ``tilt_b``; ``gravity.direction``).

1. The map (petsoft.experiment.gravity_tilt): the size kept, the tilt angle atan(|(a, b)|), the
   basis across the stated direction, and its derivatives against central differences (the
   error falls as h^2).
2. The experiment: a tilt read from a file turns the acceleration the model uses, the file's
   form (to_dict) keeps the stated one and the tilt, ``gravity.tilt_a`` is a parameter that
   with_parameters sets; clear errors for a tilt of no gravity and for calibrating the tilt
   with the components.
3. The forward model: the sensitivities of the markers to the tilt against central differences
   of whole runs, and a Taylor test (remainder of order 2), untilted and tilted.
4. diagnose proposes ``gravity.direction`` where gravity is stated and ``gravity`` where it is
   not.
"""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.diagnosis.candidates import build_candidates
from petsoft.errors import ExperimentError
from petsoft.experiment import experiment_from_dict, get_parameter, with_parameters
from petsoft.experiment.gravity_tilt import tilt_basis, tilt_derivatives, tilted

MARKERS = np.array([[0.3, 0.04, 0.04], [0.3, 0.0, 0.0], [0.15, 0.02, 0.04]])
FRAMES = [0.004, 0.008, 0.012]


def _bar(gravity=(0.0, 0.0, -9.81), **extra) -> dict:
    data = {
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [4, 1, 1]}},
        "material": {"model": "corotated", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "gravity": {"acceleration": list(gravity), **extra},
        "damping": {"mass": 0.5},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "time": {"end": 0.012, "step": 2e-3, "integrator": "alpha"},
    }
    return data


# -- 1. the map -----------------------------------------------------------------------------------
@pytest.mark.parametrize("g0", [(0.0, 0.0, -9.81), (1.0, -2.0, 3.0), (-9.81, 0.0, 0.0)])
def test_the_tilt_keeps_the_size_and_turns_by_atan_of_the_tangents(g0):
    size, n, e1, e2 = tilt_basis(g0)
    assert size == pytest.approx(np.linalg.norm(g0))
    basis = np.array([n, e1, e2])
    assert np.allclose(basis @ basis.T, np.eye(3), atol=1e-14)          # orthonormal
    assert np.allclose(np.cross(n, e1), e2)
    assert np.array_equal(tilted(g0, 0.0, 0.0), np.asarray(g0, dtype=float))
    for a, b in ((0.3, 0.0), (0.0, -0.7), (0.5, 0.4)):
        g = tilted(g0, a, b)
        assert np.linalg.norm(g) == pytest.approx(size, rel=1e-14)
        cos = float(g @ n) / size
        assert np.arccos(np.clip(cos, -1, 1)) == pytest.approx(np.arctan(np.hypot(a, b)))
        # towards e1 by a, towards e2 by b (the tangents of the two components' angles)
        s = np.sqrt(1 + a * a + b * b)
        assert float(g @ e1) == pytest.approx(size * a / s, abs=1e-12)
        assert float(g @ e2) == pytest.approx(size * b / s, abs=1e-12)


def test_along_minus_z_the_tilts_are_towards_x_and_minus_y():
    """formats.md's words: for g0 along -z, e1 = x and e2 = -y."""
    _, _, e1, e2 = tilt_basis((0.0, 0.0, -9.81))
    assert np.allclose(e1, [1, 0, 0]) and np.allclose(e2, [0, -1, 0])


@pytest.mark.parametrize("a,b", [(0.0, 0.0), (0.3, -0.2), (-0.8, 0.6)])
def test_tilt_derivatives_against_central_differences(a, b):
    g0 = (0.5, -1.0, -9.7)
    da, db = tilt_derivatives(g0, a, b)
    for d, unit in ((da, np.array([1.0, 0.0])), (db, np.array([0.0, 1.0]))):
        errors = []
        for h in (1e-2, 5e-3, 2.5e-3):
            fd = (tilted(g0, *((a, b) + h * unit)) - tilted(g0, *((a, b) - h * unit))) / (2 * h)
            errors.append(np.linalg.norm(fd - d))
        assert errors[-1] < 1e-4 * np.linalg.norm(g0)
        # a central difference's error falls as h^2: the derivative is the map's own
        assert 3.0 < errors[0] / errors[1] < 5.0 and 3.0 < errors[1] / errors[2] < 5.0


def test_a_zero_gravity_has_no_direction_to_tilt():
    with pytest.raises(ValueError, match="no direction"):
        tilt_basis((0.0, 0.0, 0.0))


# -- 2. the experiment ----------------------------------------------------------------------------
def test_a_tilt_in_the_file_turns_the_acceleration_and_the_file_keeps_both():
    exp = experiment_from_dict(_bar(tilt_a=0.2, tilt_b=-0.1))
    assert np.allclose(exp.gravity.acceleration, tilted((0.0, 0.0, -9.81), 0.2, -0.1))
    assert exp.gravity.as_stated == (0.0, 0.0, -9.81)
    d = exp.to_dict()["gravity"]
    assert d == {"acceleration": [0.0, 0.0, -9.81], "tilt_a": 0.2, "tilt_b": -0.1}
    again = experiment_from_dict(exp.to_dict())
    assert again.gravity == exp.gravity
    # an untilted file writes what it read
    plain = experiment_from_dict(_bar())
    assert plain.to_dict()["gravity"] == {"acceleration": [0.0, 0.0, -9.81]}


def test_the_tilt_is_a_parameter_that_with_parameters_sets():
    exp = experiment_from_dict(_bar())
    assert get_parameter(exp, "gravity.tilt_a") == 0.0
    turned = with_parameters(exp, {"gravity.tilt_a": 0.25, "gravity.tilt_b": 0.5})
    assert get_parameter(turned, "gravity.tilt_b") == 0.5
    assert np.allclose(turned.gravity.acceleration, tilted((0.0, 0.0, -9.81), 0.25, 0.5))
    assert np.linalg.norm(turned.gravity.acceleration) == pytest.approx(9.81)
    # the stated components are still the stated ones (not the turned ones)
    assert get_parameter(turned, "gravity.acceleration.z") == -9.81
    # no gravity: no tilt parameter
    with pytest.raises(ExperimentError, match="gravity.tilt_a"):
        get_parameter(experiment_from_dict(_bar(gravity=(0.0, 0.0, 0.0))), "gravity.tilt_a")


def test_a_tilt_of_no_gravity_is_a_clear_error():
    with pytest.raises(ExperimentError, match=r"tilt_a.*acceleration is zero.*-9\.81"):
        experiment_from_dict(_bar(gravity=(0.0, 0.0, 0.0), tilt_a=0.1))


def test_the_tilt_and_the_components_are_not_calibrated_together():
    data = _bar()
    data["calibrate"] = {"gravity.tilt_a": [-1.0, 1.0], "gravity.acceleration.x": [-1.0, 1.0]}
    with pytest.raises(ExperimentError, match="not both"):
        experiment_from_dict(data)


# -- 3. the forward model -------------------------------------------------------------------------
@pytest.mark.parametrize("tilt", [(0.0, 0.0), (0.3, -0.4)])
def test_marker_sensitivities_to_the_tilt(tilt):
    """d markers / d (tilt_a, tilt_b) of forward sensitivities == central differences of runs
    (1e-5), and the remainder of a step along a direction falls as its square."""
    exp = experiment_from_dict(_bar(tilt_a=tilt[0], tilt_b=tilt[1]))
    names = ["gravity.tilt_a", "gravity.tilt_b", "material.youngs_modulus"]
    fm = ForwardModel(exp, names, lambda s: MarkerObserver(s, MARKERS), FRAMES,
                      comm=PETSc.COMM_WORLD)
    p = fm.p0
    sim0, jac = fm.jacobian(p)
    fd = fm.fd_jacobian(p)
    scale = np.abs(jac).max(axis=(0, 1, 2))
    assert np.all(scale[:2] > 0.0)                  # the tilt moves the markers
    rel = np.abs(fd - jac).max(axis=(0, 1, 2)) / scale
    assert np.all(rel < 1e-5), rel
    d = np.array([0.3, -0.2, 0.1 * p[2]])
    rem = []
    for k in range(4):
        eps = 0.2 * 2.0 ** -k
        rem.append(np.linalg.norm(fm.simulate(p + eps * d) - sim0 - eps * jac @ d))
    orders = np.log2(np.array(rem[:-1]) / np.array(rem[1:]))
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    fm.destroy()


# -- 4. what diagnose proposes --------------------------------------------------------------------
def _proposed(gravity):
    data = _bar(gravity=gravity)
    data["calibrate"] = {"material.youngs_modulus": [1e4, 1e6]}
    cands, skipped = build_candidates(experiment_from_dict(data))
    return {c.physics: c for c in cands}, skipped


def test_diagnose_turns_a_stated_gravity_and_adds_a_missing_one():
    cands, skipped = _proposed((0.0, 0.0, -9.81))
    assert "gravity.direction" in cands and "gravity" not in cands
    assert cands["gravity.direction"].parameters == ["gravity.tilt_a", "gravity.tilt_b"]
    assert cands["gravity.direction"].bounds == [(-1.0, 1.0), (-1.0, 1.0)]
    assert "|g| = 9.81" in skipped["gravity"]
    cands, skipped = _proposed((0.0, 0.0, 0.0))
    assert "gravity" in cands and "gravity.direction" not in cands
    assert cands["gravity"].parameters == [f"gravity.acceleration.{c}" for c in "xyz"]
    assert skipped["gravity.direction"] == "the model states no gravity to turn"
