"""The body force's parameters (petsoft.physics.body_force: the gravity terms' one home in
physics), over every parameter it has, so one added to the gravity terms' keys is checked too:

1. its names are the experiment's parameter names of the gravity terms, for a continuum and
   a mass-spring body, and the systems take them;
2. the acceleration's derivative with respect to each matches a central difference, with and
   without a tilt; a component under a tilt is refused;
3. each parameter's residual derivative on a continuum bar and a spring network is the
   difference quotient of the residual (the load is linear in the acceleration).

Runs serially and under ``mpiexec -n 2``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _residuals import semi_discrete_residual
from petsc4py import PETSc

from petsoft.dynamics.factory import build_system
from petsoft.dynamics.mass_spring import rope_mesh
from petsoft.errors import ExperimentError
from petsoft.experiment import experiment_from_dict, parameter_names
from petsoft.mesh.springs import write_spring_mesh
from petsoft.physics.body_force import COMPONENTS, TILTS, BodyForce

STATED = (0.3, -0.2, -9.81)


def _experiment(kind, tmp, tilt=(0.0, 0.0)):
    data = {"gravity": {"acceleration": list(STATED), "tilt_a": tilt[0], "tilt_b": tilt[1]},
            "boundary": [{"kind": "fixed", "where": "x < 1e-6"}],
            "time": {"end": 0.01, "step": 1e-3}}
    if kind == "continuum":
        data |= {"mesh": {"box": {"size": [0.3, 0.05, 0.05], "cells": [3, 1, 1]}},
                 "material": {"youngs_modulus": 1e5, "poisson_ratio": 0.3, "density": 900.0}}
    else:
        mesh, path = rope_mesh(4, 1.0), tmp / "rope.vtu"
        if PETSc.COMM_WORLD.getRank() == 0:
            write_spring_mesh(path, mesh.points, mesh.lines, mesh.triangles)
        PETSc.COMM_WORLD.tompi4py().barrier()
        data |= {"mesh": {"file": str(path)}, "springs": {"stiffness": 30.0, "node_mass": 0.1}}
        del data["gravity"]["tilt_a"], data["gravity"]["tilt_b"]
    return experiment_from_dict(data, source="body-force-test")


@pytest.fixture
def shared_tmp(tmp_path):
    """Rank 0's temporary directory on every rank (rank 0 writes the network's mesh)."""
    return Path(PETSc.COMM_WORLD.tompi4py().bcast(str(tmp_path), root=0))


@pytest.mark.parametrize("kind", ["continuum", "mass-spring"])
def test_its_names_are_the_experiments_and_the_systems(kind, shared_tmp):
    exp = _experiment(kind, shared_tmp)
    s = build_system(exp)
    body = s.parameters.body if s.parameters is not None else s.body
    names = list(body.parameters())
    assert names == [n for n in parameter_names(exp) if n.startswith("gravity.")]
    assert set(names) <= set(s.parameter_names())
    assert names == list(COMPONENTS) + (list(TILTS) if kind == "continuum" else [])
    s.destroy()


@pytest.mark.parametrize("tilt", [(0.0, 0.0), (0.2, -0.1)])
def test_the_accelerations_derivatives_are_its_differences(tilt):
    body = BodyForce(STATED, tilt)
    tilted = tilt != (0.0, 0.0)
    for name, value in body.parameters().items():
        if tilted and name in COMPONENTS:
            with pytest.raises(ExperimentError, match="not differentiable while gravity is "
                                                      "tilted"):
                body.derivative(name)
            continue
        d = body.derivative(name)
        e = 1e-6
        body.set_parameter(name, value + e)
        hi = body.acceleration()
        body.set_parameter(name, value - e)
        lo = body.acceleration()
        body.set_parameter(name, value)
        np.testing.assert_allclose((hi - lo) / (2 * e), d, atol=1e-8 * np.abs(STATED).max())
    with pytest.raises(KeyError, match="no parameter of the body force"):
        body.set_parameter("gravity.size", 1.0)
    assert list(BodyForce((0.0, 0.0, 0.0), tilt).parameters()) == list(COMPONENTS)


@pytest.mark.parametrize("kind", ["continuum", "mass-spring"])
def test_each_parameters_residual_derivative_is_the_residuals_difference(kind, shared_tmp):
    s = build_system(_experiment(kind, shared_tmp))
    rng = np.random.default_rng(2)
    q, v, a = s.create_vec(), s.create_vec(), s.create_vec()
    for x, sc in ((q, 0.01), (v, 1.0), (a, 3.0)):
        x.setArray(sc * rng.standard_normal(x.getLocalSize()))
        s.zero_prescribed(x)
    values = (s.parameters.body if s.parameters is not None else s.body).parameters()
    for name, value in values.items():
        d = s.residual_parameter_derivatives([name], q, v, a)[0]
        # linear in a component (any step), not in a tangent of the tilt
        linear = name in COMPONENTS
        e = 0.5 if linear else 1e-5
        hi, lo = (semi_discrete_residual(s, {name: value + sign * e}, q, v, a)
                  for sign in (1.0, -1.0))
        s.set_parameters({name: value})
        hi.axpy(-1.0, lo)
        hi.scale(0.5 / e)
        assert d.norm() > 0.0, name
        hi.axpy(-1.0, d)
        assert hi.norm() <= (1e-10 if linear else 1e-6) * d.norm(), name
    s.destroy()
