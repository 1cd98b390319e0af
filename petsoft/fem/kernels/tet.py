"""Geometry of the linear (P1) tetrahedron: shape-function gradients and signed volumes.

This module owns the reference-configuration quantities every element kernel needs. They depend
only on the mesh, so the assembly computes them once and reuses them for every Newton step.
"""

from __future__ import annotations

import numpy as np

from petsoft.errors import MeshError

#: An element whose |6 V| is below this fraction of (longest edge)^3 counts as degenerate: its
#: shape gradients would be dominated by rounding error.
DEGENERACY_TOLERANCE = 1e-12


def shape_gradients(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of the barycentric shape functions and signed volumes of tetrahedra.

    Parameters
    ----------
    X : ndarray, shape (n, 4, 3)
        Reference coordinates of the 4 nodes of each tetrahedron.

    Returns
    -------
    dN : ndarray, shape (n, 4, 3)
        ``dN[e, a]`` is the (constant) gradient of the shape function of node ``a`` of element
        ``e`` with respect to the reference coordinates. ``dN[e].sum(axis=0) == 0``.
    volume : ndarray, shape (n,)
        Signed volume, positive when nodes 1, 2, 3 seen from node 0 are ordered
        counter-clockwise, i.e. ``(X1-X0) . ((X2-X0) x (X3-X0)) > 0``.

    Raises
    ------
    MeshError
        If an element is degenerate (zero volume relative to its size), naming the first one.

    Notes
    -----
    With edge vectors e_i = X_i - X_0 (columns of D), x = X_0 + D xi and N_i = xi_i, so the
    gradients of N_1..N_3 are the rows of D^{-1}: (e2 x e3, e3 x e1, e1 x e2) / det D. This
    closed form avoids a batched LU and gives an exact zero column-sum for N_0 = 1 - sum N_i.
    """
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 3 or X.shape[1:] != (4, 3):
        raise ValueError(f"X must have shape (n, 4, 3), got {X.shape}")
    e1 = X[:, 1] - X[:, 0]
    e2 = X[:, 2] - X[:, 0]
    e3 = X[:, 3] - X[:, 0]
    c23 = np.cross(e2, e3)
    c31 = np.cross(e3, e1)
    c12 = np.cross(e1, e2)
    det = np.einsum("ei,ei->e", e1, c23)

    edges = np.stack([e1, e2, e3, e2 - e1, e3 - e1, e3 - e2], axis=1)
    longest = np.sqrt(np.einsum("eki,eki->ek", edges, edges).max(axis=1)) if len(X) else det
    bad = np.flatnonzero(~(np.abs(det) > DEGENERACY_TOLERANCE * longest**3))
    if bad.size:
        e = int(bad[0])
        raise MeshError(
            f"tetrahedron {e} is degenerate (volume {det[e] / 6:.3e}, longest edge "
            f"{longest[e]:.3e}); {bad.size} degenerate element(s) in total"
        )

    dN = np.empty_like(X)
    inv_det = 1.0 / det
    dN[:, 1] = c23 * inv_det[:, None]
    dN[:, 2] = c31 * inv_det[:, None]
    dN[:, 3] = c12 * inv_det[:, None]
    dN[:, 0] = -(dN[:, 1] + dN[:, 2] + dN[:, 3])
    return dN, det / 6.0
