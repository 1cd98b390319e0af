"""Geometry of the linear (P1) tetrahedron: shape-function gradients and signed volumes.

This module owns the reference-configuration quantities every element kernel needs. They depend
only on the mesh, so the assembly computes them once and reuses them for every Newton step.
"""

from __future__ import annotations

import ctypes
from functools import lru_cache

import numpy as np

from petsoft.carrays import addr
from petsoft.errors import MeshError
from petsoft.fem.kernels.compiled import library

#: An element whose |6 V| is below this fraction of (longest edge)^3 counts as degenerate: its
#: shape gradients would be dominated by rounding error.
DEGENERACY_TOLERANCE = 1e-12


@lru_cache(maxsize=1)
def _geometry() -> ctypes.CDLL:
    lib = library()
    lib.petsoft_tet_geometry_indexed.argtypes = [ctypes.c_int64] + [ctypes.c_void_p] * 5
    lib.petsoft_tet_geometry_indexed.restype = None
    return lib


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
    X = np.ascontiguousarray(X, dtype=np.float64)
    if X.ndim != 3 or X.shape[1:] != (4, 3):
        raise ValueError(f"X must have shape (n, 4, 3), got {X.shape}")
    # the nodes of element e are rows 4e..4e+3 of X seen as points
    return mesh_shape_gradients(X.reshape(-1, 3), np.arange(4 * len(X)).reshape(-1, 4))


def mesh_shape_gradients(points: np.ndarray,
                         cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`shape_gradients` of the tetrahedra ``cells`` (n, 4) of ``points`` (nv, 3), without
    making their (n, 4, 3) coordinates (at 1M tets, 96 MB whose page faults cost more than the
    geometry)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    cells = np.ascontiguousarray(cells, dtype=np.int64)
    if cells.ndim != 2 or cells.shape[1] != 4 or points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (nv, 3) and cells (n, 4), got {points.shape} and "
                         f"{cells.shape}")
    n = len(cells)
    if n and (cells.min() < 0 or cells.max() >= len(points)):
        raise ValueError(f"cells index vertices outside 0..{len(points) - 1}")
    dN = np.empty((n, 4, 3))
    det = np.empty(n)
    longest2 = np.empty(n)
    if n:
        # one compiled pass (csrc/geometry.c)
        _geometry().petsoft_tet_geometry_indexed(n, addr(points), addr(cells), addr(dN),
                                                 addr(det), addr(longest2))
    return _checked(dN, det, longest2)


def _checked(dN: np.ndarray, det: np.ndarray, longest2: np.ndarray):
    """(dN, volume), or MeshError naming the first degenerate tetrahedron."""
    longest = np.sqrt(longest2)
    bad = np.flatnonzero(~(np.abs(det) > DEGENERACY_TOLERANCE * longest**3))
    if bad.size:
        e = int(bad[0])
        raise MeshError(
            f"tetrahedron {e} is degenerate (volume {det[e] / 6:.3e}, longest edge "
            f"{longest[e]:.3e}); {bad.size} degenerate element(s) in total"
        )

    return dN, det / 6.0
