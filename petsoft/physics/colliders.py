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

Default stiffness: when ``[[collider]] stiffness`` is not given, ``DEFAULT_STIFFNESS_FACTOR`` (1000)
times the ``[springs] stiffness`` (N/m per node): a node hanging from one spring then penetrates
1/1000 of the spring's stretch under the same load.

Friction (``friction`` = mu > 0)
-------------------------------
Coulomb friction -mu |f_n| v_t / |v_t|, smoothed as -mu |f_n| v_t / sqrt(|v_t|^2 + eps_v^2)
(eps_v = :data:`FRICTION_VELOCITY`), *lagged*: the normal force magnitude |f_n| = k p and the
normal n are those of the last configuration the contact forces were evaluated at (the current
Newton iterate), and the force enters as a velocity-dependent damping force, so its work is
booked as dissipation (it is never negative: f . v_t <= 0). Its derivative with respect to the
velocity is not in the Jacobian (the lag makes it a fixed-point term; Newton converges linearly
while sliding).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEFAULT_STIFFNESS_FACTOR = 1000.0
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

    @classmethod
    def from_spec(cls, spec, default_stiffness: float) -> Collider:
        k = spec.stiffness if spec.stiffness is not None else default_stiffness
        if spec.kind == "sphere":
            return cls("sphere", float(k), spec.friction, np.asarray(spec.center, float),
                       float(spec.radius))
        n = np.asarray(spec.normal, float)
        return cls("plane", float(k), spec.friction, point=np.asarray(spec.point, float),
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

    # -- penalty terms -------------------------------------------------------------------------
    def energy(self, x: np.ndarray) -> np.ndarray:
        """(P,) penalty energies."""
        phi, _, _ = self.distance(x)
        p = np.maximum(-phi, 0.0)
        return 0.5 * self.stiffness * p * p

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """(P, 3) gradients of the penalty energy (minus the contact forces)."""
        phi, n, _ = self.distance(x)
        p = np.maximum(-phi, 0.0)
        return -(self.stiffness * p)[:, None] * n

    def hessian(self, x: np.ndarray, clamp: bool = False) -> np.ndarray:
        """(P, 3, 3) Hessians of the penalty energy (zero out of contact)."""
        phi, n, rho = self.distance(x)
        p = np.maximum(-phi, 0.0)
        active = (p > 0.0)[:, None, None]
        nn = n[:, :, None] * n[:, None, :]
        H = self.stiffness * nn
        if self.kind == "sphere" and not clamp:
            H = H - (self.stiffness * p / rho)[:, None, None] * (np.eye(3)[None] - nn)
        return np.where(active, H, 0.0)

    def friction_force(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(P, 3) smoothed Coulomb friction forces at positions x (lagged normal) and velocity v."""
        if self.friction <= 0.0:
            return np.zeros_like(v)
        phi, n, _ = self.distance(x)
        fn = self.stiffness * np.maximum(-phi, 0.0)
        vt = v - np.einsum("pi,pi->p", v, n)[:, None] * n
        speed = np.sqrt(np.einsum("pi,pi->p", vt, vt) + FRICTION_VELOCITY ** 2)
        return -(self.friction * fn / speed)[:, None] * vt
