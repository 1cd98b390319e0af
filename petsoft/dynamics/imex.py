"""IMEX splitting of fast and slow components: the polar stiff-spring pendulum, and modal FEM.

Why: backward Euler (BE/SI) and generalized-alpha with strong damping damp *every* mode by an
amount set by tau*omega, so a step chosen to kill an invisible fast vibration also drains the
slow, visible motion (for a slow mode of frequency Omega, BE's ghost damping is
ln(1 + (tau Omega)^2) / tau ~ tau Omega^2). When the fast and slow components can be separated,
the fast ones can be integrated implicitly and damped away while the slow ones are integrated
explicitly, accurately and without damping: only the slow energy is approximated well, and that
is the point ("we don't want to conserve total energy").

:class:`ImexIntegrator` -- the lecture's "IMEX of sorts" for the stiff-spring pendulum
    (``scripts/examples/pendulum_systems.py``). The vector field in polar coordinates is split into

    * slow:  phi' = p_phi / r^2,  p_phi' = -g r cos(phi)     (r, p_r frozen),
    * fast:  r' = p_r,  p_r' = -w^2 (r - r0) + p_phi^2 / r^3 - g sin(phi)   (phi, p_phi frozen),

    whose sum is the full field. A step of h is the Strang composition S(h/2) F(h) S(h/2)
    (``splitting="lie"``: F(h) S(h)), with S one classical RK4 step on the slow pair (explicit:
    the swing has tau*Omega << 1) and F one implicit step on the fast pair:

    * ``be``: backward Euler, Newton on the scalar r1 to round-off (the default: it damps the
      vibration by 1/sqrt(1 + (tau w)^2) per step, the lecture's BE),
    * ``si``: the same equation with exactly one Newton step from r0 + h p_r (semi-implicit),
    * ``midpoint``: the implicit midpoint rule (second order, no damping: the vibration keeps its
      energy, which shows that the damping comes from the fast solver alone),
    * ``alpha``: generalized-alpha of spectral radius ``radius`` at infinity, carrying its
      acceleration from step to step; before each fast step the carried acceleration is shifted
      by the change of the slow forcing p_phi^2/r^3 - g sin(phi) that the slow sub-steps caused,
      so that its deviation from the current force (the method's auxiliary state) is preserved.

    Measured (tests/test_imex.py): order 1 with ``be``/``si`` (limited by BE), 2 with
    ``midpoint``/``alpha`` under Strang, 1 under Lie.

    It takes and returns the Cartesian state (q, v) of a ``PendulumSystem``
    (scripts/examples/pendulum_systems.py), so it runs side by side with petsoft's
    fully implicit integrators applied to the Cartesian form; consecutive steps continue from the
    polar state kept internally (no round trip through atan2, the angle is not wrapped).

:class:`ModalImexIntegrator` -- what ``imex`` means for a FEM body (any system with the interface
    of :class:`~petsoft.dynamics.system.DynamicSystem`). A FEM body has no coordinates like
    (r, phi) in which fast and slow motions separate: every nodal force mixes both (exactly like
    the Cartesian pendulum). Splitting the *forces* instead -- elastic implicit; gravity,
    tractions and damping explicit -- would not help: gravity is constant (explicit = implicit),
    explicit tractions only shift their evaluation time, and explicit Rayleigh damping adds a
    stability limit while the slow elastic modes are still damped by BE. The closest linear
    analogue of the polar coordinates are the vibration modes: the slow subspace is spanned by
    the k lowest modes Phi of K x = omega^2 M x (M-orthonormal, zero on supports), the fast one
    is its M-orthogonal complement. One step of h:

    1. a full BE (or SI) step of petsoft's :class:`~petsoft.dynamics.implicit.
       ImplicitIntegrator` gives (q*, v*);
    2. the slow modal coordinates eta = Phi^T M q, zeta = Phi^T M v are advanced by one velocity
       Verlet step of eta'' = Phi^T f(t, q, v) (explicit, symplectic, second order, no damping
       but the physical one), with the force evaluated on the full state;
    3. the slow components of (q*, v*) are replaced: q1 = q* + Phi (eta1 - Phi^T M q*), etc.

    For linear elasticity with Rayleigh damping the modes decouple, BE's fast components do not
    depend on the slow ones, and this is exactly BE on the fast modes and Verlet on the slow ones:
    slow modes keep their energy at any step with h Omega_k < 2, fast ones are damped as by BE.
    For nonlinear materials it is a linearly-implicit approximation around the reference modes:
    valid while rotations stay small. Under large rotations the stiff directions rotate out of
    the fixed fast subspace and their forces enter the explicit slow update, which then goes
    unstable (shown on the Cartesian pendulum in the tests) -- the lecture's "it's hard to
    generalize". Cost per step: one BE solve and one more internal-force evaluation; the modes
    are computed once (SLEPc via :func:`petsoft.solvers.modes.compute_modes` for a model-backed
    system, a
    dense eigensolver at the first step's state for small analytic systems).
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.dynamics.alpha import alpha_parameters
from petsoft.dynamics.implicit import ImplicitIntegrator, StepReport
from petsoft.dynamics.integrators import scheme
from petsoft.dynamics.interfaces import StepperDefaults
from petsoft.errors import ExperimentError
from petsoft.solvers.modes import compute_modes
from petsoft.solvers.options import SolverOptions

FAST_METHODS = ("be", "si", "midpoint", "alpha")
SPLITTINGS = ("strang", "lie")


class ImexIntegrator:
    """Polar fast/slow splitting of the stiff-spring pendulum (see the module docstring).

    Parameters
    ----------
    system : PendulumSystem
        The Cartesian pendulum whose (q, v) the steps take and return.
    fast : {"be", "si", "midpoint", "alpha"}
        Implicit method of the fast pair (r, p_r).
    radius : float
        Spectral radius at infinity of the fast generalized-alpha step (``fast="alpha"``).
    splitting : {"strang", "lie"}
        S(h/2) F(h) S(h/2) (second order if the fast method is) or F(h) S(h) (first order).
    rtol : float
        Newton stops when the update of r1 is below rtol (1 + |r1|).
    max_it : int
        Newton iterations per fast step before the step is reported as not converged.
    """

    def __init__(self, system, fast: str = "be", radius: float = 0.5,
                 splitting: str = "strang", rtol: float = 1e-14, max_it: int = 25):
        if fast not in FAST_METHODS:
            raise ValueError(f"fast method must be one of {FAST_METHODS}, not {fast!r}")
        if splitting not in SPLITTINGS:
            raise ValueError(f"splitting must be one of {SPLITTINGS}, not {splitting!r}")
        self.system, self.pendulum = system, system.pendulum
        self.fast, self.radius, self.splitting = fast, float(radius), splitting
        self.rtol, self.max_it = float(rtol), int(max_it)
        self.am, self.af, self.gamma, self.beta = alpha_parameters(radius)
        self._last = None          # (t1, q1 values, v1 values, polar state) of the last step
        self._accel = None         # fast alpha: (carried acceleration, slow forcing it saw)

    # -- the two sub-flows --------------------------------------------------------------------
    def slow_step(self, state: np.ndarray, h: float) -> np.ndarray:
        """One RK4 step of (phi, p_phi) with r frozen (p_r untouched)."""
        r, g = state[0], self.pendulum.g

        def f(y):
            return np.array([y[1] / r**2, -g * r * np.cos(y[0])])

        y = state[[1, 3]]
        k1 = f(y)
        k2 = f(y + 0.5 * h * k1)
        k3 = f(y + 0.5 * h * k2)
        k4 = f(y + h * k3)
        y = y + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        out = state.copy()
        out[[1, 3]] = y
        return out

    def _forcing(self, state: np.ndarray, r: float) -> float:
        """The slow forcing of the radial equation, p_phi^2 / r^3 - g sin(phi)."""
        return state[3] ** 2 / r**3 - self.pendulum.g * np.sin(state[1])

    def fast_step(self, state: np.ndarray, h: float) -> tuple[np.ndarray, int, bool]:
        """One implicit step of (r, p_r) with (phi, p_phi) frozen.

        Returns the new state, the Newton iterations and whether Newton converged.
        """
        p = self.pendulum
        w2, r0 = p.omega**2, p.r0
        rn, pn = state[0], state[2]

        def force(r):
            return -w2 * (r - r0) + self._forcing(state, r)

        def dforce(r):
            return -w2 - 3.0 * state[3] ** 2 / r**4

        m = scheme(self.fast)
        if m.carries_acceleration:
            am, af, beta = self.am, self.af, self.beta
            if self._accel is None:
                a0 = force(rn)
            else:
                # keep the carried acceleration's deviation from the force, not its value: the
                # slow sub-steps changed the forcing since the last fast step
                carried, forcing_then = self._accel
                a0 = carried + self._forcing(state, rn) - forcing_then

            def accel(r1):
                return (r1 - rn - h * pn - h * h * (0.5 - beta) * a0) / (beta * h * h)

            def residual(r1):
                return a0 + am * (accel(r1) - a0) - force(rn + af * (r1 - rn))

            def jacobian(r1):
                return am / (beta * h * h) - af * dforce(rn + af * (r1 - rn))

            r1 = rn + h * pn + 0.5 * h * h * a0
        else:
            theta = 1.0 if m.force_at == "end" else 0.5   # where the force is evaluated

            def residual(r1):
                return r1 - rn - h * pn - theta * h * h * force(rn + theta * (r1 - rn))

            def jacobian(r1):
                return 1.0 - theta**2 * h * h * dforce(rn + theta * (r1 - rn))

            r1 = rn + h * pn
        iterations, converged = 0, False
        for _ in range(1 if m.one_newton_step else self.max_it):
            dr = residual(r1) / jacobian(r1)
            r1 -= dr
            iterations += 1
            if m.one_newton_step or abs(dr) <= self.rtol * (1.0 + abs(r1)):
                converged = True
                break
        converged = converged and np.isfinite(r1) and r1 > 0.0
        out = state.copy()
        out[0] = r1
        if m.force_at == "end":
            out[2] = (r1 - rn) / h
        elif m.force_at == "midpoint":
            out[2] = 2.0 * (r1 - rn) / h - pn
        else:
            a1 = accel(r1)
            out[2] = pn + h * ((1.0 - self.gamma) * a0 + self.gamma * a1)
            self._accel = (a1, self._forcing(out, r1))
        return out, iterations, bool(converged)

    def step_polar(self, state, h: float) -> tuple[np.ndarray, int, bool]:
        """One splitting step of a polar state; returns (state, Newton iterations, converged).

        Consecutive calls continue a trajectory: with ``fast="alpha"`` the carried acceleration
        is used; call :meth:`reset` before starting from an unrelated state.
        """
        state = np.asarray(state, float)
        if self.splitting == "strang":
            state = self.slow_step(state, 0.5 * h)
            state, its, ok = self.fast_step(state, h)
            state = self.slow_step(state, 0.5 * h)
        else:
            state, its, ok = self.fast_step(state, h)
            state = self.slow_step(state, h)
        return state, its, ok

    def reset(self) -> None:
        """Forget the history (the next step restarts, generalized-alpha from a0 = f)."""
        self._last = self._accel = None

    # -- the integrator interface ---------------------------------------------------------------
    def step(self, t0: float, q0: PETSc.Vec, v0: PETSc.Vec, h: float,
             q1: PETSc.Vec, v1: PETSc.Vec) -> StepReport:
        """Advance the Cartesian state (q0, v0) by h into (q1, v1) (collective)."""
        s = self.system
        x0, w0 = s.values(q0), s.values(v0)
        last = self._last
        if (last is not None and abs(t0 - last[0]) <= 1e-12 * max(1.0, abs(t0))
                and np.array_equal(x0, last[1]) and np.array_equal(w0, last[2])):
            state = last[3]
        else:
            self.reset()
            state = self.pendulum.to_polar(x0, w0)
        new, its, ok = self.step_polar(state, h)
        report = StepReport(newton_iterations=its, converged=ok,
                            reason="CONVERGED" if ok else "DIVERGED_FAST_NEWTON")
        if not ok:
            self.reset()
            return report
        s.set_polar(new, q1, v1)
        self._last = (t0 + h, s.values(q1), s.values(v1), new)
        return report

    def destroy(self) -> None:
        """Nothing to destroy: the steps use NumPy only."""


class ModalImexIntegrator(StepperDefaults):
    """Slow vibration modes explicit (Verlet), the rest implicit (BE/SI): ``imex`` for FEM.

    Parameters
    ----------
    system : DynamicSystem, OscillatorSystem or PendulumSystem
    slow_modes : int
        Number k of lowest modes integrated explicitly. The step must satisfy h Omega_k < 2
        (checked at the first step: ExperimentError otherwise).
    fast : {"be", "si"}
        The implicit method of the complement.
    prefix : str
        Options prefix of the fast step's SNES.
    options : SolverOptions, optional
        The fast step's options (an experiment's ``[petsc]`` table under ``prefix``); the slow
        modes' eigensolver (prefix ``imex_``) takes those of its keys that begin with ``imex_``.
    """

    def __init__(self, system, slow_modes: int = 6, fast: str = "be", prefix: str = "",
                 options: SolverOptions | None = None):
        if scheme(fast).force_at != "end" or scheme(fast).carries_acceleration:
            raise ValueError(f"the fast method of modal IMEX is 'be' or 'si', not {fast!r}")
        if int(slow_modes) < 1:
            raise ValueError("slow_modes must be >= 1")
        self.system, self.count, self.fast_name = system, int(slow_modes), fast
        self.fast = ImplicitIntegrator(system, fast, prefix=prefix, options=options)
        self.modes = []        # Phi, M-orthonormal
        self.weights = []      # M Phi with supports zeroed: eta = weights . q
        self.omega2 = None
        self._a = None         # slow modal acceleration at the end of the last step
        self._last = None
        self._f = system.create_vec()
        self._tmp = system.create_vec()

    # -- modes ------------------------------------------------------------------------------
    def setup(self, q0: PETSc.Vec) -> None:
        """Compute the slow modes (done by the first step; q0 is used by the dense path)."""
        if not self.modes:
            self._compute_modes(q0)

    def slow_energy(self, q: PETSc.Vec, v: PETSc.Vec) -> float:
        """1/2 sum_i (zeta_i^2 + Omega_i^2 eta_i^2): the energy in the slow modes (linear)."""
        eta, zeta = self._project(q), self._project(v)
        return 0.5 * float(np.sum(zeta**2 + self.omega2 * eta**2))

    def _compute_modes(self, q0: PETSc.Vec) -> None:
        s = self.system
        if s.model is not None:            # a model-backed system: SLEPc on its matrices

            res = compute_modes(s.model, self.count, prefix="imex_",
                                options=self.fast.options.under("imex_"))
            values = np.asarray(res.eigenvalues, float)
            for x in res.modes:
                y = s.create_vec()
                y.getArray()[:] = x.getArray(readonly=True)
                self.modes.append(y)
            res.destroy()
        else:
            values = self._dense_modes(q0)
        self.omega2 = values
        self._weigh()

    def _weigh(self) -> None:
        """weights = M Phi with the supports zeroed (eta = weights . q)."""
        s = self.system
        for x in self.modes:
            w = s.create_vec()
            s.M.mult(x, w)
            s.zero_prescribed(w)
            self.weights.append(w)

    def _dense_modes(self, q0: PETSc.Vec) -> np.ndarray:
        """Lowest modes of K(q0) x = omega^2 M x for small systems without a mesh (dense)."""
        s = self.system
        comm = s.comm.tompi4py()
        n = q0.getSize()
        if n > 3000:
            raise ExperimentError(f"modal imex: {n} dofs is too many for the dense eigensolver "
                                  "of systems without a model")
        K = s.create_matrix()
        s.assemble_combination(q0, 0.0, 1.0, 0.0, K, eliminate=False)

        def dense(A):
            lo, hi = A.getOwnershipRange()
            rows = np.zeros((hi - lo, n))
            for i in range(lo, hi):
                cols, vals = A.getRow(i)
                rows[i - lo, cols] = vals
            return np.vstack(comm.allgather(rows))

        Kd, Md = dense(K), dense(s.M)
        K.destroy()
        L = np.linalg.cholesky(Md)
        Linv = np.linalg.inv(L)
        lam, y = np.linalg.eigh(Linv @ Kd @ Linv.T)
        vecs = Linv.T @ y[:, :self.count]            # M-orthonormal
        lo, hi = q0.getOwnershipRange()
        for j in range(vecs.shape[1]):
            x = s.create_vec()
            x.getArray()[:] = vecs[lo:hi, j]
            self.modes.append(x)
        return lam[:self.count]

    def _project(self, vec: PETSc.Vec) -> np.ndarray:
        return np.array([vec.dot(w) for w in self.weights])

    def _expand(self, vec: PETSc.Vec, coefficients: np.ndarray) -> None:
        """vec += Phi coefficients."""
        for c, x in zip(coefficients, self.modes, strict=True):
            vec.axpy(float(c), x)

    def _slow_force(self, t: float, q: PETSc.Vec, v: PETSc.Vec | None) -> np.ndarray:
        """Phi^T f(t, q, v), f = -grad W(q) - D v + gravity + tractions (v None: no damping)."""
        s, f = self.system, self._f
        s.internal_gradient(q, f)
        f.scale(-1.0)
        f.axpy(1.0, s.gravity)
        f.axpy(1.0, s.tractions(t, self._tmp))
        if v is not None:
            f.axpy(-1.0, s.damping_apply(v, self._tmp))
        return np.array([f.dot(x) for x in self.modes])

    def _damping_force(self, v: PETSc.Vec) -> np.ndarray:
        d = self.system.damping_apply(v, self._tmp)
        return np.array([d.dot(x) for x in self.modes])

    def _continues(self, t0, q0, v0) -> bool:
        if self._last is None:
            return False
        t_last, q_last, v_last = self._last
        if abs(t0 - t_last) > 1e-12 * max(1.0, abs(t0)):
            return False
        same = all(np.array_equal(a.getArray(readonly=True), b.getArray(readonly=True))
                   for a, b in ((q0, q_last), (v0, v_last)))
        return bool(self.system.comm.tompi4py().allreduce(same, op=MPI.LAND))

    # -- stepping ---------------------------------------------------------------------------
    def step(self, t0: float, q0: PETSc.Vec, v0: PETSc.Vec, h: float,
             q1: PETSc.Vec, v1: PETSc.Vec) -> StepReport:
        """BE step of everything, then the slow modal components replaced by a Verlet step."""
        s = self.system
        self.setup(q0)
        omega_max = float(np.sqrt(max(self.omega2.max(), 0.0)))
        if h * omega_max >= 2.0:
            raise ExperimentError(
                f"modal imex: step {h:g} s is above the explicit limit {2.0 / omega_max:.4g} s "
                f"of the {self.count} slow modes (highest {omega_max / (2 * np.pi):.4g} Hz); "
                "use fewer slow modes or a smaller step")
        report = self.fast.step(t0, q0, v0, h, q1, v1)
        if not report.converged:
            self._last = None
            return report
        eta0, zeta0 = self._project(q0), self._project(v0)
        a0 = self._a if self._continues(t0, q0, v0) else self._slow_force(t0, q0, v0)
        zeta_half = zeta0 + 0.5 * h * a0
        eta1 = eta0 + h * zeta_half
        self._expand(q1, eta1 - self._project(q1))
        # kick: the damping needs v1, predicted as in the explicit Verlet (second order)
        v_half = v1.copy()
        self._expand(v_half, zeta_half - self._project(v1))
        a_nodamp = self._slow_force(t0 + h, q1, None)
        zeta_pred = zeta_half + 0.5 * h * (a_nodamp - self._damping_force(v_half))
        self._expand(v_half, zeta_pred - zeta_half)      # now the predicted v1
        a1 = a_nodamp - self._damping_force(v_half)
        zeta1 = zeta_half + 0.5 * h * a1
        self._expand(v1, zeta1 - self._project(v1))
        v_half.destroy()
        self._a = a1
        # work terms paired with the final increment (trapezoidal damping, midpoint tractions)
        dq = q1.copy()
        dq.axpy(-1.0, q0)
        vm = v0.copy()
        vm.axpy(1.0, v1)
        vm.scale(0.5)
        report.dissipated = dq.dot(s.damping_apply(vm, self._tmp))
        report.external_work = dq.dot(s.tractions(t0 + 0.5 * h, self._tmp))
        dq.destroy()
        vm.destroy()
        if self._last is not None:
            for vec in self._last[1:]:
                vec.destroy()
        self._last = (t0 + h, q1.copy(), v1.copy())
        return report

    def state(self) -> dict:
        """What a restart needs to continue bit for bit: the slow modes and their eigenvalues, and
        the slow modal acceleration the next step starts from.

        The modes are part of the state because recomputing them is not repeatable to the last
        bit on several ranks (the shift-and-invert factorization's round-off varies from run to
        run): two uninterrupted 2-rank runs of a P2 bar ended 7e-18 to 1.7e-17 m apart in about
        1 run of 9. The acceleration was computed with the predicted end velocity, so recomputing
        it from the checkpoint's (q, v) gives another run (6e-9 of max |q| and 5e-8 of max |v|
        four steps after a restart of tests/test_restart_integrators.py's bar)."""
        if self._last is None or self._a is None:
            return {}
        state = {"slow_acceleration": np.array(self._a, dtype=float),
                 "slow_omega2": np.array(self.omega2, dtype=float)}
        state.update({f"slow_mode_{i}": x for i, x in enumerate(self.modes)})
        return state

    def restore(self, t, q, v, state: dict) -> None:
        """Continue from a checkpoint's (t, q, v) and :meth:`state` (without it, the next step
        recomputes the modes and the slow acceleration from (q, v))."""
        if "slow_acceleration" not in state:
            return
        names = [f"slow_mode_{i}" for i in range(self.count)]
        if "slow_omega2" in state and all(n in state for n in names):
            for vec in self.modes + self.weights:
                vec.destroy()
            self.modes, self.weights = [], []
            for n in names:
                x = self.system.create_vec()
                state[n].copy(x)
                self.modes.append(x)
            self._weigh()
            self.omega2 = np.array(state["slow_omega2"], dtype=float)
        self._a = np.array(state["slow_acceleration"], dtype=float)
        if self._last is not None:
            for vec in self._last[1:]:
                vec.destroy()
        self._last = (t, q.copy(), v.copy())

    def destroy(self) -> None:
        self.fast.destroy()
        for vec in self.modes + self.weights + [self._f, self._tmp]:
            vec.destroy()
        if self._last is not None:
            for vec in self._last[1:]:
                vec.destroy()

