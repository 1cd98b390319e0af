"""The potential energy terms of a continuum model: elasticity plus nodal terms.

:class:`ModelPotential` is what ``Model.elastic`` holds: the :class:`ElasticTerm` plus the nodal
(one-vertex) potentials -- elastic supports (:mod:`petsoft.physics.support`) and collider contact
(:mod:`petsoft.physics.contact`), each a :class:`~petsoft.physics.term.NodalTerm`. It is a
:class:`~petsoft.physics.term.Term` itself, so the static solver, the dynamic system and the
modes see every potential term without knowing them.
The nodal Hessian blocks go into the shared matrix pattern through a one-vertex element set
``"nodal"`` (the diagonal blocks exist already: the pattern does not change).

:meth:`ModelPotential.add_reference_hessian` is the reference stiffness K0: elasticity at u = 0
plus the supports (constant), without contact (a state-dependent constraint, not a property of
the undeformed body).
"""

from __future__ import annotations

import numpy as np

from petsoft.physics.elastic import ElasticTerm
from petsoft.physics.term import ParametricTerm


class ModelPotential:
    """The model's potential: an element :class:`~petsoft.physics.term.Term` plus a list of
    :class:`~petsoft.physics.term.NodalTerm` (elastic supports, contact; possibly none).

    Itself a :class:`~petsoft.physics.term.Term`.

    Parameters
    ----------
    elastic : ElasticTerm
    nodal_terms : list of NodalTerm
    """

    name = "potential"

    def __init__(self, elastic: ElasticTerm, nodal_terms=()):
        self.term = elastic
        self.nodal_terms = list(nodal_terms)
        parts = [t.nodes for t in self.nodal_terms]
        self.nodes = np.unique(np.concatenate(parts)) if parts else np.zeros(0, np.int64)
        # where each term's nodes sit among self.nodes
        self._at = [np.searchsorted(self.nodes, t.nodes) for t in self.nodal_terms]

    # -- what the rest of petsoft reads of the elastic law ----------------------------------------
    @property
    def dmesh(self):
        return self.term.dmesh

    @property
    def groups(self) -> list:
        """The elastic term's element groups (one per material law)."""
        return self.term.groups

    def lame_derivatives(self, *args, **kwargs):
        """The elastic term's derivatives in the Lame parameters (see ElasticTerm)."""
        return self.term.lame_derivatives(*args, **kwargs)

    def nodal(self, kind: str):
        """The nodal term of ``kind`` ("support", "contact"), or None."""
        return next((t for t in self.nodal_terms if t.kind == kind), None)

    @property
    def support(self):
        """The elastic supports (:class:`~petsoft.physics.support.ElasticSupport`) or None."""
        return self.nodal("support")

    @property
    def contact(self):
        """The collider contact (:class:`~petsoft.physics.contact.SurfaceContact`) or None."""
        return self.nodal("contact")

    @property
    def parametric_terms(self) -> list[ParametricTerm]:
        """The nodal terms with scalar parameters (:class:`~.term.ParametricTerm`)."""
        return [t for t in self.nodal_terms if isinstance(t, ParametricTerm)]

    # -- the Term interface ----------------------------------------------------------------------
    def connectivities(self) -> dict[str, np.ndarray]:
        conns = dict(self.term.connectivities())
        if self.nodal_terms:
            conns["nodal"] = self.nodes[:, None]
        return conns

    def energy(self, u_local: np.ndarray) -> float:
        """This rank's share of the potential energy (elastic + nodal terms)."""
        total = self.term.energy(u_local)
        for t in self.nodal_terms:
            total += t.energy(u_local)
        return total

    def nodal_gradient(self, u_local: np.ndarray) -> np.ndarray:
        """(len(nodes), 3) gradient of the nodal terms."""
        g = np.zeros((len(self.nodes), 3))
        for t, at in zip(self.nodal_terms, self._at, strict=True):
            g[at] += t.gradient(u_local)
        return g

    def nodal_hessian(self, u_local: np.ndarray, reference: bool = False) -> np.ndarray:
        """(len(nodes), 3, 3) Hessian blocks of the nodal terms (``reference``: only those in
        K0)."""
        H = np.zeros((len(self.nodes), 3, 3))
        for t, at in zip(self.nodal_terms, self._at, strict=True):
            if t.in_reference or not reference:
                H[at] += t.hessian(u_local)
        return H

    def add_gradient(self, u_local: np.ndarray, out: np.ndarray | None, assembler=None) -> None:
        """Add dW/du into the local (nv*3,) array ``out``; with ``assembler`` also the Hessian."""
        self.term.add_gradient(u_local, out, assembler)
        if not self.nodal_terms:
            return
        if out is not None:
            o = out.reshape(-1, 3)
            o[self.nodes] += self.nodal_gradient(u_local)
        if assembler is not None:
            assembler.add("nodal", self.nodal_hessian(u_local))

    def add_hessian(self, u_local: np.ndarray, assembler) -> None:
        """Add d2W/du2 into the assembler."""
        self.add_gradient(u_local, None, assembler)

    def add_reference_hessian(self, assembler) -> None:
        """Add K0: the elastic Hessian at u = 0 and the nodal terms that belong to it (the
        supports; not contact)."""
        self.term.add_reference_hessian(assembler)
        if self.nodal_terms:
            zero = np.zeros((self.term.dmesh.nvertices, 3))
            assembler.add("nodal", self.nodal_hessian(zero, reference=True))
