"""An element inverted on one rank only is an InvertedElementError on every rank.

The residual (``DynamicSystem.internal_gradient``) and the energy (``elastic_energy``: the
midpoint rule's discrete gradient, TAO's objective) sum over the ranks after a local kernel
call that refuses an inverted element. A rank that raised before the sum left the others
waiting in it for ever (a 2-rank chord whose iterate inverted an element never returned); now
the refusal travels with the sum and every rank raises. Serially the same calls raise too.
"""

from __future__ import annotations

import numpy as np
import pytest
from mpi4py import MPI

from petsoft.dynamics.system import DynamicSystem
from petsoft.errors import InvertedElementError
from petsoft.experiment import experiment_from_dict
from petsoft.physics.model import build_model


def _system():
    exp = experiment_from_dict({
        "mesh": {"box": {"size": [0.4, 0.04, 0.04], "cells": [10, 1, 1]}},
        "material": {"model": "neohookean", "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "boundary": [{"kind": "fixed", "where": "x > 0.4 - 1e-9"}],
        "time": {"end": 0.01, "step": 0.001},
    })
    return DynamicSystem(build_model(exp), 0.0, 0.0)


def test_an_element_inverted_on_one_rank_raises_on_every_rank():
    s = _system()
    q = s.create_vec()
    # the nodes near x = 0 reflected through the plane x = -0.005: the end cells invert
    pts = s.dmesh.points                                  # this rank's vertices
    u = np.zeros_like(pts)
    u[:, 0] = np.where(pts[:, 0] < 0.05, -2.0 * pts[:, 0] - 0.01, 0.0)
    s.dmesh.set_global_from_local(u, q)
    # the kernels refuse it on some ranks, not all (on two ranks: the one holding x = 0)
    try:
        s.elastic.energy(s.dmesh.to_local(q))
        local = 0
    except InvertedElementError:
        local = 1
    refusing = MPI.COMM_WORLD.allreduce(local)
    assert refusing >= 1
    if MPI.COMM_WORLD.size == 2:
        assert refusing == 1, "the test needs an inversion seen by one rank only"
    with pytest.raises(InvertedElementError):
        s.internal_gradient(q, s.create_vec())
    with pytest.raises(InvertedElementError):
        s.elastic_energy(q)
    q.zeroEntries()
    assert s.elastic_energy(q) == 0.0              # and a sound state still sums
    s.destroy()
    q.destroy()
