"""Linear solves with a changing matrix on a factorisation kept from an earlier one.

A forward-sensitivity run (:meth:`petsoft.calibration.forward.ForwardModel.jacobian`) solves
with the exact step Jacobian J_n at every step, one tangent solve per parameter. A direct solve
factors J_n at every step, and on 10-node elements that factorisation is most of the step's
cost. J_n moves little from one 2 ms step to the next (it is mostly stiffness and mass), so
:class:`LaggedFactors` solves J_n x = b by GMRES preconditioned with the factors of an earlier
J_m: the Krylov method corrects for the difference, and converges in a few iterations while
J_m^-1 J_n is near the identity. The factors are renewed only when a solve needs more than
:data:`REFACTOR_ITERATIONS` iterations or the iterations made on them since they were made
exceed what a factorisation costs (:data:`FACTOR_IN_ITERATIONS`: a run with many parameters
solves many times a step) -- then at the next matrix, that solve has converged -- or when a
solve fails (then at once, and the solve is repeated on fresh factors), or when the caller asks
(:meth:`LaggedFactors.renew`). On factors of the current matrix a solve is one substitution.

Accuracy: GMRES is left-preconditioned, so the norm it reduces is that of the preconditioned
residual J_m^-1 (b - J_n x) = (J_m^-1 J_n)(x* - x); with J_m^-1 J_n near the identity its
relative size is the relative error of x, and :data:`RTOL` bounds that. The sensitivities then
differ from those of the every-step direct solve by about that much (the tests measure it).

The factors can still be lent (:attr:`LaggedFactors.factors`, a ``preonly`` KSP on the same PC)
to the next time step's Newton chord (:mod:`petsoft.solvers.borrowed_chord`), which needs only
an approximation of the Jacobian.
"""

from __future__ import annotations

from petsc4py import PETSc

from petsoft.solvers.convergence import outcome

#: A solve that needs more GMRES iterations than this has the next matrix factored afresh.
#: Each iteration costs a forward and back substitution with the factors and a product with the
#: matrix, far less than a factorisation: on the 10-node plate of petsoft/solvers/README.md
#: (3672 dofs, PETSc's LU on 2 ranks) PETSc counted 1.6e8 flops a factorisation against 1.9e6 a
#: substitution (substitutions run at memory speed, so the time ratio is smaller). But the next
#: step's chord iterates on the same factors, and each of its iterations costs a residual
#: evaluation too: on that plate (350 steps) 6 made 124 factorisations with 4.5 iterations a
#: solve and 8.3 chord iterations a step (7.2 on the previous step's exact factors), 8 made 60
#: with 6.2 and 10.0, 10 made 34 with 7.6 and 12.3 and four chords that failed. 6 stays clear
#: of that; whether 8 is faster is for a timing on a quiet machine.
REFACTOR_ITERATIONS = 6
#: Relative tolerance of the preconditioned residual: each solve's relative error from the
#: lag. A least-squares fit's Gauss-Newton step needs far less; the errors add up over the
#: steps: on the plate above (350 steps) the sensitivities differed from the every-step direct
#: ones by 2.7e-9 / 1.8e-10 / 2.9e-11 (of their largest) at 1e-10 / 1e-11 / 1e-12, with 97 / 124
#: / 142 factorisations and 4.7 / 4.5 / 4.3 iterations a solve. 1e-11 keeps them within 1e-9.
RTOL = 1e-11
#: A solve that has not converged after this many iterations is repeated on fresh factors.
MAX_IT = 30
#: What a factorisation costs in GMRES iterations on kept factors (each a forward and back
#: substitution and a product with the matrix): when the iterations made on the factors since
#: they were made exceed it, the next matrix is factored. One solve a step rarely gets there
#: before :data:`REFACTOR_ITERATIONS` renews them; a run with many parameters does: a
#: scoring run of 8 parameters on the realistic damping taper's 10-node model (4641 dofs, 350
#: steps) made ~34 GMRES iterations a step on factors renewed every ~2.5 steps, where a
#: factorisation costs about 20 (MUMPS' LDL^T 18-20 ms against 0.6 ms a substitution and 0.4 ms
#: a product, measured side by side in one process).
FACTOR_IN_ITERATIONS = 20


class LaggedFactors:
    """GMRES on a matrix that changes between solves, preconditioned with the factors of the
    matrix as it was at the last refactoring.

    Parameters
    ----------
    ksp : PETSc.KSP
        A direct solver (``preonly`` with LU, Cholesky or redundant LU,
        :func:`~petsoft.solvers.linear.is_direct`), its operator the matrix that will change in
        place. It becomes GMRES with the same PC; the caller keeps owning it.

    Attributes
    ----------
    factorisations, solves, iterations, max_iterations : int
        Counts since construction: factorisations made, solves, GMRES iterations in all, the
        most in one solve.
    """

    def __init__(self, ksp: PETSc.KSP):
        self.ksp = ksp
        ksp.setType(PETSc.KSP.Type.GMRES)
        ksp.setTolerances(rtol=RTOL, atol=0.0, max_it=MAX_IT)
        # (GMRES' default: left preconditioning, the preconditioned residual norm; see above)
        self._lender = None
        self._last = ksp
        self._stale = True
        #: whether the factors are of the matrix as it is now (made since its last change)
        self._current = False
        #: GMRES iterations made on the factors since they were made
        self._since = 0
        self.factorisations = self.solves = self.iterations = self.max_iterations = 0

    def operator_changed(self) -> None:
        """The matrix has new values (a new step): factor them if the last solves asked for it
        (or nothing was factored yet)."""
        self._current = False
        if self._stale:
            self._factor()

    def renew(self) -> None:
        """Factor at the next :meth:`operator_changed` (e.g. the Newton chord sharing the
        factors failed on them)."""
        self._stale = True

    def _factor(self) -> None:
        pc = self.ksp.getPC()
        pc.setReusePreconditioner(False)
        # PCSetUp refactors when the operator's values changed since the last set-up (a
        # numeric factorisation on the symbolic one kept: the pattern is the same)
        pc.setUp()
        pc.setReusePreconditioner(True)
        self.factorisations += 1
        self._stale = False
        self._current = True
        self._since = 0

    def solve(self, rhs: PETSc.Vec, out: PETSc.Vec) -> None:
        """out = A^-1 rhs to :data:`RTOL`; a solve that fails is repeated on fresh factors (the
        caller checks the result's :func:`~petsoft.solvers.convergence.outcome` on
        :attr:`last_solver`). On factors of the matrix as it is now the solve is one
        substitution (the ``preonly`` :attr:`factors`: GMRES would add a product and an
        orthogonalisation to reach the same answer)."""
        if self._current:
            self._last = self.factors
            self.factors.solve(rhs, out)
            its = 1
        else:
            ksp = self._last = self.ksp
            ksp.solve(rhs, out)
            its = ksp.getIterationNumber()
            if not outcome(ksp).converged:
                self._factor()
                ksp.solve(rhs, out)
                its += ksp.getIterationNumber()
            else:
                self._since += its
                if its > REFACTOR_ITERATIONS or self._since > FACTOR_IN_ITERATIONS:
                    self._stale = True
        self.solves += 1
        self.iterations += its
        self.max_iterations = max(self.max_iterations, its)

    @property
    def last_solver(self) -> PETSc.KSP:
        """The KSP that made the last :meth:`solve` (its outcome is that solve's)."""
        return self._last

    @property
    def factors(self) -> PETSc.KSP:
        """A ``preonly`` KSP applying the current factors (the same PC, never set up again by
        it): for :meth:`~petsoft.solvers.borrowed_chord.ChordBorrower.borrow_chord`."""
        if self._lender is None:
            lender = PETSc.KSP().create(comm=self.ksp.getComm())
            lender.setType(PETSc.KSP.Type.PREONLY)
            lender.setPC(self.ksp.getPC())
            self._lender = lender
        return self._lender

    def stats(self) -> dict:
        """The counts (class docstring) as a dict."""
        return {"factorisations": self.factorisations, "solves": self.solves,
                "iterations": self.iterations, "max_iterations": self.max_iterations}

    def destroy(self) -> None:
        """Destroy the lender (the KSP given stays the caller's)."""
        if self._lender is not None:
            self._lender.destroy()
            self._lender = None
