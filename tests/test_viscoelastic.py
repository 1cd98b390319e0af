"""The standard linear solid ([viscoelastic], petsoft.physics.viscoelastic) against analytic truth.

* a bar's first mode: the discrete eigenvalues fitted (Prony) to the simulated modal coordinate
  equal the integrator's map of the roots of m s^2 + k + g k tau s/(1 + tau s) = 0 (backward
  Euler 1/(1 - h s), midpoint (1 + h s/2)/(1 - h s/2)); the fitted rates s_h = log(lambda)/h
  converge to the roots at order 1 (be) and 2 (midpoint);
* stress relaxation at a held stretch: the reaction goes from (1 + g) to 1 times the elastic
  force with time constant tau (the exact ramp-and-hold solution);
* the energy balance closes (midpoint to round-off; backward Euler's surplus is numerical);
* checkpoint restart bit for bit; serial == all ranks; bad input; the forward model.
"""

from pathlib import Path

import h5py
import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.dynamics.checkpoint import checkpoint_files
from petsoft.dynamics.simulate import Simulation, make_integrator
from petsoft.dynamics.system import DynamicSystem
from petsoft.errors import ExperimentError
from petsoft.experiment import experiment_from_dict, get_parameter, with_parameters
from petsoft.physics.model import build_model

L, A = 0.3, 0.04


def _experiment(material="linear", density=1000.0, **extra):
    data = {
        "mesh": {"box": {"size": [L, A, A], "cells": [4, 1, 1]}},
        "material": {"model": material, "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": density},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "output": {"directory": "unused"},
    }
    data.update(extra)
    return experiment_from_dict(data)


def _prony(y, k=3):
    """The k discrete eigenvalues of a sequence y_n = sum_i c_i lambda_i^n."""
    rows = np.column_stack([y[k - 1 - i:len(y) - 1 - i] for i in range(k)])
    c = np.linalg.lstsq(rows, y[k:], rcond=None)[0]
    return np.sort_complex(np.roots(np.r_[1.0, -c]).astype(complex))


# -- 1. a mode against the SLS characteristic equation ---------------------------------------------
@pytest.mark.parametrize("method,order", [("be", 1), ("midpoint", 2), ("alpha", 2)])
def test_first_mode_matches_the_sls_roots(method, order):
    """Linear cantilever with g = 0.5, tau = 1/omega_1 (the branch damps this mode most):
    started in its first mode (SLEPc), the modal coordinate y_n = phi^T M q_n is a sum of three
    discrete exponentials (four for generalized-alpha, r = 0.5: its acceleration is a state);
    Prony's fit of them equals the integrator's image of the roots of
    tau s^3 + s^2 + (1 + g) omega^2 tau s + omega^2 = 0 (be: 1/(1 - h s), midpoint:
    (1 + h s/2)/(1 - h s/2); 1e-8), and the fitted decay rate and frequency of the complex pair
    converge to the roots at the integrator's order."""
    from petsoft.solvers.modes import compute_modes

    g = 0.5
    model = build_model(_experiment(viscoelastic={"ratio": g}))
    modes = compute_modes(model, 1)
    w2, phi = float(modes.eigenvalues[0]), modes.modes[0]
    tau = 1.0 / np.sqrt(w2)
    roots = np.sort_complex(np.roots([tau, 1.0, (1.0 + g) * w2 * tau, w2]).astype(complex))
    pair = roots[np.abs(roots.imag) > 0]
    assert len(pair) == 2 and pair[0].real < -0.05 * np.sqrt(w2)   # a visibly damped mode
    system = DynamicSystem(model)
    system.set_parameters({"viscoelastic.relaxation_time": tau})
    Mphi = phi.duplicate()
    system.M.mult(phi, Mphi)
    period = 2.0 * np.pi / np.sqrt(w2)
    errors, steps = [], [period / 16, period / 32, period / 64]
    for h in steps:
        integ = make_integrator(system, method, alpha_radius=0.5)
        q, v = phi.copy(), phi.duplicate()
        v.zeroEntries()
        system.viscoelastic.reset(q)
        q1, v1 = q.duplicate(), v.duplicate()
        y = [q.dot(Mphi)]
        for n in range(int(round(period / h))):
            assert integ.step(n * h, q, v, h, q1, v1).converged
            q1.copy(q)
            v1.copy(v)
            y.append(q.dot(Mphi))
        lam = _prony(np.array(y), 4 if method == "alpha" else 3)
        if method != "alpha":
            image = 1.0 / (1.0 - h * roots) if method == "be" else \
                (1.0 + 0.5 * h * roots) / (1.0 - 0.5 * h * roots)
            image = np.sort_complex(image)
            assert np.abs(lam - image).max() <= 1e-8, (lam, image)
        s_h = np.log(lam) / h
        errors.append(max(np.abs(s_h - s).min() for s in pair))
        for x in (q, v, q1, v1):
            x.destroy()
        integ.destroy()
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    print(f"{method}: roots {roots}, errors of the fitted complex pair {errors}, orders {rates}")
    assert np.all(np.abs(rates - order) < 0.15), rates
    Mphi.destroy()
    modes.destroy()
    system.destroy()


# -- 2. stress relaxation --------------------------------------------------------------------------
def test_reaction_relaxes_from_one_plus_g_to_one():
    """A bar stretched by eps = 1% in T = 0.1 tau, then held (uniaxial: the x = 0 face slides,
    two corner nodes stop rigid motions): the end reaction follows the exact ramp-and-hold
    solution E A eps (1 + g (tau/T)(1 - e^-T/tau) e^-(t-T)/tau) within 1.5% of its viscous
    part, starts near (1 + g) E A eps, ends at E A eps, and decays with backward Euler's time
    constant h / log(1 + h/tau) (within 1.5% of tau at h = tau/50). Inertia is negligible
    (density 0.01)."""
    g, tau, T, eps, E, h = 0.8, 0.1, 0.01, 0.01, 1e5, 2e-3
    exp = _experiment(density=0.01, viscoelastic={"ratio": g, "relaxation_time": tau}, boundary=[
        {"kind": "fixed", "where": "x < 1e-9", "components": ["x"]},
        {"kind": "fixed", "where": "x < 1e-9 and y < 1e-9 and z < 1e-9",
         "components": ["y", "z"]},
        {"kind": "fixed", "where": f"x < 1e-9 and y > {A} - 1e-9 and z < 1e-9",
         "components": ["z"]},
        {"kind": "prescribed", "where": f"x > {L} - 1e-9", "components": ["x"],
         "displacement": [f"{eps * L}*min(t/{T}, 1)", "0", "0"]}])
    model = build_model(exp)
    s = DynamicSystem(model)
    dm = s.dmesh
    integ = make_integrator(s, "be")
    q, v = s.create_vec(), s.create_vec()
    q.zeroEntries()
    v.zeroEntries()
    s.viscoelastic.reset(q)
    q1, v1, f, fb = (s.create_vec() for _ in range(4))
    right = dm.mesh.points[:, 0] > L - 1e-9

    def reaction():
        s.internal_gradient(q, f)
        f.axpy(1.0, s.viscoelastic.stress_force(q, fb))
        return float(np.sum(MPI.COMM_WORLD.bcast(dm.gather_global(f))[right, 0]))

    n = int(round((T + 5 * tau) / h))
    force = [reaction()]
    for i in range(n):
        assert integ.step(i * h, q, v, h, q1, v1).converged
        q1.copy(q)
        v1.copy(v)
        force.append(reaction())
    force, t = np.array(force), h * np.arange(n + 1)
    elastic = E * A * A * eps
    exact = elastic * (1 + g * (tau / T) * (1 - np.exp(-T / tau)) * np.exp(-(t - T) / tau))
    hold = t >= T - 1e-12
    err = np.abs(force[hold] - exact[hold]).max() / (g * elastic)
    sel = hold & (t < T + 4 * tau)
    slope = np.polyfit(t[sel], np.log(force[sel] / elastic - 1.0), 1)[0]
    tau_fit = -1.0 / slope
    print(f"peak {force.max() / elastic:.5f} (1 + g = {1 + g}), final "
          f"{force[-1] / elastic:.5f}, max error {err:.3g} of g E A eps, fitted tau "
          f"{tau_fit:.6f} s")
    assert err < 0.015          # backward Euler: O(h/tau) = 2%
    # the instantaneous modulus: (1 + g) for an instant stretch, (1 + 0.95 g) for this ramp
    peak = force.max()
    assert abs(peak - exact[hold].max()) < 0.01 * g * elastic and peak > (1 + 0.9 * g) * elastic
    assert abs(force[-1] / elastic - 1.0) < 0.006                  # g e^-5 = 0.005 left
    assert abs(tau_fit - h / np.log1p(h / tau)) < 1e-5 * tau
    assert abs(tau_fit - tau) < 0.015 * tau
    for x in (q, v, q1, v1, f, fb):
        x.destroy()
    integ.destroy()
    s.destroy()


# -- 3. energy -------------------------------------------------------------------------------------
def _bent(method, g=0.5, h=1e-3, end=0.1, time_end=None, **extra):
    """A bent neo-Hookean cantilever released; g None: no [viscoelastic] table."""
    if g is not None:
        extra["viscoelastic"] = {"ratio": g, "relaxation_time": 0.02}
    return _experiment(material="neohookean", initial={"displacement": ["0", "0", "0.5*x**2"]},
                       time={"end": time_end or end, "step": h, "integrator": method},
                       **extra)


def test_energy_balance_closes():
    """Neo-Hookean bar, branch + Rayleigh damping + a moving support + a traction: with the
    midpoint rule kinetic + elastic (incl. the branch) + dissipated = E0 + work to 1e-9 of the
    energy scale, the branch's dissipation being a large part; backward Euler's imbalance is
    its numerical dissipation (>= 0, growing)."""
    extra = dict(damping={"mass": 0.2, "stiffness": 1e-5}, time_end=0.05,
                 boundary=[{"kind": "prescribed", "where": "x < 1e-9",
                            "displacement": ["0", "0", "0.01*sin(30*t)"]},
                           {"kind": "traction", "where": f"x > {L} - 1e-9",
                            "value": ["0", "100*t", "0"]}])
    rows = {}
    for method, g in (("midpoint", 0.5), ("midpoint", 0.0), ("be", 0.5)):
        exp = _bent(method, g=g, **extra)
        sim = Simulation(build_model(exp), exp)
        rows[method, g] = sim.run().energies
        sim.destroy()
    e = rows["midpoint", 0.5]
    scale = np.abs(e[:, 1:6]).max()
    print(f"midpoint: scale {scale:.4g} J, dissipated {e[-1, 4]:.4g} J (without the branch "
          f"{rows['midpoint', 0.0][-1, 4]:.4g} J), max |numerical| "
          f"{np.abs(e[:, 6]).max():.3g} J")
    assert np.abs(e[:, 6]).max() <= 1e-9 * scale
    assert e[-1, 4] > 2.0 * rows["midpoint", 0.0][-1, 4]        # the branch dissipates
    assert abs(e[-1, 5]) > 0.01 * scale
    be = rows["be", 0.5]
    assert be[-1, 6] > 1e-3 * scale and np.all(np.diff(be[:, 6]) >= -1e-10 * scale)


def test_ratio_zero_is_exactly_elastic():
    """[viscoelastic] ratio = 0 gives bit for bit the run without the table."""
    finals = []
    for exp in (_bent("be", g=0.0, end=0.01), _bent("be", g=None, end=0.01)):
        sim = Simulation(build_model(exp), exp)
        res = sim.run()
        finals.append((res.q.getArray().copy(), res.energies))
        sim.destroy()
    assert np.array_equal(finals[0][0], finals[1][0])
    assert np.array_equal(finals[0][1], finals[1][1])


def test_tao_potential_has_the_branch_force_as_gradient():
    """--solver tao minimises backward Euler's incremental potential: with the branch term
    g (1 + r)/2 |(q1 - z0)/(1 + r)|^2_K0 its central difference along a random direction equals
    the gradient (the step residual with the branch force) to 1e-6."""
    from petsoft.dynamics.implicit import ImplicitIntegrator

    s = DynamicSystem(build_model(_bent("be")))
    integ = ImplicitIntegrator(s, "be", solver="tao")
    rng = np.random.default_rng(MPI.COMM_WORLD.rank)

    def random(scale):
        x = s.create_vec()
        x.setArray(scale * rng.normal(size=x.getLocalSize()))
        s.zero_prescribed(x)
        return x

    q0, v0, z, d, grad, work = (random(1e-3), random(1e-2), random(1e-3), random(1e-3),
                                s.create_vec(), s.create_vec())
    s.viscoelastic.restore(z)
    integ.prepare(0.0, q0, v0, 1e-3)
    x = q0.copy()
    x.axpy(1e-3, v0)
    integ._objective_cb(None, x, grad)
    slope = grad.dot(d)
    values = []
    for sign in (1.0, -1.0):
        y = x.copy()
        y.axpy(sign * 1e-3, d)
        values.append(integ._objective_cb(None, y, work))
        y.destroy()
    central = (values[0] - values[1]) / 2e-3
    assert abs(central - slope) <= 1e-6 * abs(slope)
    # the branch term is a sizeable part of the potential (the check is not vacuous)
    total = integ._objective_cb(None, x, work)
    assert integ._branch.incremental_potential(x, work) > 1e-3 * abs(total)
    for v in (q0, v0, z, d, grad, work, x):
        v.destroy()
    integ.destroy()
    s.destroy()


# -- 4. checkpoints and ranks ----------------------------------------------------------------------
def _shared_dir(tmp_path_factory, name):
    comm = MPI.COMM_WORLD
    return Path(comm.bcast(str(tmp_path_factory.mktemp(name)) if comm.rank == 0 else None))


def _run(exp, out, restart=False, comm=None):
    model = build_model(exp, comm)
    sim = Simulation(model, exp, out=out)
    result = sim.run(restart=restart)
    q = MPI.COMM_WORLD.bcast(model.dmesh.gather_global(result.q))
    probes = MPI.COMM_WORLD.bcast(np.array(result.probe_displacements))
    energies = result.energies.copy()
    sim.destroy()
    return q, probes, energies


@pytest.mark.parametrize("method", ["be", "midpoint", "alpha"])
def test_restart_is_bitwise(tmp_path_factory, method):
    """Stop after the step-10 checkpoint (later ones deleted, as if the run died), restart:
    final state, probes and energies equal the uninterrupted run bit for bit; the checkpoint
    holds the branch's internal variable z (/state/z)."""
    base = _shared_dir(tmp_path_factory, f"visco-restart-{method}")

    def exp(out):
        return _bent(method, end=0.03, output={"directory": str(out), "checkpoint_every": 10,
                                               "probes": [[L, A / 2, A / 2]]})

    full = _run(exp(base / "full"), base / "full")
    _run(exp(base / "cut"), base / "cut")
    if MPI.COMM_WORLD.rank == 0:
        files = checkpoint_files(base / "cut" / "checkpoints")
        with h5py.File(files[0][1]) as f:
            assert f["state/z"].shape == f["state/q"].shape
            assert not np.array_equal(f["state/z"][()], f["state/q"][()])
        for step, path in files:
            if step > 10:
                path.unlink()
    MPI.COMM_WORLD.barrier()
    again = _run(exp(base / "cut"), base / "cut", restart=True)
    assert np.array_equal(full[0], again[0])
    assert np.array_equal(full[1], again[1])
    assert np.array_equal(full[2], again[2])


@pytest.mark.parametrize("method", ["be", "si", "midpoint", "trapezoidal", "alpha"])
def test_one_rank_equals_all_ranks(method):
    """The probe trajectory and final state on COMM_SELF equal those on COMM_WORLD (1e-10)."""
    exp = _bent(method, end=0.02, output={"directory": "unused", "probes": [[L, A / 2, A / 2]]})
    runs = []
    opts = PETSc.Options()
    opts.setValue("ksp_rtol", "1e-13")
    try:
        for comm in (PETSc.COMM_SELF, PETSc.COMM_WORLD):
            runs.append(_run(exp, None, comm=comm))
    finally:
        opts.delValue("ksp_rtol")
    (qa, pa, _), (qb, pb, _) = runs
    assert pa.size and np.abs(pa - pb).max() <= 1e-10 * np.abs(pa).max()
    assert np.abs(qa - qb).max() <= 1e-10 * np.abs(qa).max()


# -- 5. bad input ----------------------------------------------------------------------------------
@pytest.mark.parametrize("table,match", [
    ({"ratio": -0.1}, r"viscoelastic\.ratio = -0\.1 is out of range: valid is ratio >= 0"),
    ({"relaxation_time": 0.0}, r"viscoelastic\.relaxation_time = 0\.0 is out of range: valid "
                               r"is relaxation_time > 0"),
    ({"relaxation_time": -1}, r"relaxation_time = -1 is out of range"),
    ({"ratio": "big"}, r"viscoelastic\.ratio = \"big\" has the wrong type"),
    ({"tau": 0.1}, r"unknown key viscoelastic\.tau.*Valid keys in \[viscoelastic\]: ratio, "
                   r"relaxation_time"),
])
def test_bad_tables_are_refused(table, match):
    with pytest.raises(ExperimentError, match=match):
        _experiment(viscoelastic=table)


def test_mass_spring_models_refuse_the_branch():
    with pytest.raises(ExperimentError, match=r"continuum \[material\] model, not on \[springs\]"):
        experiment_from_dict({"mesh": {"box": {"size": [1, 1, 1], "cells": [1, 1, 1]}},
                              "springs": {"stiffness": 10.0}, "viscoelastic": {"ratio": 1.0}})


@pytest.mark.parametrize("integrator", ["explicit", "ere", "imex"])
def test_unsupported_integrators_are_refused(integrator):
    exp = _bent(integrator)
    with pytest.raises(ExperimentError, match=rf"time.integrator = '{integrator}': "
                       r"\[viscoelastic\] ratio = 0.5 .* be, si, alpha, midpoint, trapezoidal "
                       "only"):
        Simulation(build_model(exp), exp)
    exp = _bent("alpha")
    with pytest.raises(ExperimentError, match="--alpha-backend ts does not include"):
        Simulation(build_model(exp), exp, alpha_backend="ts")


def test_parameters_set_in_place_and_validated():
    """viscoelastic.* are experiment parameters (get/with_parameters, to_dict round trip) and
    set_parameters changes them in place; invalid values are refused with the valid range."""
    exp = _bent("be")
    assert get_parameter(exp, "viscoelastic.relaxation_time") == 0.02
    changed = with_parameters(exp, {"viscoelastic.ratio": 2.0})
    assert changed.viscoelastic.ratio == 2.0
    assert experiment_from_dict(changed.to_dict()) == changed
    assert "viscoelastic" not in _experiment().to_dict()     # the default is not written
    with pytest.raises(ExperimentError, match=r"ratio = -1\.0 is out of range: valid is ratio >= "):
        with_parameters(exp, {"viscoelastic.ratio": -1})
    s = DynamicSystem(build_model(exp))
    s.set_parameters({"viscoelastic.ratio": 0.0, "viscoelastic.relaxation_time": 3.0})
    assert not s.viscoelastic.active and s.viscoelastic.tau == 3.0
    for bad, valid in (({"viscoelastic.ratio": -1.0}, ">= 0"),
                       ({"viscoelastic.relaxation_time": 0.0}, "> 0")):
        with pytest.raises(ExperimentError, match=f"{list(bad)[0]}.* must be {valid}"):
            s.set_parameters(bad)
    q = s.create_vec()
    q.zeroEntries()
    with pytest.raises(ExperimentError, match="not differentiable.*finite differences"):
        s.residual_parameter_derivatives(["viscoelastic.ratio"], q, q, q)
    assert "viscoelastic.ratio" not in s.parameter_names()
    q.destroy()
    s.destroy()


# -- 6. the forward model --------------------------------------------------------------------------
def _forward(method="be", names=("material.youngs_modulus", "viscoelastic.ratio"), **extra):
    from petsoft.calibration.forward import ForwardModel
    from petsoft.calibration.observation import MarkerObserver

    exp = _bent(method, end=0.02, **extra)
    return ForwardModel(exp, list(names),
                        lambda s: MarkerObserver(s, [[L, A / 2, A / 2], [L / 2, A, A]]),
                        np.array([0.01, 0.015, 0.02]))


def test_forward_model_simulates_and_refuses_the_adjoint():
    """ForwardModel.simulate and fd_jacobian work with the branch (each run starts relaxed:
    two runs agree bit for bit; the branch changes the markers); the adjoint gradient,
    cell_gradient and the si forward sensitivities refuse it, pointing to fd."""
    fm = _forward()
    p = fm.p0.copy()
    a, b = fm.simulate(p), fm.simulate(p)
    assert np.array_equal(a, b)
    elastic = fm.simulate(np.array([p[0], 0.0]))
    assert np.abs(a - elastic).max() > 1e-3 * np.abs(elastic - elastic[0]).max()
    jac = fm.fd_jacobian(p)
    assert np.isfinite(jac).all() and np.abs(jac[..., 1]).max() > 0.0

    def dphi(sim):
        return 0.5 * float(np.sum(sim**2)), sim

    for call in (lambda: fm.gradient(p, dphi), lambda: fm.cell_gradient(p, dphi)):
        with pytest.raises(ExperimentError, match=r"viscoelastic\.ratio.*--gradient fd"):
            call()
    fm.destroy()
    fm = _forward(names=["material.youngs_modulus"])
    with pytest.raises(ExperimentError, match=r"ratio = 0.5 \(the branch is on\).*--gradient fd"):
        fm.gradient(fm.p0, dphi)
    fm.destroy()
    fm = _forward("si", names=["material.youngs_modulus"])
    with pytest.raises(ExperimentError, match=r"forward sensitivities of si\)"):
        fm.jacobian(fm.p0)
    fm.destroy()


@pytest.mark.parametrize("method", ["be", "alpha"])
def test_forward_sensitivities_include_the_branch(method):
    """Backward Euler's and generalized-alpha's forward sensitivities with z as one more
    state (bent neo-Hookean bar, gravity, stiffness damping): the Taylor remainder
    |sim(p + eps d) - sim(p) - eps J d| falls at order 2 (in [1.8, 2.2]) for all parameters at
    once, including the branch's ratio and relaxation time, whose columns match central
    differences (1e-5)."""
    names = ["material.youngs_modulus", "material.poisson_ratio", "material.density",
             "damping.stiffness", "viscoelastic.ratio", "viscoelastic.relaxation_time"]
    fm = _forward(method, names=names, damping={"stiffness": 1e-4},
                  gravity={"acceleration": [0.0, 0.0, -9.81]})
    p = fm.p0.copy()
    sim, jac = fm.jacobian(p)
    # equal to Newton's tolerance: the sensitivity run's chord iterates on the tangent solves'
    # factors (tests/test_borrowed_chord.py), simulate's on its own
    np.testing.assert_allclose(sim, fm.simulate(p), rtol=0, atol=1e-12 * np.abs(sim).max())
    errors = []
    for j in (4, 5):        # the branch's own columns (test_sensitivity covers the others)
        e = 1e-6 * p[j]
        step = np.where(np.arange(len(p)) == j, e, 0.0)
        fd = (fm.simulate(p + step) - fm.simulate(p - step)) / (2.0 * e)
        errors.append(np.abs(jac[..., j] - fd).max() / np.abs(fd).max())
    d = np.array([0.3, -0.5, 0.7, 0.4, -0.6, 0.5]) * p
    lin = np.tensordot(jac, d, axes=([3], [0]))
    rem = np.array([np.abs(fm.simulate(p + e * d) - sim - e * lin).max()
                    for e in 1e-2 * 2.0 ** -np.arange(4)])
    orders = np.log2(rem[:-1] / rem[1:])
    print(f"relative differences to central differences {errors}; remainders {rem}, "
          f"orders {orders}")
    assert max(errors) < 1e-5
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    fm.destroy()


@pytest.mark.parametrize("method", ["be", "alpha"])
def test_sensitivity_to_the_ratio_at_zero(method):
    """At ratio 0 (a diagnosis' null hypothesis) z is still tracked, so d sim/d ratio exists
    (backward Euler, generalized-alpha): it matches the one-sided differences
    (sim(eps) - sim(0))/eps, whose error falls as eps (order in [0.8, 1.2]; central
    differences would need a negative ratio); d sim/d relaxation_time is 0 there. The markers
    at ratio 0 equal the elastic run's (to Newton's tolerance)."""
    names = ["viscoelastic.ratio", "viscoelastic.relaxation_time"]
    fm = _forward(method, names=names, g=0.0)
    p = fm.p0.copy()
    assert p[0] == 0.0
    sim, jac = fm.jacobian(p)
    elastic = _forward(method, names=["material.youngs_modulus"], g=None)
    np.testing.assert_allclose(sim, elastic.simulate(elastic.p0), rtol=0,
                               atol=1e-12 * np.abs(sim).max())
    elastic.destroy()
    assert np.all(jac[..., 1] == 0.0) and np.abs(jac[..., 0]).max() > 0.0
    errors = []
    for eps in (4e-2, 2e-2, 1e-2):
        fd = (fm.simulate(p + [eps, 0.0]) - sim) / eps
        errors.append(np.abs(fd - jac[..., 0]).max() / np.abs(jac[..., 0]).max())
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    print(f"one-sided difference errors {errors}, orders {orders}")
    assert errors[-1] < 0.05 and np.all(np.abs(orders - 1.0) < 0.2), orders
    fm.destroy()


def test_the_branchs_parameters_are_its_terms_declared_ones():
    """The branch's parameter names are its term's declared keys and proposal (a name changed
    in the declaration but not in the branch, or the reverse, fails here); the system's
    parameter map holds them at the branch's values and set_parameters reaches the branch."""
    from petsoft.physics.viscoelastic import NAMES
    from petsoft.terms import term

    declared = term("material.viscoelastic")
    assert NAMES == tuple(k.dotted for k in declared.keys)
    assert NAMES == tuple(q.name for q in declared.proposal.parameters)
    s = DynamicSystem(build_model(_bent("be")))
    assert s.viscoelastic.parameters() == {n: s.parameters.values[n] for n in NAMES}
    s.set_parameters(dict(zip(NAMES, (0.25, 0.04), strict=True)))
    assert (s.viscoelastic.ratio, s.viscoelastic.tau) == (0.25, 0.04)
    assert s.viscoelastic.parameters() == dict(zip(NAMES, (0.25, 0.04), strict=True))
    s.destroy()
