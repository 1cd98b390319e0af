"""Supports driven by a measured input series from a recording (formats.md /inputs/<name>)."""

from pathlib import Path

import h5py
import numpy as np
import pytest
from mpi4py import MPI

from petsoft.dynamics.simulate import Simulation
from petsoft.errors import ExperimentError
from petsoft.experiment import experiment_from_dict
from petsoft.physics.model import build_model


def _experiment(support, end=0.05):
    return experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [6, 1, 1]}},
        "material": {"model": "neohookean", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "boundary": [dict(kind="prescribed", where="x < 1e-9", **support)],
        "time": {"end": end, "step": 1e-3, "integrator": "midpoint"},
        "output": {"directory": "unused"},
    })


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    comm = MPI.COMM_WORLD
    path = Path(comm.bcast(str(tmp_path_factory.mktemp("rec") / "shaker.h5")
                          if comm.rank == 0 else None))
    if comm.rank == 0:
        t = np.arange(0, 101) * 1e-3                    # sampled at the steps, up to 0.1 s
        value = np.column_stack([0 * t, 0.002 * np.sin(50 * t), 0.01 * np.sin(20 * t)])
        with h5py.File(path, "w") as f:
            f.attrs["format"], f.attrs["version"] = "petsoft-recording", 1
            f["inputs/shaker/time"] = t
            f["inputs/shaker/value"] = value
    comm.Barrier()
    return path


def _final(exp, recording=None):
    model = build_model(exp, recording=recording)
    sim = Simulation(model, exp)
    result = sim.run()
    q = MPI.COMM_WORLD.bcast(model.dmesh.gather_global(result.q))
    sim.destroy()
    return q


def test_series_drives_the_support_like_the_same_expression(recording):
    """A shaker recorded at the step times moves the clamp exactly as the expression it samples
    (to the interpolation at times one ulp off a sample)."""
    q_series = _final(_experiment({"series": "inputs/shaker"}), recording)
    q_expr = _final(_experiment({"displacement": ["0", "0.002*sin(50*t)", "0.01*sin(20*t)"]}))
    assert np.abs(q_series).max() > 1e-3
    assert np.abs(q_series - q_expr).max() <= 1e-12 * np.abs(q_expr).max()


def test_series_errors_are_clear(recording):
    with pytest.raises(ExperimentError, match="needs its recording"):
        build_model(_experiment({"series": "inputs/shaker"}))
    with pytest.raises(ExperimentError, match="no measured input 'inputs/table'.*inputs/shaker"):
        build_model(_experiment({"series": "inputs/table"}), recording=recording)
    exp = _experiment({"series": "shaker"}, end=0.2)
    sim = Simulation(build_model(exp, recording=recording), exp)
    with pytest.raises(ExperimentError, match=r"outside the recorded input \[0, 0.1\] s"):
        sim.run()
    sim.destroy()


def test_a_model_driven_by_a_measured_input_is_calibratable(tmp_path_factory):
    """A shaken bar whose clamp follows /inputs/shaker of the very recording being fitted:
    calibrate recovers Young's modulus from marker data made with the truth (noise-free, same
    model), starting 30 % off. The input lives in the recording calibrate is given, so the forward
    model must be built with it."""
    from petsoft.calibration.calibrate import run_calibration
    from petsoft.io.recording import read_recording, write_recording

    comm = MPI.COMM_WORLD
    folder = Path(comm.bcast(str(tmp_path_factory.mktemp("cal")) if comm.rank == 0 else None))
    data = _experiment({"series": "inputs/shaker"}, end=0.04).to_dict()
    data["time"]["integrator"] = "be"           # one with gradients
    truth = experiment_from_dict(data)
    t = np.arange(0, 61) * 1e-3
    shake = np.column_stack([0 * t, 0.0 * t, 0.01 * np.sin(60 * t)])
    markers = np.array([[0.3, 0.02, 0.02], [0.15, 0.0, 0.04]])
    # the truth's marker motion: probes of the same model driven by the same input
    driven = folder / "input.h5"
    if comm.rank == 0:
        write_recording(driven, markers, t[:2], np.repeat(markers[None], 2, axis=0),
                        inputs={"shaker": (t, shake)})
    comm.Barrier()
    data = truth.to_dict()
    data["output"]["probes"] = markers.tolist()
    probed = experiment_from_dict(data)
    sim = Simulation(build_model(probed, recording=driven), probed)
    result = sim.run()
    sim.destroy()
    recording = folder / "recording.h5"
    if comm.rank == 0:
        times = np.array(result.probe_times)
        positions = markers[None] + np.array(result.probe_displacements)
        write_recording(recording, markers, times, positions, inputs={"shaker": (t, shake)},
                        noise={"position_std": 1e-6})
    comm.Barrier()
    assert np.ptp(read_recording(recording).positions[:, 0, 2]) > 1e-3   # it moves
    data = truth.to_dict()
    data["material"]["youngs_modulus"] = 0.7e5
    data["calibrate"] = {"material.youngs_modulus": [1e4, 1e6]}
    start = experiment_from_dict(data)
    res = run_calibration(start, recording, method="gauss-newton", gradient="sensitivity")
    assert abs(res.values[0] - 1e5) <= 1e-6 * 1e5
