"""One reading of PETSc's converged reasons, and one exception for a solve that failed.

Every solver object petsoft runs -- SNES, KSP, TS, TAO, SLEPc's MFN and EPS -- reports why it
stopped as an integer reason. :func:`outcome` turns any of them into a :class:`Outcome` (converged
or not, the reason's name, the iteration count); :func:`check_converged` raises
:class:`~petsoft.errors.SolverError` naming the solve, the reason and the iterations when it did
not converge (as Firedrake's ``check_snes_convergence``). Solvers that retry a failed step (the
integrators halve it) read the outcome; the others call :func:`check_converged`.
"""

from __future__ import annotations

from dataclasses import dataclass

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
