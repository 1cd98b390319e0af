"""One reading of PETSc's converged reasons, and one exception for a solve that failed.

Every solver object petsoft runs -- SNES, KSP, TS, TAO, SLEPc's MFN and EPS -- reports why it
stopped as an integer reason. :func:`outcome` turns any of them into a :class:`Outcome` (converged
or not, the reason's name, the iteration count); :func:`check_converged` raises
:class:`~petsoft.errors.SolverError` naming the solve, the reason and the iterations when it did
not converge (as Firedrake's ``check_snes_convergence``). Solvers that retry a failed step (the
integrators halve it) read the outcome; the others call :func:`check_converged`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from petsc4py import PETSc

from petsoft.errors import SolverError


def _names(enum_class) -> dict[int, str]:
    """Reason code -> name of a petsc4py/slepc4py ``ConvergedReason`` class."""
    return {int(v): k for k, v in vars(enum_class).items()
            if k.isupper() and isinstance(v, int)}


_TABLES: dict[type, dict[int, str]] = {
    PETSc.SNES: _names(PETSc.SNES.ConvergedReason),
    PETSc.KSP: _names(PETSc.KSP.ConvergedReason),
    PETSc.TS: _names(PETSc.TS.ConvergedReason),
    PETSc.TAO: _names(PETSc.TAO.Reason),
}


def _table(solver) -> dict[int, str]:
    for kind, table in _TABLES.items():
        if isinstance(solver, kind):
            return table
    from slepc4py import SLEPc  # only ERE runs an MFN; SLEPc loads with it

    if isinstance(solver, SLEPc.MFN):
        return _names(SLEPc.MFN.ConvergedReason)
    if isinstance(solver, SLEPc.EPS):
        return _names(SLEPc.EPS.ConvergedReason)
    raise TypeError(f"not a PETSc/SLEPc solver: {type(solver).__name__}")


@dataclass(frozen=True)
class Outcome:
    """How a solve ended.

    Attributes
    ----------
    converged : bool
        A positive reason (TS: non-negative, i.e. it reached its final time).
    reason : str
        The reason's name, e.g. ``DIVERGED_LINE_SEARCH`` (the code when it has none).
    code : int
    iterations : int
    kind : str
        SNES, KSP, TS, TAO, MFN or EPS.
    """

    converged: bool
    reason: str
    code: int
    iterations: int
    kind: str


def reason_name(solver, code: int | None = None) -> str:
    """The name of ``solver``'s converged reason (or of ``code`` for that kind of solver)."""
    code = int(solver.getConvergedReason()) if code is None else int(code)
    return _table(solver).get(code, str(code))


def outcome(solver) -> Outcome:
    """The :class:`Outcome` of ``solver``'s last solve."""
    code = int(solver.getConvergedReason())
    kind = type(solver).__name__
    if isinstance(solver, PETSc.TS):
        # a TS counts steps, not iterations; it converged when it reached its final time (>= 0)
        ok, its = code >= 0, solver.getStepNumber()
    else:
        ok, its = code > 0, solver.getIterationNumber()
    return Outcome(converged=ok, reason=_table(solver).get(code, str(code)), code=code,
                   iterations=int(its), kind=kind)


def check_converged(solver, what: str, hint: str = "") -> Outcome:
    """Raise :class:`SolverError` when ``solver``'s last solve did not converge.

    Parameters
    ----------
    solver : PETSc.SNES, KSP, TS, TAO or SLEPc.MFN, EPS
    what : str
        Which solve, for the message (e.g. ``"the lifting solve of the prescribed
        displacements"``, ``"backward-Euler step 12 at t = 0.024 s"``).
    hint : str
        What the user can try, appended to the message.

    Returns
    -------
    Outcome
        When it converged.
    """
    result = outcome(solver)
    if not result.converged:
        raise SolverError(f"{what}: {result.kind} {result.reason} after {result.iterations} "
                          f"iteration(s){'; ' + hint if hint else ''}")
    return result


#: Newton stops at the round-off floor when its residual stalls below this many unit round-offs
#: of ``||J||_inf max(||x||_2, L sqrt(n))`` (module docstring of :func:`stop_at_round_off`).
ROUND_OFF_FACTOR = 1.0


def stop_at_round_off(snes: PETSc.SNES, jacobian: PETSc.Mat, length: float) -> None:
    """Make Newton also converge when its residual stalls at the round-off floor.

    The absolute tolerance is in Newtons, so no fixed value suits every model: the strain is
    computed from F - I, whose round-off is eps whatever the displacement, so the internal
    forces carry an error of about eps E h^2 per node, ``eps ||J||_inf L sqrt(n)`` in norm (L a
    cell size): measured 1.7e-11 N on a 10-node cantilever (E 2e7 Pa, 1275 dofs), where the
    residual then stalled above ``atol`` = 1e-12 until ``max_it`` failed the step, while the
    update, divided by a soft mode's stiffness, stayed above ``stol |x|`` (x near zero at the top
    of a swing). PETSc's default test is kept (its few lines are repeated here: petsc4py cannot
    call it from a Python test) and, where it says "go on", Newton stops with
    CONVERGED_FNORM_ABS when the residual no longer halves from one iteration to the next and is
    below ``c eps ||J||_inf max(||x||_2, L sqrt(n))`` (c = :data:`ROUND_OFF_FACTOR`, ``J`` the
    last assembled Jacobian; 4.5e-10 N there): a residual that still falls is never cut short.

    Parameters
    ----------
    snes : PETSc.SNES
    jacobian : PETSc.Mat
        The matrix the SNES assembles its Jacobian into.
    length : float
        A cell size of the model (m).
    """
    eps = float(np.finfo(float).eps)
    reasons = PETSc.SNES.ConvergedReason
    state = {"f0": 0.0, "last": math.inf}

    def test(snes, its, norms):
        xnorm, ynorm, fnorm = norms
        rtol, atol, stol, _ = snes.getTolerances()
        last, state["last"] = state["last"], fnorm
        if not math.isfinite(fnorm):
            return reasons.DIVERGED_FNORM_NAN
        if its == 0:
            state["f0"] = fnorm
        if fnorm < atol:
            return reasons.CONVERGED_FNORM_ABS
        if its == 0:
            return reasons.ITERATING
        if fnorm <= rtol * state["f0"]:
            return reasons.CONVERGED_FNORM_RELATIVE
        if ynorm < stol * xnorm:
            return reasons.CONVERGED_SNORM_RELATIVE
        if fnorm > 0.5 * last:
            scale = max(xnorm, length * snes.getSolution().getSize() ** 0.5)
            if fnorm <= ROUND_OFF_FACTOR * eps * scale * jacobian.norm(PETSc.NormType.INFINITY):
                return reasons.CONVERGED_FNORM_ABS
        return reasons.ITERATING

    snes.setConvergenceTest(test)


def on_any_rank(comm: PETSc.Comm, flag: bool) -> bool:
    """Whether ``flag`` holds on some rank of ``comm`` (collective). A step's solve that met an
    inverted element on one rank only must be repeated (or refused) on every rank alike: a
    rank-local decision sent the ranks into different solves, which never returned."""
    if comm.getSize() == 1:
        return bool(flag)
    from mpi4py import MPI

    return bool(comm.tompi4py().allreduce(bool(flag), op=MPI.LOR))
