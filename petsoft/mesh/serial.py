"""Serial tetrahedral meshes: reading, generating and validating them.

This module owns everything petsoft knows about a mesh *before* it is distributed: reading any file
meshio reads (gmsh ``.msh`` v2.2/v4.1, ``.vtu``, ``.xdmf``, medit ``.mesh``, ...), the built-in
structured box generator of the experiment file's ``[mesh] box = {size, cells}``, and the checks
that turn a broken mesh into a :class:`~petsoft.errors.MeshError` naming the file, the element or
node (0-based indices) and what would be valid. It knows nothing about PETSc: the DMPlex is built
elsewhere from the arrays of a :class:`Mesh`.

Conventions
-----------
* Tetrahedra are linear (4 nodes) and positively oriented: ``det[p1-p0, p2-p0, p3-p0] > 0``.
* Cell regions are 3D physical groups: ``cell_tags[e]`` is the tag of tetrahedron ``e`` (0 when it
  belongs to none) and ``regions`` maps a name to a tag. Named groups keep their gmsh names; groups
  known only by an integer (medit references, VTU/XDMF cell data) are called ``"group<tag>"``.
* Facet groups are 2D physical groups of triangles, kept as node triples. Triangles that lie on the
  boundary of the mesh are oriented with their normal pointing out of the body, so tractions can
  use them directly; interior ones (interfaces) keep the file's orientation.
* Quadratic tetrahedra (``tetra10``) are read as their 4 corner nodes; with ``order=2`` the file's
  mid-edge nodes are kept as the nodes of 10-node tetrahedra (curved edges allowed), otherwise
  they are dropped with a warning. A mesh of order 2 (:attr:`Mesh.edge_nodes` set; made by
  :func:`petsoft.mesh.quadratic.raise_order`) lists its corner nodes first, numbered as in the
  linear mesh, then one node per edge; ``tets`` stays the corner connectivity, so everything that
  only needs the geometry (volumes, faces, locating points) reads it unchanged.
* Element indices in messages count tetrahedra only, in file order; node indices are 0-based
  positions in the file's node list (gmsh node *tags* are usually these plus one).
"""

from __future__ import annotations

import contextlib
import io
import math
import numbers
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from petsoft.errors import MeshError
from petsoft.mesh.topology import boundary_facets, face_table, unique_rows

__all__ = ["Mesh", "MeshWarning", "boundary_facets", "box_mesh", "read_mesh", "validate"]

#: Cell-data arrays that carry an integer physical-group tag per cell, most specific first.
#: ``gmsh:physical`` (gmsh), ``medit:ref`` (medit), ``CellEntityIds`` (VTK files from some
#: generators, e.g. MMG/ParaView), and plain names people give such arrays.
TAG_KEYS = ("gmsh:physical", "medit:ref", "CellEntityIds", "region", "regions", "cell_tags", "tags")

#: A tetrahedron whose volume is below this times (mean edge length)^3 counts as degenerate. A
#: regular tetrahedron has volume ~0.118 h^3, so this only catches flat or collapsed cells.
DEGENERATE_RTOL = 1e-12

#: The outward faces of a positively oriented tetrahedron (v0, v1, v2, v3): the face opposite
#: vertex i is row i, ordered so that its right-hand normal points away from vertex i.
# How many offending items a message lists before saying "and N more".
_SHOW = 5

_LINEAR_TETS = "linear tetrahedra (gmsh element type 4, VTK type 10)"


class MeshWarning(UserWarning):
    """Something in a mesh was ignored or repaired (extra cell types, unused nodes, orientation)."""


@dataclass(eq=False)
class Mesh:
    """A serial tetrahedral mesh, validated and in metres.

    Attributes
    ----------
    points : numpy.ndarray
        ``(N, 3)`` float64 node coordinates in metres (after ``scale``).
    tets : numpy.ndarray
        ``(E, 4)`` int64 node indices of each tetrahedron, positively oriented.
    cell_tags : numpy.ndarray
        ``(E,)`` int64 physical-group tag of each tetrahedron, 0 where untagged.
    regions : dict of str to int
        Cell-region name to tag, for the 3D physical groups present in ``cell_tags``.
    facet_groups : dict of str to numpy.ndarray
        Name to ``(F, 3)`` int64 triangles (indices into ``points``) of each 2D physical group.
    source : str
        Where the mesh came from (file path or ``"box(...)"``), used in messages.
    edge_nodes : numpy.ndarray or None
        For 10-node (P2) tetrahedra: ``(E, 6)`` int64 node of each edge, in the VTK/gmsh (meshio)
        order of edges (0,1), (1,2), (0,2), (0,3), (1,3), (2,3); None for linear tetrahedra.
    """

    points: np.ndarray
    tets: np.ndarray
    cell_tags: np.ndarray
    regions: dict[str, int] = field(default_factory=dict)
    facet_groups: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = "<mesh>"
    edge_nodes: np.ndarray | None = None

    @property
    def order(self) -> int:
        """Polynomial order of the elements: 1 (4-node) or 2 (10-node tetrahedra)."""
        return 1 if self.edge_nodes is None else 2

    @property
    def cells(self) -> np.ndarray:
        """``(E, 4)`` or ``(E, 10)`` nodes of each element (the dofs' connectivity)."""
        if self.edge_nodes is None:
            return self.tets
        return np.concatenate([self.tets, self.edge_nodes], axis=1)

    @property
    def num_corners(self) -> int:
        """Number of corner (vertex) nodes; they come first in ``points``."""
        return int(self.tets.max()) + 1 if self.edge_nodes is not None else self.num_points

    @property
    def num_points(self) -> int:
        """Number of nodes."""
        return int(self.points.shape[0])

    @property
    def num_cells(self) -> int:
        """Number of tetrahedra."""
        return int(self.tets.shape[0])

    def __repr__(self) -> str:
        kind = "tetrahedra" if self.order == 1 else "10-node tetrahedra"
        return (
            f"Mesh({self.source}: {self.num_points} nodes, {self.num_cells} {kind}, "
            f"regions={sorted(self.regions)}, facet_groups={sorted(self.facet_groups)})"
        )


# --------------------------------------------------------------------------------------------
# Reading


def read_mesh(path: str | Path, scale: float = 1.0, order: int = 1) -> Mesh:
    """Read a tetrahedral mesh from any file meshio reads, scale it to metres and validate it.

    Parameters
    ----------
    path : str or pathlib.Path
        The mesh file. The format is deduced from the extension by meshio.
    scale : float, optional
        Factor that turns the file's coordinates into metres (e.g. 1e-3 for millimetres).
    order : {1, 2}, optional
        Element order of the result. With 2 a file of 10-node tetrahedra keeps its mid-edge
        nodes where they are (curved edges), and a file of linear ones gets straight-edged
        10-node tetrahedra (:func:`petsoft.mesh.quadratic.raise_order`).

    Returns
    -------
    Mesh
        The validated mesh: only nodes used by tetrahedra, all tetrahedra positively oriented.

    Raises
    ------
    MeshError
        If the file is missing or unreadable, has no tetrahedra, non-finite coordinates, cells
        referring to missing nodes, degenerate or (some) inverted tetrahedra, or ``scale`` is not
        a finite number > 0.

    Warns
    -----
    MeshWarning
        When cells other than tetrahedra are ignored, quadratic tetrahedra are reduced to their
        corners, unused nodes are dropped, or an all-negative orientation is flipped.
    """
    path = Path(path)
    scale = _check_scale(scale, path)
    raw = _read_meshio(path)
    source = str(path)
    points = _scaled_points(raw, source, scale)
    names = _group_names(raw.field_data)
    cells = _FileCells.of(raw, source)
    if not cells.tet_blocks or sum(len(b) for b in cells.tet_blocks) == 0:
        what = _count_phrase(cells.found) if cells.found else "no cells at all"
        raise MeshError(
            f"{source}: contains no tetrahedra (found {what}); petsoft needs a 3D mesh of "
            f"{_LINEAR_TETS}: mesh the volume, e.g. gmsh -3"
        )
    tets = np.concatenate(cells.tet_blocks)
    cell_tags = np.concatenate(cells.tet_tags)
    regions = {
        names.get((3, int(t)), f"group{int(t)}"): int(t) for t in np.unique(cell_tags) if t != 0
    }
    tris = (np.concatenate(cells.tri_blocks) if cells.tri_blocks
            else np.zeros((0, 3), np.int64))
    ttags = np.concatenate(cells.tri_tags) if cells.tri_tags else np.zeros(0, np.int64)
    facet_groups = {
        names.get((2, int(t)), f"group{int(t)}"): tris[ttags == t] for t in np.unique(ttags) if t
    }
    cells.warn_unused(source, int(np.count_nonzero(ttags)), facet_groups, order)
    edge_points = None
    if order == 2 and cells.n_quadratic == len(tets):
        points, tets, facet_groups, edge_points = _edge_nodes_apart(
            source, points, tets, np.concatenate(cells.mid_blocks), facet_groups)
    mesh = validate(Mesh(points, tets, cell_tags, regions, facet_groups, source))
    if order == 1:
        return mesh
    from petsoft.mesh.quadratic import raise_order

    return raise_order(mesh, edge_points=edge_points)


def _scaled_points(raw, source: str, scale: float) -> np.ndarray:
    """The file's node coordinates in metres, refused unless 3D numbers."""
    points = np.asarray(raw.points)
    if points.ndim != 2 or points.shape[1] != 3:
        shape = "x".join(map(str, points.shape))
        raise MeshError(
            f"{source}: nodes have {points.shape[1] if points.ndim == 2 else '?'} coordinates "
            f"(array {shape}); petsoft needs 3D coordinates (x, y, z) for a tetrahedral mesh"
        )
    if not np.issubdtype(points.dtype, np.number):
        raise MeshError(f"{source}: node coordinates are not numbers (dtype {points.dtype})")
    return points.astype(np.float64) * scale


@dataclass
class _FileCells:
    """The cell blocks of a mesh file, sorted: the tetrahedra (corners, tags, the mid-edge
    nodes of a tetra10 block, None for a tetra block), the triangles (corners, tags), every
    cell type's count (``found``, for messages) and the triangles kept as facets by type."""

    tet_blocks: list[np.ndarray] = field(default_factory=list)
    tet_tags: list[np.ndarray] = field(default_factory=list)
    mid_blocks: list[np.ndarray | None] = field(default_factory=list)
    n_quadratic: int = 0
    tri_blocks: list[np.ndarray] = field(default_factory=list)
    tri_tags: list[np.ndarray] = field(default_factory=list)
    found: dict[str, int] = field(default_factory=dict)
    kept: dict[str, int] = field(default_factory=dict)

    @classmethod
    def of(cls, raw, source: str) -> _FileCells:
        """The blocks of the meshio mesh ``raw`` (its tags by :data:`TAG_KEYS`)."""
        out = cls()
        tag_key = next((k for k in TAG_KEYS if k in raw.cell_data), None)
        for i, block in enumerate(raw.cells):
            data = np.asarray(block.data)
            out.found[block.type] = out.found.get(block.type, 0) + len(data)
            tags = _block_tags(raw, tag_key, i, len(data), source)
            if block.type in ("tetra", "tetra10"):
                # gmsh and VTK both list the 4 corners first in a tetra10.
                out.tet_blocks.append(data[:, :4].astype(np.int64))
                out.tet_tags.append(tags)
                out.mid_blocks.append(data[:, 4:10].astype(np.int64)
                                      if block.type == "tetra10" else None)
                if block.type == "tetra10":
                    out.n_quadratic += len(data)
            elif block.type in ("triangle", "triangle6"):
                out.tri_blocks.append(data[:, :3].astype(np.int64))
                out.tri_tags.append(tags)
                # Tagged triangles become facet groups; untagged ones are ignored like other
                # cells.
                out.kept[block.type] = (out.kept.get(block.type, 0)
                                        + int(np.count_nonzero(tags)))
        return out

    def warn_unused(self, source: str, n_facets: int, facet_groups: dict, order: int) -> None:
        """Say what was not used, and (so that it is not mistaken for loss) what triangles were
        kept; and that quadratic tetrahedra lose their mid-edge nodes at ``order`` 1."""
        ignored = {k: v - self.kept.get(k, 0) for k, v in self.found.items()
                   if k not in ("tetra", "tetra10")}
        ignored = {k: v for k, v in ignored.items() if v > 0}
        if ignored:
            msg = (f"{source}: ignored {_count_phrase(ignored)} cells; petsoft uses only the "
                   "tetrahedra")
            if n_facets:
                groups = ", ".join(repr(n) for n in facet_groups)
                msg += (
                    f" (the {n_facets} triangles in 2D physical groups {groups} are kept as facet "
                    "groups)"
                )
            # (stack: this method, read_mesh, its caller)
            warnings.warn(msg, MeshWarning, stacklevel=3)
        if self.n_quadratic and order != 2:
            warnings.warn(
                f"{source}: {self.n_quadratic} quadratic tetrahedra (tetra10): the model is linear "
                "(4-node tetrahedra), so petsoft uses their 4 corner nodes and drops the mid-edge "
                "nodes; set [mesh] order = 2 to use them",
                MeshWarning,
                stacklevel=3,
            )


def _edge_nodes_apart(source: str, points: np.ndarray, tets: np.ndarray, mids: np.ndarray,
                      facet_groups: dict):
    """A file of 10-node tetrahedra read at order 2: (the corner nodes, the tetrahedra and the
    facet groups renumbered on them, the (E, 6, 3) mid-edge nodes' positions) -- the mid-edge
    nodes are not the corner mesh's: they are left out of its validation (which would call them
    unused), then given back as edge nodes."""
    bad = (mids < 0) | (mids >= len(points))
    if bad.any():
        e = int(np.flatnonzero(bad.any(axis=1))[0])
        raise MeshError(f"{source}: tetra10 {e} (0-based) refers to a mid-edge node that "
                        f"does not exist (the file has {len(points)} nodes)")
    edge_points = points[mids]
    if (signed_volumes(points, tets) < 0).all():
        # validate() swaps corners 1 and 2 of every tetrahedron: follow with the edges
        edge_points = edge_points[:, [2, 1, 0, 3, 5, 4]]
    mid_only = np.zeros(len(points), bool)
    mid_only[mids.ravel()] = True
    mid_only[tets.ravel()] = False
    new_index = np.cumsum(~mid_only) - 1
    return (points[~mid_only], new_index[tets],
            {k: new_index[v] for k, v in facet_groups.items()}, edge_points)


def _check_scale(scale: object, path: Path) -> float:
    """Return ``scale`` as a float, or raise if it cannot turn coordinates into metres."""
    ok = isinstance(scale, numbers.Real) and not isinstance(scale, bool)
    if not ok or not math.isfinite(float(scale)) or float(scale) <= 0:
        raise MeshError(
            f"{path}: mesh scale must be a finite number > 0 that turns the file's units into "
            f"metres (e.g. 1e-3 for millimetres), got {scale!r}"
        )
    return float(scale)


def _read_meshio(path: Path):
    """Read ``path`` with meshio, turning every failure into a MeshError naming the file."""
    import meshio  # imported here so that `import petsoft.mesh.serial` stays cheap

    if not path.exists():
        raise MeshError(f"mesh file {path} does not exist (resolved: {path.resolve()})")
    if not path.is_file():
        raise MeshError(f"mesh file {path} is not a regular file")
    try:
        # meshio reports problems with all sorts of exceptions (ReadError, KeyError, ValueError,
        # UnicodeDecodeError, ...) depending on the format, and even sys.exit() when no reader
        # for the extension accepts the file: catch them all and say which file. meshio
        # prints each reader it tried that failed (a .msh is tried as gmsh 2.2 and 4.1: one
        # empty line on stdout per mesh read, seen in every diagnose log): keep those in the
        # error message instead.
        with contextlib.redirect_stdout(io.StringIO()) as tried:
            return meshio.read(path)
    except (Exception, SystemExit) as exc:
        if isinstance(exc, SystemExit):
            detail = "no meshio reader for this extension accepted it"
        else:
            detail = f"{str(exc).strip() or 'error'} ({type(exc).__name__})"
        said = " ".join(tried.getvalue().split())
        if said:
            detail += f"; meshio said: {said}"
        raise MeshError(
            f"cannot read mesh file {path}: {detail}; petsoft reads any format meshio reads "
            "(gmsh .msh, .vtu, .vtk, .xdmf, medit .mesh, ...), chosen by the file extension"
        ) from exc


def _group_names(field_data: dict) -> dict[tuple[int, int], str]:
    """Map (dimension, tag) to a physical-group name from meshio's gmsh-style ``field_data``."""
    names = {}
    for name, value in field_data.items():
        arr = np.asarray(value).ravel()
        # gmsh stores [tag, dim]; other formats may carry unrelated field data: skip those.
        if arr.size == 2 and np.issubdtype(arr.dtype, np.number):
            names[(int(arr[1]), int(arr[0]))] = str(name)
    return names


def _block_tags(raw, key: str | None, i: int, n: int, source: str) -> np.ndarray:
    """The integer tag of each cell of block ``i`` (zeros when the file has no tag array)."""
    if key is None:
        return np.zeros(n, np.int64)
    arr = np.asarray(raw.cell_data[key][i])
    if arr.size != n:
        # e.g. a vector-valued array that happens to be called "region": not tags.
        return np.zeros(n, np.int64)
    arr = arr.reshape(n)
    if not np.issubdtype(arr.dtype, np.integer):
        if not np.issubdtype(arr.dtype, np.number) or not np.all(np.isfinite(arr)):
            return np.zeros(n, np.int64)
        if np.any(arr != np.round(arr)):
            raise MeshError(
                f"{source}: cell data {key!r} (block {i}, {raw.cells[i].type}) holds non-integer "
                "values; physical-group tags must be integers"
            )
    return arr.astype(np.int64)


def _count_phrase(counts: dict[str, int]) -> str:
    """'120 triangle, 40 line' from {'triangle': 120, 'line': 40}."""
    return ", ".join(f"{n} {kind}" for kind, n in counts.items())


def _listing(indices: np.ndarray, what: str = "") -> str:
    """'3, 7, 9 and 12 more' for messages that name offenders without flooding the terminal."""
    shown = ", ".join(f"{what}{int(i)}" for i in indices[:_SHOW])
    return shown + (f" and {len(indices) - _SHOW} more" if len(indices) > _SHOW else "")


# --------------------------------------------------------------------------------------------
# Geometry helpers


def signed_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volume of each tetrahedron, ``det[p1-p0, p2-p0, p3-p0] / 6``.

    Parameters
    ----------
    points : numpy.ndarray
        ``(N, 3)`` coordinates.
    tets : numpy.ndarray
        ``(E, 4)`` node indices.

    Returns
    -------
    numpy.ndarray
        ``(E,)`` volumes, positive for positively oriented tetrahedra.
    """
    p = points[tets]
    a, b, c = (p[:, k] - p[:, 0] for k in (1, 2, 3))
    return np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0


def _mean_edge_lengths(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    p = points[tets]
    pairs = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
    return sum(np.linalg.norm(p[:, i] - p[:, j], axis=1) for i, j in pairs) / 6.0


# --------------------------------------------------------------------------------------------
# Validation


def validate(mesh: Mesh) -> Mesh:
    """Check a mesh and return a clean copy: used nodes only, all tetrahedra positive.

    Checks, each raising :class:`MeshError` naming ``mesh.source`` and the offending element or
    node (0-based): array shapes; cells referring to missing nodes; non-finite coordinates of used
    nodes; degenerate tetrahedra (|volume| <= 1e-12 * mean-edge-length^3); tetrahedra with
    inconsistent orientation; faces shared by more than two tetrahedra or repeated tetrahedra;
    facet-group triangles referring to missing nodes.

    Repairs, each with a :class:`MeshWarning`: a mesh whose tetrahedra are *all* negatively
    oriented is flipped (the file's convention); nodes used by no tetrahedron are dropped and
    indices renumbered (facet triangles touching them are removed); boundary facet-group
    triangles are oriented outward.

    Parameters
    ----------
    mesh : Mesh
        The mesh to check. It is not modified.

    Returns
    -------
    Mesh
        A new, validated mesh.
    """
    src = mesh.source
    points, tets, cell_tags = _checked_arrays(mesh)
    n = len(points)
    _check_node_indices(tets, n, src, "tetrahedron", "counting tetrahedra only")
    facet_groups = {}
    for name, tris in mesh.facet_groups.items():
        tris = np.asarray(tris).astype(np.int64).reshape(-1, 3)
        _check_node_indices(tris, n, src, "triangle", f"within facet group {name!r}")
        facet_groups[name] = tris
    used = np.zeros(n, bool)
    used[tets.ravel()] = True
    _check_used_finite(points, used, src)
    tets = _oriented(points, tets, src)
    facet_groups = _check_faces(tets, facet_groups, src)
    if not used.all():
        points, tets, facet_groups = _without_unused(points, tets, facet_groups, used, src)
    return Mesh(
        points=points,
        tets=tets,
        cell_tags=cell_tags,
        regions={str(k): int(v) for k, v in mesh.regions.items()},
        facet_groups=facet_groups,
        source=src,
    )


def _checked_arrays(mesh: Mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesh's coordinates (float64), tetrahedra (int64) and cell tags, their shapes
    checked."""
    src = mesh.source
    points = np.asarray(mesh.points)
    tets = np.asarray(mesh.tets)
    if points.ndim != 2 or points.shape[1] != 3 or not np.issubdtype(points.dtype, np.number):
        raise MeshError(f"{src}: node coordinates must be an (N, 3) array, got {points.shape}")
    if tets.ndim != 2 or tets.shape[1] != 4 or not np.issubdtype(tets.dtype, np.integer):
        raise MeshError(
            f"{src}: tetrahedra must be an (E, 4) integer array of node indices, got "
            f"{tets.shape} {tets.dtype}"
        )
    if len(tets) == 0:
        raise MeshError(f"{src}: contains no tetrahedra; petsoft needs {_LINEAR_TETS}")
    cell_tags = np.asarray(mesh.cell_tags).astype(np.int64).reshape(-1)
    if cell_tags.shape != (len(tets),):
        raise MeshError(f"{src}: {len(cell_tags)} cell tags for {len(tets)} tetrahedra")
    return points.astype(np.float64), tets.astype(np.int64), cell_tags


def _check_used_finite(points: np.ndarray, used: np.ndarray, src: str) -> None:
    """Refuse non-finite coordinates of a node a tetrahedron uses."""
    bad = np.flatnonzero(used & ~np.isfinite(points).all(axis=1))
    if len(bad):
        raise MeshError(
            f"{src}: node {bad[0]} (0-based) has non-finite coordinates "
            f"{tuple(float(c) for c in points[bad[0]])}; "
            f"{len(bad)} used node(s) are affected ({_listing(bad, 'node ')}); "
            "all coordinates must be finite numbers"
        )


def _oriented(points: np.ndarray, tets: np.ndarray, src: str) -> np.ndarray:
    """The tetrahedra, refused when degenerate or of mixed orientation, flipped (with a
    warning) when all are negative."""
    ne = len(tets)
    vol = signed_volumes(points, tets)
    h = _mean_edge_lengths(points, tets)
    degenerate = np.flatnonzero(~(np.abs(vol) > DEGENERATE_RTOL * h**3))
    if len(degenerate):
        e = degenerate[0]
        raise MeshError(
            f"{src}: tetrahedron {e} (0-based, counting tetrahedra only; nodes "
            f"{tets[e].tolist()}) is degenerate: volume {vol[e]:.3e} m^3 for mean edge length "
            f"{h[e]:.3e} m (needs |volume| > {DEGENERATE_RTOL:g} * edge^3); "
            f"{len(degenerate)} of {ne} tetrahedra are degenerate "
            f"({_listing(degenerate, 'tetrahedron ')}). "
            "Every tetrahedron needs 4 distinct, non-coplanar vertices"
        )
    negative = vol < 0
    if negative.all():
        warnings.warn(
            f"{src}: all {ne} tetrahedra are negatively oriented; taking that as the file's "
            "convention and swapping vertices 1 and 2 of each so that all have positive volume",
            MeshWarning,
            stacklevel=3,   # (stack: this function, validate, its caller)
        )
        return tets[:, [0, 2, 1, 3]]
    if negative.any():
        neg = np.flatnonzero(negative)
        shown = ", ".join(f"{e} (volume {vol[e]:.3e} m^3)" for e in neg[:_SHOW])
        more = f" and {len(neg) - _SHOW} more" if len(neg) > _SHOW else ""
        raise MeshError(
            f"{src}: {len(neg)} of {ne} tetrahedra are inverted (negative signed volume) while "
            f"the others are positive: tetrahedra {shown}{more} (0-based, counting tetrahedra "
            "only). All tetrahedra must have the same orientation, det[p1-p0, p2-p0, p3-p0] > 0; "
            "regenerate or repair the mesh"
        )
    return tets


def _without_unused(points: np.ndarray, tets: np.ndarray, facet_groups: dict,
                    used: np.ndarray, src: str):
    """(points, tets, facet groups) without the nodes no tetrahedron uses (the others keep
    their relative order; facet triangles touching a dropped node are removed), with a
    warning."""
    new_index = np.cumsum(used) - 1
    unused = np.flatnonzero(~used)
    n_dropped_tris = 0
    for name, tris in facet_groups.items():
        keep = used[tris].all(axis=1)
        n_dropped_tris += int(len(tris) - np.count_nonzero(keep))
        facet_groups[name] = new_index[tris[keep]]
    msg = (
        f"{src}: dropped {len(unused)} node(s) used by no tetrahedron "
        f"(0-based {_listing(unused, 'node ')}); nodes were renumbered"
    )
    if n_dropped_tris:
        msg += f", and {n_dropped_tris} facet-group triangle(s) touching them were removed"
    warnings.warn(msg, MeshWarning, stacklevel=3)   # (this function, validate, its caller)
    return points[used], new_index[tets], facet_groups


def _check_node_indices(cells: np.ndarray, n: int, src: str, kind: str, counting: str) -> None:
    """Raise if any cell refers to a node index outside 0..n-1."""
    bad = (cells < 0) | (cells >= n)
    if bad.any():
        rows = np.flatnonzero(bad.any(axis=1))
        e = rows[0]
        node = cells[e][bad[e]][0]
        raise MeshError(
            f"{src}: {kind} {e} (0-based, {counting}; nodes {cells[e].tolist()}) refers to "
            f"node {node}, which does not exist: the mesh has {n} nodes, so valid 0-based "
            f"indices are 0..{n - 1}; {len(rows)} {kind}(s) refer to missing nodes "
            f"({_listing(rows, kind + ' ')})"
        )


def _check_faces(
    tets: np.ndarray, facet_groups: dict[str, np.ndarray], src: str
) -> dict[str, np.ndarray]:
    """Check conformity and orient boundary facet-group triangles outward.

    Raises if a face is shared by more than two tetrahedra (overlapping or non-manifold cells),
    which a conforming mesh never has. Returns the facet groups with triangles that lie on the
    boundary replaced by the outward-oriented boundary face; warns about triangles that are no
    face of any tetrahedron (a surface mesh not matching the volume mesh).
    """
    faces, keys, inverse, counts = face_table(tets)
    over = np.flatnonzero(counts > 2)
    if len(over):
        k = over[0]
        owners = np.flatnonzero(inverse == k) // 4
        raise MeshError(
            f"{src}: the face with nodes {keys[k].tolist()} is shared by {counts[k]} tetrahedra "
            f"({_listing(owners)}, 0-based), but a face of a valid mesh belongs to at most two: "
            "the mesh has overlapping or duplicated tetrahedra"
        )
    if not facet_groups:
        return {}

    # Outward orientation of each distinct face that lies on the boundary (-1 where interior).
    boundary = counts[inverse] == 1
    owner = np.full(len(keys), -1, np.int64)
    owner[inverse[boundary]] = np.flatnonzero(boundary)

    out = {}
    for name, tris in facet_groups.items():
        if len(tris) == 0:
            out[name] = tris
            continue
        s = np.sort(tris, axis=1)
        # Locate each triangle among the sorted distinct faces (lexicographic row search).
        _, inv, _ = unique_rows(np.concatenate([keys, s]))
        face_of = np.full(inv.max() + 1, -1, np.int64)
        face_of[inv[: len(keys)]] = np.arange(len(keys))
        match = face_of[inv[len(keys) :]]
        missing = np.flatnonzero(match < 0)
        if len(missing):
            warnings.warn(
                f"{src}: facet group {name!r}: {len(missing)} of {len(tris)} triangles are not a "
                f"face of any tetrahedron (0-based triangles {_listing(missing)}, first with nodes "
                f"{tris[missing[0]].tolist()}); the surface mesh does not match the volume mesh",
                MeshWarning,
                stacklevel=3,
            )
        tris = tris.copy()
        on_boundary = np.flatnonzero(match >= 0)
        on_boundary = on_boundary[owner[match[on_boundary]] >= 0]
        tris[on_boundary] = faces[owner[match[on_boundary]]]
        out[name] = tris
    return out


# --------------------------------------------------------------------------------------------
# Generation


def box_mesh(
    size: Sequence[float], cells: Sequence[int], origin: Sequence[float] = (0.0, 0.0, 0.0)
) -> Mesh:
    """A conforming structured tetrahedral mesh of the box ``[origin, origin + size]``.

    Each of the ``nx * ny * nz`` hexahedra is split into 6 tetrahedra along its main diagonal
    (Kuhn/Freudenthal split). Every hexahedron is split the same way, so the face diagonals of
    neighbours coincide and the mesh is conforming.

    Parameters
    ----------
    size : sequence of 3 floats
        Edge lengths ``[lx, ly, lz]`` in metres, each finite and > 0.
    cells : sequence of 3 ints
        Number of hexahedra ``[nx, ny, nz]`` along each axis, each >= 1.
    origin : sequence of 3 floats, optional
        The box's minimum corner.

    Returns
    -------
    Mesh
        ``(nx+1)(ny+1)(nz+1)`` nodes (x fastest), ``6 nx ny nz`` positively oriented tetrahedra,
        all cell tags 0, no regions or facet groups.

    Raises
    ------
    MeshError
        If ``size``, ``cells`` or ``origin`` are not as described.
    """
    where = f"box(size={size!r}, cells={cells!r})"
    lengths = _three(size, "size", where, "3 finite lengths > 0 in metres, [lx, ly, lz]")
    if not all(v > 0 for v in lengths):
        raise MeshError(f"{where}: size must be 3 finite lengths > 0 in metres, got {size!r}")
    corner = _three(origin, "origin", where, "3 finite coordinates in metres")
    counts = _cell_counts(cells, where)
    nx, ny, nz = counts

    # Fractions first so that node coordinates are as exact as possible (0.4 * 3/24 == 0.05).
    axes = [corner[a] + lengths[a] * (np.arange(counts[a] + 1) / counts[a]) for a in range(3)]
    # Node (i, j, k) has index i + (nx+1) * (j + (ny+1) * k): x varies fastest.
    zz, yy, xx = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    points = np.column_stack([xx.ravel(), yy.ravel(), zz.ravel()])

    # Local corners of a hexahedron by bit pattern (x = 1, y = 2, z = 4) and their node offsets.
    bits = np.arange(8)
    corner_offset = (bits & 1) + (nx + 1) * (((bits >> 1) & 1) + (ny + 1) * ((bits >> 2) & 1))
    kk, jj, ii = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    base = (ii + (nx + 1) * (jj + (ny + 1) * kk)).ravel()
    tets = (base[:, None, None] + corner_offset[_KUHN][None]).reshape(-1, 4).astype(np.int64)

    source = f"box(size={[float(v) for v in lengths]}, cells={list(counts)}" + (
        f", origin={[float(v) for v in corner]})" if any(corner) else ")"
    )
    return Mesh(
        points=points,
        tets=tets,
        cell_tags=np.zeros(len(tets), np.int64),
        regions={},
        facet_groups={},
        source=source,
    )


def _kuhn_table() -> np.ndarray:
    """The 6 tetrahedra of the unit cube along the diagonal 0 -> 7, positively oriented.

    Tetrahedron for the axis permutation (a, b, c) walks 0 -> e_a -> e_a + e_b -> 7 along cube
    edges; corners are numbered by bits (x = 1, y = 2, z = 4).
    """
    from itertools import permutations

    corners = np.array([[b & 1, (b >> 1) & 1, (b >> 2) & 1] for b in range(8)], float)
    table = []
    for a, b, _ in permutations(range(3)):
        tet = [0, 1 << a, (1 << a) | (1 << b), 7]
        if signed_volumes(corners, np.array([tet]))[0] < 0:
            tet[1], tet[2] = tet[2], tet[1]
        table.append(tet)
    return np.array(table)


_KUHN = _kuhn_table()


def _three(value: object, key: str, where: str, valid: str) -> tuple[float, float, float]:
    """Parse 3 finite real numbers, or raise naming ``key`` and what is valid."""
    try:
        ok = len(value) == 3 and not isinstance(value, str)  # type: ignore[arg-type]
        vals = tuple(value) if ok else ()  # type: ignore[arg-type]
        ok = ok and all(isinstance(v, numbers.Real) and not isinstance(v, bool) for v in vals)
        ok = ok and all(math.isfinite(float(v)) for v in vals)
    except TypeError:
        ok = False
    if not ok:
        raise MeshError(f"{where}: {key} must be {valid}, got {value!r}")
    return tuple(float(v) for v in vals)  # type: ignore[return-value]


def _cell_counts(value: object, where: str) -> tuple[int, int, int]:
    """Parse 3 positive integers (cells per axis), or raise."""
    try:
        ok = len(value) == 3 and not isinstance(value, str)  # type: ignore[arg-type]
        vals = tuple(value) if ok else ()  # type: ignore[arg-type]
        ok = ok and all(isinstance(v, numbers.Integral) and not isinstance(v, bool) for v in vals)
        ok = ok and all(int(v) >= 1 for v in vals)
    except TypeError:
        ok = False
    if not ok:
        raise MeshError(
            f"{where}: cells must be 3 integers >= 1 (hexahedra per axis, [nx, ny, nz]), "
            f"got {value!r}"
        )
    return tuple(int(v) for v in vals)  # type: ignore[return-value]
