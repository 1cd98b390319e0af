"""The local/global backward-Euler step (Liu et al. 2013) against an independent Newton solve.

The reference is a dense Newton method on the incremental potential written here with numpy
(exact spring and penalty-contact Hessians, backtracking on the potential), independent of
petsoft. Every test runs on every rank; under ``mpiexec -n 2`` the solver is distributed and
also compared with the same solver on one rank (COMM_SELF). Tests of the iteration itself
(thousands of plain iterations, options, limits) run on COMM_SELF on each rank: each iteration
has a dozen collective operations, which on an oversubscribed 2-core machine cost seconds.
"""

from pathlib import Path

import numpy as np
import pytest
from petsc4py import PETSc

from petsoft.dynamics.local_global import (
    LocalGlobalError,
    LocalGlobalSolver,
)
from petsoft.physics.colliders import Collider
from petsoft.solvers.options import clear_options

G = np.array([0.0, 0.0, -9.81])


def cloth(n=5, size=1.0, z=0.0):
    """Square grid of n x n nodes: structural, shear and bending (skip-one) springs."""
    xs = np.linspace(0.0, size, n)
    X = np.array([(x, y, z) for y in xs for x in xs])
    idx = np.arange(n * n).reshape(n, n)
    pairs = [(idx[:, :-1], idx[:, 1:]), (idx[:-1, :], idx[1:, :]),
             (idx[:-1, :-1], idx[1:, 1:]), (idx[:-1, 1:], idx[1:, :-1]),
             (idx[:, :-2], idx[:, 2:]), (idx[:-2, :], idx[2:, :])]
    edges = np.concatenate([np.stack([a.ravel(), b.ravel()], axis=1) for a, b in pairs])
    rest = np.linalg.norm(X[edges[:, 0]] - X[edges[:, 1]], axis=1)
    return X, edges, rest


def newton_reference(X, edges, rest, k, m, fixed, q0, v0, h, f, z, alpha=0.0, spheres=(),
                     tol=1e-12):
    """Backward-Euler step by dense Newton on the incremental potential (numpy only)."""
    n = len(m)
    k = np.broadcast_to(k, (len(edges),))
    free = ~np.repeat(np.asarray(fixed, bool)[:, None], 3, axis=1).ravel() \
        if np.asarray(fixed).ndim == 1 else ~np.asarray(fixed, bool).ravel()
    mm = np.repeat(m, 3)
    y = (q0 + h * v0).ravel()
    q00 = q0.ravel()

    def parts(q):
        x = X + q.reshape(n, 3)
        e = x[edges[:, 0]] - x[edges[:, 1]]
        ln = np.linalg.norm(e, axis=1)
        u = e / ln[:, None]
        phi = (0.5 / h**2 * mm @ (q - y) ** 2 + 0.5 * alpha / h * mm @ (q - q00) ** 2
               - f.ravel() @ q + 0.5 * np.sum(k * (ln - rest) ** 2))
        grad = mm * (q - y) / h**2 + alpha / h * mm * (q - q00) - f.ravel()
        fs = (k * (ln - rest))[:, None] * u
        gn = np.zeros((n, 3))
        np.add.at(gn, edges[:, 0], fs)
        np.add.at(gn, edges[:, 1], -fs)
        H = np.diag(mm / h**2 + alpha / h * mm)
        eye = np.eye(3)
        for s, (i, j) in enumerate(edges):
            uu = np.outer(u[s], u[s])
            B = k[s] * ((1 - rest[s] / ln[s]) * (eye - uu) + uu)
            for a, b, sign in ((i, i, 1), (j, j, 1), (i, j, -1), (j, i, -1)):
                H[3 * a:3 * a + 3, 3 * b:3 * b + 3] += sign * B
        for c, radius, kc in spheres:
            r = x - c
            dist = np.linalg.norm(r, axis=1)
            for a in np.flatnonzero(dist < radius):
                nrm = r[a] / dist[a]
                pen = radius - dist[a]
                phi += 0.5 * kc * pen**2
                gn[a] += -kc * pen * nrm
                nn = np.outer(nrm, nrm)
                H[3 * a:3 * a + 3, 3 * a:3 * a + 3] += kc * (nn - pen / dist[a] * (eye - nn))
        return phi, grad + gn.ravel(), H

    q = y.copy()
    q[~free] = z.ravel()[~free]
    for _ in range(100):
        phi, g, H = parts(q)
        g[~free] = 0.0
        if np.linalg.norm(g) < tol:
            return q.reshape(n, 3)
        dq = np.zeros_like(q)
        dq[free] = -np.linalg.solve(H[np.ix_(free, free)], g[free])
        step = 1.0
        while parts(q + step * dq)[0] > phi + 1e-4 * step * (g @ dq) and step > 1e-8:
            step *= 0.5
        q = q + step * dq
    raise AssertionError("reference Newton did not converge")


def setup_case(n=5, seed=0):
    rng = np.random.default_rng(seed)
    X, edges, rest = cloth(n)
    N = len(X)
    m = np.full(N, 0.02) * (1 + 0.5 * rng.random(N))
    k = 50.0 * (1 + rng.random(len(edges)))
    fixed = np.zeros(N, bool)
    fixed[[0, n - 1]] = True
    q0 = 0.01 * rng.standard_normal((N, 3))
    q0[fixed] = 0.0
    v0 = 0.3 * rng.standard_normal((N, 3))
    v0[fixed] = 0.0
    return X, edges, rest, k, m, fixed, q0, v0


def run(solver, q0, v0, h, f, z=None):
    vecs = [solver.from_array(a) for a in (q0, v0, f)]
    q1 = solver.create_vec()
    zv = solver.from_array(z) if z is not None else None
    rep = solver.solve(vecs[0], vecs[1], h, vecs[2], q1, prescribed=zv)
    out = solver.to_array(q1)
    for v in vecs + [q1] + ([zv] if zv is not None else []):
        v.destroy()
    return out, rep


@pytest.mark.parametrize("alpha", [0.0, 2.0])
def test_converges_to_newton_step(alpha):
    X, edges, rest, k, m, fixed, q0, v0 = setup_case()
    h = 0.02
    f = m[:, None] * G
    ref = newton_reference(X, edges, rest, k, m, fixed, q0, v0, h, f, q0, alpha=alpha)
    s = LocalGlobalSolver(edges, rest, k, m, X, fixed=fixed, damping_mass=alpha, rtol=1e-12,
                          atol=1e-11)
    q1, rep = run(s, q0, v0, h, f)
    s.destroy()
    assert rep.converged, rep.reason
    assert rep.factorizations == 1          # the matrix is factored once
    scale = np.abs(ref - q0).max()
    assert np.abs(q1 - ref).max() < 1e-8 * scale
    # the iteration is not trivially exact: the first iterate is far from the solution
    assert rep.residual_history[0] > 1e6 * rep.residual_history[-1]


def test_plain_iteration_decreases_the_potential_and_converges_linearly():
    X, edges, rest, k, m, fixed, q0, v0 = setup_case(seed=1)
    h = 0.02
    f = m[:, None] * G
    s = LocalGlobalSolver(edges, rest, k, m, X, fixed=fixed, anderson=0, rtol=1e-7, max_it=3000,
                          comm=PETSc.COMM_SELF)
    q1, rep = run(s, q0, v0, h, f)
    s.destroy()
    assert rep.converged and rep.anderson_rejections == 0
    phi = np.array(rep.potential_history)
    assert np.all(np.diff(phi) <= 1e-12 * np.abs(phi).max())   # alternating minimisation
    ref = newton_reference(X, edges, rest, k, m, fixed, q0, v0, h, f, q0)
    assert np.abs(q1 - ref).max() < 1e-4 * np.abs(ref - q0).max()


def test_anderson_acceleration_needs_fewer_iterations():
    X, edges, rest, k, m, fixed, q0, v0 = setup_case(n=4, seed=2)
    f = m[:, None] * G
    its = {}
    for window in (0, 5):
        s = LocalGlobalSolver(edges, rest, k, m, X, fixed=fixed, anderson=window, rtol=1e-6,
                              max_it=3000, comm=PETSc.COMM_SELF)
        _, rep = run(s, q0, v0, 0.05, f)
        s.destroy()
        assert rep.converged
        its[window] = rep.iterations
    assert its[5] < its[0] / 2, its


def test_moving_prescribed_nodes_and_component_masks():
    """Prescribed values at t1 differ from q0; one node fixed in z only (a different matrix)."""
    X, edges, rest, k, m, fixed, q0, v0 = setup_case(seed=3)
    N = len(m)
    mask = np.repeat(fixed[:, None], 3, axis=1)
    mask[N // 2, 2] = True
    z = np.zeros((N, 3))
    z[fixed] = [0.01, -0.02, 0.03]
    z[N // 2, 2] = -0.01
    q0 = q0.copy()
    q0[N // 2, 2] = 0.0
    h = 0.02
    f = m[:, None] * G
    ref = newton_reference(X, edges, rest, k, m, mask, q0, v0, h, f, z)
    s = LocalGlobalSolver(edges, rest, k, m, X, fixed=mask, rtol=1e-12, atol=1e-11)
    q1, rep = run(s, q0, v0, h, f, z=z)
    s.destroy()
    assert rep.converged and rep.factorizations == 2     # x, y share a pattern, z does not
    assert np.array_equal(q1[mask], z[mask])
    assert np.abs(q1 - ref).max() < 1e-8 * np.abs(ref - q0).max()


def test_sphere_contact_converges_to_newton_with_penalty():
    """A cloth thrown onto a sphere: the same quadratic penalty Newton solves."""
    n = 5
    X, edges, rest = cloth(n, size=0.6, z=0.0)
    X = X - [0.3, 0.3, 0.0]
    N = len(X)
    m = np.full(N, 0.01)
    k = 80.0
    fixed = np.zeros(N, bool)
    center, radius, kc = np.array([0.0, 0.0, -0.3]), 0.32, 2000.0
    q0 = np.zeros((N, 3))
    v0 = np.tile([0.0, 0.0, -1.5], (N, 1))
    h = 0.02
    f = m[:, None] * G
    ref = newton_reference(X, edges, rest, k, m, fixed, q0, v0, h, f, q0,
                           spheres=[(center, radius, kc)])
    inside = np.linalg.norm(X + ref - center, axis=1) < radius
    assert 0 < inside.sum() < N       # the case has contact, and not everywhere
    s = LocalGlobalSolver(edges, rest, k, m, X, fixed=fixed, rtol=1e-12, atol=1e-11,
                          colliders=[Collider.sphere(center, radius, kc)])
    q1, rep = run(s, q0, v0, h, f)
    qv = s.from_array(q1)
    depth = s.penetration(qv)
    qv.destroy()
    s.destroy()
    assert rep.converged, rep.reason
    assert 1 <= rep.factorizations <= 3    # the contact set grows rarely within a step
    assert np.abs(q1 - ref).max() < 1e-8 * np.abs(ref).max()
    ref_depth = np.maximum(0, radius - np.linalg.norm(X + ref - center, axis=1)).max()
    assert depth == pytest.approx(ref_depth, rel=1e-6)


def test_plane_contact_rest_state():
    """A single node resting on a plane under gravity: penetration m g / k_c exactly."""
    m = np.array([0.1, 0.1])
    X = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    kc = 1e4
    s = LocalGlobalSolver([[0, 1]], [1.0], 10.0, m, X, rtol=1e-13, atol=1e-13,
                          damping_mass=20.0, comm=PETSc.COMM_SELF,
                          colliders=[Collider.plane((0, 0, 0), (0, 0, 1), kc)])
    f = m[:, None] * G
    q = np.zeros((2, 3))
    v = np.zeros((2, 3))
    for _ in range(40):      # damped backward Euler relaxes to the static equilibrium
        q1, rep = run(s, q, v, 0.05, f)
        assert rep.converged
        v, q = (q1 - q) / 0.05, q1
    s.destroy()
    assert q[:, 2] == pytest.approx(-0.1 * 9.81 / kc, rel=1e-8)


def test_node_numbering_does_not_change_the_step():
    X, edges, rest, k, m, fixed, q0, v0 = setup_case(seed=4)
    f = m[:, None] * G
    s = LocalGlobalSolver(edges, rest, k, m, X, fixed=fixed, rtol=1e-12, atol=1e-11)
    a, _ = run(s, q0, v0, 0.02, f)
    s.destroy()
    perm = np.random.default_rng(4).permutation(len(m))
    s = LocalGlobalSolver(edges, rest, k, m, X, fixed=fixed, rtol=1e-12, atol=1e-11,
                          node_index=perm)
    b, _ = run(s, q0, v0, 0.02, f)
    s.destroy()
    assert np.abs(a - b).max() < 1e-12


def test_distributed_equals_one_rank():
    """Under mpiexec -n 2: the distributed solve equals the COMM_SELF solve (same iterations)."""
    X, edges, rest, k, m, fixed, q0, v0 = setup_case(n=6, seed=5)
    f = m[:, None] * G
    out = {}
    for name, comm in (("world", PETSc.COMM_WORLD), ("self", PETSc.COMM_SELF)):
        s = LocalGlobalSolver(edges, rest, k, m, X, fixed=fixed, comm=comm, rtol=1e-10,
                              colliders=[Collider.sphere((0.5, 0.5, -0.5), 0.49, 1e3)])
        q = q0.copy()
        v = v0 + [0, 0, -2.0]
        its = []
        for _ in range(2):
            q1, rep = run(s, q, v, 0.02, f)
            assert rep.converged
            its.append(rep.iterations)
            v, q = (q1 - q) / 0.02, q1
        out[name] = (q, its)
        s.destroy()
    assert np.abs(out["world"][0] - out["self"][0]).max() < 1e-10
    assert abs(np.array(out["world"][1]) - out["self"][1]).max() <= 1


def test_max_iterations_reported_not_converged():
    X, edges, rest, k, m, fixed, q0, v0 = setup_case()
    s = LocalGlobalSolver(edges, rest, k, m, X, fixed=fixed, max_it=3, anderson=0,
                          comm=PETSc.COMM_SELF)
    _, rep = run(s, q0, v0, 0.05, m[:, None] * G)
    s.destroy()
    assert not rep.converged and "DIVERGED_MAX_IT" in rep.reason and rep.iterations == 3


def test_accept_takes_the_iterate_after_max_it():
    """Liu et al.'s fixed iteration count: the step is accepted, approximate, and the residual
    left is reported."""
    X, edges, rest, k, m, fixed, q0, v0 = setup_case()
    f = m[:, None] * G
    s = LocalGlobalSolver(edges, rest, k, m, X, fixed=fixed, max_it=10, accept=True,
                          comm=PETSc.COMM_SELF)
    q1, rep = run(s, q0, v0, 0.02, f)
    s.destroy()
    ref = newton_reference(X, edges, rest, k, m, fixed, q0, v0, 0.02, f, q0)
    assert rep.converged and rep.reason == "ACCEPTED_AT_MAX_IT" and rep.iterations == 10
    assert rep.residual < 0.1 * rep.initial_residual
    err = np.abs(q1 - ref).max() / np.abs(ref - q0).max()
    assert 1e-12 < err < 0.1      # approximate, but close


def test_options_override_the_defaults():
    X, edges, rest, k, m, fixed, q0, v0 = setup_case()
    opts = PETSc.Options()
    keys = ["lgt_max_it", "lgt_anderson", "lgt_ksp_type", "lgt_pc_type"]
    for key, value in zip(keys, ["2", "0", "cg", "jacobi"], strict=True):
        opts.setValue(key, value)
    try:
        s = LocalGlobalSolver(edges, rest, k, m, X, fixed=fixed, prefix="lgt_")
        _, rep = run(s, q0, v0, 0.05, m[:, None] * G)
        assert s.max_it == 2 and s.anderson == 0
        assert s._ksps[0].getType() == "cg" and s._ksps[0].getPC().getType() == "jacobi"
        s.destroy()
    finally:
        clear_options(keys)
    assert rep.iterations == 2


@pytest.mark.parametrize("change, message", [
    (dict(rest=0.0), "rest length"),
    (dict(k=-1.0), "stiffness"),
    (dict(mass=0.0), "mass"),
    (dict(edge=(3, 3)), "itself"),
    (dict(edge=(0, 99)), "node numbers"),
])
def test_bad_input_is_a_clear_error(change, message):
    X, edges, rest, k, m, fixed, q0, v0 = setup_case()
    edges, rest, k, m = edges.copy(), rest.copy(), k.copy(), m.copy()
    if "rest" in change:
        rest[4] = change["rest"]
    if "k" in change:
        k[4] = change["k"]
    if "mass" in change:
        m[7] = change["mass"]
    if "edge" in change:
        edges[4] = change["edge"]
    with pytest.raises(LocalGlobalError, match=message):
        LocalGlobalSolver(edges, rest, k, m, X, fixed=fixed)


# -- the product's backward Euler on a MassSpringSystem ----------------------------------------


def _cloth_system(tmp_path, damping=0.5, springs_extra=None, collider_extra=None,
                  damping_stiffness=0.0):
    from mpi4py import MPI

    from petsoft.dynamics.mass_spring import (
        MassSpringSystem,
        build_mass_spring_model,
    )
    from petsoft.experiment import experiment_from_dict
    from petsoft.mesh.springs import write_spring_mesh

    comm = MPI.COMM_WORLD
    base = Path(comm.bcast(str(tmp_path) if comm.rank == 0 else None))
    n = 6
    xs = np.linspace(-0.5, 0.5, n)
    pts = np.array([(x, y, 0.3) for y in xs for x in xs])
    idx = np.arange(n * n).reshape(n, n)
    tris = np.concatenate([np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:]], -1).reshape(-1, 3),
                           np.stack([idx[:-1, :-1], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 3)])
    if comm.rank == 0:
        write_spring_mesh(base / "cloth.msh", pts, triangles=tris)
    comm.barrier()
    springs = {"stiffness": 60.0, "bending": 1.0, "node_mass": 0.01, **(springs_extra or {})}
    collider = {"kind": "sphere", "center": [0.0, 0.0, 0.0], "radius": 0.28,
                "stiffness": 300.0, **(collider_extra or {})}
    exp = experiment_from_dict({
        "mesh": {"file": str(base / "cloth.msh")}, "springs": springs, "collider": [collider],
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "damping": {"mass": damping, "stiffness": damping_stiffness},
        "boundary": [{"kind": "fixed", "where": "y > 0.49"}],
        "time": {"end": 0.1, "step": 0.01}}, source="<test>")
    model = build_mass_spring_model(exp)
    return MassSpringSystem(model, exp.damping.mass, exp.damping.stiffness), pts


def test_integrator_step_equals_newton_be_on_a_mass_spring_system(tmp_path):
    """One step from a state where the predictor penetrates the sphere: the local/global step
    and petsoft's Newton backward Euler (SNES) give the same state and energy terms."""
    from petsoft.dynamics.implicit import ImplicitIntegrator
    from petsoft.dynamics.local_global import LocalGlobalIntegrator

    system, pts = _cloth_system(tmp_path)
    rng = np.random.default_rng(7)
    q0 = system.dmesh.from_file_field(0.01 * rng.standard_normal(pts.shape) * (pts[:, 1:2] < 0.49))
    v0 = system.dmesh.from_file_field(np.tile([0.2, 0.0, -3.0], (len(pts), 1))
                                      * (pts[:, 1:2] < 0.49))
    newton = ImplicitIntegrator(system, "be")
    lg = LocalGlobalIntegrator(system, rtol=1e-12, atol=1e-12)
    out = {}
    for name, integ in (("newton", newton), ("lg", lg)):
        q1, v1 = system.create_vec(), system.create_vec()
        rep = integ.step(0.0, q0, v0, 0.02, q1, v1)
        assert rep.converged, rep.reason
        out[name] = (system.dmesh.to_all(q1), system.dmesh.to_all(v1), rep)
    x1 = pts + out["newton"][0]
    assert (np.linalg.norm(x1, axis=1) < 0.28).any()          # the step is in contact
    assert np.abs(out["lg"][0] - out["newton"][0]).max() < 1e-9
    assert np.abs(out["lg"][1] - out["newton"][1]).max() < 1e-7
    assert out["lg"][2].dissipated == pytest.approx(out["newton"][2].dissipated, rel=1e-7)
    assert out["lg"][2].dissipated > 0
    newton.destroy()
    lg.destroy()
    system.destroy()


@pytest.mark.parametrize("change, message", [
    (dict(springs_extra={"damping": 0.1}), "dashpots"),
    (dict(collider_extra={"friction": 0.3}), "friction"),
    (dict(damping_stiffness=1e-3), "stiffness"),
])
def test_integrator_refuses_terms_it_does_not_handle(tmp_path, change, message):
    from petsoft.dynamics.local_global import LocalGlobalIntegrator
    from petsoft.errors import ExperimentError

    system, _ = _cloth_system(tmp_path, **change)
    with pytest.raises(ExperimentError, match=message):
        LocalGlobalIntegrator(system)
    system.destroy()


@pytest.mark.serial_only
@pytest.mark.skipif(PETSc.COMM_WORLD.size > 1, reason="spawns processes")
def test_cli_simulate_solver_local_global(tmp_path):
    """`petsoft simulate --solver local-global` on the stiff-spring pendulum: the probe trajectory
    of Newton's backward Euler, and a clear error for another integrator."""
    import os
    import subprocess
    import sys

    import h5py

    root = Path(__file__).resolve().parents[1]
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("OMPI_COMM_WORLD", "PMIX_", "OMPI_MCA_orte", "OMPI_MCA_ess"))}
    toml = str(root / "scripts" / "examples" / "stiff_spring_pendulum.toml")
    cli = [sys.executable, "-m", "petsoft.cli.main", "simulate", toml]
    runs = {}
    for solver in ("snes", "local-global"):
        r = subprocess.run(cli + ["--out", str(tmp_path / solver), "--solver", solver,
                                  "-lg_rtol", "1e-11"],
                           capture_output=True, text=True, env=env, timeout=120)
        assert r.returncode == 0, r.stdout + r.stderr
        with h5py.File(tmp_path / solver / "probes.h5") as f:
            runs[solver] = f["frames/position"][...]
    assert runs["snes"].shape == runs["local-global"].shape
    assert np.ptp(runs["snes"][:, 0, 2]) > 0.1                     # it swings
    assert np.abs(runs["snes"] - runs["local-global"]).max() < 1e-8
    r = subprocess.run(cli + ["--out", str(tmp_path / "x"), "--solver", "local-global",
                              "--integrator", "midpoint"],
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 2 and "backward-Euler steps only" in r.stdout + r.stderr
