"""The tetrahedral mesh distributed over MPI ranks, and its vector dofs (3 per node).

The nodes are the mesh's vertices for 4-node (P1) tetrahedra, and the vertices and edge nodes for
10-node (P2) ones (:attr:`~petsoft.mesh.serial.Mesh.cells`); "vertex" below means any node.

Every rank keeps the validated serial mesh (rank 0 reads it, the others receive it): regions,
boundary selections and output gathering are then simple vectorised lookups, and every rank can
compute the whole distribution itself, the same on all ranks, with no further communication:

* cells are sorted along a Morton curve of their centroids and cut into equal contiguous chunks,
  one per rank (compact subdomains with short interfaces; :mod:`petsoft.mesh.ordering`);
* vertices are numbered globally in order of first appearance along that curve; a vertex belongs
  to the rank of the first cell that touches it, so each rank owns a contiguous range of global
  numbers, and every ghost vertex of a rank is owned by a lower rank;
* a rank's local vertices are its owned ones (in global order) followed by its ghosts.

One PETSc scatter moves dofs between global vectors and local arrays. This replaced a DMPlex
(built from the cell list, distributed, given a section point by point, asked for every matrix's
preallocation): 2.5 s of set-up at 384k tets on 2 ranks, where this takes well under a second.

Numberings: *file* numbers are those of the validated :class:`~petsoft.mesh.serial.Mesh` (the user's
element and node numbers in messages and outputs); *local* numbers index this rank's arrays.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.mesh.ordering import cell_morton_order, first_touch
from petsoft.mesh.topology import exterior_faces


class DistributedMesh:
    """A tetrahedral mesh distributed over the ranks of ``comm``, 3 dofs per vertex (block size 3).

    Parameters
    ----------
    mesh : petsoft.mesh.serial.Mesh or None
        The validated mesh; needed on rank 0 only (other ranks may pass None).
    comm : PETSc.Comm, optional
        Communicator (default ``PETSC_COMM_WORLD``).

    Attributes
    ----------
    mesh : Mesh
        The full serial mesh (on every rank).
    cells : ndarray (ne, 4) or (ne, 10) int64
        Local connectivity of the cells this rank assembles (corners first).
    order : int
        Element order, 1 or 2.
    cell_ids : ndarray (ne,) int64
        File number of each local cell.
    vertex_ids : ndarray (nv,) int64
        File number of each local vertex (owned first, then ghosts).
    points : ndarray (nv, 3)
        Reference coordinates of local vertices.
    owned : ndarray (nv,) bool
        Whether this rank owns each local vertex (each vertex is owned by exactly one rank).
    global_dof : ndarray (nv, 3) int64
        Global dof numbers of each local vertex's three components.
    lgmap : PETSc.LGMap
        Local to global dof map (block size 3) for matrices assembled with local indices.
    """

    def __init__(self, mesh, comm: PETSc.Comm | None = None):
        self.comm = comm if comm is not None else PETSc.COMM_WORLD
        mpi = self.comm.tompi4py()
        if mpi.size > 1:     # (a broadcast to oneself still pickles the mesh: 0.07 s at 1M tets)
            mesh = mpi.bcast(mesh if mpi.rank == 0 else None, root=0)
        self.mesh = mesh
        ncells, nvert = len(mesh.tets), len(mesh.points)
        size, rank = mpi.size, mpi.rank
        self.order = mesh.order

        cell_perm = cell_morton_order(mesh.points, mesh.tets)
        sfc_tets = mesh.cells[cell_perm]
        # global vertex g = vertex_perm[g] in file numbers, first touched by cell first_cell[g]
        vertex_perm, first_cell = first_touch(sfc_tets, nvert)
        global_of_file = np.empty(nvert, dtype=np.int64)
        global_of_file[vertex_perm] = np.arange(nvert)
        # equal contiguous chunks of the curve (sizes differ by at most one cell)
        bounds = (ncells * np.arange(size + 1, dtype=np.int64)) // size
        # vertices owned by each rank: those first touched in its chunk (vertices in no cell,
        # numbered last, go to the last rank)
        vstart = np.searchsorted(first_cell, bounds[:-1], side="left")
        vstart[0] = 0
        vend = np.append(vstart[1:], nvert)
        lo, hi = int(vstart[rank]), int(vend[rank])
        c0, c1 = int(bounds[rank]), int(bounds[rank + 1])
        local_cells_global = global_of_file[sfc_tets[c0:c1]]
        if size == 1:
            # one rank: no ghosts, the local numbering is the global one (two passes over the
            # cells fewer: 0.05 s at 1M tets)
            global_of_local = np.arange(nvert, dtype=np.int64)
            self.cells = local_cells_global
        else:
            touched = np.zeros(nvert, dtype=bool)
            touched[local_cells_global.ravel()] = True
            ghosts = np.flatnonzero(touched[:lo])  # owned by lower ranks (first touched earlier)
            global_of_local = np.concatenate([np.arange(lo, hi, dtype=np.int64), ghosts])
            local_of_global = np.full(nvert, -1, dtype=np.int64)
            local_of_global[global_of_local] = np.arange(len(global_of_local))
            self.cells = local_of_global[local_cells_global]
            if self.cells.size and self.cells.min() < 0:
                raise RuntimeError("distributed mesh lost a vertex of a local cell")
        self.cell_ids = cell_perm[c0:c1]
        self.vertex_ids = vertex_perm[global_of_local]
        self.points = mesh.points[self.vertex_ids]
        self.nvertices = len(global_of_local)
        self.nowned = hi - lo
        #: global numbers [start, stop) of the vertices this rank owns
        self.owned_range = (lo, hi)
        self.owned = np.arange(self.nvertices) < self.nowned
        self.global_vertex = global_of_local
        self.global_dof = 3 * global_of_local[:, None] + np.arange(3)
        self.nglobal_vertices = nvert

        self._global = PETSc.Vec().createMPI((3 * self.nowned, 3 * nvert), bsize=3,
                                             comm=self.comm)
        self._local = PETSc.Vec().createSeq(3 * self.nvertices, bsize=3, comm=PETSc.COMM_SELF)
        where = PETSc.IS().createBlock(3, global_of_local.astype(PETSc.IntType),
                                       comm=PETSc.COMM_SELF)
        self._scatter = PETSc.Scatter().create(self._global, where, self._local, None)
        where.destroy()
        self.lgmap = PETSc.LGMap().create(global_of_local.astype(PETSc.IntType), bsize=3,
                                          comm=self.comm)
        self.file_to_local = np.full(nvert, -1, dtype=np.int64)
        self.file_to_local[self.vertex_ids] = np.arange(self.nvertices)
        self._exterior = None
        self._volumes = None

    # -- vectors -------------------------------------------------------------------------------
    def create_global_vec(self) -> PETSc.Vec:
        """A new global (owned dofs) vector of block size 3."""
        return self._global.duplicate()

    def create_local_vec(self) -> PETSc.Vec:
        """A new local (owned + ghost dofs) vector."""
        return self._local.duplicate()

    def to_local(self, gvec: PETSc.Vec, out: np.ndarray | None = None) -> np.ndarray:
        """Values of a global vector at the local vertices, as an (nv, 3) array."""
        self._scatter.scatter(gvec, self._local, PETSc.InsertMode.INSERT_VALUES,
                              PETSc.ScatterMode.FORWARD)
        arr = self._local.getArray(readonly=True).reshape(-1, 3)
        if out is None:
            return arr.copy()
        out[...] = arr
        return out

    def add_to_global(self, local_values: np.ndarray, gvec: PETSc.Vec) -> None:
        """Add local (nv, 3) contributions, ghosts included, into a global vector."""
        self._local.getArray()[:] = np.asarray(local_values).ravel()
        self._scatter.scatter(self._local, gvec, PETSc.InsertMode.ADD_VALUES,
                              PETSc.ScatterMode.REVERSE)

    def set_global_from_local(self, local_values: np.ndarray, gvec: PETSc.Vec) -> None:
        """Set a global vector from consistent local values (owned entries are used)."""
        # the owned vertices come first, in the global vector's order
        gvec.getArray()[:] = np.asarray(local_values).reshape(-1)[:3 * self.nowned]

    def from_file_field(self, field: np.ndarray, gvec: PETSc.Vec | None = None) -> PETSc.Vec:
        """A global vector from a (N, 3) field given in file numbering (on every rank)."""
        gvec = gvec if gvec is not None else self.create_global_vec()
        self.set_global_from_local(np.asarray(field)[self.vertex_ids], gvec)
        return gvec

    def gather(self, local_values: np.ndarray, root: int = 0) -> np.ndarray | None:
        """Gather a per-vertex local field (nv, k) to ``root`` in file numbering."""
        mpi = self.comm.tompi4py()
        local_values = np.asarray(local_values)
        if mpi.size == 1:
            # no message: the pickled gather of one part cost ~0.1 ms a call (two a frame)
            out = np.empty((self.nglobal_vertices,) + local_values.shape[1:], local_values.dtype)
            out[self.vertex_ids] = local_values
            return out
        parts = mpi.gather((self.vertex_ids[self.owned], local_values[self.owned]), root=root)
        if mpi.rank != root:
            return None
        out = np.empty((self.nglobal_vertices,) + local_values.shape[1:], local_values.dtype)
        for ids, vals in parts:
            out[ids] = vals
        return out

    def gather_global(self, gvec: PETSc.Vec, root: int = 0) -> np.ndarray | None:
        """Gather a global dof vector to ``root`` as (N, 3) in file numbering."""
        return self.gather(self.to_local(gvec), root=root)

    # -- geometry ------------------------------------------------------------------------------
    @property
    def cell_volumes(self) -> np.ndarray:
        """(ne,) reference volumes of the local cells."""
        if self._volumes is None:
            X = self.points[self.cells[:, :4]]
            self._volumes = np.einsum("ij,ij->i", np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]),
                                      X[:, 3] - X[:, 0]) / 6.0
        return self._volumes

    @property
    def exterior(self) -> tuple[np.ndarray, np.ndarray]:
        """Exterior faces of the whole mesh (file numbering) and the cell holding each."""
        if self._exterior is None:
            self._exterior = exterior_faces(self.mesh.tets)
        return self._exterior

    def local_cells_mask(self, file_cells: np.ndarray) -> np.ndarray:
        """Which of the given file cell numbers are assembled on this rank."""
        mine = np.zeros(len(self.mesh.tets), dtype=bool)
        mine[self.cell_ids] = True
        return mine[np.asarray(file_cells, dtype=np.int64)]

    def rigid_body_modes(self) -> PETSc.NullSpace:
        """The six rigid-body modes (near-nullspace for algebraic multigrid)."""
        coords = self.create_global_vec()
        self.set_global_from_local(self.points, coords)
        coords.setBlockSize(3)
        modes = PETSc.NullSpace().createRigidBody(coords)
        coords.destroy()
        return modes

    def allreduce_sum(self, value: float) -> float:
        return self.comm.tompi4py().allreduce(float(value), op=MPI.SUM)
