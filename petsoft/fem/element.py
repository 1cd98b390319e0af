"""The finite elements: 4-node (P1) and 10-node (P2) tetrahedra, their shape functions, quadrature
rules and the per-cell integrals every term shares.

This module owns what depends on the element order, so that the terms, the mass and the loads
ask it instead of branching on the order themselves:

* shape functions in barycentric coordinates (:func:`shape_values`, also used to embed markers
  and probes), 6-node triangle shape functions for faces;
* quadrature rules: for the stiffness of 10-node tetrahedra the 4-point rule of degree 2
  (Keast's), exact for the linear law on straight-edged elements (the integrand is a product of
  two linear gradients); for mass and loads a collapsed Gauss-Jacobi product rule of degree 5,
  exact for the consistent P2 mass (degree 4);
* :func:`quadratic_geometry`: shape-function gradients and weights at the points, through the
  isoparametric map (so curved edges from a file are integrated too);
* :func:`cell_integrals`: per cell and unit density the consistent mass matrix, the load vector
  of a unit body force (int N_a dV) and a positive lumped mass: row sums for P1 (V/4, as always),
  HRZ for P2 (Hinton, Rock and Zienkiewicz 1976: the diagonal of the consistent mass scaled to
  the element's mass; row sums of P2 are negative at the corners).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
from scipy.special import roots_jacobi

from petsoft.errors import MeshError
from petsoft.mesh.quadratic import TET10_EDGES, shape_values
from petsoft.mesh.topology import triangle_areas_normals

__all__ = ["CellIntegrals", "cell_integrals", "face_integrals", "face_lumped_areas",
           "integrals_of", "quadratic_geometry", "shape_values", "tet_rule", "triangle_rule"]

#: Keast's 4-point rule of degree 2 in barycentric coordinates (weights sum to 1).
_A, _B = 0.5854101966249685, 0.1381966011250105
KEAST4 = (np.array([[_A, _B, _B, _B], [_B, _A, _B, _B], [_B, _B, _A, _B], [_B, _B, _B, _A]]),
          np.full(4, 0.25))


def _gauss_jacobi01(n: int, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Points and weights on [0, 1] for the weight (1 - t)^alpha, exact to degree 2n - 1."""
    x, w = roots_jacobi(n, alpha, 0.0)
    return (x + 1.0) / 2.0, w / 2.0 ** (alpha + 1.0)


@cache
def tet_rule(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """A quadrature rule on the tetrahedron exact for polynomials of ``degree``.

    Returns barycentric points (nq, 4) and weights (nq,) summing to 1 (multiply by the volume).
    Degree <= 2: Keast's 4 points; higher: the collapsed (Duffy) product of Gauss-Jacobi rules.
    """
    if degree <= 2:
        return KEAST4
    n = (degree + 2) // 2
    a, wa = _gauss_jacobi01(n, 2.0)
    b, wb = _gauss_jacobi01(n, 1.0)
    c, wc = _gauss_jacobi01(n, 0.0)
    A, B, C = np.meshgrid(a, b, c, indexing="ij")
    W = np.einsum("i,j,k->ijk", wa, wb, wc).ravel() * 6.0
    x1, x2, x3 = A.ravel(), (B * (1 - A)).ravel(), (C * (1 - A) * (1 - B)).ravel()
    return np.column_stack([1 - x1 - x2 - x3, x1, x2, x3]), W


@cache
def triangle_rule(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric points (nq, 3) and weights (nq,) summing to 1, exact to ``degree``."""
    n = (degree + 2) // 2
    a, wa = _gauss_jacobi01(n, 1.0)
    b, wb = _gauss_jacobi01(n, 0.0)
    A, B = np.meshgrid(a, b, indexing="ij")
    W = np.outer(wa, wb).ravel() * 2.0
    x1, x2 = A.ravel(), (B * (1 - A)).ravel()
    return np.column_stack([1 - x1 - x2, x1, x2]), W


def _tet10_reference_gradients(bary: np.ndarray) -> np.ndarray:
    """d N_a / d xi_m (m, 10, 3) for reference coordinates xi = (L1, L2, L3), L0 = 1 - sum."""
    L = np.asarray(bary, dtype=float)
    m = len(L)
    dL = np.zeros((m, 10, 4))                            # d N_a / d L_k
    for i in range(4):
        dL[:, i, i] = 4 * L[:, i] - 1
    for e, (i, j) in enumerate(TET10_EDGES):
        dL[:, 4 + e, i] = 4 * L[:, j]
        dL[:, 4 + e, j] = 4 * L[:, i]
    return dL[:, :, 1:] - dL[:, :, :1]


def quadratic_geometry(X: np.ndarray, bary: np.ndarray, weights: np.ndarray,
                       cell_ids: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Shape gradients and integration weights of 10-node tetrahedra at quadrature points.

    Parameters
    ----------
    X : ndarray (n, 10, 3)
        Node coordinates (corners, then edge nodes).
    bary, weights : ndarray (nq, 4), (nq,)
        A rule from :func:`tet_rule`.
    cell_ids : ndarray (n,), optional
        File numbers of the cells, for the message of an inverted element.

    Returns
    -------
    dN : ndarray (n, nq, 10, 3)
        d N_a / d X at each point.
    w : ndarray (n, nq)
        ``weights * det J / 6`` (det J > 0): the point's share of the element's volume.

    Raises
    ------
    MeshError
        If the isoparametric map is not invertible at a point (a curved element folded over).
    """
    G = _tet10_reference_gradients(bary)                         # (nq, 10, 3)
    J = np.einsum("nai,qam->nqim", X, G)                          # dX_i / d xi_m
    det = np.linalg.det(J)
    bad = np.argwhere(~(det > 0))
    if len(bad):
        e = int(bad[0, 0])
        name = int(cell_ids[e]) if cell_ids is not None else e
        raise MeshError(f"tetrahedron {name} (0-based) of order 2 has a non-positive Jacobian "
                        f"{det[tuple(bad[0])]:.3e} at a quadrature point: its edge nodes fold "
                        "the element (move them towards the edge midpoints)")
    Jinv = np.linalg.inv(J)
    dN = np.einsum("qam,nqmi->nqai", G, Jinv)
    return np.ascontiguousarray(dN), det * weights[None, :] / 6.0


@dataclass
class CellIntegrals:
    """Per local cell and unit density: consistent mass (n, k, k) (scalar; times I3 per
    component), body-force load int N_a dV (n, k) and lumped mass (n, k), all positive for
    ``lumped``."""

    mass: np.ndarray
    load: np.ndarray
    lumped: np.ndarray


def integrals_of(X: np.ndarray, order: int) -> CellIntegrals:
    """The :class:`CellIntegrals` of cells with node coordinates ``X`` (n, 4 or 10, 3)."""
    if order == 1:
        V = np.einsum("ij,ij->i", np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]),
                      X[:, 3] - X[:, 0]) / 6.0
        mass = V[:, None, None] * ((np.ones((4, 4)) + np.eye(4)) / 20.0)[None]
        load = np.repeat((V / 4.0)[:, None], 4, axis=1)
        return CellIntegrals(mass, load, load.copy())
    bary, w = tet_rule(5)
    N = shape_values(2, bary)                                      # (nq, 10)
    _, weight = quadratic_geometry(X, bary, w)
    mass = np.einsum("nq,qa,qb->nab", weight, N, N)
    load = weight @ N
    diag = np.einsum("naa->na", mass)
    lumped = diag * (weight.sum(axis=1) / diag.sum(axis=1))[:, None]
    return CellIntegrals(mass, load, lumped)


def cell_integrals(dmesh) -> CellIntegrals:
    """The :class:`CellIntegrals` of a distributed mesh's local cells (computed once)."""
    cached = getattr(dmesh, "_cell_integrals", None)
    if cached is None:
        cached = dmesh._cell_integrals = integrals_of(dmesh.points[dmesh.cells], dmesh.order)
    return cached


def face_integrals(order: int, points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, kf, 3) integrals int N_a L_c dA of each face node a against the corner hat L_c.

    A traction interpolated linearly from its corner values t_c gives node a the force
    ``sum_c result[f, a, c] t_c``. Faces are ``(F, 3)`` corners or ``(F, 6)`` for order 2; the
    area is that of the straight triangle of the corners.
    """
    area, _ = triangle_areas_normals(points, np.asarray(faces, np.int64)[:, :3])
    bary, w = triangle_rule(3)
    N = shape_values(order, bary)                                  # (nq, kf)
    unit = np.einsum("q,qa,qc->ac", w, N, bary)                    # (kf, 3), for unit area
    return area[:, None, None] * unit[None]


def face_lumped_areas(order: int, points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, kf) positive area of each face node: A/3 at the corners of a 3-node triangle; HRZ
    for a 6-node one (A/19 at the corners, 16A/57 at the edge nodes: the diagonal of the face's
    mass matrix scaled to its area; plain row sums would be 0 at the corners)."""
    area, _ = triangle_areas_normals(points, np.asarray(faces, np.int64)[:, :3])
    if order == 1:
        return np.repeat((area / 3.0)[:, None], 3, axis=1)
    share = np.array([3.0, 3.0, 3.0, 16.0, 16.0, 16.0]) / 57.0
    return area[:, None] * share[None]
