"""Matrix assembly: element matrices into a preallocated PETSc matrix with a fixed pattern.

The pattern (3x3 blocks of the local vertex graph) and every element block's position in it are
computed once. Each assembly zeroes a value array, lets the physics terms scatter their element
matrices into it (compiled, search-free), and hands PETSc the whole local CSR in one call; PETSc
then only communicates the rows of ghost vertices to their owners.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.fem.kernels.scatter import BlockPattern, block_pattern, scalar_csr, scatter_add_matrix

CHUNK = 16384  # elements per kernel call: keeps element-matrix buffers in cache-sized pieces


class MatrixAssembler:
    """Owns the sparsity pattern of some element sets over the local vertices.

    Parameters
    ----------
    dmesh : DistributedMesh
    connectivities : dict[str, ndarray (ne, npe)]
        Named element sets (local vertex indices) whose matrices will be added.
    """

    def __init__(self, dmesh, connectivities: dict[str, np.ndarray]):
        self.dmesh = dmesh
        names = list(connectivities)
        self.pattern, positions = block_pattern(
            dmesh.nvertices, [connectivities[n] for n in names], PETSc.IntType)
        self.connectivity = {n: np.ascontiguousarray(connectivities[n], np.int64) for n in names}
        self.positions = dict(zip(names, positions, strict=True))
        self.values = np.zeros(self.pattern.nvalues)
        self._owned_csr = None     # (serially the pattern's own arrays: no copy)

    def create_matrix(self) -> PETSc.Mat:
        """A new AIJ matrix (block size 3) with exactly this pattern's nonzeros.

        The owned rows' pattern in global numbering is computed once per assembler (the rows of
        ghost vertices go to their owners) and every matrix is preallocated from it: PETSc's
        ``DMCreateMatrix`` redid its own preallocation for every matrix, 0.8 s a matrix at
        384k tets, more than the distribution and the pattern together.
        """
        if self._owned_csr is None:
            self._owned_csr = owned_rows_csr(self.dmesh, self.pattern)
        indptr, indices = self._owned_csr
        n = len(indptr) - 1
        if self.dmesh.comm.size == 1:
            # PETSc uses the arrays as they are (no copy of the pattern; petsc4py keeps them
            # alive with the matrix): the structure is shared, the values are the matrix's own
            A = PETSc.Mat().createAIJWithArrays((n, n), (indptr, indices, np.zeros(len(indices))),
                                                bsize=3, comm=self.dmesh.comm)
        else:
            A = PETSc.Mat().create(comm=self.dmesh.comm)
            A.setSizes(((n, PETSc.DETERMINE), (n, PETSc.DETERMINE)), bsize=3)
            A.setType(PETSc.Mat.Type.AIJ)
            A.setPreallocationCSR((indptr, indices))
        A.setLGMap(self.dmesh.lgmap, self.dmesh.lgmap)
        A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        A.setOption(PETSc.Mat.Option.KEEP_NONZERO_PATTERN, True)
        A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        return A

    def begin(self) -> None:
        """Start a new assembly (zero the local values)."""
        self.values[:] = 0.0

    def add(self, name: str, element_matrices: np.ndarray, start: int = 0) -> None:
        """Add matrices of elements ``start:start+len(element_matrices)`` of set ``name``."""
        stop = start + len(element_matrices)
        scatter_add_matrix(self.pattern, self.connectivity[name][start:stop],
                           self.positions[name][start:stop], element_matrices, self.values)

    def finish(self, A: PETSc.Mat) -> PETSc.Mat:
        """Replace the entries of ``A`` by the assembled values (sums over ranks)."""
        A.zeroEntries()
        A.setValuesLocalCSR(self.pattern.indptr, self.pattern.indices, self.values,
                            addv=PETSc.InsertMode.ADD_VALUES)
        A.assemble()
        return A


def owned_rows_csr(dmesh, pattern: BlockPattern) -> tuple[np.ndarray, np.ndarray]:
    """(indptr, indices): the scalar CSR, in global numbering, of the rows this rank owns.

    Every local block row (owned or ghost vertex) is mapped to global block numbers and sent to
    the rank owning its vertex, which takes the union of what it receives. In serial the local
    numbering is the global one and the local pattern is returned as it is.
    """
    first = np.asarray(dmesh.global_dof[:, 0], dtype=np.int64)
    gblock = first // 3                              # the global vertex of each local vertex
    mpi = dmesh.comm.tompi4py()
    if mpi.size == 1 and np.array_equal(gblock, np.arange(len(gblock))):
        return pattern.indptr, pattern.indices
    lo, hi = (x // 3 for x in dmesh._global.getOwnershipRange())
    nglobal = dmesh.nglobal_vertices
    rows = np.repeat(gblock, np.diff(pattern.bptr))
    cols = gblock[pattern.bcol]
    starts = np.array(mpi.allgather(lo) + [nglobal], dtype=np.int64)
    owner = np.searchsorted(starts, rows, side="right") - 1
    order = np.argsort(owner, kind="stable")
    send = np.ascontiguousarray(np.column_stack([rows, cols])[order])
    counts = np.bincount(owner, minlength=mpi.size).astype(np.int64)
    recv_counts = np.empty_like(counts)
    mpi.Alltoall(counts, recv_counts)
    recv = np.empty((int(recv_counts.sum()), 2), dtype=np.int64)
    mpi.Alltoallv([send, 2 * counts, MPI.INT64_T], [recv, 2 * recv_counts, MPI.INT64_T])
    keys = np.unique((recv[:, 0] - lo) * nglobal + recv[:, 1])
    bptr = np.zeros(hi - lo + 1, dtype=np.int64)
    np.cumsum(np.bincount(keys // nglobal, minlength=hi - lo), out=bptr[1:])
    return scalar_csr(bptr, keys % nglobal, PETSc.IntType)
