"""Hyperelastic constitutive laws: the numpy reference implementation.

This module owns the definition of every material model petsoft knows: the strain-energy
density psi(F), the first Piola-Kirchhoff stress P = dpsi/dF and the tangent dP/dF, plus the
projection of a tangent onto the positive semi-definite cone. The compiled kernels
(``csrc/elastic.c``) implement the same formulas and are tested against these functions, so
this file is the specification: change a formula here and there together.

Conventions: F has shape (n, 3, 3); ``P[e, i, j] = dpsi/dF_ij``;
``dPdF[e, i, j, k, l] = dP_ij / dF_kl``, which is symmetric under (ij) <-> (kl) because it is a
second derivative.
"""

from __future__ import annotations

import numpy as np

from petsoft.errors import InvertedElementError, PetsoftError

#: The material models, in the order of their integer codes in the C kernels.
MODELS = ("linear", "stvk", "corotated", "neohookean")

#: Lower bound on sigma_p + sigma_q in the derivative of the rotation of the polar
#: decomposition (1 / (sigma_p + sigma_q) blows up when an element is flattened through a plane).
#: It only matters for (nearly) inverted elements; the C kernels use the same value.
SIGMA_SUM_MIN = 1e-12

_I3 = np.eye(3)
#: delta_ik delta_jl: dF/dF.
_II = np.einsum("ik,jl->ijkl", _I3, _I3)
#: delta_il delta_jk: d(F^T)/dF.
_IT = np.einsum("il,jk->ijkl", _I3, _I3)
#: delta_ij delta_kl.
_IxI = np.einsum("ij,kl->ijkl", _I3, _I3)
#: The three index pairs (p < q) of the rotation modes of the polar decomposition.
_PAIRS = ((0, 1), (0, 2), (1, 2))


def check_model(model: str) -> int:
    """Return the integer code of a material model name (its index in :data:`MODELS`).

    Raises
    ------
    PetsoftError
        If ``model`` is not one of :data:`MODELS`.
    """
    try:
        return MODELS.index(model)
    except ValueError:
        raise PetsoftError(
            f"unknown material model {model!r}; valid models are {', '.join(MODELS)}"
        ) from None


def lame_parameters(E, nu) -> tuple[np.ndarray, np.ndarray]:
    """Lamé parameters from Young's modulus and Poisson's ratio.

    Parameters
    ----------
    E : float or array_like
        Young's modulus (> 0).
    nu : float or array_like
        Poisson's ratio, -1 < nu < 0.5 (broadcast against ``E``).

    Returns
    -------
    mu, lam : ndarray
        Shear modulus ``E / (2 (1 + nu))`` and ``E nu / ((1 + nu)(1 - 2 nu))``.

    Raises
    ------
    PetsoftError
        If a value is out of range (nu = 0.5 would make lam infinite).
    """
    E, nu = np.broadcast_arrays(np.asarray(E, dtype=np.float64), np.asarray(nu, dtype=np.float64))
    if not np.all(E > 0):
        raise PetsoftError(f"Young's modulus must be > 0, got {E[~(E > 0)].ravel()[0]}")
    if not np.all((nu > -1.0) & (nu < 0.5)):
        bad = nu[~((nu > -1.0) & (nu < 0.5))].ravel()[0]
        raise PetsoftError(f"Poisson's ratio must satisfy -1 < nu < 0.5, got {bad}")
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


def signed_svd(F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation-variant SVD ``F = U diag(sigma) V^T`` with U, V proper rotations.

    Parameters
    ----------
    F : ndarray, shape (n, 3, 3)

    Returns
    -------
    U : ndarray, shape (n, 3, 3)
        det U = +1.
    sigma : ndarray, shape (n, 3)
        sigma_0 >= sigma_1 >= |sigma_2|; sigma_2 < 0 exactly when det F < 0.
    V : ndarray, shape (n, 3, 3)
        det V = +1.

    Notes
    -----
    LAPACK returns orthogonal U, V that may be reflections; flipping the last column of a
    reflection and the sign of the smallest singular value keeps the product unchanged and makes
    ``R = U V^T`` the closest proper rotation to F even for inverted elements (Irving et al.
    2004), which is what the corotated model needs.
    """
    U, sigma, Vt = np.linalg.svd(F)
    V = np.swapaxes(Vt, -1, -2).copy()
    for W in (U, V):
        flip = np.linalg.det(W) < 0
        W[flip, :, 2] *= -1.0
        sigma[flip, 2] *= -1.0
    return U, sigma, V


def _first_inverted(J: np.ndarray) -> None:
    """Raise :class:`InvertedElementError` for the first J <= 0, if any."""
    bad = np.flatnonzero(J <= 0.0)
    if bad.size:
        raise InvertedElementError(int(bad[0]), float(J[bad[0]]))


def _response(model: str, F: np.ndarray, mu: np.ndarray, lam: np.ndarray, order: int):
    """psi (order 0), and P (order >= 1), and dP/dF (order 2) for one model."""
    check_model(model)
    F = np.asarray(F, dtype=np.float64)
    if F.ndim != 3 or F.shape[1:] != (3, 3):
        raise ValueError(f"F must have shape (n, 3, 3), got {F.shape}")
    n = F.shape[0]
    mu = np.broadcast_to(np.asarray(mu, dtype=np.float64), (n,))
    lam = np.broadcast_to(np.asarray(lam, dtype=np.float64), (n,))
    mu2, lam2 = mu[:, None, None], lam[:, None, None]
    mu4, lam4 = mu[:, None, None, None, None], lam[:, None, None, None, None]
    P = dPdF = None

    if model == "linear":
        eps = 0.5 * (F + np.swapaxes(F, 1, 2)) - _I3
        tr = np.trace(eps, axis1=1, axis2=2)
        psi = mu * np.einsum("eij,eij->e", eps, eps) + 0.5 * lam * tr**2
        if order >= 1:
            P = 2.0 * mu2 * eps + lam2 * tr[:, None, None] * _I3
        if order >= 2:
            dPdF = np.broadcast_to(mu4 * (_II + _IT) + lam4 * _IxI, (n, 3, 3, 3, 3)).copy()

    elif model == "stvk":
        E = 0.5 * (np.einsum("eki,ekj->eij", F, F) - _I3)
        tr = np.trace(E, axis1=1, axis2=2)
        psi = mu * np.einsum("eij,eij->e", E, E) + 0.5 * lam * tr**2
        if order >= 1:
            S = 2.0 * mu2 * E + lam2 * tr[:, None, None] * _I3  # second Piola-Kirchhoff stress
            P = F @ S
        if order >= 2:
            B = F @ np.swapaxes(F, 1, 2)
            # d(F S)/dF = dF S + F dS/dF, with dE/dF = sym(F^T dF) and dtrE/dF = F.
            dPdF = (
                np.einsum("ik,elj->eijkl", _I3, S)
                + mu4 * (np.einsum("eil,ekj->eijkl", F, F) + np.einsum("eik,jl->eijkl", B, _I3))
                + lam4 * np.einsum("eij,ekl->eijkl", F, F)
            )

    elif model == "corotated":
        U, sig, V = signed_svd(F)
        trS = sig.sum(axis=1)
        # ||F - R||^2 = sum (sigma_i - 1)^2 and tr(R^T F) = sum sigma_i, accurate near F = I.
        psi = mu * np.sum((sig - 1.0) ** 2, axis=1) + 0.5 * lam * (trS - 3.0) ** 2
        if order >= 1:
            R = U @ np.swapaxes(V, 1, 2)
            P = 2.0 * mu2 * (F - R) + (lam * (trS - 3.0))[:, None, None] * R
        if order >= 2:
            # dR/dF = sum_{p<q} Q_pq (x) Q_pq / (sigma_p + sigma_q) with the twist modes
            # Q_pq = u_p v_q^T - u_q v_p^T (from R^T dR skew, R^T dF - dF^T R = W S + S W).
            dRdF = np.zeros((n, 3, 3, 3, 3))
            for p, q in _PAIRS:
                Q = np.einsum("ei,ej->eij", U[:, :, p], V[:, :, q]) - np.einsum(
                    "ei,ej->eij", U[:, :, q], V[:, :, p]
                )
                T = 1.0 / np.maximum(sig[:, p] + sig[:, q], SIGMA_SUM_MIN)
                dRdF += T[:, None, None, None, None] * np.einsum("eij,ekl->eijkl", Q, Q)
            c1 = lam * (trS - 3.0) - 2.0 * mu
            dPdF = (
                2.0 * mu4 * _II
                + c1[:, None, None, None, None] * dRdF
                + lam4 * np.einsum("eij,ekl->eijkl", R, R)
            )

    else:  # neohookean
        J = np.linalg.det(F)
        _first_inverted(J)
        logJ = np.log(J)
        psi = 0.5 * mu * (np.einsum("eij,eij->e", F, F) - 3.0) - mu * logJ + 0.5 * lam * logJ**2
        if order >= 1:
            FinvT = np.swapaxes(np.linalg.inv(F), 1, 2)
            P = mu2 * F + (lam * logJ - mu)[:, None, None] * FinvT
        if order >= 2:
            # d(F^-T)_ij/dF_kl = -F^-T_il F^-T_kj and dlnJ/dF = F^-T.
            dPdF = (
                mu4 * _II
                + (mu - lam * logJ)[:, None, None, None, None]
                * np.einsum("eil,ekj->eijkl", FinvT, FinvT)
                + lam4 * np.einsum("eij,ekl->eijkl", FinvT, FinvT)
            )
    return psi, P, dPdF


def energy_density(model: str, F: np.ndarray, mu, lam) -> np.ndarray:
    """Strain-energy density psi(F) only (cheaper than :func:`material_response`).

    Parameters and errors as :func:`material_response`.
    """
    return _response(model, F, mu, lam, 0)[0]


def material_response(
    model: str, F: np.ndarray, mu, lam
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Energy density, first Piola-Kirchhoff stress and its derivative for one material model.

    Parameters
    ----------
    model : str
        One of :data:`MODELS`:

        - ``"linear"``: eps = sym(F - I); psi = mu eps:eps + lam/2 tr(eps)^2.
        - ``"stvk"``: E = (F^T F - I)/2; psi = mu E:E + lam/2 tr(E)^2.
        - ``"corotated"``: F = R S (polar, R proper); psi = mu ||F - R||^2
          + lam/2 tr(R^T F - I)^2 (Stomakhin et al. 2012).
        - ``"neohookean"``: psi = mu/2 (tr(F^T F) - 3) - mu ln J + lam/2 (ln J)^2.
    F : ndarray, shape (n, 3, 3)
        Deformation gradients.
    mu, lam : float or ndarray, shape (n,)
        Lamé parameters per element.

    Returns
    -------
    psi : ndarray, shape (n,)
    P : ndarray, shape (n, 3, 3)
        ``P[e, i, j] = dpsi/dF_ij``.
    dPdF : ndarray, shape (n, 3, 3, 3, 3)
        ``dPdF[e, i, j, k, l] = dP_ij/dF_kl`` (the exact derivative, including that of R for
        the corotated model).

    Raises
    ------
    InvertedElementError
        neo-Hookean only: some det F <= 0; names the first such element.
    PetsoftError
        Unknown model.
    """
    return _response(model, F, mu, lam, 2)


def project_spd(dPdF: np.ndarray) -> np.ndarray:
    """Closest positive semi-definite tangent: clamp negative eigenvalues to zero.

    Parameters
    ----------
    dPdF : ndarray, shape (n, 3, 3, 3, 3) or (n, 9, 9)
        Tangents, viewed per element as a symmetric 9x9 matrix ``A[(ij), (kl)]``.

    Returns
    -------
    ndarray, same shape
        ``A - sum_{lambda_m < 0} lambda_m q_m q_m^T``: identical to the (symmetrised) input
        where it is already positive semi-definite.

    Notes
    -----
    Removing only the negative part, instead of rebuilding ``Q max(Lambda, 0) Q^T``, returns a
    definite tangent bit for bit and keeps the rounding error proportional to what was removed.
    Element Hessians built from a PSD tangent are PSD (congruence with the shape gradients).
    """
    dPdF = np.asarray(dPdF, dtype=np.float64)
    shape = dPdF.shape
    A = dPdF.reshape(shape[0], 9, 9)
    A = 0.5 * (A + np.swapaxes(A, 1, 2))
    w, Q = np.linalg.eigh(A)
    neg = np.minimum(w, 0.0)
    return (A - np.einsum("eim,em,ejm->eij", Q, neg, Q)).reshape(shape)
