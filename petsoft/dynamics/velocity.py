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

from petsoft.physics.velocity_law import VelocitySupport
from petsoft.terms import builders, coefficients, value_of

#: The velocity terms' laws, from their declarations (petsoft.terms, contributes "velocity"):
#: name -> law class (petsoft.physics.velocity_law), in the registry's order.
LAWS = {t.name: law for t, law in builders("velocity")}
#: Parameter names of the velocity terms (calibratable; all >= 0).
NAMES = tuple(LAWS)


def coefficients_of(experiment) -> dict[str, float]:
    """name -> the experiment's coefficient of each velocity term: the value of its first key
    (``[drag] linear``, ``[drag] quadratic``, ``[friction] dry``)."""
    return coefficients(experiment, NAMES)


def settings_of(experiment) -> dict[str, dict[str, float]]:
    """name -> the experiment's values of each law's declared ``settings`` (``friction.dry``:
    ``{"speed": [friction] speed}``)."""
    return {name: {setting: float(value_of(experiment, key)) for setting, key in law.settings}
            for name, law in LAWS.items()}


def where_of(experiment, resolver) -> dict[str, np.ndarray]:
    """name -> (N,) bool over the mesh's nodes: where each law whose ``where`` key the
    experiment sets acts (``resolver``: the model's
    :class:`~petsoft.fem.regions.RegionResolver`); the laws not named act on every node."""
    out = {}
    for name, law in LAWS.items():
        where = value_of(experiment, law.where) if law.where else None
        if where is not None:
            out[name] = resolver.vertex_mask(where, law.where)
    return out


def _linearised(law, v: np.ndarray, v_lin: np.ndarray | None) -> np.ndarray:
    """G(v_lin) + dG/dv(v_lin) (v - v_lin) of one ``law`` (v_lin None: G(v))."""
    if v_lin is None:
        return law.damping(v)
    return law.damping(v_lin) + np.einsum("pij,pj->pi", law.blocks(v_lin), v - v_lin)


class VelocityTerms:
    """The velocity laws (drag, dry friction) on the nodes a rank owns, each times its
    coefficient, each on the nodes its ``where`` selects.

    Parameters
    ----------
    nnodes : int
        Nodes this rank owns (rows of its (nnodes, 3) view of a global vector).
    pairs : (node, weight, normal)
        Surface pairs from :func:`petsoft.physics.drag.face_pairs` (owned rows); None: no surface.
    node_mass : ndarray (nnodes,)
        Lumped mass of every owned node (the mass-proportional laws' masses, :meth:`rate_bound`;
        the system sets it again when the masses change).
    coefficients : mapping, optional
        name (:data:`NAMES`) -> coefficient (``[drag] linear``, ...; :func:`coefficients_of`);
        the terms not named are 0.
    where : mapping, optional
        name -> (nnodes,) bool: the owned nodes a law acts on (:func:`where_of`'s rows); the
        laws not named act on every node.
    settings : mapping, optional
        name -> the law's settings (:func:`settings_of`).
    """

    def __init__(self, nnodes: int, pairs, node_mass: np.ndarray,
                 coefficients: dict[str, float] | None = None,
                 where: dict[str, np.ndarray] | None = None,
                 settings: dict[str, dict[str, float]] | None = None):
        coefficients = dict(coefficients or {})
        unknown = sorted((set(coefficients) | set(where or {}) | set(settings or {}))
                         - set(NAMES))
        if unknown:
            raise ValueError(f"no velocity term {unknown} (known: {', '.join(NAMES)})")
        self.nnodes = int(nnodes)
        self.has_surface = pairs is not None
        self._pairs = pairs
        self.where = dict(where or {})
        self.settings = {name: dict((settings or {}).get(name, {})) for name in NAMES}
        self.coef = {name: float(coefficients.get(name, 0.0)) for name in NAMES}
        self.node_mass = node_mass

    @property
    def node_mass(self) -> np.ndarray:
        """(nnodes,) the lumped mass of the owned nodes; set when the masses change (the
        density calibrated), which rebuilds the laws on their supports."""
        return self._node_mass

    @node_mass.setter
    def node_mass(self, value: np.ndarray) -> None:
        self._node_mass = value
        self.laws = {name: law(self._support(name, value)) for name, law in LAWS.items()}

    def _support(self, name: str, node_mass: np.ndarray) -> VelocitySupport:
        """Law ``name``'s support: the masses and the surface pairs of its nodes."""
        acts, pairs = self.where.get(name), self._pairs
        mass = np.asarray(node_mass, dtype=float)
        if acts is not None:
            mass = np.where(acts, mass, 0.0)
            if pairs is not None:
                keep = acts[pairs[0]]
                pairs = tuple(x[keep] for x in pairs)
        return VelocitySupport.of(self.nnodes, pairs, mass, self.settings[name])

    def _acting(self):
        return [(c, self.laws[name]) for name, c in self.coef.items() if c != 0.0]

    @property
    def active(self) -> bool:
        """Whether any term has a non-zero coefficient (same on every rank)."""
        return any(c != 0.0 for c in self.coef.values())

    @property
    def nonlinear(self) -> bool:
        return any(not law.linear for _, law in self._acting())

    @property
    def parameter_names(self) -> list[str]:
        """The velocity terms this body can carry, in the registry's order: every law, but
        those that act on the surface only where there is one (``on_surface``)."""
        return [name for name, law in LAWS.items() if self.has_surface or not law.on_surface]

    # -- unit terms (coefficient 1): the parameter derivatives ------------------------------------
    def unit_damping(self, name: str, v: np.ndarray) -> np.ndarray:
        """(nnodes, 3) G of term ``name`` per unit coefficient at velocity v."""
        return self.laws[name].damping(v)

    def unit_blocks(self, name: str, v: np.ndarray) -> np.ndarray:
        """(nnodes, 3, 3) dG/dv of term ``name`` per unit coefficient."""
        return self.laws[name].blocks(v)

    def unit_linearised(self, name: str, v: np.ndarray, v_lin: np.ndarray | None) -> np.ndarray:
        """G(v_lin) + dG/dv(v_lin) (v - v_lin) per unit coefficient (v_lin None: G(v)): the
        parameter derivative of a step whose damping term is linearised at v_lin (SI)."""
        return _linearised(self.laws[name], v, v_lin)

    def mass_linearised(self, v: np.ndarray, v_lin: np.ndarray | None,
                        where: dict[str, np.ndarray] | None = None) -> np.ndarray | None:
        """(n, 3) the acting mass-proportional laws' G (``mass_proportional``), each times its
        coefficient, per unit node mass on the n nodes of v where each acts, linearised at
        v_lin as :meth:`unit_linearised`; None when none acts. ``where``: name -> (n,) bool,
        as :func:`where_of` (None: this object's own, the owned nodes).

        A law proportional to the node masses adds this to a derivative with respect to the
        density or the node mass (the nodes need not be this object's: a FEM system passes its
        local vertices, whose share is integrated per cell)."""
        where = self.where if where is None else where
        out = None
        for name, c in self.coef.items():
            if c == 0.0 or not LAWS[name].mass_proportional:
                continue
            acts = where.get(name)
            unit = np.ones(len(v)) if acts is None else acts.astype(float)
            law = LAWS[name](VelocitySupport.of(len(v), None, unit, self.settings[name]))
            y = c * _linearised(law, v, v_lin)
            out = y if out is None else out + y
        return out

    # -- the total term ------------------------------------------------------------------------
    def damping(self, v: np.ndarray) -> np.ndarray:
        """(nnodes, 3) G(v) = minus the velocity forces."""
        out = np.zeros((self.nnodes, 3))
        for c, law in self._acting():
            out += c * law.damping(v)
        return out

    def blocks(self, v: np.ndarray) -> np.ndarray:
        """(nnodes, 3, 3) dG/dv (symmetric PSD)."""
        out = np.zeros((self.nnodes, 3, 3))
        for c, law in self._acting():
            out += c * law.blocks(v)
        return out

    def tangent(self, v: np.ndarray, x: np.ndarray) -> np.ndarray:
        """(nnodes, 3) dG/dv(v) x."""
        return np.einsum("pij,pj->pi", self.blocks(v), x)

    def second(self, v: np.ndarray, w: np.ndarray, x: np.ndarray) -> np.ndarray:
        """(nnodes, 3) d/dv [dG/dv x] along w (the linear laws: zero)."""
        out = np.zeros((self.nnodes, 3))
        for c, law in self._acting():
            if not law.linear:
                out += c * law.second(v, w, x)
        return out

    def potential(self, v: np.ndarray) -> float:
        """Local part of the dissipation potential psi(v) with grad psi = G."""
        return float(sum(c * law.potential(v) for c, law in self._acting()))

    def rate_bound(self) -> float:
        """An upper bound (this rank's nodes) of the largest eigenvalue of M^-1 dG/dv: each
        acting law's ``rate`` times its coefficient (the linear drag: c_l trace S_i / m_i, the
        lumped area over the mass; the friction: dry / speed, its viscous regime): the explicit
        schemes' damping rate. The quadratic drag's rate 2 c_q (A_i/m_i) |v.n| grows with the
        speed and is not bounded here."""
        return max([c * law.rate(self.node_mass) for c, law in self._acting()], default=0.0)


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
