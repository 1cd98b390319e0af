"""Matrix assembly: element matrices into a preallocated PETSc matrix with a fixed pattern.

The pattern (3x3 blocks of the local vertex graph) and every element block's position in it are
computed once. Each assembly zeroes a value array, lets the physics terms scatter their element
matrices into it (compiled, search-free), and hands PETSc the whole local CSR in one call; PETSc
then only communicates the rows of ghost vertices to their owners.
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from petsoft.fem.kernels.scatter import block_pattern, scatter_add_matrix

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

    def create_matrix(self) -> PETSc.Mat:
        """A new matrix preallocated for this pattern (block size 3)."""
        A = self.dmesh.dm.createMatrix()
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
