"""Gradients of the forward model (petsoft.calibration.forward) and of the residual.

1. ``residual_parameter_derivatives`` of a damped, loaded two-material bar: Taylor test of
   r(p + eps d) in a random direction of all parameters (remainder order 2), and every parameter
   against a central difference; the reference stiffness K0 of every law is the linear one.
2. For be, si and alpha on a tiny FEM bar (box 4x1x1 cells, 5 steps, frames between steps), with
   a nonlinear (corotated) and the linear material: Taylor tests of the adjoint gradient of a
   least-squares misfit and of the forward-sensitivity directional derivative of the marker
   positions (observed order of the first-order remainder in [1.8, 2.2]); adjoint gradient ==
   forward-sensitivity gradient to 1e-10; forward sensitivities == central differences.
3. Serial == parallel: under ``mpiexec -n 2`` the gradient on COMM_WORLD equals the gradient each
   rank computes alone on COMM_SELF to 1e-10 (serially the two runs are on one rank each).
4. A static initial state (its derivative K dq0/dp = -dr/dp): Taylor and adjoint == forward.
5. User errors: an unknown parameter, an explicit integrator, invalid values (raised on every
   rank), a frame before the start.

``pytest -s`` prints the Taylor tables.
"""

from __future__ import annotations

import numpy as np
import pytest
from _residuals import semi_discrete_residual as _residual
from petsc4py import PETSc

from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.dynamics.system import DynamicSystem
from petsoft.errors import ExperimentError, SolverError
from petsoft.experiment import experiment_from_dict
from petsoft.fem.kernels import elastic as kernels
from petsoft.fem.kernels.tet import shape_gradients
from petsoft.physics.model import build_model
from petsoft.solvers.options import clear_options

NAMES = ["material.youngs_modulus", "material.poisson_ratio", "material.density",
         "damping.mass", "damping.stiffness", "gravity.acceleration.z",
         "material.youngs_modulus#0", "material.youngs_modulus#2"]
MARKERS = np.array([[0.3, 0.04, 0.04], [0.3, 0.0, 0.0], [0.15, 0.02, 0.04], [0.2, 0.01, 0.0]])
FRAMES = [0.003, 0.0075, 0.01]


@pytest.fixture
def light_forward_solver():
    """CG + Jacobi for the forward Newton steps of these 60-dof bars (GAMG's set-up per Newton
    iteration dominated the 2-rank run time); the sensitivity/adjoint solves keep their default
    (CG + GAMG), and the serial == parallel test keeps every default. Cleared afterwards."""
    opts = PETSc.Options()
    keys = ["fm_pc_type", "fm_static_pc_type", "fm_static_lift_pc_type"]
    for key in keys:
        opts.setValue(key, "jacobi")
    yield
    clear_options(keys)


def _print(*args):
    if PETSc.COMM_WORLD.getRank() == 0:
        print(*args)


def _bar(model="corotated", integrator="be", order=1, **extra):
    data = {
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [4, 1, 1]}, "order": order},
        "material": {"model": model, "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "damping": {"mass": 0.5, "stiffness": 0.002},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"displacement": ["0", "0", "0.3*x**2"], "velocity": ["0", "0.1*x", "0"]},
        "time": {"end": 0.01, "step": 2e-3, "integrator": integrator},
    }
    data.update(extra)
    return experiment_from_dict(data)


def _orders(remainders):
    r = np.asarray(remainders)
    return np.log2(r[:-1] / r[1:])


def _direction(p, seed=3):
    """A random direction scaled like each parameter (1 for a zero value)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.0, 1.0, len(p)) * np.where(p != 0.0, np.abs(p), 1.0)


# -- 1. residual derivatives ----------------------------------------------------------------------
def test_reference_stiffness_of_every_law_is_the_linear_one():
    """H_e(u = 0) v_e == grad W_e^linear(v_e) for every law and unit (mu, lambda): the
    damping-stiffness derivative uses the linear law's gradient for K0 v."""
    rng = np.random.default_rng(0)
    X = rng.random((20, 4, 3))
    dN, vol = shape_gradients(X)
    ok = vol > 0
    dN, vol = dN[ok], vol[ok]
    n = len(vol)
    v = rng.standard_normal((n, 12))
    for model in kernels.MODELS:
        for mu, lam in ((1.0, 0.0), (0.0, 1.0)):
            _, H = kernels.element_gradient_hessian(model, dN, vol, np.zeros((n, 12)),
                                                    np.full(n, mu), np.full(n, lam))
            g, _ = kernels.element_gradient_hessian("linear", dN, vol, v, np.full(n, mu),
                                                    np.full(n, lam), hessian=False)
            np.testing.assert_allclose(np.einsum("nij,nj->ni", H, v), g, atol=1e-12 * abs(g).max())


def _two_material_system(order=1):
    exp = _bar(order=order,
               material={"model": "corotated", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                         "density": 1000.0, "tip": {"youngs_modulus": 2e5, "density": 800.0}},
               region={"tip": {"where": "x > 0.2"}})
    s = DynamicSystem(build_model(exp), exp.damping.mass, exp.damping.stiffness)
    s.define_stiffness_groups(3)
    return s


def _state(s, seed=1):
    rng = np.random.default_rng(seed)
    vecs = []
    for scale in (0.01, 0.1, 1.0):
        x = s.create_vec()
        x.setArray(scale * rng.standard_normal(x.getLocalSize()))
        s.apply_prescribed(x, 0.0)
        vecs.append(x)
    return vecs



@pytest.mark.parametrize("order", [1, 2])
def test_residual_parameter_derivatives_taylor_and_central_differences(order):
    """r(p + eps d) - r(p) - eps R_p d falls as eps^2 (all parameters at once, Poisson's ratio
    and the E-nu coupling make r nonlinear in p); each derivative matches a central
    difference to 1e-6 (round-off of r / step). For 4- and 10-node tetrahedra."""
    s = _two_material_system(order)
    names = s.parameter_names()
    assert "material.tip.youngs_modulus" in names and "material.youngs_modulus#2" in names
    q, v, a = _state(s)
    base = dict(s.parameters.values)
    p = np.array([base[n] for n in names])
    vecs = s.residual_parameter_derivatives(names, q, v, a)
    r0 = _residual(s, base, q, v, a)
    d = _direction(p)
    lin = s.create_vec()
    lin.zeroEntries()
    for dj, vec in zip(d, vecs, strict=True):
        lin.axpy(dj, vec)
    rem = []
    for k in range(5):
        eps = 1e-2 * 2.0**-k
        r = _residual(s, dict(zip(names, p + eps * d, strict=True)), q, v, a)
        r.axpy(-1.0, r0)
        r.axpy(-eps, lin)
        rem.append(r.norm())
    orders = _orders(rem)
    _print(f"residual Taylor remainders {rem}, orders {orders}")
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    for name, vec in zip(names, vecs, strict=True):
        e = 1e-6 * max(abs(base[name]), 1.0)
        hi = _residual(s, {**base, name: base[name] + e}, q, v, a)
        lo = _residual(s, {**base, name: base[name] - e}, q, v, a)
        hi.axpy(-1.0, lo)
        hi.scale(1.0 / (2 * e))
        hi.axpy(-1.0, vec)
        assert hi.norm() <= 1e-5 * vec.norm() + 1e-9 * r0.norm() / e, name
    s.set_parameters(base)
    # the tip region's own parameter acts on its cells only, the default on the others
    tip = s.residual_parameter_derivatives(["material.tip.density"], q, v, a)[0]
    both = s.residual_parameter_derivatives(["material.density"], q, v, a)[0]
    assert tip.norm() > 0 and both.norm() > 0


# -- 2. forward model -----------------------------------------------------------------------------
def _forward(method, model, comm=None, order=1):
    exp = _bar(model, method, order)
    return ForwardModel(exp, NAMES, lambda s: MarkerObserver(s, MARKERS), FRAMES, comm=comm)


def _misfit(target):
    def dphi(sim):
        r = sim - target
        return 0.5 * float(np.sum(r * r)), r
    return dphi


CASES = [(m, mat, 1) for m in ("be", "si", "alpha") for mat in ("corotated", "linear")]
# 10-node tetrahedra through each integrator, with a nonlinear law
CASES += [(m, mat, 2) for m, mat in (("be", "neohookean"), ("si", "corotated"),
                                     ("alpha", "stvk"))]


@pytest.mark.parametrize("method,model,order", CASES)
def test_taylor_adjoint_and_forward_sensitivities(method, model, order, light_forward_solver):
    """Adjoint gradient and forward-sensitivity directional derivative: remainders of order 2;
    adjoint == forward sensitivities (1e-10, scaled by the parameters); forward sensitivities
    == central differences (1e-5)."""
    fm = _forward(method, model, order=order)
    p = fm.p0.copy()
    sim0 = fm.simulate(p)
    # a target the run does not meet, so the misfit's gradient is not small
    target = sim0 + 1e-3 * np.random.default_rng(5).standard_normal(sim0.shape)
    dphi = _misfit(target)
    value, grad = fm.gradient(p, dphi)
    sim1, jac = fm.jacobian(p)
    np.testing.assert_array_equal(sim0, sim1)
    assert value == pytest.approx(dphi(sim0)[0], rel=1e-14)
    # adjoint == forward sensitivities: the chain rule on the jacobian
    g_fwd = np.einsum("kmc,kmcp->p", sim0 - target, jac)
    scale = np.where(p != 0, np.abs(p), 1.0)
    err = np.abs((grad - g_fwd) * scale).max() / np.abs(grad * scale).max()
    _print(f"{method}/{model}: adjoint vs forward sensitivities {err:.2e}")
    assert err < 1e-10
    d = _direction(p)
    rem_phi, rem_sim = [], []
    for k in range(5):
        eps = 2e-2 * 2.0**-k
        sim = fm.simulate(p + eps * d)
        rem_phi.append(abs(dphi(sim)[0] - value - eps * grad @ d))
        rem_sim.append(np.linalg.norm(sim - sim0 - eps * jac @ d))
    o_phi, o_sim = _orders(rem_phi), _orders(rem_sim)
    _print(f"{method}/{model}: adjoint remainders {np.array(rem_phi)} orders {o_phi}")
    _print(f"{method}/{model}: forward remainders {np.array(rem_sim)} orders {o_sim}")
    assert np.all((o_phi > 1.8) & (o_phi < 2.2)), o_phi
    assert np.all((o_sim > 1.8) & (o_sim < 2.2)), o_sim
    # finite differences as a method, on two parameters
    fm2 = ForwardModel(_bar(model, method, order), NAMES[:2],
                       lambda s: MarkerObserver(s, MARKERS), FRAMES)
    fd = fm2.fd_jacobian(fm2.p0)
    rel = np.abs(fd - jac[..., :2]).max(axis=(0, 1, 2)) / np.abs(jac[..., :2]).max(axis=(0, 1, 2))
    assert np.all(rel < 1e-5), rel
    fm.destroy()
    fm2.destroy()


def test_si_third_derivative_term_is_needed_and_where_taylor_flattens(light_forward_solver):
    """SI on the corotated bar: with the central-difference third-derivative term T_w the
    adjoint Taylor remainder falls as eps^2 over eps = 2e-2 .. 4e-5 (and flattens near the
    round-off of the misfit, ~1e-19 below eps ~ 1e-7: printed); without it the remainder falls only
    as eps (order < 1.3 below eps = 3e-4), so the test above would catch a missing term."""
    fm = _forward("si", "corotated")
    p = fm.p0.copy()
    sim0 = fm.simulate(p)
    dphi = _misfit(sim0 + 1e-3 * np.random.default_rng(5).standard_normal(sim0.shape))
    d = _direction(p)
    eps = 2e-2 * 8.0 ** -np.arange(7)
    table = {}
    for with_t in (True, False):
        fm.step_derivatives.linear_material = not with_t      # True skips T_w
        value, grad = fm.gradient(p, dphi)
        table[with_t] = np.array([abs(dphi(fm.simulate(p + e * d))[0] - value - e * grad @ d)
                                  for e in eps])
    _print("eps         remainder with T_w   without")
    for e, a, b in zip(eps, table[True], table[False], strict=True):
        _print(f"{e:.3e}   {a:.3e}            {b:.3e}")
    with_orders = np.log(table[True][:-1] / table[True][1:]) / np.log(8.0)
    without = np.log(table[False][:-1] / table[False][1:]) / np.log(8.0)
    assert np.all((with_orders[:4] > 1.8) & (with_orders[:4] < 2.2)), with_orders
    assert np.all(without[2:] < 1.3), without
    fm.destroy()


class _InterfaceOnly:
    """A DynamicSystem seen through the three-method parameter interface only (as a mass-spring
    system offers it): no element-level ``parameter_derivatives``, no ``parameters`` (None, as
    :class:`petsoft.dynamics.interfaces.SystemDefaults` declares a capability a system lacks)."""

    HIDDEN = ("parameter_derivatives", "parameters", "model")

    def __init__(self, system, experiment):
        self._s, self._exp = system, experiment

    def __getattr__(self, name):
        if name in self.HIDDEN:
            return None
        return getattr(self._s, name)

    def initial_state(self, monitor=None):
        return self._s.initial_state(monitor)


@pytest.mark.parametrize("method", ["si", "alpha"])
def test_interface_only_system_gives_the_same_gradient(method, light_forward_solver):
    """Through the generic path (residual_parameter_derivatives only; SI's w term by a central
    difference in q) the adjoint gradient equals the native one to 1e-6."""
    exp = _bar("corotated", method)
    names = NAMES[:6]
    native = ForwardModel(exp, names, lambda s: MarkerObserver(s, MARKERS), FRAMES)
    system = DynamicSystem(build_model(exp), exp.damping.mass, exp.damping.stiffness)
    generic = ForwardModel(exp, names, lambda s: MarkerObserver(s, MARKERS), FRAMES,
                           system=_InterfaceOnly(system, exp))
    dphi = _misfit(MARKERS[None] + 0.01)
    v1, g1 = native.gradient(native.p0, dphi)
    v2, g2 = generic.gradient(generic.p0, dphi)
    np.testing.assert_array_equal(native.p0, generic.p0)
    scale = np.where(native.p0 != 0, np.abs(native.p0), 1.0)
    assert v1 == pytest.approx(v2, rel=1e-12)
    assert np.abs((g1 - g2) * scale).max() <= 1e-6 * np.abs(g1 * scale).max(), (g1, g2)
    native.destroy()
    generic.destroy()


@pytest.mark.parametrize("method", ["be", "si", "alpha"])
def test_cell_sensitivity_map_sums_to_the_gradients(method, light_forward_solver):
    """d phi / d E_cell and d phi / d rho_cell from the adjoint sweep: their sums are
    d phi / d material.youngs_modulus and d phi / d material.density, and the E map's sums over
    the Morton groups times E are the stiffness-field gradients (1e-10)."""
    fm = _forward(method, "corotated")
    dphi = _misfit(MARKERS[None] + 0.01)
    value, grad, maps = fm.cell_gradient(fm.p0, dphi)
    assert value == pytest.approx(dphi(fm.simulate(fm.p0))[0], rel=1e-14)
    cells = maps["youngs_modulus"]
    assert cells.shape == maps["density"].shape == (len(fm.system.dmesh.mesh.tets),)
    E = NAMES.index("material.youngs_modulus")
    assert cells.sum() == pytest.approx(grad[E], rel=1e-10)
    rho = NAMES.index("material.density")
    assert abs(grad[rho]) > 0.0
    assert maps["density"].sum() == pytest.approx(grad[rho], rel=1e-10)
    # the maps are not uniform: they say where
    assert np.ptp(maps["density"]) > 0.1 * np.abs(maps["density"]).max()
    from petsoft.dynamics.parameters import morton_groups

    mesh = fm.system.dmesh.mesh
    group = morton_groups(mesh.points, mesh.tets, fm.system.parameters.ngroups)
    for k in (0, 2):
        j = NAMES.index(f"material.youngs_modulus#{k}")
        assert 1e5 * cells[group == k].sum() == pytest.approx(grad[j], rel=1e-10)
    fm.destroy()


@pytest.mark.parametrize("method", ["be", "si", "alpha"])
def test_observed_accelerations(method, light_forward_solver):
    """observe = "acceleration" (frames at t = 0, between steps and at the end): the accelerations
    are those of the scheme (alpha's a_n; (v_n - v_n-1)/h for be/si; the consistent a0 at t = 0,
    which equals alpha's), adjoint == forward sensitivities, Taylor orders 2."""
    exp = _bar("corotated", method)
    frames = [0.0, 0.0031, 0.01]
    fm = ForwardModel(exp, NAMES, lambda s: MarkerObserver(s, MARKERS), frames,
                      observe="acceleration")
    p = fm.p0.copy()
    acc0 = fm.simulate(p)
    ref = ForwardModel(_bar("corotated", "alpha"), NAMES, lambda s: MarkerObserver(s, MARKERS),
                       [0.0], observe="acceleration").simulate(p)
    np.testing.assert_allclose(acc0[0], ref[0], rtol=1e-12, atol=1e-12 * abs(ref).max())
    assert abs(acc0).max() > 1.0          # released from a bend: m/s^2, not a position
    dphi = _misfit(acc0 + 0.1 * np.random.default_rng(9).standard_normal(acc0.shape))
    value, grad = fm.gradient(p, dphi)
    _, jac = fm.jacobian(p)
    g_fwd = np.einsum("kmc,kmcp->p", dphi(acc0)[1], jac)
    scale = np.where(p != 0, np.abs(p), 1.0)
    err = np.abs((grad - g_fwd) * scale).max() / np.abs(grad * scale).max()
    d = _direction(p)
    rem_phi, rem_sim = [], []
    for k in range(4):
        eps = 2e-2 * 2.0**-k
        sim = fm.simulate(p + eps * d)
        rem_phi.append(abs(dphi(sim)[0] - value - eps * grad @ d))
        rem_sim.append(np.linalg.norm(sim - acc0 - eps * jac @ d))
    o_phi, o_sim = _orders(rem_phi), _orders(rem_sim)
    _print(f"accelerations/{method}: adjoint vs forward {err:.2e}; orders {o_phi} {o_sim}")
    assert err < 1e-8
    assert np.all((o_phi > 1.8) & (o_phi < 2.2)), o_phi
    assert np.all((o_sim > 1.8) & (o_sim < 2.2)), o_sim
    fm.destroy()


@pytest.mark.parametrize("method", ["be", "si", "alpha"])
def test_mass_spring_forward_model(tmp_path, method):
    """A [springs] experiment (a 6-node rope, pivot fixed, swinging under gravity) through the
    generic path (the mass-spring system's residual_parameter_derivatives; SI's w term by a
    central difference): adjoint == forward sensitivities, Taylor orders 2."""
    from pathlib import Path

    from petsoft.dynamics.mass_spring import rope_mesh
    from petsoft.mesh.springs import write_spring_mesh

    mpi = PETSc.COMM_WORLD.tompi4py()
    path = Path(mpi.bcast(str(tmp_path), root=0)) / "rope.vtu"
    mesh = rope_mesh(6, 1.0)
    if mpi.rank == 0:
        write_spring_mesh(path, mesh.points, mesh.lines, mesh.triangles)
    mpi.barrier()
    exp = experiment_from_dict({
        "mesh": {"file": str(path)},
        "springs": {"stiffness": 50.0, "node_mass": 0.02, "damping": 0.01},
        "damping": {"mass": 0.1},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "boundary": [{"kind": "fixed", "where": "x < 1e-6"}],
        "initial": {"velocity": ["0", "0.5*x", "0"]},
        "time": {"end": 0.1, "step": 0.01, "integrator": method}}, source="<rope>")
    names = ["springs.stiffness", "springs.damping", "springs.node_mass", "damping.mass",
             "gravity.acceleration.z"]
    markers = mesh.points[[2, 5]]
    fm = ForwardModel(exp, names, lambda s: MarkerObserver(s, markers), [0.035, 0.1])
    p = fm.p0.copy()
    np.testing.assert_array_equal(p, [50.0, 0.01, 0.02, 0.1, -9.81])
    sim0 = fm.simulate(p)
    dphi = _misfit(sim0 + 1e-3 * np.random.default_rng(11).standard_normal(sim0.shape))
    value, grad = fm.gradient(p, dphi)
    _, jac = fm.jacobian(p)
    g_fwd = np.einsum("kmc,kmcp->p", dphi(sim0)[1], jac)
    err = np.abs((grad - g_fwd) * p).max() / np.abs(grad * p).max()
    d = _direction(p)
    rem = [abs(dphi(fm.simulate(p + e * d))[0] - value - e * grad @ d)
           for e in 2e-2 * 2.0 ** -np.arange(4)]
    orders = _orders(rem)
    _print(f"springs/{method}: adjoint vs forward {err:.2e}; orders {orders}")
    assert err < 1e-8
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    fm.destroy()


# -- 3. serial == parallel ------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["be", "si", "alpha"])
def test_gradient_same_on_one_and_all_ranks(method):
    """The gradient on COMM_WORLD equals the one on COMM_SELF (every rank alone) to 1e-10."""
    dphi = _misfit(MARKERS[None] + 0.01)
    results = []
    for comm in (PETSc.COMM_WORLD, PETSc.COMM_SELF):
        fm = _forward(method, "corotated", comm)
        results.append(fm.gradient(fm.p0, dphi))
        scale = np.where(fm.p0 != 0, np.abs(fm.p0), 1.0)
        fm.destroy()
    (v_all, g_all), (v_one, g_one) = results
    assert v_all == pytest.approx(v_one, rel=1e-12)
    err = np.abs((g_all - g_one) * scale).max() / np.abs(g_one * scale).max()
    _print(f"{method}: gradient on all ranks vs one rank: {err:.2e}")
    assert err <= 1e-10, (g_all, g_one)


# -- 4. static initial state -----------------------------------------------------------------------
@pytest.mark.parametrize("method", ["be", "alpha"])
def test_static_initial_state_is_differentiated(method, light_forward_solver):
    """[initial] from = "static" (sag under gravity, then a kick): the initial state depends on
    E, nu, rho and g; adjoint == forward sensitivities and both Taylor remainders are order 2."""
    exp = _bar("corotated", method, initial={"from": "static", "velocity": ["0", "0.2*x", "0"]},
               gravity={"acceleration": [0.0, 0.0, -30.0]})
    fm = ForwardModel(exp, NAMES, lambda s: MarkerObserver(s, MARKERS), FRAMES)
    p = fm.p0.copy()
    sim0 = fm.simulate(p)
    # the static sag is there: the tip is below its reference at the first frame
    assert sim0[0, 0, 2] < MARKERS[0, 2] - 1e-4
    dphi = _misfit(sim0 + 1e-3 * np.random.default_rng(7).standard_normal(sim0.shape))
    value, grad = fm.gradient(p, dphi)
    _, jac = fm.jacobian(p)
    g_fwd = np.einsum("kmc,kmcp->p", dphi(sim0)[1], jac)
    scale = np.where(p != 0, np.abs(p), 1.0)
    err = np.abs((grad - g_fwd) * scale).max() / np.abs(grad * scale).max()
    d = _direction(p)
    rem_phi, rem_sim = [], []
    for k in range(4):
        eps = 2e-2 * 2.0**-k
        sim = fm.simulate(p + eps * d)
        rem_phi.append(abs(dphi(sim)[0] - value - eps * grad @ d))
        rem_sim.append(np.linalg.norm(sim - sim0 - eps * jac @ d))
    o_phi, o_sim = _orders(rem_phi), _orders(rem_sim)
    _print(f"static/{method}: adjoint vs forward {err:.2e}; orders {o_phi} {o_sim}")
    assert err < 1e-8
    assert np.all((o_phi > 1.8) & (o_phi < 2.2)), o_phi
    assert np.all((o_sim > 1.8) & (o_sim < 2.2)), o_sim
    fm.destroy()


# -- 5. errors --------------------------------------------------------------------------------
def test_user_errors():
    obs = lambda s: MarkerObserver(s, MARKERS)  # noqa: E731
    with pytest.raises(ExperimentError, match="not a differentiable parameter.*valid"):
        ForwardModel(_bar(), ["material.youngs_modulu"], obs, FRAMES)
    with pytest.raises(ExperimentError, match="gradients are implemented for be, si, alpha"):
        ForwardModel(_bar(integrator="explicit"), NAMES[:1], obs, FRAMES)
    fm = ForwardModel(_bar(), NAMES, obs, FRAMES)
    bad = fm.p0.copy()
    bad[1] = 0.5           # Poisson's ratio: the error is raised on every rank, not only those
    with pytest.raises(ExperimentError, match=r"material.poisson_ratio.*\(-1, 0.5\)"):
        fm.simulate(bad)
    bad = fm.p0.copy()
    bad[7] = -1.0          # a stiffness multiplier whose cells may live on one rank only
    with pytest.raises(ExperimentError, match=r"youngs_modulus#2.*> 0"):
        fm.gradient(bad, _misfit(MARKERS[None]))
    fm.destroy()
    # a step that inverts elements: a clear error naming the step, no retry with halved steps
    crash = _bar("neohookean", initial={"velocity": ["0", "0", "3000*x"]})
    fm = ForwardModel(crash, NAMES[:1], obs, FRAMES)
    with pytest.raises(SolverError, match=r"forward model \(be\) step \d+ at t = .*No retry"):
        fm.simulate(fm.p0)
    fm.destroy()
    from petsoft.calibration.observation import ObservationError

    with pytest.raises(ObservationError, match="outside the simulated span"):
        ForwardModel(_bar(), NAMES[:1], obs, [-0.001, 0.002])
