"""The Rayleigh terms the registry declares (petsoft.terms, contributes "rayleigh";
petsoft.dynamics.rayleigh), parametrised over the registry so a term added by its declaration
alone is checked too:

1. the matrix a term's law names agrees with its declared unit (a coefficient of M is a rate,
   1/s; one of the stiffness a time, s: both make D v a force);
2. on a free continuum body and a free spring network, each term alone damps a rigid
   translation as its unit says (a mass-proportional one with c m v, a stiffness-proportional
   one not at all) and a deformation with positive power;
3. the residual's derivative with respect to its coefficient is the difference quotient of the
   residual (exact: the residual is linear in it), on both kinds of body.

Runs serially and under ``mpiexec -n 2``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _residuals import semi_discrete_residual
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.dynamics.factory import build_system
from petsoft.dynamics.mass_spring import cloth_mesh
from petsoft.dynamics.rayleigh import LAWS, MATRICES, NAMES, RayleighDamping, RayleighLaw
from petsoft.experiment import experiment_from_dict
from petsoft.mesh.springs import write_spring_mesh
from petsoft.terms import term

#: The unit of a Rayleigh coefficient of each matrix: D v = c B v is a force.
UNIT = {"mass": "1/s", "reference": "s"}
RHO, SIZE = 900.0, (0.3, 0.1, 0.05)


def _free_body(kind, tmp_path, name, c):
    """A body with no support, no gravity, only term ``name`` at coefficient ``c``."""
    table, key = term(name).keys[0].table, term(name).keys[0].key
    data = {table: {key: c}, "time": {"end": 0.01, "step": 1e-3}}
    if kind == "continuum":
        data |= {"mesh": {"box": {"size": list(SIZE), "cells": [3, 2, 1]}},
                 "material": {"model": "linear", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                              "density": RHO}}
    else:
        mesh = cloth_mesh(3, 3, 0.2, 0.2)
        path = tmp_path / "cloth.vtu"
        if PETSc.COMM_WORLD.getRank() == 0:
            write_spring_mesh(path, mesh.points, mesh.lines, mesh.triangles)
        PETSc.COMM_WORLD.tompi4py().barrier()
        data |= {"mesh": {"file": str(path)},
                 "springs": {"stiffness": 30.0, "node_mass": 0.01, "bending": 2.0}}
    return build_system(experiment_from_dict(data, source="rayleigh-test"))


def _total_mass(s, kind):
    if kind == "continuum":
        return RHO * np.prod(SIZE)
    return float(np.sum(s.masses))


@pytest.fixture
def shared_tmp(tmp_path):
    """Rank 0's temporary directory on every rank (rank 0 writes the network's mesh)."""
    return Path(PETSc.COMM_WORLD.tompi4py().bcast(str(tmp_path), root=0))


@pytest.mark.parametrize("name", NAMES)
def test_the_declared_matrix_agrees_with_the_declared_unit(name):
    law = LAWS[name]
    assert isinstance(law, RayleighLaw) and law.matrix in MATRICES
    assert term(name).keys[0].unit == UNIT[law.matrix], (name, law.matrix)


@pytest.mark.parametrize("kind", ["continuum", "mass-spring"])
@pytest.mark.parametrize("name", NAMES)
def test_each_term_damps_a_translation_as_its_unit_says(name, kind, shared_tmp):
    c = 0.7
    s = _free_body(kind, shared_tmp, name, c)
    assert s.rayleigh.coef[name] == c
    assert s.parameters is None or s.parameters.values[name] == c
    v, out = s.create_vec(), s.create_vec()
    arr = v.getArray().reshape(-1, 3)
    arr[:] = [0.2, -0.1, 0.3]
    s.damping_apply(v, out)
    force = s.comm.tompi4py().allreduce(out.getArray(readonly=True).reshape(-1, 3).sum(axis=0))
    momentum = _total_mass(s, kind) * np.array([0.2, -0.1, 0.3])
    if term(name).keys[0].unit == "1/s":
        np.testing.assert_allclose(force, c * momentum, rtol=1e-12)
    else:
        largest = s.comm.tompi4py().allreduce(np.abs(out.getArray(readonly=True)).max(initial=0),
                                              op=MPI.MAX)
        assert largest <= 1e-9 * c * np.abs(momentum).max()
    # a deformation (a velocity varying over the body) loses energy
    rng = np.random.default_rng(4)
    arr[:] = rng.standard_normal(arr.shape)
    s.damping_apply(v, out)
    assert v.dot(out) > 0.0
    s.destroy()


@pytest.mark.parametrize("kind", ["continuum", "mass-spring"])
@pytest.mark.parametrize("name", NAMES)
def test_the_coefficients_derivative_is_the_residuals_difference(name, kind, shared_tmp):
    s = _free_body(kind, shared_tmp, name, 0.4)
    assert name in s.parameter_names()
    rng = np.random.default_rng(7)
    q, v, a = s.create_vec(), s.create_vec(), s.create_vec()
    for x, sc in ((q, 0.01), (v, 1.0), (a, 3.0)):
        x.setArray(sc * rng.standard_normal(x.getLocalSize()))

    d = s.residual_parameter_derivatives([name], q, v, a)[0]
    hi, lo = (semi_discrete_residual(s, {name: c}, q, v, a) for c in (0.9, 0.4))
    hi.axpy(-1.0, lo)
    hi.scale(1.0 / 0.5)
    assert d.norm() > 0.0
    hi.axpy(-1.0, d)
    assert hi.norm() <= 1e-10 * d.norm(), name
    s.destroy()


def test_coefficients_by_matrix_and_their_errors():
    r = RayleighDamping.of_matrices(0.5, 0.002)
    assert (r.alpha, r.beta) == (0.5, 0.002)
    assert sorted(r.coef.values()) == [0.002, 0.5]
    assert all(r.coefficient(LAWS[n].matrix) == c for n, c in r.coef.items())
    with pytest.raises(ValueError, match="no Rayleigh term"):
        RayleighDamping({"damping.cubic": 1.0})
    with pytest.raises(ValueError, match="scales one of"):
        RayleighLaw("damping")
