"""Velocity-dependent forces of a system: surface drag (``[drag]``), dry friction (``[friction]``).

The integrators' residuals contain the damping term as ``damping_apply(v)``; the systems add

    G(v) = c_l S v + c_q G_q(v) + mu_g G_f(v)     (G = minus the force, see physics.drag/friction)

to it, so its work dq . G is booked as dissipation like the Rayleigh damping's. Every term is
node-local (block-diagonal velocity Jacobian), so :class:`VelocityTerms` works on the rows of the
nodes a rank owns -- the entries of its part of a global vector -- with no communication.

Jacobians: ``assemble_combination(..., velocity=c)`` adds c dG/dv, with c = dv/dq1 of the scheme
(1/h for be/si/midpoint/trapezoidal, whose damping is evaluated at v1 or vm = (q1-q0)/h;
alpha_f gamma/(beta h) for generalized-alpha), at the velocity last passed to ``damping_apply``
(the current Newton iterate: lagged as the colliders' friction is) or set by
``set_velocity_state`` (the calibration's derivative steps). Tangents (forward sensitivities,
adjoints) use ``damping_tangent_apply(v_state, x)`` = D x + dG/dv(v_state) x and, for the
semi-implicit step, ``damping_second_apply(v_state, w, x)`` = d/dv[dG/dv x] along w.
"""

from __future__ import annotations

import numpy as np

from petsoft.physics import drag, friction

#: Parameter names of the velocity terms (calibratable; all >= 0).
NAMES = ("drag.linear", "drag.quadratic", "friction.dry")


class VelocityTerms:
    """Drag and dry friction on the nodes a rank owns.

    Parameters
    ----------
    nnodes : int
        Nodes this rank owns (rows of its (nnodes, 3) view of a global vector).
    pairs : (node, weight, normal)
        Surface pairs from :func:`petsoft.physics.drag.face_pairs` (owned rows); None: no surface.
    friction_mass : ndarray (nnodes,)
        Lumped mass of each owned node where friction acts, 0 elsewhere.
    linear, quadratic, dry, speed : float
        ``[drag] linear``, ``quadratic``, ``[friction] dry``, ``speed``.
    node_mass : ndarray (nnodes,), optional
        Lumped mass of every owned node (for :meth:`rate_bound`; the system keeps it current).
    """

    def __init__(self, nnodes: int, pairs, friction_mass: np.ndarray, linear: float = 0.0,
                 quadratic: float = 0.0, dry: float = 0.0, speed: float = 1e-3,
                 node_mass: np.ndarray | None = None):
        self.node_mass = node_mass
        self.nnodes = int(nnodes)
        self.has_surface = pairs is not None
        if pairs is None:
            pairs = (np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)))
        self.node, self.weight, self.normal = pairs
        self.S = drag.linear_blocks(self.node, self.weight, self.normal, self.nnodes)
        self.friction_mass = np.asarray(friction_mass, dtype=float)
        self.speed = float(speed)
        self.coef = {"drag.linear": float(linear), "drag.quadratic": float(quadratic),
                     "friction.dry": float(dry)}

    @property
    def active(self) -> bool:
        """Whether any term has a non-zero coefficient (same on every rank)."""
        return any(c != 0.0 for c in self.coef.values())

    @property
    def nonlinear(self) -> bool:
        return self.coef["drag.quadratic"] != 0.0 or self.coef["friction.dry"] != 0.0

    # -- unit terms (coefficient 1): the parameter derivatives ------------------------------------
    def unit_damping(self, name: str, v: np.ndarray) -> np.ndarray:
        """(nnodes, 3) G of term ``name`` per unit coefficient at velocity v."""
        if name == "drag.linear":
            return np.einsum("pij,pj->pi", self.S, v)
        if name == "drag.quadratic":
            return drag.quadratic_damping(v, self.node, self.weight, self.normal)
        return friction.damping(v, self.friction_mass, self.speed)

    def unit_blocks(self, name: str, v: np.ndarray) -> np.ndarray:
        """(nnodes, 3, 3) dG/dv of term ``name`` per unit coefficient."""
        if name == "drag.linear":
            return self.S
        if name == "drag.quadratic":
            return drag.quadratic_damping_blocks(v, self.node, self.weight, self.normal)
        return friction.damping_blocks(v, self.friction_mass, self.speed)

    def unit_linearised(self, name: str, v: np.ndarray, v_lin: np.ndarray | None) -> np.ndarray:
        """G(v_lin) + dG/dv(v_lin) (v - v_lin) per unit coefficient (v_lin None: G(v)): the
        parameter derivative of a step whose damping term is linearised at v_lin (SI)."""
        if v_lin is None:
            return self.unit_damping(name, v)
        return (self.unit_damping(name, v_lin)
                + np.einsum("pij,pj->pi", self.unit_blocks(name, v_lin), v - v_lin))

    # -- the total term ------------------------------------------------------------------------
    def damping(self, v: np.ndarray) -> np.ndarray:
        """(nnodes, 3) G(v) = minus the velocity forces."""
        out = np.zeros((self.nnodes, 3))
        for name, c in self.coef.items():
            if c != 0.0:
                out += c * self.unit_damping(name, v)
        return out

    def blocks(self, v: np.ndarray) -> np.ndarray:
        """(nnodes, 3, 3) dG/dv (symmetric PSD)."""
        out = np.zeros((self.nnodes, 3, 3))
        for name, c in self.coef.items():
            if c != 0.0:
                out += c * self.unit_blocks(name, v)
        return out

    def tangent(self, v: np.ndarray, x: np.ndarray) -> np.ndarray:
        """(nnodes, 3) dG/dv(v) x."""
        return np.einsum("pij,pj->pi", self.blocks(v), x)

    def second(self, v: np.ndarray, w: np.ndarray, x: np.ndarray) -> np.ndarray:
        """(nnodes, 3) d/dv [dG/dv x] along w (linear drag: zero)."""
        out = np.zeros((self.nnodes, 3))
        cq, cf = self.coef["drag.quadratic"], self.coef["friction.dry"]
        if cq != 0.0:
            out += cq * drag.quadratic_damping_second(v, w, x, self.node, self.weight,
                                                      self.normal)
        if cf != 0.0:
            out += cf * friction.damping_second(v, w, x, self.friction_mass, self.speed)
        return out

    def potential(self, v: np.ndarray) -> float:
        """Local part of the dissipation potential psi(v) with grad psi = G."""
        out = 0.5 * self.coef["drag.linear"] * float(np.einsum("pi,pij,pj->", v, self.S, v))
        if self.coef["drag.quadratic"] != 0.0:
            out += self.coef["drag.quadratic"] * drag.quadratic_potential(
                v, self.node, self.weight, self.normal)
        if self.coef["friction.dry"] != 0.0:
            out += self.coef["friction.dry"] * friction.potential(v, self.friction_mass,
                                                                  self.speed)
        return out

    def rate_bound(self) -> float:
        """An upper bound (this rank's nodes) of the largest eigenvalue of M^-1 dG/dv of the
        linear drag (c_l trace S_i / m_i, the lumped area over the mass) and the friction
        (dry / speed, its viscous regime): the explicit schemes' damping rate. The quadratic
        drag's rate 2 c_q (A_i/m_i) |v.n| grows with the speed and is not bounded here."""
        rate = 0.0
        if self.coef["friction.dry"] != 0.0 and np.any(self.friction_mass > 0.0):
            rate = self.coef["friction.dry"] / self.speed
        m = self.node_mass
        if self.coef["drag.linear"] != 0.0 and m is not None and len(m):
            trace = np.einsum("pii->p", self.S)
            free = m > 0.0
            if np.any(free):
                rate = max(rate, self.coef["drag.linear"] * float(np.max(trace[free] / m[free])))
        return rate


class VelocityDamping:
    """The damping interface of a system with velocity terms, shared by the FEM and the
    mass-spring systems: the tangent, second derivative and potential of D v + G(v).

    The system provides ``velocity_terms`` (:class:`VelocityTerms`), ``dmesh`` (its
    ``allreduce_sum``), a work vector ``_work`` and ``_linear_damping_apply(x, out)``: out = D x,
    its velocity-linear damping (Rayleigh; plus the springs' dashpots).
    """

    def damping_tangent_apply(self, v_state, x, out):
        """out = D x + dG/dv(v_state) x: the damping term linearised at v_state, applied to a
        tangent or adjoint vector x (a mass-spring system's colliders' lagged friction is not
        differentiated)."""
        self._linear_damping_apply(x, out)
        vt = self.velocity_terms
        if vt.active:
            out.getArray().reshape(-1, 3)[:] += vt.tangent(
                v_state.getArray(readonly=True).reshape(-1, 3),
                x.getArray(readonly=True).reshape(-1, 3))
        return out

    def damping_second_apply(self, v_state, w, x, out):
        """out = d/dv [dG/dv x] along w at v_state (zero without nonlinear velocity terms)."""
        out.zeroEntries()
        vt = self.velocity_terms
        if vt.nonlinear:
            arr = [y.getArray(readonly=True).reshape(-1, 3) for y in (v_state, w, x)]
            out.getArray().reshape(-1, 3)[:] = vt.second(*arr)
        return out

    def dissipation_potential(self, v) -> float:
        """psi(v) = v^T D v / 2 + the velocity terms' potential: grad psi = D v + G(v)
        (collective; a mass-spring system's colliders' friction is not a potential: refused by
        the caller)."""
        self._linear_damping_apply(v, self._work)
        local = self.velocity_terms.potential(v.getArray(readonly=True).reshape(-1, 3))
        return 0.5 * v.dot(self._work) + self.dmesh.allreduce_sum(local)
