"""Default linear solvers (petsoft.solvers.linear.linear_defaults): direct for small systems (on
several ranks a redundant PETSc LU, bit-reproducible there), CG + GAMG above DIRECT_DOFS."""

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
