"""Verification of the quasistatic solver (petsoft.solvers.static) against exact and reference
solutions.

1. Patch test: a homogeneous deformation prescribed on the whole boundary of a distorted mesh is
   reproduced exactly inside, for every material model and both solution methods.
2. Manufactured solution, linear elasticity: second-order L2 convergence to a smooth field.
3. Cantilever, small load: tip deflection against Timoshenko beam theory.
4. Cantilever, large load: neo-Hookean and co-rotated agree with each other (and roughly with the
   elastica); the linear model over-predicts.
5. Serial == parallel: for each linear solver and for TAO the displacement computed on
   PETSC_COMM_WORLD equals the one computed on a single rank.

Every test runs collectively: serially and under ``mpiexec -n 2`` (checked quantities are
reduced or broadcast, so assertions hold on every rank). ``pytest -s`` shows measured numbers.
"""

from __future__ import annotations

import numpy as np
import pytest
from _static_cases import (
    BOUNDARY_OF_UNIT_CUBE,
    ProductField,
    add_body_force,
    experiment,
    jittered_unit_cube,
    l2_error,
    linear_expressions,
    solve,
)
from petsc4py import PETSc

from petsoft.physics.model import build_model

MATERIALS = ("linear", "stvk", "corotated", "neohookean")
MUMPS = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}

def _print(*args):
    if PETSc.COMM_WORLD.getRank() == 0:
        print(*args)


def _rank_consistent(value: float) -> float:
    """The root's value, on every rank (assertions then agree across ranks)."""
    return PETSc.COMM_WORLD.tompi4py().bcast(value, root=0)


# ================================================================================================
# 1. Patch test


def _homogeneous_gradient() -> np.ndarray:
    """G = A - I with A = R (I + S): ~5% stretches/shears S and a 0.15 rad rotation R."""
    S = np.array([[0.05, 0.02, -0.01], [0.02, -0.03, 0.015], [-0.01, 0.015, 0.04]])
    axis = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    th = 0.15
    R = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
    A = R @ (np.eye(3) + S)
    assert np.linalg.det(A) > 0
    return A - np.eye(3)


def _patch_cases():
    for material in MATERIALS:
        for method in ("snes", "tao"):
            for start in ("zero", "perturbed"):
                yield pytest.param(material, method, start, id=f"{material}-{method}-{start}")


@pytest.mark.parametrize(("material", "method", "start"), list(_patch_cases()))
def test_patch_homogeneous_deformation(material, method, start):
    """Patch test: u = (A - I) X prescribed on every boundary vertex of a 4x4x4-hex box with
    randomly displaced interior vertices (no body force) must be reproduced at the 27 interior
    vertices to round-off (max error < 1e-9 of max |u|) for every material: the discrete
    equilibrium of P1 elements holds exactly for homogeneous (constant-F) states. A = R (I + S):
    ~5% strain and a 0.15 rad rotation (finite: the linear model must also pass, its exact
    solution for these boundary values is the same affine field). 'perturbed' starts Newton from
    a random interior displacement so that the nonlinear iterations, not only the initial
    lifting, are tested."""
    G = _homogeneous_gradient()
    mesh, interior = jittered_unit_cube(4, amplitude=0.3, seed=7)
    exp = experiment(material, box=((1.0, 1.0, 1.0), (4, 4, 4)), boundary=[{
        "kind": "prescribed", "where": BOUNDARY_OF_UNIT_CUBE,
        "displacement": linear_expressions(G)}])
    model = build_model(exp, mesh=mesh)
    x0 = None
    if start == "perturbed":
        rng = np.random.default_rng(3)
        x0 = model.dmesh.from_file_field(rng.uniform(-0.03, 0.03, mesh.points.shape)
                                         * interior[:, None])
    u, result = solve(model, method=method, x0=x0)
    exact = mesh.points @ G.T
    err = _rank_consistent(float(np.abs(u - exact)[interior].max() / np.abs(exact).max()))
    _print(f"\npatch {material}/{method}/{start}: max interior error / max|u| = {err:.2e}, "
           f"{result.newton_iterations} Newton iterations")
    assert err < 1e-9
    if start == "perturbed":
        assert result.newton_iterations >= 1


# ================================================================================================
# 2. Manufactured solution, linear elasticity

E_MMS, NU_MMS = 1e6, 0.3
FIELD = ProductField(
    amp=np.array([0.01, -0.008, 0.012]),
    omega=np.pi / 2 * np.array([[1.3, 0.9, 1.1], [0.8, 1.5, 0.7], [1.2, 1.0, 1.4]]),
    phase=np.array([[0.3, 1.1, 0.5], [0.9, 0.2, 1.3], [0.4, 0.8, 0.1]]))


def _lame(E, nu):
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def test_manufactured_body_force_is_minus_div_sigma():
    """The hand-derived manufactured body force f = -(mu lap u + (lam + mu) grad div u) equals
    -div sigma(u) computed by central differences of the stress (h = 1e-5, rel. 1e-7)."""
    lam, mu = _lame(E_MMS, NU_MMS)
    x = np.random.default_rng(0).uniform(0.0, 1.0, (20, 3))
    h, fd = 1e-5, np.zeros((20, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = h
        dsigma = FIELD.stress(lam, mu, x + e) - FIELD.stress(lam, mu, x - e)
        fd -= dsigma[:, :, j] / (2 * h)
    f = FIELD.body_force(lam, mu)(x)
    assert np.abs(f - fd).max() < 1e-7 * np.abs(fd).max()


@pytest.mark.parametrize("method", ["snes", "tao"])
def test_manufactured_solution_linear_elasticity_converges_at_second_order(method):
    """Manufactured solution: u = (a_i prod_j sin(w_ij x_j + p_ij)) on the unit cube, linear
    material (E = 1e6, nu = 0.3), body force f = -div sigma(u) as consistent nodal loads
    (27-point conical-product quadrature per tet), u = u_exact prescribed on the whole boundary.
    On 4^3, 8^3, 16^3-hex meshes the L2 error (same quadrature) must converge at rate 2 for P1:
    last rate in [1.8, 2.2]."""
    lam, mu = _lame(E_MMS, NU_MMS)
    errors = []
    for n in (4, 8, 16):
        exp = experiment("linear", box=((1.0, 1.0, 1.0), (n, n, n)), E=E_MMS, nu=NU_MMS,
                         boundary=[{"kind": "prescribed", "where": BOUNDARY_OF_UNIT_CUBE,
                                    "displacement": FIELD.expressions()}])
        model = build_model(exp)
        add_body_force(model, FIELD.body_force(lam, mu))
        u, result = solve(model, method=method)
        err, norm = l2_error(model, u, FIELD)
        errors.append(err)
        _print(f"\nMMS {method} n={n}: ||u_h - u||_L2 = {err:.4e} (relative {err / norm:.3e}), "
               f"{result.newton_iterations} Newton / {result.linear_iterations} linear iterations")
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    _print(f"MMS {method} rates: {np.array2string(rates, precision=3)}")
    rates = _rank_consistent(rates)
    assert 1.8 <= rates[-1] <= 2.2
    assert rates[0] > 1.5


# ================================================================================================
# 3./4. Cantilever

L_BAR, B_BAR, E_BAR = 1.0, 0.1, 1e6


def _cantilever(material: str, cells, traction_z: float, nu: float):
    """Bar [0, L] x [0, b] x [0, b] clamped at x = 0 (all components), uniform traction
    (0, 0, traction_z) on the face x = L."""
    exp = experiment(material, box=((L_BAR, B_BAR, B_BAR), cells), E=E_BAR, nu=nu,
                     boundary=[{"kind": "fixed", "where": "x < 1e-9"},
                               {"kind": "traction", "where": f"x > {L_BAR} - 1e-9",
                                "value": [0.0, 0.0, traction_z]}])
    return build_model(exp)


def _tip(model, u):
    """Mean displacement of the vertices of the loaded end face (x = L)."""
    tip = model.dmesh.mesh.points[:, 0] > L_BAR - 1e-9
    return u[tip].mean(axis=0)


CANTILEVER_CELLS = (120, 1, 14)


def test_cantilever_small_load_matches_timoshenko():
    """Cantilever 1 x 0.1 x 0.1 m, E = 1e6 Pa, nu = 0, clamped at x = 0, end traction 1 Pa
    (P = 0.01 N): the mean tip deflection must agree with Timoshenko beam theory
    d = P L^3 / (3 E I) + P L / (kappa G A), kappa = 5/6 (0.6% above Euler-Bernoulli), within 2%.
    Mesh 120 x 1 x 14 hexahedra (6 tets each; 3630 vertices): P1 tets lock in bending, so the
    length and the thickness (bending direction z) need many cells; with nu = 0 the exact
    solution does not depend on y, so one cell across the width suffices. Linear material, MUMPS."""
    nu, q = 0.0, 1.0
    model = _cantilever("linear", CANTILEVER_CELLS, -q, nu)
    u, result = solve(model, method="snes", options=MUMPS)
    d = _rank_consistent(float(-_tip(model, u)[2]))
    P, A, I = q * B_BAR**2, B_BAR**2, B_BAR**4 / 12
    G, kappa = E_BAR / (2 * (1 + nu)), 10 * (1 + nu) / (12 + 11 * nu)
    euler = P * L_BAR**3 / (3 * E_BAR * I)
    timoshenko = euler + P * L_BAR / (kappa * G * A)
    rel = (d - timoshenko) / timoshenko
    _print(f"\ncantilever small load, mesh {CANTILEVER_CELLS} hexes: tip deflection {d:.6e} m, "
           f"Timoshenko {timoshenko:.6e} (error {rel:+.3%}), Euler-Bernoulli {euler:.6e} "
           f"(error {(d - euler) / euler:+.3%}), {result.newton_iterations} Newton iterations")
    assert d == pytest.approx(timoshenko, rel=0.02)


def test_tao_solves_linear_cantilever_like_snes():
    """TAO (minimisation) must give the SNES displacement (relative max-norm difference < 1e-8)
    on a small linear cantilever (20 x 1 x 2 hexes, end traction 1 Pa, default solvers)."""
    model = _cantilever("linear", (20, 1, 2), -1.0, 0.0)
    u_snes, _ = solve(model, method="snes")
    u_tao, result = solve(model, method="tao")
    diff = _rank_consistent(float(np.abs(u_tao - u_snes).max() / np.abs(u_snes).max()))
    _print(f"\nTAO vs SNES, linear cantilever: relative difference {diff:.2e}, "
           f"{result.newton_iterations} TAO iterations")
    assert diff < 1e-8


def _elastica_tip(alpha: float, n: int = 400) -> tuple[float, float]:
    """Inextensible elastica under a dead transverse tip load, alpha = P L^2 / (E I):
    theta'' = -alpha cos(theta), theta(0) = 0, theta'(1) = 0 (arc length s in [0, 1]), by
    RK4 shooting on theta'(0). Returns (deflection / L, shortening / L) of the tip."""
    def run(k):
        s, h = np.array([0.0, k, 0.0, 0.0]), 1.0 / n

        def f(v):
            return np.array([v[1], -alpha * np.cos(v[0]), np.cos(v[0]), np.sin(v[0])])
        for _ in range(n):
            k1 = f(s)
            k2 = f(s + h / 2 * k1)
            k3 = f(s + h / 2 * k2)
            k4 = f(s + h * k3)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return s
    lo, hi = 0.0, alpha
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if run(mid)[1] > 0 else (mid, hi)
    s = run(0.5 * (lo + hi))
    return float(s[3]), float(1.0 - s[2])


LARGE_CELLS = (60, 1, 6)


def test_cantilever_large_load_corotated_matches_neohookean_not_linear():
    """Cantilever as above (nu = 0), end load P = 1.5 E I / L^2 (traction 1250 Pa), mesh
    60 x 1 x 6 hexahedra, 2 load steps, MUMPS: the tip deflects ~40% of L with a ~37 degree end
    rotation. Neo-Hookean and co-rotated must both converge (Newton) and their tip deflections
    agree within 2% (the strains stay small, the large rotation dominates); the linear model,
    without geometric stiffening, must over-predict by more than 10% (beam theory: 0.50 L against
    the elastica's 0.411 L). As a sanity check both nonlinear deflections lie within 8% of the
    elastica (the coarse P1 mesh is ~5% too stiff in bending)."""
    nu, alpha = 0.0, 1.5
    I = B_BAR**4 / 12
    q = alpha * E_BAR * I / L_BAR**2 / B_BAR**2
    elastica, shortening = _elastica_tip(alpha)
    tips, iterations = {}, {}
    for material in ("linear", "corotated", "neohookean"):
        model = _cantilever(material, LARGE_CELLS, -q, nu)
        u, result = solve(model, method="snes", load_steps=2, options=MUMPS)
        tips[material] = _rank_consistent(_tip(model, u))
        iterations[material] = result.newton_iterations
        _print(f"\ncantilever large load {material}: tip deflection {-tips[material][2]:.5f} L, "
               f"tip shortening {-tips[material][0]:.5f} L (elastica {elastica:.5f} L, "
               f"{shortening:.5f} L), {result.newton_iterations} Newton iterations in "
               f"{result.load_steps} load steps ({result.retries} retries) {result.history}")
        assert result.load_steps >= 2
    d = {m: -t[2] for m, t in tips.items()}
    rel_nl = abs(d["neohookean"] - d["corotated"]) / d["corotated"]
    over = d["linear"] / d["corotated"] - 1
    _print(f"neo-Hookean vs co-rotated: {rel_nl:.3%}; linear over-predicts by {over:.2%}")
    assert rel_nl < 0.02
    assert over > 0.10
    for m in ("corotated", "neohookean"):
        assert d[m] == pytest.approx(elastica, rel=0.08)
        assert -tips[m][0] > 0.05  # the tip moves back (rotation), unlike the linear model
    assert abs(tips["linear"][0]) < 1e-3


# ================================================================================================
# 5. Serial == parallel

PATHS = {
    "gamg": {},
    "sor": {"pc_type": "sor", "ksp_max_it": "20000"},
    "jacobi": {"pc_type": "jacobi", "ksp_max_it": "20000"},
    "mumps": dict(MUMPS),
}


def _path_options(method: str, path: str) -> dict[str, str]:
    tight = {"ksp_rtol": "1e-12", **PATHS[path]}
    if method == "snes":
        return {"snes_rtol": "1e-12", **tight}
    # TAO's Newton KSP has the options prefix tao_nls_ (plain -ksp_* do not reach it).
    return {f"tao_nls_{k}": v for k, v in tight.items()}


def _parallel_cases():
    for method in ("snes", "tao"):
        for path in PATHS:
            yield pytest.param(method, path, id=f"{method}-{path}")


@pytest.mark.parametrize(("method", "path"), list(_parallel_cases()))
def test_parallel_equals_serial(method, path):
    """Neo-Hookean bar 1 x 0.3 x 0.3 m (12 x 4 x 4 hexes), E = 1e6, nu = 0.3, clamped at x = 0,
    gravity (0, 0, -9.81) with density 1000 and an end traction (0, 400, -800) Pa, 2 load steps
    (tip displacement ~0.2 m):
    the displacement solved on PETSC_COMM_WORLD (2 ranks under mpiexec) must equal the one solved
    on a single rank (PETSC_COMM_SELF, same options) within a relative max-norm difference of
    1e-8, for each linear solver (CG + GAMG/SOR/Jacobi, MUMPS LU) under SNES and TAO."""
    exp = experiment("neohookean", box=((1.0, 0.3, 0.3), (12, 4, 4)), E=1e6, nu=0.3,
                     gravity=(0.0, 0.0, -9.81),
                     boundary=[{"kind": "fixed", "where": "x < 1e-9"},
                               {"kind": "traction", "where": "x > 1 - 1e-9",
                                "value": [0.0, 400.0, -800.0]}])
    options = _path_options(method, path)
    runs = {}
    for name, comm in (("serial", PETSc.COMM_SELF), ("parallel", PETSc.COMM_WORLD)):
        model = build_model(exp, comm=comm)
        u, result = solve(model, method=method, load_steps=2, options=options)
        runs[name] = (u, result)
    (u1, r1), (un, rn) = runs["serial"], runs["parallel"]
    diff = _rank_consistent(float(np.abs(un - u1).max() / np.abs(u1).max()))
    _print(f"\n{method}/{path} on {PETSc.COMM_WORLD.getSize()} ranks vs 1: relative difference "
           f"{diff:.2e}; |u|max {np.abs(u1).max():.4f} m; Newton iterations {r1.newton_iterations} "
           f"(1 rank) / {rn.newton_iterations}, linear {r1.linear_iterations} / "
           f"{rn.linear_iterations}")
    assert diff < 1e-8
