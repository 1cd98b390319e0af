"""Plane colliders on FEM bodies (penalty contact on the surface nodes, collider.<i>.offset).

1. Static: a bar resting on a plane carries its weight: the contact forces sum to m g (1e-8);
   an elastically supported cantilever sagging onto a plane: support + contact = m g; modes of a
   body pressed into a plane keep 3 rigid motions.
2. Dynamics: a bar dropped on a plane (be) penetrates less than the energy (penalty) bound
   sum k/2 p^2 <= released gravitational energy and comes to rest on it carrying its weight;
   with the discrete-gradient midpoint rule the energy balance closes (contact energy counted as
   potential: the ledger's "numerical" column stays at round-off); explicit: its default
   stiffness keeps the drop's balance within 5 %.
3. Taylor tests: energy/gradient/Hessian with contact (plane, sphere); the residual's derivatives
   with respect to collider.0.offset (jointly with boundary.compliance: order 2; the offset alone:
   exactly linear); the forward model's jacobian (be) w.r.t. both vs central differences, and the
   adjoint gradient; Gauss-Newton recovers both from synthetic markers.
4. serial == 2 ranks (probe trajectories, 1e-10).
5. Bad input: a zero normal (file and key named), friction on a FEM body, offset on a sphere.
"""

from __future__ import annotations

import numpy as np
import pytest
from _residuals import semi_discrete_residual as _residual
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.dynamics.implicit import ImplicitIntegrator
from petsoft.dynamics.simulate import Simulation
from petsoft.dynamics.system import DynamicSystem
from petsoft.errors import ExperimentError
from petsoft.experiment import (
    experiment_from_dict,
    get_parameter,
    load_experiment,
    with_parameters,
    with_plane_collider,
    write_toml,
)
from petsoft.physics.model import build_model
from petsoft.solvers.modes import compute_modes
from petsoft.solvers.options import clear_options
from petsoft.solvers.static import StaticSolver

L, A, RHO, G = 0.3, 0.04, 1000.0, 9.81
WEIGHT = RHO * L * A * A * G


def _print(*args):
    if PETSc.COMM_WORLD.getRank() == 0:
        print(*args)


def _orders(remainders):
    r = np.asarray(remainders)
    return np.log2(r[:-1] / r[1:])


def _data(collider, model="linear", **extra):
    data = {
        "mesh": {"box": {"size": [L, A, A], "cells": [4, 1, 1]}},
        "material": {"model": model, "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": RHO},
        "gravity": {"acceleration": [0.0, 0.0, -G]},
        "collider": [collider],
    }
    data.update(extra)
    return data


def _contact_force(model, q):
    c = model.elastic.contact
    return model.dmesh.comm.tompi4py().allreduce(c.forces(model.dmesh.to_local(q)).sum(axis=0))


# -- 1. static ------------------------------------------------------------------------------------
@pytest.mark.parametrize("time", [None, {"end": 0.1, "step": 1e-3}], ids=["no_time", "time"])
def test_bar_resting_on_plane_carries_its_weight(time):
    """x, y held at the bottom (the plane holds z only); start in contact (offset 1e-9 m) so
    the tangent is not singular in z. Both default stiffnesses (with and without [time])."""
    extra = {"boundary": [{"kind": "fixed", "where": "z < 1e-9", "components": ["x", "y"]}]}
    if time is not None:
        extra["time"] = time
    exp = experiment_from_dict(_data({"kind": "plane", "point": [0, 0, 0], "normal": [0, 0, 1],
                                      "offset": 1e-9}, **extra))
    model = build_model(exp)
    solver = StaticSolver(model)
    try:
        q = solver.solve().displacement
        force = _contact_force(model, q)
        k = model.elastic.contact.colliders[0].stiffness
        pen = model.dmesh.comm.tompi4py().allreduce(
            model.elastic.contact.penetration(model.dmesh.to_local(q)).max(initial=0.0), op=MPI.MAX)
    finally:
        solver.destroy()
    _print(f"resting bar ({'static' if time is None else 'step'} default k = {k:.3g} N/m): "
           f"contact force {force}, weight {WEIGHT}, penetration {pen:.3g} m")
    assert abs(force[2] - WEIGHT) <= 1e-8 * WEIGHT
    assert np.abs(force[:2]).max() <= 1e-12 * WEIGHT
    assert 0 < pen < 1e-3 * A


def test_cantilever_sagging_onto_plane_static():
    """An elastically supported cantilever sags onto a plane (no contact at the start; the
    default Newton line search for contact, l2): the support springs and the contact together
    carry the weight, and both carry a share."""
    exp = experiment_from_dict(_data(
        {"kind": "plane", "point": [0, 0, -0.004], "normal": [0, 0, 1], "stiffness": 4e4},
        boundary=[{"kind": "fixed", "where": "x < 1e-9", "compliance": 1e-8}]))
    model = build_model(exp)
    solver = StaticSolver(model)
    try:
        result = solver.solve()
        q = result.displacement
        contact = _contact_force(model, q)
        u = model.dmesh.to_local(q)
        support = model.dmesh.comm.tompi4py().allreduce(
            -model.elastic.support.gradient(u).sum(axis=0))
    finally:
        solver.destroy()
    _print(f"sagging cantilever: {result.newton_iterations} Newton iterations, contact "
           f"{contact[2]:.6g} N + support {support[2]:.6g} N = weight {WEIGHT:.6g} N")
    assert result.retries == 0 and result.newton_iterations <= 10
    assert contact[2] > 0.1 * WEIGHT and support[2] > 0.1 * WEIGHT
    assert abs(contact[2] + support[2] - WEIGHT) <= 1e-8 * WEIGHT


def test_modes_of_a_body_resting_in_a_plane():
    """modes: a free bar pressed into a plane at the reference (offset > 0) keeps 3 rigid motions
    (in-plane translations, rotation about the normal); the plane holds the other 3."""
    plane = {"kind": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "stiffness": 1e4}
    counts = []
    for offset in (-1.0, 1e-4):
        model = build_model(experiment_from_dict(_data({**plane, "offset": offset})))
        result = compute_modes(model, 7)
        counts.append(result.rigid_modes)
        assert result.relative_errors.max() < 1e-8
        assert result.frequencies_hz[result.rigid_modes] > 1.0
        result.destroy()
    assert counts == [6, 3]


# -- 2. dynamics ----------------------------------------------------------------------------------
def test_dropped_bar_be_penetration_bound_and_rest():
    d, h, n = 0.01, 1e-3, 150
    exp = experiment_from_dict(_data({"kind": "plane", "point": [0, 0, -d], "normal": [0, 0, 1]},
                                     damping={"mass": 40.0},
                                     time={"end": n * h, "step": h, "integrator": "be"}))
    model = build_model(exp)
    s = DynamicSystem(model, exp.damping.mass)
    # CG + Jacobi under this test's prefix: GAMG's set-up per Newton iteration dominated the
    # 2-rank run time of these 60 dofs
    PETSc.Options().setValue("drop_pc_type", "jacobi")
    integ = ImplicitIntegrator(s, "be", prefix="drop_")
    q, v = s.create_vec(), s.create_vec()
    q.zeroEntries()
    v.zeroEntries()
    q1, v1 = q.duplicate(), v.duplicate()
    c = model.elastic.contact
    k = c.colliders[0].stiffness
    mpi = s.comm.tompi4py()
    pmax, worst = 0.0, 0.0
    try:
        for i in range(n):
            assert integ.step(i * h, q, v, h, q1, v1).converged
            q1.copy(q)
            v1.copy(v)
            u = s.dmesh.to_local(q)
            pmax = max(pmax, mpi.allreduce(c.penetration(u).max(initial=0.0), op=MPI.MAX))
            contact = s.dmesh.allreduce_sum(c.energy(u))
            released = -s.gravitational_energy(q)
            worst = max(worst, contact - released)
        force = _contact_force(model, q)
        speed = v.norm(PETSc.NormType.INFINITY)
    finally:
        integ.destroy()
        clear_options(["drop_pc_type"])
    bound = np.sqrt(2.0 * WEIGHT * (d + pmax) / k)
    _print(f"dropped bar (be): k = {k:.3g} N/m, max penetration {pmax:.3g} m, energy bound "
           f"{bound:.3g} m, final contact force {force[2]:.6g} N (weight {WEIGHT:.6g}), speed "
           f"{speed:.2g} m/s")
    assert pmax > 0.0                           # it did hit the plane
    assert worst <= 1e-12 * WEIGHT * d          # contact energy <= released gravity energy
    assert pmax <= bound
    assert abs(force[2] - WEIGHT) <= 1e-2 * WEIGHT and speed < 1e-2   # at rest on the plane


def test_dropped_bar_midpoint_energy_balance_closes():
    d, h = 0.005, 1e-3
    exp = experiment_from_dict(_data({"kind": "plane", "point": [0, 0, -d], "normal": [0, 0, 1]},
                                     model="corotated",
                                     time={"end": 0.06, "step": h, "integrator": "midpoint"}))
    model = build_model(exp)
    sim = Simulation(model, exp)
    try:
        result = sim.run()
    finally:
        sim.destroy()
    e = result.energies        # time, kinetic, elastic (+ contact), gravitational, ..., numerical
    contact = model.elastic.contact
    released = -e[:, 3].min()
    assert released > WEIGHT * d                       # it fell onto the plane and into it
    assert e[:, 2].max() > 0.1 * WEIGHT * d            # contact energy took a large share
    _print(f"midpoint drop: max |numerical| {np.abs(e[:, 6]).max():.2e} J of {released:.3g} J "
           f"released; contact k {contact.colliders[0].stiffness:.3g}")
    assert np.abs(e[:, 6]).max() <= 1e-9 * released


def test_dropped_bar_explicit_default_stiffness_is_stable():
    """integrator = "explicit": k = m_min / h^2 (the implicit rule 4 m_max / h^2 gained energy);
    the drop's energy balance stays within 5 % of the released energy."""
    h = 2e-4
    exp = experiment_from_dict(_data({"kind": "plane", "point": [0, 0, -0.005],
                                      "normal": [0, 0, 1]},
                                     time={"end": 0.06, "step": h, "integrator": "explicit"}))
    model = build_model(exp)
    mesh = model.dmesh.mesh
    X = mesh.points[mesh.tets]
    volume = np.abs(np.linalg.det(X[:, 1:] - X[:, :1])) / 6.0
    masses = np.bincount(mesh.tets.ravel(), weights=np.repeat(RHO * volume / 4.0, 4))
    k = model.elastic.contact.colliders[0].stiffness
    surface_min = masses.min()          # every vertex of this 1-cell-thick bar is on the surface
    assert abs(k - surface_min / h**2) <= 1e-9 * k
    sim = Simulation(model, exp)
    try:
        e = sim.run().energies
    finally:
        sim.destroy()
    released = -e[:, 3].min()
    _print(f"explicit drop: k = {k:.3g} N/m, max |numerical| {np.abs(e[:, 6]).max():.2e} J of "
           f"{released:.3g} J released")
    assert e[:, 2].max() > 0.1 * released          # the contact was hit hard
    assert np.abs(e[:, 6]).max() <= 0.05 * released


# -- 3. Taylor tests ------------------------------------------------------------------------------
def _penetrated(model="corotated", offset=0.004, **extra):
    """The bar with its bottom 4 mm inside a plane (tilted a little) and an elastic support."""
    data = _data({"kind": "plane", "point": [0, 0, 0], "normal": [0.005, -0.003, 1.0],
                  "offset": offset, "stiffness": 2e4}, model=model,
                 boundary=[{"kind": "fixed", "where": "x < 1e-9", "compliance": 3e-7}],
                 damping={"mass": 0.5, "stiffness": 0.002})
    data.update(extra)
    return experiment_from_dict(data)


def _state(s, seed=1, scale=1e-4):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(3):
        x = s.create_vec()
        x.setArray(scale * 10.0**k * rng.standard_normal(x.getLocalSize()))
        out.append(x)
    return out


SPHERE = {"kind": "sphere", "center": [0.15, 0.02, -10.0 + 0.004], "radius": 10.0,
          "stiffness": 2e4}


@pytest.mark.parametrize("sphere", [False, True], ids=["plane", "sphere"])
def test_contact_energy_gradient_hessian_taylor(sphere):
    """Plane, and a sphere (its exact Hessian has the curvature term -k p (I - n n^T) / r)."""
    exp = _penetrated(collider=[SPHERE]) if sphere else _penetrated()
    s = DynamicSystem(build_model(exp), exp.damping.mass, exp.damping.stiffness)
    q, d, _ = _state(s)
    u = s.dmesh.to_local(q)
    c = s.elastic.contact
    active = s.comm.tompi4py().allreduce(int((c.penetration(u) > 1e-3).sum()))
    assert active == 10        # the bottom nodes are in contact, far from the switch
    d.scale(1.0 / d.norm())
    g0 = s.internal_gradient(q, s.create_vec())
    W0 = s.elastic_energy(q)
    H = s.assemble_combination(q, 0.0, 1.0, 0.0, s.create_matrix(), eliminate=False)
    Hd = H.createVecLeft()
    H.mult(d, Hd)
    remW, remG = [], []
    for k in range(5):
        eps = 1e-4 * 2.0**-k
        x = q.copy()
        x.axpy(eps, d)
        remW.append(abs(s.elastic_energy(x) - W0 - eps * g0.dot(d)))
        g = s.internal_gradient(x, s.create_vec())
        g.axpy(-1.0, g0)
        g.axpy(-eps, Hd)
        remG.append(g.norm())
    _print(f"contact Taylor: energy {_orders(remW)}, gradient {_orders(remG)}")
    for rem in (remW, remG):
        o = _orders(rem)
        assert np.all((o > 1.8) & (o < 2.2)), o
    # the contact is in K(q) but not in K0 (penetrating here: K0 would differ if it were)
    K0 = s.K0_matrix()
    lin = DynamicSystem(build_model(_penetrated(collider=[])), 0.0, 0.0).K0_matrix()
    K0.axpy(-1.0, lin)
    assert K0.norm() <= 1e-12 * lin.norm()



def test_offset_derivative_taylor():
    exp = _penetrated()
    s = DynamicSystem(build_model(exp), exp.damping.mass, exp.damping.stiffness)
    names = ["collider.0.offset", "boundary.compliance"]
    assert set(names) <= set(s.parameter_names())
    q, v, a = _state(s)
    base = {n: s.parameters.values[n] for n in names}
    R = s.residual_parameter_derivatives(names, q, v, a)
    r0 = _residual(s, base, q, v, a)
    assert R[0].norm() > 0
    # the offset alone: r is exactly linear in it while no node enters or leaves the contact
    for eps in (1e-4, 1e-5):
        r = _residual(s, {**base, names[0]: base[names[0]] + eps}, q, v, a)
        r.axpy(-1.0, r0)
        r.axpy(-eps, R[0])
        assert r.norm() <= 1e-9 * eps * R[0].norm()
    # jointly with the compliance (r ~ 1/c): a wrong offset derivative would leave O(eps)
    dp = np.array([5e-4, 0.5 * base["boundary.compliance"]])
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
    _print(f"offset + compliance residual Taylor {rem}, orders {orders}")
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    s.set_parameters(base)
    # the plane moved by the offset along its unit normal
    c = s.elastic.contact.colliders[0]
    s.set_parameters({names[0]: 0.01})
    n = np.array([0.005, -0.003, 1.0]) / np.linalg.norm([0.005, -0.003, 1.0])
    np.testing.assert_allclose(c.point, 0.01 * n, atol=1e-15)
    s.set_parameters(base)


MARKERS = np.array([[L, 0.02, 0.02], [0.15, 0.0, 0.0], [0.2, 0.04, 0.04]])
FRAMES = [0.004, 0.01]


def test_forward_jacobian_offset_and_compliance():
    """be through 5 steps of a bar bouncing in contact: jacobian == central differences."""
    exp = _penetrated(model="linear", offset=0.002,
                      time={"end": 0.01, "step": 2e-3, "integrator": "be"})
    names = ["collider.0.offset", "boundary.compliance"]
    fm = ForwardModel(exp, names, lambda s: MarkerObserver(s, MARKERS), FRAMES)
    weights = np.random.default_rng(2).standard_normal((len(FRAMES), len(MARKERS), 3))
    try:
        p = fm.p0.copy()
        _, jac = fm.jacobian(p)
        fd = fm.fd_jacobian(p, rel_step=1e-9)     # steps of 1e-9 (m, m/Pa)
        # the discrete adjoint (contract path of the derivatives) agrees with the sensitivities
        _, grad = fm.gradient(p, lambda sim: (float(np.sum(weights * sim)), weights))
    finally:
        fm.destroy()
    np.testing.assert_allclose(grad, np.einsum("kmc,kmcp->p", weights, jac), rtol=1e-8)
    for j, name in enumerate(names):
        scale = np.abs(jac[..., j]).max()
        err = np.abs(jac[..., j] - fd[..., j]).max() / scale
        _print(f"{name}: |jacobian| {scale:.3e}, relative difference to central differences "
               f"{err:.2e}")
        assert scale > 0 and err < 1e-5, (name, err)


@pytest.mark.serial_only
def test_gauss_newton_recovers_compliance_and_offset():
    """Noise-free synthetic markers of a cantilever on an elastic support slapping onto a plane:
    Gauss-Newton (backtracking) on the forward sensitivities recovers (c, offset) from
    (0.6 c, offset - 2 mm). Serial only: ~25 runs of 2x2-rank collectives cost 30 s on 2 ranks,
    and serial == parallel is checked on the trajectories and gradients above."""
    data = _data({"kind": "plane", "point": [0, 0, -0.02], "normal": [0, 0, 1]},
                 boundary=[{"kind": "fixed", "where": "x < 1e-9", "compliance": 5e-7}],
                 initial={"velocity": ["0", "0", "-2*x"]},
                 time={"end": 0.04, "step": 2e-3, "integrator": "be"})
    names = ["boundary.compliance", "collider.0.offset"]
    truth = np.array([5e-7, 0.008])
    start = truth * [0.6, 1.0] - [0, 0.002]
    exp = with_parameters(experiment_from_dict(data), dict(zip(names, start, strict=True)))
    frames = np.arange(1, 21) * 2e-3
    fm = ForwardModel(exp, names, lambda s: MarkerObserver(s, MARKERS), frames)
    PETSc.Options().setValue("fm_pc_type", "jacobi")    # 90 dofs: GAMG set-ups dominate
    try:
        target = fm.simulate(truth)
        p = fm.p0.copy()
        history = []
        for _ in range(10):
            sim, jac = fm.jacobian(p)
            r = (sim - target).ravel()
            history.append(np.linalg.norm(r))
            if history[-1] < 1e-11:
                break
            step = np.linalg.lstsq(jac.reshape(-1, len(names)), -r, rcond=None)[0]
            # backtracking: the contact makes the misfit only piecewise smooth
            while p[0] + step[0] <= 0.0 or np.linalg.norm(
                    (fm.simulate(p + step) - target).ravel()) >= history[-1]:
                step *= 0.5
            p = p + step
    finally:
        fm.destroy()
        clear_options(["fm_pc_type"])
    _print(f"Gauss-Newton misfits {history}; recovered {p} (truth {truth})")
    assert np.allclose(p, truth, rtol=1e-6, atol=0)


# -- 4. serial == 2 ranks --------------------------------------------------------------------
def test_one_rank_equals_all_ranks():
    exp = experiment_from_dict(_data({"kind": "plane", "point": [0, 0, -0.002],
                                      "normal": [0.1, 0, 1]},
                                     time={"end": 0.04, "step": 1e-3, "integrator": "be"},
                                     output={"probes": [[L, 0.02, 0.0], [0.0, 0.0, 0.0]]}))
    runs = []
    opts = PETSc.Options()
    opts.setValue("ksp_rtol", "1e-13")
    try:
        for comm in (PETSc.COMM_SELF, PETSc.COMM_WORLD):
            model = build_model(exp, comm)
            sim = Simulation(model, exp)
            runs.append(np.array(sim.run().probe_displacements))
            sim.destroy()
    finally:
        clear_options(["ksp_rtol"])
    a, b = (MPI.COMM_WORLD.bcast(x) for x in runs)
    assert np.abs(a).max() > 1e-3
    assert np.abs(a - b).max() <= 1e-10 * np.abs(a).max()


# -- 5. the experiment side ---------------------------------------------------------------------
def test_offset_parameter_round_trip(tmp_path):
    exp = _penetrated()
    assert get_parameter(exp, "collider.0.offset") == 0.004
    new = with_parameters(exp, {"collider.0.offset": -0.002})
    assert new.colliders[0].offset == -0.002 and new.colliders[0].point == (0.0, 0.0, 0.0)
    path = tmp_path / "calibrated.toml"        # every rank has its own tmp_path
    write_toml(new, path)
    assert load_experiment(path) == new
    # adding a plane (e.g. a candidate contact term) gives it the next index
    more, i = with_plane_collider(exp, [0, 0, -0.1], [0, 0, 3], stiffness=1e4)
    assert i == 1 and more.colliders[1].normal == (0.0, 0.0, 1.0)
    assert get_parameter(more, "collider.1.offset") == 0.0
    sphere = experiment_from_dict(_data({"kind": "sphere", "center": [0, 0, -1], "radius": 0.5}))
    with pytest.raises(ExperimentError, match="plane"):
        get_parameter(sphere, "collider.0.offset")


def test_zero_normal_names_file_and_key(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('[mesh]\nbox = { size = [0.3, 0.04, 0.04], cells = [2, 1, 1] }\n'
                    '[material]\nyoungs_modulus = 1e5\npoisson_ratio = 0.3\ndensity = 1000\n'
                    '[[collider]]\nkind = "plane"\npoint = [0, 0, 0]\nnormal = [0, 0, 0]\n')
    with pytest.raises(ExperimentError,
                       match=rf"^{path}: collider\[0\]\.normal = \[0, 0, 0\]: the plane's normal "
                             "must be non-zero"):
        load_experiment(path)


def test_friction_and_sphere_offset_refused():
    exp = experiment_from_dict(_data({"kind": "plane", "point": [0, 0, 0], "normal": [0, 0, 1],
                                      "friction": 0.3}))
    with pytest.raises(ExperimentError, match=r"collider\[0\]\.friction = 0\.3: Coulomb friction "
                                              r"is implemented for \[springs\] models only"):
        build_model(exp)
    with pytest.raises(ExperimentError, match=r"unknown key collider\[0\]\.offset"):
        experiment_from_dict(_data({"kind": "sphere", "center": [0, 0, -1], "radius": 0.5,
                                    "offset": 0.1}))
