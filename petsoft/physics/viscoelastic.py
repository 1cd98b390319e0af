"""A standard linear solid (Zener): one Maxwell branch in parallel with the elastic law.

The branch's stress is sigma_M = g C0 (eps - eps_v) with d eps_v/dt = (eps - eps_v)/tau, C0 the
elasticity tensor of the reference configuration (the material's linear law), g = E_M/E >= 0 the
branch's modulus ratio and tau > 0 its relaxation time. For P1 elements eps = B q is linear in
the nodal displacements, so with a *nodal* internal variable z (eps_v = B z, the same layout as q)
the branch is exactly

    f_M = -g K0 (q - z),    dz/dt = (q - z)/tau,    stored energy 1/2 g (q - z)^T K0 (q - z),

with K0 the reference stiffness (:meth:`DynamicSystem.K0_matrix`). Its instantaneous modulus is
(1 + g) E, its long-term modulus E; a mode of stiffness k and mass m has the characteristic
equation m s^2 + k + g k tau s/(1 + tau s) = 0, whose damping peaks near omega tau = 1 (Rayleigh
stiffness damping, Kelvin-Voigt, grows with omega instead).

Time discretisation (r = h/tau; z is updated once a step is accepted, never inside Newton):

* ``be``, ``si``: backward Euler, z1 = (z0 + r q1)/(1 + r), so q1 - z1 = (q1 - z0)/(1 + r) and
  the step's residual gains g/(1 + r) K0 (q1 - z0), its Jacobian g/(1 + r) K0. The step is then
  exactly backward Euler applied to the first-order system (q, v, z): its unconditional
  stability and first order carry over, and (for TAO) it is the gradient of the incremental
  potential g/(2 (1 + r)) |q1 - z0|^2_K0. The exact exponential update for q frozen at q1,
  z1 = e^-r z0 + (1 - e^-r) q1, is also first order and stable, but it is not the backward Euler
  discretisation of the coupled system, so it was not chosen.
* ``midpoint``, ``trapezoidal``: the implicit midpoint (= trapezoidal, the branch is linear)
  rule, z1 - z0 = r (wm), wm = (q0 + q1)/2 - (z0 + z1)/2, which gives
  wm = ((q0 + q1)/2 - z0)/(1 + r/2); the residual gains g K0 wm, the Jacobian g/(2 (1 + r/2)) K0.
  Second order.
* ``alpha`` (petsoft's generalized-alpha; not ``--alpha-backend ts``): z by the same
  trapezoidal rule, the force evaluated like the elastic one at the alpha_f level,
  g K0 w_f with w_f = (1 - alpha_f) w0 + alpha_f w1, w1 = q1 - z1
  = (q1 - (r/2) q0 - (1 - r/2) z0)/(1 + r/2); Jacobian g alpha_f/(1 + r/2) K0. The consistent
  initial acceleration includes the branch force g K0 (q0 - z0).

Energy: the branch's stored energy is booked with the elastic energy, its dissipation
g dz . K0 w with the dissipated work (w1 for backward Euler, the mean strain wm of the
trapezoidal z update for midpoint, trapezoidal and generalized-alpha; >= 0 because dz = r w).
For the midpoint rule f_M . dq = (stored energy change) + dissipation exactly; backward Euler's
surplus 1/2 g |dw|^2_K0 >= 0 (and generalized-alpha's f-level pairing) is numerical and shows
in the ledger's ``numerical`` column.

The initial state is z(0) = q(0): the branch is relaxed (the body has rested at q(0) for long).
"""

from __future__ import annotations

import enum

from petsc4py import PETSc

from petsoft.errors import ExperimentError
from petsoft.terms import term

#: The branch's parameters: its term's keys (``[viscoelastic] ratio``, ``relaxation_time``),
#: settable in place; the residual derivatives do not cover them (z is not part of that state).
NAMES = tuple(k.dotted for k in term("material.viscoelastic").keys)
RATIO, RELAXATION_TIME = NAMES


class MaxwellRule(enum.Enum):
    """How the branch's internal variable z steps with an integrator (its registry entry,
    :data:`petsoft.dynamics.integrators.SCHEMES`, says which)."""

    #: backward Euler on z (be, si): dz = r w1
    BACKWARD_EULER = "backward-euler"
    #: the trapezoidal/midpoint rule on z (midpoint, trapezoidal): dz = r (w0 + w1)/2
    TRAPEZOIDAL = "trapezoidal"
    #: trapezoidal z with the force at generalized-alpha's alpha_f level
    GENERALIZED_ALPHA = "generalized-alpha"


def check(name: str, value: float) -> None:
    """Raise an ExperimentError saying the valid range when ``value`` is not valid for the
    branch's parameter ``name`` (:data:`NAMES`: ratio >= 0, relaxation_time > 0, finite)."""
    v = float(value)
    if name == RATIO and not 0.0 <= v < float("inf"):
        raise ExperimentError(f'parameter "{RATIO}" = {v!r} is invalid: it must be >= 0 and '
                              "finite (E_M / E; 0 = no branch)")
    if name == RELAXATION_TIME and not 0.0 < v < float("inf"):
        raise ExperimentError(f'parameter "{RELAXATION_TIME}" = {v!r} is invalid: it must be '
                              "> 0 and finite (seconds)")


class MaxwellBranch:
    """The Maxwell branch of a :class:`~petsoft.dynamics.system.DynamicSystem`.

    Parameters
    ----------
    system : DynamicSystem
        Provides ``K0_matrix()`` (kept current by ``set_parameters``) and ``create_vec()``.
    ratio : float
        g = E_M / E >= 0; 0 switches the branch off (the model is then exactly the elastic one).
    relaxation_time : float
        tau > 0, s.
    """

    def __init__(self, system, ratio: float, relaxation_time: float):
        self.system = system
        self.set(ratio, relaxation_time)
        #: Update z also at ratio 0 (no force): the forward sensitivities then differentiate
        #: with respect to the ratio at 0 (a diagnosis' null hypothesis). Set by ForwardModel.
        self.track = False
        self.z = None          # the internal variable (a global vector), set by reset()
        self._z0 = None
        self._q0 = None
        self._rule = None
        self._h = None
        self._af = 1.0         # generalized-alpha's alpha_f
        self._w = None         # the branch strain q - z the last force used
        self._wm = None        # the trapezoidal rule's mean strain (accept)

    # -- parameters ---------------------------------------------------------------------------
    def set(self, ratio: float, relaxation_time: float) -> None:
        """Change g and tau (validated by :func:`check`)."""
        ratio, tau = float(ratio), float(relaxation_time)
        check(RATIO, ratio)
        check(RELAXATION_TIME, tau)
        self.ratio, self.tau = ratio, tau

    def parameters(self) -> dict[str, float]:
        """name (:data:`NAMES`) -> value: the ratio and the relaxation time."""
        return dict(zip(NAMES, (self.ratio, self.tau), strict=True))

    def set_parameters(self, values: dict) -> None:
        """Take the branch's values from ``values`` (any mapping holding :data:`NAMES`)."""
        self.set(*(values[n] for n in NAMES))

    @property
    def active(self) -> bool:
        """Whether the branch contributes (ratio > 0)."""
        return self.ratio > 0.0

    @property
    def stepping(self) -> bool:
        """Whether the integrators advance z (the branch is active, or :attr:`track`)."""
        return self.active or self.track

    # -- state --------------------------------------------------------------------------------
    def reset(self, q0: PETSc.Vec) -> None:
        """Start a run at q0 with the branch relaxed: z = q0."""
        if self.z is None:
            self.z = q0.duplicate()
        q0.copy(self.z)

    def restore(self, z: PETSc.Vec) -> None:
        """Continue from a checkpointed internal variable."""
        if self.z is None:
            self.z = z.duplicate()
        z.copy(self.z)

    # -- one step -----------------------------------------------------------------------------
    def _factor(self) -> float:
        """1 + r (backward Euler) or 1 + r/2 (midpoint): q - z = (q* - z0)/factor."""
        r = self._h / self.tau
        return 1.0 + r if self._rule is MaxwellRule.BACKWARD_EULER else 1.0 + 0.5 * r

    def prepare(self, rule: MaxwellRule, h: float, q0: PETSc.Vec, alpha_f: float = 1.0) -> None:
        """Fix the step [t0, t0 + h] that starts from (q0, z). A branch never reset starts
        relaxed here (z = q0); a caller running several trajectories on one system calls
        :meth:`reset` at the start of each (Simulation and ForwardModel do)."""
        if self.z is None:
            self.reset(q0)
        self._rule, self._h, self._af = MaxwellRule(rule), float(h), float(alpha_f)
        if self._z0 is None:
            self._z0, self._q0, self._w, self._wm = (self.z.duplicate(), q0.duplicate(),
                                                     q0.duplicate(), q0.duplicate())
        self.z.copy(self._z0)
        q0.copy(self._q0)

    def jacobian_coefficient(self) -> float:
        """c such that the step's Jacobian gains c K0 (0 when off)."""
        if not self.active:
            return 0.0
        c = self.ratio / self._factor()
        if self._rule is MaxwellRule.BACKWARD_EULER:
            return c
        return self._af * c if self._rule is MaxwellRule.GENERALIZED_ALPHA else 0.5 * c

    def strain(self, q1: PETSc.Vec) -> PETSc.Vec:
        """The branch strain w the step's force uses, as a function of the unknown q1."""
        w = self._w
        if self._rule is MaxwellRule.BACKWARD_EULER:
            w.waxpy(-1.0, self._z0, q1)
            w.scale(1.0 / self._factor())
        elif self._rule is MaxwellRule.GENERALIZED_ALPHA:
            r2 = 0.5 * self._h / self.tau
            w.waxpy(-r2, self._q0, q1)                  # w1 = (q1 - r/2 q0 - (1 - r/2) z0)
            w.axpy(-(1.0 - r2), self._z0)               #      / (1 + r/2)
            w.scale(self._af / (1.0 + r2))
            w.axpy(1.0 - self._af, self._q0)            # + (1 - af) (q0 - z0)
            w.axpy(-(1.0 - self._af), self._z0)
        else:
            self._mean_strain(q1, w)
        return w

    def _mean_strain(self, q1: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """wm = (w0 + w1)/2 = ((q0 + q1)/2 - z0)/(1 + r/2) of the trapezoidal z update."""
        out.waxpy(1.0, self._q0, q1)
        out.scale(0.5)
        out.axpy(-1.0, self._z0)
        out.scale(1.0 / (1.0 + 0.5 * self._h / self.tau))
        return out

    def add_force(self, q1: PETSc.Vec, out: PETSc.Vec, work: PETSc.Vec) -> None:
        """out += g K0 w(q1) (the branch's contribution to the step's residual; all rows)."""
        if not self.active:
            return
        self.system.K0_matrix().mult(self.strain(q1), work)
        out.axpy(self.ratio, work)

    def incremental_potential(self, q1: PETSc.Vec, work: PETSc.Vec) -> float:
        """Backward Euler's branch potential g (1 + r)/2 |w1|^2_K0, w1 = (q1 - z0)/(1 + r): its
        gradient is the branch force g K0 w1."""
        if not self.active:
            return 0.0
        w = self.strain(q1)
        self.system.K0_matrix().mult(w, work)
        return 0.5 * self.ratio * self._factor() * w.dot(work)

    def accept(self, q1: PETSc.Vec) -> float:
        """Update z for the accepted step ending at q1; returns the dissipated work g dz . K0 w
        (>= 0)."""
        if not self.stepping:
            return 0.0
        # be: dz = r w1; midpoint, trapezoidal, alpha: dz = r wm
        w = (self.strain(q1) if self._rule is MaxwellRule.BACKWARD_EULER
             else self._mean_strain(q1, self._wm))
        dz = w.copy()
        dz.scale(self._h / self.tau)
        self.z.axpy(1.0, dz)
        Kw = w.duplicate()
        self.system.K0_matrix().mult(w, Kw)
        dissipated = self.ratio * dz.dot(Kw)
        dz.destroy()
        Kw.destroy()
        return dissipated

    # -- derivatives of a step (forward sensitivities: backward Euler, generalized-alpha) ------
    @property
    def step_start(self) -> PETSc.Vec:
        """z0 of the step last prepared (z itself is z1 once the step is accepted)."""
        return self._z0

    def residual_derivative(self, name: str, q1: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = d R/d p of the step's branch term for p = ``viscoelastic.ratio`` or
        ``viscoelastic.relaxation_time``; all rows.

        Backward Euler, g/(1 + r) K0 (q1 - z0): d/dg = K0 (q1 - z0)/(1 + r), d/dtau =
        g (r/tau)/(1 + r)^2 K0 (q1 - z0). Generalized-alpha, g K0 W with W = af (q1 - r2 q0 -
        (1 - r2) z0)/(1 + r2) + (1 - af)(q0 - z0), r2 = h/(2 tau): d/dg = K0 W, d/dtau =
        g af (r2/tau) K0 (q0 + q1 - 2 z0)/(1 + r2)^2."""
        x = q1.copy()
        if self._rule is MaxwellRule.GENERALIZED_ALPHA:
            r2 = 0.5 * self._h / self.tau
            if name == RATIO:
                self.strain(q1).copy(x)
                scale = 1.0
            else:
                x.axpy(1.0, self._q0)
                x.axpy(-2.0, self._z0)
                scale = self.ratio * self._af * (r2 / self.tau) / (1.0 + r2) ** 2
        elif self._rule is MaxwellRule.BACKWARD_EULER:
            r = self._h / self.tau
            x.axpy(-1.0, self._z0)
            scale = (1.0 / (1.0 + r) if name == RATIO
                     else self.ratio * (r / self.tau) / (1.0 + r) ** 2)
        else:
            raise NotImplementedError(f"branch derivatives for the {self._rule.value} rule")
        self.system.K0_matrix().mult(x, out)
        out.scale(scale)
        x.destroy()
        return out

    def state_coefficients(self) -> tuple[float, float]:
        """(a_q, a_z): the step's branch term depends on the step's start as
        K0 (a_q q0 + a_z z0) (backward Euler: (0, -g/(1 + r)); generalized-alpha: g (1 - af -
        af r2/(1 + r2)), -g (1 - af + af (1 - r2)/(1 + r2))), so its tangent adds
        K0 (a_q dq0 + a_z dz0) to the tangent step's residual."""
        g = self.ratio
        if self._rule is MaxwellRule.GENERALIZED_ALPHA:
            r2, af = 0.5 * self._h / self.tau, self._af
            return (g * (1.0 - af - af * r2 / (1.0 + r2)),
                    -g * (1.0 - af + af * (1.0 - r2) / (1.0 + r2)))
        return 0.0, -g / (1.0 + self._h / self.tau)

    def tangent_update(self, dz: PETSc.Vec, dq1: PETSc.Vec, q1: PETSc.Vec,
                       name: str | None = None, dq0: PETSc.Vec | None = None) -> None:
        """dz <- dz1 of the accepted step (``dq0``: the start's tangent, generalized-alpha).

        Backward Euler, z1 = (z0 + r q1)/(1 + r): dz1 = (dz0 + r dq1 + dr (q1 - z1))/(1 + r),
        dr = -r/tau for ``relaxation_time``. Generalized-alpha (trapezoidal z), z1 =
        ((1 - r2) z0 + r2 (q0 + q1))/(1 + r2): dz1 = ((1 - r2) dz0 + r2 (dq0 + dq1))/(1 + r2)
        - (r2/tau) (q0 + q1 - 2 z0)/(1 + r2)^2 for ``relaxation_time``."""
        if self._rule is MaxwellRule.GENERALIZED_ALPHA:
            r2 = 0.5 * self._h / self.tau
            dz.scale(1.0 - r2)
            dz.axpy(r2, dq0)
            dz.axpy(r2, dq1)
            dz.scale(1.0 / (1.0 + r2))
            if name == RELAXATION_TIME:
                c = -(r2 / self.tau) / (1.0 + r2) ** 2
                dz.axpy(c, self._q0)
                dz.axpy(c, q1)
                dz.axpy(-2.0 * c, self._z0)
            return
        r = self._h / self.tau
        dz.axpy(r, dq1)
        if name == RELAXATION_TIME:
            dz.axpy(-r / self.tau, q1)
            dz.axpy(r / self.tau, self.z)
        dz.scale(1.0 / (1.0 + r))

    # -- energy -------------------------------------------------------------------------------
    def energy(self, q: PETSc.Vec) -> float:
        """Stored energy 1/2 g (q - z)^T K0 (q - z) (0 when off or before reset)."""
        if not self.active or self.z is None:
            return 0.0
        w = q.copy()
        w.axpy(-1.0, self.z)
        Kw = w.duplicate()
        self.system.K0_matrix().mult(w, Kw)
        value = 0.5 * self.ratio * w.dot(Kw)
        w.destroy()
        Kw.destroy()
        return value

    def stress_force(self, q: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = g K0 (q - z): the branch's internal force at state q (e.g. for reactions)."""
        out.zeroEntries()
        if not self.active or self.z is None:
            return out
        w = q.copy()
        w.axpy(-1.0, self.z)
        self.system.K0_matrix().mult(w, out)
        out.scale(self.ratio)
        w.destroy()
        return out

    def destroy(self) -> None:
        for v in (self.z, self._z0, self._q0, self._w, self._wm):
            if v is not None:
                v.destroy()
        self.z = self._z0 = self._q0 = self._w = self._wm = None
