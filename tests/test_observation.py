"""Marker observation: embedding, the operator B and its adjoint on 1 and 2 ranks."""

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.calibration.observation import (
    MarkerObserver,
    ObservationError,
    frame_residual,
    time_interpolation,
)
from petsoft.dynamics.system import DynamicSystem
from petsoft.experiment import experiment_from_dict
from petsoft.io.recording import Recording
from petsoft.mesh.probes import interpolate, locate
from petsoft.physics.model import build_model

SIZE = [0.3, 0.04, 0.04]


@pytest.fixture(scope="module")
def system():
    exp = experiment_from_dict({
        "mesh": {"box": {"size": SIZE, "cells": [6, 2, 2]}},
        "material": {"model": "linear", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "output": {"directory": "unused"},
    })
    model = build_model(exp)
    s = DynamicSystem(model)
    yield s
    s.destroy()


MARKERS = np.array([[0.3, 0.02, 0.04], [0.1234, 0.011, 0.0271], [0.0, 0.0, 0.0],
                    [0.2, 0.04, 0.013]])


def _random_q(system, seed):
    dm = system.dmesh
    field = np.random.default_rng(seed).standard_normal((len(dm.mesh.points), 3))
    return dm.from_file_field(field), field


def test_observe_interpolates_the_displacement(system):
    """B q equals barycentric interpolation of the gathered field (probes.py, independent code),
    the same on every rank."""
    obs = MarkerObserver(system, MARKERS, source="test")
    q, field = _random_q(system, 3)
    got = obs.observe(q)
    mesh = system.dmesh.mesh
    cells, weights = locate(mesh.points, mesh.tets, MARKERS)
    expect = MARKERS + interpolate(field, mesh.tets, cells, weights)
    np.testing.assert_allclose(got, expect, rtol=0, atol=1e-13)
    everywhere = MPI.COMM_WORLD.allgather(got)
    assert all(np.array_equal(g, got) for g in everywhere)
    q.destroy()
    obs.destroy()


def test_adjoint_is_consistent(system):
    """<B q, w> == <q, B^T w> for random q and w (on any number of ranks)."""
    rec = Recording(MARKERS, [f"k{i}" for i in range(len(MARKERS))], np.zeros(1),
                    MARKERS[None].copy(), source="mem.h5")
    obs = MarkerObserver.from_recording(system, rec)
    assert obs.names[0] == "k0" and obs.source == "mem.h5"
    q, _ = _random_q(system, 5)
    w = np.random.default_rng(6).standard_normal((len(MARKERS), 3))
    lhs = float(np.sum((obs.observe(q) - MARKERS) * w))
    bt = obs.adjoint(w)
    rhs = q.dot(bt)
    assert abs(bt.norm()) > 0
    assert abs(lhs - rhs) <= 1e-12 * max(1.0, abs(lhs))
    with pytest.raises(ValueError, match="finite"):
        obs.adjoint(np.full((len(MARKERS), 3), np.nan))
    for v in (q, bt):
        v.destroy()
    obs.destroy()


def test_marker_outside_the_mesh_is_named_with_its_distance(system):
    markers = np.array([[0.1, 0.02, 0.02], [0.35, 0.02, 0.02]])
    with pytest.raises(ObservationError) as err:
        MarkerObserver(system, markers, names=["inside", "tip+5cm"], source="rec.h5")
    msg = str(err.value)
    assert "rec.h5: marker 'tip+5cm' (index 1)" in msg and "0.05 m from its surface" in msg
    # a recording in millimetres is 1000 times too large: the message suggests the units
    with pytest.raises(ObservationError, match="are the recording's units"):
        MarkerObserver(system, 1000 * MARKERS[:2] + 1.0)


class _NodeSystem:
    """A minimal mass-spring-like system: nodes on a line, dofs distributed by PETSc."""

    def __init__(self, n=5):
        self.comm = PETSc.COMM_WORLD
        self.vertex_points = np.column_stack([np.linspace(0, 1, n), np.zeros(n), np.zeros(n)])
        self.n = n

    def create_vec(self):
        return PETSc.Vec().createMPI(3 * self.n, bsize=3, comm=self.comm)

    def vertex_global_dofs(self, ids):
        return 3 * np.asarray(ids)[:, None] + np.arange(3)


def test_markers_on_nodes_of_a_mass_spring_model():
    s = _NodeSystem()
    obs = MarkerObserver(s, s.vertex_points[[4, 1]], names=["tip", "second"])
    q = s.create_vec()
    lo, hi = q.getOwnershipRange()
    full = np.arange(3 * s.n, dtype=float)
    q.getArray()[:] = full[lo:hi]
    np.testing.assert_array_equal(obs.observe(q) - s.vertex_points[[4, 1]],
                                  full.reshape(-1, 3)[[4, 1]])
    w = np.random.default_rng(0).standard_normal((2, 3))
    assert abs(q.dot(obs.adjoint(w)) - np.sum(w * full.reshape(-1, 3)[[4, 1]])) < 1e-12
    obs.destroy()
    with pytest.raises(ObservationError, match=r"marker 'off' \(index 0\).*0.1 m from the "
                                               r"nearest node \(1 at"):
        MarkerObserver(s, [[0.35, 0.0, 0.0]], names=["off"])


def test_frame_residual_leaves_unseen_markers_out():
    pred = np.ones((3, 3))
    meas = np.array([[1.5, 1, 1], [np.nan] * 3, [0, 0, 0.0]])
    r, seen = frame_residual(pred, meas)
    assert seen.tolist() == [True, False, True]
    np.testing.assert_array_equal(r, [[-0.5, 0, 0], [0, 0, 0], [1, 1, 1]])


def test_time_interpolation():
    steps = np.arange(11) * 0.1
    frames = np.array([0.0, 0.05, 0.33, 1.0])
    idx, w = time_interpolation(frames, steps)
    values = np.sin(steps)                      # linear interpolation of a known function
    got = (w * values[idx]).sum(axis=1)
    np.testing.assert_allclose(got, np.interp(frames, steps, values), atol=1e-15)
    assert idx.tolist()[2] == [3, 4] and np.allclose(w[2], [0.7, 0.3])
    with pytest.raises(ObservationError, match=r"frame 1 at t = 1.2 s lies outside the "
                                               r"simulated span \[0, 1\] s"):
        time_interpolation([0.5, 1.2], steps, source="rec")
