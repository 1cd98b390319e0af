"""Defaults of the linear solvers every Newton-type solver in petsoft uses."""

from __future__ import annotations

from petsc4py import PETSc

#: Systems up to this many dofs are solved directly by default: a forward run or a calibration
#: makes thousands of solves, and on a few thousand dofs one factorisation costs less than an
#: algebraic-multigrid set-up plus its iterations (scripts/benchmarks/bench_linear_solvers.py).
DIRECT_DOFS = 6000
#: Up to this many dofs the direct solve is PETSc's own LU with a nested-dissection ordering:
#: MUMPS costs ~1.5 ms a factorisation whatever the size (its set-up per call), which was most of
#: a 351-dof bar's Newton iteration; PETSc's LU is faster up to ~1200 dofs, MUMPS beyond
#: (generalized-alpha forward runs of a neo-Hookean bar, 351 / 567 / 1200 / 2325 dofs: PETSc's
#: LU took 0.51 / 0.64 / 0.98 / 1.8 x MUMPS's time).
SMALL_DIRECT_DOFS = 1000


def solver_chosen(ksp: PETSc.KSP) -> bool:
    """Whether an option (user, experiment ``[petsc]`` or a caller's scoped default) names this
    solver's Krylov method or preconditioner."""
    prefix = ksp.getOptionsPrefix() or ""
    db = PETSc.Options()
    return db.hasName(prefix + "ksp_type") or db.hasName(prefix + "pc_type")


def linear_defaults(ksp: PETSc.KSP, rtol: float = 1e-12, dofs: int | None = None) -> None:
    """A direct solve for up to :data:`DIRECT_DOFS` dofs, else CG + algebraic multigrid (the
    caller attaches the rigid-body near-nullspace).

    The direct solve is PETSc's LU (nested dissection) up to :data:`SMALL_DIRECT_DOFS`, then
    MUMPS when PETSc has it (on a 1875-dof bar it factors 2.5x faster than PETSc's own LU),
    and only on one rank: across ranks MUMPS schedules
    dynamically and asynchronously, and two identical 2-rank runs on a loaded machine differed
    in the last bits (tests/test_restart.py's bitwise restart failed once; not reproduced on a
    quiet machine, so the scheduling is the likely, unproven cause), while the iterative
    default has always repeated itself exactly there. Set before ``setFromOptions()``,
    so ``-ksp_type``/``-pc_type`` (with the object's prefix) replace them: SOR (Gauss-Seidel),
    Jacobi, CG + GAMG, or a direct solve. A solver half-chosen by options (only ``-pc_type
    jacobi``) gets the iterative default for the other half, never "preonly".

    Parameters
    ----------
    ksp :
        The solver, its options prefix already set.
    rtol :
        Relative tolerance of the iterative default.
    dofs :
        Global size of the system; ``None`` keeps the iterative default.
    """
    if (dofs is not None and dofs <= DIRECT_DOFS and not solver_chosen(ksp)
            and ksp.getComm().getSize() == 1):
        ksp.setType(PETSc.KSP.Type.PREONLY)
        pc = ksp.getPC()
        pc.setType(PETSc.PC.Type.LU)
        if dofs <= SMALL_DIRECT_DOFS or not PETSc.Sys.hasExternalPackage("mumps"):
            pc.setFactorSolverType("petsc")
            pc.setFactorOrdering(PETSc.Mat.OrderingType.ND)
        else:
            pc.setFactorSolverType("mumps")
        return
    ksp.setType(PETSc.KSP.Type.CG)
    ksp.getPC().setType(PETSc.PC.Type.GAMG)
    ksp.setTolerances(rtol=rtol, atol=1e-50, max_it=2000)
