"""Element energy, gradient and Hessian of P1 tetrahedra: the numpy reference implementation.

This module owns the element-level definitions, built from :mod:`petsoft.fem.kernels.materials`
by plain tensor contractions. It is the readable specification the compiled kernels are tested
against, and a fallback backend; it is vectorised over elements but makes no attempt at speed.

Conventions
-----------
Per element: ``dN`` (4, 3) shape gradients and ``volume`` from
:func:`petsoft.fem.kernels.tet.shape_gradients`, displacement ``u`` (4, 3) (or flattened (12,),
dof ``3 * a + i`` for node ``a``, component ``i``), ``F = I + sum_a u_a (x) dN_a``.
Element energy ``W = volume * psi(F)``; gradient ``g = dW/du`` (the internal force on the
element's nodes is ``-g``), ``g[3a+i] = volume * P_ij dN_a[j]``; Hessian
``H[3a+i, 3b+k] = volume * dN_a[j] dPdF_ijkl dN_b[l]``.
"""

from __future__ import annotations

import numpy as np

from petsoft.errors import InvertedElementError, MeshError
from petsoft.fem.kernels import materials


def _check_inputs(dN, volume, u, mu, lam):
    """Validate shapes, convert to float64 and broadcast mu, lam to (n,)."""
    dN = np.asarray(dN, dtype=np.float64)
    if dN.ndim != 3 or dN.shape[1:] != (4, 3):
        raise ValueError(f"dN must have shape (n, 4, 3), got {dN.shape}")
    n = dN.shape[0]
    volume = np.asarray(volume, dtype=np.float64)
    if volume.shape != (n,):
        raise ValueError(f"volume must have shape ({n},), got {volume.shape}")
    u = np.asarray(u, dtype=np.float64)
    if u.shape not in ((n, 4, 3), (n, 12)):
        raise ValueError(f"u must have shape ({n}, 4, 3) or ({n}, 12), got {u.shape}")
    u = u.reshape(n, 4, 3)
    mu = np.broadcast_to(np.asarray(mu, dtype=np.float64), (n,))
    lam = np.broadcast_to(np.asarray(lam, dtype=np.float64), (n,))
    check_volumes(volume)
    return dN, volume, u, mu, lam


def check_volumes(volume: np.ndarray) -> None:
    """Raise :class:`MeshError` naming the first element with volume <= 0.

    The volume is the quadrature weight: a negatively oriented reference element would flip the
    sign of its energy, so the mesh must be oriented before it reaches the kernels.
    """
    if volume.size == 0 or volume.min() > 0.0:     # (NaN fails this test too)
        return      # the common case, cheaply: the kernels check every call (~15 us saved)
    bad = np.flatnonzero(~(volume > 0.0))
    if bad.size:
        e = int(bad[0])
        raise MeshError(
            f"element {e} has reference volume {volume[e]:.3e} <= 0: tetrahedra must be "
            "positively oriented (swap two nodes) and non-degenerate"
        )


def deformation_gradient(dN: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``F = I + sum_a u_a (x) dN_a`` for each element, shape (n, 3, 3)."""
    n = dN.shape[0]
    return np.eye(3) + np.einsum("eai,eaj->eij", np.reshape(u, (n, 4, 3)), dN)


def element_energy(model: str, dN, volume, u, mu, lam) -> np.ndarray:
    """Elastic energy ``W_e = volume * psi(F)`` of each element.

    Parameters
    ----------
    model : str
        One of :data:`petsoft.fem.kernels.materials.MODELS`.
    dN : ndarray, shape (n, 4, 3)
        Shape-function gradients (reference configuration).
    volume : ndarray, shape (n,)
        Reference volumes (> 0).
    u : ndarray, shape (n, 4, 3) or (n, 12)
        Nodal displacements of each element.
    mu, lam : float or ndarray, shape (n,)
        Lamé parameters.

    Returns
    -------
    ndarray, shape (n,)

    Raises
    ------
    InvertedElementError
        neo-Hookean with det F <= 0 (first such element).
    MeshError
        Some volume <= 0.
    """
    dN, volume, u, mu, lam = _check_inputs(dN, volume, u, mu, lam)
    return volume * materials.energy_density(model, deformation_gradient(dN, u), mu, lam)


def element_gradient_hessian(
    model: str,
    dN,
    volume,
    u,
    mu,
    lam,
    project_spd: bool = False,
    hessian: bool = True,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Gradient and Hessian of the element energy with respect to the element displacements.

    Parameters
    ----------
    model, dN, volume, u, mu, lam
        As in :func:`element_energy`.
    project_spd : bool
        Build H from the positive semi-definite projection of dP/dF
        (:func:`petsoft.fem.kernels.materials.project_spd`), so that H is PSD. The gradient is
        unaffected.
    hessian : bool
        If False, only the gradient is computed and H is None.

    Returns
    -------
    g : ndarray, shape (n, 12)
        ``dW_e/du``, dof order ``3 * a + i``.
    H : ndarray, shape (n, 12, 12), or None
        ``d^2 W_e/du^2`` (symmetric).

    Raises
    ------
    InvertedElementError, MeshError
        As :func:`element_energy`.
    """
    dN, volume, u, mu, lam = _check_inputs(dN, volume, u, mu, lam)
    n = dN.shape[0]
    F = deformation_gradient(dN, u)
    _, P, dPdF = materials._response(model, F, mu, lam, 2 if hessian else 1)
    g = (volume[:, None, None] * np.einsum("eij,eaj->eai", P, dN)).reshape(n, 12)
    if not hessian:
        return g, None
    if project_spd:
        dPdF = materials.project_spd(dPdF)
    T = np.einsum("eijkl,ebl->eijbk", dPdF, dN)
    H = np.einsum("eaj,eijbk->eaibk", dN, T).reshape(n, 12, 12)
    H = volume[:, None, None] * 0.5 * (H + np.swapaxes(H, 1, 2))
    return g, H


def quadrature(model: str, dN, weight, u, mu, lam, project_spd: bool = False,
               hessian: bool = True):
    """Energy, gradient and Hessian of elements integrated by quadrature (10-node tetrahedra).

    Parameters
    ----------
    model : str
        One of :data:`petsoft.fem.kernels.materials.MODELS`.
    dN : ndarray, shape (n, nq, k, 3)
        Shape-function gradients of the k nodes at the nq points of each element.
    weight : ndarray, shape (n, nq)
        Quadrature weights times |det J| at the points.
    u : ndarray, shape (n, k, 3) or (n, 3k)
        Nodal displacements.
    mu, lam : float or ndarray, shape (n,)
        Lamé parameters per element.
    project_spd, hessian : bool
        As :func:`element_gradient_hessian`.

    Returns
    -------
    W : ndarray (n,)
        ``sum_q weight_q psi(F_q)``, ``F_q = I + sum_a u_a (x) dN_qa``.
    g : ndarray (n, 3k)
    H : ndarray (n, 3k, 3k) or None
    """
    dN = np.asarray(dN, dtype=np.float64)
    n, nq, k, _ = dN.shape
    u = np.asarray(u, dtype=np.float64).reshape(n, k, 3)
    weight = np.asarray(weight, dtype=np.float64).reshape(n, nq)
    mu = np.repeat(np.broadcast_to(np.asarray(mu, float), (n,)), nq)
    lam = np.repeat(np.broadcast_to(np.asarray(lam, float), (n,)), nq)
    F = np.eye(3) + np.einsum("eai,eqaj->eqij", u, dN).reshape(n * nq, 3, 3)
    try:
        psi, P, dPdF = materials._response(model, F, mu, lam, 2 if hessian else 1)
    except InvertedElementError as err:   # numbered by point: name the element
        raise InvertedElementError(err.element // nq, err.jacobian) from None
    w = weight.reshape(-1)
    W = (w * psi).reshape(n, nq).sum(axis=1)
    P = (w[:, None, None] * P).reshape(n, nq, 3, 3)
    g = np.einsum("eqij,eqaj->eai", P, dN).reshape(n, 3 * k)
    if not hessian:
        return W, g, None
    if project_spd:
        dPdF = materials.project_spd(dPdF)
    A = (w[:, None, None, None, None] * dPdF.reshape(n * nq, 3, 3, 3, 3)).reshape(
        n, nq, 3, 3, 3, 3)
    H = np.einsum("eqaj,eqijkl,eqbl->eaibk", dN, A, dN).reshape(n, 3 * k, 3 * k)
    return W, g, 0.5 * (H + np.swapaxes(H, 1, 2))
