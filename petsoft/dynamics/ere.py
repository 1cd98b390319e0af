"""Exponential Rosenbrock-Euler (ERE): large steps by the exponential of the linearised system.

The first-order form y = (q, v) of ``M q'' = f(t) - grad W(q) - D v`` is

    y' = F(t, y) = (v, M^-1 (f(t) - grad W(q) - D v)),
    J = dF/dy (y0) = [[0, I], [-M^-1 K(q0), -M^-1 D]],

and one ERE step is y1 = y0 + h phi1(h J) F(t0, y0), phi1(z) = (e^z - 1)/z (lecture notes
000: the method of the twisted bar and cloth figures). It is exact for linear autonomous
problems (there F(y0) = J y0 and the step is exp(h J) y0: no stability limit, no artificial
damping), and of order two for nonlinear autonomous ones.

Large steps on nonlinear problems need some physical damping of the stiff modes. ERE is not an
energy-stable scheme: the nonlinear remainder F - J y is frozen over the step, and undamped
stiff modes (h omega >> 1) driven by it can gain energy. Measured on the neo-Hookean bar of the
tests (released from a bend that puts most of its energy in high modes), undamped, over
1.33 s: at 0.5x and 1x the explicit limit the energy drifts by -1% and -9%; at 2x, 3x, 5x, 20x
it grows 127, 29, 30 and 24-fold, and at 10x an element inverts after 47 steps. With Rayleigh
beta = 1e-4 s (damping ratio 2e-4 in the first bending mode, 4.5% at omega_max) 300 steps at
10x the limit stay bounded and follow the physical energy decay (midpoint reference); with
beta = 1e-5 s the energy blows up after ~90 steps.

Time-dependent loads and moving supports make F depend on t. Freezing t at t0 would make the
step first order; petsoft uses the nonautonomous form (Hochbruck, Ostermann, Schweitzer 2009)

    y1 = y0 + h phi1(h J) F + h^2 phi2(h J) w,   w = dF/dt (t0, y0),

which is ERE applied to the autonomous system (y, t)' = (F, 1): both terms come out of one
phi1 product with the operator augmented by one row and column (see below). w is a centred
difference over [t0 - h, t0 + h] of the loads and of the supports' positions, velocities and
(consistent mass) accelerations, so the step stays second order.

Implementation:

* phi1(A) b by SLEPc MFN (restarted Krylov) with the FN ``phi`` function (index 1); A is a
  PETSc shell matrix: the Jacobian is never formed, each product costs one K(q0) product (K
  assembled once per step), one damping product and one application of M^-1.
* Scaling: the Krylov space mixes positions and velocities, whose units differ; the product is
  computed for S y with S = diag(I, h I) (velocities times h are lengths), i.e.
  A = h S J S^-1, A (x_q, x_v) = (x_v, -M^-1 (h^2 K x_q + h D x_v)), b = h S F
  = (h v0, h^2 a0): all entries are lengths and A is dimensionless, so MFN's relative tolerance
  means the same for both halves.
* Nonautonomous augmentation: A_hat (x, s) = (A x + s c, 0) on (b, sigma), c = h^2 S w / sigma,
  gives phi1(A_hat)(b, sigma) = (phi1(A) b + phi2(A) h^2 S w, sigma). sigma (a norm of b and
  h^2 S w) keeps the extra entry on the scale of the others.
* Mass: ``lumped`` (default) uses the row-sum mass, so M^-1 is a pointwise scaling; this is the
  ODE of the explicit integrators, not of the implicit ones (consistent mass). ``consistent``
  applies M^-1 by a tight KSP solve (CG + Jacobi, rtol 1e-13) inside every product: same ODE
  as the implicit integrators, ~20 CG iterations per product on the test bar.
* Supports: prescribed rows of A and b are zero, so the Krylov vectors never move the supports;
  after the step q1's prescribed entries are the supports' positions at t0 + h and v1's the
  finite-difference support velocity (as the explicit integrators do).
* Layout in parallel: one PETSc Vec of local size 2 n_local (+1 on rank 0 when augmented);
  its local array is [q part, v part, (s)], copied into and out of the system's global vectors
  around each product. The global order of the entries differs between 1 and p ranks, which
  changes MFN's inner products only by round-off.

* Cost: MFN Krylov restarts every ncv (default 10, ``-ere_mfn_ncv``) products and runs at
  least two cycles, so a step costs >= 20 products; ``linear_iterations`` of the report counts
  the cycles (products = cycles x ncv). Measured on the bar: 2 cycles below the explicit
  limit, 5 at 10x the limit.

Limitations: the Jacobian must be exact for order two (``project_spd`` Hessians make ERE first
order). An inverted element is detected on the rank that owns it only (as in the other
integrators), so in parallel it stops the run instead of halving the step. The work terms of
the report are quadratures over the step, not the scheme's own energy identity: the ledger's
misfit falls with h (measured 1.7% and 0.6% of the energy scale at h = 2e-3 and 1e-3 s on the
damped test bar with moving support) and is large when h omega_max >> 1.
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from petsoft.dependencies import slepc
from petsoft.dynamics.implicit import StepReport
from petsoft.dynamics.interfaces import StepperDefaults
from petsoft.errors import InvertedElementError
from petsoft.solvers.convergence import outcome
from petsoft.solvers.options import SolverOptions, own_options, with_options

MASSES = ("lumped", "consistent")
NCV = 10


class _ShellOperator:
    """The (possibly augmented) scaled Jacobian A = h S J S^-1 as a PETSc shell matrix."""

    def __init__(self, integrator):
        self.ig = integrator

    def mult(self, mat, X, Y):
        self.ig._apply(X, Y)


class EREIntegrator(StepperDefaults):
    """Exponential Rosenbrock-Euler steps with SLEPc MFN (phi1 products, no linear solves).

    Parameters
    ----------
    system : DynamicSystem or OscillatorSystem
    mass : {"lumped", "consistent"}
        Mass matrix of the integrated ODE. ``lumped``: row-sum (diagonal) mass, M^-1 pointwise.
        ``consistent``: M^-1 applied with a KSP (options prefix ``<prefix>mass_``).
    krylov_tol : float
        Relative tolerance of the MFN phi1 product (``-<prefix>mfn_tol`` overrides it).
    time_derivative : bool
        Include the h^2 phi2(hJ) dF/dt term for time-dependent loads and moving supports
        (second order). False freezes them at t0 (the plain ERE formula: first order in them).
    prefix : str
        Options prefix of the MFN (``-ere_mfn_ncv``, ``-ere_mfn_max_it``, ...).
    options : SolverOptions, optional
        The options (an experiment's ``[petsc]`` table) pushed under ``prefix`` (the mass
        solve's among them) while the solvers are set up and step.
    """

    def __init__(self, system, *, mass: str = "lumped", krylov_tol: float = 1e-10,
                 time_derivative: bool = True, prefix: str = "ere_",
                 options: SolverOptions | None = None):
        SLEPc = slepc("the ERE integrator (SLEPc's matrix functions)")
        if mass not in MASSES:
            raise ValueError(f"ERE mass must be one of {MASSES}, not {mass!r}")
        self.system, self.mass = system, mass
        self.options = own_options(prefix, options)
        prefix = self.options.prefix
        s = system
        self.comm = s.comm
        self._mpi = s.comm.tompi4py()
        # The lumped ODE is the one whose energy we book (as the explicit integrators do).
        s.lumped_kinetic = mass == "lumped"
        self.moving = bool(s.moving_boundary)
        self.nonautonomous = time_derivative and (
            self.moving or bool(s.time_dependent_loads))
        self.K = s.create_matrix()
        # work vectors: _xq, _xv, _t1, _t2 belong to the operator and the work terms; _force
        # writes only its ``out`` and _grad, _qt, _vt, _g, _tmp
        vecs = [s.create_vec() for _ in range(14)]
        (self._xq, self._xv, self._t1, self._t2, self._a0, self._w, self._f, self._fp,
         self._grad, self._qt, self._vt, self._g, self._tmp, self._dq) = vecs
        self._pool = [s.create_vec() for _ in range(3)]
        self._v_state = None    # v0 with the supports' velocity (the first step creates it)
        self._supports, self._tractions_at = {}, {}
        self.fixed = s.prescribed_offsets(self._xq)
        self.n = self._xq.getLocalSize()
        if mass == "lumped":
            self.inv_mass = s.lumped.copy()
            self.inv_mass.reciprocal()
            self.ksp = self.Me = None
        else:
            self.inv_mass = None
            self.Me = s.create_matrix()
            s.assemble_combination(None, 1.0, 0.0, 0.0, self.Me, eliminate=True)
            self.ksp = PETSc.KSP().create(comm=self.comm)
            self.ksp.setOptionsPrefix(prefix + "mass_")
            self.ksp.setOperators(self.Me)
            self.ksp.setType(PETSc.KSP.Type.CG)
            self.ksp.getPC().setType(PETSc.PC.Type.JACOBI)
            # inside a Krylov product the solve must be far tighter than the MFN tolerance
            self.ksp.setTolerances(rtol=1e-13, atol=1e-50, max_it=1000)
            with self.options.pushed():
                self.ksp.setFromOptions()
        # combined layout: [q part, v part] per rank, the augmentation entry on rank 0 only
        self.aug = self.nonautonomous and self.comm.rank == 0
        local = 2 * self.n + int(self.aug)
        self.Y = PETSc.Vec().createMPI((local, PETSc.DECIDE), comm=self.comm)
        self.B, self.X = self.Y.duplicate(), self.Y.duplicate()
        size = self.Y.getSize()
        self.A = PETSc.Mat().createPython(((local, size), (local, size)), _ShellOperator(self),
                                          comm=self.comm)
        self.A.setUp()
        self.mfn = mfn = SLEPc.MFN().create(comm=self.comm)
        mfn.setOptionsPrefix(prefix)
        mfn.setType(SLEPc.MFN.Type.KRYLOV)
        fn = mfn.getFN()
        fn.setType(SLEPc.FN.Type.PHI)
        fn.setPhiIndex(1)
        fn.setScale(1.0, 1.0)          # A already carries h
        # each restart cycle enlarges the dense Hessenberg matrix phi1 is evaluated on by ncv
        mfn.setTolerances(krylov_tol, 100)
        # SLEPc's restarted Krylov (Eiermann-Ernst) runs at least two full cycles of ncv
        # products; 10 instead of its 30 costs 20 products per step at small steps and needs
        # more, shorter cycles only at steps far above the explicit limit (measured on the bar)
        mfn.setDimensions(min(NCV, size))
        mfn.setOperator(self.A)
        with self.options.pushed():
            mfn.setFromOptions()
        self.h = None
        self._c = None                  # augmentation column (v part), None when autonomous
        self._mass_failure = None       # a failed consistent-mass solve (inside MFN's products)

    # -- the operator -----------------------------------------------------------------------
    def _inverse_mass(self, rhs: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = M^-1 rhs on the free rows (rhs's prescribed rows are zeroed first), 0 on
        prescribed rows."""
        self.system.zero_prescribed(rhs)
        if self.inv_mass is not None:
            out.pointwiseMult(rhs, self.inv_mass)
        else:
            self.ksp.solve(rhs, out)
            solve = outcome(self.ksp)
            if not solve.converged and self._mass_failure is None:
                # not raised: this runs inside MFN's callbacks; the step reports it
                self._mass_failure = f"consistent mass solve diverged (KSP {solve.reason})"
        self.system.zero_prescribed(out)
        return out

    def _apply(self, X: PETSc.Vec, Y: PETSc.Vec) -> None:
        """Y = A_hat X: (x_v, -M^-1 (h^2 K x_q + h D x_v) + s c, 0)."""
        n, h = self.n, self.h
        x = X.getArray(readonly=True)
        self._xq.getArray()[:] = x[:n]
        self._xv.getArray()[:] = x[n:2 * n]
        s = 0.0
        if self._c is not None:
            # the augmentation entry lives on rank 0; every rank needs it for s c
            s = self._mpi.bcast(float(x[2 * n]) if self.aug else None, root=0)
        self.K.mult(self._xq, self._t1)
        self._t1.scale(h * h)
        # the damping's Jacobian: D, plus the drag and friction linearised at the step's v0
        tangent = self.system.damping_tangent_apply
        if tangent is not None:
            self._t1.axpy(h, tangent(self._v_state, self._xv, self._t2))
        else:
            self._t1.axpy(h, self.system.damping_apply(self._xv, self._t2))
        self._inverse_mass(self._t1, self._t2)
        y = Y.getArray()
        y[:n] = x[n:2 * n]
        y[:n][self.fixed] = 0.0
        y[n:2 * n] = -self._t2.getArray(readonly=True)
        if self._c is not None and s != 0.0:
            y[n:2 * n] += s * self._c.getArray(readonly=True)
        if self.aug:
            y[2 * n] = 0.0

    # -- the right-hand side ------------------------------------------------------------------
    def _support(self, t: float) -> np.ndarray:
        """Owned prescribed displacements at time t (memoised within a step: the centred
        differences ask for the same five times several times)."""
        if t not in self._supports:
            self.system.apply_prescribed(self._g, t)
            self._supports[t] = self._g.getArray(readonly=True)[self.fixed].copy()
        return self._supports[t]

    def _traction(self, t: float) -> PETSc.Vec:
        """Traction forces at time t (memoised within a step: at most t0 - h, t0, t0 + h)."""
        vec = self._tractions_at.get(t)
        if vec is None:
            vec = self._pool[len(self._tractions_at)]
            self.system.tractions(t, vec)
            self._tractions_at[t] = vec
        return vec

    def _force(self, t: float, q: PETSc.Vec, v: PETSc.Vec, out: PETSc.Vec, d: float,
               grad: PETSc.Vec | None = None) -> PETSc.Vec:
        """out = f(t) - grad W(q_t) - D v_t - M a_D(t), all rows.

        q_t, v_t are q, v with the supports' position, velocity at t (centred differences of
        width d), a_D the supports' acceleration (consistent mass couples it to free rows).
        ``grad`` = grad W(q) may be given when the supports do not move.
        """
        s = self.system
        self._traction(t).copy(out)
        out.axpy(1.0, s.gravity)
        v.copy(self._vt)
        vt = self._vt.getArray()
        if self.moving:
            g_minus, g0, g_plus = self._support(t - d), self._support(t), self._support(t + d)
            q.copy(self._qt)
            self._qt.getArray()[self.fixed] = g0
            grad = s.internal_gradient(self._qt, self._grad)
            vt[self.fixed] = (g_plus - g_minus) / (2.0 * d)
            if self.mass == "consistent":
                acc = self._qt
                acc.zeroEntries()
                acc.getArray()[self.fixed] = (g_plus - 2.0 * g0 + g_minus) / d**2
                s.M.mult(acc, self._tmp)
                out.axpy(-1.0, self._tmp)
        else:
            vt[self.fixed] = 0.0     # fixed supports have no velocity, whatever v0 holds there
            if grad is None:
                grad = s.internal_gradient(q, self._grad)
        del vt
        out.axpy(-1.0, grad)
        out.axpy(-1.0, s.damping_apply(self._vt, self._tmp))
        return out

    # -- stepping -----------------------------------------------------------------------------
    @with_options
    def step(self, t0: float, q0: PETSc.Vec, v0: PETSc.Vec, h: float,
             q1: PETSc.Vec, v1: PETSc.Vec) -> StepReport:
        """Advance (q0, v0) at t0 by h into (q1, v1); returns the step's report."""
        s, n = self.system, self.n
        self.h = h
        self._supports, self._tractions_at = {}, {}
        self._mass_failure = None
        report = StepReport()
        try:
            s.assemble_combination(q0, 0.0, 1.0, 0.0, self.K, eliminate=False)
            grad0 = None if self.moving else s.internal_gradient(q0, self._grad)
            self._inverse_mass(self._force(t0, q0, v0, self._f, h, grad0), self._a0)
            if self._v_state is None:
                self._v_state = self._vt.duplicate()
            self._vt.copy(self._v_state)     # v0 with the supports' velocity at t0
            if self.nonautonomous:
                # w = dF/dt (t0, y0) by a centred difference: the v part only (F_q = v)
                fp = self._force(t0 + h, q0, v0, self._fp, h, grad0)
                fm = self._force(t0 - h, q0, v0, self._f, h, grad0)
                fp.axpy(-1.0, fm)
                fp.scale(1.0 / (2.0 * h))
                self._inverse_mass(fp, self._w)
        except InvertedElementError as err:
            report.converged, report.reason = False, f"inverted element at t0: {err}"
            return report
        # b = h S F = (h v0, h^2 a0), supports' rows zero
        b = self.B.getArray()
        b[:n] = h * v0.getArray(readonly=True)
        b[:n][self.fixed] = 0.0
        b[n:2 * n] = h * h * self._a0.getArray(readonly=True)
        if self.aug:
            b[2 * n] = 0.0
        del b
        self._c = None
        if self.nonautonomous:
            self._w.scale(h**3)                                  # v part of h^2 S w
            sigma = max(self.B.norm(), self._w.norm())
            if sigma > 0.0:
                self._w.scale(1.0 / sigma)
                self._c = self._w
                # getArray on every rank: it invalidates the Vec's cached norm, which must
                # happen on all ranks alike or the next norm() is collective on some only
                b = self.B.getArray()
                if self.aug:
                    b[2 * n] = sigma
                del b
        if self.B.norm() == 0.0:
            self.X.zeroEntries()
        else:
            # A's action changed (h, K(q0)) behind the shell: set it again so MFN sets up anew
            self.mfn.setOperator(self.A)
            self.mfn.solve(self.B, self.X)
            solve = outcome(self.mfn)
            report.linear_iterations = solve.iterations
            report.reason = solve.reason
            if solve.code < 0:
                report.converged = False
                report.reason = f"MFN did not converge ({report.reason})"
                return report
        if self._mass_failure is not None:
            report.converged, report.reason = False, self._mass_failure
            return report
        x = self.X.getArray(readonly=True)
        q0.copy(q1)
        q1.getArray()[:] += x[:n]
        v0.copy(v1)
        v1.getArray()[:] += x[n:2 * n] / h
        del x
        s.apply_prescribed(q1, t0 + h)
        dq = self._dq
        dq.waxpy(-1.0, q0, q1)
        v1.getArray()[self.fixed] = dq.getArray(readonly=True)[self.fixed] / h
        if not np.isfinite(dq.norm()):
            report.converged, report.reason = False, "non-finite state after the ERE step"
            return report
        try:
            # a step that inverts an element is refused here (the caller can halve it), not
            # at the start of the next one
            s.elastic_energy(q1)
            self._work_terms(t0, h, q0, v0, q1, v1, dq, report)
        except InvertedElementError as err:
            report.converged, report.reason = False, f"inverted element after the step: {err}"
        return report

    def _work_terms(self, t0, h, q0, v0, q1, v1, dq, report) -> None:
        """Dissipation, traction work and (moving supports) reaction work of the step."""
        s = self.system
        # trapezoidal rule for the integral of v.Dv: second order and >= 0 (D is PSD); the
        # pairing dq . D (v0 + v1)/2 of the implicit schemes goes negative when h omega >> 1,
        # where ERE's dq is not h times its mean velocity
        report.dissipated = 0.5 * h * (v0.dot(s.damping_apply(v0, self._t2))
                                       + v1.dot(s.damping_apply(v1, self._t1)))
        vm = self._t1
        vm.waxpy(1.0, v0, v1)
        vm.scale(0.5)
        s.damping_apply(vm, self._t2)                   # D vm, for the support reactions
        load = self._traction(t0).copy(self._f)
        if self.nonautonomous:
            # the step integrates the load linearly in time: its work is the trapezoid's
            load.axpy(1.0, self._traction(t0 + h))
            load.scale(0.5)
        report.external_work = dq.dot(load)
        if self.moving:
            # support reactions at the step's midpoint: M (v1 - v0)/h + grad W(qm) + D vm - f,
            # with the load of the work above
            qm = self._qt
            qm.waxpy(1.0, q0, q1)
            qm.scale(0.5)
            r = s.internal_gradient(qm, self._xv)
            r.axpy(1.0, self._t2)                                   # D vm
            r.axpy(-1.0, load)
            r.axpy(-1.0, s.gravity)
            acc = self._vt
            acc.waxpy(-1.0, v0, v1)
            acc.scale(1.0 / h)
            if self.inv_mass is not None:
                self._xq.pointwiseMult(acc, s.lumped)
            else:
                s.M.mult(acc, self._xq)
            r.axpy(1.0, self._xq)
            local = float(np.dot(dq.getArray(readonly=True)[self.fixed],
                                 r.getArray(readonly=True)[self.fixed]))
            report.boundary_work = self._mpi.allreduce(local)

    def destroy(self) -> None:
        for obj in (self.mfn, self.A, self.Y, self.B, self.X, self.K, self.Me, self.ksp,
                    self.inv_mass, self._xq, self._xv, self._t1, self._t2, self._a0, self._w,
                    self._f, self._fp, self._grad, self._qt, self._vt, self._g, self._tmp,
                    self._dq, self._v_state):
            if obj is not None:
                obj.destroy()
        for vec in self._pool:
            vec.destroy()
