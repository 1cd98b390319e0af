"""Velocity-dependent forces: ``[drag] linear/quadratic`` and ``[friction] dry``.

Modules: petsoft.physics.drag, petsoft.physics.friction, petsoft.dynamics.velocity.

1. Kernels: Taylor tests (remainder order 2) of the forces' velocity Jacobians, of the second
   velocity derivative (the SI gradient needs it) and of the dissipation potentials.
2. Analytic solutions on mass-spring models: a single free mass under dry friction decelerates
   as v0 - mu t and stops; a unit-area plate under quadratic drag follows v0 / (1 + c A v0 t / m);
   under linear drag exp(-c A t / m), backward Euler converging at order 1.
3. Energy balance (kinetic + elastic + dissipated = initial + work) with the discrete-gradient
   midpoint rule, with each term alone on a corotated FEM bar.
4. Parameter derivatives (exact, also at coefficient 0), and the forward-sensitivity and adjoint
   gradients of ForwardModel through be, si and alpha with drag.quadratic and friction.dry
   non-zero: Taylor remainders of order 2, adjoint == forward sensitivities.
5. Serial == 2 ranks: marker positions and gradient of an FEM bar with all three terms (1e-10).
6. Bad input: negative coefficients, speed <= 0, drag on a line-only network, unknown keys.

``pytest -s`` prints the Taylor tables.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from _residuals import semi_discrete_residual
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.dynamics.energy import EnergyLedger
from petsoft.dynamics.implicit import ImplicitIntegrator
from petsoft.dynamics.mass_spring import (
    MassSpringSystem,
    build_mass_spring_model,
    rope_mesh,
)
from petsoft.dynamics.system import DynamicSystem
from petsoft.dynamics.velocity import LAWS as VELOCITY_LAWS
from petsoft.errors import ExperimentError
from petsoft.experiment import DragSpec, experiment_from_dict, load_experiment, with_parameters
from petsoft.mesh.springs import SpringMesh, write_spring_mesh
from petsoft.physics import drag, friction
from petsoft.physics.model import build_model
from petsoft.solvers.options import clear_options
from petsoft.terms import TERMS

MARKERS = np.array([[0.3, 0.04, 0.04], [0.3, 0.0, 0.0], [0.15, 0.02, 0.04]])
FRAMES = [0.003, 0.0075, 0.01]
VNAMES = ["drag.linear", "drag.quadratic", "friction.dry"]


def _print(*args):
    if PETSc.COMM_WORLD.getRank() == 0:
        print(*args)


def _orders(rem):
    r = np.asarray(rem)
    return np.log2(r[:-1] / r[1:])


def _taylor(f, df, x, d, eps0=1e-2, n=5):
    """Remainders |f(x + e d) - f(x) - e df(d)| for e = eps0 2^-k and their orders."""
    f0, lin = f(x), df(d)
    rem = [np.abs(f(x + e * d) - f0 - e * lin).max() for e in eps0 * 2.0 ** -np.arange(n)]
    return _orders(rem)


# -- 1. kernels ----------------------------------------------------------------------------------
def _pairs(rng, nnodes=6, nfaces=5):
    pts = rng.standard_normal((nnodes, 3))
    faces = np.array([rng.choice(nnodes, 3, replace=False) for _ in range(nfaces)])
    return drag.face_pairs(pts, faces, np.arange(nnodes))


def test_drag_kernels_taylor_and_lumping():
    rng = np.random.default_rng(0)
    node, weight, normal = _pairs(rng)
    v, d, w, x = (rng.standard_normal((6, 3)) for _ in range(4))
    q = (node, weight, normal)
    G = lambda y: drag.quadratic_damping(y, *q)  # noqa: E731
    dG = lambda y: np.einsum("pij,pj->pi", drag.quadratic_damping_blocks(v, *q), y)  # noqa: E731
    orders = _taylor(G, dG, v, d)
    _print("quadratic drag G' orders", orders)
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    # second derivative: d/dv [G'(v) x] along w, symmetric in (w, x)
    Gx = lambda y: np.einsum("pij,pj->pi", drag.quadratic_damping_blocks(y, *q), x)  # noqa: E731
    sec = lambda y: drag.quadratic_damping_second(v, y, x, *q)  # noqa: E731
    # G'' is piecewise constant in |u|: the remainder vanishes unless a sign changes
    e = 1e-6
    np.testing.assert_allclose((Gx(v + e * w) - Gx(v - e * w)) / (2 * e), sec(w), rtol=1e-7,
                               atol=1e-9)
    np.testing.assert_allclose(drag.quadratic_damping_second(v, w, x, *q),
                               drag.quadratic_damping_second(v, x, w, *q), rtol=1e-12)
    # the potential's gradient is G
    P = lambda y: np.array([drag.quadratic_potential(y, *q)])  # noqa: E731
    dP = lambda y: np.array([np.sum(G(v) * y)])  # noqa: E731
    orders = _taylor(P, dP, v, d)
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    # linear drag: S_i = sum (A/3) n n^T; total force on a uniformly moving closed surface -> 0
    # (sum A n = 0), and on a flat unit square moving normally it is c A v
    sq = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    tri = np.array([[0, 1, 2], [0, 2, 3]])
    qq = drag.face_pairs(sq, tri, np.arange(4))
    S = drag.linear_blocks(*qq, 4)
    vz = np.tile([0.0, 0.0, 2.0], (4, 1))
    assert np.einsum("pij,pj->pi", S, vz).sum(axis=0) == pytest.approx([0, 0, 2.0])
    assert drag.quadratic_damping(vz, *qq).sum(axis=0) == pytest.approx([0, 0, 4.0])


def test_friction_kernels_taylor():
    rng = np.random.default_rng(1)
    m = rng.uniform(0.5, 2.0, 7)
    eps = 0.3
    v, d, w, x = (rng.standard_normal((7, 3)) for _ in range(4))
    v[0] *= 1e-3   # a node in the viscous regime
    G = lambda y: friction.damping(y, m, eps)  # noqa: E731
    dG = lambda y: np.einsum("pij,pj->pi", friction.damping_blocks(v, m, eps), y)  # noqa: E731
    orders = _taylor(G, dG, v, d)
    _print("friction G' orders", orders)
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    Gx = lambda y: np.einsum("pij,pj->pi", friction.damping_blocks(y, m, eps), x)  # noqa: E731
    sec = lambda y: friction.damping_second(v, y, x, m, eps)  # noqa: E731
    orders = _taylor(Gx, sec, v, w)
    _print("friction G'' orders", orders)
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    np.testing.assert_allclose(friction.damping_second(v, w, x, m, eps),
                               friction.damping_second(v, x, w, m, eps), rtol=1e-12, atol=1e-14)
    P = lambda y: np.array([friction.potential(y, m, eps)])  # noqa: E731
    dP = lambda y: np.array([np.sum(G(v) * y)])  # noqa: E731
    orders = _taylor(P, dP, v, d)
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    # |force| -> mu m far above the regularisation speed, opposite to v
    big = 1e4 * v[1:]
    f = friction.damping(big, m[1:], eps)
    np.testing.assert_allclose(np.linalg.norm(f, axis=1), m[1:], rtol=1e-6)
    assert np.all(np.einsum("pi,pi->p", f, big) > 0)


# -- 2. analytic solutions (mass-spring) --------------------------------------------------------
def _mesh_file(tmp_path, mesh, name="m.vtu"):
    path = Path(tmp_path) / name
    write_spring_mesh(path, mesh.points, mesh.lines, mesh.triangles)
    return path


def _spring_experiment(tmp_path, mesh, springs, **extra):
    data = {"mesh": {"file": str(_mesh_file(tmp_path, mesh))}, "springs": springs, **extra}
    return experiment_from_dict(data, source="<test>")


def _run(system, exp, h, steps, method="be"):
    """Velocities (steps + 1, N, 3) (file numbering, every rank) of an implicit run."""
    integ = ImplicitIntegrator(system, method)
    q, v = system.initial_state()
    q1, v1 = q.duplicate(), v.duplicate()
    out = [system.dmesh.to_all(v)]
    for n in range(steps):
        rep = integ.step(n * h, q, v, h, q1, v1)
        assert rep.converged, rep.reason
        q1.copy(q)
        v1.copy(v)
        out.append(system.dmesh.to_all(v))
    integ.destroy()
    return np.array(out)


def _ms_system(exp):
    model = build_mass_spring_model(exp)
    s = MassSpringSystem(model, exp.damping.mass, exp.damping.stiffness)
    return s


def test_single_mass_dry_friction_decelerates_linearly_and_stops(tmp_path):
    """One free mass (on a negligibly soft spring to a fixed node) sliding at v0 = 1 m/s with
    dry = 2 m/s^2: v = v0 - dry t (BE is exact for a constant force; the regularisation changes
    the force by (eps/v)^2 / 2 < 1e-7), then it stops (|v| < 10 eps)."""
    v0, mu, h = 1.0, 2.0, 5e-3
    exp = _spring_experiment(
        tmp_path, rope_mesh(2, 1.0), {"stiffness": 1e-12, "node_mass": 0.0},
        mass=[{"at": [1.0, 0, 0], "value": 3.0}],
        boundary=[{"kind": "fixed", "where": "x < 0.5"}],
        initial={"velocity": ["1.0*(x > 0.5)", "0", "0"]},
        friction={"dry": mu, "speed": 1e-4},
        time={"end": 1.0, "step": h, "integrator": "be"})
    s = _ms_system(exp)
    vel = _run(s, exp, h, 120)[:, 1, 0]
    t = h * np.arange(len(vel))
    moving = t < 0.45
    err = np.abs(vel[moving] - (v0 - mu * t[moving])).max()
    _print(f"dry friction: max |v - (v0 - mu t)| = {err:.2e} while sliding; v(0.6) = {vel[-1]:.2e}")
    assert err < 1e-6
    assert np.all(np.abs(vel[t > 0.55]) < 1e-3)
    assert vel[t > 0.55].min() > -1e-3       # it stops, it does not reverse
    s.destroy()


def _plate(tmp_path, h, kind, c, v0=2.0, m=1.0):
    """A unit square of two triangles moving along its normal; node masses proportional to the
    lumped face areas (1/6, 1/3), so every node has the same deceleration: a rigid plate."""
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    share = np.array([2, 1, 2, 1]) / 6.0           # nodes 0 and 2 are in both triangles
    mesh = SpringMesh(pts, np.zeros((0, 2), np.int64), tris)
    exp = _spring_experiment(
        tmp_path, mesh, {"stiffness": 10.0, "node_mass": 0.0},
        mass=[{"at": list(p), "value": m * a} for p, a in zip(pts, share, strict=True)],
        initial={"velocity": ["0", "0", str(v0)]},
        drag={kind: c}, time={"end": 1.0, "step": h, "integrator": "be"})
    return _ms_system(exp), exp


def test_plate_quadratic_and_linear_drag_analytic(tmp_path):
    """Quadratic drag c = 0.5 kg/m^3 on a 1 m^2 plate of 1 kg at 2 m/s: v0 / (1 + c A v0 t / m);
    linear drag 0.8 Pa s/m: v0 exp(-c A t / m). Backward Euler's error at t = 1 s falls at
    order 1 (h = 0.02, 0.01, 0.005)."""
    v0, T = 2.0, 1.0
    for kind, c, exact in (("quadratic", 0.5, lambda t: v0 / (1 + 0.5 * v0 * t)),
                           ("linear", 0.8, lambda t: v0 * np.exp(-0.8 * t))):
        errs = []
        for h in (0.02, 0.01, 0.005):
            s, exp = _plate(tmp_path, h, kind, c, v0)
            vel = _run(s, exp, h, int(round(T / h)))
            # rigid: every node has the same velocity, along z only
            assert np.abs(vel[:, :, 2] - vel[:, :1, 2]).max() < 1e-12
            assert np.abs(vel[:, :, :2]).max() < 1e-12
            errs.append(abs(vel[-1, 0, 2] - exact(T)))
            s.destroy()
        orders = _orders(errs)
        _print(f"{kind} drag: BE errors at t = 1 s {errs}, orders {orders}")
        assert errs[-1] < 0.01 * exact(T)
        assert np.all((orders > 0.9) & (orders < 1.1)), orders


# -- 3. energy balance (FEM bar, midpoint) -----------------------------------------------------
def _bar(integrator="be", **extra):
    data = {
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [4, 1, 1]}},
        "material": {"model": "corotated", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"displacement": ["0", "0", "0.3*x**2"], "velocity": ["0", "0.1*x", "0"]},
        "time": {"end": 0.01, "step": 2e-3, "integrator": integrator},
    }
    data.update(extra)
    return experiment_from_dict(data)


@pytest.mark.parametrize("section", [{"drag": {"linear": 200.0}},
                                     {"drag": {"quadratic": 2000.0}},
                                     {"friction": {"dry": 2.0, "speed": 0.01}}],
                         ids=["linear", "quadratic", "dry"])
def test_energy_balance_closes_with_each_term(section):
    """Midpoint on the bar: kinetic + elastic + dissipated == initial energy to 1e-9 of it,
    and the term dissipates a sizeable part (> 5 %) of the energy in 60 ms."""
    exp = _bar(**section)
    model = build_model(exp)
    s = DynamicSystem(model)
    integ = ImplicitIntegrator(s, "midpoint")
    q, v = s.initial_state()
    q1, v1 = q.duplicate(), v.duplicate()
    ledger = EnergyLedger()
    first = ledger.record(s, 0.0, q, v)
    h = 1e-3
    for n in range(60):
        rep = integ.step(n * h, q, v, h, q1, v1)
        assert rep.converged
        assert rep.dissipated >= 0.0
        ledger.add_step(rep)
        row = ledger.record(s, (n + 1) * h, q1, v1)
        q1.copy(q)
        v1.copy(v)
    e0 = first["kinetic"] + first["elastic"]
    _print(f"{section}: dissipated {row['dissipated'] / e0:.3f} of E0, numerical "
           f"{row['numerical'] / e0:.2e}")
    assert abs(row["numerical"]) < 1e-9 * e0
    assert row["dissipated"] > 0.05 * e0
    integ.destroy()
    s.destroy()


# -- 4. parameter derivatives and gradients --------------------------------------------------
def _vecs(s, seed=1):
    rng = np.random.default_rng(seed)
    out = []
    for scale in (0.01, 0.1, 1.0):
        x = s.create_vec()
        x.setArray(scale * rng.standard_normal(x.getLocalSize()))
        s.apply_prescribed(x, 0.0)
        out.append(x)
    return out


def _residual(s, values, q, v, a):
    return semi_discrete_residual(s, values, q, v, a).getArray().copy()


@pytest.mark.parametrize("at_zero", [False, True])
def test_residual_parameter_derivatives_exact(at_zero):
    """r is linear in each coefficient: (r(p + e) - r(p)) / e == d r/d p to round-off, also at
    p = 0 (the diagnosis' score test) where the term is absent from the residual; with friction
    on, the density derivative includes the friction's mass (Taylor order 2 over all names)."""
    coef = 0.0 if at_zero else 1.0
    exp = _bar(drag={"linear": 20.0 * coef, "quadratic": 500.0 * coef},
               friction={"dry": 3.0 * coef, "speed": 0.05})
    s = DynamicSystem(build_model(exp))
    q, v, a = _vecs(s)
    names = VNAMES + ["material.density"]
    base = {n: s.parameters.values[n] for n in names}
    vecs = [x.getArray().copy() for x in s.residual_parameter_derivatives(names, q, v, a)]
    r0 = _residual(s, base, q, v, a)
    for name, dv in zip(VNAMES, vecs[:3], strict=True):
        assert np.abs(dv).max() > 0, name
        e = 0.37
        r1 = _residual(s, {**base, name: base[name] + e}, q, v, a)
        np.testing.assert_allclose((r1 - r0) / e, dv, atol=1e-9 * np.abs(dv).max())
    d = np.array([1.0, 200.0, 2.0, 100.0]) * np.array([1, -1, 1, 1])
    p = np.array([base[n] for n in names])
    lin = sum(dj * vj for dj, vj in zip(d, vecs, strict=True))
    rem = []
    for k in range(5):
        eps = 1e-2 * 2.0**-k
        r = _residual(s, dict(zip(names, p + eps * d, strict=True)), q, v, a)
        rem.append(np.abs(r - r0 - eps * lin).max())
    rem = s.comm.tompi4py().allreduce(np.array(rem))
    orders = _orders(rem)
    _print(f"residual Taylor (p = {coef}) remainders {rem} orders {orders}")
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    s.destroy()


@pytest.fixture
def light_forward_solver():
    """CG + Jacobi for the forward Newton steps of the tiny bar (cleared afterwards)."""
    opts = PETSc.Options()
    keys = ["fm_pc_type"]
    for key in keys:
        opts.setValue(key, "jacobi")
    yield
    clear_options(keys)


GRAD_NAMES = ["material.youngs_modulus", "drag.linear", "drag.quadratic", "friction.dry",
              "material.density"]


def _forward(method, comm=None, names=GRAD_NAMES):
    exp = _bar(method, drag={"linear": 20.0, "quadratic": 2000.0},
               friction={"dry": 2.0, "speed": 0.02})
    return ForwardModel(exp, names, lambda s: MarkerObserver(s, MARKERS), FRAMES, comm=comm)


def _misfit(target):
    def dphi(sim):
        r = sim - target
        return 0.5 * float(np.sum(r * r)), r
    return dphi


@pytest.mark.parametrize("method", ["be", "si", "alpha"])
def test_gradients_taylor_with_drag_and_friction(method, light_forward_solver):
    """Adjoint gradient and forward-sensitivity directional derivative through the step with
    drag.quadratic and friction.dry non-zero: remainders of order 2; adjoint == forward
    sensitivities to 1e-10 (scaled by the parameters)."""
    fm = _forward(method)
    p = fm.p0.copy()
    sim0 = fm.simulate(p)
    target = sim0 + 1e-3 * np.random.default_rng(5).standard_normal(sim0.shape)
    dphi = _misfit(target)
    value, grad = fm.gradient(p, dphi)
    sim1, jac = fm.jacobian(p)
    np.testing.assert_array_equal(sim0, sim1)
    g_fwd = np.einsum("kmc,kmcp->p", sim0 - target, jac)
    scale = np.abs(p)
    err = np.abs((grad - g_fwd) * scale).max() / np.abs(grad * scale).max()
    _print(f"{method}: adjoint vs forward sensitivities {err:.2e}; grad * p = {grad * scale}")
    assert err < 1e-10
    # every velocity parameter changes the markers (the terms act)
    assert np.all(np.abs(jac[..., 1:4]).max(axis=(0, 1, 2)) * scale[1:4]
                  > 1e-3 * np.abs(jac[..., 0]).max() * scale[0])
    d = np.random.default_rng(3).uniform(-1.0, 1.0, len(p)) * scale
    rem_phi, rem_sim = [], []
    for k in range(5):
        eps = 2e-2 * 2.0**-k
        sim = fm.simulate(p + eps * d)
        rem_phi.append(abs(dphi(sim)[0] - value - eps * grad @ d))
        rem_sim.append(np.linalg.norm(sim - sim0 - eps * jac @ d))
    o_phi, o_sim = _orders(rem_phi), _orders(rem_sim)
    _print(f"{method}: adjoint remainders {np.array(rem_phi)} orders {o_phi}")
    _print(f"{method}: forward remainders {np.array(rem_sim)} orders {o_sim}")
    assert np.all((o_phi > 1.8) & (o_phi < 2.2)), o_phi
    assert np.all((o_sim > 1.8) & (o_sim < 2.2)), o_sim
    fm.destroy()


@pytest.mark.parametrize("method", ["be", "si"])
def test_sensitivities_at_zero_coefficients(method, light_forward_solver):
    """The diagnosis' score test: drag and friction absent (coefficients 0), their columns of
    d sim / d p still exact -- sim(e d) - sim(0) - e J d falls as e^2 for d >= 0 (one-sided:
    the terms are not defined below 0 in an experiment) -- and non-zero."""
    exp = _bar(method, friction={"speed": 0.02})
    fm = ForwardModel(exp, VNAMES, lambda s: MarkerObserver(s, MARKERS), FRAMES)
    p = fm.p0.copy()
    assert np.all(p == 0.0)
    sim0, jac = fm.jacobian(p)
    assert np.all(np.abs(jac).max(axis=(0, 1, 2)) > 0)
    d = np.array([30.0, 1500.0, 2.0])
    rem = [np.abs(fm.simulate(p + e * d) - sim0 - e * jac @ d).max()
           for e in 2e-2 * 2.0 ** -np.arange(5)]
    orders = _orders(rem)
    _print(f"{method} at 0: remainders {np.array(rem)} orders {orders}")
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    fm.destroy()


# -- 5. serial == 2 ranks ------------------------------------------------------------------------
def test_serial_equals_parallel_with_all_terms():
    """Marker positions and the adjoint gradient on COMM_WORLD equal those each rank computes
    alone on COMM_SELF (serially: the same run twice) to 1e-10."""
    runs = []
    opts = PETSc.Options()
    keys = ["fm_ksp_rtol", "fm_grad_ksp_rtol"]
    for key in keys:
        opts.setValue(key, "1e-14")
    try:
        for comm in (PETSc.COMM_WORLD, PETSc.COMM_SELF):
            fm = _forward("be", comm=comm)
            sim = fm.simulate(fm.p0)
            value, grad = fm.gradient(fm.p0, _misfit(np.zeros_like(sim)))
            runs.append((sim, grad * np.abs(fm.p0)))
            fm.destroy()
    finally:
        clear_options(keys)
    (s1, g1), (s2, g2) = runs
    assert np.abs(s1 - s2).max() < 1e-10 * np.abs(s1).max()
    assert np.abs(g1 - g2).max() < 1e-10 * np.abs(g1).max()


def test_friction_where_and_parameter_round_trip():
    """friction.where selects the nodes it acts on; with_parameters / to_dict keep the keys."""
    exp = _bar(friction={"dry": 1.0, "where": "x > 0.2"}, drag={"quadratic": 3.0})
    s = DynamicSystem(build_model(exp))
    mass = s.velocity_terms.laws["friction.dry"].mass
    total = s.dmesh.allreduce_sum(mass.sum())
    assert 0.0 < total < 0.5 * s.dmesh.allreduce_sum(
        s.lumped.getArray(readonly=True)[::3].sum())
    s.destroy()
    exp2 = with_parameters(exp, {"friction.dry": 4.0, "drag.linear": 2.5})
    assert exp2.friction.dry == 4.0 and exp2.drag.linear == 2.5
    assert exp2.friction.where == exp.friction.where and exp2.drag.quadratic == 3.0
    assert experiment_from_dict(exp2.to_dict()) == exp2


# -- 6. bad input -------------------------------------------------------------------------------
BASE = """
[mesh]
box = { size = [0.3, 0.04, 0.04], cells = [4, 1, 1] }
[material]
youngs_modulus = 1e5
poisson_ratio = 0.3
density = 1000.0
"""


@pytest.mark.parametrize("text,key,what", [
    ("[drag]\nlinear = -1.0\n", "drag.linear", ">= 0"),
    ("[drag]\nquadratic = -0.5\n", "drag.quadratic", ">= 0"),
    ("[friction]\ndry = -2.0\n", "friction.dry", ">= 0"),
    ("[friction]\ndry = 2.0\nspeed = 0.0\n", "friction.speed", "> 0"),
    ("[friction]\ndry = 2.0\nspeed = -1e-3\n", "friction.speed", "> 0"),
    ("[drag]\nlinaer = 1.0\n", "drag.linaer", "linear"),
    ("[friction]\nmu = 1.0\n", "friction.mu", "dry"),
])
def test_bad_input_names_file_and_key(tmp_path, text, key, what):
    path = Path(tmp_path) / "bad.toml"
    path.write_text(BASE + text)
    with pytest.raises(ExperimentError) as info:
        load_experiment(path)
    msg = str(info.value)
    assert str(path) in msg and key in msg and what in msg, msg


@pytest.mark.parametrize("name", [n for n, t in TERMS.items()
                                  if t.contributes in ("velocity", "rayleigh")])
def test_the_reader_refuses_on_a_rope_exactly_the_terms_declared_on_the_surface(tmp_path, name):
    """Over the registry's velocity and Rayleigh terms: the reader refuses a term declared on
    the surface (``Term.surface``) on a line-only network, naming its key and the terms a rope
    can carry, and accepts the others there; the law's ``on_surface`` is the declaration."""
    path = _mesh_file(tmp_path, rope_mesh(3, 1.0))
    t = TERMS[name]
    key = t.keys[0]
    data = {"mesh": {"file": str(path)}, "springs": {"stiffness": 10.0, "node_mass": 0.1},
            "boundary": [{"kind": "fixed", "where": "x < 0.1"}], key.table: {key.key: 0.5}}
    if t.surface:
        with pytest.raises(ExperimentError, match=rf"{key.table}\.{key.key} = 0\.5: .* needs a "
                           r"surface") as err:
            experiment_from_dict(data, source="rope.toml")
        said = str(err.value)
        assert "[friction] dry" in said and "[damping] mass" in said
        assert not any(f"[{k.table}] {k.key}" in said.split("; use")[1]
                       for u in TERMS.values() if u.surface for k in u.keys)
    else:
        experiment_from_dict(data, source="rope.toml")
    if t.contributes == "velocity":
        assert VELOCITY_LAWS[name].on_surface == t.surface


def test_drag_on_a_line_only_network_is_refused(tmp_path):
    """The reader refuses drag (non-zero, or calibrated from 0) on a rope; so does the model
    builder for a mesh handed to it."""
    path = _mesh_file(tmp_path, rope_mesh(3, 1.0))
    base = {"mesh": {"file": str(path)}, "springs": {"stiffness": 10.0, "node_mass": 0.1},
            "boundary": [{"kind": "fixed", "where": "x < 0.1"}]}
    with pytest.raises(ExperimentError, match="drag.quadratic = 1: drag needs a surface"):
        experiment_from_dict({**base, "drag": {"quadratic": 1.0}}, source="rope.toml")
    with pytest.raises(ExperimentError, match=r'rope.toml: calibrate."drag.linear": drag needs'):
        experiment_from_dict({**base, "drag": {"linear": 0.0},
                              "calibrate": {"drag.linear": [0.0, 1.0]}}, source="rope.toml")
    exp = experiment_from_dict(base, source="rope.toml")
    mesh = rope_mesh(3, 1.0)
    exp = dataclasses.replace(exp, drag=DragSpec(quadratic=1.0))
    with pytest.raises(ExperimentError, match="drag needs a surface"):
        build_mass_spring_model(exp, mesh=mesh)
    # friction is fine on a rope, and the rope offers no drag parameters
    exp = _spring_experiment(tmp_path, rope_mesh(3, 1.0), {"stiffness": 10.0, "node_mass": 0.1},
                             boundary=[{"kind": "fixed", "where": "x < 0.1"}],
                             friction={"dry": 1.0})
    s = _ms_system(exp)
    assert "friction.dry" in s.parameter_names() and "drag.linear" not in s.parameter_names()
    s.destroy()


# -- 7. the mass-spring pendulum: a Coulomb pivot torque ------------------------------------------
PEND_L, PEND_G = 0.15, 9.81


def _pendulum(tmp_path, theta0, dry, speed, integrator, step, end):
    """A 0.1 kg point mass on a stiff spring (k = 1e5 N/m) from a fixed pivot, released at rest
    at theta0 from hanging, with dry friction on the bob."""
    L = PEND_L
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -L]])
    mesh = SpringMesh(pts, np.array([[0, 1]]), np.zeros((0, 3), np.int64))
    ux, uz = L * np.sin(theta0), L * (1.0 - np.cos(theta0))
    return _spring_experiment(
        tmp_path, mesh, {"stiffness": 1e5, "node_mass": 0.0},
        mass=[{"at": [0.0, 0.0, -L], "value": 0.1}],
        gravity={"acceleration": [0.0, 0.0, -PEND_G]},
        boundary=[{"kind": "fixed", "where": "x*x + y*y + z*z < 1e-12"}],
        initial={"displacement": [f"{-ux / L!r}*z", "0", f"{-uz / L!r}*z"]},
        friction={"dry": dry, "speed": speed},
        time={"end": end, "step": step, "integrator": integrator})


def test_pendulum_dry_friction_is_a_coulomb_pivot_torque(tmp_path):
    """Midpoint run of the pendulum (theta0 = 0.2 rad, dry = 0.2 m/s^2): between consecutive
    turning points theta_a -> theta_b the work of the constant tangential force equals the
    potential energy lost, g (cos theta_b - cos theta_a) = dry (theta_a + theta_b) (per unit
    mass and length L): the amplitude decrement (~2 dry/g = 0.041 rad per swing) matches the
    solution of that relation to 0.5 % (measured 0.13 %)."""
    from scipy.optimize import brentq

    h, dry, end = 1e-3, 0.2, 1.25
    exp = _pendulum(tmp_path, 0.2, dry, 1e-4, "midpoint", h, end)
    # one free node: every rank runs the whole pendulum alone (a 2-rank split of two nodes only
    # costs communication; the terms' parallel layout is tested on the plate and the bar)
    s = MassSpringSystem(build_mass_spring_model(exp, PETSc.COMM_SELF))
    integ = ImplicitIntegrator(s, "midpoint")
    q, v = s.initial_state()
    q1, v1 = q.duplicate(), v.duplicate()
    theta = []
    for n in range(int(round(end / h))):
        x = s.points + s.dmesh.to_all(q)
        theta.append(np.arctan2(x[1, 0], -x[1, 2]))
        rep = integ.step(n * h, q, v, h, q1, v1)
        assert rep.converged, rep.reason
        q1.copy(q)
        v1.copy(v)
    theta = np.array(theta)
    # turning points: extrema of theta, refined by a parabola through three samples
    k = np.flatnonzero((np.abs(theta[1:-1]) >= np.abs(theta[:-2]))
                       & (np.abs(theta[1:-1]) > np.abs(theta[2:]))) + 1
    ym, y0, yp = theta[k - 1], theta[k], theta[k + 1]
    peaks = np.abs(y0 - 0.125 * (yp - ym) ** 2 / (yp - 2 * y0 + ym))
    peaks = np.concatenate([[0.2], peaks])
    assert len(peaks) >= 4
    measured = peaks[:-1] - peaks[1:]
    predicted = np.array([a - brentq(lambda b, a=a: PEND_G * (np.cos(b) - np.cos(a))
                                     - dry * (a + b), 0.0, a) for a in peaks[:-1]])
    _print(f"pendulum turning angles {peaks}; decrements {measured} vs {predicted}")
    np.testing.assert_allclose(measured, predicted, rtol=5e-3)
    integ.destroy()
    s.destroy()


@pytest.mark.parametrize("method", ["be", "si"])
def test_pendulum_gradient_with_dry_friction(tmp_path, method):
    """The mass-spring forward model (generic derivative path) through a turning point of the
    pendulum: Taylor remainders of the adjoint gradient of order 2, adjoint == forward."""
    exp = _pendulum(tmp_path, 0.2, 0.3, 0.02, method, 5e-3, 0.5)
    names = ["friction.dry", "damping.mass", "gravity.acceleration.z"]
    exp = with_parameters(exp, {"damping.mass": 0.2})
    fm = ForwardModel(exp, names, lambda s: MarkerObserver(s, [[0.0, 0.0, -PEND_L]]),
                      [0.1, 0.25, 0.4, 0.5], comm=PETSc.COMM_SELF)   # one free node: see above
    p = fm.p0.copy()
    sim0 = fm.simulate(p)
    dphi = _misfit(sim0 + 1e-3 * np.random.default_rng(2).standard_normal(sim0.shape))
    value, grad = fm.gradient(p, dphi)
    _, jac = fm.jacobian(p)
    g_fwd = np.einsum("kmc,kmcp->p", dphi(sim0)[1], jac)
    err = np.abs((grad - g_fwd) * np.abs(p)).max() / np.abs(grad * np.abs(p)).max()
    assert err < 1e-9, err
    d = np.array([0.3, 0.2, -1.0]) * np.array([1.0, -1.0, 1.0])
    rem = [abs(dphi(fm.simulate(p + e * d))[0] - value - e * grad @ d)
           for e in 2e-2 * 2.0 ** -np.arange(5)]
    orders = _orders(rem)
    _print(f"pendulum {method}: remainders {np.array(rem)} orders {orders}; grad {grad}")
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    fm.destroy()


# -- 8. every integrator runs with the terms; TAO == SNES; explicit refuses a stiff friction ------
ALL_TERMS = {"drag": {"linear": 50.0, "quadratic": 2000.0}, "friction": {"dry": 2.0,
                                                                         "speed": 0.05}}


@pytest.mark.parametrize("integrator,extra", [
    ("be", {}), ("si", {}), ("midpoint", {}), ("trapezoidal", {}), ("alpha", {}),
    ("alpha", {"alpha_backend": "ts"}), ("explicit", {}), ("ere", {}), ("imex", {})])
def test_every_integrator_dissipates_with_the_terms(integrator, extra):
    """A 10 ms run of the bar with all three terms: the booked dissipation is positive, nothing
    is NaN, and the energy lost matches an independent scheme for the same ODE: at least 70 % of
    the midpoint rule's (consistent mass; BE/SI/alpha add numerical damping; the midpoint rule
    against the trapezoidal one), or for the lumped-mass
    schemes explicit and ERE each other within 2 % (measured 0.1 %; the lumped ODE of this
    coarse bar loses half the energy the consistent one does, with or without these terms)."""
    from petsoft.dynamics.energy import FIELDS
    from petsoft.dynamics.simulate import Simulation

    lumped = {"explicit": "ere", "ere": "explicit"}
    reference = lumped.get(integrator, "trapezoidal" if integrator == "midpoint" else "midpoint")
    losses = {}
    for name, opts in ((reference, {}), (integrator, extra)):
        h = 2e-5 if name == "explicit" else 5e-4
        exp = _bar(name, **ALL_TERMS)
        exp = experiment_from_dict({**exp.to_dict(), "time": {"end": 0.01, "step": h,
                                                              "integrator": name}})
        sim = Simulation(build_model(exp), exp, **opts)
        e = sim.run().energies
        sim.system.destroy()
        assert np.all(np.isfinite(e))
        assert e[-1, FIELDS.index("dissipated")] > 0.0
        total = e[:, FIELDS.index("kinetic")] + e[:, FIELDS.index("elastic")]
        losses[name] = 1 - total[-1] / total[0]
    _print(f"{integrator} {extra}: energy loss {losses[integrator]:.4f} ({reference} "
           f"{losses[reference]:.4f})")
    ratio = losses[integrator] / losses[reference]
    if integrator in lumped:
        assert abs(ratio - 1.0) < 0.02, ratio
    else:
        assert ratio > 0.7, ratio


def test_tao_step_equals_snes_step():
    """Backward Euler as a minimisation (TAO: the incremental potential with the drag and
    friction dissipation potentials) reaches the SNES solution of the same step."""
    exp = _bar(**ALL_TERMS)
    model = build_model(exp)
    s = DynamicSystem(model)
    q, v = s.initial_state()
    out = []
    for solver in ("snes", "tao"):
        integ = ImplicitIntegrator(s, "be", solver=solver)
        q1, v1 = q.duplicate(), v.duplicate()
        for n in range(3):
            assert integ.step(n * 1e-3, q if n == 0 else q1, v if n == 0 else v1, 1e-3,
                              q1, v1).converged
        out.append(q1.getArray().copy())
        integ.destroy()
    scale = s.comm.tompi4py().allreduce(np.abs(out[0]).max(), op=MPI.MAX)
    diff = s.comm.tompi4py().allreduce(np.abs(out[0] - out[1]).max(),
                                       op=MPI.MAX)
    assert diff < 1e-7 * scale, diff / scale
    s.destroy()


def test_explicit_refuses_a_step_above_the_friction_limit():
    from petsoft.dynamics.explicit import ExplicitIntegrator

    exp = _bar(friction={"dry": 10.0, "speed": 1e-3})     # viscous rate 1e4 1/s: h < 2e-4
    model = build_model(exp)
    s = DynamicSystem(model)
    q, _ = s.initial_state()
    integ = ExplicitIntegrator(s)
    with pytest.raises(ExperimentError, match="regularised dry friction"):
        integ.check_step(q, 5e-4)
    assert integ.check_step(q, 1e-5) > 1e-5
    s.destroy()
    # linear drag: rate c_l A_i / m_i; the bar's lightest surface node (a corner) has
    # A_i / m_i = (sum of its faces' A/3) / (sum of its cells' rho V / 4)
    exp = _bar(drag={"linear": 2e4})
    model = build_model(exp)
    s = DynamicSystem(model)
    vt = s.velocity_terms
    rate = s.comm.tompi4py().allreduce(vt.rate_bound(), op=MPI.MAX)
    area = np.einsum("pii->p", vt.laws["drag.linear"].S)
    expected = 2e4 * s.comm.tompi4py().allreduce(float(np.max(area / vt.node_mass)),
                                                 op=MPI.MAX)
    assert rate == pytest.approx(expected) and rate > 0
    q, _ = s.initial_state()
    integ = ExplicitIntegrator(s)
    with pytest.raises(ExperimentError, match="drag.linear"):
        integ.check_step(q, 2.5 / rate)
    s.destroy()


def test_mass_spring_residual_parameter_derivatives(tmp_path):
    """Mass-spring plate with all three terms: every parameter derivative of the residual
    (node_mass includes the friction's mass) against a central difference (1e-6); with v_lin
    the velocity terms' derivatives are those of the step linearised at v_lin."""
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    mesh = SpringMesh(pts, np.zeros((0, 2), np.int64), np.array([[0, 1, 2], [0, 2, 3]]))
    exp = _spring_experiment(tmp_path, mesh, {"stiffness": 10.0, "node_mass": 0.3,
                                              "damping": 0.2},
                             gravity={"acceleration": [0, 0, -9.81]},
                             boundary=[{"kind": "fixed", "where": "x < 0.1 and y < 0.1"}],
                             drag={"linear": 0.7, "quadratic": 1.3},
                             friction={"dry": 0.9, "speed": 0.1, "where": "x > 0.5"})
    s = _ms_system(exp)
    names = s.parameter_names()
    assert set(VNAMES) <= set(names)
    rng = np.random.default_rng(4)

    def vec(scale):
        x = s.create_vec()
        x.setArray(scale * rng.standard_normal(x.getLocalSize()))
        return x
    q, v, a, vl = vec(0.05), vec(1.0), vec(3.0), vec(1.0)

    def residual(values):
        return semi_discrete_residual(s, values, q, v, a).getArray().copy()
    base = s.get_parameters()
    base = {n: base[n] for n in names}
    vecs = [x.getArray().copy() for x in s.residual_parameter_derivatives(names, q, v, a)]
    for name, dv in zip(names, vecs, strict=True):
        e = 1e-6 * max(abs(base[name]), 1.0)
        fd = (residual({**base, name: base[name] + e})
              - residual({**base, name: base[name] - e})) / (2 * e)
        np.testing.assert_allclose(fd, dv, atol=1e-6 * max(np.abs(dv).max(), 1e-3),
                                   err_msg=name)
    s.set_parameters(base)
    # linearised at v_lin: G(v_lin) + G'(v_lin)(v - v_lin), checked against the kernels
    lin = s.residual_parameter_derivatives(VNAMES, q, v, a, v_lin=vl)
    vt = s.velocity_terms
    varr, larr = (x.getArray(readonly=True).reshape(-1, 3) for x in (v, vl))
    for name, x in zip(VNAMES, lin, strict=True):
        y = s.create_vec()
        y.getArray().reshape(-1, 3)[:] = (vt.unit_damping(name, larr) + np.einsum(
            "pij,pj->pi", vt.unit_blocks(name, larr), varr - larr))
        s.zero_prescribed(y)
        np.testing.assert_allclose(x.getArray(), y.getArray(), rtol=1e-12, atol=1e-14)
    s.destroy()
