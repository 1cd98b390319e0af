"""The stiff-spring pendulum with gravity [Ascher & Reich '99]: fast radius, slow angle.

A unit mass on a massless spring of stiffness w^2 and rest length r0, hinged at the origin, under
gravity g. In polar coordinates (r, phi) with momenta (p_r, p_phi) the Hamiltonian is the
lecture's

    H = 1/2 [p_r^2 + r^-2 p_phi^2 + w^2 (r - r0)^2] + g r sin(phi),

    r' = p_r,      p_r'   = -w^2 (r - r0) + r^-3 p_phi^2 - g sin(phi),
    phi' = p_phi / r^2,   p_phi' = -g r cos(phi).

Cartesian coordinates: q = (x, y) = (r cos phi, r sin phi), so that the gravity potential
g r sin(phi) = g y belongs to a force -g e_y (y up; the hanging rest state is phi = -pi/2). The
slide writes q = (r cos phi, -r sin phi), which with the same H makes gravity point along +y; the
polar equations are identical. The Cartesian Hamiltonian is

    H = 1/2 |v|^2 + W(q) + g y,    W(q) = 1/2 w^2 (|q| - r0)^2,

with grad W = w^2 (1 - r0/|q|) q and Hessian w^2 [(1 - r0/|q|) I + (r0/|q|) n n^T], n = q/|q|.
In q every component carries both the fast radial vibration (frequency ~w) and the slow swing
(frequency ~sqrt(g/r0)); in (r, phi) they separate, which is what the IMEX splitting of
:mod:`petsoft.dynamics.imex` exploits.

Energy split (all measured from the hanging rest state, i.e. H_rest = H + g r0). Let
rbar(phi, p_phi) = r0 + delta be the quasi-static radius, where the spring force balances the
centrifugal force and the radial pull of gravity, w^2 delta = p_phi^2 / rbar^3 - g sin(phi)
(solved by fixed-point iteration; delta ~ g / w^2).

* fast energy   E_fast = 1/2 p_r^2 + 1/2 w^2 (r - rbar)^2: the energy of the radial vibration
  about the quasi-static stretch. It is zero when the spring merely follows the swing; an
  unresolved vibration of amplitude a has E_fast = 1/2 w^2 a^2.
* slow energy   E_slow = 1/2 rbar^-2 p_phi^2 + g (rbar sin phi + r0) + 1/2 w^2 delta^2: the
  lecture's pendulum part 1/2 r^-2 p_phi^2 + g r sin(phi) (shifted by the constant g r0, so a
  relative error refers to the swing) evaluated on the quasi-static radius instead of the actual
  one, plus the spring energy of the quasi-static stretch (~g^2 / (2 w^2), negligible).

Evaluating the pendulum part on rbar rather than r removes the first-order coupling: with
r = rbar + rho, H_rest = E_fast + E_slow + O(rho^2 p_phi^2 / r^4), whereas the plain pendulum
part flickers with the vibration by ~w^2 delta rho (1% of the swing energy for the demo's
E_fast = 1 J, w = 1000). In the exact solution both energies are then nearly conserved (the
radial action is an adiabatic invariant); a large-step method should keep E_slow and may (should,
for visual computing) drain E_fast.

:class:`StiffSpringPendulum` holds the parameters and the formulas (NumPy, vectorised over
time); :class:`PendulumSystem` wraps the Cartesian form in the interface of
:class:`~petsoft.dynamics.system.DynamicSystem` (like :class:`~petsoft.dynamics.oscillator.
OscillatorSystem`, but nonlinear) so that petsoft's own implicit integrators, generalized-alpha
and the explicit schemes run on it unchanged: it is the "fully implicit in Cartesian
coordinates" side of the comparison.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from petsc4py import PETSc

from petsoft.dynamics.interfaces import SystemDefaults


@dataclass(frozen=True)
class StiffSpringPendulum:
    """Parameters and formulas of the unit-mass stiff-spring pendulum.

    Parameters
    ----------
    omega : float
        Spring frequency w (rad/s): stiffness w^2 for the unit mass.
    r0 : float
        Rest length of the spring (m).
    g : float
        Gravitational acceleration (m/s^2), acting along -y.

    Notes
    -----
    Polar states are arrays ``(..., 4)`` ordered ``(r, phi, p_r, p_phi)``; Cartesian states are
    ``(q, v)`` with ``q, v`` arrays ``(..., 2)``.
    """

    omega: float = 1000.0
    r0: float = 1.0
    g: float = 9.81

    # -- coordinates ------------------------------------------------------------------------
    @staticmethod
    def to_polar(q, v) -> np.ndarray:
        """(r, phi, p_r, p_phi) from positions and velocities (p_r = n . v, p_phi = q x v)."""
        q, v = np.asarray(q, float), np.asarray(v, float)
        x, y, vx, vy = q[..., 0], q[..., 1], v[..., 0], v[..., 1]
        r = np.hypot(x, y)
        return np.stack([r, np.arctan2(y, x), (x * vx + y * vy) / r, x * vy - y * vx], axis=-1)

    @staticmethod
    def to_cartesian(state) -> tuple[np.ndarray, np.ndarray]:
        """(q, v) from a polar state; v = p_r n + (p_phi / r) t, t the unit tangent."""
        s = np.asarray(state, float)
        r, phi, pr, pphi = s[..., 0], s[..., 1], s[..., 2], s[..., 3]
        c, si = np.cos(phi), np.sin(phi)
        q = np.stack([r * c, r * si], axis=-1)
        vt = pphi / r
        v = np.stack([pr * c - vt * si, pr * si + vt * c], axis=-1)
        return q, v

    # -- right-hand sides -------------------------------------------------------------------
    def rhs_polar(self, state) -> np.ndarray:
        """d/dt (r, phi, p_r, p_phi): the lecture's ODE system."""
        s = np.asarray(state, float)
        r, phi, pr, pphi = s[..., 0], s[..., 1], s[..., 2], s[..., 3]
        return np.stack([pr,
                         pphi / r**2,
                         -self.omega**2 * (r - self.r0) + pphi**2 / r**3 - self.g * np.sin(phi),
                         -self.g * r * np.cos(phi)], axis=-1)

    def acceleration(self, q) -> np.ndarray:
        """q'' = -grad W(q) - g e_y."""
        a = -self.spring_gradient(q)
        a[..., 1] -= self.g
        return a

    # -- the spring (Cartesian) -------------------------------------------------------------
    def spring_energy(self, q) -> np.ndarray:
        """W(q) = 1/2 w^2 (|q| - r0)^2."""
        r = np.linalg.norm(np.asarray(q, float), axis=-1)
        return 0.5 * self.omega**2 * (r - self.r0) ** 2

    def spring_gradient(self, q) -> np.ndarray:
        """grad W = w^2 (1 - r0/|q|) q."""
        q = np.asarray(q, float)
        r = np.linalg.norm(q, axis=-1, keepdims=True)
        return self.omega**2 * (1.0 - self.r0 / r) * q

    def spring_hessian(self, q) -> np.ndarray:
        """w^2 [(1 - r0/|q|) I + (r0/|q|) n n^T]: indefinite when the spring is compressed."""
        q = np.asarray(q, float)
        r = np.linalg.norm(q, axis=-1)[..., None, None]
        n = q[..., :, None] / r
        nnT = n * np.swapaxes(n, -1, -2)
        return self.omega**2 * ((1.0 - self.r0 / r) * np.eye(2) + (self.r0 / r) * nnT)

    # -- energies (polar states) -------------------------------------------------------------
    def quasi_static_radius(self, state) -> np.ndarray:
        """rbar = r0 + delta with w^2 delta = p_phi^2 / rbar^3 - g sin(phi).

        Fixed-point iteration from r0; it contracts by ~3 p_phi^2 / (w^2 r0^4) per sweep (1e-5
        for the demo), so four sweeps reach round-off for any stiff spring.
        """
        s = np.asarray(state, float)
        phi, pphi = s[..., 1], s[..., 3]
        rbar = np.full_like(phi, self.r0)
        for _ in range(4):
            rbar = self.r0 + (pphi**2 / rbar**3 - self.g * np.sin(phi)) / self.omega**2
        return rbar

    def hamiltonian(self, state) -> np.ndarray:
        """The lecture's H (not shifted)."""
        s = np.asarray(state, float)
        r, phi, pr, pphi = s[..., 0], s[..., 1], s[..., 2], s[..., 3]
        return (0.5 * (pr**2 + pphi**2 / r**2 + self.omega**2 * (r - self.r0) ** 2)
                + self.g * r * np.sin(phi))

    def total_energy(self, state) -> np.ndarray:
        """H + g r0: the total energy measured from the hanging rest state."""
        return self.hamiltonian(state) + self.g * self.r0

    def fast_energy(self, state) -> np.ndarray:
        """1/2 p_r^2 + 1/2 w^2 (r - rbar)^2 (see the module docstring)."""
        s = np.asarray(state, float)
        rho = s[..., 0] - self.quasi_static_radius(s)
        return 0.5 * s[..., 2] ** 2 + 0.5 * self.omega**2 * rho**2

    def slow_energy(self, state) -> np.ndarray:
        """1/2 rbar^-2 p_phi^2 + g (rbar sin phi + r0) + 1/2 w^2 (rbar - r0)^2: the swing."""
        s = np.asarray(state, float)
        phi, pphi = s[..., 1], s[..., 3]
        rbar = self.quasi_static_radius(s)
        return (0.5 * pphi**2 / rbar**2 + self.g * (rbar * np.sin(phi) + self.r0)
                + 0.5 * self.omega**2 * (rbar - self.r0) ** 2)

    # -- states -----------------------------------------------------------------------------
    def initial_state(self, angle: float = np.pi / 3, fast_energy: float = 1.0,
                      angular_velocity: float = 0.0) -> np.ndarray:
        """A polar state swung ``angle`` away from hanging, with the spring vibrating.

        The radius is the quasi-static one plus a = sqrt(2 E_fast)/w, so that the fast energy is
        exactly ``fast_energy`` (p_r = 0); ``angular_velocity`` sets p_phi = r0^2 phi'.
        """
        phi = -0.5 * np.pi + angle
        pphi = angular_velocity * self.r0**2
        r = self.quasi_static_radius([self.r0, phi, 0.0, pphi])
        return np.array([r + np.sqrt(2.0 * fast_energy) / self.omega, phi, 0.0, pphi])

    def midpoint_trajectory(self, state, h: float, nsteps: int, every: int = 1) -> np.ndarray:
        """Polar states of the implicit midpoint rule on the Cartesian form (the fine reference).

        q_m = q0 + h/2 v0 + h^2/4 a(q_m) is solved by Newton (2x2, to round-off), then
        q1 = 2 q_m - q0, v1 = v0 + h a(q_m). Symplectic and second order, with no numerical
        damping: at tau*w = 0.1 it resolves the vibration (phase error ~(tau w)^2 / 24 per
        radian). Plain floats (no NumPy per step): ~15 us a step.

        Parameters
        ----------
        state : array_like (4,)
            Initial polar state.
        h : float
        nsteps : int
        every : int
            Keep every ``every``-th state.

        Returns
        -------
        ndarray (nsteps // every + 1, 4)
            Polar states at t = 0, every h, 2 every h, ...; the angle is unwrapped.
        """
        w2, r0, g = self.omega**2, self.r0, self.g
        (x, y), (vx, vy) = self.to_cartesian(state)
        x, y, vx, vy = float(x), float(y), float(vx), float(vy)
        c = 0.25 * h * h
        out = [(x, y, vx, vy)]
        for n in range(1, nsteps + 1):
            bx, by = x + 0.5 * h * vx, y + 0.5 * h * vy
            mx, my = bx, by
            for _ in range(20):
                r = math.hypot(mx, my)
                k = w2 * (1.0 - r0 / r)
                ax, ay = -k * mx, -k * my - g
                fx, fy = mx - bx - c * ax, my - by - c * ay
                # Jacobian I + c Hess W = (1 + c k) I + c w2 (r0/r) n n^T
                d, e = 1.0 + c * k, c * w2 * r0 / r**3
                j11, j12, j22 = d + e * mx * mx, e * mx * my, d + e * my * my
                det = j11 * j22 - j12 * j12
                dx, dy = (j22 * fx - j12 * fy) / det, (j11 * fy - j12 * fx) / det
                mx, my = mx - dx, my - dy
                if abs(dx) + abs(dy) <= 1e-15 * (abs(mx) + abs(my)):
                    break
            r = math.hypot(mx, my)
            k = w2 * (1.0 - r0 / r)
            vx, vy = vx - h * k * mx, vy + h * (-k * my - g)
            x, y = 2.0 * mx - x, 2.0 * my - y
            if n % every == 0:
                out.append((x, y, vx, vy))
        arr = np.array(out)
        polar = self.to_polar(arr[:, :2], arr[:, 2:])
        polar[:, 1] = np.unwrap(polar[:, 1])
        return polar

    def swing_frequency(self) -> float:
        """sqrt(g / r0), the small-amplitude angular frequency of the slow motion."""
        return float(np.sqrt(self.g / self.r0))


class PendulumSystem(SystemDefaults):
    """The Cartesian stiff-spring pendulum in petsoft's integrator interface (2 dofs, M = I).

    Both dofs live on rank 0 of ``comm`` (the other ranks own none), so every collective
    integrator runs on it on any number of ranks; with ``PETSc.COMM_SELF`` each rank has its own
    copy.

    Parameters
    ----------
    pendulum : StiffSpringPendulum
    comm : PETSc.Comm, optional
        Defaults to ``PETSc.COMM_WORLD``.
    """

    def __init__(self, pendulum: StiffSpringPendulum, comm: PETSc.Comm | None = None):
        self.pendulum = p = pendulum
        self.comm = comm if comm is not None else PETSc.COMM_WORLD
        self.nlocal = 2 if self.comm.rank == 0 else 0
        self._proto = PETSc.Vec().createMPI((self.nlocal, 2), comm=self.comm)
        self.alpha = self.beta = 0.0          # no physical damping: only numerical
        self.lumped_kinetic = False
        self.time_dependent_loads = False
        self.M = self._matrix(np.eye(2))
        self.lumped = self.create_vec()
        self.lumped.set(1.0)
        self.gravity = self.create_vec()
        self.set_values(self.gravity, [0.0, -p.g])
        # Reference stiffness (only multiplied by the Rayleigh beta, which is 0): the Hessian at
        # the unstretched hanging position.
        self._k0 = p.spring_hessian(np.array([0.0, -p.r0]))

    # -- helpers ----------------------------------------------------------------------------
    def values(self, vec: PETSc.Vec) -> np.ndarray:
        """The two entries of ``vec`` on every rank (collective)."""
        local = vec.getArray(readonly=True).copy() if self.nlocal else None
        return np.asarray(self.comm.tompi4py().bcast(local, root=0), dtype=float)

    def set_values(self, vec: PETSc.Vec, values) -> PETSc.Vec:
        """Set ``vec`` from two values given on every rank (rank 0's are used)."""
        if self.nlocal:
            vec.getArray()[:] = np.asarray(values, float)
        return vec

    def _matrix(self, dense: np.ndarray, out: PETSc.Mat | None = None) -> PETSc.Mat:
        if out is None:
            out = PETSc.Mat().createAIJ(((self.nlocal, 2), (self.nlocal, 2)), nnz=(2, 0),
                                        comm=self.comm)
            out.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
        out.zeroEntries()
        if self.nlocal:
            idx = np.arange(2, dtype=PETSc.IntType)
            out.setValues(idx, idx, np.asarray(dense, float).ravel())
        out.assemble()
        return out

    # -- the integrators' interface -----------------------------------------------------------
    def create_vec(self) -> PETSc.Vec:
        return self._proto.duplicate()

    def create_matrix(self) -> PETSc.Mat:
        return self._matrix(np.zeros((2, 2)))

    def near_nullspace(self):
        return None

    def linear_defaults(self, ksp: PETSc.KSP) -> None:
        """A 2x2, possibly indefinite Jacobian on one rank: a direct solve (LU; redundant LU
        when the communicator has other, empty ranks)."""
        ksp.setType(PETSc.KSP.Type.PREONLY)
        serial = self.comm.size == 1
        ksp.getPC().setType(PETSc.PC.Type.LU if serial else PETSc.PC.Type.REDUNDANT)

    def assemble_combination(self, q, a_mass, b_tangent, c_reference, out, eliminate=True,
                             velocity=0.0, reuse=False):
        """out = a I + b Hess W(q) + c K0 (no velocity-dependent forces: ``velocity`` unused)."""
        x = self.values(q) if b_tangent != 0.0 else None
        dense = a_mass * np.eye(2) + c_reference * self._k0
        if b_tangent != 0.0:
            dense = dense + b_tangent * self.pendulum.spring_hessian(x)
        return self._matrix(dense, out)

    def internal_gradient(self, q: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        if self.nlocal:
            out.getArray()[:] = self.pendulum.spring_gradient(q.getArray(readonly=True))
        return out

    def elastic_energy(self, q: PETSc.Vec) -> float:
        local = float(self.pendulum.spring_energy(q.getArray(readonly=True))) if self.nlocal \
            else 0.0
        return self.comm.tompi4py().allreduce(local)

    def kinetic_energy(self, v: PETSc.Vec) -> float:
        return 0.5 * v.dot(v)

    def gravitational_energy(self, q: PETSc.Vec) -> float:
        return -self.gravity.dot(q)

    def damping_apply(self, v: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        out.zeroEntries()
        return out

    def tractions(self, t: float, out: PETSc.Vec) -> PETSc.Vec:
        out.zeroEntries()
        return out

    def apply_prescribed(self, vec: PETSc.Vec, t: float) -> None:
        """No supports: the hinge is built into W."""

    def zero_prescribed(self, vec: PETSc.Vec) -> None:
        """No supports."""

    def prescribed_offsets(self, vec: PETSc.Vec) -> np.ndarray:
        return np.zeros(0, dtype=np.int64)

    # -- polar views ----------------------------------------------------------------------------
    def polar(self, q: PETSc.Vec, v: PETSc.Vec) -> np.ndarray:
        """(r, phi, p_r, p_phi) of the state (q, v), on every rank (collective)."""
        return self.pendulum.to_polar(self.values(q), self.values(v))

    def set_polar(self, state, q: PETSc.Vec, v: PETSc.Vec) -> None:
        """Set (q, v) from a polar state."""
        x, w = self.pendulum.to_cartesian(state)
        self.set_values(q, x)
        self.set_values(v, w)

    def destroy(self) -> None:
        for obj in (self._proto, self.M, self.lumped, self.gravity):
            obj.destroy()
