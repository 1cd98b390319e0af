"""Newton's chord on a factorisation another solve already made.

A forward-sensitivity run (:meth:`petsoft.calibration.forward.ForwardModel.jacobian`) factors
the exact step Jacobian at every converged step for its tangent solves. The next time step's
Newton chord (:func:`petsoft.solvers.linear.factor_once_per_step`) would then assemble and
factor the step Jacobian once more, at its predictor: the same matrix one step later. The chord
needs only an approximation of the Jacobian (its residual is exact and it converges to the
same tolerance), so the next step can iterate on the sensitivities' factors instead, saving an
assembly and a factorisation a step -- two of a sensitivity step's costliest parts.
The sensitivity run keeps its factorisation across steps too
(:mod:`petsoft.solvers.lagged_factors`: GMRES on each step's exact Jacobian, preconditioned with
an earlier step's factors, refactored when a tangent solve needs more than a few iterations);
the chord then iterates on those kept factors (a ``preonly`` KSP on the same PC), older than
the previous step's, and takes a few more iterations.

A forward run that is not differentiated (:meth:`petsoft.calibration.forward.ForwardModel.simulate`)
can lend itself its own factors the same way (:meth:`ChordBorrower.keep_factors`): each step's
chord iterates on the factorisation of an earlier step's predictor until a step needs
:data:`LAG_SLACK` iterations more than the freshly factored one did; the next step then factors
afresh. The step matrix of a 2 ms step is mostly stiffness, which moves little from one step to
the next, so the factorisation -- most of a 10-node step's time -- is made every few steps
instead of every step.
"""

from __future__ import annotations

from collections.abc import Callable

from petsc4py import PETSc

from petsoft.solvers.convergence import outcome, stop_at_round_off
from petsoft.solvers.linear import solve_newton
from petsoft.solvers.options import SolverOptions, own_options


class _ApplyBorrowed:
    """Python PC context: y = A^-1 x by the borrowed (set-up) KSP."""

    def __init__(self):
        self.ksp = None

    def apply(self, pc, x, y) -> None:
        self.ksp.solve(x, y)


class BorrowedChord:
    """A Newton solver (SNES, the stepper's line search) whose every linear system is solved by
    a KSP someone else set up (:meth:`solve`); its Jacobian is never assembled.

    Parameters
    ----------
    like : PETSc.SNES
        The stepper's own solver: its communicator, options prefix, residual (function and
        vector) and, at each :meth:`solve`, its tolerances are taken.
    residual : callable(snes, x, F)
        The step's residual callback.
    F : PETSc.Vec
        The residual vector.
    J : PETSc.Mat
        A matrix of the step Jacobian's layout and scale (its infinity norm sets the round-off
        floor of :func:`~petsoft.solvers.convergence.stop_at_round_off`); never written.
    length : float
        A cell size of the model (m), for that floor.
    linesearch : str
        The stepper's default line search (backtracking where a saturating force needs it;
        the options still choose).
    options : SolverOptions, optional
        The stepper's options (its prefix), pushed while this SNES is set up.
    """

    def __init__(self, like: PETSc.SNES, residual: Callable, F: PETSc.Vec, J: PETSc.Mat,
                 length: float, linesearch: str = "basic",
                 options: SolverOptions | None = None):
        self._context = _ApplyBorrowed()
        self.snes = snes = PETSc.SNES().create(comm=like.getComm())
        prefix = like.getOptionsPrefix() or ""
        snes.setOptionsPrefix(prefix)
        snes.setFunction(residual, F)
        snes.setJacobian(self._unchanged, J, J)
        stop_at_round_off(snes, J, length)
        with own_options(prefix, options).pushed(snes_linesearch_type=linesearch):
            snes.setFromOptions()
        snes.getKSP().setType(PETSc.KSP.Type.PREONLY)

    @staticmethod
    def _unchanged(snes, x, J, P) -> None:
        """The Jacobian callback: nothing to assemble (the borrowed factors stand for it)."""

    def solve(self, ksp: PETSc.KSP, x: PETSc.Vec, like: PETSc.SNES) -> bool:
        """Newton's chord from the guess in ``x`` on ``ksp``'s factors, to ``like``'s
        tolerances; whether it converged (``x`` is then the solution)."""
        self.snes.setTolerances(*like.getTolerances())
        pc = self.snes.getKSP().getPC()
        self._context.ksp = ksp
        pc.setType(PETSc.PC.Type.PYTHON)
        pc.setPythonContext(self._context)
        try:
            self.snes.solve(None, x)
        finally:
            # no Python PC outlives the solve: one left to PETSc's finalisation (a model the
            # user never destroyed) crashed the interpreter at exit
            pc.setType(PETSc.PC.Type.NONE)
            self._context.ksp = None
        return outcome(self.snes).converged

    def destroy(self) -> None:
        self.snes.destroy()


#: A step iterating on kept factors may take this many chord iterations more than the step that
#: factored them; one that takes more has the next step factor afresh.
LAG_SLACK = 4


class ChordBorrower:
    """Mixin of the SNES steppers whose Newton runs to convergence (backward Euler,
    generalized-alpha): :meth:`borrow_chord`, and :meth:`_newton` to solve a step with what was
    lent. The stepper has ``snes``, ``_lagged`` (its own solver is the direct chord of
    :func:`~petsoft.solvers.linear.factor_once_per_step`), ``options``, ``_residual_cb``,
    ``R``, ``J``,
    ``length``, ``_linesearch`` and ``_forget_rejected()``, and calls :meth:`_destroy_chord`
    when destroyed."""

    _borrowed = None
    _chord: BorrowedChord | None = None
    #: the stepper's default line search, which the borrowed chord uses too
    _linesearch = "basic"
    _keep_factors = False
    #: (the stepper's SNES, chord iterations of the step that factored) while factors are kept
    _kept: tuple[PETSc.SNES, int] | None = None
    #: whether the last step's chord on lent or kept factors failed (the step was then solved
    #: by the stepper's own solver): the factors are too far from the step's Jacobian
    borrowed_failed = False

    def new_run(self) -> None:
        super().new_run()
        self._borrowed = None
        self._kept = None

    def keep_factors(self, on: bool) -> None:
        """Whether the steps of the coming runs keep the factorisation of their own chord for
        the next steps (until one needs :data:`LAG_SLACK` more iterations than the step that
        made it), where the stepper's solver is the default direct chord and its Jacobian is
        not constant (a constant one is factored once anyway). The run's steps
        then converge to the same tolerances from other Jacobians: the trajectory equals one
        made without to that tolerance, not bit for bit. Calling it again (``True``) makes the
        next step factor afresh: a checkpointed run (:class:`petsoft.dynamics.simulate.
        Simulation`) does after each checkpoint, so that a run restarted there, whose first
        step factors afresh, repeats the uninterrupted one bit for bit.

        Where the stepper's solver is algebraic multigrid, its hierarchy's interpolation is
        kept the same way (:meth:`petsoft.dynamics.implicit.SolverReuse._keeps_multigrid`),
        and calling this renews it at the next step."""
        self._keep_factors = bool(on)
        self._kept = None
        self.new_run()

    def borrow_chord(self, ksp: PETSc.KSP | None) -> None:
        """Solve the next step's Newton systems by ``ksp``, set up on an approximation of the
        step Jacobian (the exact one at the previous step's end, factored for the forward
        sensitivities), instead of assembling and factoring one. For that step only, and only
        where the stepper's own solver is the default direct chord; a chord that fails there is
        repeated by the stepper's own solver. ``None`` withdraws it."""
        self._borrowed = ksp

    def _newton(self, q1: PETSc.Vec) -> PETSc.SNES:
        """Newton from the guess in ``q1``: on the factors lent for this step, if any, else
        (or when that fails) by the stepper's own solver; returns the SNES that solved."""
        borrowed, self._borrowed = self._borrowed, None
        kept, self._kept = self._kept, None
        self.borrowed_failed = False
        # the factors kept are the stepper's own solver's, while that SNES is kept across steps
        # (a replaced SNES took them with it)
        own = kept is not None and kept[0] is self.snes
        if borrowed is None and own:
            borrowed = self.snes.getKSP()
        if borrowed is not None and self._lagged:
            if self._chord is None:
                self._chord = BorrowedChord(self.snes, self._residual_cb, self.R, self.J,
                                            self.length, self._linesearch, self.options)
            guess = q1.copy()
            try:
                converged = self._chord.solve(borrowed, q1, self.snes)
                if not self._forget_rejected() and converged:   # (forgotten either way)
                    if own and self._chord.snes.getIterationNumber() <= kept[1] + LAG_SLACK:
                        self._kept = kept
                    return self._chord.snes
                self.borrowed_failed = True
                guess.copy(q1)
            finally:
                guess.destroy()
        solve_newton(self.snes, q1, self._lagged, self._forget_rejected)
        if (self._keep_factors and self._lagged and not self.system.jacobian_is_constant
                and outcome(self.snes).converged):
            # (the SNES refactors only when it assembles again, at a step that factors afresh)
            self._kept = (self.snes, self.snes.getIterationNumber())
        return self.snes

    def _destroy_chord(self) -> None:
        if self._chord is not None:
            self._chord.destroy()
            self._chord = None
