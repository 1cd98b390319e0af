"""Defaults of the linear solvers every Newton-type solver in petsoft uses."""

from __future__ import annotations

from petsc4py import PETSc


def linear_defaults(ksp: PETSc.KSP, rtol: float = 1e-12) -> None:
    """CG + algebraic multigrid (the caller attaches the rigid-body near-nullspace).

    Set before ``setFromOptions()``, so ``-ksp_type``/``-pc_type`` (with the object's prefix)
    replace them: SOR (Gauss-Seidel), Jacobi, or a direct MUMPS solve.
    """
    ksp.setType(PETSc.KSP.Type.CG)
    ksp.getPC().setType(PETSc.PC.Type.GAMG)
    ksp.setTolerances(rtol=rtol, atol=1e-50, max_it=2000)
