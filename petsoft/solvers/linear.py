"""Defaults of the linear solvers every Newton-type solver in petsoft uses."""

from __future__ import annotations

from collections.abc import Callable
from contextlib import contextmanager

from petsc4py import PETSc

from petsoft.solvers.convergence import outcome

#: Systems up to this many dofs are solved directly by default (on one rank): a forward run or
#: a calibration makes thousands of solves, and since the steps factor once (the chord method,
#: :func:`factor_once_per_step`) and forward runs keep their factors across steps, one
#: factorisation serves many solves. Measured with ``ForwardModel.simulate`` on bench_forward's
#: neo-Hookean bar (generalized-alpha, 1 rank, this limit patched to one or the other): 46,644
#: dofs 0.84 s a step against CG + GAMG's 3.59 s (trajectories equal to 7e-15 m); 125,388 dofs
#: 5.4 s against 11.1 s, peak memory 1.9 GB against 1.5 GB. The limit was 6000 before the chord
#: (bench_linear_solvers.py: one factorisation against one multigrid set-up per solve).
DIRECT_DOFS = 100_000
#: The same for 10-node tetrahedra, whose denser rows favour the direct solve far longer:
#: generalized-alpha runs of a linear bar (bench_linear_solvers.py --order 2, 1 rank, at
#: ecf72b0) took 0.23x / 0.29x / 0.30x CG + GAMG's time a step at 1875 / 11907 / 37011 dofs
#: (MUMPS's symmetric factor); CG + GAMG on a neo-Hookean bar broke down (indefinite Newton
#: iterate) where the direct solve went on. With the chord, the same neo-Hookean forward run as
#: above at 72,225 dofs of 10-node elements: 2.66 s a step against CG + GAMG's 13.0 s (peak
#: memory 1.33 GB against 1.08 GB). The limit was 40,000.
DIRECT_DOFS_QUADRATIC = 100_000
#: Up to this many dofs the direct solve is PETSc's own LU with a nested-dissection ordering:
#: MUMPS costs ~1.5 ms a factorisation whatever the size (its set-up per call), which was most of
#: a 351-dof bar's Newton iteration; PETSc's LU is faster up to ~1200 dofs, MUMPS beyond
#: (generalized-alpha forward runs of a neo-Hookean bar, 351 / 567 / 1200 / 2325 dofs: PETSc's
#: LU took 0.51 / 0.64 / 0.98 / 1.8 x MUMPS's time).
SMALL_DIRECT_DOFS = 1000
#: On several ranks, systems up to this many dofs are solved by a redundant direct solve: each
#: rank gathers the matrix and factors it by PETSc's LU (MUMPS's parallel scheduling is not
#: bit-reproducible, see :func:`linear_defaults`). A sequential MUMPS inside the redundant solve
#: (``-fm_redundant_pc_factor_mat_solver_type mumps``) was measured and is not the default: on
#: the realistic cases' 10-node model (4641 dofs, 2 ranks, quiet, -log_view) it factors 3x
#: faster (control: 31.9 -> 9.7 s for 1048 factorisations) but solves 1.3x slower (65.9 -> 85.4 s
#: for 86657), and diagnose's runs, which keep their factors, solve far more often than they
#: factor: the damping case took 373 s with it, 349 s without (the same path and result).

REDUNDANT_DOFS = 6000


@contextmanager
def direct_solve_up_to(dofs: int):
    """Raise :data:`DIRECT_DOFS` to ``dofs`` while the context is open (on one rank only, as
    always): for a single forward run above the default's size whose time steps change the
    matrix little. Measured on the independent L-bracket's 10-node split mesh (21k dofs, 200
    generalized-alpha steps, 1 rank): MUMPS 140 s; CG + GAMG had not finished after 200 s."""
    global DIRECT_DOFS, DIRECT_DOFS_QUADRATIC
    before = DIRECT_DOFS, DIRECT_DOFS_QUADRATIC
    DIRECT_DOFS, DIRECT_DOFS_QUADRATIC = (max(b, int(dofs)) for b in before)
    try:
        yield
    finally:
        DIRECT_DOFS, DIRECT_DOFS_QUADRATIC = before


def solver_chosen(ksp: PETSc.KSP) -> bool:
    """Whether an option (user, experiment ``[petsc]`` or a caller's scoped default) names this
    solver's Krylov method or preconditioner."""
    prefix = ksp.getOptionsPrefix() or ""
    db = PETSc.Options()
    return db.hasName(prefix + "ksp_type") or db.hasName(prefix + "pc_type")


def direct_limit(order: int = 1) -> int:
    """The largest system solved directly by default for elements of ``order`` (one rank)."""
    return DIRECT_DOFS_QUADRATIC if order == 2 else DIRECT_DOFS


def linear_defaults(ksp: PETSc.KSP, rtol: float = 1e-12, dofs: int | None = None,
                    order: int = 1) -> None:
    """A direct solve for up to :data:`DIRECT_DOFS` dofs (:data:`DIRECT_DOFS_QUADRATIC` for
    10-node elements), else CG + algebraic multigrid (the caller attaches the rigid-body
    near-nullspace).

    The direct solve is PETSc's LU (nested dissection) up to :data:`SMALL_DIRECT_DOFS`, then
    MUMPS when PETSc has it (on a 1875-dof bar it factors 2.5x faster than PETSc's own LU),
    on one rank; on several ranks, up to :data:`REDUNDANT_DOFS`, a redundant PETSc LU (each
    rank factors the gathered matrix: the 2-rank test pass 330 -> 257 s, a neo-Hookean bar's
    midpoint run 24 -> 9 s, both against CG + GAMG), not MUMPS: across ranks MUMPS schedules
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
    order :
        Element order of the system (2: 10-node tetrahedra).
    """
    small = dofs is not None and dofs <= direct_limit(order) and not solver_chosen(ksp)
    if small and ksp.getComm().getSize() > 1 and dofs <= REDUNDANT_DOFS:
        # every rank factors the whole (small) matrix by PETSc's own LU: deterministic, unlike
        # MUMPS across ranks, and no multigrid set-up
        ksp.setType(PETSc.KSP.Type.PREONLY)
        ksp.getPC().setType(PETSc.PC.Type.REDUNDANT)
        return
    if small and ksp.getComm().getSize() == 1:
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


def symmetric_factorisation(ksp: PETSc.KSP, A: PETSc.Mat) -> bool:
    """Factor ``A`` by MUMPS's symmetric LDL^T (indefinite allowed) instead of LU when the
    default direct solve (not chosen by options) uses MUMPS and ``A`` is flagged symmetric
    (petsoft's assembled FEM and spring matrices are: ``Mat.Option.SYMMETRIC``). Half the
    work of LU: a 2.2k-dof 10-node finger's step matrix 4.0 ms against 7.6 ms. Call after
    ``setFromOptions()``; returns whether it changed the solver."""
    pc = ksp.getPC()
    if (solver_chosen(ksp) or ksp.getType() != PETSc.KSP.Type.PREONLY
            or pc.getType() != PETSc.PC.Type.LU or pc.getFactorSolverType() != "mumps"
            or A.isSymmetricKnown() != (True, True)):
        return False
    pc.setType(PETSc.PC.Type.CHOLESKY)
    pc.setFactorSolverType("mumps")
    return True


#: Preconditioners that are a direct solve under ``preonly`` (redundant: each rank factors the
#: gathered matrix by LU, :func:`linear_defaults`' choice for small systems on several ranks)
DIRECT_PCS = (PETSc.PC.Type.LU, PETSc.PC.Type.CHOLESKY, PETSc.PC.Type.REDUNDANT)


def is_direct(ksp: PETSc.KSP) -> bool:
    """Whether ``ksp`` solves by one factorisation (``preonly`` with LU or Cholesky): its
    solves are exact, and cheap once it is set up."""
    return (ksp.getType() == PETSc.KSP.Type.PREONLY
            and ksp.getPC().getType() in DIRECT_PCS)


def factor_once_per_step(snes: PETSc.SNES) -> bool:
    """Assemble and factor the Jacobian once per time step: Newton becomes the chord method.

    When the step's solver is the default direct solve (``preonly`` + LU, Cholesky or redundant
    LU, not chosen by options) of a Newton line search, the Jacobian and its factorisation are
    computed at the first iteration of each solve only and every later iteration solves with
    them (PETSc's ``-snes_lag_jacobian`` and ``-snes_lag_preconditioner``, not persistent
    across solves). The residual is exact, so the step converges to the same solution to the
    same tolerance; within a time step the Jacobian hardly moves, so the chord contracts fast.
    Measured on a 10-node neo-Hookean finger (2.2k dofs, generalized-alpha, 140 steps): 3.9
    Newton iterations a step, each assembling the Jacobian (and, before, solving it by GMRES on
    the step's factor), against 5.8 chord iterations a step with one assembly: a forward run
    3.6 -> 2.2 s, and 1.6 s with MUMPS's symmetric factorisation (below); trajectories equal
    to 4e-15 m.

    Every step starts from a fresh factorisation of its own first Jacobian, so a run restarted
    at any step computes what the uninterrupted run did, bit for bit.

    Call after ``snes.setFromOptions()``; a step that fails should be repeated after
    :func:`refactor_every_iteration` (:func:`solve_newton` does). Returns whether it changed
    the solver.
    """
    ksp = snes.getKSP()
    pc = ksp.getPC()
    prefix = snes.getOptionsPrefix() or ""
    db = PETSc.Options()
    if (solver_chosen(ksp) or ksp.getType() != PETSc.KSP.Type.PREONLY
            or pc.getType() not in DIRECT_PCS
            or snes.getType() != PETSc.SNES.Type.NEWTONLS
            or db.hasName(prefix + "snes_lag_preconditioner")
            or db.hasName(prefix + "snes_lag_jacobian")):
        return False
    if pc.getType() == PETSc.PC.Type.LU and pc.getFactorSolverType() == "mumps":
        # The chord needs only an approximation of the Jacobian (the residual is exact), and
        # the step matrices are symmetric (hyperelastic, Rayleigh, drag, friction, penalty
        # contact: 1e-18 relative asymmetry measured): MUMPS's symmetric LDL^T (indefinite
        # allowed) factors the 2.2k-dof 10-node finger's in 4.0 ms against LU's 7.6 ms. A
        # nonsymmetric part would only slow the chord; full Newton goes back to LU.
        pc.setType(PETSc.PC.Type.CHOLESKY)
        pc.setFactorSolverType("mumps")
    _set_lag(snes, 1 << 30)
    return True


def multigrid_once_per_step(snes: PETSc.SNES) -> bool:
    """Set algebraic multigrid up once per Newton solve, and solve its Newton systems only as
    accurately as the Newton iteration needs (Eisenstat-Walker).

    Where a Newton line search (a step solved to convergence, not the semi-implicit step's one
    linear solve) runs a Krylov method preconditioned by GAMG, each iteration would build a new
    hierarchy and iterate to the KSP's 1e-12: on one backward-Euler step of a bent neo-Hookean
    bar (27,300 dofs, ``bench_step.py``) 4 Newton iterations, 4 hierarchies (1.1 s) and 220 CG
    iterations (1.9 s), 3.0 s in all. The Jacobian is still assembled at every iteration (the
    Newton direction stays exact up to the Krylov tolerance); the hierarchy of the first one
    preconditions the others (PETSc's ``-snes_lag_preconditioner``), and the Krylov tolerance
    follows the residual's decrease (``-snes_ksp_ew``): 9 Newton iterations, 72 CG iterations,
    one hierarchy, 1.44 s, to the same Newton tolerance. A fresh solver per step sets up afresh
    at each step (restarts stay bit for bit); a run that keeps its factors keeps the
    hierarchy's interpolation across steps too
    (:meth:`petsoft.dynamics.implicit.SolverReuse._keeps_multigrid`).

    Either option given (``-<prefix>snes_lag_preconditioner``, ``-<prefix>snes_ksp_ew``) leaves
    the solver as the options made it. Call after ``snes.setFromOptions()``; returns whether it
    changed the solver.
    """
    from petsoft.solvers.options import scoped_defaults

    ksp = snes.getKSP()
    prefix = snes.getOptionsPrefix() or ""
    db = PETSc.Options()
    if (snes.getType() != PETSc.SNES.Type.NEWTONLS or ksp.getType() == PETSc.KSP.Type.PREONLY
            or ksp.getPC().getType() != PETSc.PC.Type.GAMG
            or db.hasName(prefix + "snes_lag_preconditioner")
            or db.hasName(prefix + "snes_ksp_ew")):
        return False
    with scoped_defaults(**{prefix + "snes_lag_preconditioner": str(1 << 30),
                            prefix + "snes_ksp_ew": "true"}):
        snes.setFromOptions()
    return True


def keep_supports(x: PETSc.Vec, y: PETSc.Vec, system) -> bool:
    """Line-search pre-check of a Newton solve whose linear systems are solved iteratively
    (inexactly by :func:`multigrid_once_per_step` or ``-snes_ksp_ew``): the update ``y`` gets
    no component on ``system``'s prescribed dofs (``system.zero_prescribed``).

    Their residual rows are zero and their Jacobian rows and columns the identity, so an exact
    solve leaves them unchanged; a Krylov method stopped early (Eisenstat-Walker's first
    iterations stop at 10-90 %) does not, its multigrid couples them to the free dofs. The
    residual never sees the drift, and resetting the supports after the solve then left a
    residual of 1e-2 of the step's first one (a bent bar's backward-Euler step, the Newton
    iteration converged to 3e-13). Returns True: ``y`` may have changed."""
    system.zero_prescribed(y)
    return True


def reuse_across_iterations(snes: PETSc.SNES, system, chord: bool = True) -> bool:
    """Set a time step's Newton solver to reuse what it can across its iterations: the chord's
    factorisation (:func:`factor_once_per_step`, unless ``chord`` is False), else the multigrid
    hierarchy (:func:`multigrid_once_per_step`); a solver that is not direct keeps ``system``'s
    supports in place (:func:`keep_supports`). Call after ``snes.setFromOptions()``; returns
    whether the chord is used (a failed step then calls :func:`refactor_every_iteration`)."""
    lagged = chord and factor_once_per_step(snes)
    if not lagged:
        multigrid_once_per_step(snes)
    if not is_direct(snes.getKSP()):
        snes.setLineSearchPreCheck(keep_supports, args=(system,))
    return lagged


def refactor_every_iteration(snes: PETSc.SNES) -> None:
    """Undo :func:`factor_once_per_step`'s lag: the Jacobian is assembled and factored at every
    Newton iteration (full Newton), by LU where the chord used a symmetric factorisation."""
    pc = snes.getKSP().getPC()
    if pc.getType() == PETSc.PC.Type.CHOLESKY and pc.getFactorSolverType() == "mumps":
        pc.setType(PETSc.PC.Type.LU)
        pc.setFactorSolverType("mumps")
    _set_lag(snes, 1)


def _set_lag(snes: PETSc.SNES, lag: int) -> None:
    """SNESSetLagJacobian and SNESSetLagPreconditioner (not in petsc4py 3.18) through the
    options database, for this solver only; the other options are read again unchanged."""
    from petsoft.solvers.options import scoped_defaults

    prefix = snes.getOptionsPrefix() or ""
    with scoped_defaults(**{prefix + "snes_lag_preconditioner": str(lag),
                            prefix + "snes_lag_jacobian": str(lag)}):
        snes.setFromOptions()


def solve_newton(snes: PETSc.SNES, x: PETSc.Vec, lagged: bool,
                 rejected: Callable[[], bool] | None = None) -> None:
    """``snes.solve(None, x)`` from the guess in ``x``; with ``lagged`` (the solver was set up by
    :func:`factor_once_per_step`) a failure of the chord iteration (the Jacobian moved far
    within the step: an impact, a snap-through, a large rotation) repeats the solve from the
    same guess by full Newton, then restores the lag for the next step. ``rejected()``: whether
    the solve went through a state the model refuses (an inverted element), forgetting it; such
    a chord counts as failed (seen: a backward-Euler step of a bent neo-Hookean bar at h = 1/60 s
    whose chord iterates inverted an element that full Newton never reached)."""
    if not lagged:
        snes.solve(None, x)
        return
    guess = x.copy()
    try:
        snes.solve(None, x)
        bad = rejected() if rejected is not None else False
        if outcome(snes).converged and not bad:
            return
        guess.copy(x)
        refactor_every_iteration(snes)
        snes.solve(None, x)
        factor_once_per_step(snes)
    finally:
        guess.destroy()
