"""Constitutive laws (numpy reference and the C implementation), pointwise in F.

Serial computations only: under ``mpiexec -n 2`` every rank simply runs the same checks.
"""

from __future__ import annotations

import numpy as np
import pytest

from petsoft.errors import InvertedElementError, PetsoftError
from petsoft.fem.kernels import compiled, materials
from petsoft.fem.kernels.materials import MODELS, lame_parameters, material_response, project_spd

NONLINEAR = ("stvk", "corotated", "neohookean")
# The C constitutive law (exposed for testing) next to the numpy reference.
RESPONSES = {"numpy": material_response, "c": compiled.material_response}
PROJECTIONS = {"numpy": project_spd, "c": compiled.project_spd}


def random_F(rng, n, scale=0.3, min_det=0.2):
    """Moderately large random deformation gradients with det F > min_det."""
    F = np.eye(3) + scale * rng.standard_normal((4 * n, 3, 3))
    return F[np.linalg.det(F) > min_det][:n]


def random_rotations(rng, n):
    Q, R = np.linalg.qr(rng.standard_normal((n, 3, 3)))
    Q = Q * np.sign(np.diagonal(R, axis1=1, axis2=2))[:, None, :]
    Q[np.linalg.det(Q) < 0, :, 0] *= -1.0
    return Q


@pytest.fixture
def rng():
    return np.random.default_rng(20240611)


@pytest.fixture
def params(rng):
    def make(n):
        return rng.uniform(0.5, 2.0, n), rng.uniform(0.5, 5.0, n)

    return make


def taylor_rates(remainder, hs):
    """Observed convergence orders log2(r(h) / r(h/2)) per entry, shape (len(hs) - 1, ...)."""
    r = np.array([remainder(h) for h in hs])
    return np.log2(r[:-1] / r[1:]), r


HS = 1e-3 * 0.5 ** np.arange(4)


# --------------------------------------------------------------------------------------------
# Parameters and model names


def test_lame_parameters_values_and_arrays():
    mu, lam = lame_parameters(1e5, 0.25)
    assert mu == pytest.approx(4e4) and lam == pytest.approx(4e4)
    mu, lam = lame_parameters([1.0, 2.0], 0.0)
    np.testing.assert_allclose(mu, [0.5, 1.0])
    np.testing.assert_allclose(lam, [0.0, 0.0])


@pytest.mark.parametrize("E, nu", [(1.0, 0.5), (1.0, -1.0), (0.0, 0.3), ([1.0, -1.0], 0.3)])
def test_lame_parameters_reject_out_of_range(E, nu):
    with pytest.raises(PetsoftError):
        lame_parameters(E, nu)


@pytest.mark.parametrize("backend", RESPONSES)
def test_unknown_model_is_a_user_error(backend):
    with pytest.raises(PetsoftError, match="valid models are linear, stvk"):
        RESPONSES[backend]("mooney", np.eye(3)[None], 1.0, 1.0)


# --------------------------------------------------------------------------------------------
# Reference state, frame indifference, linearisation


@pytest.mark.parametrize("backend", RESPONSES)
@pytest.mark.parametrize("model", MODELS)
def test_zero_energy_and_stress_at_identity(model, backend, params):
    mu, lam = params(3)
    psi, P, _ = RESPONSES[backend](model, np.broadcast_to(np.eye(3), (3, 3, 3)), mu, lam)
    np.testing.assert_array_equal(psi, 0.0)
    np.testing.assert_array_equal(P, 0.0)


@pytest.mark.parametrize("backend", RESPONSES)
@pytest.mark.parametrize("model", NONLINEAR)
def test_rotation_invariance(model, backend, rng, params):
    F = random_F(rng, 20)
    Q = random_rotations(rng, len(F))
    mu, lam = params(len(F))
    psi, P, _ = RESPONSES[backend](model, F, mu, lam)
    psi_q, P_q, _ = RESPONSES[backend](model, Q @ F, mu, lam)
    np.testing.assert_allclose(psi_q, psi, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(P_q, Q @ P, rtol=1e-11, atol=1e-12)  # P(QF) = Q P(F)


def test_linear_model_is_not_rotation_invariant(rng):
    """Sanity check of the test above: small-strain elasticity sees rotations as strain."""
    Q = random_rotations(rng, 5)
    psi, _, _ = material_response("linear", Q, 1.0, 1.0)
    assert np.all(psi > 1e-3)


@pytest.mark.parametrize("backend", RESPONSES)
@pytest.mark.parametrize("model", MODELS)
def test_linearisation_at_identity_is_linear_elasticity(model, backend, params):
    mu, lam = params(4)
    _, _, A = RESPONSES[backend](model, np.broadcast_to(np.eye(3), (4, 3, 3)), mu, lam)
    d = np.eye(3)
    C = mu[:, None, None, None, None] * (
        np.einsum("ik,jl->ijkl", d, d) + np.einsum("il,jk->ijkl", d, d)
    ) + lam[:, None, None, None, None] * np.einsum("ij,kl->ijkl", d, d)
    np.testing.assert_allclose(A, C, rtol=1e-13, atol=1e-13)


# --------------------------------------------------------------------------------------------
# Derivatives: Taylor tests


@pytest.mark.parametrize("backend", RESPONSES)
@pytest.mark.parametrize("model", MODELS)
def test_taylor_stress_is_derivative_of_energy(model, backend, rng, params):
    response = RESPONSES[backend]
    F = random_F(rng, 10)
    mu, lam = params(len(F))
    dF = rng.standard_normal(F.shape)
    psi, P, _ = response(model, F, mu, lam)
    slope = np.einsum("eij,eij->e", P, dF)

    def remainder(h):
        return np.abs(response(model, F + h * dF, mu, lam)[0] - psi - h * slope)

    rates, _ = taylor_rates(remainder, HS)
    assert rates.min() > 1.8 and rates.max() < 2.2, rates


@pytest.mark.parametrize("backend", RESPONSES)
@pytest.mark.parametrize("model", MODELS)
def test_taylor_tangent_is_derivative_of_stress(model, backend, rng, params):
    response = RESPONSES[backend]
    F = random_F(rng, 10)
    mu, lam = params(len(F))
    dF = rng.standard_normal(F.shape)
    _, P, A = response(model, F, mu, lam)
    slope = np.einsum("eijkl,ekl->eij", A, dF)

    def remainder(h):
        R = response(model, F + h * dF, mu, lam)[1] - P - h * slope
        return np.linalg.norm(R.reshape(len(F), 9), axis=1)

    if model == "linear":
        # P is linear in F: the first-order expansion is exact, the remainder is rounding.
        for h in HS:
            assert np.all(remainder(h) <= 1e-12 * h * np.linalg.norm(slope.reshape(-1, 9), axis=1))
        return
    rates, _ = taylor_rates(remainder, HS)
    assert rates.min() > 1.8 and rates.max() < 2.2, rates


@pytest.mark.parametrize("model", MODELS)
def test_tangent_has_major_symmetry(model, rng, params):
    F = random_F(rng, 10)
    _, _, A = material_response(model, F, *params(len(F)))
    A = A.reshape(-1, 9, 9)
    np.testing.assert_allclose(A, np.swapaxes(A, 1, 2), rtol=1e-13, atol=1e-13)


# --------------------------------------------------------------------------------------------
# C constitutive law against the reference


@pytest.mark.parametrize("model", MODELS)
def test_c_material_response_matches_numpy(model, rng, params):
    F = random_F(rng, 50)
    mu, lam = params(len(F))
    for ref, c in zip(
        material_response(model, F, mu, lam),
        compiled.material_response(model, F, mu, lam),
        strict=True,
    ):
        scale = np.abs(ref).max()
        np.testing.assert_allclose(c, ref, rtol=1e-12, atol=1e-12 * scale)


def test_corotated_handles_inverted_elements(rng, params):
    """R stays a proper rotation for det F < 0 (sign-fixed SVD); everything stays finite."""
    F = random_F(rng, 30)
    F[:, :, 0] *= -1.0  # reflect: det F < 0
    mu, lam = params(len(F))
    U, sig, V = materials.signed_svd(F)
    np.testing.assert_allclose(np.linalg.det(U), 1.0)
    np.testing.assert_allclose(np.linalg.det(V), 1.0)
    assert np.all(sig[:, 2] < 0) and np.all(sig[:, 1] >= np.abs(sig[:, 2]))
    np.testing.assert_allclose(U @ (sig[:, :, None] * np.swapaxes(V, 1, 2)), F, atol=1e-13)
    ref = material_response("corotated", F, mu, lam)
    c = compiled.material_response("corotated", F, mu, lam)
    for a, b in zip(ref, c, strict=True):
        assert np.all(np.isfinite(a)) and np.all(np.isfinite(b))
        np.testing.assert_allclose(b, a, rtol=1e-10, atol=1e-10 * np.abs(a).max())


# --------------------------------------------------------------------------------------------
# Neo-Hookean with J <= 0


@pytest.mark.parametrize("backend", RESPONSES)
@pytest.mark.parametrize("J_bad", [0.0, -0.5])
def test_neohookean_inverted_raises_with_element_index(backend, J_bad, rng):
    F = random_F(rng, 8)
    F[5] = np.diag([1.0, 1.0, J_bad])
    F[7] = np.diag([1.0, -1.0, 1.0])  # also inverted, but not the first one
    with pytest.raises(InvertedElementError) as err:
        RESPONSES[backend]("neohookean", F, 1.0, 1.0)
    assert err.value.element == 5
    assert err.value.jacobian == pytest.approx(J_bad)
    assert "element 5" in str(err.value)


@pytest.mark.parametrize("backend", RESPONSES)
def test_neohookean_near_inversion_is_finite(backend):
    F = np.diag([1.0, 1.0, 1e-300])[None]
    psi, P, A = RESPONSES[backend]("neohookean", F, 1.0, 1.0)
    assert np.isfinite(psi).all() and np.isfinite(P).all()


# --------------------------------------------------------------------------------------------
# SPD projection


def random_symmetric(rng, n):
    A = rng.standard_normal((n, 9, 9))
    return A + np.swapaxes(A, 1, 2)


@pytest.mark.parametrize("backend", PROJECTIONS)
def test_projection_is_psd_and_clamps_only_negative_part(backend, rng):
    A = random_symmetric(rng, 40)
    Ap = PROJECTIONS[backend](A)
    w, Q = np.linalg.eigh(A)
    wp = np.linalg.eigvalsh(Ap)
    assert wp.min() > -1e-12 * np.abs(w).max()
    # The projection keeps the eigenvectors and the positive eigenvalues, zeroes the others.
    expected = np.einsum("eim,em,ejm->eij", Q, np.maximum(w, 0.0), Q)
    np.testing.assert_allclose(Ap, expected, atol=1e-12 * np.abs(w).max())
    np.testing.assert_allclose(np.sort(wp, axis=1), np.sort(np.maximum(w, 0.0), axis=1), atol=1e-12)


@pytest.mark.parametrize("backend", PROJECTIONS)
def test_projection_leaves_positive_definite_tangent_unchanged(backend, rng):
    B = rng.standard_normal((10, 9, 9))
    A = B @ np.swapaxes(B, 1, 2) + 0.1 * np.eye(9)
    np.testing.assert_array_equal(PROJECTIONS[backend](A), A)
    # Neo-Hookean under moderate uniform stretch (mu = 1, lam = 2) has a definite tangent.
    _, _, T = material_response("neohookean", np.broadcast_to(1.2 * np.eye(3), (3, 3, 3)), 1.0, 2.0)
    assert np.linalg.eigvalsh(T.reshape(3, 9, 9)).min() > 0.01
    np.testing.assert_array_equal(PROJECTIONS[backend](T), T)
    assert PROJECTIONS[backend](T).shape == T.shape


@pytest.mark.parametrize("model", NONLINEAR)
def test_projection_of_tangents_c_matches_numpy(model, rng, params):
    F = random_F(rng, 60, scale=0.4)
    _, _, A = material_response(model, F, *params(len(F)))
    ref = project_spd(A)
    assert np.abs(ref - A).max() > 1e-3 * np.abs(A).max()  # some tangents were indefinite
    np.testing.assert_allclose(compiled.project_spd(A), ref, atol=1e-12 * np.abs(A).max())


def test_projection_of_psd_singular_matrix(rng):
    """Rank-deficient PSD input (the linear tangent has a zero skew eigenspace) is kept."""
    _, _, A = material_response("linear", np.broadcast_to(np.eye(3), (2, 3, 3)), 1.0, 1.0)
    for proj in PROJECTIONS.values():
        np.testing.assert_allclose(proj(A), A, atol=1e-14)
