"""Face topology of tetrahedral meshes: faces of cells, exterior faces, and which cell holds a face.

Pure numpy on the global (serial) connectivity, shared by the mesh checks, boundary conditions and
surface loads.
"""

from __future__ import annotations

import numpy as np

# Face i of tet (v0, v1, v2, v3) is the one opposite vertex i, ordered so that its right-hand
# normal points out of a positively oriented tet.
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)


def unique_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct rows of an (M, 3) int array, the index of each row among them, and counts.

    Same result as ``np.unique(rows, axis=0, return_inverse=True, return_counts=True)``, but a
    lexicographic sort of the columns is several times faster than numpy's row-as-void sort.
    """
    order = np.lexsort(rows.T[::-1])
    srt = rows[order]
    new = np.ones(len(rows), bool)
    new[1:] = np.any(srt[1:] != srt[:-1], axis=1)
    group = np.cumsum(new) - 1
    inverse = np.empty(len(rows), np.int64)
    inverse[order] = group
    counts = np.bincount(group)
    return srt[new], inverse, counts


def face_table(tets: np.ndarray):
    """All 4E outward faces, and for each its class among the geometrically equal faces.

    Returns
    -------
    faces : (4E, 3) outward-oriented faces, row ``4*e + i`` is the face opposite vertex i of e.
    keys : (U, 3) the distinct faces with sorted vertices, in lexicographic order.
    inverse : (4E,) index into ``keys`` of each face.
    counts : (U,) how many tetrahedra share each distinct face.
    """
    faces = tets[:, TET_FACES].reshape(-1, 3)
    keys, inverse, counts = unique_rows(np.sort(faces, axis=1))
    return faces, keys, inverse, counts


def _face_keys(faces: np.ndarray, nvertices: int) -> np.ndarray:
    s = np.sort(np.asarray(faces, dtype=np.int64), axis=1)
    return (s[:, 0] * nvertices + s[:, 1]) * nvertices + s[:, 2]


def exterior_faces(tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Faces that belong to exactly one tet.

    Returns
    -------
    faces : ndarray (F, 3) int64
        Vertex triples oriented with outward normals, in the order of their tets.
    cells : ndarray (F,) int64
        The tet each face belongs to.
    """
    tets = np.asarray(tets, dtype=np.int64)
    if tets.size == 0:
        return np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    faces, _, inverse, counts = face_table(tets)
    exterior = np.flatnonzero(counts[inverse] == 1)
    return faces[exterior], exterior // 4


def boundary_facets(tets: np.ndarray) -> np.ndarray:
    """The exterior triangles (F, 3) of a tetrahedral mesh, oriented with outward normals."""
    return exterior_faces(tets)[0]


def face_cells(tets: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """For each face (F, 3), a tet that has it as a face, or -1 if none does."""
    tets = np.asarray(tets, dtype=np.int64)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) == 0:
        return np.zeros(0, dtype=np.int64)
    nv = max(int(tets.max()), int(faces.max())) + 1
    keys = _face_keys(tets[:, TET_FACES].reshape(-1, 3), nv)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    query = _face_keys(faces, nv)
    pos = np.clip(np.searchsorted(sorted_keys, query), 0, len(sorted_keys) - 1)
    found = sorted_keys[pos] == query
    return np.where(found, order[pos] // 4, -1)


def triangle_areas_normals(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Areas (F,) and unit normals (F, 3) of triangles."""
    p = np.asarray(points)[faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    twice_area = np.linalg.norm(n, axis=1)
    return 0.5 * twice_area, n / np.maximum(twice_area, np.finfo(float).tiny)[:, None]
