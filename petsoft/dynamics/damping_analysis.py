"""Artificial (numerical) damping of the time integrators (``petsoft damping``).

Applied to the undamped oscillator q'' + w^2 q = 0, a one-step method is a linear map of its state,
x_{n+1} = T(tau w) x_n, and its modes decay per step by the spectral radius rho = max |mu| of T
(the modulus of the principal root: the complex pair that approximates exp(+-i tau w)). The
computed solution is then the exact solution of the *ghost* ODE q'' + d q' + w^2 q = 0 with
exp(-d tau / 2) = rho, i.e. the artificial damping ratio

    d / w = -2 ln(rho) / (tau w),

a function of tau*w alone (lecture notes 000, "SI/BE artificial damping" and "generalized alpha
artificial damping curve"). For backward Euler / semi-implicit rho = 1/sqrt(1 + (tau w)^2) and
d/w = ln(1 + (tau w)^2) / (tau w).

This module owns three views of that number:

* **analytic**: the amplification matrices written down from the methods' formulas (not from the
  integrator code): the 2x2 BE/SI propagator of the lecture, the Cayley map of the midpoint and
  trapezoidal rules (|mu| = 1), symplectic Euler and velocity Verlet (|mu| = 1 for tau w < 2,
  unstable above), and the 3x3 generalized-alpha map of (q, v, a) built from the lecture's
  (alpha_m, alpha_f, beta, gamma) of spectral radius r at infinity;
* **measured on oscillators**: the real integrator classes run on one undamped
  :class:`~petsoft.dynamics.oscillator.OscillatorSystem` holding one oscillator per tau*w value
  (same tau for all), and rho fitted to each trajectory;
* **measured on a FEM body**: each integrator started from each of the K lowest mode shapes
  (q0 = small amplitude x mode, v0 = 0) of an experiment's undamped, unloaded body at its
  ``[time] step``, the state projected back on the mode (x^T M q, x^T M v) and rho fitted to
  that scalar trajectory. For a linear material the mode is an invariant subspace of every
  implicit method, so the measured value equals the analytic one at the mode's tau*w (to the
  Newton/eigen-solver tolerances); for a nonlinear material it does so in the small-amplitude
  limit (the default amplitude is 1e-3 of the body's size; much smaller amplitudes make the
  round-off of W(q1) - W(q0) stall the discrete-gradient midpoint's Newton iteration on
  nonlinear materials, reported as a failed run). The explicit schemes integrate with
  the lumped mass, whose modes are not exactly the consistent-mass modes: their measured values
  carry that mode coupling.

The fit: a trajectory y_n = (w q_n, v_n) of a linear one-step method satisfies z_{n+1} = A z_n for
the delay vectors z_n = (y_n, y_{n+1}) (4 components, enough for the 3-dimensional state of
generalized alpha, whose acceleration is not observed), so A is found by least squares over the
run (dynamic mode decomposition, keeping at most the method's state size of singular directions
and none below 1e-8 of the largest: modes the run does not excite are not fitted, and on a FEM
body the little of other modes in the projection gets no eigenvalue of its own), and rho is the
largest modulus of its eigenvalues.
It measures the per-step decay of the principal mode's amplitude over the whole run, independent
of the phase at which the run stops.
"""

from __future__ import annotations

import csv
import io
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from petsc4py import PETSc

from petsoft.atomic import write_text
from petsoft.dynamics.system import DynamicSystem
from petsoft.errors import ExperimentError
from petsoft.io.summary import write_summary
from petsoft.solvers.modes import compute_modes
from petsoft.solvers.options import SolverOptions

DEFAULT_RADII = (0.0, 0.25, 0.5, 0.75, 1.0)
TABLE_TAU_OMEGA = (0.1, 1.0, 10.0)
# tau*w of the measured markers: 10^(k/4), k = -8..8 (includes 0.1, 1 and 10 exactly)
MEASURED_TAU_OMEGA = 10.0 ** (np.arange(-8, 9) / 4.0)
EXPLICIT_LIMIT = 2.0   # symplectic Euler and Verlet: |mu| = 1 for tau w < 2, unstable above
RANK_TOL = 1e-8        # singular values of the fit below this fraction of the largest are noise


# ------------------------------------------------------------------------------------------------
# Schemes


@dataclass(frozen=True)
class Scheme:
    """One integrator: ``name`` in be, si, midpoint, trapezoidal, alpha, verlet, euler.

    ``radius`` is generalized alpha's spectral radius at infinity (None for the others).
    """

    name: str
    radius: float | None = None

    @property
    def key(self) -> str:
        """Identifier for files: ``be``, ``alpha_r0.5``, ..."""
        return f"alpha_r{self.radius:g}" if self.name == "alpha" else self.name

    @property
    def label(self) -> str:
        """Name for people (tables, legends)."""
        if self.name == "alpha":
            return f"alpha r={self.radius:g}"
        return {"be": "BE", "si": "SI", "midpoint": "midpoint", "trapezoidal": "trapezoidal",
                "verlet": "Verlet", "euler": "symplectic Euler"}[self.name]

    @property
    def explicit(self) -> bool:
        return self.name in ("verlet", "euler")

    @property
    def state_size(self) -> int:
        """Dimension of the one-step map on one oscillator: (q, v), or (q, v, a) for alpha."""
        return 3 if self.name == "alpha" else 2

    def integrator(self, system, petsc=None):
        """The petsoft integrator object of this scheme on ``system`` (the caller destroys it);
        ``petsc``: an experiment's ``[petsc]`` table, for its solvers."""
        from petsoft.dynamics.alpha import GeneralizedAlpha
        from petsoft.dynamics.explicit import ExplicitIntegrator
        from petsoft.dynamics.implicit import ImplicitIntegrator

        if self.name == "alpha":
            return GeneralizedAlpha(system, self.radius, options=SolverOptions("", petsc))
        if self.explicit:
            return ExplicitIntegrator(system, self.name,
                                      options=SolverOptions("stability_", petsc))
        return ImplicitIntegrator(system, self.name, options=SolverOptions("", petsc))


def default_schemes(radii=DEFAULT_RADII) -> list[Scheme]:
    """BE, SI, generalized alpha (each radius), midpoint, trapezoidal, Verlet, symplectic Euler."""
    return ([Scheme("be"), Scheme("si")] + [Scheme("alpha", float(r)) for r in radii]
            + [Scheme("midpoint"), Scheme("trapezoidal"), Scheme("verlet"), Scheme("euler")])


# ------------------------------------------------------------------------------------------------
# Analytic amplification matrices (state scaled to (w q, v), or (q, h v, h^2 a) for alpha, so
# that they depend on x = tau*w only)


def _stack(x: np.ndarray, rows) -> np.ndarray:
    """(n, k, k) array from nested lists of scalars / (n,) arrays."""
    return np.stack([np.stack([np.broadcast_to(np.asarray(e, float), x.shape) for e in row],
                              axis=-1) for row in rows], axis=-2)


def be_propagator(tau_omega) -> np.ndarray:
    """BE (= SI on a linear problem) on (w q, v): the lecture's T with d = 0.

    (q_n, v_n) = [[1, tau], [-tau w^2, 1]] (q, v)_{n-1} / (1 + tau^2 w^2); eigenvalues
    1/(1 +- i tau w).
    """
    x = np.atleast_1d(np.asarray(tau_omega, float))
    return _stack(x, [[1.0, x], [-x, 1.0]]) / (1.0 + x**2)[:, None, None]


def midpoint_propagator(tau_omega) -> np.ndarray:
    """Midpoint = trapezoidal on a linear problem: the Cayley map (I - A/2)^-1 (I + A/2)."""
    x = np.atleast_1d(np.asarray(tau_omega, float))
    c = 1.0 - 0.25 * x**2
    return _stack(x, [[c, x], [-x, c]]) / (1.0 + 0.25 * x**2)[:, None, None]


def symplectic_euler_propagator(tau_omega) -> np.ndarray:
    """v1 = v0 - tau w^2 q0, q1 = q0 + tau v1 on (w q, v)."""
    x = np.atleast_1d(np.asarray(tau_omega, float))
    return _stack(x, [[1.0 - x**2, x], [-x, 1.0]])


def verlet_propagator(tau_omega) -> np.ndarray:
    """Velocity Verlet (kick-drift-kick) on (w q, v)."""
    x = np.atleast_1d(np.asarray(tau_omega, float))
    c = 1.0 - 0.5 * x**2
    return _stack(x, [[c, x], [-x * (1.0 - 0.25 * x**2), c]])


def lecture_alpha_parameters(radius: float) -> tuple[float, float, float, float]:
    """(alpha_m, alpha_f, beta, gamma) of the lecture (Chung-Hulbert, weights on old values).

    alpha_m = (2r - 1)/(1 + r), alpha_f = r/(1 + r), alpha = alpha_m - alpha_f,
    beta = (1 - alpha)^2 / 4, gamma = 1/2 - alpha.
    """
    r = float(radius)
    am, af = (2.0 * r - 1.0) / (1.0 + r), r / (1.0 + r)
    a = am - af
    return am, af, 0.25 * (1.0 - a) ** 2, 0.5 - a


def alpha_amplification(tau_omega, radius: float) -> np.ndarray:
    """The 3x3 generalized-alpha map (q, h v, h^2 a)_n -> (q, h v, h^2 a)_{n+1} on q'' = -w^2 q.

    From the lecture's step (a the method's acceleration variable, f(q) = -w^2 q):

        q1 = q0 + h v0 + h^2/2 ((1 - 2 beta) a0 + 2 beta a1)
        v1 = v0 + h ((1 - gamma) a0 + gamma a1)
        (1 - alpha_m) a1 + alpha_m a0 = -w^2 ((1 - alpha_f) q1 + alpha_f q0)

    written as L x1 = R x0. The last row is divided by 1 + (tau w)^2 so that the map stays well
    scaled for large tau*w and ``tau_omega = inf`` gives the limit map exactly.
    """
    x = np.atleast_1d(np.asarray(tau_omega, float))
    am, af, beta, gamma = lecture_alpha_parameters(radius)
    with np.errstate(divide="ignore", over="ignore"):
        s = 1.0 / (1.0 + x**-2.0)            # x^2 / (1 + x^2): 0 at x = 0, 1 at x = inf
        c = 1.0 / (1.0 + x**2)               # 1 / (1 + x^2)
    zero, one = 0.0, 1.0
    L = _stack(x, [[one, zero, -beta], [zero, one, -gamma], [(1.0 - af) * s, zero, (1.0 - am) * c]])
    R = _stack(x, [[one, one, 0.5 - beta], [zero, one, 1.0 - gamma], [-af * s, zero, -am * c]])
    return np.linalg.solve(L, R)


def amplification(scheme: Scheme, tau_omega) -> np.ndarray:
    """The analytic amplification matrices (n, k, k) of ``scheme`` at each tau*w."""
    if scheme.name in ("be", "si"):
        return be_propagator(tau_omega)
    if scheme.name in ("midpoint", "trapezoidal"):
        return midpoint_propagator(tau_omega)
    if scheme.name == "verlet":
        return verlet_propagator(tau_omega)
    if scheme.name == "euler":
        return symplectic_euler_propagator(tau_omega)
    if scheme.name == "alpha":
        return alpha_amplification(tau_omega, scheme.radius)
    raise ValueError(f"unknown scheme {scheme.name!r}")


def spectral_radius(T: np.ndarray) -> np.ndarray:
    """max |eigenvalue| of each matrix of a stack (n, k, k)."""
    return np.abs(np.linalg.eigvals(T)).max(axis=-1)


def analytic_rho(scheme: Scheme, tau_omega) -> np.ndarray:
    """Spectral radius of the scheme's amplification matrix at each tau*w."""
    return spectral_radius(amplification(scheme, tau_omega))


def damping_ratio(rho, tau_omega) -> np.ndarray:
    """d/w = -2 ln(rho) / (tau w); negative where rho > 1 (growth: unstable)."""
    rho = np.asarray(rho, float)
    x = np.asarray(tau_omega, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return -2.0 * np.log(rho) / x + 0.0          # + 0.0: no "-0" in the tables


def be_damping_ratio(tau_omega) -> np.ndarray:
    """The lecture's closed form ln(1 + (tau w)^2) / (tau w)."""
    x = np.asarray(tau_omega, float)
    return np.log1p(x**2) / x


def stable(scheme: Scheme, tau_omega) -> np.ndarray:
    """Whether the scheme is stable at tau*w (only the explicit schemes have a limit).

    At tau*w = 2 exactly the explicit schemes have a double root -1 (linear growth): unstable.
    """
    x = np.asarray(tau_omega, float)
    if scheme.explicit:
        return x < EXPLICIT_LIMIT
    return np.ones(x.shape, bool)


# ------------------------------------------------------------------------------------------------
# The measurement: fit the one-step map to trajectories


def fit_spectral_radius(y: np.ndarray, floor: float = 1e-10, rank: int = 4) -> np.ndarray:
    """Per-step growth factor of the principal mode of each trajectory, by least squares.

    Parameters
    ----------
    y : ndarray (n, N+1, 2)
        n trajectories of (w q_n, v_n), n = 0..N (N >= 4).
    floor : float
        Pairs of steps where the state has fallen below ``floor`` times its initial size are left
        out (round-off and solver tolerances dominate there).
    rank : int
        At most this many singular directions are fitted: the method's state size. On a FEM
        body the projection on a mode also carries a little of other modes (nonlinear coupling,
        a lumped mass); a fit of full rank would give that residue eigenvalues of its own, of
        any modulus.

    Returns
    -------
    ndarray (n,)
        rho: the largest eigenvalue modulus of the fitted map z_n -> z_{n+1}, z_n = (y_n, y_{n+1}).
    """
    y = np.asarray(y, float)
    z = np.concatenate([y[:, :-1], y[:, 1:]], axis=2)          # (n, N, 4)
    z0, z1 = z[:, :-1], z[:, 1:]                               # pairs z_k -> z_{k+1}
    # A pair may be rescaled by any common factor without changing z1 = A z0: scale each by its
    # size, so that fast growth or decay does not hand the least squares to a few steps.
    size0 = np.abs(z0).max(axis=2, keepdims=True)
    size1 = np.abs(z1).max(axis=2, keepdims=True)
    initial = np.abs(y[:, :1]).max(axis=2, keepdims=True)
    keep = (np.minimum(size0, size1) > floor * initial) & np.isfinite(size1)
    scale = np.where(keep, size0, 1.0)
    z0 = np.where(keep, z0 / scale, 0.0)
    z1 = np.where(keep, z1 / scale, 0.0)
    # rows are snapshots: z1 = z0 A^T; A^T = V S^+ U^T z1 with small singular values dropped
    U, S, Vt = np.linalg.svd(z0, full_matrices=False)
    kept = (S > RANK_TOL * S[:, :1]) & (np.arange(S.shape[1]) < rank)
    Sinv = np.where(kept, 1.0 / np.where(S > 0, S, 1.0), 0.0)
    At = np.swapaxes(Vt, 1, 2) @ (Sinv[:, :, None] * (np.swapaxes(U, 1, 2) @ z1))
    return spectral_radius(At)


def measure_oscillators(scheme: Scheme, tau_omega, nsteps: int = 40, tau: float = 0.01,
                        comm: PETSc.Comm | None = None) -> np.ndarray:
    """Run the scheme's integrator on undamped oscillators w_i = tau_omega_i / tau; fitted rho.

    All oscillators live in one :class:`OscillatorSystem` (distributed over ``comm``) started
    from q = 1, v = 0 and stepped ``nsteps`` times with the same step ``tau`` (collective; the
    result is the same on every rank).
    """
    from petsoft.dynamics.oscillator import OscillatorSystem

    x = np.atleast_1d(np.asarray(tau_omega, float))
    system = OscillatorSystem(x / tau, comm=comm)
    integrator = scheme.integrator(system)
    q, v = system.initial_state()
    q1, v1 = q.duplicate(), v.duplicate()
    omega = np.sqrt(system.omega2)
    history = np.empty((nsteps + 1, len(omega), 2))
    history[0] = np.column_stack([omega * q.getArray(readonly=True), v.getArray(readonly=True)])
    with np.errstate(over="ignore", invalid="ignore"):     # unstable explicit runs grow
        for n in range(nsteps):
            report = integrator.step(n * tau, q, v, tau, q1, v1)
            if not report.converged:
                raise RuntimeError(f"{scheme.label} step {n} on the oscillators did not converge "
                                   f"({report.reason})")
            q1.copy(q)
            v1.copy(v)
            history[n + 1] = np.column_stack([omega * q.getArray(readonly=True),
                                              v.getArray(readonly=True)])
    for obj in (integrator, q, v, q1, v1, system):
        obj.destroy()
    # ownership ranges ascend with the rank: concatenating the ranks' blocks restores the order
    parts = system.comm.tompi4py().allgather(np.ascontiguousarray(np.swapaxes(history, 0, 1)))
    return fit_spectral_radius(np.concatenate(parts, axis=0), rank=scheme.state_size)


# ------------------------------------------------------------------------------------------------
# Scalar analysis


@dataclass
class ScalarRow:
    """Analytic and measured rho and d/w of one scheme at the measured tau*w values."""

    scheme: Scheme
    tau_omega: np.ndarray
    rho_analytic: np.ndarray
    rho_measured: np.ndarray
    nsteps: int = 40

    @property
    def d_analytic(self) -> np.ndarray:
        return damping_ratio(self.rho_analytic, self.tau_omega)

    @property
    def d_measured(self) -> np.ndarray:
        return damping_ratio(self.rho_measured, self.tau_omega)

    @property
    def stable(self) -> np.ndarray:
        return stable(self.scheme, self.tau_omega)


def scalar_analysis(schemes, tau_omega=MEASURED_TAU_OMEGA, nsteps: int = 40,
                    comm: PETSc.Comm | None = None) -> list[ScalarRow]:
    """Analytic and measured rho of every scheme at every tau*w (collective)."""
    x = np.asarray(tau_omega, float)
    return [ScalarRow(s, x, analytic_rho(s, x), measure_oscillators(s, x, nsteps, comm=comm),
                      nsteps) for s in schemes]


# ------------------------------------------------------------------------------------------------
# FEM body


class FreeVibrationSystem(DynamicSystem):
    """An experiment's undamped body without loads, supports held at zero (free vibration).

    The modes (``petsoft modes``) are those of this system's consistent mass and reference
    stiffness, so a mode shape is an invariant subspace of it (for a linear material).
    """

    time_dependent_loads = False
    moving_boundary = False

    def __init__(self, model):
        super().__init__(model)             # no Rayleigh damping: only the artificial one
        self.viscoelastic.set(0.0, self.viscoelastic.tau)   # nor the viscoelastic branch's
        self.gravity.zeroEntries()

    def tractions(self, t: float, out: PETSc.Vec) -> PETSc.Vec:
        out.zeroEntries()
        return out

    def apply_prescribed(self, vec: PETSc.Vec, t: float) -> None:
        self.zero_prescribed(vec)


@dataclass
class FemModesResult:
    """Measured and analytic rho of each scheme on each elastic mode of a body.

    ``rho_measured[key]`` is NaN where the scheme did not run (explicit above its stability
    limit: ``explicit_limit`` is then the largest stable step, s; ``notes[key]`` says so) or its
    Newton iteration failed (``failures[(key, k)]`` for mode index k). ``notes`` also carries the
    explicit schemes' lumped-mass caveat.
    """

    step: float
    frequencies_hz: np.ndarray
    omega: np.ndarray
    schemes: list
    rho_analytic: dict = field(default_factory=dict)
    rho_measured: dict = field(default_factory=dict)
    explicit_limit: float | None = None
    amplitude: float = 0.0
    nsteps: int = 0
    material: str = ""
    rigid_modes: int = 0
    notes: dict = field(default_factory=dict)
    failures: dict = field(default_factory=dict)

    @property
    def tau_omega(self) -> np.ndarray:
        return self.step * self.omega


def fem_mode_damping(model, step: float, schemes, nmodes: int = 6, nsteps: int = 16,
                     amplitude: float = 1e-3, monitor=None, petsc=None) -> FemModesResult:
    """Artificial damping of each scheme on each of the ``nmodes`` lowest modes of a body.

    Parameters
    ----------
    model : petsoft.physics.model.Model
    step : float
        The time step tau (s), e.g. the experiment's ``[time] step``.
    schemes : list of Scheme
    nmodes : int
        Modes from :func:`petsoft.solvers.modes.compute_modes`; rigid-body modes (w = 0) are
        skipped.
    nsteps : int
        Steps per run (>= 6).
    amplitude : float
        Initial displacement q0 = c x_k with max |q0| = amplitude x the bounding-box diagonal.
    monitor : callable or None
        Receives progress lines.
    petsc : mapping of str to str, optional
        The experiment's ``[petsc]`` table, for the eigensolver and the integrators' solvers.

    Returns
    -------
    FemModesResult
    """
    modes = compute_modes(model, nmodes, options=SolverOptions("", petsc))
    elastic = np.flatnonzero(modes.eigenvalues > 0.0)
    omega = np.sqrt(modes.eigenvalues[elastic])
    shapes = [modes.modes[k] for k in elastic]
    system = FreeVibrationSystem(model)
    points = model.dmesh.mesh.points
    size = float(np.linalg.norm(np.ptp(points, axis=0)))
    result = FemModesResult(step, modes.frequencies_hz[elastic], omega, list(schemes),
                            amplitude=amplitude, nsteps=nsteps,
                            material=", ".join(sorted({m.model for m in
                                                       model.experiment.material.values()})),
                            rigid_modes=modes.rigid_modes)
    Mx = [system.M.createVecLeft() for _ in shapes]
    for x, mx in zip(shapes, Mx, strict=True):
        system.M.mult(x, mx)
    q, v = system.create_vec(), system.create_vec()
    q1, v1 = q.duplicate(), v.duplicate()
    for scheme in schemes:
        result.rho_analytic[scheme.key] = np.where(stable(scheme, result.tau_omega),
                                                   analytic_rho(scheme, result.tau_omega), np.nan)
        measured = result.rho_measured[scheme.key] = np.full(len(shapes), np.nan)
        if scheme.explicit:
            probe = scheme.integrator(system, petsc)
            q.zeroEntries()
            try:
                result.explicit_limit = probe.check_step(q, step)
            except ExperimentError:
                result.explicit_limit = 2.0 / probe.omega_max
                # the body is unstable at this step, even where its lowest modes alone are not
                result.rho_analytic[scheme.key] = measured
                result.notes[scheme.key] = (f"unstable: step above the limit "
                                            f"{result.explicit_limit:.4g} s")
            finally:
                probe.destroy()
                system.lumped_kinetic = False
            if scheme.key in result.notes:
                if monitor:
                    monitor(f"  {scheme.label}: {result.notes[scheme.key]}, not run")
                continue
        for k, (x, mx, w) in enumerate(zip(shapes, Mx, omega, strict=True)):
            # a fresh integrator per run: no state (Verlet's acceleration, alpha's) carries over
            integrator = scheme.integrator(system, petsc)
            x.copy(q)
            q.scale(amplitude * size / x.norm(PETSc.NormType.INFINITY))
            v.zeroEntries()
            y = np.empty((nsteps + 1, 2))
            y[0] = w * mx.dot(q), mx.dot(v)
            for n in range(nsteps):
                report = integrator.step(n * step, q, v, step, q1, v1)
                if not report.converged:
                    result.failures[scheme.key, k] = (f"step {n} not converged "
                                                      f"({report.reason})")
                    break
                q1.copy(q)
                v1.copy(v)
                y[n + 1] = w * mx.dot(q), mx.dot(v)
            else:
                measured[k] = fit_spectral_radius(y[None], floor=1e-7,
                                                  rank=scheme.state_size)[0]
            integrator.destroy()
        system.lumped_kinetic = False
        if scheme.explicit:
            result.notes[scheme.key] = ("lumped mass: the consistent-mass mode is not one of its "
                                        "modes, the fit sees their beating")
        failed = sum(1 for key, _ in result.failures if key == scheme.key)
        if monitor:
            monitor(f"  {scheme.label}: {len(shapes)} modes x {nsteps} steps"
                    + (f"; {failed} run(s) failed" if failed else ""))
    for obj in (q, v, q1, v1, *Mx, system):
        obj.destroy()
    modes.destroy()
    return result


# ------------------------------------------------------------------------------------------------
# Reporting


def _fmt(value, spec=".6g") -> str:
    if value is None or not np.isfinite(value):
        return "—"
    if spec.endswith("g") and abs(value) < 1e-12:
        return "0"       # |mu| = 1 up to the round-off of an eigenvalue solve (CSV: raw values)
    return format(value, spec)


def _deviation(measured: float, analytic: float) -> float:
    """|measured - analytic| / |analytic|, or the absolute difference where |analytic| < 1e-6."""
    diff = abs(measured - analytic)
    return diff / abs(analytic) if abs(analytic) > 1e-6 else diff


def _number(value) -> float | None:
    value = float(value)
    return value if np.isfinite(value) else None


def scalar_table_rows(rows: list[ScalarRow], at=None) -> list[dict]:
    """Rows (scheme, tau*w, rho and d/w analytic and measured) at the tau*w values ``at``
    (default: all measured values)."""
    out = []
    for row in rows:
        index = (range(len(row.tau_omega)) if at is None
                 else [int(np.argmin(np.abs(row.tau_omega - t))) for t in at])
        for i in index:
            ok = bool(row.stable[i])
            da, dm = float(row.d_analytic[i]), float(row.d_measured[i])
            out.append({"scheme": row.scheme.label, "key": row.scheme.key,
                        "tau_omega": float(row.tau_omega[i]), "stable": ok,
                        "rho_analytic": float(row.rho_analytic[i]),
                        "rho_measured": float(row.rho_measured[i]),
                        "d_over_omega_analytic": da if ok else None,
                        "d_over_omega_measured": dm if ok else None,
                        "deviation": _deviation(dm, da) if ok else None,
                        "note": "" if ok else (f"unstable: rho = {row.rho_analytic[i]:.4g} "
                                               f"(measured {row.rho_measured[i]:.4g})")})
    return out


def fem_table_rows(fem: FemModesResult) -> list[dict]:
    """Rows (mode, frequency, tau*w, scheme, analytic and measured d/w, note)."""
    out = []
    x = fem.tau_omega
    for scheme in fem.schemes:
        da = damping_ratio(fem.rho_analytic[scheme.key], x)
        dm = damping_ratio(fem.rho_measured[scheme.key], x)
        for k in range(len(x)):
            ok = bool(np.isfinite(da[k]) and np.isfinite(dm[k]))
            out.append({"mode": k + 1 + fem.rigid_modes,
                        "frequency_hz": float(fem.frequencies_hz[k]),
                        "tau_omega": float(x[k]), "scheme": scheme.label, "key": scheme.key,
                        "d_over_omega_analytic": _number(da[k]),
                        "d_over_omega_measured": _number(dm[k]),
                        "deviation": _deviation(dm[k], da[k]) if ok else None,
                        "note": fem.failures.get((scheme.key, k), fem.notes.get(scheme.key, ""))})
    return out


def _markdown(rows: list[dict], columns: list[tuple[str, str, str]]) -> list[str]:
    lines = ["| " + " | ".join(title for _, title, _ in columns) + " |",
             "|" + "|".join("---:" if spec else "---" for *_, spec in columns) + "|"]
    for r in rows:
        lines.append("| " + " | ".join(
            (_fmt(r[k], spec) if spec else str(r[k])) for k, _, spec in columns) + " |")
    return lines


SCALAR_COLUMNS = [("scheme", "scheme", ""), ("tau_omega", "τω", "g"),
                  ("d_over_omega_analytic", "d/ω analytic", ".6g"),
                  ("d_over_omega_measured", "d/ω measured", ".6g"),
                  ("deviation", "deviation", ".1e"), ("note", "note", "")]
FEM_COLUMNS = [("mode", "mode", ""), ("frequency_hz", "f (Hz)", ".5g"),
               ("tau_omega", "τω", ".4g"), ("scheme", "scheme", ""),
               ("d_over_omega_analytic", "d/ω analytic", ".6g"),
               ("d_over_omega_measured", "d/ω measured", ".6g"),
               ("deviation", "deviation", ".1e"), ("note", "note", "")]


def _write_csv(path: Path, rows: list[dict]) -> None:
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, fieldnames=list(rows[0]))
    writer.writeheader()
    for r in rows:
        writer.writerow({k: ("" if v is None else v) for k, v in r.items()})
    write_text(path, text.getvalue())


def plot(rows: list[ScalarRow], path: Path, fem: FemModesResult | None = None) -> Path:
    """d/w against tau*w (log axis, 1e-2..1e2): analytic lines, measured markers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.logspace(-2, 2, 400)
    fig, ax = plt.subplots(figsize=(12, 5.6))
    alphas = [r for r in rows if r.scheme.name == "alpha"]
    cmap = plt.get_cmap("viridis")
    colors = {"be": "black", "si": "black", "midpoint": "tab:red", "trapezoidal": "tab:red",
              "verlet": "tab:orange", "euler": "tab:orange"}
    for i, r in enumerate(alphas):
        colors[r.scheme.key] = cmap(0.9 * i / max(1, len(alphas) - 1))
    markers = {"be": "o", "si": "x", "midpoint": "s", "trapezoidal": "+", "verlet": "^",
               "euler": "v"}
    drawn = set()
    for r in rows:
        s, c = r.scheme, colors[r.scheme.key]
        line_key = "be" if s.name in ("be", "si") else (
            "cayley" if s.name in ("midpoint", "trapezoidal") else (
                "explicit" if s.explicit else s.key))
        if line_key not in drawn:
            drawn.add(line_key)
            label = {"be": "BE / SI: ln(1+(τω)²)/(τω)",
                     "cayley": "midpoint, trapezoidal: |μ| = 1",
                     "explicit": "Verlet, sympl. Euler: |μ| = 1 (τω < 2)"}.get(line_key)
            label = label or f"gen. α, r = {s.radius:g}"
            xs = x[stable(s, x)]
            dashed = line_key in ("cayley", "explicit")
            # the d = 0 lines coincide: dashed and on top, so that alpha r = 1 shows between
            ax.plot(xs, damping_ratio(analytic_rho(s, xs), xs), color=c, lw=1.2 if dashed else 1.6,
                    ls=(0, (4, 4)) if line_key == "cayley" else ((4, (4, 4)) if dashed else "-"),
                    label=label, zorder=3 if dashed else 2)
        ok = r.stable
        ax.plot(r.tau_omega[ok], r.d_measured[ok], ls="none", marker=markers.get(s.name, "o"),
                mfc="none" if s.name not in ("si", "trapezoidal") else c, color=c, ms=6,
                label=f"measured: {s.label}" if s.name in markers else None)
    ax.plot([], [], ls="none", marker="o", mfc="none", color="0.4",
            label="measured: gen. α (petsoft integrator)")
    if fem is not None:
        xf = fem.tau_omega
        for s in fem.schemes:
            dm = damping_ratio(fem.rho_measured[s.key], xf)
            ok = np.isfinite(dm)
            ax.plot(xf[ok], dm[ok], ls="none", marker="*", ms=11, color=colors.get(s.key, "k"),
                    mec="k", mew=0.4)
        ax.plot([], [], ls="none", marker="*", ms=11, color="0.6", mec="k", mew=0.4,
                label=f"FEM modes ({len(xf)}; colour: integrator), τ = {fem.step:g} s")
    ax.axvspan(EXPLICIT_LIMIT, 1e2, color="tab:orange", alpha=0.08)
    ax.text(0.99, 0.6, "explicit schemes\nunstable (τω ≥ 2)", color="tab:orange", fontsize=9,
            ha="right", transform=ax.transAxes)
    ax.set_xscale("log")
    ax.set_xlim(1e-2, 1e2)
    ax.set_ylim(-0.03, None)
    ax.set_xlabel("τω  (time step × angular frequency)")
    ax.set_ylabel("artificial damping ratio  d / ω = −2 ln ρ / (τω)")
    ax.set_title("Artificial damping of petsoft's integrators on q'' + ω²q = 0 "
                 "(lines: analytic, markers: measured)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    # outside the axes: inside it would hide the curves' peaks and the FEM markers
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def report(out: Path, schemes, fem: FemModesResult | None, rows: list[ScalarRow],
           comm: PETSc.Comm, started: float, printer=print, source: str | None = None) -> dict:
    """Print the tables and write damping.png, scalar/fem CSV, damping.md and summary.json.

    Collective (only rank 0 writes and prints); returns the summary's results on rank 0.
    """
    table = scalar_table_rows(rows, TABLE_TAU_OMEGA)
    full = scalar_table_rows(rows)
    fem_rows = fem_table_rows(fem) if fem is not None else []
    results = {}
    if comm.rank != 0:
        return results
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# Artificial damping (petsoft damping)", "",
             "d/ω = −2 ln ρ / (τω), ρ the spectral radius of the one-step map on q'' + ω²q = 0. "
             "Analytic: amplification matrices; measured: petsoft's integrators on undamped "
             f"oscillators, ρ fitted to {rows[0].nsteps} steps. Deviation is relative "
             "(absolute where d/ω < 1e-6).", ""]
    lines += _markdown(table, SCALAR_COLUMNS)
    for line in lines[4:]:
        printer(line)
    if fem is not None:
        head = (f"FEM modes ({source or 'experiment'}, {fem.material} material): τ = "
                f"{fem.step:g} s, q0 = mode × amplitude {fem.amplitude:g} of the body size, "
                f"v0 = 0, {fem.nsteps} steps, state projected on the mode (xᵀMq, xᵀMv)")
        if fem.explicit_limit is not None:
            head += f"; explicit stability limit {fem.explicit_limit:.4g} s"
        fem_lines = ["", "## " + head, ""] + _markdown(fem_rows, FEM_COLUMNS)
        printer("")
        printer(head)
        for line in fem_lines[3:]:
            printer(line)
        lines += fem_lines
    write_text(out / "damping.md", "\n".join(lines) + "\n")
    _write_csv(out / "damping_scalar.csv", full)
    files = ["damping.png", "damping.md", "damping_scalar.csv"]
    if fem_rows:
        _write_csv(out / "damping_fem.csv", fem_rows)
        files.append("damping_fem.csv")
    png = plot(rows, out / "damping.png", fem)
    stable_dev = [r["deviation"] for r in table if r["deviation"] is not None]
    results = {
        "definition": "d/omega = -2 ln(rho) / (tau omega), rho = spectral radius per step",
        "tau_omega": list(TABLE_TAU_OMEGA),
        "schemes": {s.key: {"label": s.label,
                            **{k: [_number(r[k]) if r[k] is not None else None
                                   for r in table if r["key"] == s.key]
                               for k in ("d_over_omega_analytic", "d_over_omega_measured",
                                         "rho_analytic", "rho_measured")}}
                    for s in schemes},
        "be_closed_form": {"tau_omega": list(TABLE_TAU_OMEGA),
                           "d_over_omega": be_damping_ratio(TABLE_TAU_OMEGA).tolist()},
        "max_deviation_measured_vs_analytic": max(stable_dev) if stable_dev else None,
        "files": files,
    }
    if fem is not None:
        fem_dev = [r["deviation"] for r in fem_rows
                   if r["deviation"] is not None and r["key"] not in ("verlet", "euler")]
        results["fem"] = {
            "source": source, "step": fem.step, "material": fem.material,
            "amplitude": fem.amplitude, "steps": fem.nsteps, "rigid_modes": fem.rigid_modes,
            "frequencies_hz": fem.frequencies_hz.tolist(), "tau_omega": fem.tau_omega.tolist(),
            "explicit_limit": fem.explicit_limit,
            "d_over_omega_analytic": {k: list(map(_number, damping_ratio(v, fem.tau_omega)))
                                      for k, v in fem.rho_analytic.items()},
            "d_over_omega_measured": {k: list(map(_number, damping_ratio(v, fem.tau_omega)))
                                      for k, v in fem.rho_measured.items()},
            "notes": fem.notes,
            "failures": [{"scheme": key, "mode": k + 1 + fem.rigid_modes, "reason": why}
                         for (key, k), why in fem.failures.items()],
            "max_deviation_implicit": max(fem_dev) if fem_dev else None,
        }
    solver = {"fit": "least-squares one-step map of (w q, v) delay vectors (DMD)",
              "oscillator_steps": rows[0].nsteps}
    path = write_summary(out, "damping", results, solver, time.perf_counter() - started, comm)
    printer(f"plot: {png}; wrote {path.parent}/")
    return results
