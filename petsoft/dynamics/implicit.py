"""One-step implicit integrators solved for the new displacement by Newton (SNES) or TAO.

With h the step, q0, v0 the old state and q1 the unknown:

=============  ====================================  ==========================================
method         velocity update                        equation R(q1) = 0
=============  ====================================  ==========================================
be / si        v1 = (q1 - q0)/h                        M(v1-v0)/h + grad W(q1) + D v1 - f(t1)
midpoint       v1 = 2(q1-q0)/h - v0                    M(v1-v0)/h + grad_d W + D vm - f(tm)
trapezoidal    v1 = 2(q1-q0)/h - v0                    M(v1-v0)/h + (gW0 + gW1)/2 + D vm - (f0+f1)/2
=============  ====================================  ==========================================

``si`` is ``be`` with exactly one Newton step from q1 = q0 + h v0 (SNES ``ksponly``). The
midpoint rule uses Gonzalez's discrete gradient grad_d W = grad W(qm) + c dq, c chosen so that
grad_d W . dq = W(q1) - W(q0): it is second order and conserves the energy of a nonlinear
undamped body exactly (to the Newton tolerance), where the plain midpoint rule conserves only
quadratic energies. The Jacobian a M + b K + c K0 ignores the rank-one correction's derivative.

With a Maxwell branch (``[viscoelastic]``, :mod:`petsoft.physics.viscoelastic`) every residual
gains the branch force g K0 w(q1) (backward Euler: w = (q1 - z0)/(1 + h/tau); midpoint and
trapezoidal: w = ((q0 + q1)/2 - z0)/(1 + h/(2 tau))), the Jacobian the matching multiple of K0,
and an accepted step updates the branch's internal variable z and books its dissipation.

Solvers by options (``prefix`` the integrator's): Newton (SNES ``newtonls``) on the assembled
Jacobian by default; ``-<prefix>petsoft_jacobian shell`` keeps the Jacobian unassembled, a
MatShell with CG + Jacobi (:mod:`petsoft.dynamics.matrix_free`); ``-<prefix>snes_type ngs`` is
nonlinear Gauss-Seidel, or with ``-<prefix>petsoft_ngs jacobi`` nonlinear Jacobi, one 3x3 Newton
update per node (:mod:`petsoft.dynamics.nonlinear_gs`). TAO keeps the assembled Hessian.

Every step also returns the work terms paired with dq = q1 - q0 by the method itself (damping,
tractions, the reactions of moving supports), so that the energy balance of
:mod:`petsoft.dynamics.energy` closes exactly for the midpoint rule and exposes the numerical
dissipation of the others.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from petsc4py import PETSc

from petsoft.dynamics import matrix_free, nonlinear_gs
from petsoft.dynamics.integrators import SCHEMES, scheme
from petsoft.dynamics.interfaces import StepperDefaults, length_scale
from petsoft.errors import InvertedElementError, without_frames
from petsoft.solvers.borrowed_chord import ChordBorrower
from petsoft.solvers.convergence import on_any_rank, outcome, stop_at_round_off
from petsoft.solvers.linear import reuse_across_iterations
from petsoft.solvers.options import SolverOptions, own_options, scoped_defaults, with_options

METHODS = ("be", "si", "midpoint", "trapezoidal")
# The discrete-gradient correction is applied when its defect exceeds this many ulps of the
# energies: below, it is noise that would stall Newton; the energy error it leaves per step is
# then ~1e4 eps |W| (1e-12 relative).
NOISE_FACTOR = 1.0e4


@dataclass
class StepReport:
    """What one step did: solver effort and the work terms of the energy balance."""

    newton_iterations: int = 0
    linear_iterations: int = 0
    dissipated: float = 0.0        # dq . (damping force), >= 0
    external_work: float = 0.0     # dq . tractions
    boundary_work: float = 0.0     # dq . reactions (moving supports)
    converged: bool = True
    reason: str = ""


class NoBranch:
    """Stands in for the Maxwell branch of a system without one (e.g. mass-spring)."""

    active = False

    def add_force(self, q1, out, work) -> None:
        pass

    def jacobian_coefficient(self) -> float:
        return 0.0

    def incremental_potential(self, q1, work) -> float:
        return 0.0

    def accept(self, q1) -> float:
        return 0.0


def branch_of(system):
    """The system's stepping Maxwell branch, or a :class:`NoBranch` that does nothing."""
    branch = system.viscoelastic
    return branch if branch is not None and branch.stepping else NoBranch()


class SolverReuse:
    """Mixin of the SNES-based integrators: whether a step keeps the previous step's SNES.

    The integrator sets ``self.snes`` and ``self.system``, calls :meth:`new_run` when a run
    starts or a step fails, and asks :meth:`keeps_solver` before each step.
    """

    _solver_used = False
    snes = None     # the subclass's SNES, once it has one
    #: whether the run keeps its factors (ChordBorrower.keep_factors sets it): a changing
    #: matrix then keeps its multigrid solver across steps too
    _keep_factors = False
    #: linear iterations of the first step of the kept multigrid solver (None: not measured)
    _multigrid_its: int | None = None

    def new_run(self) -> None:
        """The next step sets up a new solver (a caller's options may have changed)."""
        self._solver_used = False
        self._multigrid_its = None

    def keeps_solver(self) -> bool:
        """Whether this step keeps the previous step's SNES (and its factorisation's analysis).

        True within a run (since :meth:`new_run`) when the system has a constant Jacobian:
        ``assemble_combination(..., reuse=True)`` then leaves the matrix untouched and PETSc
        keeps its factorisation (or multigrid set-up). A new SNES per step refactored the same
        matrix every step: 70 % of a linear bar's forward run was MUMPS factoring (-log_view).

        Also true when the preconditioner's set-up depends on the matrix alone
        (:data:`REPEATABLE_PCS`: a factorisation keeps its symbolic analysis, the pattern never
        changes, and refactors the new values): a new SNES, KSP and MUMPS instance per step
        was most of a small model's step (7.5 of 13 ms at 351 dofs). Not for algebraic
        multigrid, whose set-up draws random numbers from a generator that survives it --
        unless the run keeps its factors, when the multigrid keeps its interpolation
        (:meth:`_keeps_multigrid`).

        A run restarted from a checkpoint still computes bit for bit what the uninterrupted run
        did: its first step sets the solver up on the same matrix, and a kept solver computes
        the same factors or iterates from the same matrix as a new one would (a kept multigrid
        is renewed where the restart sets up its first).
        """
        if not self._solver_used or self.snes is None:
            self._solver_used = True
            return False
        if self.system.jacobian_is_constant:
            return True
        ksp = self.snes.getKSP()
        return repeatable_setup(ksp) or self._keeps_multigrid(ksp)

    def _keeps_multigrid(self, ksp: PETSc.KSP) -> bool:
        """Whether this step keeps the previous step's algebraic multigrid (only while
        :attr:`_keep_factors`): its set-up on the new matrix then reuses the interpolation
        (PETSc's ``-pc_gamg_reuse_interpolation``, on by default) and only recomputes the
        coarse operators: on one backward-Euler step of a bent neo-Hookean bar at 306,372 dofs
        on 2 ranks (``bench_step.py``) 0.6 s against 2.4 s for a new hierarchy, a quarter of
        the step. A DOLFINx time loop does the same (its KSP lives across steps).

        Not bit for bit a new solver (the interpolation is an earlier matrix's): the steps
        converge to the same tolerances. A run that keeps it renews it where a restart would
        (:meth:`~petsoft.solvers.borrowed_chord.ChordBorrower.keep_factors` after a
        checkpoint, a failed step), and when a step's linear iterations exceed twice the first
        kept step's plus :data:`MULTIGRID_SLACK` (the interpolation has gone stale): a function
        of the run since its last renewal, so a restart repeats the run bit for bit."""
        if not self._keep_factors or not reuses_interpolation(ksp):
            return False
        its = self.snes.getLinearSolveIterations()      # the previous step's
        if self._multigrid_its is None:
            self._multigrid_its = its
            return True
        if its > 2 * self._multigrid_its + MULTIGRID_SLACK:
            self._multigrid_its = None
            return False
        return True


#: Preconditioners whose set-up is a function of the matrix only (no state carried between
#: set-ups, no random numbers): keeping them across steps changes no number.
REPEATABLE_PCS = frozenset({"lu", "cholesky", "jacobi", "pbjacobi", "sor", "ilu", "icc", "none",
                            "bjacobi", "asm", "eisenstat"})


#: Linear iterations a step may take beyond twice the first step's on a kept multigrid
#: hierarchy before the next step sets up a new one (SolverReuse._keeps_multigrid).
MULTIGRID_SLACK = 10


def reuses_interpolation(ksp: PETSc.KSP) -> bool:
    """Whether ``ksp``'s preconditioner is algebraic multigrid that, set up again on a new
    matrix, keeps its interpolation (``-<prefix>pc_gamg_reuse_interpolation``, PETSc's default
    true): its new set-up draws no random numbers, only recomputes the coarse operators."""
    if ksp.getPC().getType() != PETSc.PC.Type.GAMG:
        return False
    prefix = ksp.getOptionsPrefix() or ""
    return PETSc.Options().getBool(prefix + "pc_gamg_reuse_interpolation", True)


def repeatable_setup(ksp: PETSc.KSP) -> bool:
    """Whether ``ksp``'s preconditioner (and, for block Jacobi or additive Schwarz, its blocks')
    is in :data:`REPEATABLE_PCS`."""
    pc = ksp.getPC()
    kind = pc.getType()
    if kind == "redundant":
        # petsoft's default on several ranks (an LU on every rank); its inner solver is named
        # only by options (petsc4py 3.18 has no accessor)
        inner = PETSc.Options().getString((ksp.getOptionsPrefix() or "") + "redundant_pc_type",
                                          "lu")
        return inner in REPEATABLE_PCS
    if kind not in REPEATABLE_PCS:
        return False
    if kind in ("bjacobi", "asm"):
        try:
            subs = pc.getBJacobiSubKSP() if kind == "bjacobi" else pc.getASMSubKSP()
        except PETSc.Error:        # not set up yet: the sub-solvers are the defaults (ILU)
            return True
        return all(repeatable_setup(sub) for sub in subs)
    return True


class ImplicitIntegrator(ChordBorrower, SolverReuse, StepperDefaults):
    """Backward Euler, semi-implicit, (discrete-gradient) midpoint or trapezoidal steps.

    Parameters
    ----------
    system : DynamicSystem
    method : {"be", "si", "midpoint", "trapezoidal"}
    solver : {"snes", "tao"}
        ``tao`` minimises the incremental potential (backward Euler only: it is the one method
        whose step is a minimisation).
    prefix : str
        Options prefix of the SNES/TAO.
    options : SolverOptions, optional
        The options (an experiment's ``[petsc]`` table) pushed under ``prefix`` while the
        solver is set up and steps.
    """

    def __init__(self, system, method: str = "be", solver: str = "snes", prefix: str = "",
                 options: SolverOptions | None = None):
        if method not in METHODS:
            raise ValueError(f"unknown implicit method {method!r}")
        self.scheme = scheme(method)
        if solver == "tao" and not self.scheme.minimization:
            raise ValueError("the optimisation form (TAO) exists for backward Euler only")
        self.system, self.method, self.solver = system, method, solver
        self.length = length_scale(system)   # the round-off floor of Newton's residual
        s = system
        self.J = s.create_matrix()
        modes = s.near_nullspace()
        if modes is not None:
            self.J.setNearNullSpace(modes)
        vecs = [s.create_vec() for _ in range(8)]
        (self.R, self.q0, self.v0, self.f0, self.f1, self._a, self._b, self._c) = vecs
        self.h = None
        self.t0 = 0.0
        self._dg_c = 0.0
        self._branch = NoBranch()
        self.options = own_options(prefix, options)
        self.prefix = self.options.prefix
        self.snes = self.tao = None
        self.operator = self.shell = None   # the matrix-free Jacobian, when the options ask
        self.ngs = None                     # the per-node update of SNES ngs
        self._new_solver()
        self.new_run()

    @with_options
    def _new_solver(self) -> None:
        """A fresh SNES or TAO (with KSP and PC): see :meth:`step` for why one per step."""
        for obj in (self.snes, self.tao):
            if obj is not None:
                obj.destroy()
        s, prefix = self.system, self.prefix
        linear = s.linear_defaults
        if self.solver == "snes":
            self.snes = snes = PETSc.SNES().create(comm=s.comm)
            snes.setOptionsPrefix(prefix)
            if self.scheme.one_newton_step:
                snes.setType(PETSc.SNES.Type.KSPONLY)
            else:
                snes.setType(PETSc.SNES.Type.NEWTONLS)
            snes.setFunction(self._residual_cb, self.R)
            # -<prefix>petsoft_jacobian shell: Newton on an unassembled Jacobian (MatShell),
            # CG + Jacobi unless the options say otherwise (petsoft.dynamics.matrix_free)
            shell = matrix_free.requested(prefix)
            if shell and self.shell is None:
                self.operator = matrix_free.StepOperator(s)
                self.shell = self.operator.create_mat()
            J = self.shell if shell else self.J
            snes.setJacobian(self._jacobian_cb, J, J)
            # stol: the residual carries 1/h^2 round-off; a Newton update below 1e-12 |q| is
            # converged
            snes.setTolerances(rtol=1e-10, atol=1e-12, stol=1e-12, max_it=25)
            stop_at_round_off(snes, self.operator if shell else self.J, self.length)
            self.ksp = snes.getKSP()
            linear(self.ksp)
            # The mass term keeps the step's energy convex near the old state: full Newton steps.
            # Not with dry friction or quadratic drag: their force saturates (friction: a
            # sigmoid of width friction.speed), where full Newton steps cycle around the stop;
            # backtracking on the residual norm converges (the step's potential is convex).
            terms = s.velocity_terms
            search = self._linesearch = ("bt" if terms is not None and terms.nonlinear
                                         else "basic")
            defaults = {prefix + "snes_linesearch_type": search}
            if shell:
                defaults.update({prefix + "ksp_type": "cg", prefix + "pc_type": "jacobi"})
            with scoped_defaults(**defaults):
                snes.setFromOptions()
            self._lagged = reuse_across_iterations(snes, s, chord=not shell)
            # -<prefix>snes_type ngs: petsoft's per-node update (petsoft.dynamics.nonlinear_gs)
            self.ngs = nonlinear_gs.install(self, snes, prefix)
        else:
            self.tao = tao = PETSc.TAO().create(comm=s.comm)
            tao.setOptionsPrefix(prefix)
            tao.setType(PETSc.TAO.Type.NLS)
            tao.setObjectiveGradient(self._objective_cb, self.R.duplicate())
            tao.setHessian(self._hessian_cb, self.J, self.J)
            tao.setTolerances(gatol=1e-12, grtol=0.0, gttol=1e-10)
            tao.setMaximumIterations(25)
            self.ksp = tao.getKSP()
            linear(self.ksp)
            tao.setFromOptions()

    # -- the discrete equations ---------------------------------------------------------------
    def _velocity(self, q1: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """v1 as a function of q1 (see the table above)."""
        h = self.h
        q1.copy(out)
        out.axpy(-1.0, self.q0)
        if self.scheme.force_at == "end":
            out.scale(1.0 / h)
        else:
            out.scale(2.0 / h)
            out.axpy(-1.0, self.v0)
        return out

    def _terms(self, q1: PETSc.Vec, full: PETSc.Vec) -> dict:
        """Residual with all rows in ``full``; returns the damping and traction vectors used."""
        s, h = self.system, self.h
        v1 = self._velocity(q1, self._a)
        # inertia M (v1 - v0)/h
        self._b.waxpy(-1.0, self.v0, v1)
        s.M.mult(self._b, full)
        full.scale(1.0 / h)
        grad = self._c
        damping = s.create_vec()
        if self.scheme.force_at == "end":
            s.internal_gradient(q1, grad)
            s.damping_apply(v1, damping)
            load = self.f1
        elif self.scheme.force_at == "midpoint":
            qm = self._b
            qm.waxpy(1.0, self.q0, q1)
            qm.scale(0.5)
            s.internal_gradient(qm, grad)
            dq = qm  # reuse: dq = q1 - q0
            dq.waxpy(-1.0, self.q0, q1)
            dq2 = dq.dot(dq)
            self._dg_c = 0.0
            if dq2 > 0.0:
                W1 = s.elastic_energy(q1)
                gdq = grad.dot(dq)
                defect = (W1 - self._W0) - gdq
                # The defect is O(|dq|^3); when it is at the round-off level of the energies the
                # correction would only amplify noise by 1/|dq|^2 (and stall Newton at small
                # steps): the plain midpoint gradient is then exact to working precision.
                noise = NOISE_FACTOR * np.finfo(float).eps * (abs(W1) + abs(self._W0) + abs(gdq))
                if abs(defect) > noise:
                    self._dg_c = defect / dq2
                    grad.axpy(self._dg_c, dq)
            vm = dq
            vm.scale(1.0 / h)                              # (v0 + v1)/2 = (q1 - q0)/h
            s.damping_apply(vm, damping)
            load = self.fm
        else:  # trapezoidal
            s.internal_gradient(q1, grad)
            grad.axpy(1.0, self.g0)
            grad.scale(0.5)
            vm = self._b
            vm.waxpy(1.0, self.v0, v1)
            vm.scale(0.5)
            s.damping_apply(vm, damping)
            load = self.fm
        full.axpy(1.0, grad)
        full.axpy(1.0, damping)
        full.axpy(-1.0, load)
        self._branch.add_force(q1, full, grad)   # grad is free again: the branch's work vector
        return {"damping": damping, "load": load}

    def _residual(self, q1: PETSc.Vec, R: PETSc.Vec) -> bool:
        try:
            terms = self._terms(q1, R)
        except InvertedElementError as err:
            # without the frames it holds (petsoft.errors.without_frames)
            self._bad = without_frames(err)
            R.set(np.inf)
            return False
        terms["damping"].destroy()
        self.system.zero_prescribed(R)
        return True

    def _jacobian_coefficients(self) -> tuple[float, float, float]:
        h, s = self.h, self.system
        branch = self._branch.jacobian_coefficient()
        if self.scheme.force_at == "end":
            return 1.0 / h**2 + s.alpha / h, 1.0, s.beta / h + branch
        return 2.0 / h**2 + s.alpha / h, 0.5, s.beta / h + branch

    def _jacobian(self, q1: PETSc.Vec, P: PETSc.Mat) -> None:
        a, b, c = self._jacobian_coefficients()
        if self.scheme.force_at == "midpoint":
            state = self._b
            state.waxpy(1.0, self.q0, q1)
            state.scale(0.5)
        else:
            state = q1
        # the damping term is evaluated at v1 (be, si) or vm = (q1 - q0)/h: dv/dq1 = 1/h either
        # way; the velocity terms are linearised at the velocity of the last residual.
        # P: an assembled matrix, the matrix-free MatShell or a StepOperator (NGS blocks)
        matrix_free.fill_jacobian(self.system, state, a, b, c, P, 1.0 / self.h)

    # PETSc callbacks (thin)
    def _residual_cb(self, snes, x, F):
        self._residual(x, F)

    def _jacobian_cb(self, snes, x, J, P):
        self._jacobian(x, P)

    def _objective_cb(self, tao, x, G):
        if not self._residual(x, G):
            return np.inf
        s, h = self.system, self.h
        # incremental potential of backward Euler:
        # |q - q0 - h v0|^2_M / (2h^2) + W(q) + |q - q0|^2_D / (2h) - f1 . q
        d = self._a
        d.waxpy(-1.0, self.q0, x)
        d.axpy(-h, self.v0)
        s.M.mult(d, self._b)
        value = 0.5 * d.dot(self._b) / h**2 + s.elastic_energy(x) - self.f1.dot(x)
        terms = s.velocity_terms
        if terms is not None and terms.active:
            # h psi((q - q0)/h): psi = v^T D v / 2 + the drag and friction potentials
            d.waxpy(-1.0, self.q0, x)
            d.scale(1.0 / h)
            value += h * s.dissipation_potential(d)
        elif s.alpha or s.beta:
            d.waxpy(-1.0, self.q0, x)
            damp = s.damping_apply(d, s.create_vec())
            value += 0.5 * d.dot(damp) / h
            damp.destroy()
        return value + self._branch.incremental_potential(x, self._b)

    def _hessian_cb(self, tao, x, H, P):
        self._jacobian(x, P)

    # -- stepping ---------------------------------------------------------------------------------
    def prepare(self, t0: float, q0: PETSc.Vec, v0: PETSc.Vec, h: float) -> None:
        """Set the old state and the loads of the step [t0, t0 + h]."""
        s = self.system
        self.t0, self.h = t0, h
        q0.copy(self.q0)
        v0.copy(self.v0)
        self._branch = branch_of(s)
        if not isinstance(self._branch, NoBranch):
            self._branch.prepare(SCHEMES[self.method].maxwell, h, q0)
        t1 = t0 + h
        gravity = s.gravity
        s.tractions(t1, self.f1)
        self.tractions1 = self.f1.copy()
        self.f1.axpy(1.0, gravity)
        if self.scheme.force_at == "midpoint":
            self.fm = s.tractions(t0 + 0.5 * h, s.create_vec())
            self.tractions_m = self.fm.copy()
            self.fm.axpy(1.0, gravity)
            self._W0 = s.elastic_energy(q0)
        elif self.scheme.force_at == "trapezoidal":
            t0_load = s.tractions(t0, s.create_vec())
            self.tractions_m = t0_load.copy()
            self.tractions_m.axpy(1.0, self.tractions1)
            self.tractions_m.scale(0.5)
            self.fm = self.tractions_m.copy()
            self.fm.axpy(1.0, gravity)
            t0_load.destroy()
            self.g0 = s.internal_gradient(q0, s.create_vec())

    def _forget_rejected(self) -> bool:
        """Whether the last solve met an inverted element on some rank (forgotten: the solve
        is repeated, on every rank)."""
        bad, self._bad = self._bad is not None, None
        return on_any_rank(self.system.comm, bad)

    @with_options
    def step(self, t0: float, q0: PETSc.Vec, v0: PETSc.Vec, h: float,
             q1: PETSc.Vec, v1: PETSc.Vec) -> StepReport:
        """Advance (q0, v0) at t0 by h into (q1, v1); returns the step's report."""
        s = self.system
        self.prepare(t0, q0, v0, h)
        self._bad = None
        # predictor q0 + h v0, with the supports at their new position
        q0.copy(q1)
        q1.axpy(h, v0)
        s.apply_prescribed(q1, t0 + h)
        report = StepReport()
        # A fresh solver each step: algebraic multigrid keeps state between set-ups (its random
        # generator survives KSPReset), and a run restarted from a checkpoint must compute
        # bit for bit what the uninterrupted run did. Creating a SNES costs microseconds.
        # Except where keeps_solver says a kept one computes the same (a constant Jacobian,
        # a set-up that depends on the matrix alone), or a run keeps its multigrid
        # interpolation until a renewal a restart repeats.
        if not self.keeps_solver():
            self._new_solver()
        if self.solver == "snes":
            snes = self._newton(q1)
            report.newton_iterations = snes.getIterationNumber()
            report.linear_iterations = snes.getLinearSolveIterations()
            done = outcome(snes)
            report.converged, report.reason = done.converged, done.reason
        else:
            self.tao.setSolution(q1)
            self.tao.solve(q1)
            report.newton_iterations = self.tao.getIterationNumber()
            report.linear_iterations = self.ksp.getIterationNumber()
            done = outcome(self.tao)
            report.converged, report.reason = done.converged, done.reason
        if on_any_rank(s.comm, self._bad is not None):
            report.converged = False
            report.reason += f" ({self._bad or 'an element inverted on another rank'})"
        if not report.converged:
            self.new_run()
            return report
        s.apply_prescribed(q1, t0 + h)
        self._velocity(q1, v1)
        self._work_terms(q1, report)
        # the branch's internal variable moves only with an accepted step
        report.dissipated += self._branch.accept(q1)
        return report

    def _work_terms(self, q1: PETSc.Vec, report: StepReport) -> None:
        full = self.system.create_vec()
        terms = self._terms(q1, full)
        dq = self.system.create_vec()
        dq.waxpy(-1.0, self.q0, q1)
        report.dissipated = dq.dot(terms["damping"])
        tractions = self.tractions1 if self.scheme.force_at == "end" else self.tractions_m
        report.external_work = dq.dot(tractions)
        # the residual's prescribed rows are the reactions the supports exert; free rows ~ 0
        report.boundary_work = dq.dot(full)
        for v in (full, dq, terms["damping"]):
            v.destroy()

    def destroy(self) -> None:
        self._destroy_chord()
        for obj in (self.snes, self.tao, self.J, self.R, self.q0, self.v0, self.f0, self.f1,
                    self._a, self._b, self._c, self.shell):
            if obj is not None:
                obj.destroy()
