"""What a velocity-dependent force law is given, and what it answers (issue 38, item 1).

A term whose force depends on the velocity (``drag.linear``, ``drag.quadratic``,
``friction.dry``) declares its law in its term module (``Term.builds``, contributes
``"velocity"``): a class built from a :class:`VelocitySupport`, with, per unit coefficient
(the residual is linear in each term's coefficient) and in the "damping" sign G = -f,

``damping(v)``       (nnodes, 3) G(v)
``blocks(v)``        (nnodes, 3, 3) dG/dv (symmetric positive semi-definite)
``second(v, w, x)``  (nnodes, 3) d/dv [dG/dv x] along w
``potential(v)``     the dissipation potential psi, grad psi = G (this rank's nodes)
``rate(node_mass)``  a bound of the largest eigenvalue of M^-1 dG/dv (the explicit schemes'
                     damping rate; 0 where the law has none independent of the speed)
``linear``           whether G is linear in v (then ``second`` is zero)
``on_surface``       whether it acts through the body's surface pairs only (a body without
                     surface triangles, a mass-spring model of edges, cannot carry it)
``mass_proportional`` whether G is proportional to the support's node masses
                     (``VelocitySupport.friction_mass``): then a derivative with respect to the
                     density or the node mass has the law's share, its G per unit mass

:class:`petsoft.dynamics.velocity.VelocityTerms` sums the laws the registry declares, each
times its coefficient; adding a velocity law is its term module and its class.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class VelocitySupport:
    """Where the velocity laws act on the nodes a rank owns.

    Attributes
    ----------
    nnodes : int
        The nodes this rank owns (rows of its (nnodes, 3) view of a global vector).
    node, weight, normal : ndarray (P,), (P,), (P, 3)
        Surface pairs (:func:`petsoft.physics.drag.face_pairs`; empty: no surface).
    friction_mass : ndarray (nnodes,)
        Lumped mass of each owned node where friction acts, 0 elsewhere.
    speed : float
        The friction's regularisation speed (``[friction] speed``, m/s).
    """

    nnodes: int
    node: np.ndarray
    weight: np.ndarray
    normal: np.ndarray
    friction_mass: np.ndarray
    speed: float

    @classmethod
    def of(cls, nnodes: int, pairs, friction_mass, speed: float) -> VelocitySupport:
        """From surface ``pairs`` (node, weight, normal) or None (no surface)."""
        if pairs is None:
            pairs = (np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)))
        node, weight, normal = pairs
        return cls(int(nnodes), node, weight, normal,
                   np.asarray(friction_mass, dtype=float), float(speed))
