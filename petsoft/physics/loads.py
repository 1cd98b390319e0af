"""External loads (gravity, surface tractions) as consistent nodal forces, and the mass matrices.

A constant body force b gives node a of a cell b int N_a dV (V/4 at each vertex of a P1 tet;
-V/20 at the corners and V/5 at the edge nodes of a straight P2 one); a traction t, linear on a
face (evaluated at its corners), gives each face node the integral of t N_a
(:func:`petsoft.fem.element.face_integrals`). The integrals themselves live in
:mod:`petsoft.fem.element`.
"""

from __future__ import annotations

import numpy as np

from petsoft.fem.element import cell_integrals, face_integrals
from petsoft.fem.kernels.scatter import scatter_add_vector
from petsoft.mesh.quadratic import face_nodes
from petsoft.mesh.topology import face_cells


def gravity_forces(dmesh, density: np.ndarray, acceleration) -> np.ndarray:
    """Local (nv, 3) nodal forces of the body force density * acceleration on local cells."""
    load = cell_integrals(dmesh).load                                   # (ne, k)
    fe = (density[:, None] * load)[:, :, None] * np.asarray(acceleration, float)[None, None, :]
    out = np.zeros(3 * dmesh.nvertices)
    scatter_add_vector(dmesh.cells, np.ascontiguousarray(fe), out)
    return out.reshape(-1, 3)


def traction_forces(dmesh, faces: np.ndarray, traction_at_vertices: np.ndarray) -> np.ndarray:
    """Local (nv, 3) nodal forces of a traction on faces (file numbering).

    Parameters
    ----------
    faces : ndarray (F, 3)
        Faces in file vertex numbering (all ranks pass the same faces).
    traction_at_vertices : ndarray (F, 3, 3)
        Traction vector (Pa) at each face vertex; its linear interpolation on the face is
        integrated exactly against the face's shape functions (P1: f_a = A/12 (2 t_a + t_b +
        t_c); P2: the 6-node triangle's).
    """
    faces = np.asarray(faces, dtype=np.int64)
    out = np.zeros((dmesh.nvertices, 3))
    if len(faces) == 0:
        return out
    # Each face is integrated on the rank that assembles a cell holding it (exactly one rank).
    cells = face_cells(dmesh.mesh.tets, faces)
    mine = np.zeros(len(faces), dtype=bool)
    held = cells >= 0
    mine[held] = dmesh.local_cells_mask(cells[held])
    # Faces inside no cell's boundary (a stray 2D group): fall back to the owner of vertex 0.
    stray = ~held
    if stray.any():
        owner0 = dmesh.file_to_local[faces[stray, 0]]
        ok = owner0 >= 0
        ok[ok] = dmesh.owned[owner0[ok]] & (dmesh.file_to_local[faces[stray][ok]] >= 0).all(1)
        mine[np.flatnonzero(stray)[ok]] = True
    faces, t = faces[mine], np.asarray(traction_at_vertices, float)[mine]
    nodes = face_nodes(dmesh.mesh, faces)
    fe = np.einsum("fac,fci->fai", face_integrals(dmesh.order, dmesh.mesh.points, nodes), t)
    scatter_add_vector(dmesh.file_to_local[nodes], np.ascontiguousarray(fe), out.reshape(-1))
    return out


def consistent_mass_matrices(dmesh, density: np.ndarray, start: int = 0,
                             stop: int | None = None) -> np.ndarray:
    """(n, 3k, 3k) consistent mass matrices of local cells [start, stop) (all by default;
    P1: rho V / 20 (1 + delta_ab) I3)."""
    scalar = cell_integrals(dmesh).mass[start:stop]                      # (n, k, k)
    n, k, _ = scalar.shape
    scalar = np.asarray(density, float)[start:stop, None, None] * scalar
    # kron(scalar, I3) per cell: dof 3a+i couples to 3b+k with scalar[a, b] delta_ik
    block = scalar[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]
    return np.ascontiguousarray(block.reshape(n, 3 * k, 3 * k))


def lumped_masses(dmesh, density: np.ndarray) -> np.ndarray:
    """Local (nv,) lumped node masses of local cells (ghosts partial): rho V / 4 per P1 vertex,
    HRZ for P2 (:mod:`petsoft.fem.element`); all positive."""
    lumped = cell_integrals(dmesh).lumped                                # (ne, k)
    out = np.zeros(3 * dmesh.nvertices)
    fe = np.repeat(density[:, None] * lumped, 3, axis=1)
    scatter_add_vector(dmesh.cells, np.ascontiguousarray(fe), out)
    return out.reshape(-1, 3)[:, 0].copy()
