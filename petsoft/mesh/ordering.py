"""Space-filling-curve orderings of mesh entities.

Cells sorted along a Morton (Z-order) curve of their centroids are close in memory when they are
close in space: assembly gets cache locality and PETSc's cheap ``simple`` partitioner, which cuts
the cell list into contiguous chunks, produces compact subdomains with short interfaces. (PTScotch
on the uninterpolated mesh took 10 s for 384k tets on 2 ranks here; this takes 0.1 s.)
"""

from __future__ import annotations

import ctypes
import importlib
from functools import lru_cache

import numpy as np

from petsoft.carrays import addr

_BITS = 21  # 3 x 21 bits fit an int64 key


@lru_cache(maxsize=1)
def _library() -> ctypes.CDLL:
    lib = ctypes.CDLL(importlib.import_module("petsoft.mesh._cmesh").__file__)
    # arrays go in as plain addresses (see petsoft.carrays.addr for why)
    lib.petsoft_cell_morton_keys.argtypes = [ctypes.c_int64, ctypes.c_int32, ctypes.c_int64,
                                             ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
    lib.petsoft_cell_morton_keys.restype = None
    return lib


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """Insert two zero bits between the low 21 bits of each value (for 3D interleaving)."""
    v = v.astype(np.uint64) & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


def morton_keys(points: np.ndarray) -> np.ndarray:
    """Morton keys of points (n, 3) quantised on their bounding box."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return np.zeros(0, dtype=np.uint64)
    lo = points.min(axis=0)
    extent = np.maximum(points.max(axis=0) - lo, np.finfo(float).tiny)
    q = np.floor((points - lo) / extent.max() * ((1 << _BITS) - 1)).astype(np.int64)
    return (_spread_bits(q[:, 0]) | (_spread_bits(q[:, 1]) << np.uint64(1))
            | (_spread_bits(q[:, 2]) << np.uint64(2)))


def morton_order(points: np.ndarray) -> np.ndarray:
    """Permutation sorting points along the Morton curve (stable, deterministic)."""
    return np.argsort(morton_keys(points), kind="stable")


def cell_morton_keys(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Morton keys of the centroids of cells (n, k) quantised on the centroids' bounding box:
    the same keys as ``morton_keys(cell_centroids(points, cells))`` (tests/test_ordering.py),
    from one compiled pass (``csrc/ordering.c``) with no (n, 3) temporaries."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    cells = np.asarray(cells, dtype=np.int64)
    if cells.ndim != 2 or cells.strides[1] != cells.itemsize or cells.strides[0] % cells.itemsize:
        cells = np.ascontiguousarray(cells)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {points.shape}")
    if cells.size and (cells.min() < 0 or cells.max() >= len(points)):
        raise ValueError("cells refer to points that do not exist")
    keys = np.empty(len(cells), dtype=np.uint64)
    if len(cells):
        _library().petsoft_cell_morton_keys(len(cells), cells.shape[1],
                                            cells.strides[0] // cells.itemsize, addr(cells),
                                            addr(points), addr(keys))
    return keys


def cell_morton_order(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Permutation sorting cells along the Morton curve of their centroids (stable): the same
    as ``morton_order(cell_centroids(points, cells))``."""
    return np.argsort(cell_morton_keys(points, cells), kind="stable")


def cell_centroids(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Centroids (n, 3) of cells (n, k): the same numbers as ``points[cells].mean(axis=1)``
    (the same additions in the same order, and a division by a power of two for tetrahedra),
    without the (n, k, 3) temporary, whose strided reduction took 0.4 s at 1M tets."""
    cells = np.asarray(cells)
    total = points[cells[:, 0]].copy()
    for k in range(1, cells.shape[1]):      # a loop over the (few) vertices of a cell
        total += points[cells[:, k]]
    return total / cells.shape[1]


def first_touch(cells: np.ndarray, nvertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices in order of first appearance in ``cells``, and the cell of each appearance.

    Returns ``(perm, first_cell)``: ``perm[new] = old``, and ``first_cell[new]`` the index of the
    first cell holding that vertex (nondecreasing); vertices in no cell come last, with
    ``first_cell = len(cells)``.
    """
    cells = np.asarray(cells, dtype=np.int64)
    flat = cells.ravel()
    # the first position of every vertex, in linear time (np.unique sorted all 4n entries):
    # assigning positions in reverse leaves each vertex's smallest one, since numpy assigns a
    # repeated index's values in order (tests/test_ordering.py checks against np.unique)
    first = np.full(nvertices, len(flat), dtype=np.int64)
    first[flat[::-1]] = np.arange(len(flat) - 1, -1, -1, dtype=np.int64)
    perm = np.argsort(first, kind="stable")
    return perm, first[perm] // max(cells.shape[1], 1)


def first_touch_order(cells: np.ndarray, nvertices: int) -> np.ndarray:
    """Vertex permutation numbering vertices in order of first appearance in ``cells``.

    Returns ``perm`` with ``perm[new] = old``; vertices in no cell come last.
    """
    return first_touch(cells, nvertices)[0]
