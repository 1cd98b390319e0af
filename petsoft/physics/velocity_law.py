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
                     (``VelocitySupport.mass``): then a derivative with respect to the
                     density or the node mass has the law's share, its G per unit mass
``where``            the dotted experiment key (of its term) that selects the nodes it acts on
                     (``"friction.where"``), ``""`` when it acts on every node (or its whole
                     surface); the key's value None: every node. Its support holds the masses
                     and the surface pairs of those nodes only. A built-in law's is its term's
                     ``where_key``: its term's key of type ``"where"``
``settings``         ``((name, dotted key), ...)``: the experiment's numbers it is built with
                     besides its coefficient (``(("speed", "friction.speed"),)``), handed to it
                     as ``support.settings[name]``. A built-in law's are its term's
                     ``setting_keys``: its term's number keys after the first

A law's keys live in its term's declaration (:mod:`petsoft.terms`): the experiment reader, the
spec and its dict form read them there, and the law's ``where`` and ``settings`` name them.

:class:`petsoft.dynamics.velocity.VelocityTerms` sums the laws the registry declares, each
times its coefficient, each on its own support: the systems read ``where`` and ``settings``
(:func:`petsoft.dynamics.velocity.where_of`, :func:`~petsoft.dynamics.velocity.settings_of`), so
adding a velocity law is its term module and its class.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class VelocitySupport:
    """Where the velocity laws act on the nodes a rank owns.

    Attributes
    ----------
    nnodes : int
        The nodes this rank owns (rows of its (nnodes, 3) view of a global vector).
    node, weight, normal : ndarray (P,), (P,), (P, 3)
        Surface pairs (:func:`petsoft.physics.drag.face_pairs`) of the nodes the law acts on
        (empty: no surface).
    mass : ndarray (nnodes,)
        Lumped mass of each owned node the law acts on (its ``where``), 0 elsewhere.
    settings : mapping
        The law's ``settings`` by name (``{"speed": 1e-3}``: ``[friction] speed``, m/s).
    """

    nnodes: int
    node: np.ndarray
    weight: np.ndarray
    normal: np.ndarray
    mass: np.ndarray
    settings: Mapping[str, float] = field(default_factory=dict)

    @classmethod
    def of(cls, nnodes: int, pairs, mass, settings: Mapping[str, float] | None = None
           ) -> VelocitySupport:
        """From surface ``pairs`` (node, weight, normal) or None (no surface)."""
        if pairs is None:
            pairs = (np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)))
        node, weight, normal = pairs
        return cls(int(nnodes), node, weight, normal, np.asarray(mass, dtype=float),
                   dict(settings or {}))
