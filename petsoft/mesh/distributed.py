"""The tetrahedral mesh distributed over MPI ranks (PETSc DMPlex) and its P1 vector dofs.

Every rank keeps the validated serial mesh (rank 0 reads it, the others receive it): regions,
boundary selections and output gathering are then simple vectorised lookups. DMPlex decides which
cells each rank assembles, which local vertices are ghosts, the global dof numbering, the matrix
preallocation and the local-to-global communication.

Numberings: *file* numbers are those of the validated :class:`~petsoft.mesh.serial.Mesh` (the user's
element and node numbers in messages and outputs); *local* numbers index this rank's arrays.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.mesh.ordering import cell_centroids, first_touch_order, morton_order
from petsoft.mesh.topology import exterior_faces


class DistributedMesh:
    """A tetrahedral mesh distributed with DMPlex, with 3 dofs per vertex (block size 3).

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
    dm : PETSc.DMPlex
        The distributed plex with its local section (3 dofs per vertex).
    cells : ndarray (ne, 4) int64
        Local connectivity of the cells this rank assembles.
    cell_ids : ndarray (ne,) int64
        File number of each local cell.
    vertex_ids : ndarray (nv,) int64
        File number of each local vertex (owned and ghost).
    points : ndarray (nv, 3)
        Reference coordinates of local vertices.
    owned : ndarray (nv,) bool
        Whether this rank owns each local vertex (each vertex is owned by exactly one rank).
    """

    def __init__(self, mesh, comm: PETSc.Comm | None = None):
        self.comm = comm if comm is not None else PETSc.COMM_WORLD
        mpi = self.comm.tompi4py()
        self.mesh = mesh = mpi.bcast(mesh if mpi.rank == 0 else None, root=0)
        ncells, nvert = len(mesh.tets), len(mesh.points)

        # Same deterministic reordering on every rank; only rank 0 hands cells to DMPlex.
        cell_perm = morton_order(cell_centroids(mesh.points, mesh.tets))
        sfc_tets = mesh.tets[cell_perm]
        vertex_perm = first_touch_order(sfc_tets, nvert)
        vertex_rank = np.empty(nvert, dtype=np.int64)
        vertex_rank[vertex_perm] = np.arange(nvert)
        plex_cells = vertex_rank[sfc_tets]
        if mpi.rank == 0:
            cells_in, coords_in = plex_cells.astype(PETSc.IntType), mesh.points[vertex_perm]
        else:
            cells_in, coords_in = np.zeros((0, 4), PETSc.IntType), np.zeros((0, 3))
        dm = PETSc.DMPlex().createFromCellList(3, cells_in, coords_in, interpolate=False,
                                               comm=self.comm)
        dm.setName("petsoft_mesh")
        partitioner = dm.getPartitioner()
        partitioner.setType(PETSc.Partitioner.Type.SIMPLE)  # cells are already SFC-ordered
        partitioner.setFromOptions()                         # -petscpartitioner_type overrides
        original_points = np.arange(*dm.getChart(), dtype=np.int64)
        migration = dm.distribute() if self.comm.size > 1 else None
        p_start, p_end = dm.getChart()
        if migration is not None:
            plex_point = np.full(p_end - p_start, -1, dtype=np.int64)
            migration.bcastBegin(MPI.INT64_T, original_points, plex_point, MPI.REPLACE)
            migration.bcastEnd(MPI.INT64_T, original_points, plex_point, MPI.REPLACE)
        else:
            plex_point = original_points
        c_start, c_end = dm.getHeightStratum(0)
        v_start, v_end = dm.getDepthStratum(0)
        sfc_cell = plex_point[c_start:c_end]                      # plex numbering before distribute
        plex_vertex = plex_point[v_start:v_end] - ncells
        self.cell_ids = cell_perm[sfc_cell]
        self.vertex_ids = vertex_perm[plex_vertex]
        local_of_plex_vertex = np.full(nvert, -1, dtype=np.int64)
        local_of_plex_vertex[plex_vertex] = np.arange(v_end - v_start)
        self.cells = local_of_plex_vertex[plex_cells[sfc_cell]]
        if self.cells.size and self.cells.min() < 0:
            raise RuntimeError("distributed mesh lost a vertex of a local cell")
        self.points = mesh.points[self.vertex_ids]

        # DMPlexCreateSection leaves an uninterpolated plex with no dofs (3.18), so the section is
        # filled point by point; this runs once per mesh, at ~0.3 us per vertex.
        section = PETSc.Section().create(comm=self.comm)
        section.setNumFields(1)
        section.setFieldComponents(0, 3)
        section.setChart(p_start, p_end)
        for v in range(v_start, v_end):
            section.setDof(v, 3)
            section.setFieldDof(v, 0, 3)
        section.setUp()
        (dm.setLocalSection if hasattr(dm, "setLocalSection") else dm.setSection)(section)
        self.dm = dm
        self.nvertices = v_end - v_start
        self._global = dm.createGlobalVec()   # creates the global section the LGMap needs
        self._local = dm.createLocalVec()
        self.lgmap = dm.getLGMap()
        lo, hi = self._global.getOwnershipRange()
        first_dof = self.lgmap.apply(3 * np.arange(self.nvertices, dtype=PETSc.IntType))
        self.owned = (first_dof >= lo) & (first_dof < hi)
        self.global_dof = np.asarray(first_dof, dtype=np.int64)[:, None] + np.arange(3)
        self.nglobal_vertices = nvert
        self.file_to_local = np.full(nvert, -1, dtype=np.int64)
        self.file_to_local[self.vertex_ids] = np.arange(self.nvertices)
        self._exterior = None
        self._volumes = None

    # -- vectors -------------------------------------------------------------------------------
    def create_global_vec(self) -> PETSc.Vec:
        """A new global (owned dofs) vector of block size 3."""
        return self.dm.createGlobalVec()

    def create_local_vec(self) -> PETSc.Vec:
        """A new local (owned + ghost dofs) vector."""
        return self.dm.createLocalVec()

    def to_local(self, gvec: PETSc.Vec, out: np.ndarray | None = None) -> np.ndarray:
        """Values of a global vector at the local vertices, as an (nv, 3) array."""
        self.dm.globalToLocal(gvec, self._local, addv=PETSc.InsertMode.INSERT_VALUES)
        arr = self._local.getArray(readonly=True).reshape(-1, 3)
        if out is None:
            return arr.copy()
        out[...] = arr
        return out

    def add_to_global(self, local_values: np.ndarray, gvec: PETSc.Vec) -> None:
        """Add local (nv, 3) contributions, ghosts included, into a global vector."""
        self._local.getArray()[:] = np.asarray(local_values).ravel()
        self.dm.localToGlobal(self._local, gvec, addv=PETSc.InsertMode.ADD_VALUES)

    def set_global_from_local(self, local_values: np.ndarray, gvec: PETSc.Vec) -> None:
        """Set a global vector from consistent local values (owned entries are used)."""
        self._local.getArray()[:] = np.asarray(local_values).ravel()
        self.dm.localToGlobal(self._local, gvec, addv=PETSc.InsertMode.INSERT_VALUES)

    def from_file_field(self, field: np.ndarray, gvec: PETSc.Vec | None = None) -> PETSc.Vec:
        """A global vector from a (N, 3) field given in file numbering (on every rank)."""
        gvec = gvec if gvec is not None else self.create_global_vec()
        self.set_global_from_local(np.asarray(field)[self.vertex_ids], gvec)
        return gvec

    def gather(self, local_values: np.ndarray, root: int = 0) -> np.ndarray | None:
        """Gather a per-vertex local field (nv, k) to ``root`` in file numbering."""
        mpi = self.comm.tompi4py()
        local_values = np.asarray(local_values)
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
            X = self.points[self.cells]
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
