"""Default linear solvers (petsoft.solvers.linear.linear_defaults): direct for small systems (on
several ranks a redundant solve, each rank factoring alone: bit-reproducible there), CG + GAMG
above DIRECT_DOFS."""

from petsc4py import PETSc

from petsoft.solvers.linear import DIRECT_DOFS, DIRECT_DOFS_QUADRATIC, linear_defaults


def _ksp(comm, prefix):
    ksp = PETSc.KSP().create(comm=comm)
    ksp.setOptionsPrefix(prefix)
    return ksp


def test_small_systems_are_direct():
    world = PETSc.COMM_WORLD
    ksp = _ksp(world, "ld_small_")
    linear_defaults(ksp, dofs=100)
    if world.getSize() == 1:
        assert ksp.getType() == PETSc.KSP.Type.PREONLY
        assert ksp.getPC().getType() == PETSc.PC.Type.LU
    else:
        # every rank factors the whole matrix by PETSc's LU (deterministic, no GAMG set-up)
        assert ksp.getType() == PETSc.KSP.Type.PREONLY
        assert ksp.getPC().getType() == PETSc.PC.Type.REDUNDANT
    ksp.destroy()
    ksp = _ksp(world, "ld_medium_")
    linear_defaults(ksp, dofs=DIRECT_DOFS + 1)
    assert ksp.getType() == PETSc.KSP.Type.CG and ksp.getPC().getType() == PETSc.PC.Type.GAMG
    ksp.destroy()
    # a one-rank sub-communicator (a candidate fit on its own rank) is direct whatever the world
    own = _ksp(PETSc.COMM_SELF, "ld_self_")
    linear_defaults(own, dofs=100)
    assert own.getType() == PETSc.KSP.Type.PREONLY
    own.destroy()


def test_large_or_user_chosen_systems_keep_their_solver():
    ksp = _ksp(PETSc.COMM_SELF, "ld_large_")
    linear_defaults(ksp, dofs=DIRECT_DOFS + 1)
    assert ksp.getType() == PETSc.KSP.Type.CG
    ksp.destroy()
    # 10-node elements: their own limit
    for dofs, expected in ((DIRECT_DOFS_QUADRATIC, PETSc.KSP.Type.PREONLY),
                           (DIRECT_DOFS_QUADRATIC + 1, PETSc.KSP.Type.CG)):
        ksp = _ksp(PETSc.COMM_SELF, "ld_quadratic_")
        linear_defaults(ksp, dofs=dofs, order=2)
        assert ksp.getType() == expected, dofs
        ksp.destroy()
    opts = PETSc.Options()
    opts["ld_user_pc_type"] = "jacobi"
    try:
        ksp = _ksp(PETSc.COMM_SELF, "ld_user_")
        linear_defaults(ksp, dofs=100)
        assert ksp.getType() == PETSc.KSP.Type.CG      # the other half stays iterative
        ksp.destroy()
    finally:
        opts.delValue("ld_user_pc_type")


def _laplacian(comm, n):
    """A 1-D Laplacian of size n (distributed), symmetric positive definite."""
    A = PETSc.Mat().createAIJ([n, n], nnz=3, comm=comm)
    lo, hi = A.getOwnershipRange()
    for i in range(lo, hi):
        A.setValue(i, i, 2.0)
        if i > 0:
            A.setValue(i, i - 1, -1.0)
        if i < n - 1:
            A.setValue(i, i + 1, -1.0)
    A.assemble()
    return A


def _solve_and_view(prefix, n, tmp_path):
    comm = PETSc.COMM_WORLD
    A = _laplacian(comm, n)
    ksp = _ksp(comm, prefix)
    linear_defaults(ksp, dofs=n)
    ksp.setOperators(A)
    ksp.setFromOptions()
    b = A.createVecLeft()
    b.set(1.0)
    x = A.createVecRight()
    ksp.solve(b, x)
    # one file for the communicator (each rank's pytest has a temporary folder of its own)
    path = type(tmp_path)(comm.tompi4py().bcast(str(tmp_path / f"{prefix}view.txt")))
    viewer = PETSc.Viewer().createASCII(str(path), comm=comm)
    ksp.view(viewer)
    viewer.destroy()
    comm.tompi4py().Barrier()
    text = path.read_text()
    residual = A.createVecLeft()
    A.mult(x, residual)
    residual.axpy(-1.0, b)
    err = residual.norm() / b.norm()
    for obj in (ksp, A, b, x, residual):
        obj.destroy()
    return text, err


def test_a_redundant_solve_factors_by_mumps_on_each_rank(tmp_path_factory):
    """On several ranks a redundant solve above SMALL_DIRECT_DOFS factors the gathered matrix
    by a sequential MUMPS on each rank (faster than PETSc's LU there), below it by PETSc's LU;
    a user's -<prefix>redundant_pc_factor_mat_solver_type wins. Every variant solves."""
    import pytest

    from petsoft.solvers.linear import SMALL_DIRECT_DOFS
    from petsoft.solvers.options import clear_options

    if PETSc.COMM_WORLD.getSize() == 1:
        pytest.skip("a redundant solve is made on several ranks (run under mpiexec -n 2)")
    if not PETSc.Sys.hasExternalPackage("mumps"):
        pytest.skip("PETSc without MUMPS")
    tmp = tmp_path_factory.getbasetemp()
    big = SMALL_DIRECT_DOFS + 200
    text, err = _solve_and_view("ld_red_big_", big, tmp)
    assert "redundant" in text and "mumps" in text, text
    assert err < 1e-9          # (a direct solve: eps x condition ~1e6)
    text, err = _solve_and_view("ld_red_small_", SMALL_DIRECT_DOFS - 200, tmp)
    assert "mumps" not in text and "redundant" in text, text
    assert err < 1e-9          # (a direct solve: eps x condition ~1e6)
    PETSc.Options()["ld_red_user_redundant_pc_factor_mat_solver_type"] = "petsc"
    try:
        text, err = _solve_and_view("ld_red_user_", big, tmp)
        assert "mumps" not in text and "redundant" in text, text
        assert err < 1e-9          # (a direct solve: eps x condition ~1e6)
    finally:
        clear_options(["ld_red_user_redundant_pc_factor_mat_solver_type",
                       "ld_red_big_redundant_pc_factor_mat_solver_type"])
