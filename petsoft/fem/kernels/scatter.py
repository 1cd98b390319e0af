"""Scatter-add of element vectors and matrices into local arrays (compiled, with numpy reference).

The matrix side works on a :class:`BlockPattern`: the 3x3-block sparsity of the local vertex
graph of a set of elements, computed once, with the position of every element block in it. Adding
element matrices is then a search-free scatter whose result is the value array of a scalar CSR
matrix that PETSc takes in one call (``Mat.setValuesLocalCSR``).
"""

from __future__ import annotations

import ctypes
import importlib
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from petsoft.carrays import addr

# Arrays go in as plain addresses (checked contiguous and typed by the callers below): numpy's
# ndpointer/``.ctypes`` conversion leaves a self-referencing ctypes object per call that keeps the
# array alive until the cyclic collector runs (see petsoft.carrays.addr).
_i64p = _f64p = ctypes.c_void_p


@lru_cache(maxsize=1)
def _library() -> ctypes.CDLL:
    lib = ctypes.CDLL(importlib.import_module("petsoft.fem.kernels._ckernels").__file__)
    lib.petsoft_scatter_add_matrix.argtypes = [
        ctypes.c_int64, ctypes.c_int32, _i64p, _i64p, _i64p, _f64p, _f64p]
    lib.petsoft_scatter_add_matrix.restype = None
    lib.petsoft_scatter_add_vector.argtypes = [ctypes.c_int64, ctypes.c_int32, _i64p, _f64p, _f64p]
    lib.petsoft_scatter_add_vector.restype = None
    lib.petsoft_pattern_build.argtypes = [ctypes.c_int64, ctypes.c_int32, _i64p, _i64p, _i64p,
                                          ctypes.c_int64, _i64p, _i64p, _i64p, _i64p]
    lib.petsoft_pattern_build.restype = ctypes.c_void_p
    lib.petsoft_pattern_take.argtypes = [ctypes.c_void_p, _i64p]
    lib.petsoft_pattern_take.restype = None
    lib.petsoft_csr_find.argtypes = [ctypes.c_int64, _i64p, _i64p, ctypes.c_int64, _i64p, _i64p,
                                     _i64p]
    lib.petsoft_csr_find.restype = None
    lib.petsoft_csr_find_local.argtypes = [ctypes.c_int64, _i64p, _i64p, _i64p, ctypes.c_int64,
                                           ctypes.c_int64, _i64p, _i64p, _i64p]
    lib.petsoft_csr_find_local.restype = None
    for bits in (32, 64):
        fn = getattr(lib, f"petsoft_pattern_scalar{bits}")
        fn.argtypes = [ctypes.c_int64, _i64p, _i64p, _i64p, _i64p, _i64p]
        fn.restype = None
    return lib


@dataclass(frozen=True)
class BlockPattern:
    """Sparsity of the 3x3-block vertex graph of local elements, in scalar-CSR layout.

    Attributes
    ----------
    nvertices : int
        Number of local vertices (rows of blocks).
    bptr : ndarray, int64, (nvertices + 1,)
        Block-row pointers.
    bcol : ndarray, int64, (nblocks,)
        Block column (local vertex) of every block, sorted within a row.
    indptr, indices : ndarray, PETSc int type
        The scalar CSR (rows = local dofs 3*v+i, columns = local dofs) matching the value layout.
    """

    nvertices: int
    bptr: np.ndarray
    bcol: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray

    @property
    def nvalues(self) -> int:
        return 9 * int(self.bptr[-1])


def block_pattern(nvertices: int, connectivities: list[np.ndarray], index_dtype=np.int32,
                  backend: str = "c"):
    """Build the block pattern of several element sets and each set's block positions.

    Parameters
    ----------
    nvertices : int
        Number of local vertices.
    connectivities : list of ndarray (ne, npe)
        Local vertex indices of each element set (all sets share the pattern).
    index_dtype : dtype
        Integer type of the CSR arrays handed to PETSc (``PETSc.IntType``).
    backend : {"c", "numpy"}
        The compiled builder (``csrc/pattern.c``: linear in the element-vertex pairs) or the
        numpy reference (sorts every element block pair: ~5x slower; kept to test against).

    Returns
    -------
    pattern : BlockPattern
    positions : list of ndarray, int32, (ne, npe, npe)
        For each element set, the index into ``bcol`` of the block (a, b) of each element
        (int32: half the memory of int64; 128 MB at 1M tets, whose first touch was a tenth of
        the set-up).
    """
    conns = [np.ascontiguousarray(c, dtype=np.int64) for c in connectivities]
    if backend == "numpy" or np.dtype(index_dtype) not in (np.int32, np.int64):
        return _block_pattern_numpy(nvertices, conns, index_dtype)
    positions = [np.empty((c.shape[0], c.shape[1], c.shape[1]), dtype=np.int32) for c in conns]
    bptr, bcol = block_rows(nvertices, conns, np.arange(nvertices, dtype=np.int64),
                            positions=positions)
    indptr, indices = scalar_csr(bptr, bcol, index_dtype)
    return BlockPattern(nvertices, bptr, bcol, indptr, indices), positions


def block_rows(nvertices: int, connectivities: list[np.ndarray], rows: np.ndarray,
               positions: list[np.ndarray] | None = None):
    """(bptr, bcol): the sorted distinct neighbours (vertices sharing an element) of ``rows``.

    ``connectivities`` are C-contiguous int64 (ne, npe) arrays of vertex indices < nvertices;
    ``rows`` (int64) the vertices whose rows are wanted, in the order wanted. ``positions``
    (one (ne, npe, npe) int32 array per set; rows must be all vertices in order) are filled
    with the index into ``bcol`` of every element block.
    """
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    if positions is not None:
        positions = [p for p, c in zip(positions, connectivities, strict=True) if c.size]
    conns = [c for c in connectivities if c.size]
    ne = np.array([c.shape[0] for c in conns] or [0], dtype=np.int64)
    npe = np.array([c.shape[1] for c in conns] or [0], dtype=np.int32)
    ptrs = np.array([addr(c) for c in conns] or [0], dtype=np.uint64)
    lib = _library()
    bptr = np.zeros(len(rows) + 1, dtype=np.int64)
    pos = (None if positions is None
           else np.array([addr(p) for p in positions] or [0], dtype=np.uint64))
    status = np.zeros(1, dtype=np.int32)
    built = lib.petsoft_pattern_build(nvertices, len(conns), addr(ne), addr(npe), addr(ptrs),
                                      len(rows), addr(rows), addr(bptr),
                                      None if pos is None else addr(pos), addr(status))
    if not built and status[0] == 2:
        raise OverflowError("block pattern: more than 2^31 blocks on one rank; use more ranks")
    if not built:
        raise MemoryError("block pattern: out of memory")
    try:
        bcol = np.empty(int(bptr[-1]), dtype=np.int64)
    except MemoryError:
        lib.petsoft_pattern_take(built, None)
        raise
    lib.petsoft_pattern_take(built, addr(bcol))
    return bptr, bcol


def scalar_csr(bptr: np.ndarray, bcol: np.ndarray, index_dtype=np.int32,
               colmap: np.ndarray | None = None):
    """(indptr, indices) of the scalar CSR of a block pattern (scatter.c's layout); block column
    c becomes scalar columns colmap[c] + (0, 1, 2) (default 3 c)."""
    nrows = len(bptr) - 1
    bits = 8 * np.dtype(index_dtype).itemsize
    indptr = np.empty(3 * nrows + 1, dtype=index_dtype)
    indices = np.empty(9 * int(bptr[-1]), dtype=index_dtype)
    if bits == 32 and 9 * int(bptr[-1]) >= 2**31:
        raise OverflowError("the matrix has more than 2^31 nonzeros: PETSc needs 64-bit indices")
    cmap = None if colmap is None else np.ascontiguousarray(colmap, dtype=np.int64)
    getattr(_library(), f"petsoft_pattern_scalar{bits}")(
        nrows, addr(bptr), addr(np.ascontiguousarray(bcol)), None if cmap is None else addr(cmap),
        addr(indptr), addr(indices))
    return indptr, indices


def csr_find(ai: np.ndarray, aj: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Index into ``aj`` of each entry (rows[q], cols[q]) of a CSR structure (ai, aj) whose rows
    hold sorted columns, -1 where absent (compiled: a bisection within the row per entry).

    Parameters
    ----------
    ai : ndarray (nrows + 1,)
    aj : ndarray (nnz,)
    rows, cols : ndarray (n,)
        Row (0-based, into ai) and column of each entry sought.
    """
    ai, aj = (np.ascontiguousarray(a, dtype=np.int64) for a in (ai, aj))
    rows, cols = (np.ascontiguousarray(a, dtype=np.int64) for a in (rows, cols))
    if rows.shape != cols.shape or rows.ndim != 1:
        raise ValueError("rows and cols must be 1-D arrays of one length")
    if len(ai) < 1 or ai[-1] > len(aj):
        raise ValueError("ai does not fit aj")
    out = np.empty(len(rows), dtype=np.int64)
    _library().petsoft_csr_find(len(rows), addr(rows), addr(cols), len(ai) - 1, addr(ai),
                                addr(aj), addr(out))
    return out


def csr_find_local(ai: np.ndarray, aj: np.ndarray, row0: int, indptr: np.ndarray,
                   indices: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """:func:`csr_find` of every entry of a local CSR (``indptr``, ``indices``: local rows and
    columns) in global numbers (``dof``: the global number of each local one; rows of ``ai``
    count from global row ``row0``): ``out[k]`` for ``indptr[0] <= k < indptr[-1]``."""
    ai, aj, indptr, indices, dof = (np.ascontiguousarray(a, dtype=np.int64)
                                    for a in (ai, aj, indptr, indices, dof))
    if len(indptr) < 1 or indptr[-1] > len(indices) or len(dof) < len(indptr) - 1:
        raise ValueError("indptr, indices and dof do not fit each other")
    if len(indices) and (indices.min() < 0 or indices.max() >= len(dof)):
        raise ValueError("indices refer to dofs that do not exist")
    out = np.empty(int(indptr[-1] - indptr[0]), dtype=np.int64)
    _library().petsoft_csr_find_local(len(indptr) - 1, addr(indptr), addr(indices), addr(dof),
                                      int(row0), len(ai) - 1, addr(ai), addr(aj), addr(out))
    return out


def _block_pattern_numpy(nvertices: int, connectivities: list[np.ndarray], index_dtype):
    """The numpy reference of :func:`block_pattern` (a sort of all element block pairs)."""
    keys = []
    for conn in connectivities:
        npe = conn.shape[1]
        rows = np.repeat(conn, npe, axis=1)
        cols = np.tile(conn, (1, npe))
        keys.append((rows * nvertices + cols).ravel())
    all_keys = np.concatenate(keys) if keys else np.zeros(0, np.int64)
    unique_keys, inverse = np.unique(all_keys, return_inverse=True)
    brow = unique_keys // nvertices
    bcol = unique_keys % nvertices
    bptr = np.zeros(nvertices + 1, dtype=np.int64)
    np.cumsum(np.bincount(brow, minlength=nvertices), out=bptr[1:])
    nb = np.diff(bptr)
    # scalar rows 3r+i start at 9*bptr[r] + 3*nb[r]*i
    indptr = np.empty(3 * nvertices + 1, dtype=np.int64)
    indptr[:-1] = (9 * bptr[:-1, None] + 3 * nb[:, None] * np.arange(3)[None, :]).ravel()
    indptr[-1] = 9 * bptr[-1]
    k_in_row = np.arange(len(bcol)) - bptr[brow]
    indices = np.empty(9 * len(bcol), dtype=np.int64)
    base = 9 * bptr[brow] + 3 * k_in_row
    for i in range(3):  # three scalar rows per block row, three columns per block
        for j in range(3):
            indices[base + 3 * nb[brow] * i + j] = 3 * bcol + j
    positions, start = [], 0
    for conn in connectivities:
        npe = conn.shape[1]
        n = conn.shape[0] * npe * npe
        positions.append(inverse[start:start + n].reshape(conn.shape[0], npe, npe).astype(np.int32))
        start += n
    pattern = BlockPattern(nvertices, bptr, bcol, indptr.astype(index_dtype),
                           indices.astype(index_dtype))
    return pattern, positions


def scatter_add_matrix(pattern: BlockPattern, conn: np.ndarray, positions: np.ndarray,
                       element_matrices: np.ndarray, values: np.ndarray, backend: str = "c"):
    """Add element matrices ``(ne, 3npe, 3npe)`` into the CSR ``values`` of ``pattern``."""
    conn = np.ascontiguousarray(conn, dtype=np.int64)
    ne, npe = conn.shape
    ke = np.ascontiguousarray(element_matrices, dtype=np.float64)
    if ke.shape != (ne, 3 * npe, 3 * npe):
        raise ValueError(f"element matrices have shape {ke.shape}, expected {(ne, 3*npe, 3*npe)}")
    if values.shape != (pattern.nvalues,) or not values.flags.c_contiguous:
        raise ValueError("values must be a contiguous array of the pattern's size")
    if backend == "c" and values.dtype == np.float64:
        pos = np.ascontiguousarray(positions, dtype=np.int32)
        bptr = np.ascontiguousarray(pattern.bptr, dtype=np.int64)
        _library().petsoft_scatter_add_matrix(ne, npe, addr(conn), addr(pos), addr(bptr),
                                              addr(ke), addr(values))
        return
    r = conn[:, :, None]                                   # (ne, a, 1)
    row0 = pattern.bptr[r]
    stride = 3 * (pattern.bptr[r + 1] - row0)              # (ne, a, 1)
    base = 9 * row0 + 3 * (positions - row0)               # (ne, a, b)
    i = np.arange(3)[None, None, :, None, None]
    j = np.arange(3)[None, None, None, None, :]
    dest = base[:, :, None, :, None] + i * stride[:, :, :, None, None] + j
    values += np.bincount(dest.ravel(), weights=ke.reshape(ne, npe, 3, npe, 3).ravel(),
                          minlength=values.size)


def scatter_add_vector(conn: np.ndarray, element_vectors: np.ndarray, out: np.ndarray,
                       backend: str = "c"):
    """Add element vectors ``(ne, 3npe)`` (node-major) into the local dof array ``out``."""
    conn = np.ascontiguousarray(conn, dtype=np.int64)
    ne, npe = conn.shape
    fe = np.ascontiguousarray(element_vectors, dtype=np.float64).reshape(ne, 3 * npe)
    if backend == "c" and out.flags.c_contiguous and out.dtype == np.float64:
        _library().petsoft_scatter_add_vector(ne, npe, addr(conn), addr(fe), addr(out))
        return
    dofs = (3 * conn[:, :, None] + np.arange(3)).ravel()
    out += np.bincount(dofs, weights=fe.ravel(), minlength=out.size)
