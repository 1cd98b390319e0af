"""External loads: gravity (body force) and surface tractions, as consistent nodal forces.

For P1 elements a constant body force b gives each vertex of a tet V b / 4, and a traction t
(constant or linear on a face; evaluated at the face's vertices) gives each face vertex the
consistent share of the integral of t N_a.
"""

from __future__ import annotations

import numpy as np

from petsoft.fem.kernels.scatter import scatter_add_vector
from petsoft.mesh.topology import face_cells, triangle_areas_normals


def gravity_forces(dmesh, density: np.ndarray, acceleration) -> np.ndarray:
    """Local (nv, 3) nodal forces of the body force density * acceleration on local cells."""
    volume = dmesh.cell_volumes
    fe = (density * volume / 4.0)[:, None, None] * np.asarray(acceleration, float)[None, None, :]
    out = np.zeros(3 * dmesh.nvertices)
    scatter_add_vector(dmesh.cells, np.broadcast_to(fe, (len(volume), 4, 3)), out)
    return out.reshape(-1, 3)


def traction_forces(dmesh, faces: np.ndarray, traction_at_vertices: np.ndarray) -> np.ndarray:
    """Local (nv, 3) nodal forces of a traction on faces (file numbering).

    Parameters
    ----------
    faces : ndarray (F, 3)
        Faces in file vertex numbering (all ranks pass the same faces).
    traction_at_vertices : ndarray (F, 3, 3)
        Traction vector (Pa) at each face vertex; linear interpolation on the face is integrated
        exactly: f_a = A/12 (2 t_a + t_b + t_c).
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
    area, _ = triangle_areas_normals(dmesh.mesh.points, faces)
    fe = area[:, None, None] / 12.0 * (t + t.sum(axis=1, keepdims=True))
    scatter_add_vector(dmesh.file_to_local[faces], fe, out.reshape(-1))
    return out


def consistent_mass_matrices(dmesh, density: np.ndarray) -> np.ndarray:
    """(ne, 12, 12) consistent P1 mass matrices rho V / 20 (1 + delta_ab) I3 of local cells."""
    volume = dmesh.cell_volumes
    scalar = (np.ones((4, 4)) + np.eye(4)) / 20.0
    block = np.kron(scalar, np.eye(3))
    return (density * volume)[:, None, None] * block[None]


def lumped_masses(dmesh, density: np.ndarray) -> np.ndarray:
    """Local (nv,) lumped (row-sum) vertex masses rho V / 4 of local cells (ghosts partial)."""
    volume = dmesh.cell_volumes
    out = np.zeros(3 * dmesh.nvertices)
    fe = np.repeat((density * volume / 4.0)[:, None], 12, axis=1)
    scatter_add_vector(dmesh.cells, fe, out)
    return out.reshape(-1, 3)[:, 0].copy()
