"""Forward sensitivities of reduced runs (petsoft.reduced.sensitivity).

On the tiny neo-Hookean bar of tests/test_reduced.py (24 tets, 48 free dofs; Rayleigh damping,
gravity, initial displacement and velocity):

1. With a basis spanning every free dof the reduced sensitivities equal the full model's
   (ForwardModel.jacobian, tangent-linear runs of the full equations) to round-off, for
   generalized-alpha and backward Euler, for every kind of parameter the reduced model
   follows (Young's modulus, Poisson's ratio, density, both Rayleigh coefficients, linear drag,
   gravity).
2. Taylor test on a truncated POD basis (r = 4 or 5), with the full assembly and with ECSW:
   the remainder |m(p + e dp) - m(p) - e dm/dp dp| of the reduced run falls 4x when e halves
   (second order), per parameter and scheme -- a wrong coefficient leaves a first-order
   remainder (ratio 2).
3. 2 ranks == 1 rank (basis, ECSW mesh, sensitivities).
"""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc
from test_reduced import FRAMES, MARKERS, _bar, _differences, _forward, _trajectory, _unit_vectors

from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.errors import ExperimentError
from petsoft.reduced.basis import coordinates_of, pod_basis
from petsoft.reduced.ecsw import ReducedMesh, SampledForces, ecsw_mesh
from petsoft.reduced.galerkin import ReducedModel, steps_for
from petsoft.reduced.sensitivity import sensitivities

ALL = ["material.youngs_modulus", "damping.mass", "damping.stiffness", "material.density",
       "material.poisson_ratio", "drag.linear", "gravity.acceleration.z"]
TAYLOR = ["material.youngs_modulus", "damping.mass", "damping.stiffness", "material.density"]


@pytest.mark.parametrize(("method", "beta"), [("alpha", 0.002), ("be", 0.002), ("alpha", 0.0)])
def test_full_basis_sensitivities_equal_the_full_models(method, beta):
    """(beta = 0: D_p of the elastic names is zero, taken without the column evaluations)"""
    exp = _bar(method, drag={"linear": 3.0}, damping={"mass": 0.5, "stiffness": beta})
    fm = ForwardModel(exp, ALL, lambda s: MarkerObserver(s, MARKERS), FRAMES)
    sim, jac = fm.jacobian(fm.p0)
    s = fm.system
    V = pod_basis(s, _unit_vectors(s), energy=1.0)
    q0, v0 = s.initial_state()
    rm = ReducedModel(s, V, q0, fm.observer, method=method, radius=0.9)
    red, djac = sensitivities(rm, v0, fm.h, steps_for(FRAMES, fm.h), ALL).frames(FRAMES, fm.h)
    assert djac.shape == jac.shape
    for j, name in enumerate(ALL):
        size = np.abs(jac[..., j]).max()
        assert size > 0.0, name
        assert np.abs(djac[..., j] - jac[..., j]).max() <= 1e-9 * size, name
    rm.destroy()
    fm.destroy()


def test_regions_and_stiffness_fields_with_every_element_sampled():
    """A region's E and density and a stiffness field's multipliers (per-cell coefficients:
    the sampled derivative picks each sampled element's own) through ECSW with every element
    at weight 1 and a full basis: the full model's sensitivities to round-off."""
    names = ["material.youngs_modulus", "material.tip.youngs_modulus", "material.tip.density",
             "material.youngs_modulus#0", "material.youngs_modulus#2"]
    exp = _bar("alpha", region={"tip": {"where": "x > 0.2"}},
               material={"model": "neohookean", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                         "density": 1000.0, "tip": {"density": 1500.0,
                                                    "youngs_modulus": 2e5}})
    fm = ForwardModel(exp, names, lambda s: MarkerObserver(s, MARKERS), FRAMES)
    _, jac = fm.jacobian(fm.p0)
    s = fm.system
    V = pod_basis(s, _unit_vectors(s), energy=1.0)
    q0, v0 = s.initial_state()
    forces = SampledForces(s, V, q0, ReducedMesh.everything(s))
    rm = ReducedModel(s, V, q0, fm.observer, forces=forces, method="alpha", radius=0.9)
    _, djac = sensitivities(rm, v0, fm.h, steps_for(FRAMES, fm.h), names).frames(FRAMES, fm.h)
    for j, name in enumerate(names):
        size = np.abs(jac[..., j]).max()
        assert size > 0.0, name
        assert np.abs(djac[..., j] - jac[..., j]).max() <= 1e-9 * size, name
    rm.destroy()
    fm.destroy()


def _reduced(method, sampled, comm=None):
    exp, fm = _forward(method, comm=comm)
    s = fm.system
    states = _trajectory(fm)
    V = pod_basis(s, _differences(states), energy=0.99999)
    q0, v0 = s.initial_state()
    forces, mesh = None, None
    if sampled:
        coords = np.array([coordinates_of(s, V, q, q0) for q in states[1:]])
        mesh = ecsw_mesh(s, V, q0, coords, tolerance=1e-3)
        forces = SampledForces(s, V, q0, mesh)
    rm = ReducedModel(s, V, q0, fm.observer, forces=forces, method=method, radius=0.9)
    return fm, rm, v0, mesh


@pytest.mark.parametrize("method", ["alpha", "be"])
@pytest.mark.parametrize("sampled", [False, True])
def test_taylor_reduced_runs_converge_to_the_sensitivities(method, sampled):
    fm, rm, v0, mesh = _reduced(method, sampled)
    s = fm.system
    if sampled:
        assert 0 < mesh.size < s.dmesh.allreduce_sum(len(s.dmesh.cells))
    N = steps_for(FRAMES, fm.h)
    p0 = {n: s.parameters.values[n] for n in TAYLOR}
    sens = sensitivities(rm, v0, fm.h, N, TAYLOR)
    m0 = sens.run.markers
    # the sensitivities' run is the plain run
    assert np.array_equal(m0, rm.run(v0, fm.h, N).markers)
    for j, name in enumerate(TAYLOR):
        first, rem = [], []
        for eps in (1e-2, 5e-3):
            dp = eps * p0[name]
            rm.set_parameters({**p0, name: p0[name] + dp})
            m1 = rm.run(v0, fm.h, N).markers
            first.append(np.abs(m1 - m0).max())
            rem.append(np.abs(m1 - m0 - dp * sens.markers[..., j]).max())
        rm.set_parameters(p0)
        assert first[1] > 0.0, name
        # second order, and far below the first-order change
        assert 3.5 < rem[0] / rem[1] < 4.5, (name, rem)
        assert rem[1] < 0.05 * first[1], (name, rem, first)
    rm.destroy()
    fm.destroy()


def test_sensitivities_refuse_bad_names():
    fm, rm, v0, _ = _reduced("be", False)
    with pytest.raises(ExperimentError, match="no parameter"):
        sensitivities(rm, v0, fm.h, 2, [])
    with pytest.raises(ExperimentError, match="repeated"):
        sensitivities(rm, v0, fm.h, 2, ["damping.mass", "damping.mass"])
    with pytest.raises(ExperimentError, match="not a differentiable parameter"):
        sensitivities(rm, v0, fm.h, 2, ["material.stiffness"])
    with pytest.raises(ExperimentError, match="not differentiated in the reduced model"):
        sensitivities(rm, v0, fm.h, 2, ["drag.quadratic"])
    rm.destroy()
    fm.destroy()


def test_reduced_sensitivities_same_on_one_and_all_ranks():
    out = []
    for comm in (PETSc.COMM_WORLD, PETSc.COMM_SELF):
        fm, rm, v0, mesh = _reduced("alpha", True, comm=comm)
        sens = sensitivities(rm, v0, fm.h, steps_for(FRAMES, fm.h), TAYLOR)
        out.append((rm.basis.size, mesh.size, sens.frames(FRAMES, fm.h)))
        rm.destroy()
        fm.destroy()
    (r_all, m_all, (f_all, d_all)), (r_one, m_one, (f_one, d_one)) = out
    assert (r_all, m_all) == (r_one, m_one)
    for j in range(len(TAYLOR)):
        size = np.abs(d_one[..., j]).max()
        assert np.abs(d_all[..., j] - d_one[..., j]).max() <= 1e-8 * size
