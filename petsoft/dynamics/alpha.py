"""Generalized-alpha (Chung-Hulbert 1993): petsoft's own step (default) and PETSc TS alpha2.

Both use the parameters of spectral radius r at infinity (weights on the new values):
alpha_m = (2 - r)/(1 + r), alpha_f = 1/(1 + r), gamma = 1/2 + alpha_m - alpha_f,
beta = (1 + alpha_m - alpha_f)^2 / 4.

Why petsoft has its own step: the method is second order only if the acceleration it starts from
is consistent. TS alpha2 (PETSc 3.18) estimates it on every (re)start from two backward-Euler
half steps, and on damped oscillators at r = 0.5 its error at a fixed time then falls only at
rate 0.94 (measured: tests/test_alpha.py), against 2.00 at r = 1 and 2.00 for the same scheme
started from a0 = M^-1 f(t0, q0, v0). :class:`GeneralizedAlpha` starts from that consistent a0
and solves each step with SNES like the other implicit integrators; :class:`AlphaTSIntegrator`
keeps the TS path (``--alpha-backend ts``).

TS alpha2 details:

The residual is the second-order form F(t, q, v, a) = M a + grad W(q) + D v - f(t) and its
Jacobian shift_a M + K(q) + shift_v D, which TS solves with its SNES. The spectral radius at
infinity r (``[time] alpha_radius``) reaches TS through the option ``-ts_alpha_radius``: in
petsc4py 3.18 ``TS.setAlphaRadius`` configures the first-order ``alpha`` scheme and leaves alpha2
at r = 1 (checked: amplitude ratio 1.00000 per step instead of 0.99021 at tau w = 1, r = 0.5).

Supports: with only fixed supports the prescribed rows are eliminated symmetrically (CG works);
with moving supports they are imposed as q_D - g(t) = 0 on identity rows, which makes the
Jacobian unsymmetric, so the default linear solver becomes GMRES.
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from petsoft.dynamics.implicit import NoBranch, SolverReuse, StepReport, branch_of
from petsoft.dynamics.interfaces import StepperDefaults, length_scale
from petsoft.dynamics.step_derivatives import mass_solver
from petsoft.errors import InvertedElementError, without_frames
from petsoft.physics.viscoelastic import MaxwellRule
from petsoft.solvers.borrowed_chord import ChordBorrower
from petsoft.solvers.convergence import on_any_rank, outcome, reason_name, stop_at_round_off
from petsoft.solvers.linear import reuse_across_iterations
from petsoft.solvers.options import SolverOptions, own_options, scoped_defaults, with_options


class AlphaTSIntegrator(StepperDefaults):
    """Generalized-alpha steps of a system with TS alpha2.

    Parameters
    ----------
    system : DynamicSystem or OscillatorSystem
    radius : float
        Spectral radius at infinity, 0 <= r <= 1 (1: no numerical damping; 0: strongest).
    prefix : str
        Options prefix of the TS (its SNES and KSP inherit it).
    options : SolverOptions, optional
        The options (an experiment's ``[petsc]`` table) pushed under ``prefix`` while the
        TS is set up and steps.
    """

    def __init__(self, system, radius: float = 0.5, prefix: str = "",
                 options: SolverOptions | None = None):
        self.system, self.radius = system, float(radius)
        self.length = length_scale(system)   # the round-off floor of Newton's residual
        s = system
        self.moving = bool(s.moving_boundary)
        self.J = s.create_matrix()
        modes = s.near_nullspace()
        if modes is not None:
            self.J.setNearNullSpace(modes)
        self.F = s.create_vec()
        self._grad = s.create_vec()
        self._damp = s.create_vec()
        self._load = s.create_vec()
        self._bad = None
        self.options = own_options(prefix, options)
        prefix = self.options.prefix
        ts = self.ts = PETSc.TS().create(comm=s.comm)
        ts.setOptionsPrefix(prefix)
        ts.setType(PETSc.TS.Type.ALPHA2)
        ts.setI2Function(self._residual_cb, self.F)
        ts.setI2Jacobian(self._jacobian_cb, self.J, self.J)
        ts.setErrorIfStepFails(False)
        ts.setMaxSNESFailures(1)
        snes = ts.getSNES()
        # stol: the residual carries 1/h^2 round-off; a Newton update below 1e-12 |q| is converged
        snes.setTolerances(rtol=1e-10, atol=1e-12, stol=1e-12, max_it=25)
        stop_at_round_off(snes, self.J, self.length)
        ksp = snes.getKSP()
        # the defaults ask whether the options name a solver: they are pushed already
        with self.options.pushed(ts_alpha_radius=repr(self.radius),
                                 snes_linesearch_type="basic"):
            s.linear_defaults(ksp)
            if self.moving:
                ksp.setType(PETSc.KSP.Type.GMRES)
            ts.setFromOptions()
        self.ksp = ksp
        self._last = None

    # -- callbacks -----------------------------------------------------------------------------
    def _residual_cb(self, ts, t, U, V, A, F):
        s = self.system
        try:
            s.internal_gradient(U, self._grad)
        except InvertedElementError as err:
            # without the frames it holds (petsoft.errors.without_frames)
            self._bad = without_frames(err)
            F.set(np.inf)
            return
        s.M.mult(A, F)
        F.axpy(1.0, self._grad)
        F.axpy(1.0, s.damping_apply(V, self._damp))
        F.axpy(-1.0, s.gravity)
        F.axpy(-1.0, s.tractions(t, self._load))
        if self.moving:
            rows = s.prescribed_offsets(F)
            target = U.duplicate()
            U.copy(target)
            s.apply_prescribed(target, t)
            F.getArray()[rows] = U.getArray(readonly=True)[rows] - target.getArray()[rows]
            target.destroy()
        else:
            s.zero_prescribed(F)

    def _jacobian_cb(self, ts, t, U, V, A, shift_v, shift_a, J, P):
        s = self.system
        s.assemble_combination(U, shift_a + shift_v * s.alpha, 1.0, shift_v * s.beta, P,
                               eliminate=not self.moving, velocity=shift_v)
        if self.moving:
            rows = s.prescribed_offsets(self.F) + self.F.getOwnershipRange()[0]
            P.zeroRows(rows.astype(PETSc.IntType), diag=1.0)

    # -- stepping --------------------------------------------------------------------------------
    def _continues(self, t0, q0, v0) -> bool:
        """Whether (t0, q0, v0) is where TS stopped (then its acceleration history is valid)."""
        if self._last is None:
            return False
        t_last, q_last, v_last = self._last
        if abs(t0 - t_last) > 1e-12 * max(1.0, abs(t0)):
            return False
        dq = q0.copy()
        dq.axpy(-1.0, q_last)
        dv = v0.copy()
        dv.axpy(-1.0, v_last)
        same = dq.norm(PETSc.NormType.INFINITY) == 0.0 and dv.norm(PETSc.NormType.INFINITY) == 0.0
        dq.destroy()
        dv.destroy()
        return same

    @with_options
    def step(self, t0, q0, v0, h, q1, v1) -> StepReport:
        s, ts = self.system, self.ts
        if not self._continues(t0, q0, v0):
            # (Re)start: TS alpha2 estimates the initial acceleration itself on a restart.
            self._u = q0.copy()
            self._v = v0.copy()
            ts.setSolution2(self._u, self._v)
            ts.setTime(t0)
        ts.setTimeStep(h)
        ts.setMaxTime(t0 + h)
        ts.setConvergedReason(PETSc.TS.ConvergedReason.CONVERGED_ITERATING)
        self._bad = None
        ts.step()
        report = StepReport()
        snes = ts.getSNES()
        report.newton_iterations = snes.getIterationNumber()
        report.linear_iterations = snes.getLinearSolveIterations()
        report.converged = outcome(ts).converged and outcome(snes).converged
        report.reason = reason_name(ts)
        if self._bad is not None:
            report.converged = False
            report.reason += f" ({self._bad})"
        if not report.converged:
            self._last = None
            return report
        u, v = ts.getSolution2()
        u.copy(q1)
        v.copy(v1)
        if self._last is not None:
            self._last[1].destroy()
            self._last[2].destroy()
        self._last = (t0 + h, q1.copy(), v1.copy())
        # work terms paired with dq by the trapezoidal rule (the scheme's own pairing is not
        # an exact energy identity: the remainder shows as numerical dissipation)
        dq = q1.duplicate()
        dq.waxpy(-1.0, q0, q1)
        vm = v1.duplicate()
        vm.waxpy(1.0, v0, v1)
        vm.scale(0.5)
        report.dissipated = dq.dot(s.damping_apply(vm, self._damp))
        load = s.tractions(t0, self._load).copy()
        load.axpy(1.0, s.tractions(t0 + h, self._load))
        report.external_work = 0.5 * dq.dot(load)
        for vec in (dq, vm, load):
            vec.destroy()
        return report

    def destroy(self) -> None:
        for obj in (self.ts, self.J, self.F, self._grad, self._damp, self._load):
            obj.destroy()


def alpha_parameters(radius: float) -> tuple[float, float, float, float]:
    """(alpha_m, alpha_f, gamma, beta) of spectral radius ``radius`` at infinity."""
    r = float(radius)
    am, af = (2.0 - r) / (1.0 + r), 1.0 / (1.0 + r)
    return am, af, 0.5 + am - af, 0.25 * (1.0 + am - af) ** 2


def consistent_acceleration(system, t0, q0, v0, out, work=None) -> None:
    """out = M^-1 (f(t0) - grad W(q0) - D v0 - the viscoelastic branch's force) (zero on
    supports): the acceleration :class:`GeneralizedAlpha` starts from, and the one a forward
    model observes at t0. ``work``: a scratch vector of the system's layout (else one is made).
    """
    s = system
    own = work is None
    if own:
        work = s.create_vec()
    rhs = s.create_vec()
    s.internal_gradient(q0, rhs)
    rhs.scale(-1.0)
    rhs.axpy(-1.0, s.damping_apply(v0, work))
    branch = s.viscoelastic
    if branch is not None and branch.active:
        rhs.axpy(-1.0, branch.stress_force(q0, work))   # g K0 (q0 - z0)
    rhs.axpy(1.0, s.gravity)
    rhs.axpy(1.0, s.tractions(t0, work))
    s.zero_prescribed(rhs)
    ksp = mass_solver(s)
    ksp.solve(rhs, out)
    for obj in (ksp, rhs) + ((work,) if own else ()):
        obj.destroy()


class GeneralizedAlpha(ChordBorrower, SolverReuse):
    """Generalized-alpha steps solved for q1 with SNES, started from the consistent a0.

    With a1 = (q1 - q0 - h v0 - h^2 (1/2 - beta) a0) / (beta h^2) and
    v1 = v0 + h ((1 - gamma) a0 + gamma a1), the step solves

        M a_m + grad W(q_f) + D v_f - f(t0 + alpha_f h) = 0,

    a_m = a0 + alpha_m (a1 - a0), q_f = q0 + alpha_f (q1 - q0), v_f = v0 + alpha_f (v1 - v0),
    whose Jacobian is alpha_m/(beta h^2) M + alpha_f K(q_f) + alpha_f gamma/(beta h) D.

    ``prefix`` and ``options`` as for :class:`AlphaTSIntegrator` (a SNES instead of a TS).
    """

    def __init__(self, system, radius: float = 0.5, prefix: str = "",
                 options: SolverOptions | None = None):
        self.system, self.radius = system, float(radius)
        self.length = length_scale(system)   # the round-off floor of Newton's residual
        self.am, self.af, self.gamma, self.beta = alpha_parameters(radius)
        s = system
        self.J = s.create_matrix()
        modes = s.near_nullspace()
        if modes is not None:
            self.J.setNearNullSpace(modes)
        (self.R, self.q0, self.v0, self.a0, self.a1, self.v1, self.qf, self.vf, self.work,
         self.load, self._grad) = (s.create_vec() for _ in range(11))
        self._last = None
        self._bad = None
        self._branch = NoBranch()
        self.options = own_options(prefix, options)
        self.prefix = self.options.prefix
        self.snes = None
        self._new_solver()
        self.new_run()

    @with_options
    def _new_solver(self) -> None:
        """A fresh SNES (with KSP and PC): see :meth:`step` for why one per step."""
        if self.snes is not None:
            self.snes.destroy()
        s = self.system
        self.snes = snes = PETSc.SNES().create(comm=s.comm)
        snes.setOptionsPrefix(self.prefix)
        snes.setFunction(self._residual_cb, self.R)
        snes.setJacobian(self._jacobian_cb, self.J, self.J)
        # stol: the residual carries 1/h^2 round-off; a Newton update below 1e-12 |q| is converged
        snes.setTolerances(rtol=1e-10, atol=1e-12, stol=1e-12, max_it=25)
        stop_at_round_off(snes, self.J, self.length)
        self.ksp = snes.getKSP()
        s.linear_defaults(self.ksp)
        with scoped_defaults(**{self.prefix + "snes_linesearch_type": "basic"}):
            snes.setFromOptions()
        self._lagged = reuse_across_iterations(snes, s)

    def consistent_acceleration(self, t0, q0, v0, out) -> None:
        """out = M^-1 (f(t0) - grad W(q0) - D v0) (zero on supports):
        :func:`consistent_acceleration`."""
        consistent_acceleration(self.system, t0, q0, v0, out, self.work)

    def _update(self, q1) -> None:
        """a1, v1, q_f, v_f from q1."""
        h, b, g = self.h, self.beta, self.gamma
        a1, v1 = self.a1, self.v1
        a1.waxpy(-1.0, self.q0, q1)
        a1.axpy(-h, self.v0)
        a1.axpy(-h * h * (0.5 - b), self.a0)
        a1.scale(1.0 / (b * h * h))
        self.v0.copy(v1)
        v1.axpy(h * (1.0 - g), self.a0)
        v1.axpy(h * g, a1)
        self.qf.waxpy(-1.0, self.q0, q1)
        self.qf.aypx(self.af, self.q0)
        self.vf.waxpy(-1.0, self.v0, v1)
        self.vf.aypx(self.af, self.v0)

    def _full_residual(self, q1, R) -> None:
        s = self.system
        self._update(q1)
        am = self.work
        am.waxpy(-1.0, self.a0, self.a1)
        am.aypx(self.am, self.a0)
        s.M.mult(am, R)
        R.axpy(1.0, s.internal_gradient(self.qf, self._grad))
        R.axpy(1.0, s.damping_apply(self.vf, self.work))
        R.axpy(-1.0, self.load)
        self._branch.add_force(q1, R, self.work)       # the viscoelastic branch at alpha_f

    def _residual_cb(self, snes, x, F):
        try:
            self._full_residual(x, F)
        except InvertedElementError as err:
            self._bad = without_frames(err)
            F.set(np.inf)
            return
        self.system.zero_prescribed(F)

    def _jacobian_cb(self, snes, x, J, P):
        s, h = self.system, self.h
        self._update(x)
        c = self.af * self.gamma / (self.beta * h)
        # the damping term is evaluated at v_f: dv_f/dq1 = c (velocity terms at the last v_f)
        s.assemble_combination(self.qf, self.am / (self.beta * h * h) + s.alpha * c, self.af,
                               s.beta * c + self._branch.jacobian_coefficient(), P, velocity=c,
                               reuse=True)

    def forget(self) -> None:
        """Start the next step from a newly computed consistent acceleration, wherever it
        starts (a new run from the same state as the last step's end, too)."""
        if self._last is not None:
            self._last[1].destroy()
            self._last[2].destroy()
        self._last = None

    def _continues(self, t0, q0, v0) -> bool:
        if self._last is None:
            return False
        t_last, q_last, v_last = self._last
        if abs(t0 - t_last) > 1e-12 * max(1.0, abs(t0)):
            return False
        dq, dv = q0.copy(), v0.copy()
        dq.axpy(-1.0, q_last)
        dv.axpy(-1.0, v_last)
        same = max(dq.norm(PETSc.NormType.INFINITY), dv.norm(PETSc.NormType.INFINITY)) == 0.0
        dq.destroy()
        dv.destroy()
        return same

    def state(self) -> dict:
        """Internal state a restart needs: the acceleration the next step starts from."""
        return {"acceleration": self.a0} if self._last is not None else {}

    def restore(self, t, q, v, state: dict) -> None:
        """Continue from a checkpoint exactly (else the next step recomputes a0)."""
        if "acceleration" in state:
            state["acceleration"].copy(self.a0)
            self._remember(t, q, v)

    def _remember(self, t, q, v) -> None:
        """Keep (t, q, v): where the next step must start for a0 to be valid."""
        if self._last is None:
            self._last = (t, q.copy(), v.copy())
            return
        _, q_last, v_last = self._last
        q.copy(q_last)
        v.copy(v_last)
        self._last = (t, q_last, v_last)

    def _forget_rejected(self) -> bool:
        """Whether the last solve met an inverted element on some rank (forgotten: the solve
        is repeated, on every rank)."""
        bad, self._bad = self._bad is not None, None
        return on_any_rank(self.system.comm, bad)

    @with_options
    def step(self, t0, q0, v0, h, q1, v1) -> StepReport:
        s = self.system
        self._branch = branch_of(s)
        if not isinstance(self._branch, NoBranch):
            # (before the consistent acceleration: a branch never reset starts relaxed here)
            self._branch.prepare(MaxwellRule.GENERALIZED_ALPHA, h, q0, alpha_f=self.af)
        if not self._continues(t0, q0, v0):
            self.consistent_acceleration(t0, q0, v0, self.a0)
        self.h = h
        q0.copy(self.q0)
        v0.copy(self.v0)
        s.tractions(t0 + self.af * h, self.load)
        traction_f = self.load.copy()
        self.load.axpy(1.0, s.gravity)
        # Predictor q0 + h v0: adding h^2/2 a0 overshoots badly when stiff vibrations are
        # excited (1.8 m on the stiff-spring pendulum at tau w = 50), and Newton then found a
        # spurious root.
        q0.copy(q1)
        q1.axpy(h, v0)
        s.apply_prescribed(q1, t0 + h)
        self._bad = None
        # A fresh solver each step: algebraic multigrid keeps state between set-ups (its random
        # generator survives KSPReset), and a run restarted from a checkpoint must compute
        # bit for bit what the uninterrupted run did. Creating a SNES costs microseconds.
        # Except where keeps_solver says a kept one computes the same (a constant Jacobian,
        # a set-up that depends on the matrix alone), or a run keeps its multigrid
        # interpolation until a renewal a restart repeats.
        if not self.keeps_solver():
            self._new_solver()
        snes = self._newton(q1)
        report = StepReport()
        report.newton_iterations = snes.getIterationNumber()
        report.linear_iterations = snes.getLinearSolveIterations()
        done = outcome(snes)
        bad = on_any_rank(s.comm, self._bad is not None)
        report.converged = done.converged and not bad
        report.reason = done.reason
        if bad:
            report.reason += f" ({self._bad or 'an element inverted on another rank'})"
        if not report.converged:
            self.forget()
            self.new_run()
            traction_f.destroy()
            return report
        s.apply_prescribed(q1, t0 + h)
        dq = s.create_vec()
        dq.waxpy(-1.0, q0, q1)
        full = self._converged_residual(q1, dq)
        self.v1.copy(v1)
        report.dissipated = dq.dot(s.damping_apply(self.vf, self.work))
        report.external_work = dq.dot(traction_f)
        report.boundary_work = dq.dot(full)
        report.dissipated += self._branch.accept(q1)
        self.a1.copy(self.a0)   # the new step starts from this step's acceleration
        self._remember(t0 + h, q1, v1)
        for vec in (dq, traction_f) + ((full,) if full is not self.R else ()):
            vec.destroy()
        return report

    def _converged_residual(self, q1, dq) -> PETSc.Vec:
        """The step's residual at the converged ``q1`` with its prescribed rows kept (there it
        is the supports' reaction), for the work they do over ``dq = q1 - q0``.

        When no support moved in this step (dq = 0 on every prescribed row) the reactions do no
        work, and the free rows are the residual Newton last evaluated, at ``q1`` (``self.R``,
        prescribed rows zeroed): that vector is returned and one residual evaluation a step is
        saved (one of the 6-8 a converged chord step makes; ``dq . R`` is the same sum). Else a
        new vector with the full residual (the caller destroys it)."""
        s = self.system
        moved = dq.copy()
        s.zero_prescribed(moved)
        moved.axpy(-1.0, dq)
        still = moved.norm(PETSc.NormType.INFINITY) == 0.0
        if still:
            moved.destroy()
            return self.R
        self._full_residual(q1, moved)
        return moved

    def destroy(self) -> None:
        self.snes.destroy()
        self._destroy_chord()
        for vec in (self.J, self.R, self.q0, self.v0, self.a0, self.a1, self.v1, self.qf,
                    self.vf, self.work, self.load, self._grad):
            vec.destroy()
