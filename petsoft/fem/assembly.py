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

from petsoft.fem.kernels.scatter import (
    BlockPattern,
    block_pattern,
    block_rows,
    scalar_csr,
    scatter_add_matrix,
)
from petsoft.fem.matrix_values import ParallelValues, copy_into_seqaij

#: The attribute naming the pattern a sequential matrix was made with (its values can be copied).
_PATTERN = "petsoft_pattern"
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
        self._owned_csr = None     # the owned rows' global CSR, in parallel (computed once)
        self._parallel = None      # ParallelValues of the parallel matrices (at first finish)

    def create_matrix(self) -> PETSc.Mat:
        """A new AIJ matrix (block size 3; serially 1: petsc4py 3.18's ``createAIJWithArrays``
        drops it, and setting it afterwards changed nothing measurable for GAMG on a 27,300-dof
        step) with exactly this pattern's nonzeros.

        Serially the matrix is made on the pattern's own arrays; in parallel from the CSR of
        its owned rows (:func:`owned_rows_csr`, computed once per assembler), which PETSc takes
        with explicit zeros in one call (``MatMPIAIJSetPreallocationCSR``). PETSc's
        ``DMCreateMatrix`` redid its own preallocation for every matrix (0.8 s a matrix at 384k
        tets, more than the distribution and the pattern); zeros inserted through
        ``MatSetValuesLocal`` searched every entry and sent the ghost rows' (0.4 s a matrix at
        1M tets on 2 ranks).
        """
        if self.dmesh.comm.size == 1:
            # PETSc uses the arrays as they are (no copy of the pattern; petsc4py keeps them
            # alive with the matrix): the structure is shared, the values are the matrix's own.
            # Serially the local numbering is the global one.
            n = 3 * self.dmesh.nvertices
            A = PETSc.Mat().createAIJWithArrays(
                (n, n), (self.pattern.indptr, self.pattern.indices,
                         np.zeros(len(self.pattern.indices))), bsize=3, comm=self.dmesh.comm)
        else:
            if self._owned_csr is None:
                self._owned_csr = owned_rows_csr(self.dmesh, self.pattern)
            n = 3 * self.dmesh.nowned
            A = PETSc.Mat().create(comm=self.dmesh.comm)
            A.setSizes(((n, PETSc.DETERMINE), (n, PETSc.DETERMINE)), bsize=3)
            A.setType(PETSc.Mat.Type.AIJ)
            # every entry of the pattern present (explicit zeros, assembled), as a matrix from
            # DMCreateMatrix had: one may be copied or combined with another before its first
            # assembly
            A.setPreallocationCSR(self._owned_csr)
        A.setAttr(_PATTERN, self.pattern)
        A.setLGMap(self.dmesh.lgmap, self.dmesh.lgmap)
        A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        A.setOption(PETSc.Mat.Option.KEEP_NONZERO_PATTERN, True)
        A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        return A

    def _parallel_values(self, A: PETSc.Mat) -> ParallelValues:
        """Where this rank's values go in the matrices of :meth:`create_matrix` (all alike),
        found at the first :meth:`finish` (collective)."""
        if self._parallel is None:
            self._parallel = ParallelValues(A, self.pattern.indptr, self.pattern.indices,
                                            self.dmesh.global_dof.ravel(),
                                            3 * self.dmesh.nowned)
        return self._parallel

    def begin(self) -> None:
        """Start a new assembly (zero the local values)."""
        self.values[:] = 0.0

    def add(self, name: str, element_matrices: np.ndarray, start: int = 0) -> None:
        """Add matrices of elements ``start:start+len(element_matrices)`` of set ``name``."""
        stop = start + len(element_matrices)
        scatter_add_matrix(self.pattern, self.connectivity[name][start:stop],
                           self.positions[name][start:stop], element_matrices, self.values)

    def finish(self, A: PETSc.Mat) -> PETSc.Mat:
        """Replace the entries of ``A`` by the assembled values (sums over ranks).

        A sequential matrix made by :meth:`create_matrix` has this pattern as its structure:
        the values are copied into its array (:mod:`petsoft.fem.matrix_values`), 100x faster
        than inserting them; other matrices get them through ``MatSetValuesLocal``.
        """
        if A.getAttr(_PATTERN) is self.pattern:
            if self.dmesh.comm.size == 1:
                if copy_into_seqaij(A, self.values):
                    return A
            elif self._parallel_values(A).write(A, self.values):
                return A
        A.zeroEntries()
        A.setValuesLocalCSR(self.pattern.indptr, self.pattern.indices, self.values,
                            addv=PETSc.InsertMode.ADD_VALUES)
        A.assemble()
        return A


def owned_rows_csr(dmesh, pattern: BlockPattern) -> tuple[np.ndarray, np.ndarray]:
    """(indptr, indices): the scalar CSR of the rows this rank owns in a parallel matrix of the
    ranks' local patterns, with global column numbers, sorted (PETSc's
    ``MatMPIAIJSetPreallocationCSR``).

    Every local block row (owned or ghost vertex), in global numbering, goes to the rank owning
    its vertex, which takes the distinct columns of each of its rows (the union of what it
    receives, by :func:`~petsoft.fem.kernels.scatter.block_rows` on the received pairs: the
    pattern is symmetric, so a pair (row, column) as a two-vertex element adds nothing else).
    """
    gblock = np.asarray(dmesh.global_vertex, dtype=np.int64)
    mpi = dmesh.comm.tompi4py()
    lo, hi = dmesh.owned_range
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
    pairs = np.empty((int(recv_counts.sum()), 2), dtype=np.int64)
    mpi.Alltoallv([send, 2 * counts, MPI.INT64_T], [pairs, 2 * recv_counts, MPI.INT64_T])
    bptr, bcol = block_rows(nglobal, [pairs], np.arange(lo, hi, dtype=np.int64))
    # block column c becomes the global scalar columns 3c, 3c+1, 3c+2 (scalar_csr's default)
    return scalar_csr(bptr, bcol, PETSc.IntType)
