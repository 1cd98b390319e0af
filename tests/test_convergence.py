"""One reading of converged reasons (petsoft.solvers.convergence) on real solves that converge
and real solves that fail."""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

from petsoft.errors import SolverError
from petsoft.solvers.convergence import check_converged, outcome, reason_name


def _laplacian(n: int) -> PETSc.Mat:
    A = PETSc.Mat().createAIJ((n, n), nnz=3, comm=PETSc.COMM_WORLD)
    lo, hi = A.getOwnershipRange()
    for i in range(lo, hi):
        A.setValue(i, i, 2.0)
        if i > 0:
            A.setValue(i, i - 1, -1.0)
        if i < n - 1:
            A.setValue(i, i + 1, -1.0)
    A.assemble()
    return A


def _ksp(A, max_it: int) -> tuple[PETSc.KSP, PETSc.Vec, PETSc.Vec]:
    ksp = PETSc.KSP().create(comm=A.getComm())
    ksp.setOperators(A)
    ksp.setType("cg")
    ksp.getPC().setType("none")
    ksp.setTolerances(rtol=1e-12, max_it=max_it)
    b, x = A.createVecs()
    b.set(1.0)
    ksp.solve(b, x)
    return ksp, b, x


def test_a_converged_ksp_passes_and_is_named():
    A = _laplacian(20)
    ksp, b, x = _ksp(A, 100)
    result = check_converged(ksp, "a Laplacian solve")
    assert result.converged and result.kind == "KSP"
    assert result.reason.startswith("CONVERGED_") and result.iterations > 0
    for obj in (ksp, b, x, A):
        obj.destroy()


def test_a_ksp_out_of_iterations_raises_one_error_naming_solve_reason_and_iterations():
    A = _laplacian(50)
    ksp, b, x = _ksp(A, 3)
    assert not outcome(ksp).converged
    with pytest.raises(SolverError, match=r"^the lifting solve: KSP DIVERGED_MAX_IT after 3 "
                                          r"iteration\(s\); try -ksp_type preonly$"):
        check_converged(ksp, "the lifting solve", hint="try -ksp_type preonly")
    for obj in (ksp, b, x, A):
        obj.destroy()


def test_a_snes_without_a_root_is_a_failure():
    """x^2 + 1 = 0 has no real root: Newton's line search fails or it runs out of iterations."""
    snes = PETSc.SNES().create(comm=PETSc.COMM_SELF)
    f, x = PETSc.Vec().createSeq(1), PETSc.Vec().createSeq(1)
    J = PETSc.Mat().createDense((1, 1), comm=PETSc.COMM_SELF)
    J.setUp()

    def residual(snes, x, out):
        out[0] = x[0] ** 2 + 1.0
        out.assemble()

    def jacobian(snes, x, J, P):
        P.setValue(0, 0, 2.0 * x[0])
        P.assemble()

    snes.setFunction(residual, f)
    snes.setJacobian(jacobian, J)
    snes.setTolerances(max_it=20)
    snes.getKSP().setType("preonly")
    snes.getKSP().getPC().setType("lu")
    x.set(0.3)              # not 1: Newton's first step would land on the singular x = 0
    snes.solve(None, x)
    result = outcome(snes)
    assert not result.converged and result.reason.startswith("DIVERGED_")
    assert reason_name(snes) == result.reason
    with pytest.raises(SolverError, match="a scalar Newton solve: SNES DIVERGED_"):
        check_converged(snes, "a scalar Newton solve")
    for obj in (snes, f, x, J):
        obj.destroy()


def test_reason_names_cover_every_kind_and_unknown_codes():
    snes, ksp, ts, tao = (PETSc.SNES().create(), PETSc.KSP().create(), PETSc.TS().create(),
                          PETSc.TAO().create())
    assert reason_name(snes, -6) == "DIVERGED_LINE_SEARCH"
    assert reason_name(ksp, -3) == "DIVERGED_MAX_IT"
    assert reason_name(ts, 1) == "CONVERGED_TIME"
    assert reason_name(tao, -2) == "DIVERGED_MAXITS"
    assert reason_name(ksp, 12345) == "12345"
    with pytest.raises(TypeError, match="not a PETSc/SLEPc solver"):
        reason_name(np.zeros(1), 0)
    for obj in (snes, ksp, ts, tao):
        obj.destroy()


def test_preonly_and_ksponly_reasons_are_converged():
    """preonly stops with KSP CONVERGED_ITS and -snes_type ksponly with SNES CONVERGED_ITS."""
    A = _laplacian(10)
    ksp = PETSc.KSP().create(comm=A.getComm())
    ksp.setOperators(A)
    ksp.setType("preonly")
    ksp.getPC().setType("jacobi")
    b, x = A.createVecs()
    b.set(1.0)
    ksp.solve(b, x)
    assert check_converged(ksp, "one preonly application").reason == "CONVERGED_ITS"

    snes = PETSc.SNES().create(comm=A.getComm())
    f = b.duplicate()

    def residual(snes, x, out):
        A.mult(x, out)
        out.axpy(-1.0, b)

    snes.setFunction(residual, f)
    snes.setJacobian(lambda *args: None, A)
    snes.setType("ksponly")
    x.zeroEntries()
    snes.solve(None, x)
    assert check_converged(snes, "a ksponly solve").reason == "CONVERGED_ITS"
    for obj in (snes, f, ksp, b, x, A):
        obj.destroy()


def _decay_ts(max_snes_its: int) -> tuple[PETSc.TS, PETSc.Vec, PETSc.Mat]:
    """u' = -u by backward Euler over [0, 0.1] in steps of 0.05."""
    ts = PETSc.TS().create(comm=PETSc.COMM_SELF)
    u = PETSc.Vec().createSeq(1)
    J = PETSc.Mat().createDense((1, 1), comm=PETSc.COMM_SELF)
    J.setUp()

    def rhs(ts, t, u, out):
        out[0] = -u[0]
        out.assemble()

    def rhs_jacobian(ts, t, u, J, P):
        P.setValue(0, 0, -1.0)
        P.assemble()

    ts.setRHSFunction(rhs, u.duplicate())
    ts.setRHSJacobian(rhs_jacobian, J)
    ts.setType("beuler")
    ts.setTimeStep(0.05)
    ts.setMaxTime(0.1)
    ts.setExactFinalTime(PETSc.TS.ExactFinalTime.MATCHSTEP)
    ts.setMaxSNESFailures(1)
    ts.setErrorIfStepFails(False)     # report the reason (as petsoft's alpha backend does)
    snes = ts.getSNES()
    # newtonls with rtol 1e-300 never converges on a linear problem in max_it iterations
    snes.setTolerances(rtol=1e-300, atol=0.0, stol=0.0, max_it=max_snes_its)
    snes.getKSP().setType("preonly")
    snes.getKSP().getPC().setType("lu")
    u.set(1.0)
    return ts, u, J


def test_a_ts_reaching_its_final_time_is_converged_and_counts_steps():
    ts, u, J = _decay_ts(max_snes_its=50)
    ts.getSNES().setTolerances(rtol=1e-10, atol=1e-14, max_it=50)
    ts.solve(u)
    result = check_converged(ts, "backward-Euler decay")
    assert result.kind == "TS" and result.reason.startswith("CONVERGED_")
    assert result.iterations == 2     # steps
    for obj in (ts, u, J):
        obj.destroy()


def test_a_ts_whose_newton_fails_raises_naming_the_step():
    ts, u, J = _decay_ts(max_snes_its=1)
    ts.solve(u)
    assert not outcome(ts).converged
    with pytest.raises(SolverError, match=r"^backward-Euler step 1 at t = 0 s: TS "
                                          r"DIVERGED_NONLINEAR_SOLVE after \d+ iteration"):
        check_converged(ts, "backward-Euler step 1 at t = 0 s")
    for obj in (ts, u, J):
        obj.destroy()
