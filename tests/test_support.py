"""Elastic supports (``[[boundary]] kind = "fixed"`` with ``compliance`` > 0, boundary.compliance).

1. Analytic: a bar (nu = 0) pulled by a traction T on an elastic support: the support face moves by
   c T, the tip by T L / E + c T (P1 is exact for this linear field).
2. c -> 0 converges to the Dirichlet answer at rate 1 in c (nu = 0.3: the support's lateral
   restraint makes the field non-trivial); the cantilever's first frequency drops with c and
   tends to the clamped one.
3. Taylor tests: the potential (elastic + supports) energy/gradient/Hessian, the residual's
   derivative with respect to the compliance, the forward model's jacobian (be) vs central
   differences; the springs are exactly diag(A/c) in K0 and K; the midpoint energy balance
   closes with them.
4. serial == 2 ranks (probe trajectory of a run on COMM_SELF vs COMM_WORLD, 1e-10).
5. with_parameters / get_parameter / write_toml round trip; bad input.
"""

from __future__ import annotations

import numpy as np
import pytest
from _residuals import semi_discrete_residual as _residual
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.dynamics.simulate import Simulation
from petsoft.dynamics.system import DynamicSystem
from petsoft.errors import ExperimentError
from petsoft.experiment import (
    experiment_from_dict,
    get_parameter,
    load_experiment,
    parameter_names,
    with_compliance,
    with_parameters,
    write_toml,
)
from petsoft.physics.model import build_model
from petsoft.solvers.modes import compute_modes
from petsoft.solvers.options import clear_options
from petsoft.solvers.static import StaticSolver

L, A, E, T = 0.3, 0.04, 1e6, 1e3


def _print(*args):
    if PETSc.COMM_WORLD.getRank() == 0:
        print(*args)


def _data(c, nu=0.0, cells=(4, 1, 1), **extra):
    support = {"kind": "fixed", "where": "x < 1e-9"}
    if c > 0:
        support["compliance"] = c
    data = {
        "mesh": {"box": {"size": [L, A, A], "cells": list(cells)}},
        "material": {"model": "linear", "youngs_modulus": E, "poisson_ratio": nu,
                     "density": 1000.0},
        "boundary": [support,
                     {"kind": "traction", "where": f"x > {L} - 1e-9", "value": [str(T), "0", "0"]}],
    }
    data.update(extra)
    return data


def _static(exp, comm=None):
    model = build_model(exp, comm)
    solver = StaticSolver(model)
    try:
        u = model.dmesh.gather_global(solver.solve().displacement)
    finally:
        solver.destroy()
    return model.dmesh.comm.tompi4py().bcast(u), model.dmesh.mesh.points


def _orders(remainders):
    r = np.asarray(remainders)
    return np.log2(r[:-1] / r[1:])


# -- 1. analytic --------------------------------------------------------------------------------
def test_support_moves_by_compliance_times_traction():
    c = 1e-5
    u, pts = _static(experiment_from_dict(_data(c)))
    support, tip = pts[:, 0] < 1e-9, pts[:, 0] > L - 1e-9
    np.testing.assert_allclose(u[support, 0], c * T, rtol=1e-9)
    np.testing.assert_allclose(u[tip, 0], T * L / E + c * T, rtol=1e-9)
    assert np.abs(u[:, 1:]).max() < 1e-9 * c * T            # nu = 0: no lateral motion
    rigid, _ = _static(experiment_from_dict(_data(0.0)))
    np.testing.assert_allclose(u[tip, 0] - rigid[tip, 0], c * T, rtol=1e-9)


def test_compliance_to_zero_converges_at_rate_one():
    """|u_tip(c) - u_tip(Dirichlet)| ~ C c: halving c halves the error (order in [0.9, 1.1])."""
    rigid, pts = _static(experiment_from_dict(_data(0.0, nu=0.3)))
    tip = pts[:, 0] > L - 1e-9
    # asymptotic once the springs A_i / c are much stiffer than the elements (~ E h): c E / h
    # from 2.5e-3 down to 3e-4
    cs = 1e-10 * 0.5 ** np.arange(4)
    errors = []
    for c in cs:
        u, _ = _static(experiment_from_dict(_data(c, nu=0.3)))
        errors.append(np.abs(u[tip] - rigid[tip]).max())
    orders = _orders(errors)
    _print(f"compliance -> 0: errors {errors}, orders {orders}")
    assert np.all((orders > 0.9) & (orders < 1.1)), orders


def test_first_frequency_drops_with_compliance_and_tends_to_clamped():
    data = _data(0.0, cells=(6, 1, 1))
    data["boundary"] = data["boundary"][:1]
    freqs = []
    for c in (0.0, 1e-9, 1e-8, 1e-7):
        if c > 0:
            data["boundary"][0]["compliance"] = c
        model = build_model(experiment_from_dict(data))
        result = compute_modes(model, 1)
        assert result.rigid_modes == 0          # the springs hold every rigid motion
        freqs.append(float(result.frequencies_hz[0]))
        result.destroy()
    _print(f"first frequency (clamped, c = 1e-9, 1e-8, 1e-7): {freqs}")
    clamped, f = freqs[0], np.array(freqs[1:])
    assert np.all(np.diff(f) < 0) and f[0] < clamped      # softer support, lower frequency
    assert abs(f[0] - clamped) < 0.02 * clamped            # c E / L = 3e-3: close to clamped
    assert abs(f[0] - clamped) < 0.2 * abs(f[1] - clamped)  # and closer as c falls


# -- 3. Taylor tests ------------------------------------------------------------------------------
def _system(c=3e-7, model="corotated", **extra):
    data = _data(c, nu=0.3, **extra)
    data["material"]["model"] = model
    data.setdefault("damping", {"mass": 0.5, "stiffness": 0.002})
    data.setdefault("gravity", {"acceleration": [0.0, 0.0, -9.81]})
    exp = experiment_from_dict(data)
    return DynamicSystem(build_model(exp), exp.damping.mass, exp.damping.stiffness)


def _state(s, seed=1, scale=1e-3):
    rng = np.random.default_rng(seed)
    vecs = []
    for k in range(3):
        x = s.create_vec()
        x.setArray(scale * 10.0**k * rng.standard_normal(x.getLocalSize()))
        s.apply_prescribed(x, 0.0)
        vecs.append(x)
    return vecs


def test_potential_energy_gradient_hessian_taylor():
    """W(q + e d) - W - e g.d ~ e^2 and g(q + e d) - g - e H d ~ e^2 (corotated + supports)."""
    s = _system()
    assert s.comm.tompi4py().allreduce(len(s.elastic.support.nodes)) == 4   # the x = 0 face
    q, d, _ = _state(s, scale=1e-3)
    d.scale(1.0 / d.norm())
    g0 = s.internal_gradient(q, s.create_vec())
    W0 = s.elastic_energy(q)
    H = s.assemble_combination(q, 0.0, 1.0, 0.0, s.create_matrix(), eliminate=False)
    Hd = H.createVecLeft()
    H.mult(d, Hd)
    remW, remG = [], []
    for k in range(5):
        eps = 1e-3 * 2.0**-k
        x = q.copy()
        x.axpy(eps, d)
        remW.append(abs(s.elastic_energy(x) - W0 - eps * g0.dot(d)))
        g = s.internal_gradient(x, s.create_vec())
        g.axpy(-1.0, g0)
        g.axpy(-eps, Hd)
        remG.append(g.norm())
    _print(f"potential Taylor: energy {_orders(remW)}, gradient {_orders(remG)}")
    for rem in (remW, remG):
        o = _orders(rem)
        assert np.all((o > 1.8) & (o < 2.2)), o


def test_support_is_in_k0_and_k():
    """The supports' diagonal springs are in K0 (the damping's beta K0) and in K(q): with a
    linear material K(q) == K0, and K0 - K0(rigid support) = diag(A_i / c), whose trace is
    3 x (support face area) / c."""
    s = _system(model="linear")
    K = s.assemble_combination(None, 0.0, 0.0, 1.0, s.create_matrix(), eliminate=False)
    q, _, _ = _state(s)
    Kq = s.assemble_combination(q, 0.0, 1.0, 0.0, s.create_matrix(), eliminate=False)
    Kq.axpy(-1.0, K)
    assert Kq.norm() <= 1e-12 * K.norm()
    rigid = _system(c=0.0, model="linear")
    diff = K.copy()
    diff.axpy(-1.0, rigid.assemble_combination(None, 0.0, 0.0, 1.0, rigid.create_matrix(),
                                               eliminate=False))
    d = diff.getDiagonal()
    c = s.parameters.values["boundary.compliance"]
    assert abs(d.sum() - 3 * A * A / c) <= 1e-9 * d.sum()
    assert abs(diff.norm() - d.norm()) <= 1e-9 * d.norm()      # diagonal only
    assert d.min()[1] >= 0.0



def test_compliance_derivative_taylor():
    """r(c + e dc) - r(c) - e R_c dc falls as e^2 (r ~ 1/c is nonlinear), with the damping's
    beta K0 v term (K0 holds the supports); also the SI form's d/dc [K(q) w]."""
    s = _system()
    assert "boundary.compliance" in s.parameter_names()
    q, v, a = _state(s)
    c0 = s.parameters.values["boundary.compliance"]
    names = ["boundary.compliance", "material.youngs_modulus"]
    base = {n: s.parameters.values[n] for n in names}
    R = s.residual_parameter_derivatives(names, q, v, a)
    r0 = _residual(s, base, q, v, a)
    dp = np.array([0.7 * c0, -0.4 * base["material.youngs_modulus"]])
    lin = R[0].copy()
    lin.scale(dp[0])
    lin.axpy(dp[1], R[1])
    rem = []
    for k in range(5):
        eps = 1e-1 * 2.0**-k
        r = _residual(s, {n: base[n] + eps * dp[j] for j, n in enumerate(names)}, q, v, a)
        r.axpy(-1.0, r0)
        r.axpy(-eps, lin)
        rem.append(r.norm())
    orders = _orders(rem)
    _print(f"compliance residual Taylor {rem} orders {orders}")
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    s.set_parameters(base)
    # contract == vectors . mu, and the w-term: d/dc [K(q) w] = -(A/c^2) w on the supports
    mu = s.create_vec()
    mu.setRandom()
    s.zero_prescribed(mu)
    deriv = s.parameter_derivatives(q, v, a)
    np.testing.assert_allclose(deriv.contract(names, mu), [R[0].dot(mu), R[1].dot(mu)],
                               rtol=1e-10)
    w = _state(s, seed=7)[0]
    with_w = s.parameter_derivatives(q, v, a, w).vectors(["boundary.compliance"])[0]
    with_w.axpy(-1.0, R[0])
    K = s.assemble_combination(q, 0.0, 1.0, 0.0, s.create_matrix())
    Kw0 = K.createVecLeft()
    K.mult(w, Kw0)
    s.set_parameters({"boundary.compliance": c0 * (1 + 1e-6)})
    K = s.assemble_combination(q, 0.0, 1.0, 0.0, s.create_matrix())
    Kw1 = K.createVecLeft()
    K.mult(w, Kw1)
    Kw1.axpy(-1.0, Kw0)
    Kw1.scale(1.0 / (1e-6 * c0))
    s.zero_prescribed(Kw1)
    Kw1.axpy(-1.0, with_w)
    assert Kw1.norm() <= 1e-5 * with_w.norm()
    s.set_parameters(base)


MARKERS = np.array([[L, 0.02, 0.02], [0.0, 0.02, 0.02], [0.15, 0.0, 0.04]])
FRAMES = [0.004, 0.01]


def _dynamic_data(c=3e-7, integrator="be"):
    data = _data(c, nu=0.3, cells=(4, 1, 1))
    data["material"]["youngs_modulus"] = 1e5
    data["boundary"][1]["value"] = ["100*t/0.01", "0", "-50"]
    data.update(gravity={"acceleration": [0.0, 0.0, -9.81]}, damping={"mass": 0.5},
                time={"end": 0.01, "step": 2e-3, "integrator": integrator},
                output={"probes": [[L, 0.02, 0.02], [0.0, 0.0, 0.0]]})
    return data


def test_forward_jacobian_matches_central_differences():
    """ForwardModel (be) jacobian w.r.t. boundary.compliance == central differences (step 1e-9
    m/Pa, 0.3 % of c: fd_jacobian's step is rel_step x max(|p|, 1))."""
    exp = experiment_from_dict(_dynamic_data())
    fm = ForwardModel(exp, ["boundary.compliance"], lambda s: MarkerObserver(s, MARKERS), FRAMES)
    try:
        p = fm.p0.copy()
        _, jac = fm.jacobian(p)
        fd = fm.fd_jacobian(p, rel_step=1e-9)
    finally:
        fm.destroy()
    scale = np.abs(jac).max()
    err = np.abs(jac - fd).max() / scale
    _print(f"boundary.compliance: |jacobian| {scale:.3e} m/(m/Pa), relative difference to "
           f"central differences {err:.2e}")
    assert scale > 0 and err < 1e-5, err


def test_midpoint_energy_balance_with_elastic_support():
    """The support springs are a potential (booked as elastic energy): with the discrete-gradient
    midpoint rule, a time-dependent traction's work and the stored energies balance."""
    data = _dynamic_data(integrator="midpoint")
    data["damping"] = {"mass": 0.0}
    data["material"]["model"] = "corotated"
    data["time"]["end"] = 0.03
    exp = experiment_from_dict(data)
    model = build_model(exp)
    sim = Simulation(model, exp)
    try:
        e = sim.run().energies        # time, kinetic, elastic, gravitational, dissipated, work
    finally:
        sim.destroy()
    scale = np.abs(e[:, 1:6]).max()
    _print(f"midpoint with support: max |numerical| {np.abs(e[:, 6]).max():.2e} J of {scale:.3g}")
    assert np.abs(e[:, 5]).max() > 0.01 * scale             # the traction did work
    assert np.abs(e[:, 6]).max() <= 1e-9 * scale


# -- 4. serial == 2 ranks -------------------------------------------------------------------------
def test_one_rank_equals_all_ranks():
    exp = experiment_from_dict(_dynamic_data(integrator="be"))
    runs = []
    opts = PETSc.Options()
    opts.setValue("ksp_rtol", "1e-13")
    try:
        for comm in (PETSc.COMM_SELF, PETSc.COMM_WORLD):
            model = build_model(exp, comm)
            sim = Simulation(model, exp)
            result = sim.run()
            runs.append(np.array(result.probe_displacements))
            sim.destroy()
    finally:
        clear_options(["ksp_rtol"])
    a, b = runs
    a = MPI.COMM_WORLD.bcast(a)
    b = MPI.COMM_WORLD.bcast(b)
    assert a.shape == b.shape and np.abs(a).max() > 1e-6
    assert np.abs(a - b).max() <= 1e-10 * np.abs(a).max()


# -- 5. the experiment side ---------------------------------------------------------------------
def test_parameter_round_trip(tmp_path):
    exp = experiment_from_dict(_data(2e-7))
    assert "boundary.compliance" in parameter_names(exp)
    assert get_parameter(exp, "boundary.compliance") == 2e-7
    new = with_parameters(exp, {"boundary.compliance": 5e-7})
    assert new.boundaries[0].compliance == 5e-7
    path = tmp_path / "calibrated.toml"      # every rank has its own tmp_path
    write_toml(new, path)
    again = load_experiment(path)
    assert again.boundaries[0].compliance == 5e-7 and again == new
    # rigid supports: no such parameter, and the message says what to do
    rigid = experiment_from_dict(_data(0.0))
    assert "boundary.compliance" not in parameter_names(rigid)
    with pytest.raises(ExperimentError, match="compliance > 0"):
        get_parameter(rigid, "boundary.compliance")


def test_set_parameters_rigid_to_elastic_is_refused():
    exp = experiment_from_dict(_data(0.0))
    s = DynamicSystem(build_model(exp))
    with pytest.raises(ExperimentError, match="set compliance > 0 in the experiment"):
        s.set_parameters({"boundary.compliance": 1e-7})
    s2 = DynamicSystem(build_model(experiment_from_dict(_data(1e-7))))
    with pytest.raises(ExperimentError, match="must be > 0"):
        s2.set_parameters({"boundary.compliance": 0.0})


@pytest.mark.parametrize("boundary, match", [
    ({"kind": "fixed", "where": "x < 1e-9", "compliance": -1e-7},
     r"<embedded>: boundary\[0\]\.compliance = -1e-07 is out of range: valid is compliance >= 0"),
    ({"kind": "prescribed", "where": "x < 1e-9", "displacement": ["0", "0", "0"],
      "compliance": 1e-7},
     r"<embedded>: boundary\[0\]\.compliance is not a key of a boundary with kind = "
     r"\"prescribed\".*belongs to kind = \"fixed\""),
    ({"kind": "traction", "where": "x < 1e-9", "value": ["0", "0", "0"], "compliance": 1e-7},
     r"boundary\[0\]\.compliance is not a key of a boundary with kind = \"traction\""),
])
def test_bad_compliance(boundary, match):
    data = _data(0.0)
    data["boundary"] = [boundary]
    with pytest.raises(ExperimentError, match=match):
        experiment_from_dict(data)


def test_support_without_faces_and_differing_compliances():
    data = _data(1e-7)
    data["boundary"][0]["where"] = "x < 1e-9 and y < 1e-9"      # an edge: no face
    with pytest.raises(ExperimentError, match=r"boundary\[0\]\.where: the elastic support"):
        build_model(experiment_from_dict(data))
    data = _data(1e-7)
    data["boundary"].append({"kind": "fixed", "where": f"x > {L} - 1e-9", "compliance": 2e-7})
    data["boundary"].pop(1)
    exp = experiment_from_dict(data)
    s = DynamicSystem(build_model(exp))
    assert "boundary.compliance" not in s.parameter_names()
    with pytest.raises(ExperimentError, match="different compliances"):
        s.set_parameters({"boundary.compliance": 1e-7})


def test_with_compliance_turns_rigid_supports_elastic():
    rigid = experiment_from_dict(_data(0.0))
    elastic = with_compliance(rigid, 4e-7)
    assert elastic.boundaries[0].compliance == 4e-7
    assert get_parameter(elastic, "boundary.compliance") == 4e-7
    assert elastic == experiment_from_dict(_data(4e-7))
    with pytest.raises(ExperimentError, match=r"boundary\[1\] is not a \[\[boundary\]\] kind = "):
        with_compliance(rigid, 1e-7, boundaries=[1])
    with pytest.raises(ExperimentError, match="finite compliance > 0"):
        with_compliance(rigid, 0.0)


def test_compliance_on_a_mass_spring_model_is_refused():
    data = {"mesh": {"box": {"size": [1.0, 0.1, 0.1], "cells": [2, 1, 1]}},
            "springs": {"stiffness": 100.0, "damping": 0.0},
            "boundary": [{"kind": "fixed", "where": "x < 1e-9", "compliance": 1e-3}]}
    with pytest.raises(ExperimentError, match=r"<embedded>: boundary\[0\]\.compliance = 0\.001: "
                                              r"elastic supports are implemented for \[material\]"):
        experiment_from_dict(data)
