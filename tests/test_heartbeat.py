"""Long runs are never silent: the heartbeat of petsoft.io.progress (issue 15, item 5).

diagnose on the independent L-bracket printed nothing for 138 s while it simulated a refined
mesh once, and for 108 s while it scored a round of candidates; a candidate fit by finite
differences printed a line every 50 to 120 s. The forward model's time steps (forward, adjoint,
sensitivities) now beat; a heartbeat says where they are once its interval passed without a line.
"""

import numpy as np
from petsc4py import PETSc

from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.experiment import experiment_from_dict
from petsoft.io.progress import beat, doing, heartbeat, touch


def test_beats_are_said_only_inside_a_heartbeat_and_after_its_interval():
    said = []
    beat("nobody listens")
    with heartbeat(said.append, interval=0.0):
        beat("one")
        with doing("candidate drag.linear"):
            beat(lambda: "two")
            with doing("inner"):
                beat("three")
            beat("four")
    beat("after")
    assert said == ["one", "candidate drag.linear: two", "inner: three",
                    "candidate drag.linear: four"]

    said.clear()
    with heartbeat(said.append, interval=3600.0):
        beat("too soon")                    # the interval starts with the heartbeat
        touch()
        beat(lambda: 1 / 0)                 # not even made: nothing is said
    assert said == []


def _bar():
    return experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [6, 2, 2]}},
        "material": {"model": "neohookean", "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"displacement": ["0", "0", "0.05*x**2"]},
        "time": {"end": 0.01, "step": 2e-3, "integrator": "alpha"},
    }, source="heartbeat bar")


def test_forward_adjoint_and_sensitivity_steps_beat():
    markers = np.array([[0.3, 0.0, 0.0], [0.3, 0.04, 0.04]])
    fm = ForwardModel(_bar(), ["material.youngs_modulus"],
                      lambda s: MarkerObserver(s, markers), np.arange(1, 6) * 2e-3,
                      comm=PETSc.COMM_WORLD)
    said = []
    try:
        with heartbeat(said.append, interval=0.0), doing("base fit"):
            sim = fm.simulate(fm.p0)
            forward = list(said)
            said.clear()
            fm.gradient(fm.p0, lambda s: (0.5 * float(np.sum(s ** 2)), s))
            adjoint = list(said)
            said.clear()
            fm.jacobian(fm.p0)
            sensitivities = list(said)
    finally:
        fm.destroy()
    assert np.isfinite(sim).all()
    if PETSc.COMM_WORLD.getRank() != 0:
        # the run's first rank alone speaks for it (a run on a group of ranks is heard from
        # the group's first rank; the others would repeat its lines)
        assert forward == adjoint == sensitivities == []
        return
    dofs = 3 * 7 * 3 * 3             # 7 x 3 x 3 nodes, 3 dofs each (the clamp's included)
    assert forward == [f"base fit: still simulating: step {k} of 5 ({dofs} dofs, alpha)"
                       for k in range(1, 6)]
    assert [line for line in adjoint if "adjoint" in line] == [
        f"base fit: still computing the gradient: adjoint step {k} of 5" for k in range(1, 6)]
    assert len(sensitivities) >= 5 and all("still simulating" in s for s in sensitivities)
