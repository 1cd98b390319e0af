"""Quadratic (10-node, P2) tetrahedral meshes: raising a linear mesh's order and lowering it back.

A mesh of order 2 is the linear mesh with one node added on every edge. This module owns that
construction and the lookups that follow from it:

* :func:`raise_order` numbers the edges of a validated linear mesh and appends their nodes after
  the corners (the corners keep their numbers, so a node id of the linear mesh names the same
  material point); the nodes sit at the edge midpoints (straight edges) unless a file gave them
  elsewhere (curved edges of a gmsh second-order mesh);
* :func:`corner_mesh` is the inverse: the linear mesh of the corners (what refinement and the
  P1 view of outputs work on);
* :func:`face_nodes` gives the 6 nodes of triangles (tractions, Dirichlet faces, surface nodes);
* :func:`shape_values` interpolates within an element from barycentric coordinates (markers,
  probes, and the element module's quadrature).

Edge order within a tetrahedron is VTK's and gmsh's (as meshio reads both): (0,1), (1,2), (0,2),
(0,3), (1,3), (2,3); triangle6 order is the corners then edges (0,1), (1,2), (2,0).
"""

from __future__ import annotations

import numpy as np

from petsoft.errors import MeshError
from petsoft.mesh.serial import Mesh

__all__ = ["TET10_EDGES", "TRI6_EDGES", "corner_mesh", "edge_table", "face_nodes", "raise_order",
           "shape_values", "with_order"]

#: The corners joined by the edge of each mid-edge node 4..9 of a 10-node tetrahedron.
TET10_EDGES = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])
#: The corners joined by the edge of each mid-edge node 3..5 of a 6-node triangle.
TRI6_EDGES = np.array([[0, 1], [1, 2], [2, 0]])


class EdgeTable:
    """The distinct edges of a linear tetrahedral mesh, sorted by their (min, max) corner pair.

    Parameters
    ----------
    tets : ndarray (E, 4)
        Corner connectivity.
    num_corners : int
        Number of corner nodes (edge keys are ``a * num_corners + b``).
    edges : ndarray (6, 2), optional
        The order of a tetrahedron's edges in :attr:`of_tets` (default :data:`TET10_EDGES`).
    """

    def __init__(self, tets: np.ndarray, num_corners: int, edges: np.ndarray = TET10_EDGES):
        self.n = int(num_corners)
        pairs = np.sort(np.asarray(tets, np.int64)[:, edges].reshape(-1, 2), axis=1)
        self.keys, inverse = np.unique(pairs[:, 0] * self.n + pairs[:, 1], return_inverse=True)
        #: (E, 6) index of each tetrahedron's edges among the distinct edges
        self.of_tets = inverse.reshape(-1, 6)

    @property
    def ends(self) -> tuple[np.ndarray, np.ndarray]:
        """The two corners of every distinct edge."""
        return self.keys // self.n, self.keys % self.n

    def find(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Index of the edges (u, v) among the distinct edges; -1 where there is no such edge."""
        u, v = np.asarray(u, np.int64), np.asarray(v, np.int64)
        k = np.minimum(u, v) * self.n + np.maximum(u, v)
        pos = np.minimum(np.searchsorted(self.keys, k), max(len(self.keys) - 1, 0))
        return np.where(self.keys[pos] == k, pos, -1)


def edge_table(mesh: Mesh) -> EdgeTable:
    """The edge table of a mesh's corner connectivity, built once per mesh (time-dependent
    tractions ask for their faces' nodes every step)."""
    table = mesh.__dict__.get("_edge_table")
    if table is None:
        table = mesh.__dict__["_edge_table"] = EdgeTable(mesh.tets, mesh.num_corners)
    return table


def raise_order(mesh: Mesh, edge_points: np.ndarray | None = None) -> Mesh:
    """The 10-node version of a validated linear mesh.

    Parameters
    ----------
    mesh : Mesh
        A validated mesh of order 1 (a mesh of order 2 is returned unchanged).
    edge_points : ndarray (E, 6, 3), optional
        Where each tetrahedron's mid-edge nodes are (a curved mesh from a file); the default is
        the edge midpoints. Tetrahedra sharing an edge must agree on its node.

    Returns
    -------
    Mesh
        Same corners (same numbers), cell tags, regions and facet groups; ``points`` extended
        by one node per distinct edge (in the order of the sorted edges); ``edge_nodes`` set.

    Raises
    ------
    MeshError
        If tetrahedra sharing an edge put its node in different places, or a mid-edge node lies
        so far from its edge that the element would be inverted.
    """
    if mesh.order == 2:
        return mesh
    n = mesh.num_points
    edges = EdgeTable(mesh.tets, n)
    a, b = edges.ends
    if edge_points is None:
        new_points = 0.5 * (mesh.points[a] + mesh.points[b])
    else:
        edge_points = np.asarray(edge_points, float).reshape(len(mesh.tets), 6, 3)
        new_points = np.empty((len(edges.keys), 3))
        flat = edges.of_tets.ravel()
        new_points[flat] = edge_points.reshape(-1, 3)
        spread = np.abs(new_points[flat] - edge_points.reshape(-1, 3)).max(axis=1)
        length = np.linalg.norm(mesh.points[a] - mesh.points[b], axis=1)
        bad = np.flatnonzero(spread > 1e-9 * length[flat])
        if len(bad):
            e, k = divmod(int(bad[0]), 6)
            raise MeshError(f"{mesh.source}: tetrahedron {e} (0-based) places the node of its "
                            f"edge {TET10_EDGES[k].tolist()} elsewhere than a neighbour sharing "
                            "that edge: the quadratic mesh is not conforming")
        # a mid-edge node must stay in the middle half of its edge for the element map to be
        # invertible near the edge (the classical quarter-point limit)
        mid = 0.5 * (mesh.points[a] + mesh.points[b])
        offset = np.linalg.norm(new_points - mid, axis=1)
        far = np.flatnonzero(offset >= 0.25 * length)
        if len(far):
            i = int(far[0])
            raise MeshError(f"{mesh.source}: the mid-edge node of edge ({int(a[i])}, {int(b[i])}) "
                            f"(0-based corner nodes) is {offset[i]:.3e} m from the edge's "
                            f"midpoint, for an edge {length[i]:.3e} m long; it must be within a "
                            "quarter of the edge length or the element is inverted")
    return Mesh(points=np.concatenate([mesh.points, new_points]), tets=mesh.tets,
                cell_tags=mesh.cell_tags, regions=dict(mesh.regions),
                facet_groups=dict(mesh.facet_groups), source=mesh.source,
                edge_nodes=n + edges.of_tets)


def corner_mesh(mesh: Mesh) -> Mesh:
    """The linear mesh of a mesh's corners (the mesh itself when it is linear)."""
    if mesh.order == 1:
        return mesh
    nc = mesh.num_corners
    return Mesh(points=mesh.points[:nc], tets=mesh.tets, cell_tags=mesh.cell_tags,
                regions=dict(mesh.regions), facet_groups=dict(mesh.facet_groups),
                source=mesh.source)


def with_order(mesh: Mesh, order: int) -> Mesh:
    """``mesh`` with elements of ``order`` (1 or 2): raised, lowered or unchanged."""
    if order not in (1, 2):
        raise MeshError(f"{mesh.source}: element order must be 1 (4-node) or 2 (10-node "
                        f"tetrahedra), got {order!r}")
    return raise_order(mesh) if order == 2 else corner_mesh(mesh)


def shape_values(order: int, bary: np.ndarray) -> np.ndarray:
    """Shape functions (m, k) of a tetrahedron (bary (m, 4)) or triangle (bary (m, 3)).

    Order 1: the barycentric coordinates. Order 2: ``L_i (2 L_i - 1)`` at the corners and
    ``4 L_i L_j`` at the edge nodes (edge order of :mod:`petsoft.mesh.quadratic`).
    """
    L = np.asarray(bary, dtype=float)
    if order == 1:
        return L.copy()
    edges = TET10_EDGES if L.shape[-1] == 4 else TRI6_EDGES
    return np.concatenate([L * (2 * L - 1), 4 * L[..., edges[:, 0]] * L[..., edges[:, 1]]],
                          axis=-1)


def face_nodes(mesh: Mesh, faces: np.ndarray) -> np.ndarray:
    """The nodes of triangles of the mesh: ``(F, 3)`` corners, or ``(F, 6)`` for order 2.

    Raises
    ------
    MeshError
        If an edge of a triangle is not an edge of the mesh (a surface not matching the volume).
    """
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    if mesh.order == 1:
        return faces
    edges = edge_table(mesh)
    found = edges.find(faces[:, TRI6_EDGES[:, 0]], faces[:, TRI6_EDGES[:, 1]])   # (F, 3)
    if (found < 0).any():
        f, k = np.argwhere(found < 0)[0]
        raise MeshError(f"{mesh.source}: the edge {faces[f, TRI6_EDGES[k]].tolist()} of the "
                        "triangle with corners "
                        f"{faces[f].tolist()} is not an edge of any tetrahedron")
    # the mesh's edge nodes are numbered num_corners + edge index (raise_order)
    return np.concatenate([faces, mesh.num_corners + found], axis=1)
