"""Tetrahedron geometry and element energy/gradient/Hessian kernels (numpy reference and C).

Serial computations only: under ``mpiexec -n 2`` every rank simply runs the same checks.
"""

from __future__ import annotations

import numpy as np
import pytest

from petsoft.errors import InvertedElementError, MeshError, PetsoftError
from petsoft.fem.kernels import compiled, elastic, reference
from petsoft.fem.kernels.materials import MODELS
from petsoft.fem.kernels.tet import mesh_shape_gradients, shape_gradients

BACKENDS = ("numpy", "c")
REF_TET = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def orient(X):
    """Swap nodes 1 and 2 of negatively oriented tets."""
    X = X.copy()
    _, vol = shape_gradients(X)
    X[vol < 0] = X[vol < 0][:, [0, 2, 1, 3]]
    return X


def random_elements(rng, n, scale=0.25, min_det=0.3):
    """Well-shaped random tets and displacements with det F > min_det (moderately large)."""
    X = orient(REF_TET + 0.15 * rng.standard_normal((3 * n, 4, 3)))
    dN, vol = shape_gradients(X)
    u = scale * rng.standard_normal((3 * n, 4, 3))
    keep = np.linalg.det(reference.deformation_gradient(dN, u)) > min_det
    dN, vol, u = dN[keep][:n], vol[keep][:n], u[keep][:n]
    assert len(vol) == n
    return dN, vol, u, rng.uniform(0.5, 2.0, n), rng.uniform(0.5, 5.0, n)


@pytest.fixture
def rng():
    return np.random.default_rng(7)


def rates_of(remainders):
    r = np.asarray(remainders)
    return np.log2(r[:-1] / r[1:])


HS = 1e-3 * 0.5 ** np.arange(4)


def test_mesh_shape_gradients_equal_those_of_the_gathered_coordinates(rng):
    points = rng.standard_normal((30, 3))
    cells = np.array([rng.choice(30, 4, replace=False) for _ in range(40)])
    dN, vol = mesh_shape_gradients(points, cells)
    ref_dN, ref_vol = shape_gradients(points[cells])
    assert np.array_equal(dN, ref_dN) and np.array_equal(vol, ref_vol)
    # the gradients are those of the closed form: reproduce linear fields
    np.testing.assert_allclose(np.einsum("eai,eaj->eij", points[cells], dN),
                               np.broadcast_to(np.eye(3), (40, 3, 3)), atol=1e-9)
    flat = cells.copy()
    flat[7] = [0, 1, 2, 2]                 # a repeated vertex: zero volume
    with pytest.raises(MeshError, match="tetrahedron 7 is degenerate"):
        mesh_shape_gradients(points, flat)
    with pytest.raises(ValueError, match="outside 0..29"):
        mesh_shape_gradients(points, np.where(cells == 5, 30, cells))


# --------------------------------------------------------------------------------------------
# Geometry


def test_shape_gradients_reference_tet():
    dN, vol = shape_gradients(REF_TET[None])
    np.testing.assert_allclose(vol, [1.0 / 6.0])
    np.testing.assert_allclose(dN[0], [[-1, -1, -1], [1, 0, 0], [0, 1, 0], [0, 0, 1]])


def test_shape_gradients_random_tets(rng):
    X = rng.standard_normal((50, 4, 3))
    dN, vol = shape_gradients(X)
    # Partition of unity and exact reproduction of linear fields: sum_a X_a (x) dN_a = I.
    np.testing.assert_allclose(dN.sum(axis=1), 0.0, atol=1e-10)
    np.testing.assert_allclose(
        np.einsum("eai,eaj->eij", X, dN), np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-10
    )
    expected = np.linalg.det(np.swapaxes(X[:, 1:] - X[:, :1], 1, 2)) / 6.0
    np.testing.assert_allclose(vol, expected, rtol=1e-12)
    assert (vol < 0).any() and (vol > 0).any()  # signed
    _, vol_swapped = shape_gradients(X[:, [0, 2, 1, 3]])
    np.testing.assert_allclose(vol_swapped, -vol, rtol=1e-12)


def test_shape_gradients_reject_degenerate_tet():
    X = np.stack([REF_TET, REF_TET, REF_TET])
    X[1, 3] = [0.5, 0.5, 0.0]  # flat: all four nodes in the plane z = 0
    with pytest.raises(MeshError, match="tetrahedron 1 is degenerate"):
        shape_gradients(X)


# --------------------------------------------------------------------------------------------
# Taylor tests of the element terms


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("model", MODELS)
def test_taylor_gradient_is_derivative_of_energy(model, backend, rng):
    dN, vol, u, mu, lam = random_elements(rng, 10)
    du = rng.standard_normal(u.shape)
    W = elastic.element_energy(model, dN, vol, u, mu, lam, backend=backend)
    g, _ = elastic.element_gradient_hessian(
        model, dN, vol, u, mu, lam, hessian=False, backend=backend
    )
    slope = np.einsum("ei,ei->e", g, du.reshape(-1, 12))
    r = [
        np.abs(
            elastic.element_energy(model, dN, vol, u + h * du, mu, lam, backend=backend)
            - W
            - h * slope
        )
        for h in HS
    ]
    rates = rates_of(r)
    assert rates.min() > 1.8 and rates.max() < 2.2, rates


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("model", MODELS)
def test_taylor_hessian_is_derivative_of_gradient(model, backend, rng):
    dN, vol, u, mu, lam = random_elements(rng, 10)
    du = rng.standard_normal(u.shape)
    g, H = elastic.element_gradient_hessian(model, dN, vol, u, mu, lam, backend=backend)
    slope = np.einsum("eij,ej->ei", H, du.reshape(-1, 12))

    def remainder(h):
        g2, _ = elastic.element_gradient_hessian(
            model, dN, vol, u + h * du, mu, lam, hessian=False, backend=backend
        )
        return np.linalg.norm(g2 - g - h * slope, axis=1)

    if model == "linear":
        # g is linear in u: the expansion is exact and the remainder is rounding error.
        for h in HS:
            assert np.all(remainder(h) <= 1e-11 * h * np.linalg.norm(slope, axis=1))
        return
    rates = rates_of([remainder(h) for h in HS])
    assert rates.min() > 1.8 and rates.max() < 2.2, rates


# --------------------------------------------------------------------------------------------
# C against the numpy reference


@pytest.mark.parametrize("project", [False, True])
@pytest.mark.parametrize("model", MODELS)
def test_c_matches_numpy(model, project, rng):
    dN, vol, u, mu, lam = random_elements(rng, 200, scale=0.3, min_det=0.15)
    W_ref = reference.element_energy(model, dN, vol, u, mu, lam)
    W_c = compiled.element_energy(model, dN, vol, u, mu, lam)
    np.testing.assert_allclose(W_c, W_ref, rtol=1e-12, atol=1e-12 * np.abs(W_ref).max())
    g_ref, H_ref = reference.element_gradient_hessian(
        model, dN, vol, u, mu, lam, project_spd=project
    )
    g_c, H_c = compiled.element_gradient_hessian(model, dN, vol, u, mu, lam, project_spd=project)
    np.testing.assert_allclose(g_c, g_ref, rtol=1e-12, atol=1e-12 * np.abs(g_ref).max())
    # Per element, relative to that element's (unprojected) Hessian: elements differ in
    # stiffness, and the projection's rounding error scales with what it removes.
    _, H_full = reference.element_gradient_hessian(model, dN, vol, u, mu, lam)
    scale = np.abs(H_full).max(axis=(1, 2))[:, None, None]
    assert np.all(np.abs(H_c - H_ref) <= 1e-12 * scale)
    if project and model != "linear":
        # The test is meaningful: some tangents were indefinite and got projected.
        assert (np.abs(H_full - H_ref).max(axis=(1, 2)) > 1e-6 * scale[:, 0, 0]).sum() > 5


def displacement_for(dN, F):
    """Element displacements (n, 4, 3) whose deformation gradients are F (n, 3, 3).

    Solves F - I = sum_a u_a (x) dN_a, i.e. (F - I) row-major = kron(I, dN^T) @ u
    component-major, for the minimum-norm u.
    """
    u = np.empty((len(dN), 4, 3))
    for e in range(len(dN)):  # a handful of test elements
        M = np.kron(np.eye(3), dN[e].T)
        u[e] = np.linalg.lstsq(M, (F[e] - np.eye(3)).ravel(), rcond=None)[0].reshape(3, 4).T
    return u


@pytest.mark.parametrize("model", ["stvk", "corotated", "neohookean"])
def test_projection_with_repeated_and_negative_singular_values(model, rng):
    """The C projection works in the SVD frame: check it where that frame is not unique
    (repeated singular values) and, where the model allows it, for det F < 0."""
    Q = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    stretches = [
        [0.6, 0.6, 0.6], [0.5, 0.5, 1.2], [1.3, 0.7, 0.7], [1.0, 1.0, 1.0], [0.3, 0.3, 0.3],
        [1.5, 1.5, 0.4], [0.2, 1.0, 1.0],
    ]  # fmt: skip
    if model != "neohookean":
        stretches += [[1.0, 1.0, -0.5], [0.8, 0.6, -0.5], [2.0, -0.3, 0.7]]
    F = np.array([Q @ np.diag(s) @ Q.T for s in stretches])
    F[1] = F[1] @ Q  # a rotation on top
    n = len(F)
    dN, vol, _, mu, lam = random_elements(rng, n)
    u = displacement_for(dN, F)
    np.testing.assert_allclose(reference.deformation_gradient(dN, u), F, atol=1e-12)
    _, H_ref = reference.element_gradient_hessian(model, dN, vol, u, mu, lam, project_spd=True)
    _, H_c = compiled.element_gradient_hessian(model, dN, vol, u, mu, lam, project_spd=True)
    # Relative to the unprojected Hessian: some of these tangents are entirely negative, so
    # the projection is 0 up to rounding of the size of what was removed.
    _, H_full = reference.element_gradient_hessian(model, dN, vol, u, mu, lam)
    scale = np.abs(H_full).max(axis=(1, 2))[:, None, None]
    assert np.all(np.abs(H_c - H_ref) <= 1e-12 * scale)
    assert np.all(np.linalg.eigvalsh(H_c).min(axis=1) > -1e-12 * scale[:, 0, 0])


@pytest.mark.parametrize("model", MODELS)
def test_hessians_symmetric_and_projected_psd(model, rng):
    dN, vol, u, mu, lam = random_elements(rng, 100, scale=0.3, min_det=0.15)
    for backend in BACKENDS:
        _, H = elastic.element_gradient_hessian(model, dN, vol, u, mu, lam, backend=backend)
        if backend == "c":
            np.testing.assert_array_equal(H, np.swapaxes(H, 1, 2))  # exactly, by construction
        else:
            np.testing.assert_allclose(H, np.swapaxes(H, 1, 2), atol=1e-14 * np.abs(H).max())
        _, Hp = elastic.element_gradient_hessian(
            model, dN, vol, u, mu, lam, project_spd=True, backend=backend
        )
        w = np.linalg.eigvalsh(Hp)
        assert w.min(axis=1).min() > -1e-12 * np.abs(w).max()


# --------------------------------------------------------------------------------------------
# Patch test: a homogeneous stress exerts no force on interior nodes


def octahedron_patch(rng):
    """8 tets sharing the interior node 0, with randomly perturbed node positions."""
    nodes = np.vstack([np.zeros(3), np.eye(3), -np.eye(3)]) + 0.1 * rng.standard_normal((7, 3))
    tets = np.array([[0, 1 + 3 * (sx < 0), 2 + 3 * (sy < 0), 3 + 3 * (sz < 0)]
                     for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)])  # fmt: skip
    X = nodes[tets]
    _, vol = shape_gradients(X)
    tets[vol < 0] = tets[vol < 0][:, [0, 2, 1, 3]]
    return nodes, tets


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("model", MODELS)
def test_patch_affine_displacement_no_interior_force(model, backend, rng):
    nodes, tets = octahedron_patch(rng)
    dN, vol = shape_gradients(nodes[tets])
    assert np.all(vol > 0)
    A = 0.3 * rng.standard_normal((3, 3))
    assert np.linalg.det(np.eye(3) + A) > 0.2
    u = nodes[tets] @ A.T + 0.05  # affine (a rigid translation included)
    g, _ = elastic.element_gradient_hessian(
        model, dN, vol, u, 1.3, 2.1, hessian=False, backend=backend
    )
    f = np.zeros((len(nodes), 3))
    np.add.at(f, tets, g.reshape(-1, 4, 3))
    assert np.abs(g).max() > 1e-2  # the stress is not trivially zero
    np.testing.assert_allclose(f[0], 0.0, atol=1e-13 * np.abs(g).max())
    # Boundary nodes do feel the (equilibrated) traction; all forces sum to zero.
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-13 * np.abs(g).max())


# --------------------------------------------------------------------------------------------
# Inverted elements, argument handling


@pytest.mark.parametrize("backend", BACKENDS)
def test_neohookean_inverted_element_named(backend, rng):
    dN, vol, u, mu, lam = random_elements(rng, 12)
    # Invert elements 9 (det F = -0.5) and 11 (det F = 0).
    u[[9, 11]] = displacement_for(
        dN[[9, 11]], np.array([np.diag([1.0, 1.0, J]) for J in (-0.5, 0.0)])
    )
    F = reference.deformation_gradient(dN, u)
    np.testing.assert_allclose(np.linalg.det(F[[9, 11]]), [-0.5, 0.0], atol=1e-12)
    for call in (
        lambda: elastic.element_energy("neohookean", dN, vol, u, mu, lam, backend=backend),
        lambda: elastic.element_gradient_hessian(
            "neohookean", dN, vol, u, mu, lam, backend=backend
        ),
        lambda: elastic.element_gradient_hessian(
            "neohookean", dN, vol, u, mu, lam, project_spd=True, backend=backend
        ),
    ):
        with pytest.raises(InvertedElementError) as err:
            call()
        assert err.value.element == 9
        assert err.value.jacobian == pytest.approx(-0.5)
    # Other models are defined there and stay finite.
    for model in ("linear", "stvk", "corotated"):
        g, H = elastic.element_gradient_hessian(model, dN, vol, u, mu, lam, backend=backend)
        assert np.isfinite(g).all() and np.isfinite(H).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_flat_and_scalar_arguments(backend, rng):
    dN, vol, u, mu, lam = random_elements(rng, 5)
    g1, H1 = elastic.element_gradient_hessian("stvk", dN, vol, u, 1.5, 2.5, backend=backend)
    g2, H2 = elastic.element_gradient_hessian(
        "stvk", dN, vol, u.reshape(5, 12), np.full(5, 1.5), np.full(5, 2.5), backend=backend
    )
    np.testing.assert_array_equal(g1, g2)
    np.testing.assert_array_equal(H1, H2)
    g3, H3 = elastic.element_gradient_hessian(
        "stvk", dN, vol, u, 1.5, 2.5, hessian=False, backend=backend
    )
    assert H3 is None
    np.testing.assert_array_equal(g3, g1)
    # Non-contiguous arrays and lists are converted.
    g4, _ = elastic.element_gradient_hessian(
        "stvk", np.asfortranarray(dN), vol.tolist(), u.transpose(1, 0, 2).copy().transpose(1, 0, 2),
        [1.5] * 5, 2.5, backend=backend,
    )  # fmt: skip
    np.testing.assert_allclose(g4, g1, rtol=1e-14)


@pytest.mark.parametrize("backend", BACKENDS)
def test_into_writes_preallocated_buffers(backend, rng):
    dN, vol, u, mu, lam = random_elements(rng, 7)
    g_ref, H_ref = elastic.element_gradient_hessian(
        "neohookean", dN, vol, u, mu, lam, project_spd=True
    )
    g, H = np.full((7, 12), np.nan), np.full((7, 12, 12), np.nan)
    elastic.element_gradient_hessian_into(
        "neohookean", dN, vol, u, mu, lam, g, H, project_spd=True, backend=backend
    )
    np.testing.assert_allclose(g, g_ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(H, H_ref, rtol=1e-12, atol=1e-12 * np.abs(H_ref).max())
    g[:] = np.nan
    elastic.element_gradient_hessian_into(
        "neohookean", dN, vol, u, mu, lam, g, None, backend=backend
    )
    np.testing.assert_allclose(g, g_ref, rtol=1e-12, atol=1e-14)


def test_into_rejects_bad_buffers(rng):
    dN, vol, u, mu, lam = random_elements(rng, 4)
    good_g, good_H = np.empty((4, 12)), np.empty((4, 12, 12))
    for g, H in [
        (np.empty((4, 12), dtype=np.float32), good_H),
        (good_g, np.empty((4, 144))),
        (good_g, np.empty((4, 12, 24))[:, :, ::2]),  # not contiguous
        (np.empty((3, 12)), good_H),
    ]:
        with pytest.raises(ValueError):
            elastic.element_gradient_hessian_into("linear", dN, vol, u, mu, lam, g, H)


@pytest.mark.parametrize("backend", BACKENDS)
def test_bad_inputs(backend, rng):
    dN, vol, u, mu, lam = random_elements(rng, 4)
    with pytest.raises(PetsoftError, match="unknown material model"):
        elastic.element_energy("rubber", dN, vol, u, mu, lam, backend=backend)
    bad_vol = vol.copy()
    bad_vol[2] = -bad_vol[2]
    with pytest.raises(MeshError, match="element 2"):
        elastic.element_energy("linear", dN, bad_vol, u, mu, lam, backend=backend)
    for bad in (0.0, np.nan):      # degenerate, or a geometry that went wrong upstream
        bad_vol = vol.copy()
        bad_vol[3] = bad
        with pytest.raises(MeshError, match="element 3"):
            elastic.element_energy("linear", dN, bad_vol, u, mu, lam, backend=backend)
    with pytest.raises(ValueError):
        elastic.element_energy("linear", dN, vol, u[:3], mu, lam, backend=backend)


def test_unknown_backend(rng):
    dN, vol, u, mu, lam = random_elements(rng, 2)
    with pytest.raises(PetsoftError, match="valid backends are c, numpy"):
        elastic.element_energy("linear", dN, vol, u, mu, lam, backend="fortran")


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("model", MODELS)
def test_empty_element_set(model, backend):
    dN, vol, u = np.empty((0, 4, 3)), np.empty(0), np.empty((0, 4, 3))
    W = elastic.element_energy(model, dN, vol, u, 1.0, 1.0, backend=backend)
    g, H = elastic.element_gradient_hessian(
        model, dN, vol, u, 1.0, 1.0, project_spd=True, backend=backend
    )
    assert W.shape == (0,) and g.shape == (0, 12) and H.shape == (0, 12, 12)


def test_lame_parameters_reexported():
    assert elastic.lame_parameters is not None and elastic.MODELS == MODELS


@pytest.mark.parametrize("mu, lam", [(1.0, -1.0), (-0.5, 2.0)])
def test_linear_projection_with_nonphysical_parameters(mu, lam, rng):
    """mu < 0 or 3 lam + 2 mu < 0 makes the linear tangent indefinite (C: numeric 9x9 path)."""
    dN, vol, u, _, _ = random_elements(rng, 20)
    _, H_full = reference.element_gradient_hessian("linear", dN, vol, u, mu, lam)
    _, H_ref = reference.element_gradient_hessian("linear", dN, vol, u, mu, lam, project_spd=True)
    _, H_c = compiled.element_gradient_hessian("linear", dN, vol, u, mu, lam, project_spd=True)
    scale = np.abs(H_full).max(axis=(1, 2))[:, None, None]
    assert np.abs(H_full - H_ref).max() > 1e-3 * scale.max()
    assert np.all(np.abs(H_c - H_ref) <= 1e-12 * scale)
    assert np.all(np.linalg.eigvalsh(H_c).min(axis=1) > -1e-12 * scale[:, 0, 0])


def _shared_node_mesh(rng, n_elements=60, n_nodes=40):
    """Random tetrahedra sharing nodes (so the scatter adds), with their node displacements."""
    points = rng.standard_normal((n_nodes, 3))
    cells = np.array([rng.choice(n_nodes, 4, replace=False) for _ in range(3 * n_elements)])
    dN, vol = mesh_shape_gradients(points, cells[:, [0, 1, 2, 3]])
    flip = vol < 0
    cells[flip] = cells[flip][:, [0, 2, 1, 3]]
    dN, vol = mesh_shape_gradients(points, cells)
    u = 0.02 * rng.standard_normal((n_nodes, 3))
    keep = (np.abs(vol) > 1e-3) & (np.linalg.det(reference.deformation_gradient(dN, u[cells]))
                                    > 0.3)
    cells, dN, vol = cells[keep][:n_elements], dN[keep][:n_elements], vol[keep][:n_elements]
    assert len(cells) == n_elements
    mu, lam = rng.uniform(0.5, 2.0, n_elements), rng.uniform(0.5, 5.0, n_elements)
    return cells.astype(np.int64), np.ascontiguousarray(dN), vol, u, mu, lam


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("model", MODELS)
def test_indexed_elements_energy_and_scattered_gradient(model, backend, rng):
    cells, dN, vol, u, mu, lam = _shared_node_mesh(rng)
    g, _ = reference.element_gradient_hessian(model, dN, vol, u[cells], mu, lam, hessian=False)
    expected = np.full(u.shape, 0.5)        # added to what the output holds
    np.add.at(expected, cells, g.reshape(-1, 4, 3))
    out = np.full(u.shape, 0.5)
    gradient = elastic.IndexedElements(model, cells, dN, vol, mu, lam, len(u), backend=backend)
    gradient.add_gradient(u, out)
    np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    energy = reference.element_energy(model, dN, vol, u[cells], mu, lam).sum()
    assert gradient.energy(u) == pytest.approx(energy, rel=1e-13)
    # the Lame parameters are read at every call: changed in place, the law changes
    mu *= 2.0
    lam *= 2.0
    out[:] = 0.0
    gradient.add_gradient(u.ravel(), out.reshape(-1))
    np.testing.assert_allclose(out, 2.0 * (expected - 0.5), rtol=1e-12,
                               atol=1e-12 * np.abs(expected).max())


@pytest.mark.parametrize("backend", BACKENDS)
def test_indexed_elements_name_the_inverted_element(backend, rng):
    cells, dN, vol, u, mu, lam = _shared_node_mesh(rng)
    bad = 17
    u_bad = u.copy()
    # move its first node through the opposite face: det(I + d (x) dN_a) = 1 + dN_a . d = -1
    grad_a = dN[bad, 0]
    u_bad[cells[bad, 0]] += -2.0 * grad_a / grad_a.dot(grad_a)
    X = np.linalg.det(reference.deformation_gradient(dN, u_bad[cells]))
    first = int(np.flatnonzero(X <= 0)[0])
    gradient = elastic.IndexedElements("neohookean", cells, dN, vol, mu, lam, len(u),
                                       backend=backend)
    with pytest.raises(InvertedElementError) as err:
        gradient.add_gradient(u_bad, np.zeros_like(u))
    assert err.value.element == first
    with pytest.raises(InvertedElementError) as err:
        gradient.energy(u_bad)
    assert err.value.element == first


def test_indexed_elements_reject_bad_arrays(rng):
    cells, dN, vol, u, mu, lam = _shared_node_mesh(rng)
    with pytest.raises(ValueError, match="conn names nodes"):
        compiled.IndexedElements("linear", cells, dN, vol, mu, lam, int(cells.max()))
    with pytest.raises(ValueError, match="mu must be"):
        compiled.IndexedElements("linear", cells, dN, vol, mu[:-1], lam, len(u))
    with pytest.raises(ValueError, match="dN must be"):
        compiled.IndexedElements("linear", cells, np.asfortranarray(dN), vol, mu, lam, len(u))
    with pytest.raises(MeshError):
        compiled.IndexedElements("linear", cells, dN, -vol, mu, lam, len(u))
    with pytest.raises(PetsoftError):
        compiled.IndexedElements("rubber", cells, dN, vol, mu, lam, len(u))
    gradient = compiled.IndexedElements("linear", cells, dN, vol, mu, lam, len(u))
    with pytest.raises(ValueError, match="nodal arrays"):
        gradient.add_gradient(u[:-1], np.zeros_like(u))
    with pytest.raises(ValueError, match="nodal arrays"):
        gradient.add_gradient(u, np.zeros(u.shape, np.float32))
    with pytest.raises(ValueError, match="nodal arrays"):
        gradient.add_gradient(np.asfortranarray(u), np.zeros_like(u))
    with pytest.raises(ValueError, match="nodal arrays"):
        gradient.energy(u[:-1])
