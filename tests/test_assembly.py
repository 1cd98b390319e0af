"""Assembly: compiled scatter against numpy, the distributed mesh, mass matrices and loads."""

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.fem.assembly import MatrixAssembler
from petsoft.fem.kernels.scatter import (
    block_pattern,
    csr_find,
    scatter_add_matrix,
    scatter_add_vector,
)
from petsoft.mesh.distributed import DistributedMesh
from petsoft.mesh.serial import box_mesh
from petsoft.physics.loads import consistent_mass_matrices, gravity_forces, lumped_masses


def test_scatter_c_equals_numpy_and_dense_reference():
    """The compiled CSR scatter equals the numpy scatter and a dense assembly."""
    rng = np.random.default_rng(0)
    nv, ne = 30, 50
    conn = np.array([rng.choice(nv, 4, replace=False) for _ in range(ne)])
    pattern, (pos,) = block_pattern(nv, [conn])
    ke = rng.standard_normal((ne, 12, 12))
    vals_c = np.zeros(pattern.nvalues)
    vals_np = np.zeros(pattern.nvalues)
    scatter_add_matrix(pattern, conn, pos, ke, vals_c, backend="c")
    scatter_add_matrix(pattern, conn, pos, ke, vals_np, backend="numpy")
    np.testing.assert_allclose(vals_c, vals_np, rtol=0, atol=1e-13)
    dense = np.zeros((3 * nv, 3 * nv))
    dofs = (3 * conn[:, :, None] + np.arange(3)).reshape(ne, 12)
    for e in range(ne):  # the independent (slow) reference
        dense[np.ix_(dofs[e], dofs[e])] += ke[e]
    from_csr = np.zeros_like(dense)
    for r in range(3 * nv):
        cols = pattern.indices[pattern.indptr[r]:pattern.indptr[r + 1]]
        from_csr[r, cols] = vals_c[pattern.indptr[r]:pattern.indptr[r + 1]]
    np.testing.assert_allclose(from_csr, dense, atol=1e-12)
    fe = rng.standard_normal((ne, 12))
    out_c, out_np = np.zeros(3 * nv), np.zeros(3 * nv)
    scatter_add_vector(conn, fe, out_c, backend="c")
    scatter_add_vector(conn, fe, out_np, backend="numpy")
    np.testing.assert_allclose(out_c, out_np, atol=1e-13)


@pytest.mark.parametrize("dtype", [np.int32, np.int64])
def test_compiled_block_pattern_equals_the_numpy_reference(dtype):
    """Several element sets of different sizes (tets, springs, triangles; repeated vertices
    across sets, an unused vertex, an empty set): the compiled pattern, scalar CSR and block
    positions equal the numpy reference's."""
    rng = np.random.default_rng(1)
    nv = 40
    sets = [np.array([rng.choice(nv - 1, 4, replace=False) for _ in range(60)]),
            np.array([rng.choice(nv - 1, 2, replace=False) for _ in range(25)]),
            np.zeros((0, 3), dtype=np.int64),
            np.array([rng.choice(nv - 1, 3, replace=False) for _ in range(10)])]
    got, pos_c = block_pattern(nv, sets, dtype)
    ref, pos_np = block_pattern(nv, sets, dtype, backend="numpy")
    for name in ("bptr", "bcol", "indptr", "indices"):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)
    assert got.indptr.dtype == dtype and got.indices.dtype == dtype
    for a, b in zip(pos_c, pos_np, strict=True):
        np.testing.assert_array_equal(a, b)
    assert got.bptr[-1] == got.bptr[-2]        # the unused last vertex has an empty row


def test_block_pattern_of_long_rows_equals_the_numpy_reference():
    """Rows longer than the compiled builder's first guess (16 a row: its buffer grows) and
    than its insertion sort (64: qsort): every pair of 90 vertices as a spring, and a hub."""
    nv = 90
    pairs = np.array([(i, j) for i in range(nv) for j in range(i + 1, nv)])
    hub = np.column_stack([np.zeros(nv - 1, dtype=np.int64), np.arange(1, nv)])
    for sets in ([pairs[::-1]], [hub, pairs[:5]]):
        got, pos_c = block_pattern(nv, sets)
        ref, pos_np = block_pattern(nv, sets, backend="numpy")
        for name in ("bptr", "bcol", "indptr", "indices"):
            np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)
        for a, b in zip(pos_c, pos_np, strict=True):
            np.testing.assert_array_equal(a, b)
    assert got.bptr[1] == nv                   # the hub's row holds every vertex


def test_csr_find_equals_a_search_of_every_entry():
    """csr_find against the definition (a search of row * ncols + column in the sorted keys):
    present entries, absent columns, rows out of range and empty rows give -1."""
    rng = np.random.default_rng(3)
    nrows, ncols = 50, 70
    rows = [np.sort(rng.choice(ncols, rng.integers(0, 12), replace=False)) for _ in range(nrows)]
    ai = np.r_[0, np.cumsum([len(r) for r in rows])]
    aj = np.concatenate(rows)
    qr = rng.integers(-2, nrows + 2, size=2000)
    qc = rng.integers(0, ncols, size=2000)
    keys = np.repeat(np.arange(nrows), np.diff(ai)) * ncols + aj
    at = np.searchsorted(keys, qr * ncols + qc)
    want = np.where((qr >= 0) & (qr < nrows) & (at < len(keys))
                    & (keys[np.minimum(at, len(keys) - 1)] == qr * ncols + qc), at, -1)
    got = csr_find(ai, aj, qr, qc)
    np.testing.assert_array_equal(got, want)
    assert (got >= 0).sum() > 100 and (got < 0).sum() > 100     # both kinds were asked


@pytest.fixture(scope="module")
def dmesh():
    mesh = box_mesh([1.0, 0.5, 0.25], [6, 4, 3]) if MPI.COMM_WORLD.rank == 0 else None
    return DistributedMesh(mesh)


def test_distributed_mesh_partitions_cells_and_vertices(dmesh):
    """Every cell is assembled by one rank, every vertex owned by one, coordinates consistent."""
    comm = MPI.COMM_WORLD
    ncells = comm.allreduce(len(dmesh.cells))
    assert ncells == len(dmesh.mesh.tets)
    all_cells = np.sort(np.concatenate(comm.allgather(dmesh.cell_ids)))
    np.testing.assert_array_equal(all_cells, np.arange(len(dmesh.mesh.tets)))
    assert comm.allreduce(int(dmesh.owned.sum())) == len(dmesh.mesh.points)
    np.testing.assert_array_equal(dmesh.points, dmesh.mesh.points[dmesh.vertex_ids])
    np.testing.assert_array_equal(dmesh.mesh.tets[dmesh.cell_ids],
                                  dmesh.vertex_ids[dmesh.cells])
    # owned vertices first, a contiguous range of global numbers; ghosts owned by lower ranks
    lo, hi = (x // 3 for x in dmesh.create_global_vec().getOwnershipRange())
    np.testing.assert_array_equal(dmesh.global_dof[dmesh.owned, 0] // 3, np.arange(lo, hi))
    assert np.all(dmesh.global_dof[~dmesh.owned, 0] // 3 < lo)
    # the scatter: a global vector holding each dof's global number arrives at every local copy
    g = dmesh.create_global_vec()
    g.setArray(np.arange(3 * lo, 3 * hi, dtype=float))
    np.testing.assert_array_equal(dmesh.to_local(g), dmesh.global_dof)
    gathered = dmesh.gather(dmesh.points)
    if comm.rank == 0:
        np.testing.assert_array_equal(gathered, dmesh.mesh.points)


def test_consistent_and_lumped_mass(dmesh):
    """Consistent mass: total mass rho*V on each axis, SPD, row sums equal the lumped masses."""
    rho = 1100.0 * np.ones(len(dmesh.cells))
    asm = MatrixAssembler(dmesh, {"cells": dmesh.cells})
    M = asm.create_matrix()
    asm.begin()
    asm.add("cells", consistent_mass_matrices(dmesh, rho))
    asm.finish(M)
    ones = dmesh.create_global_vec()
    ones.set(1.0)
    ex = dmesh.create_global_vec()
    dmesh.set_global_from_local(np.tile([1.0, 0.0, 0.0], (dmesh.nvertices, 1)), ex)
    Mex = ex.duplicate()
    M.mult(ex, Mex)
    volume = 1.0 * 0.5 * 0.25
    assert ex.dot(Mex) == pytest.approx(1100.0 * volume, rel=1e-12)
    lumped = dmesh.create_global_vec()
    lumped.zeroEntries()
    dmesh.add_to_global(np.repeat(lumped_masses(dmesh, rho)[:, None], 3, axis=1), lumped)
    rowsum = ones.duplicate()
    M.mult(ones, rowsum)
    assert (rowsum - lumped).norm() <= 1e-12 * lumped.norm()
    assert lumped.sum() == pytest.approx(3 * 1100.0 * volume, rel=1e-12)
    # smallest eigenvalue of the consistent mass of a tet is rho V / 20 > 0: M is SPD
    x = dmesh.create_global_vec()
    x.setRandom()
    Mx = x.duplicate()
    M.mult(x, Mx)
    assert x.dot(Mx) > 0
    M.destroy()


def test_gravity_load_totals_weight(dmesh):
    """Nodal gravity forces sum to rho * V * g."""
    rho = 2.0 * np.ones(len(dmesh.cells))
    f = dmesh.create_global_vec()
    f.zeroEntries()
    dmesh.add_to_global(gravity_forces(dmesh, rho, [0.0, 0.0, -9.81]), f)
    arr = f.getArray().reshape(-1, 3)
    total = MPI.COMM_WORLD.allreduce(arr.sum(axis=0))
    np.testing.assert_allclose(total, [0, 0, -9.81 * 2.0 * 0.125], atol=1e-12)


def test_assembler_matches_elementwise_petsc_insertion(dmesh):
    """The CSR path gives the same matrix as PETSc's element-by-element blocked insertion."""
    rng = np.random.default_rng(MPI.COMM_WORLD.rank)
    ke = rng.standard_normal((len(dmesh.cells), 12, 12))
    asm = MatrixAssembler(dmesh, {"cells": dmesh.cells})
    A = asm.create_matrix()
    asm.begin()
    asm.add("cells", ke)
    asm.finish(A)
    n = 3 * int(dmesh.owned.sum())
    B = PETSc.Mat().createAIJ(((n, None), (n, None)), bsize=3, comm=dmesh.comm)
    B.setUp()
    B.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
    B.setLGMap(dmesh.lgmap, dmesh.lgmap)
    idx = dmesh.cells.astype(PETSc.IntType)
    B.setValuesBlockedLocalRCV(idx, idx, ke, addv=PETSc.InsertMode.ADD_VALUES)
    B.assemble()
    B.axpy(-1.0, A)
    assert B.norm() <= 1e-12 * A.norm()
    A.destroy()
    B.destroy()


def test_matrix_holds_exactly_the_whole_mesh_pattern(dmesh):
    """create_matrix on any number of ranks: assembled, every nonzero of the whole mesh's
    pattern (counted serially from the file mesh) and no other, allocated without mallocs."""
    A = MatrixAssembler(dmesh, {"cells": dmesh.cells}).create_matrix()
    whole, _ = block_pattern(len(dmesh.mesh.points), [dmesh.mesh.tets])
    info = A.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)
    assert A.assembled
    assert int(info["nz_used"]) == whole.nvalues
    assert int(info["mallocs"]) == 0
    A.destroy()


def test_parallel_values_leave_a_matrix_with_unreached_places_to_insertion(dmesh):
    """The in-place writer sets each place its rank owns a value of, and sets (not adds) the
    places only other ranks' values reach. A matrix with an entry beyond every rank's pattern
    (a place no value reaches, which an in-place write would leave stale) is refused: finish()
    inserts generically, the extra entry is zeroed, the rest equals the inserted values."""
    if dmesh.comm.size == 1:
        pytest.skip("the parallel writer needs two ranks")
    rng = np.random.default_rng(5)
    asm = MatrixAssembler(dmesh, {"cells": dmesh.cells})
    A = asm.create_matrix()
    ref = asm.create_matrix()
    ref.setAttr("petsoft_pattern", None)
    n = A.getSize()[0]
    X = PETSc.Mat().createAIJ(A.getSizes(), nnz=(2, 2), comm=dmesh.comm)
    if dmesh.comm.rank == 0:
        X.setValue(0, n - 1, 7.0)             # first and last dof: no element couples them
    X.assemble()
    A.axpy(1.0, X, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
    A.setAttr("petsoft_pattern", asm.pattern)  # (MatAXPY's new storage lost the attribute)
    ke = rng.standard_normal((len(dmesh.cells), 12, 12))
    asm.begin()
    asm.add("cells", ke)
    asm.finish(A)
    asm.finish(ref)
    assert asm._parallel is not None
    # (the place is in rank 0's rows: its writer cannot reach it, the others' can)
    assert asm._parallel._covers_all == (dmesh.comm.rank != 0)
    assert not asm._parallel.write(A, asm.values)
    if A.getOwnershipRange()[0] == 0:
        cols, vals = A.getRow(0)
        assert n - 1 in cols and vals[list(cols).index(n - 1)] == 0.0
    diff = A.copy()
    diff.axpy(-1.0, ref, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
    assert diff.norm() <= 1e-14 * ref.norm()
    for obj in (A, ref, X, diff):
        obj.destroy()


def test_values_copied_in_place_equal_inserted_ones_and_solvers_see_them(dmesh):
    """finish() on a matrix of its own pattern copies the values into PETSc's arrays (serially
    the matrix's, in parallel its diagonal and off-diagonal blocks, the ghost rows' values
    sent to their owners): the same matrix as the inserted values, a solver set up before the
    change sees the new values, and a matrix whose storage PETSc replaced (MatAXPY builds a new
    one for a "different" pattern) still gets them (the arrays are asked of PETSc every time)."""
    rng = np.random.default_rng(2)
    asm = MatrixAssembler(dmesh, {"cells": dmesh.cells})
    A = asm.create_matrix()
    ref = asm.create_matrix()
    ref.setAttr("petsoft_pattern", None)       # not recognised: the generic insertion
    ke = rng.standard_normal((len(dmesh.cells), 12, 12))
    ke = ke @ ke.transpose(0, 2, 1) + 12 * np.eye(12)   # SPD element blocks: a solvable matrix
    asm.begin()
    asm.add("cells", ke)
    asm.finish(A)
    asm.finish(ref)
    if dmesh.comm.size > 1:         # the in-place path was taken (not the generic insertion)
        assert asm._parallel is not None and asm._parallel.write(A, asm.values)
    diff = A.copy()
    diff.axpy(-1.0, ref)
    # equal on 1 and 2 ranks; from 3 ranks on a sum of three differs in its order (1e-16)
    assert diff.norm() <= (0.0 if dmesh.comm.size <= 2 else 1e-14 * ref.norm())
    ksp = PETSc.KSP().create(comm=dmesh.comm)
    ksp.setOperators(A)
    ksp.setType("cg")
    ksp.getPC().setType("jacobi")
    ksp.setTolerances(rtol=1e-12)
    b = A.createVecLeft()
    b.set(1.0)
    x1, x2 = b.duplicate(), b.duplicate()
    ksp.solve(b, x1)
    asm.values *= 2.0                           # the same matrix, doubled
    asm.finish(A)
    ksp.solve(b, x2)
    x2.scale(2.0)
    assert (x2 - x1).norm() <= 1e-8 * x1.norm()
    # new storage made by PETSc (a diagonal matrix added as of a different pattern)
    D = PETSc.Mat().createAIJ(A.getSizes(), nnz=(1, 0), comm=dmesh.comm)
    D.setDiagonal(b)
    D.assemble()
    A.axpy(1.0, D, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
    asm.finish(A)
    diff = A.copy()
    diff.axpy(-2.0, ref)
    assert diff.norm() <= 1e-12 * ref.norm()
    for obj in (A, ref, ksp, b, x1, x2, diff, D):
        obj.destroy()
