"""A term's key at its minimum: another model, or a value like any other (``Key.at_minimum``).

For every number key of the registry that a continuum system can set in place, the declaration
is checked against what the system builder does at the key's minimum: where it declares
``at_minimum`` (the supports' compliance: 0 is a rigid support, a Dirichlet condition) a system
built there has no such parameter, and setting the minimum in place is refused with the declared
words; where it does not, setting the minimum in place gives the same forces as a system built
at the minimum (the coefficient is simply 0).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from petsoft.dynamics.system import DynamicSystem
from petsoft.errors import ExperimentError
from petsoft.experiment import experiment_from_dict
from petsoft.physics.model import build_model
from petsoft.terms import TERMS

#: Every term of a table or an array of tables on, each key above its minimum.
DATA = {
    "mesh": {"box": {"size": [0.4, 0.04, 0.04], "cells": [4, 1, 1]}},
    "material": {"model": "linear", "youngs_modulus": 1.0e6, "poisson_ratio": 0.3,
                 "density": 1000.0},
    "boundary": [{"kind": "fixed", "where": "x < 1e-6", "compliance": 1e-7}],
    "damping": {"mass": 0.5, "stiffness": 1e-4},
    "drag": {"linear": 2.0, "quadratic": 3.0},
    "friction": {"dry": 0.5, "speed": 0.01},
    "viscoelastic": {"ratio": 0.3, "relaxation_time": 0.05},
    "time": {"end": 0.1, "step": 0.01},
}

#: The number keys whose minimum is a valid value of the experiment file, by parameter name
#: (a plane collider's keys are not parameters: the plane's is its unbounded offset).
KEYS = {k.dotted: k for t in TERMS.values() for k in t.keys
        if k.type == "number" and k.minimum is not None and not k.open
        and k.section in ("table", "array") and k.table != "collider"}


def _at_minimum(name: str) -> dict:
    data = copy.deepcopy(DATA)
    k = KEYS[name]
    if k.section == "table":
        data[k.table][k.key] = k.minimum
    else:
        for entry in data.get(k.table, []):
            if entry.get("kind") == k.only:
                entry[k.key] = k.minimum
    return data


def _system(data) -> DynamicSystem:
    return DynamicSystem(build_model(experiment_from_dict(data)))


def _forces(s: DynamicSystem) -> np.ndarray:
    """grad W(q) + D v + G(v) at a fixed state, and the branch's energy there."""
    rng = np.random.default_rng(2)
    q, v, out = s.create_vec(), s.create_vec(), s.create_vec()
    lo, hi = q.getOwnershipRange()
    q.setArray(1e-4 * rng.standard_normal(q.getSize())[lo:hi])
    v.setArray(1e-2 * rng.standard_normal(v.getSize())[lo:hi])
    s.zero_prescribed(q)
    s.zero_prescribed(v)
    f = s.internal_gradient(q, out).getArray().copy()
    f += s.damping_apply(v, out).getArray()
    return np.append(f, s.viscoelastic_energy(q))


@pytest.fixture(scope="module")
def full():
    return _system(DATA)


def test_every_key_of_the_full_model_is_settable(full):
    """The full model carries every key tested here (else a key would escape the test)."""
    missing = sorted(set(KEYS) - set(full.parameters.values))
    assert missing == [], missing


@pytest.mark.parametrize("name", sorted(KEYS))
def test_the_minimum_is_another_model_exactly_where_declared(full, name):
    k = KEYS[name]
    built = _system(_at_minimum(name))
    try:
        if k.at_minimum:
            assert name not in built.parameters.values
            with pytest.raises(ExperimentError, match=f"{k.key} = 0 is {k.at_minimum}"):
                full.set_parameters({name: k.minimum})
            with pytest.raises(ExperimentError, match="cannot be changed in place"):
                built.set_parameters({name: 2 * _value(name)})
        else:
            assert name in built.parameters.values
            before = full.parameters.values[name]
            full.set_parameters({name: k.minimum})
            try:
                np.testing.assert_allclose(_forces(full), _forces(built), rtol=1e-12,
                                           atol=1e-14)
            finally:
                full.set_parameters({name: before})
    finally:
        built.destroy()


def _value(name: str) -> float:
    """The value :data:`DATA` gives ``name``."""
    k = KEYS[name]
    if k.section == "table":
        return DATA[k.table][k.key]
    return next(e[k.key] for e in DATA[k.table] if e.get("kind") == k.only)
