"""Verification of the 10-node (P2) tetrahedra (``[mesh] order = 2``).

1. The compiled quadrature kernel equals the numpy reference (all laws, energy/gradient/Hessian,
   with and without the PSD projection).
2. Taylor tests: element energy -> gradient -> Hessian for every law; the assembled potential of
   a small P2 model.
3. Patch test: an affine displacement prescribed on every boundary node (corners and edge nodes)
   of a box with jittered interior corners is reproduced inside to round-off, for every law; the
   affine state's internal force vanishes at the interior nodes.
4. Manufactured solution, linear elasticity: L2 error rate 3 for P2 (2 for P1 on the same meshes).
5. Cantilever under gravity against Timoshenko: P2 within 1 % on a 20 x 1 x 2 mesh, P1 far off.
6. DOLFINx reference data (tests/data/p2_reference, scripts/benchmarks/independent/
   p2_reference.py): Cook's membrane (static, traction), beam modes (consistent mass) and the
   beam's gravity sag.
7. Serial == 2 ranks: a P2 static solve and a short P2 dynamic run (alpha, backward Euler).
8. Mass: HRZ lumped masses positive and summing to rho V; the consistent mass sums to rho V and
   integrates a linear field exactly.
9. More: tetra10 files (.vtu, .msh, all-negatively oriented, a curved edge) keep their edge
   nodes; d/dmu, d/dlambda of the element forces recombine to the gradient; curved elements
   leave rigid motions free; a linearly varying traction's resultant and moments are exact;
   explicit (HRZ lumped) steps 1 rank == 2 ranks; quadrature rules and shape functions.

Every test runs collectively (serially and under ``mpiexec -n 2``); checked quantities are
reduced or broadcast, so assertions hold on every rank. ``pytest -s`` prints measured numbers.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from _static_cases import (
    BOUNDARY_OF_UNIT_CUBE,
    ProductField,
    bcast_gathered,
    jittered_unit_cube,
    linear_expressions,
    solve,
)
from mpi4py import MPI
from petsc4py import PETSc
from scipy.spatial import cKDTree

from petsoft.dynamics.simulate import Simulation
from petsoft.dynamics.system import DynamicSystem
from petsoft.experiment import experiment_from_dict
from petsoft.fem.element import cell_integrals, quadratic_geometry, shape_values, tet_rule
from petsoft.fem.kernels import elastic as kernels
from petsoft.fem.kernels.materials import MODELS
from petsoft.fem.kernels.tet import shape_gradients
from petsoft.mesh.quadratic import raise_order
from petsoft.mesh.serial import Mesh, MeshWarning, box_mesh, validate
from petsoft.physics.loads import lumped_masses
from petsoft.physics.model import build_model
from petsoft.solvers.modes import compute_modes
from petsoft.solvers.options import clear_options

MUMPS = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
DATA = Path(__file__).parent / "data" / "p2_reference"
REF_TET = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def _print(*args):
    if PETSc.COMM_WORLD.getRank() == 0:
        print(*args)


def _rank_consistent(value):
    """The root's value, on every rank (assertions then agree across ranks)."""
    return PETSc.COMM_WORLD.tompi4py().bcast(value, root=0)


def _experiment(material="linear", *, size=(1.0, 1.0, 1.0), cells=(2, 2, 2), order=2,
                E=1e6, nu=0.3, density=1000.0, gravity=(0.0, 0.0, 0.0), boundary=(), **extra):
    data = {
        "mesh": {"box": {"size": list(size), "cells": list(cells)}, "order": order},
        "material": {"model": material, "youngs_modulus": E, "poisson_ratio": nu,
                     "density": density},
        "gravity": {"acceleration": list(gravity)},
        "boundary": [dict(b) for b in boundary],
        "output": {"directory": "/tmp/petsoft-verification-p2"},
    }
    data.update(extra)
    return experiment_from_dict(data)


# ================================================================================================
# 1./2. Element kernels


def _random_p2_elements(rng, n, scale=0.08, curved=0.03, min_det=0.3):
    """Random well-shaped 10-node tetrahedra (mid-edge nodes moved off the midpoints by up to
    ``curved``: curved edges), their shape gradients/weights at Keast's 4 points, random
    displacements with det F > min_det at every point, and Lamé parameters."""
    X = REF_TET + 0.15 * rng.standard_normal((3 * n, 4, 3))
    _, vol = shape_gradients(X)
    X[vol < 0] = X[vol < 0][:, [0, 2, 1, 3]]
    edges = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])
    mid = 0.5 * (X[:, edges[:, 0]] + X[:, edges[:, 1]])
    X10 = np.concatenate([X, mid + curved * rng.uniform(-1, 1, mid.shape)], axis=1)
    dN, w = quadratic_geometry(X10, *tet_rule(2))
    u = scale * rng.standard_normal((3 * n, 10, 3))
    F = np.eye(3) + np.einsum("eai,eqaj->eqij", u, dN)
    keep = (np.linalg.det(F) > min_det).all(axis=1)
    dN, w, u = dN[keep][:n], w[keep][:n], u[keep][:n]
    assert len(w) == n
    return (np.ascontiguousarray(dN), np.ascontiguousarray(w), np.ascontiguousarray(u),
            rng.uniform(0.5, 2.0, n), rng.uniform(0.5, 5.0, n))


def _evaluate(model, dN, w, u, mu, lam, backend="c", project=False, hessian=True):
    n = len(w)
    W, g = np.empty(n), np.empty((n, 30))
    H = np.empty((n, 30, 30)) if hessian else None
    kernels.quadrature_into(model, dN, w, u, mu, lam, W, g, H, project_spd=project,
                            backend=backend)
    return W, g, H


@pytest.mark.parametrize("project", [False, True])
@pytest.mark.parametrize("model", MODELS)
def test_quadrature_kernel_c_matches_numpy(model, project):
    """C quadrature kernel == numpy reference on 100 random curved P2 elements with ~8 %
    random displacements: energy, gradient, Hessian (per element, relative 1e-10)."""
    dN, w, u, mu, lam = _random_p2_elements(np.random.default_rng(11), 100)
    Wc, gc, Hc = _evaluate(model, dN, w, u, mu, lam, "c", project)
    Wn, gn, Hn = _evaluate(model, dN, w, u, mu, lam, "numpy", project)
    assert np.abs(Wc - Wn).max() <= 1e-10 * np.abs(Wn).max()
    scale_g = np.abs(gn).max(axis=1, keepdims=True)
    assert (np.abs(gc - gn) <= 1e-10 * scale_g).all()
    scale_H = np.abs(Hn).max(axis=(1, 2), keepdims=True)
    assert (np.abs(Hc - Hn) <= 1e-10 * scale_H).all()
    # the outputs are not trivially equal: the energy is positive, the Hessians symmetric
    assert (Wn > 0).all() and np.abs(Hc - np.swapaxes(Hc, 1, 2)).max() == 0.0
    if project:
        assert np.linalg.eigvalsh(Hc).min() >= -1e-10 * np.abs(Hc).max()
    # only energy: the same energy (the optional outputs are independent)
    W_only = np.empty(len(w))
    kernels.quadrature_into(model, dN, w, u, mu, lam, W_only, None, None, backend="c")
    assert np.abs(W_only - Wc).max() <= 1e-14 * np.abs(Wc).max()


def _orders(rem):
    r = np.asarray(rem, float)
    return np.log2(r[:-1] / r[1:])


HS = 1e-3 * 0.5 ** np.arange(4)


@pytest.mark.parametrize("backend", ["c", "numpy"])
@pytest.mark.parametrize("model", MODELS)
def test_element_taylor(model, backend):
    """Per element: W(u + h d) - W - h g.d ~ h^2 and g(u + h d) - g - h H d ~ h^2 (orders in
    [1.8, 2.2]; for the linear law g is linear and the second remainder is round-off)."""
    dN, w, u, mu, lam = _random_p2_elements(np.random.default_rng(5), 10, scale=0.15)
    d = np.random.default_rng(6).standard_normal(u.shape)
    W, g, H = _evaluate(model, dN, w, u, mu, lam, backend)
    slope = np.einsum("ei,ei->e", g, d.reshape(-1, 30))
    Hd = np.einsum("eij,ej->ei", H, d.reshape(-1, 30))
    remW, remG = [], []
    for h in HS:
        W2, g2, _ = _evaluate(model, dN, w, u + h * d, mu, lam, backend, hessian=False)
        remW.append(np.abs(W2 - W - h * slope))
        remG.append(np.linalg.norm(g2 - g - h * Hd, axis=1))
    oW = _orders(remW)
    _print(f"\nP2 element Taylor {model}/{backend}: energy orders {oW.min():.3f}..{oW.max():.3f}")
    assert oW.min() > 1.8 and oW.max() < 2.2, oW
    if model == "linear":
        for h, r in zip(HS, remG, strict=True):
            assert (r <= 1e-11 * h * np.linalg.norm(Hd, axis=1)).all()
        return
    oG = _orders(remG)
    _print(f"P2 element Taylor {model}/{backend}: gradient orders {oG.min():.3f}..{oG.max():.3f}")
    assert oG.min() > 1.8 and oG.max() < 2.2, oG


@pytest.mark.parametrize("model", ["stvk", "corotated", "neohookean"])
def test_assembled_potential_taylor(model):
    """The assembled P2 system (clamped bar, 3 x 1 x 1 cells): elastic energy -> internal force
    -> tangent matrix, Taylor remainders of order 2 (in [1.8, 2.2])."""
    exp = _experiment(model, size=(0.3, 0.1, 0.1), cells=(3, 1, 1),
                      boundary=[{"kind": "fixed", "where": "x < 1e-9"}])
    s = DynamicSystem(build_model(exp), 0.0, 0.0)
    rng = np.random.default_rng(PETSc.COMM_WORLD.getRank() + 1)
    q, d = s.create_vec(), s.create_vec()
    q.setArray(1e-3 * rng.standard_normal(q.getLocalSize()))
    d.setArray(rng.standard_normal(d.getLocalSize()))
    s.apply_prescribed(q, 0.0)
    s.apply_prescribed(d, 0.0)
    d.scale(1.0 / d.norm())
    g0 = s.internal_gradient(q, s.create_vec())
    W0 = s.elastic_energy(q)
    H = s.assemble_combination(q, 0.0, 1.0, 0.0, s.create_matrix(), eliminate=False)
    Hd = H.createVecLeft()
    H.mult(d, Hd)
    remW, remG = [], []
    for k in range(4):
        eps = 1e-3 * 2.0**-k
        x = q.copy()
        x.axpy(eps, d)
        remW.append(abs(s.elastic_energy(x) - W0 - eps * g0.dot(d)))
        g = s.internal_gradient(x, s.create_vec())
        g.axpy(-1.0, g0)
        g.axpy(-eps, Hd)
        remG.append(g.norm())
    oW, oG = _rank_consistent((_orders(remW), _orders(remG)))
    _print(f"\nassembled P2 Taylor {model}: energy {np.round(oW, 3)}, gradient {np.round(oG, 3)}")
    for o in (oW, oG):
        assert np.all((o > 1.8) & (o < 2.2)), o


# ================================================================================================
# 3. Patch test


def _affine_gradient(scale=1.0):
    """G = A - I with A = R (I + S): ~5 % strains and a 0.15 rad rotation (times ``scale``)."""
    S = scale * np.array([[0.05, 0.02, -0.01], [0.02, -0.03, 0.015], [-0.01, 0.015, 0.04]])
    axis = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    th = 0.15 * scale
    R = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
    return R @ (np.eye(3) + S) - np.eye(3)


C_SHIFT = np.array([0.01, -0.02, 0.005])


def _affine_expressions(G):
    return [f"{e} + ({c!r})" for e, c in zip(linear_expressions(G), C_SHIFT, strict=True)]


def _patch_mesh(jitter: bool):
    if jitter:
        mesh, _ = jittered_unit_cube(3, amplitude=0.3, seed=7)
    else:
        mesh = box_mesh([1.0, 1.0, 1.0], [2, 2, 2])
    p2 = raise_order(mesh)
    interior = np.all((p2.points > 1e-9) & (p2.points < 1 - 1e-9), axis=1)
    return p2, interior


@pytest.mark.parametrize("jitter", [False, True], ids=["box", "jittered"])
@pytest.mark.parametrize("material", MODELS)
def test_patch_affine_displacement(material, jitter):
    """u = G X + c prescribed on every boundary node (corners and edge nodes) of a P2 box (2^3 or
    jittered 3^3 hexes): the interior nodes (corners and edge nodes) reproduce it to round-off
    (max error < 1e-10 of max |u|), starting Newton from a perturbed interior; and the affine
    state's assembled internal force vanishes at the interior nodes (< 1e-10 of its largest
    entry)."""
    G = _affine_gradient()
    mesh, interior = _patch_mesh(jitter)
    exp = _experiment(material, cells=(3, 3, 3), boundary=[{
        "kind": "prescribed", "where": BOUNDARY_OF_UNIT_CUBE,
        "displacement": _affine_expressions(G)}])
    model = build_model(exp, mesh=mesh)
    exact = mesh.points @ G.T + C_SHIFT
    rng = np.random.default_rng(3)
    x0 = model.dmesh.from_file_field(rng.uniform(-0.02, 0.02, mesh.points.shape)
                                     * interior[:, None])
    u, result = solve(model, x0=x0, options={"snes_rtol": "1e-14", "snes_atol": "1e-13",
                                             **MUMPS})
    err = _rank_consistent(float(np.abs(u - exact)[interior].max() / np.abs(exact).max()))
    # the affine state's internal force, assembled
    dm = model.dmesh
    g_local = np.zeros(3 * dm.nvertices)
    model.elastic.term.add_gradient(np.ascontiguousarray(exact[dm.vertex_ids]), g_local)
    g = dm.create_global_vec()
    g.zeroEntries()
    dm.add_to_global(g_local.reshape(-1, 3), g)
    force = bcast_gathered(model, g)
    g.destroy()
    residual = _rank_consistent(float(np.abs(force[interior]).max() / np.abs(force).max()))
    _print(f"\nP2 patch {material}/{'jittered' if jitter else 'box'}: interior error / max|u| "
           f"{err:.2e}, affine internal force at interior nodes / max {residual:.2e}, "
           f"{result.newton_iterations} Newton iterations")
    assert interior.sum() >= 7 and result.newton_iterations >= 1
    assert err < 1e-10
    assert residual < 1e-10


# ================================================================================================
# 4. Manufactured solution


E_MMS, NU_MMS = 1e6, 0.3
FIELD = ProductField(
    amp=np.array([0.01, -0.008, 0.012]),
    omega=np.pi / 2 * np.array([[1.3, 0.9, 1.1], [0.8, 1.5, 0.7], [1.2, 1.0, 1.4]]),
    phase=np.array([[0.3, 1.1, 0.5], [0.9, 0.2, 1.3], [0.4, 0.8, 0.1]]))


def _cell_rule(dm, degree):
    """Physical points (ne, nq, 3), weights (ne, nq) and shape values (nq, k) of the local
    (straight-edged) cells, by tet_rule(degree)."""
    bary, w = tet_rule(degree)
    corners = dm.points[dm.cells[:, :4]]
    pts = np.einsum("qc,eci->eqi", bary, corners)
    D = corners[:, 1:] - corners[:, :1]
    vol = np.linalg.det(D) / 6.0
    assert (vol > 0).all()
    return pts, vol[:, None] * w[None, :], shape_values(dm.order, bary)


def _add_body_force(model, f, degree=5):
    dm = model.dmesh
    pts, wq, N = _cell_rule(dm, degree)
    fq = f(pts.reshape(-1, 3)).reshape(pts.shape)
    fe = np.einsum("eq,qa,eqi->eai", wq, N, fq)
    local = np.zeros((dm.nvertices, 3))
    np.add.at(local, dm.cells.ravel(), fe.reshape(-1, 3))
    dm.add_to_global(local, model.external)


def _l2_error(model, u_file, exact, degree=5):
    dm = model.dmesh
    pts, wq, N = _cell_rule(dm, degree)
    uh = np.einsum("qa,eai->eqi", N, np.asarray(u_file)[dm.vertex_ids][dm.cells])
    ue = exact(pts.reshape(-1, 3)).reshape(pts.shape)
    err = float(np.einsum("eq,eqi->", wq, (uh - ue) ** 2))
    mpi = dm.comm.tompi4py()
    return float(np.sqrt(mpi.allreduce(err, op=MPI.SUM)))


def test_manufactured_solution_rates():
    """u = (a_i prod_j sin(w_ij x_j + p_ij)) on the unit cube, linear law (E = 1e6, nu = 0.3),
    f = -div sigma(u) as consistent nodal loads (degree-5 rule), u prescribed on every boundary
    node; meshes 2^3, 4^3, 8^3 hexes: the L2 error (degree-5 rule) converges at rate 3 for P2
    (last rate in [2.8, 3.2]) and at rate ~2 for P1 (last rate in [1.7, 2.3])."""
    lam = E_MMS * NU_MMS / ((1 + NU_MMS) * (1 - 2 * NU_MMS))
    mu = E_MMS / (2 * (1 + NU_MMS))
    rates = {}
    for order in (1, 2):
        errors = []
        for n in (2, 4, 8):
            exp = _experiment("linear", cells=(n, n, n), order=order, E=E_MMS, nu=NU_MMS,
                              boundary=[{"kind": "prescribed", "where": BOUNDARY_OF_UNIT_CUBE,
                                         "displacement": FIELD.expressions()}])
            model = build_model(exp)
            _add_body_force(model, FIELD.body_force(lam, mu))
            u, _ = solve(model, options={"snes_rtol": "1e-12", **MUMPS})
            errors.append(_l2_error(model, u, FIELD))
        rates[order] = _rank_consistent(np.log2(np.array(errors[:-1]) / np.array(errors[1:])))
        _print(f"\nMMS P{order}: L2 errors {np.array2string(np.array(errors), precision=3)}, "
               f"rates {np.array2string(rates[order], precision=3)}")
    assert 2.8 <= rates[2][-1] <= 3.2
    assert rates[2][0] > 2.5
    assert 1.7 <= rates[1][-1] <= 2.3


# ================================================================================================
# 5. Cantilever under gravity

L_C, B_C, H_C, E_C, RHO_C, G_C = 1.0, 0.05, 0.1, 1e7, 1000.0, 9.81


def _cantilever_tip(order, nu):
    exp = _experiment("linear", size=(L_C, B_C, H_C), cells=(20, 1, 2), order=order, E=E_C,
                      nu=nu, density=RHO_C, gravity=(0.0, 0.0, -G_C),
                      boundary=[{"kind": "fixed", "where": "x < 1e-9"}])
    model = build_model(exp)
    u, _ = solve(model, options={"snes_rtol": "1e-12", **MUMPS})
    tip = model.dmesh.mesh.points[:, 0] > L_C - 1e-9
    return _rank_consistent(float(-u[tip, 2].mean()))


def _timoshenko(nu):
    q, I, A = RHO_C * G_C * B_C * H_C, B_C * H_C**3 / 12, B_C * H_C
    G = E_C / (2 * (1 + nu))
    return q * L_C**4 / (8 * E_C * I) + q * L_C**2 / (2 * 5 / 6 * G * A)


def test_cantilever_gravity_timoshenko():
    """Cantilever 1 x 0.05 x 0.1 m, 20 x 1 x 2 hexes, clamped at x = 0, gravity, E = 1e7,
    rho = 1000: with nu = 0 the mean P2 tip deflection is within 1 % of Timoshenko
    (q L^4/(8EI) + q L^2/(2 k G A), k = 5/6) and P1 on that mesh locks (< 0.7 of it); with
    nu = 0.3 P2 is within 1.5 % (the 3D clamp stiffens: converged 3D is ~0.993 of Timoshenko)."""
    ratios = {}
    for order, nu in ((2, 0.0), (1, 0.0), (2, 0.3)):
        ratios[order, nu] = _cantilever_tip(order, nu) / _timoshenko(nu)
    _print("\ncantilever tip / Timoshenko: " + ", ".join(
        f"P{o} nu={nu}: {r:.5f}" for (o, nu), r in ratios.items()))
    assert ratios[2, 0.0] == pytest.approx(1.0, abs=0.01)
    assert ratios[1, 0.0] < 0.7
    assert ratios[2, 0.3] == pytest.approx(1.0, abs=0.015)


# ================================================================================================
# 6. DOLFINx reference data


def _reference_mesh(data) -> Mesh:
    points = np.asarray(data["points"], float)
    tets = np.asarray(data["tets"], np.int64)
    mesh = validate(Mesh(points=points, tets=tets, cell_tags=np.zeros(len(tets), np.int64),
                         source="dolfinx reference"))
    return raise_order(mesh)


def _match(points, dof_coords):
    """Row of ``dof_coords`` of each point (every point must be found to 1e-12)."""
    dist, idx = cKDTree(dof_coords).query(points)
    scale = np.abs(dof_coords).max()
    assert dist.max() < 1e-12 * scale
    assert len(np.unique(idx)) == len(points) == len(dof_coords)
    return idx


def _reference_experiment(boundary, E, nu, rho=1000.0, gravity=(0.0, 0.0, 0.0)):
    return _experiment("linear", E=E, nu=nu, density=rho, gravity=gravity, boundary=boundary)


def test_cook_membrane_matches_dolfinx():
    """Cook's membrane (linear, E = 1e6, nu = 0.3, clamped at x = 0, traction (0, 1e3, 0) Pa on
    x = 0.048) on DOLFINx's own tet mesh: petsoft's P2 displacement at every P2 node (matched
    by coordinate) equals DOLFINx's within 1e-8 of max |u|."""
    data = np.load(DATA / "cook.npz")
    mesh = _reference_mesh(data)
    exp = _reference_experiment(
        [{"kind": "fixed", "where": "x < 1e-9"},
         {"kind": "traction", "where": "x > 0.048 - 1e-9", "value": [0.0, 1e3, 0.0]}],
        E=float(data["E"]), nu=float(data["nu"]))
    model = build_model(exp, mesh=mesh)
    u, _ = solve(model, options={"snes_rtol": "1e-14", **MUMPS})
    ref = np.asarray(data["u"])[_match(mesh.points, np.asarray(data["dof_coords"]))]
    diff = _rank_consistent(float(np.abs(u - ref).max() / np.abs(ref).max()))
    _print(f"\nCook P2 vs DOLFINx: max |u - u_ref| / max |u_ref| = {diff:.2e} "
           f"(max |u| {np.abs(ref).max():.4e} m)")
    assert diff < 1e-8


def _beam(gravity=(0.0, 0.0, 0.0)):
    data = np.load(DATA / "beam_modes.npz")
    mesh = _reference_mesh(data)
    exp = _reference_experiment([{"kind": "fixed", "where": "x < 1e-9"}], E=float(data["E"]),
                                nu=float(data["nu"]), rho=float(data["rho"]), gravity=gravity)
    return data, mesh, build_model(exp, mesh=mesh)


def test_beam_modes_match_dolfinx():
    """Clamped beam 0.2 x 0.01 x 0.02 (DOLFINx's mesh), P2, consistent mass: the first 8
    natural frequencies equal DOLFINx's within 1e-6 (relative)."""
    data, _, model = _beam()
    result = compute_modes(model, 8)
    freqs = result.frequencies_hz.copy()
    result.destroy()
    ref = np.asarray(data["frequencies_hz"])
    rel = _rank_consistent(np.abs(freqs[:8] - ref) / ref)
    _print(f"\nbeam modes P2 (Hz): {np.array2string(freqs[:8], precision=5)}; relative "
           f"differences to DOLFINx {np.array2string(rel, precision=2)}")
    assert result.rigid_modes == 0
    assert rel.max() < 1e-6


def test_beam_gravity_matches_dolfinx():
    """The same beam under gravity (0, 0, -9.81), rho = 1000: petsoft's P2 static displacement
    equals DOLFINx's at every P2 node within 1e-8 of max |u|."""
    g = tuple(float(c) for c in np.load(DATA / "beam_modes.npz")["g"])
    assert g == (0.0, 0.0, -9.81)
    data, mesh, model = _beam(gravity=g)
    u, _ = solve(model, options={"snes_rtol": "1e-14", **MUMPS})
    ref = np.asarray(data["u_gravity"])[_match(mesh.points, np.asarray(data["dof_coords_gravity"]))]
    diff = _rank_consistent(float(np.abs(u - ref).max() / np.abs(ref).max()))
    _print(f"\nbeam gravity P2 vs DOLFINx: relative difference {diff:.2e} "
           f"(max |u| {np.abs(ref).max():.4e} m)")
    assert diff < 1e-8


# ================================================================================================
# 7. Serial == 2 ranks


def _bar_experiment(**extra):
    return _experiment("neohookean", size=(1.0, 0.3, 0.3), cells=(4, 2, 2), E=1e6, nu=0.3,
                       gravity=(0.0, 0.0, -9.81),
                       boundary=[{"kind": "fixed", "where": "x < 1e-9"},
                                 {"kind": "traction", "where": "x > 1 - 1e-9",
                                  "value": [0.0, 400.0, -800.0]}], **extra)


def test_static_serial_equals_parallel():
    """Neo-Hookean P2 bar (gravity + end traction, 2 load steps): the displacement solved on
    PETSC_COMM_WORLD equals the one on PETSC_COMM_SELF within 1e-8 (relative max norm)."""
    exp = _bar_experiment()
    runs = []
    for comm in (PETSc.COMM_SELF, PETSc.COMM_WORLD):
        u, _ = solve(build_model(exp, comm=comm), load_steps=2,
                     options={"snes_rtol": "1e-12", **MUMPS})
        runs.append(u)
    diff = _rank_consistent(float(np.abs(runs[1] - runs[0]).max() / np.abs(runs[0]).max()))
    _print(f"\nP2 static on {PETSc.COMM_WORLD.getSize()} ranks vs 1: {diff:.2e} "
           f"(|u|max {np.abs(runs[0]).max():.4f} m)")
    assert np.abs(runs[0]).max() > 1e-3
    assert diff < 1e-8


@pytest.mark.parametrize("integrator", ["alpha", "be"])
def test_dynamics_serial_equals_parallel(integrator):
    """A P2 neo-Hookean bar released under gravity and traction, 5 steps of 1e-3 s: the final
    displacement on PETSC_COMM_WORLD equals the one on PETSC_COMM_SELF within 1e-8."""
    step = 1e-3
    exp = _bar_experiment(time={"end": 5 * step, "step": step, "integrator": integrator})
    finals = []
    for comm in (PETSc.COMM_SELF, PETSc.COMM_WORLD):
        keys = ["ksp_rtol"]
        PETSc.Options().setValue("ksp_rtol", "1e-13")
        try:
            model = build_model(exp, comm)
            sim = Simulation(model, exp)
            result = sim.run()
            finals.append(MPI.COMM_WORLD.bcast(model.dmesh.gather_global(result.q)))
            sim.destroy()
        finally:
            clear_options(keys)
    a, b = finals
    diff = float(np.abs(a - b).max() / np.abs(a).max())
    _print(f"\nP2 {integrator} on {PETSc.COMM_WORLD.getSize()} ranks vs 1: {diff:.2e} "
           f"(|u|max {np.abs(a).max():.3e} m)")
    assert np.abs(a).max() > 1e-6
    assert diff < 1e-8


# ================================================================================================
# 8. Mass


def test_mass_matrices():
    """On a jittered P2 mesh: HRZ lumped masses are positive and sum to V per element (and to
    rho V over the mesh, assembled); the consistent mass sums to V per element, is symmetric
    positive definite, and integrates a linear field exactly (1^T M f = V f(centroid),
    M f = int N_a f dV by a degree-5 rule); the unit body-force load is -V/20 at the corners
    and V/5 at the edge nodes of a straight element."""
    mesh, _ = jittered_unit_cube(2, amplitude=0.3, seed=2)
    exp = _experiment("linear", density=750.0)
    model = build_model(exp, mesh=raise_order(mesh))
    dm = model.dmesh
    ci = cell_integrals(dm)
    V = dm.cell_volumes
    assert ci.mass.shape == (len(V), 10, 10)
    assert (ci.lumped > 0).all()
    np.testing.assert_allclose(ci.lumped.sum(axis=1), V, rtol=1e-13)
    np.testing.assert_allclose(ci.mass.sum(axis=(1, 2)), V, rtol=1e-13)
    np.testing.assert_allclose(ci.mass, np.swapaxes(ci.mass, 1, 2), rtol=0, atol=1e-15)
    assert np.linalg.eigvalsh(ci.mass).min() > 0
    expected_load = V[:, None] * np.r_[np.full(4, -1 / 20), np.full(6, 1 / 5)][None]
    np.testing.assert_allclose(ci.load, expected_load, rtol=1e-12, atol=1e-15 * V.max())
    # a linear field f = a . X + b at the nodes
    a, b = np.array([0.3, -1.2, 0.7]), 0.4
    f = dm.points[dm.cells] @ a + b                                  # (ne, 10)
    centroid = dm.points[dm.cells[:, :4]].mean(axis=1)
    np.testing.assert_allclose(np.einsum("nab,nb->n", ci.mass, f), V * (centroid @ a + b),
                               rtol=1e-12)
    pts, wq, N = _cell_rule(dm, 5)
    Mf = np.einsum("eq,qa,eq->ea", wq, N, pts @ a + b)
    np.testing.assert_allclose(np.einsum("nab,nb->na", ci.mass, f), Mf, rtol=1e-11,
                               atol=1e-14)
    # assembled lumped masses: rho times the total volume, every node positive
    local = lumped_masses(dm, model.density)
    m = dm.create_global_vec()
    m.zeroEntries()
    dm.add_to_global(np.repeat(local[:, None], 3, axis=1), m)
    masses = bcast_gathered(model, m)[:, 0]
    m.destroy()
    total = _rank_consistent(float(masses.sum()))
    assert masses.min() > 0
    assert total == pytest.approx(750.0 * 1.0, rel=1e-12)



# ================================================================================================
# More: tetra10 files, parameter derivatives, curved elements, linear tractions, explicit steps


@pytest.mark.parametrize("fmt", ["vtu", "msh"])
def test_cook_from_tetra10_file(fmt, tmp_path):
    """Cook's membrane read from a tetra10 file (DOLFINx's own P2 nodes, VTK order in .vtu;
    gmsh order in .msh, converted by meshio) through an experiment file with ``[mesh] order =
    2``: the same displacement as DOLFINx within 1e-8 of max |u|."""
    import meshio

    data = np.load(DATA / "cook.npz")
    path = tmp_path / f"cook.{fmt}"
    meshio.write(path, meshio.Mesh(np.asarray(data["dof_coords"]),
                                   [("tetra10", np.asarray(data["tets10"]))]),
                 **({"file_format": "gmsh22", "binary": False} if fmt == "msh" else {}))
    toml = tmp_path / "cook.toml"
    toml.write_text(f"""
[mesh]
file = "{path.name}"
order = 2

[material]
model = "linear"
youngs_modulus = {float(data["E"])!r}
poisson_ratio = {float(data["nu"])!r}
density = 1000.0

[[boundary]]
kind = "fixed"
where = "x < 1e-9"

[[boundary]]
kind = "traction"
where = "x > 0.048 - 1e-9"
value = [0.0, 1e3, 0.0]

[output]
directory = "out"
""")
    from petsoft.experiment import load_experiment

    model = build_model(load_experiment(toml))
    mesh = model.dmesh.mesh
    assert mesh.order == 2 and len(mesh.points) == len(data["dof_coords"])
    u, _ = solve(model, options={"snes_rtol": "1e-14", **MUMPS})
    ref = np.asarray(data["u"])[_match(mesh.points, np.asarray(data["dof_coords"]))]
    diff = _rank_consistent(float(np.abs(u - ref).max() / np.abs(ref).max()))
    _print(f"\nCook from a tetra10 .{fmt}: relative difference to DOLFINx {diff:.2e}")
    assert diff < 1e-8


@pytest.mark.parametrize("material", MODELS)
def test_lame_derivatives_recombine_to_the_gradient(material):
    """Every law is linear in (mu, lambda): per P2 cell, mu d_mu + lam d_lam equals the element
    gradient (assembled, relative 1e-12), and d_mu, d_lam are (ncells, 30)."""
    mesh, _ = jittered_unit_cube(2, amplitude=0.2, seed=4)
    model = build_model(_experiment(material), mesh=raise_order(mesh))
    term, dm = model.elastic.term, model.dmesh
    u = 0.02 * np.random.default_rng(9).standard_normal((dm.nvertices, 3))
    u = np.ascontiguousarray(u)
    d_mu, d_lam = term.lame_derivatives(u)
    assert d_mu.shape == (len(dm.cells), 30)
    mu, lam = np.empty(len(dm.cells)), np.empty(len(dm.cells))
    for g in term.groups:
        mu[g.cells], lam[g.cells] = g.mu, g.lam
    combined = np.zeros((dm.nvertices, 3))
    np.add.at(combined, dm.cells.ravel(),
              (mu[:, None] * d_mu + lam[:, None] * d_lam).reshape(-1, 3))
    g_local = np.zeros(3 * dm.nvertices)
    term.add_gradient(u, g_local)
    assert np.abs(combined.ravel() - g_local).max() <= 1e-12 * np.abs(g_local).max()


def _curved_mesh():
    """A 2^3 box raised to order 2 with its interior edge nodes moved off the midpoints by up to
    8 % of the cell size (curved edges)."""
    mesh = box_mesh([1.0, 1.0, 1.0], [2, 2, 2])
    p2 = raise_order(mesh)
    edge_points = p2.points[p2.edge_nodes].copy()
    rng = np.random.default_rng(12)
    inside = np.all((edge_points > 1e-9) & (edge_points < 1 - 1e-9), axis=2)
    moves = rng.uniform(-0.04, 0.04, (len(p2.points), 3))[p2.edge_nodes]
    edge_points[inside] += moves[inside]
    curved = raise_order(mesh, edge_points=edge_points)
    assert np.abs(curved.points - p2.points).max() > 0.01
    return curved


@pytest.mark.parametrize("material", ["stvk", "corotated", "neohookean"])
def test_curved_elements_rigid_motion_is_free(material):
    """Curved P2 elements reproduce linear fields exactly (isoparametric): a finite rotation plus
    a translation has F = R at every quadrature point, so the elastic energy and the internal
    forces vanish to round-off for the rotation-invariant laws; the consistent mass still sums
    to the element volumes (the quadrature weights) and the volume of the curved mesh is 1 (the
    boundary is straight: only interior nodes moved)."""
    mesh = _curved_mesh()
    model = build_model(_experiment(material), mesh=mesh)
    dm, term = model.dmesh, model.elastic.term
    R = np.eye(3) + _affine_gradient()
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt                                                    # a pure rotation
    u = np.ascontiguousarray(dm.points @ (R - np.eye(3)).T + C_SHIFT)
    energy = dm.comm.tompi4py().allreduce(term.energy(u), op=MPI.SUM)
    g_local = np.zeros(3 * dm.nvertices)
    term.add_gradient(u, g_local)
    stretch = np.ascontiguousarray(0.01 * dm.points)               # 1 % dilation: scale
    g_ref = np.zeros(3 * dm.nvertices)
    term.add_gradient(stretch, g_ref)
    scale = dm.comm.tompi4py().allreduce(float(np.abs(g_ref).max()), op=MPI.MAX)
    gmax = dm.comm.tompi4py().allreduce(float(np.abs(g_local).max()), op=MPI.MAX)
    ci = cell_integrals(dm)
    volume = dm.comm.tompi4py().allreduce(float(ci.mass.sum()), op=MPI.SUM)
    _print(f"\ncurved P2 {material}: rigid energy {energy:.2e}, max force {gmax / scale:.2e} of "
           f"a 1 % dilation's, volume {volume:.15f}")
    assert abs(energy) < 1e-10 * 1e6 * 1e-4
    assert gmax < 1e-10 * scale
    assert volume == pytest.approx(1.0, rel=1e-13)
    assert (ci.lumped > 0).all()


def test_linear_traction_is_integrated_exactly():
    """A traction varying linearly over the loaded face (value = [0, 0, 1e3 (1 + y + 2 z)] on the
    face x = 1 of a P2 bar): the nodal forces' sum and their first moments equal the exact
    integrals int t dA and int t y dA, int t z dA (relative 1e-12)."""
    exp = _experiment("linear", size=(1.0, 0.4, 0.3), cells=(2, 2, 2),
                      boundary=[{"kind": "fixed", "where": "x < 1e-9"},
                                {"kind": "traction", "where": "x > 1 - 1e-9",
                                 "value": ["0", "0", "1e3 * (1 + y + 2 * z)"]}])
    model = build_model(exp)
    f = bcast_gathered(model, model.external)
    p = model.dmesh.mesh.points
    assert np.abs(f[p[:, 0] < 1 - 1e-9]).max() == 0.0
    b, c = 0.4, 0.3
    total = 1e3 * (b * c + b**2 / 2 * c + 2 * b * c**2 / 2)
    moment_y = 1e3 * (b**2 / 2 * c + b**3 / 3 * c + 2 * b**2 / 2 * c**2 / 2)
    moment_z = 1e3 * (b * c**2 / 2 + b**2 / 2 * c**2 / 2 + 2 * b * c**3 / 3)
    fz = f[:, 2]
    assert np.abs(f[:, :2]).max() == 0.0
    assert fz.sum() == pytest.approx(total, rel=1e-12)
    assert (fz * p[:, 1]).sum() == pytest.approx(moment_y, rel=1e-12)
    assert (fz * p[:, 2]).sum() == pytest.approx(moment_z, rel=1e-12)
    # the 6-node triangle's loads reach the edge nodes (P1 would load only the corners)
    assert np.abs(fz[model.dmesh.mesh.num_corners:]).max() > 0.1 * np.abs(fz).max()


def test_explicit_serial_equals_parallel():
    """Explicit (Verlet, HRZ lumped P2 mass) steps of a P2 bar: COMM_WORLD == COMM_SELF within
    1e-10 and the run is stable (bounded) at a step below the lumped-mass limit."""
    step = 2e-5
    exp = _bar_experiment(time={"end": 20 * step, "step": step, "integrator": "explicit"})
    finals = []
    for comm in (PETSc.COMM_SELF, PETSc.COMM_WORLD):
        model = build_model(exp, comm)
        sim = Simulation(model, exp)
        result = sim.run()
        finals.append(MPI.COMM_WORLD.bcast(model.dmesh.gather_global(result.q)))
        sim.destroy()
    a, b = finals
    diff = float(np.abs(a - b).max() / np.abs(a).max())
    _print(f"\nP2 explicit on {PETSc.COMM_WORLD.getSize()} ranks vs 1: {diff:.2e} "
           f"(|u|max {np.abs(a).max():.3e} m)")
    assert 0 < np.abs(a).max() < 1e-3
    assert diff < 1e-10


@pytest.mark.parametrize("flipped", [False, True], ids=["positive", "all-negative"])
def test_tetra10_file_nodes_land_on_their_edges(flipped, tmp_path):
    """read_mesh(order=2) of a tetra10 .vtu (the beam's DOLFINx nodes; with ``flipped`` every
    element written negatively oriented, corners 1 and 2 and their edges swapped, which
    validate() flips back): every element's edge node is the midpoint of its two corners, and
    a moved (curved) interior-edge node keeps its file position."""
    import meshio

    from petsoft.mesh.serial import read_mesh

    data = np.load(DATA / "beam_modes.npz")
    coords = np.asarray(data["dof_coords"]).copy()
    tets10 = np.asarray(data["tets10"]).copy()
    # curve one edge shared by several elements: move its node 1 % of the beam's width in y
    node = int(tets10[0, 9])
    coords[node, 1] += 1e-4
    if flipped:
        tets10 = tets10[:, [0, 2, 1, 3, 6, 5, 4, 7, 9, 8]]
    path = tmp_path / "beam.vtu"
    meshio.write(path, meshio.Mesh(coords, [("tetra10", tets10)]))
    with warnings.catch_warnings():   # the flip (and the corner renumbering) are reported
        warnings.simplefilter("ignore", MeshWarning)
        mesh = read_mesh(path, order=2)
    assert mesh.order == 2 and len(mesh.points) == len(coords)
    X = mesh.points[mesh.tets]
    _, vol = shape_gradients(X)
    assert (vol > 0).all()
    edges = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])
    mid = 0.5 * (X[:, edges[:, 0]] + X[:, edges[:, 1]])
    off = np.linalg.norm(mesh.points[mesh.edge_nodes] - mid, axis=2)
    moved = np.linalg.norm(mesh.points[mesh.edge_nodes] - coords[node], axis=2) < 1e-15
    assert moved.sum() >= 2                      # shared by several elements, found in each
    assert np.abs(off[moved] - 1e-4).max() < 1e-12
    assert off[~moved].max() < 1e-15


def test_rules_and_shape_functions():
    """tet_rule(d) integrates every monomial x^a y^b z^c of degree <= d over the reference
    tetrahedron exactly (a! b! c! / (a+b+c+3)!, relative 1e-13) and triangle_rule(d) likewise
    (a! b! / (a+b+2)!); the P2 shape functions are 1 at their own node and 0 at the others,
    and their gradients (quadratic_geometry on a curved element) equal central differences of
    the isoparametric map."""
    from math import factorial

    from petsoft.fem.element import triangle_rule

    for degree in range(1, 8):
        bary, w = tet_rule(degree)
        assert abs(w.sum() - 1.0) < 1e-14 and (w > 0).all()
        for a in range(degree + 1):
            for b in range(degree + 1 - a):
                for c in range(degree + 1 - a - b):
                    got = (w * bary[:, 1] ** a * bary[:, 2] ** b * bary[:, 3] ** c).sum() / 6
                    exact = factorial(a) * factorial(b) * factorial(c) / factorial(a + b + c + 3)
                    assert got == pytest.approx(exact, rel=1e-13), (degree, a, b, c)
        bary, w = triangle_rule(degree)
        for a in range(degree + 1):
            for b in range(degree + 1 - a):
                got = (w * bary[:, 1] ** a * bary[:, 2] ** b).sum() / 2
                exact = factorial(a) * factorial(b) / factorial(a + b + 2)
                assert got == pytest.approx(exact, rel=1e-13), (degree, a, b)
    # nodes of the reference element in barycentric coordinates: corners, then edge midpoints
    corners = np.eye(4)
    edges = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])
    nodes = np.concatenate([corners, 0.5 * (corners[edges[:, 0]] + corners[edges[:, 1]])])
    np.testing.assert_allclose(shape_values(2, nodes), np.eye(10), atol=1e-15)
    tri = np.eye(3)
    tri_nodes = np.concatenate([tri, 0.5 * (tri[[0, 1, 2]] + tri[[1, 2, 0]])])
    np.testing.assert_allclose(shape_values(2, tri_nodes), np.eye(6), atol=1e-15)
    # gradients on a curved element against differences of N(xi) mapped through X(xi)
    rng = np.random.default_rng(2)
    X = np.concatenate([REF_TET, 0.5 * (REF_TET[edges[:, 0]] + REF_TET[edges[:, 1]])])
    X = X + 0.05 * rng.uniform(-1, 1, X.shape) * (np.arange(10) >= 4)[:, None]
    xi = np.array([[0.2, 0.3, 0.1]])
    bary = np.column_stack([1 - xi.sum(axis=1), xi])
    dN, _ = quadratic_geometry(X[None], bary, np.ones(1))
    h, dN_dxi, dX_dxi = 1e-6, np.empty((10, 3)), np.empty((3, 3))
    for m in range(3):
        e = np.zeros(3)
        e[m] = h
        Np, Nm = (shape_values(2, np.column_stack([1 - (xi + s * e).sum(axis=1), xi + s * e]))[0]
                  for s in (1, -1))
        dN_dxi[:, m] = (Np - Nm) / (2 * h)
        dX_dxi[:, m] = (Np - Nm) @ X / (2 * h)
    np.testing.assert_allclose(dN[0, 0], dN_dxi @ np.linalg.inv(dX_dxi), rtol=0, atol=1e-8)
