"""Rigid colliders (sphere, plane) acting on nodes: a smooth penalty contact and lagged friction.

Contact model
-------------
With phi(x) the signed distance to the collider's surface (positive on the allowed side) and
p = max(0, -phi) the penetration, each node carries the penalty energy

    E(x) = k/2 p^2,   grad E = -k p grad phi,   Hess E = k (grad phi grad phi^T - p Hess phi)

(exactly consistent: E is C1 with a piecewise-smooth gradient, so the Hessian jumps by k n n^T
where contact begins -- Newton handles that like any active-set switch). For a plane
Hess phi = 0; for a sphere Hess phi = (I - n n^T) / |x - c|, whose contribution -k p (I - n n^T)/r
is negative (tangential sliding over a convex obstacle lowers the penetration): ``clamp`` drops
it so that the contact Hessian stays PSD, as the clamped spring Hessian does.

The C2-smooth variant (``margin`` delta > 0, set programmatically) starts the contact delta before
the surface: E = k/(6 delta) (delta - phi)^3 for 0 <= phi < delta, continued inside by the
quadratic k/2 p^2 + k delta/2 p + k delta^2/6 with the same value, slope and curvature k at phi = 0,
so the Hessian is continuous too.

Default stiffness (:func:`default_stiffness`), when ``[[collider]] stiffness`` is not given:
k = 4 m_max / h^2 with m_max the largest node mass and h the ``[time] step``. The contact's own
frequency sqrt(k/m) <= 2/h is then resolved by one step, which keeps the single Newton step of the
semi-implicit method from overshooting into an energy gain (stiffer penalties do gain energy with
``si``: measured in tests/test_mass_spring.py), and a node hitting the collider at speed v
penetrates at most v sqrt(m/k) >= v h / 2 (its kinetic energy turned into penalty energy);
under its own weight a node sinks g h^2 / 4. Without ``[time]``: 1000 x ``[springs] stiffness``.

Friction (``friction`` = mu > 0)
-------------------------------
Coulomb friction -mu |f_n| v_t / |v_t|, smoothed as -mu |f_n| v_t / sqrt(|v_t|^2 + eps_v^2)
(eps_v = :data:`FRICTION_VELOCITY`), *lagged*: the normal force magnitude |f_n| = k p and the
normal n are those of the last configuration the contact forces were evaluated at (the current
Newton iterate), and the force enters as a velocity-dependent damping force, so its work is
booked as dissipation (it is never negative: f . v_t <= 0). Its velocity derivative at the latest
velocity, -df/dv (:meth:`Collider.friction_damping`, PSD), joins the Jacobians' damping term, so
Newton also converges when a sliding node comes to rest (the viscous regime is stiff: mu |f_n| /
eps_v); the normal force's dependence on the position is the lagged part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEFAULT_STIFFNESS_FACTOR = 1000.0   # x [springs] stiffness, without a time step
DEFAULT_STEP_FACTOR = 4.0           # x m_max / h^2 with a time step


def default_stiffness(masses: np.ndarray, step: float | None, spring_stiffness: float) -> float:
    """The penalty stiffness of a collider without ``stiffness`` (see the module docstring)."""
    m = float(np.max(masses)) if len(masses) else 0.0
    if step is not None and m > 0.0:
        return DEFAULT_STEP_FACTOR * m / step ** 2
    return DEFAULT_STIFFNESS_FACTOR * spring_stiffness
FRICTION_VELOCITY = 1.0e-3  # m/s: below this tangential speed friction is viscous


@dataclass
class Collider:
    """A rigid sphere (center, radius) or plane (point, unit normal to the allowed side)."""

    kind: str
    stiffness: float
    friction: float = 0.0
    center: np.ndarray | None = None
    radius: float | None = None
    point: np.ndarray | None = None
    normal: np.ndarray | None = None
    margin: float = 0.0

    @classmethod
    def from_spec(cls, spec, default_stiffness: float) -> Collider:
        """The collider of a ``[[collider]]`` table (:class:`petsoft.experiment.ColliderSpec`)."""
        k = spec.stiffness if spec.stiffness is not None else default_stiffness
        if spec.kind == "sphere":
            return cls.sphere(spec.center, spec.radius, k, spec.friction)
        plane = cls.plane(spec.point, spec.normal, k, spec.friction)
        # the plane moved by its offset along the normal
        plane.point = plane.point + float(spec.offset) * plane.normal
        return plane

    @classmethod
    def sphere(cls, center, radius: float, stiffness: float, friction: float = 0.0) -> Collider:
        """A solid sphere pushing nodes out by the penalty k/2 max(0, radius - |x - c|)^2."""
        return cls("sphere", float(stiffness), friction, np.asarray(center, float), float(radius))

    @classmethod
    def plane(cls, point, normal, stiffness: float, friction: float = 0.0) -> Collider:
        """The half-space below a plane: penalty k/2 max(0, -(x - point) . n)^2."""
        n = np.asarray(normal, float)
        return cls("plane", float(stiffness), friction, point=np.asarray(point, float),
                   normal=n / np.linalg.norm(n))

    def describe(self) -> str:
        if self.kind == "sphere":
            return f"sphere (center {self.center.tolist()}, radius {self.radius:g})"
        return f"plane (point {self.point.tolist()}, normal {self.normal.tolist()})"

    # -- geometry ------------------------------------------------------------------------------
    def distance(self, x: np.ndarray):
        """phi (P,), unit grad phi (P, 3) and |x - c| (P,) (None for a plane) at points x."""
        if self.kind == "plane":
            phi = (x - self.point) @ self.normal
            return phi, np.broadcast_to(self.normal, x.shape), None
        r = x - self.center
        rho = np.sqrt(np.einsum("pi,pi->p", r, r))
        safe = np.where(rho > 0.0, rho, 1.0)
        n = r / safe[:, None]
        n[rho == 0.0] = (0.0, 0.0, 1.0)   # the center itself: any direction pushes out
        return rho - self.radius, n, safe

    # -- projection (the local step of the local/global solver) ---------------------------------
    def project(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(active, p): which points of ``x`` (n, 3) penetrate, and their closest surface points
        (the minimisers of the quadratic penalty's local step)."""
        if self.kind == "plane":
            phi = (x - self.point) @ self.normal
            active = phi < 0.0
            return active, np.where(active[:, None], x - phi[:, None] * self.normal, x)
        r = x - self.center
        dist = np.linalg.norm(r, axis=1)
        active = dist < self.radius
        # a node exactly at the centre has no closest point; any surface point is a minimiser
        safe = np.where(dist > 0.0, dist, 1.0)
        direction = np.where((dist > 0.0)[:, None], r / safe[:, None], np.array([0.0, 0.0, 1.0]))
        return active, np.where(active[:, None], self.center + self.radius * direction, x)

    def penetration(self, x: np.ndarray) -> np.ndarray:
        """Depth of each point inside the collider (0 outside)."""
        if self.kind == "plane":
            return np.maximum(0.0, -(x - self.point) @ self.normal)
        return np.maximum(0.0, self.radius - np.linalg.norm(x - self.center, axis=1))

    # -- penalty terms -------------------------------------------------------------------------
    def _profile(self, phi: np.ndarray):
        """e(phi), e'(phi), e''(phi) of the penalty as a function of the signed distance."""
        k, delta = self.stiffness, self.margin
        if delta <= 0.0:
            p = np.maximum(-phi, 0.0)
            return 0.5 * k * p * p, -k * p, np.where(phi < 0.0, k, 0.0)
        # C2 with a margin delta: cubic k/(6 delta) (delta - phi)^3 on [0, delta), continued by the
        # quadratic with the same value, slope and curvature k at phi = 0 inside
        s = np.clip(delta - phi, 0.0, delta)                    # depth into the margin
        p = np.maximum(-phi, 0.0)                               # penetration
        e = k / (6 * delta) * s ** 3 + 0.5 * k * p * p + 0.5 * k * delta * p
        inside = phi < 0.0
        de = np.where(inside, -k * p - 0.5 * k * delta, -k / (2 * delta) * s ** 2)
        dde = np.where(inside, k, k / delta * s)
        return e, de, dde

    def energy(self, x: np.ndarray) -> np.ndarray:
        """(P,) penalty energies."""
        return self._profile(self.distance(x)[0])[0]

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """(P, 3) gradients of the penalty energy (minus the contact forces)."""
        phi, n, _ = self.distance(x)
        return self._profile(phi)[1][:, None] * n

    def hessian(self, x: np.ndarray, clamp: bool = False) -> np.ndarray:
        """(P, 3, 3) Hessians of the penalty energy (zero out of contact)."""
        phi, n, rho = self.distance(x)
        _, de, dde = self._profile(phi)
        nn = n[:, :, None] * n[:, None, :]
        H = dde[:, None, None] * nn
        if self.kind == "sphere" and not clamp:
            H = H + (de / rho)[:, None, None] * (np.eye(3)[None] - nn)
        return H

    def friction_force(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(P, 3) smoothed Coulomb friction forces at positions x (lagged normal) and velocity v."""
        if self.friction <= 0.0:
            return np.zeros_like(v)
        phi, n, _ = self.distance(x)
        fn = -self._profile(phi)[1]
        vt = v - np.einsum("pi,pi->p", v, n)[:, None] * n
        speed = np.sqrt(np.einsum("pi,pi->p", vt, vt) + FRICTION_VELOCITY ** 2)
        return -(self.friction * fn / speed)[:, None] * vt

    def friction_damping(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(P, 3, 3) -d(friction force)/dv at (x, v), normal force held (lagged): PSD,
        mu |f_n| (P / s - v_t v_t^T / s^3) with P = I - n n^T, s = sqrt(|v_t|^2 + eps_v^2)."""
        phi, n, _ = self.distance(x)
        fn = -self._profile(phi)[1]
        vt = v - np.einsum("pi,pi->p", v, n)[:, None] * n
        s = np.sqrt(np.einsum("pi,pi->p", vt, vt) + FRICTION_VELOCITY ** 2)
        P = np.eye(3)[None] - n[:, :, None] * n[:, None, :]
        outer = vt[:, :, None] * vt[:, None, :]
        c = self.friction * fn
        return (c / s)[:, None, None] * P - (c / s ** 3)[:, None, None] * outer
