"""Face topology of tetrahedral meshes: faces of cells, exterior faces, and which cell holds a face.

Pure numpy on the global (serial) connectivity, shared by the mesh checks, boundary conditions and
surface loads.
"""

from __future__ import annotations

import numpy as np

# Faces of tet (v0, v1, v2, v3) opposite to vertex 3, 2, 1, 0, each ordered so that its normal
# (right-hand rule) points out of a positively oriented tet.
TET_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int64)


def _face_keys(faces: np.ndarray, nvertices: int) -> np.ndarray:
    s = np.sort(np.asarray(faces, dtype=np.int64), axis=1)
    return (s[:, 0] * nvertices + s[:, 1]) * nvertices + s[:, 2]


def exterior_faces(tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Faces that belong to exactly one tet.

    Returns
    -------
    faces : ndarray (F, 3) int64
        Vertex triples oriented with outward normals.
    cells : ndarray (F,) int64
        The tet each face belongs to.
    """
    tets = np.asarray(tets, dtype=np.int64)
    nv = int(tets.max()) + 1 if tets.size else 0
    all_faces = tets[:, TET_FACES].reshape(-1, 3)
    keys = _face_keys(all_faces, nv)
    _, first, counts = np.unique(keys, return_index=True, return_counts=True)
    ext = np.sort(first[counts == 1])
    return all_faces[ext], ext // 4


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
