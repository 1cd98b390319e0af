"""Generate the small meshes in ``meshes/`` that tests and demos use.

Run line (from the repository root; rewrites the files, byte-for-byte the same each time)::

    .venv/bin/python scripts/tools/make_meshes.py            # writes into meshes/
    .venv/bin/python scripts/tools/make_meshes.py /tmp/out   # or anywhere else

The meshes are structured (``petsoft.mesh.serial.box_mesh``: hexahedra split into 6 tetrahedra) with
physical groups attached by position, and written by meshio in gmsh 2.2 ASCII format, which every
gmsh-reading tool understands. gmsh itself is not needed.

* ``bar.msh``: a 0.4 x 0.04 x 0.04 m bar, 24 x 3 x 3 hexahedra (1296 tetrahedra, 400 nodes).
  3D physical groups ``left`` (tag 1, x < 0.2) and ``right`` (tag 2, x > 0.2); 2D physical groups
  ``clamp`` (tag 3, the face x = 0) and ``tip`` (tag 4, the face x = 0.4).
* ``cube_mm.msh``: a 10 mm cube **in millimetres** (use ``scale = 1e-3``), 4 x 4 x 4 hexahedra.
  3D group ``body`` (tag 1); 2D groups ``bottom`` (tag 2, z = 0) and ``top`` (tag 3, z = 10).

Things to try: change the sizes and cell counts below, then run the tests (``tests/test_mesh.py``
checks the committed files match what this script writes).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from petsoft.mesh.serial import Mesh, boundary_facets, box_mesh


def _faces_on(mesh: Mesh, axis: int, value: float, tol: float) -> np.ndarray:
    """Boundary triangles (outward) whose 3 vertices all have ``x[axis] == value``."""
    faces = boundary_facets(mesh.tets)
    on = np.abs(mesh.points[faces, axis] - value) < tol
    return faces[on.all(axis=1)]


def tagged_box(
    size, cells, regions: dict[str, tuple[int, np.ndarray]], facets: dict[str, tuple[int, tuple]]
):
    """A meshio mesh of ``box_mesh(size, cells)`` with gmsh physical groups.

    Parameters
    ----------
    size, cells
        As for :func:`petsoft.mesh.serial.box_mesh`.
    regions : dict
        Name -> (tag, boolean mask over tetrahedra) for 3D groups (every tetrahedron in one).
    facets : dict
        Name -> (tag, (axis, value)) for 2D groups: the boundary faces on that plane.
    """
    import meshio

    mesh = box_mesh(size, cells)
    tet_tags = np.zeros(mesh.num_cells, np.int64)
    for tag, mask in regions.values():
        tet_tags[mask(mesh)] = tag
    tol = 1e-9 * max(size)
    tri_blocks, tri_tags = [], []
    for tag, (axis, value) in facets.values():
        tris = _faces_on(mesh, axis, value, tol)
        tri_blocks.append(tris)
        tri_tags.append(np.full(len(tris), tag, np.int64))
    tris = np.concatenate(tri_blocks)
    ttags = np.concatenate(tri_tags)
    field_data = {name: np.array([tag, 3]) for name, (tag, _) in regions.items()}
    field_data.update({name: np.array([tag, 2]) for name, (tag, _) in facets.items()})
    return meshio.Mesh(
        mesh.points,
        [("triangle", tris), ("tetra", mesh.tets)],
        # gmsh 2.2 stores a physical and a geometrical (entity) tag per element: use the same.
        cell_data={"gmsh:physical": [ttags, tet_tags], "gmsh:geometrical": [ttags, tet_tags]},
        field_data=field_data,
    )


def _centroid_x(mesh: Mesh) -> np.ndarray:
    return mesh.points[mesh.tets, 0].mean(axis=1)


def bar():
    """The bar of ``meshes/bar.msh`` as a meshio mesh."""
    return tagged_box(
        [0.4, 0.04, 0.04],
        [24, 3, 3],
        regions={
            "left": (1, lambda m: _centroid_x(m) < 0.2),
            "right": (2, lambda m: _centroid_x(m) >= 0.2),
        },
        facets={"clamp": (3, (0, 0.0)), "tip": (4, (0, 0.4))},
    )


def cube_mm():
    """The millimetre cube of ``meshes/cube_mm.msh`` as a meshio mesh."""
    return tagged_box(
        [10.0, 10.0, 10.0],
        [4, 4, 4],
        regions={"body": (1, lambda m: np.ones(m.num_cells, bool))},
        facets={"bottom": (2, (2, 0.0)), "top": (3, (2, 10.0))},
    )


MESHES = {"bar.msh": bar, "cube_mm.msh": cube_mm}


def main(outdir: str | Path | None = None) -> list[Path]:
    """Write every mesh of :data:`MESHES` into ``outdir`` (default: ``meshes/``)."""
    import meshio

    out = Path(outdir) if outdir else Path(__file__).resolve().parent.parent / "meshes"
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, make in MESHES.items():
        path = out / name
        meshio.write(path, make(), file_format="gmsh22", binary=False)
        written.append(path)
    return written


if __name__ == "__main__":
    for p in main(sys.argv[1] if len(sys.argv) > 1 else None):
        print(p)
