"""MassSpringSystem: Taylor tests, the backward-Euler amplitude law, integrators, contact, the
calibration interface, serial == 2 ranks, and the bad inputs of issue 4.

Runs serially and under ``mpiexec -n 2`` (every test collectively on every rank).
"""

import dataclasses
import os
from pathlib import Path

import h5py
import numpy as np
import pytest
from petsc4py import PETSc

from petsoft.dynamics.mass_spring import (
    MassSpringSystem,
    MassSpringWarning,
    build_mass_spring_model,
    cloth_mesh,
    rope_mesh,
)
from petsoft.dynamics.simulate import Simulation
from petsoft.errors import ExperimentError
from petsoft.experiment import experiment_from_dict, load_experiment
from petsoft.mesh.springs import write_spring_mesh

ROOT = Path(__file__).resolve().parents[1]


def _mesh_file(tmp_path, mesh, name="m.vtu"):
    path = tmp_path / name
    write_spring_mesh(path, mesh.points, mesh.lines, mesh.triangles)
    return path


def _experiment(tmp_path, mesh, springs, **extra):
    data = {"mesh": {"file": str(_mesh_file(tmp_path, mesh))}, "springs": springs, **extra}
    return experiment_from_dict(data, source="<test>")


def _shared(tmp_path):
    """Rank 0's temporary directory on every rank (outputs are written by rank 0)."""
    return Path(PETSc.COMM_WORLD.tompi4py().bcast(str(tmp_path), root=0))


def _read_probes(out):
    PETSc.COMM_WORLD.tompi4py().barrier()
    with h5py.File(out / "probes.h5", "r") as f:
        return f["frames/position"][:]


def _vec(system, field):
    return system.dmesh.from_file_field(np.asarray(field, float).reshape(-1, 3))


def _orders(rem, hs):
    rem = np.asarray(rem)
    return np.log(rem[1:] / rem[:-1]) / np.log(hs[1:] / hs[:-1])


def _rope_on_sphere(tmp_path, **springs):
    """A 6-node rope, pivot fixed, sagging onto a sphere (some nodes in contact), gravity."""
    exp = _experiment(
        tmp_path, rope_mesh(6, 1.0),
        {"stiffness": 50.0, "node_mass": 0.02, **springs},
        gravity={"acceleration": [0.0, 0.0, -9.81]},
        boundary=[{"kind": "fixed", "where": "x < 1e-6"}],
        collider=[{"kind": "sphere", "center": [0.7, 0.0, -0.45], "radius": 0.4}],
        time={"end": 0.1, "step": 0.01})
    return build_mass_spring_model(exp)


def test_system_force_and_jacobian_taylor(tmp_path):
    """grad W against W, and K(q) against grad W, on springs in tension and compression with
    sphere contact, assembled over the ranks."""
    model = _rope_on_sphere(tmp_path)
    s = MassSpringSystem(model)
    rng = np.random.default_rng(11)
    n = len(s.points)
    q_np = 0.05 * rng.normal(size=(n, 3))
    q_np[:, 2] -= 0.1 * s.points[:, 0]            # sag the rope into the sphere
    q_np[0] = 0.0
    x = s.points + q_np
    c = model.colliders[0]
    assert (c.distance(x)[0] < 0).sum() >= 1      # some contact
    lengths = np.linalg.norm(x[s.edges[:, 0]] - x[s.edges[:, 1]], axis=1)
    assert (lengths < s.rest_lengths).any() and (lengths > s.rest_lengths).any()
    q, dq = _vec(s, q_np), _vec(s, rng.normal(size=(n, 3)))
    W0 = s.elastic_energy(q)
    g0 = s.internal_gradient(q, s.create_vec())
    K = s.create_matrix()
    s.assemble_combination(q, 0.0, 1.0, 0.0, K, eliminate=False)
    Kdq = s.create_vec()
    K.mult(dq, Kdq)
    hs = 1e-4 * 0.5 ** np.arange(5)
    remW, remG = [], []
    qh, gh = s.create_vec(), s.create_vec()
    for h in hs:
        q.copy(qh)
        qh.axpy(h, dq)
        remW.append(abs(s.elastic_energy(qh) - W0 - h * g0.dot(dq)))
        s.internal_gradient(qh, gh)
        gh.axpy(-1.0, g0)
        gh.axpy(-h, Kdq)
        remG.append(gh.norm())
    for rem in (remW, remG):
        orders = _orders(rem, hs)
        assert np.all((orders > 1.8) & (orders < 2.2)), orders
    assert K.isSymmetric(1e-10)
    s.destroy()


def test_clamped_jacobian_is_psd(tmp_path):
    """The clamped Jacobian of a configuration with compressed springs and sphere contact has no
    negative eigenvalue; the exact one has (serially: dense eigenvalues of the gathered matrix)."""
    model = _rope_on_sphere(tmp_path)
    rng = np.random.default_rng(12)
    for clamp, expect_negative in ((True, False), (False, True)):
        s = MassSpringSystem(model, clamp=clamp)
        q_np = 0.3 * rng.normal(size=(len(s.points), 3))
        K = s.create_matrix()
        s.assemble_combination(_vec(s, q_np), 0.0, 1.0, 0.0, K, eliminate=False)
        dense = _gather_dense(K)
        lam = np.linalg.eigvalsh(dense)
        if clamp:
            assert lam.min() >= -1e-10 * abs(lam).max()
        else:
            assert (lam.min() < -1e-8 * abs(lam).max()) == expect_negative
        s.destroy()


def _gather_dense(A):
    """A parallel AIJ matrix as a dense array on every rank (small matrices)."""
    lo, hi = A.getOwnershipRange()
    n = A.getSize()[0]
    rows = np.zeros((n, n))
    for i in range(lo, hi):
        cols, vals = A.getRow(i)
        rows[i, cols] = vals
    return A.getComm().tompi4py().allreduce(rows)


def _single_mass(tmp_path, k, m, h, steps, integrator="be", **extra):
    exp = _experiment(
        tmp_path, rope_mesh(2, 1.0), {"stiffness": k},
        mass=[{"at": [1.0, 0.0, 0.0], "value": m}],
        boundary=[{"kind": "fixed", "where": "x < 0.5"}],
        initial={"displacement": ["0.01", "0", "0"]},
        time={"end": steps * h, "step": h, "integrator": integrator},
        output={"directory": str(tmp_path / "out"), "probes": [[1.0, 0.0, 0.0]]}, **extra)
    return exp, build_mass_spring_model(exp)


def test_be_amplitude_ratio_at_tau_omega_one(tmp_path):
    """Lecture 000: BE maps (q, v) by [[1, tau], [-tau w^2, 1]] / (1 + tau^2 w^2), eigenvalues
    1/(1 +- i tau w): at tau w = 1 the amplitude drops by 1/sqrt(2) per step. Measured from the
    probe trajectory (probes.h5) of a point mass on a spring along its axis (linear motion)."""
    k, m = 400.0, 4.0                          # w = 10 rad/s
    h = 0.1                                    # tau w = 1
    exp, model = _single_mass(tmp_path, k, m, h, 24)
    out = _shared(tmp_path) / "out"
    sim = Simulation(model, exp, out=out)
    sim.run()
    sim.destroy()
    x = _read_probes(out)[:, 0, 0] - 1.0
    # the per-step linear recurrence x[n+2] = a x[n+1] + b x[n] of the trajectory: the eigenvalues
    # solve z^2 - a z - b = 0, so |z| = sqrt(-b) and Re z = a/2
    A = np.column_stack([x[1:-1], x[:-2]])
    (a, b), *_ = np.linalg.lstsq(A, x[2:], rcond=None)
    assert np.sqrt(-b) == pytest.approx(1 / np.sqrt(2), rel=1e-8)
    assert a / 2 == pytest.approx(0.5, rel=1e-8)       # Re 1/(1 + i) = 1/2
    # and the whole trajectory is the analytic BE map of the lecture
    w2 = k / m
    T = np.array([[1.0, h], [-h * w2, 1.0]]) / (1 + h * h * w2)
    state, expect = np.array([0.01, 0.0]), [0.01]
    for _ in range(24):
        state = T @ state
        expect.append(state[0])
    assert np.allclose(x, expect, rtol=0, atol=1e-12)


def test_stiff_spring_pendulum_experiment(tmp_path):
    """scripts/examples/stiff_spring_pendulum.toml runs (BE, shortened): the bob keeps
    r ~ r0 + mg/k, BE
    never gains energy, and the swing starts downward."""
    exp = load_experiment(ROOT / "scripts" / "examples" / "stiff_spring_pendulum.toml")
    exp = dataclasses.replace(exp, time=dataclasses.replace(exp.time, end=0.2))
    model = build_mass_spring_model(exp)
    out = _shared(tmp_path) / "out"
    sim = Simulation(model, exp, out=out)
    result = sim.run()
    sim.destroy()
    pos = _read_probes(out)[:, 0]
    r = np.linalg.norm(pos, axis=1)
    assert np.all(np.abs(r - 1.0) < 10 * 9.81 / 1e6)   # the stiff spring barely stretches
    assert pos[-1, 2] < pos[0, 2] - 0.05                # it swings down
    E = result.energies[:, 1:4].sum(axis=1)
    assert np.all(np.diff(E) <= 1e-9)
    assert (out / "summary.json").exists()
    assert (out / "trajectory.xdmf").read_text().count('TopologyType="Polyline"')


ROPE = dict(nodes=5, length=0.4, stiffness=20.0, node_mass=0.01, g=9.81, end=0.04)


def _rope_reference() -> np.ndarray:
    """The hanging rope's node displacements at ``end``, by an independent route: the spring
    law (k (l - L) along the spring) and Newton's second law written here and integrated by
    scipy's DOP853 at a tolerance far below any integrator's error."""
    from scipy.integrate import solve_ivp

    n, k, m, g = ROPE["nodes"], ROPE["stiffness"], ROPE["node_mass"], ROPE["g"]
    X = rope_mesh(n, ROPE["length"], direction=(1.0, 0.0, -1.0)).points
    L = np.linalg.norm(X[1:] - X[:-1], axis=1)

    def rate(t, y):
        x, v = y[:3 * n].reshape(n, 3), y[3 * n:].reshape(n, 3).copy()
        d = x[1:] - x[:-1]
        length = np.linalg.norm(d, axis=1)
        pull = (k * (length - L) / length)[:, None] * d       # on node i, towards node i + 1
        a = np.zeros((n, 3))
        a[:-1] += pull
        a[1:] -= pull
        a = a / m + [0.0, 0.0, -g]
        a[0] = v[0] = 0.0                                      # the pivot is fixed
        return np.concatenate([v.ravel(), a.ravel()])

    y = solve_ivp(rate, (0.0, ROPE["end"]), np.concatenate([X.ravel(), np.zeros(3 * n)]),
                  method="DOP853", rtol=1e-13, atol=1e-15).y[:3 * n, -1]
    return y.reshape(n, 3) - X


@pytest.mark.parametrize("name, order", [("be", 1), ("si", 1), ("midpoint", 2),
                                         ("trapezoidal", 2), ("alpha", 2), ("explicit", 2),
                                         ("ere", 2)])
def test_integrators_converge_on_a_hanging_rope_at_their_order(tmp_path, name, order):
    """Every integrator steps a damped-free hanging rope released from straight; its node
    displacements at the end converge to the independent reference (_rope_reference) at the
    scheme's order as the step halves (measured: errors 3.9e-4 (be, si), 1.6e-6 (midpoint) to
    2.1e-7 (ere) m at h = 2 ms, of a motion of 7.8 mm); the discrete-gradient midpoint rule
    conserves the energy (the ledger's numerical column), BE only loses energy."""
    reference = _rope_reference()
    errors = []
    for h in (0.002, 0.001):
        exp = _experiment(
            tmp_path, rope_mesh(ROPE["nodes"], ROPE["length"], direction=(1.0, 0.0, -1.0)),
            {"stiffness": ROPE["stiffness"], "node_mass": ROPE["node_mass"]},
            gravity={"acceleration": [0.0, 0.0, -ROPE["g"]]},
            boundary=[{"kind": "fixed", "where": "x < 1e-6"}],
            time={"end": ROPE["end"], "step": h, "integrator": name})
        model = build_mass_spring_model(exp)
        sim = Simulation(model, exp)
        result = sim.run()
        q = PETSc.COMM_WORLD.tompi4py().bcast(model.dmesh.gather_global(result.q), root=0)
        sim.destroy()
        errors.append(float(np.abs(q.reshape(-1, 3) - reference).max()))
        E = result.energies
        scale = 0.04 * 9.81 * 0.4                              # m g L of the rope
        if name == "midpoint":
            assert abs(E[-1, -1]) < 1e-8 * scale
        if name == "be":
            assert np.all(np.diff(E[:, 1:4].sum(axis=1)) <= 1e-12 * scale)
    observed = np.log2(errors[0] / errors[1])
    assert abs(observed - order) < 0.15, (errors, observed)
    # and close: a tenth of the motion for the first-order schemes, 1e-3 of it for the others
    assert errors[0] < (0.1 if order == 1 else 1e-3) * np.abs(reference).max(), errors


def test_prescribed_node_drives_a_rope(tmp_path):
    """A prescribed support moving as 0.02 sin(20 t) in y drags a hanging rope sideways: the
    support follows its expression exactly, the far end responds, and the ledger books the
    support's work (external_work column) so that BE's energy balance stays non-negative."""
    exp = _experiment(
        tmp_path, rope_mesh(4, 0.3, direction=(0.0, 0.0, -1.0)),
        {"stiffness": 40.0, "node_mass": 0.01, "damping": 0.01},
        gravity={"acceleration": [0.0, 0.0, -9.81]},
        boundary=[{"kind": "prescribed", "where": "z > -1e-6",
                   "displacement": ["0", "0.02 * sin(20 * t)", "0"]}],
        time={"end": 0.1, "step": 0.005, "integrator": "be"})
    model = build_mass_spring_model(exp)
    sim = Simulation(model, exp)
    assert sim.system.moving_boundary
    result = sim.run()
    u = model.dmesh.to_all(result.q)
    assert u[0] == pytest.approx([0.0, 0.02 * np.sin(2.0), 0.0], abs=1e-14)
    assert abs(u[-1, 1]) > 1e-6                 # the far end feels it (the wave arrives)
    E = result.energies
    assert abs(E[-1, 5]) > 0.0                 # the support did work
    assert E[-1, 6] >= -1e-12                  # BE: numerical dissipation, never creation
    assert E[-1, 4] > 0.0                      # the dashpots dissipated
    sim.destroy()


def _cloth_on_sphere(tmp_path, integrator, comm=None, end=0.3):
    mesh = cloth_mesh(6, 6, 0.5, 0.5, z=0.05)
    exp = _experiment(
        tmp_path, mesh, {"stiffness": 50.0, "node_mass": 0.005, "bending": 1.0},
        gravity={"acceleration": [0.0, 0.0, -9.81]},
        collider=[{"kind": "sphere", "center": [0.25, 0.25, -0.2], "radius": 0.2}],
        time={"end": end, "step": 0.01, "integrator": integrator})
    return exp, build_mass_spring_model(exp, comm)


@pytest.mark.parametrize("name", ["be", "si"])
def test_cloth_on_sphere_energy_never_grows(tmp_path, name):
    """A cloth falls 5 cm onto a sphere and drapes: BE/SI total energy never increases, and no
    node penetrates deeper than the energy bound v_impact sqrt(m/k_c) (a node's whole kinetic
    energy at impact turned into penalty energy), with a factor 2 for the pull of its neighbours."""
    exp, model = _cloth_on_sphere(tmp_path, name)
    sim = Simulation(model, exp)
    depths = []
    s = sim.system
    c = model.colliders[0]
    step = sim.integrator.step

    def watched(t0, q0, v0, h, q1, v1):
        report = step(t0, q0, v0, h, q1, v1)
        if report.converged:        # a failed Newton solve is retried with half steps
            x = s.positions(q1)
            depths.append(float(np.maximum(-c.distance(x)[0], 0.0).max()))
        return report

    sim.integrator.step = watched
    result = sim.run()
    sim.destroy()
    E = result.energies[:, 1:4].sum(axis=1)
    scale = 36 * 0.005 * 9.81 * 0.05
    assert np.all(np.diff(E) <= 1e-10 * scale), np.diff(E).max()
    assert max(depths) > 0.0                                   # it did touch
    v_impact = np.sqrt(2 * 9.81 * 0.05)
    bound = 2 * v_impact * np.sqrt(0.005 / c.stiffness)
    print(f"{name}: max penetration {max(depths):.3e} m, bound {bound:.3e} m, k_c {c.stiffness:g}")
    assert max(depths) < bound, (max(depths), bound)


def test_friction_decelerates_a_sliding_pair_at_mu_g(tmp_path):
    """Two nodes joined by a spring slide together on a plane at v0 = 0.3 m/s with Coulomb
    friction mu = 0.5: the velocity drops by mu g per second (BE: exactly per step once the normal
    force is settled), they stop at v0 / (mu g) = 61 ms and stay at rest (Newton gets through the
    stick with the friction's velocity Jacobian, at most after a halved step), and the dissipated
    energy is the kinetic energy lost."""
    m, mu, g, v0, h = 0.1, 0.5, 9.81, 0.3, 0.002
    k_c = 4 * m / h ** 2                                  # the default contact stiffness
    sink = m * g / k_c                                    # equilibrium penetration
    exp = _experiment(
        tmp_path, rope_mesh(2, 0.1), {"stiffness": 100.0, "node_mass": m},
        gravity={"acceleration": [0.0, 0.0, -g]},
        collider=[{"kind": "plane", "point": [0, 0, 0], "normal": [0, 0, 1.0], "friction": mu}],
        initial={"displacement": ["0", "0", f"{-sink!r}"], "velocity": [f"{v0!r}", "0", "0"]},
        time={"end": 0.04, "step": h, "integrator": "be"})
    model = build_mass_spring_model(exp)
    assert model.colliders[0].stiffness == pytest.approx(k_c)
    sim = Simulation(model, exp)
    result = sim.run()
    vx = model.dmesh.to_all(result.v)[:, 0]
    assert np.allclose(vx, v0 - mu * g * 0.04, rtol=2e-3)
    E = result.energies
    lost = 0.5 * 2 * m * (v0 ** 2 - vx[0] ** 2)
    # BE books dq . f = h v1 . f per step: the kinetic energy lost minus BE's own numerical
    # dissipation 1/2 m (v0 - v1)^2 = 1/2 m (h mu g)^2 per node and step
    numerical = 20 * 2 * 0.5 * m * (h * mu * g) ** 2
    assert E[-1, 4] == pytest.approx(lost - numerical, rel=2e-3)      # dissipated column
    sim.destroy()
    exp = dataclasses.replace(exp, time=dataclasses.replace(exp.time, end=0.1))
    sim = Simulation(build_mass_spring_model(exp), exp)
    result = sim.run()
    assert result.retries <= 2        # the stick transition may need one halved step
    assert np.abs(sim.model.dmesh.to_all(result.v)).max() < 1e-3
    sim.destroy()


@pytest.mark.serial_only
def test_petsoft_simulate_command_on_the_pendulum(tmp_path):
    """`petsoft simulate` (the console command, 1 and 2 ranks) on the pendulum experiment with
    the clamped Jacobian: the same probe trajectory, XDMF with a line cell, summary.json."""
    import json
    import shutil
    import subprocess
    import sys

    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    for k in list(env):  # a child must not inherit this process's MPI singleton state
        if k.startswith(("OMPI_COMM_WORLD", "PMIX_", "OMPI_MCA_orte", "OMPI_MCA_ess")):
            env.pop(k)
    text = (ROOT / "scripts" / "examples" / "stiff_spring_pendulum.toml").read_text()
    (tmp_path / "p.toml").write_text(text.replace("end = 2.0", "end = 0.1"))
    shutil.copy(ROOT / "scripts" / "examples" / "stiff_spring_pendulum.msh", tmp_path)
    traj = []
    for ranks in (1, 2):
        out = tmp_path / f"out{ranks}"
        cmd = [sys.executable, "-m", "petsoft.cli.main", "simulate", "p.toml", "--out", str(out),
               "--integrator", "si", "--spd"]
        if ranks > 1:
            cmd = [shutil.which("mpiexec") or "mpiexec", "-n", str(ranks)] + cmd
        run = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, env=env,
                             timeout=300)
        assert run.returncode == 0, run.stderr
        summary = json.loads((out / "summary.json").read_text())
        assert summary["steps"] == 10 and summary["integrator"] == "si"
        assert summary["ranks"] == ranks
        traj.append(_read_probes(out))
    assert traj[0].shape == (11, 1, 3)
    assert np.allclose(traj[0], traj[1], rtol=0, atol=1e-12)


def test_serial_equals_two_ranks(tmp_path):
    """The same cloth-on-sphere run on this process alone (COMM_SELF) and over all ranks."""
    finals = []
    for comm in (PETSc.COMM_SELF, PETSc.COMM_WORLD):
        exp, model = _cloth_on_sphere(tmp_path, "be", comm, end=0.15)
        sim = Simulation(model, exp)
        result = sim.run()
        full = model.dmesh.to_all(result.q)
        finals.append((full, result.energies))
        sim.destroy()
    (q1, E1), (q2, E2) = finals
    assert np.max(np.abs(q1 - q2)) < 1e-9 * np.max(np.abs(q1))
    assert np.allclose(E1, E2, rtol=1e-8, atol=1e-12)


def test_residual_parameter_derivatives(tmp_path):
    """d r / d p against differences of r(p), per parameter (r is affine in each: the remainder is
    round-off) and along a joint direction (bilinear terms such as node_mass x damping.mass make
    the remainder O(h^2): order 2)."""
    mesh = cloth_mesh(3, 3, 0.2, 0.2)
    exp = _experiment(
        tmp_path, mesh, {"stiffness": 30.0, "node_mass": 0.01, "bending": 2.0, "damping": 0.3},
        damping={"mass": 0.5, "stiffness": 0.01},
        gravity={"acceleration": [0.1, 0.2, -9.81]},
        boundary=[{"kind": "fixed", "where": "x < 1e-6", "components": ["x", "z"]}])
    model = build_mass_spring_model(exp)
    s = MassSpringSystem(model, 0.5, 0.01)
    rng = np.random.default_rng(13)
    n = len(s.points)
    q, v, a = (_vec(s, rng.normal(size=(n, 3)) * sc) for sc in (0.02, 1.0, 5.0))
    names = s.parameter_names()
    assert "springs.bending" in names and "springs.node_mass" in names

    def residual():
        r, w = s.create_vec(), s.create_vec()
        s.M.mult(a, r)
        r.axpy(1.0, s.internal_gradient(q, w))
        r.axpy(1.0, s.damping_apply(v, w))
        r.axpy(-1.0, s.gravity)
        s.zero_prescribed(r)
        return r

    p0 = s.get_parameters()
    r0 = residual()
    derivs = s.residual_parameter_derivatives(names, q, v, a, 0.0)
    for name, d in zip(names, derivs, strict=True):
        assert d.norm() > 0.0, name
        for h in (1e-3, 1e-5):
            s.set_parameters({name: p0[name] + h})
            r = residual()
            r.axpy(-1.0, r0)
            r.axpy(-h, d)
            assert r.norm() <= 1e-7 * h * d.norm(), name
        s.set_parameters({name: p0[name]})
    direction = {nm: float(rng.uniform(0.5, 1.5)) * max(abs(p0[nm]), 1.0) for nm in names}
    lin = s.create_vec()
    for nm, d in zip(names, derivs, strict=True):
        lin.axpy(direction[nm], d)
    hs = 1e-2 * 0.5 ** np.arange(5)
    rem = []
    for h in hs:
        s.set_parameters({nm: p0[nm] + h * direction[nm] for nm in names})
        r = residual()
        r.axpy(-1.0, r0)
        r.axpy(-h, lin)
        rem.append(r.norm())
    s.set_parameters(p0)
    orders = _orders(rem, hs)
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    # observation helpers
    assert np.array_equal(s.vertex_points, mesh.points)
    dofs = s.vertex_global_dofs([0, 4])
    assert dofs.tolist() == [[0, 1, 2], [12, 13, 14]]
    s.destroy()


# -- bad input ------------------------------------------------------------------------------------

def test_zero_rest_length_spring_is_an_error(tmp_path):
    mesh = rope_mesh(3, 1.0)
    mesh.points[2] = mesh.points[1]
    with pytest.raises(ExperimentError, match=r"springs.pairs\[1\] joins nodes \[1, 2\].*rest "
                                              r"length > 0"):
        build_mass_spring_model(_experiment(
            tmp_path, mesh, {"stiffness": 1.0, "node_mass": 1.0, "pairs": [[0, 1], [1, 2]]}))


def test_node_in_no_spring(tmp_path):
    mesh = rope_mesh(4, 1.0)
    spr = {"stiffness": 1.0, "pairs": [[0, 1], [1, 2]]}
    with pytest.warns(MassSpringWarning, match=r"node\(s\) 3 belong to no spring"):
        build_mass_spring_model(_experiment(tmp_path, mesh, {**spr, "node_mass": 0.1}))
    with pytest.raises(ExperimentError, match=r"node\(s\) 1, 2, 3 are free but have no mass"):
        build_mass_spring_model(_experiment(
            tmp_path, mesh, spr, boundary=[{"kind": "fixed", "where": "x < 1e-6"}]))


@pytest.mark.parametrize("section, key", [
    ({"springs": {"stiffness": -1.0}}, "springs.stiffness"),
    ({"springs": {"stiffness": 1.0, "node_mass": -0.1}}, "springs.node_mass"),
    ({"springs": {"stiffness": 1.0, "damping": -2.0}}, "springs.damping"),
    ({"springs": {"stiffness": 1.0}, "mass": [{"at": [0, 0, 0], "value": -1.0}]},
     r"mass\[0\].value"),
])
def test_negative_stiffness_or_mass_is_an_error(tmp_path, section, key):
    path = _mesh_file(tmp_path, rope_mesh(2, 1.0))
    with pytest.raises(ExperimentError, match=key):
        experiment_from_dict({"mesh": {"file": str(path)}, **section}, source="<test>")


def test_mass_off_the_nodes_is_an_error(tmp_path):
    with pytest.raises(ExperimentError, match=r"mass\[1\].at = \[0.5, 0.0, 0.0\] is not a node.*"
                                              r"nearest node is 0"):
        build_mass_spring_model(_experiment(
            tmp_path, rope_mesh(2, 1.0), {"stiffness": 1.0, "node_mass": 1.0},
            mass=[{"at": [1.0, 0.0, 0.0], "value": 1.0}, {"at": [0.5, 0.0, 0.0], "value": 1.0}]))


def test_collider_containing_a_fixed_node_is_an_error(tmp_path):
    spr = {"stiffness": 1.0, "node_mass": 1.0}
    fixed = [{"kind": "fixed", "where": "x < 1e-6"}]
    with pytest.raises(ExperimentError, match=r"collider\[1\] \(plane.*supported node\(s\) 0"):
        build_mass_spring_model(_experiment(
            tmp_path, rope_mesh(3, 1.0), spr, boundary=fixed,
            collider=[{"kind": "sphere", "center": [5.0, 0, 0], "radius": 1.0},
                      {"kind": "plane", "point": [0.1, 0, 0], "normal": [1.0, 0, 0]}]))
    with pytest.warns(MassSpringWarning, match=r"collider\[0\].*node\(s\) 2 inside"):
        build_mass_spring_model(_experiment(
            tmp_path, rope_mesh(3, 1.0), spr, boundary=fixed,
            collider=[{"kind": "sphere", "center": [1.2, 0, 0], "radius": 0.3}]))


def test_probe_off_the_nodes_imex_and_tractions_are_errors(tmp_path):
    exp = _experiment(tmp_path, rope_mesh(2, 1.0), {"stiffness": 1.0, "node_mass": 1.0},
                      time={"end": 0.1, "step": 0.1}, output={"probes": [[0.5, 0.0, 0.0]]})
    with pytest.raises(ExperimentError, match=r"output.probes\[0\].*not a node"):
        Simulation(build_mass_spring_model(exp), exp)
    with pytest.raises(ExperimentError, match=r"imex .* does not apply to \[springs\]"):
        Simulation(build_mass_spring_model(exp), exp, integrator="imex")
    with pytest.raises(ExperimentError, match=r"boundary\[0\]: tractions"):
        build_mass_spring_model(_experiment(
            tmp_path, rope_mesh(2, 1.0), {"stiffness": 1.0, "node_mass": 1.0},
            boundary=[{"kind": "traction", "where": "x > 0.5", "value": [1.0, 0, 0]}]))

