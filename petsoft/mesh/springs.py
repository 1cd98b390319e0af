"""Meshes of nodes, lines and triangles: what a mass-spring model is built from.

Reading and writing them (any file meshio reads: gmsh ``.msh``, ``.vtu``, ...) is mesh work, not
dynamics: the experiment reader looks at a spring mesh's surface (its triangles,
:attr:`SpringMesh.surface`) before any model exists, and :mod:`petsoft.dynamics.mass_spring`
builds its springs from the cells.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from petsoft.errors import MeshError


@dataclass
class SpringMesh:
    """Nodes with line and triangle cells (what a mass-spring model is built from).

    ``tets`` is the cell array written to output (triangles if any, else lines, else one vertex
    cell per node): the name is the one :class:`~petsoft.dynamics.simulate.Simulation` and the
    XDMF writer read from a mesh.
    """

    points: np.ndarray
    lines: np.ndarray
    triangles: np.ndarray
    source: str = "<mesh>"
    regions: dict = field(default_factory=dict)
    facet_groups: dict = field(default_factory=dict)

    @property
    def surface(self) -> np.ndarray:
        """(F, 3) the faces of the body's surface, those a surface term (the drag) acts
        through: the triangle cells, each once (a cloth's two sides together); none for a
        network of lines (:mod:`petsoft.experiment.surface`)."""
        return self.triangles

    @property
    def tets(self) -> np.ndarray:
        if len(self.triangles):
            return self.triangles
        if len(self.lines):
            return self.lines
        return np.arange(len(self.points), dtype=np.int64)[:, None]

    @property
    def cells(self) -> np.ndarray:
        """The output cells (as ``tets``: a spring mesh's nodes are all corners)."""
        return self.tets

    @property
    def cell_tags(self) -> np.ndarray:
        return np.zeros(len(self.tets), dtype=np.int64)


def read_spring_mesh(path: str | Path, scale: float = 1.0) -> SpringMesh:
    """Nodes, lines and triangles of any mesh file meshio reads (vertex cells are ignored).

    Raises
    ------
    MeshError
        Unreadable file, volume cells, cell node numbers out of range.
    """
    import meshio

    path = Path(path)
    try:
        raw = meshio.read(path)
    except Exception as exc:  # meshio raises many types for a bad file
        raise MeshError(f"{path}: cannot read the mesh ({exc})") from exc
    points = np.asarray(raw.points, dtype=float)
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    lines, tris = [], []
    for block in raw.cells:
        if block.type == "line":
            lines.append(block.data)
        elif block.type == "triangle":
            tris.append(block.data)
        elif block.type != "vertex":
            raise MeshError(f"{path}: cells of type {block.type!r}: a mass-spring model is built "
                            "from nodes, lines (ropes) and triangles (cloth); use [material] for "
                            "a volume mesh")
    lines = np.concatenate(lines).astype(np.int64) if lines else np.zeros((0, 2), np.int64)
    tris = np.concatenate(tris).astype(np.int64) if tris else np.zeros((0, 3), np.int64)
    for what, cells in (("line", lines), ("triangle", tris)):
        bad = np.flatnonzero((cells < 0).any(axis=1) | (cells >= len(points)).any(axis=1))
        if len(bad):
            raise MeshError(f"{path}: {what} {int(bad[0])} refers to a node outside "
                            f"0..{len(points) - 1}: {cells[bad[0]].tolist()}")
    return SpringMesh(points * scale, lines, tris, source=str(path))


def write_spring_mesh(path: str | Path, points, lines=None, triangles=None) -> None:
    """Write nodes and line/triangle cells with meshio (gmsh 2.2 for ``.msh``)."""
    import meshio

    cells = []
    if lines is not None and len(lines):
        cells.append(("line", np.asarray(lines)))
    if triangles is not None and len(triangles):
        cells.append(("triangle", np.asarray(triangles)))
    fmt = "gmsh22" if str(path).endswith(".msh") else None
    meshio.write(path, meshio.Mesh(np.asarray(points, float), cells), file_format=fmt,
                 **({"binary": False} if fmt else {}))
