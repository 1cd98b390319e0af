"""Regularised dry (Coulomb) friction on nodes, per unit mass (pure numpy kernels).

``[friction] dry`` mu_g (m/s^2) and ``speed`` eps (m/s): node i of lumped mass m_i feels

    f_i = -mu_g m_i v_i / s_i,   s_i = sqrt(|v_i|^2 + eps^2),

a force of magnitude mu_g m_i against the motion when |v_i| >> eps, viscous (rate mu_g / eps)
below. It is minus the gradient of the dissipation potential psi = mu_g m_i (s_i - eps), convex,
so the velocity Jacobian is symmetric PSD. For a point mass on a stiff spring from a fixed pivot
it is a constant tangential force on the bob, i.e. a Coulomb pivot torque.

As in :mod:`petsoft.physics.drag` the kernels are per unit coefficient (mu_g = 1; the residual
is linear in it) and give the "damping" sign G = -f; ``mass`` is the per-node mass with zeros
where the friction does not act (``where``).
"""

from __future__ import annotations

import numpy as np

from petsoft.terms import term


def _speed(v: np.ndarray, eps: float) -> np.ndarray:
    return np.sqrt(np.einsum("pi,pi->p", v, v) + eps * eps)


def damping(v: np.ndarray, mass: np.ndarray, eps: float) -> np.ndarray:
    """(P, 3) G = m v / s per unit mu_g."""
    return (mass / _speed(v, eps))[:, None] * v


def damping_blocks(v: np.ndarray, mass: np.ndarray, eps: float) -> np.ndarray:
    """(P, 3, 3) dG/dv = m (I / s - v v^T / s^3) per unit mu_g (PSD)."""
    s = _speed(v, eps)
    outer = v[:, :, None] * v[:, None, :]
    return ((mass / s)[:, None, None] * np.eye(3)[None]
            - (mass / s**3)[:, None, None] * outer)


def damping_second(v: np.ndarray, w: np.ndarray, x: np.ndarray, mass: np.ndarray,
                   eps: float) -> np.ndarray:
    """(P, 3) d/dv [dG/dv x] along w per unit mu_g (symmetric in w and x):
    -m [x (v.w) + w (v.x) + v (w.x)] / s^3 + 3 m v (v.x)(v.w) / s^5."""
    s = _speed(v, eps)
    vw = np.einsum("pi,pi->p", v, w)
    vx = np.einsum("pi,pi->p", v, x)
    wx = np.einsum("pi,pi->p", w, x)
    a = (mass / s**3)[:, None]
    return (-a * (x * vw[:, None] + w * vx[:, None] + v * wx[:, None])
            + (3.0 * mass * vx * vw / s**5)[:, None] * v)


def potential(v: np.ndarray, mass: np.ndarray, eps: float) -> float:
    """sum m (s - eps) per unit mu_g: the dissipation potential whose gradient is G."""
    return float(np.sum(mass * (_speed(v, eps) - eps)))


class DryFriction:
    """``friction.dry``'s law (:mod:`petsoft.physics.velocity_law`): per unit mu_g,
    G_i = m_i v_i / s_i on the nodes of ``support.mass`` (those of ``[friction] where``),
    regularised below ``support.settings["speed"]`` (``[friction] speed``)."""

    linear = False
    on_surface = term("friction.dry").surface
    mass_proportional = True
    where = term("friction.dry").where_key
    settings = term("friction.dry").setting_keys

    def __init__(self, support):
        self.mass, self.speed = support.mass, support.settings["speed"]

    def damping(self, v: np.ndarray) -> np.ndarray:
        return damping(v, self.mass, self.speed)

    def blocks(self, v: np.ndarray) -> np.ndarray:
        return damping_blocks(v, self.mass, self.speed)

    def second(self, v: np.ndarray, w: np.ndarray, x: np.ndarray) -> np.ndarray:
        return damping_second(v, w, x, self.mass, self.speed)

    def potential(self, v: np.ndarray) -> float:
        return potential(v, self.mass, self.speed)

    def rate(self, node_mass: np.ndarray | None) -> float:
        """1 / speed (its viscous regime) where it acts anywhere on this rank."""
        return 1.0 / self.speed if np.any(self.mass > 0.0) else 0.0
