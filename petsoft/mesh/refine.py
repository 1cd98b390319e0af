"""Uniform refinement of tetrahedral meshes: every tetrahedron split into 8 (Bey 1995).

This module owns the 1 -> 8 subdivision that halves a mesh's size, used wherever a finer copy of
any mesh (a file as well as a box) is needed: ``petsoft synth --refine K`` simulates its truth on
it, ``[mesh] refine = L`` applies it ``L`` times after reading, and the numerics checks of
``petsoft diagnose`` and ``petsoft calibrate --check-mesh`` compare the model on it with the
model on the user's mesh.

What is carried over, and why it can be relied on:

* the nodes of the original mesh keep their numbers (new nodes, the edge midpoints, come after
  them), so a node id of the original mesh (a synth marker, a spring's end) names the same
  material point of the refined mesh;
* a child lies inside its parent (its vertices are the parent's corners and edge midpoints), so
  it inherits the parent's cell tag (region / physical group), and the refined mesh covers
  exactly the original domain: a marker embedded by position stays at the same material point;
* a facet-group triangle is split 1 -> 4 through the same edge midpoints, keeping its
  orientation, so the children are faces of the refined tetrahedra and the group's area is kept;
  for the exterior boundary this makes the boundary of the refined mesh equal to the refined
  boundary;
* children are positively oriented (vertices swapped where the subdivision's ordering is
  negative).
"""

from __future__ import annotations

import numpy as np

from petsoft.errors import MeshError
from petsoft.mesh.quadratic import EdgeTable, corner_mesh, raise_order
from petsoft.mesh.serial import Mesh, validate

__all__ = ["CHILDREN_PER_TET", "refine_mesh", "refine_triangles", "refined_cell_count"]

#: A 1 -> 8 subdivision makes this many children of every tetrahedron.
CHILDREN_PER_TET = 8

# Local numbering of the 10 points of a tetrahedron: 0..3 corners, 4 m01, 5 m02, 6 m03, 7 m12,
# 8 m13, 9 m23. The 4 corner children, then the inner octahedron split into 4 around one of its
# three diagonals (m01-m23, m02-m13, m03-m12): the shortest, whose children are the best shaped
# (a fixed diagonal let the minimum shape quality of a sheared bar fall 4x in two levels; the
# shortest kept it within 20 %). The diagonal is inside the parent, so the choice never breaks
# conformity.
_CORNERS = np.array([[0, 4, 5, 6], [4, 1, 7, 8], [5, 7, 2, 9], [6, 8, 9, 3]])
_DIAGONALS = np.array([[4, 9], [5, 8], [6, 7]])


def _octahedron(a: int, b: int, c: int, d: int, e: int, f: int) -> list[list[int]]:
    """The 4 tetrahedra around the diagonal (a, b) of the octahedron whose other opposite
    pairs are (c, d) and (e, f): its equator is the cycle c-e-d-f."""
    return [[a, b, c, e], [a, b, e, d], [a, b, d, f], [a, b, f, c]]


_CHILDREN = np.array([np.concatenate([_CORNERS, _octahedron(*_DIAGONALS[k],
                                                            *_DIAGONALS[(k + 1) % 3],
                                                            *_DIAGONALS[(k + 2) % 3])])
                      for k in range(3)])                                  # (3, 8, 4)
_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


def refined_cell_count(num_cells: int, levels: int = 1) -> int:
    """Tetrahedra after ``levels`` subdivisions of a mesh of ``num_cells``."""
    return int(num_cells) * CHILDREN_PER_TET ** int(levels)


class _Midpoints(EdgeTable):
    """The edges of a tetrahedral mesh, numbered, and the node number of each edge's midpoint
    (the original nodes first, then one new node per edge in the order of the sorted edges)."""

    def __init__(self, tets: np.ndarray, num_points: int):
        super().__init__(tets, num_points, edges=_EDGES)
        #: (E, 6) midpoint node of each tetrahedron's edges, in the order of _EDGES
        self.of_tets = self.n + self.of_tets

    def of(self, u: np.ndarray, v: np.ndarray, source: str) -> np.ndarray:
        """Midpoint nodes of the edges (u, v); raises if one is no edge of the mesh."""
        found = self.find(u, v)
        missing = np.flatnonzero(found < 0)
        if len(missing):
            i = missing[0]
            raise MeshError(f"{source}: the triangle edge ({int(u[i])}, {int(v[i])}) (0-based "
                            "nodes) is not an edge of any tetrahedron, so its facet group "
                            "cannot be refined with the mesh: the surface mesh does not match "
                            "the volume mesh")
        return self.n + found


def refine_triangles(tris: np.ndarray, midpoints: _Midpoints, source: str = "<mesh>"):
    """Split triangles 1 -> 4 through the mesh's edge midpoints, keeping their orientation.

    Row ``4 t + k`` of the result is child ``k`` of triangle ``t`` (the three corner triangles,
    then the middle one).
    """
    tris = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
    p, q, r = tris[:, 0], tris[:, 1], tris[:, 2]
    mpq, mqr, mrp = (midpoints.of(a, b, source) for a, b in ((p, q), (q, r), (r, p)))
    return np.stack([np.column_stack([p, mpq, mrp]), np.column_stack([mpq, q, mqr]),
                     np.column_stack([mrp, mqr, r]), np.column_stack([mpq, mqr, mrp])],
                    axis=1).reshape(-1, 3)


def refine_mesh(mesh: Mesh, levels: int = 1) -> Mesh:
    """The mesh with every tetrahedron split into 8, ``levels`` times (module docstring).

    Parameters
    ----------
    mesh : Mesh
        A validated tetrahedral mesh.
    levels : int
        Number of subdivisions, >= 0 (each halves the mesh size; 0 returns ``mesh``).

    Returns
    -------
    Mesh
        ``8**levels`` times the tetrahedra; row ``8 e + k`` is child ``k`` of tetrahedron
        ``e``; the original nodes first with their numbers; cell tags, regions and facet groups
        carried over; source ``"<source> refined 1->8"`` (once per level).

    Raises
    ------
    MeshError
        If ``levels`` is not an integer >= 0, or a facet-group triangle's edge is no edge of the
        mesh.
    """
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 0:
        raise MeshError(f"{mesh.source}: refinement levels must be an integer >= 0 (number of "
                        f"1->8 subdivisions), got {levels!r}")
    if mesh.order == 2 and levels > 0:
        # refine the corners' mesh; the children get straight edges at their own midpoints
        return raise_order(refine_mesh(corner_mesh(mesh), levels))
    for _ in range(int(levels)):
        mesh = _refine_once(mesh)
    return mesh


def _refine_once(mesh: Mesh) -> Mesh:
    tets = np.asarray(mesh.tets, dtype=np.int64)
    mid = _Midpoints(tets, len(mesh.points))
    a, b = mid.keys // mid.n, mid.keys % mid.n
    points = np.concatenate([mesh.points, 0.5 * (mesh.points[a] + mesh.points[b])])
    local = np.concatenate([tets, mid.of_tets], axis=1)                 # (E, 10)
    P = points[local[:, _DIAGONALS]]                                     # (E, 3, 2, 3)
    diagonal = np.argmin(np.sum((P[:, :, 1] - P[:, :, 0]) ** 2, axis=2), axis=1)
    children = np.take_along_axis(local, _CHILDREN[diagonal].reshape(len(tets), -1),
                                  axis=1).reshape(-1, 4)
    X = points[children]
    vol = np.einsum("ij,ij->i", np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]), X[:, 3] - X[:, 0])
    flip = vol < 0
    children[flip] = children[flip][:, [0, 1, 3, 2]]
    groups = {name: refine_triangles(tri, mid, mesh.source)
              for name, tri in mesh.facet_groups.items()}
    return validate(Mesh(points=points, tets=children,
                         cell_tags=np.repeat(np.asarray(mesh.cell_tags), CHILDREN_PER_TET),
                         regions=dict(mesh.regions), facet_groups=groups,
                         source=f"{mesh.source} refined 1->8"))
