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
