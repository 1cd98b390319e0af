"""The potential energy terms of a continuum model: elasticity plus nodal terms.

:class:`ModelPotential` is what ``Model.elastic`` holds: the :class:`ElasticTerm` plus the nodal
(one-vertex) potentials -- elastic supports (:mod:`petsoft.physics.support`) and collider contact
(:mod:`petsoft.physics.contact`). It offers the ElasticTerm interface (``energy``,
``add_gradient``, ``add_hessian``, ``connectivities``, ``groups``, ``lame_derivatives``), so the
static solver, the dynamic system and the modes see every potential term without knowing them.
The nodal Hessian blocks go into the shared matrix pattern through a one-vertex element set
``"nodal"`` (the diagonal blocks exist already: the pattern does not change).

:meth:`ModelPotential.add_reference_hessian` is the reference stiffness K0: elasticity at u = 0
plus the supports (constant), without contact (a state-dependent constraint, not a property of
the undeformed body).
"""

from __future__ import annotations

import numpy as np

from petsoft.physics.elastic import ElasticTerm


class ModelPotential:
    """Elastic energy + elastic supports + contact (either may be None).

    Parameters
    ----------
    elastic : ElasticTerm
    support : ElasticSupport or None
    contact : SurfaceContact or None
    """

    name = "potential"

    def __init__(self, elastic: ElasticTerm, support=None, contact=None):
        self.term = elastic
        self.support = support
        self.contact = contact
        parts = [t.nodes for t in (support, contact) if t is not None]
        self.nodes = np.unique(np.concatenate(parts)) if parts else np.zeros(0, np.int64)
        # where each term's nodes sit among self.nodes
        self._at = {id(t): np.searchsorted(self.nodes, t.nodes) for t in (support, contact)
                    if t is not None}

    # -- the ElasticTerm interface ---------------------------------------------------------------
    def __getattr__(self, name):
        # groups, dmesh, project_spd, lame_derivatives, ...: the elastic term's
        if name == "term":
            raise AttributeError(name)
        return getattr(self.term, name)

    @property
    def nodal_terms(self) -> list:
        return [t for t in (self.support, self.contact) if t is not None]

    def connectivities(self) -> dict[str, np.ndarray]:
        conns = dict(self.term.connectivities())
        if self.nodal_terms:
            conns["nodal"] = self.nodes[:, None]
        return conns

    def energy(self, u_local: np.ndarray) -> float:
        """This rank's share of the potential energy (elastic + supports + contact)."""
        total = self.term.energy(u_local)
        for t in self.nodal_terms:
            total += t.energy(u_local)
        return total

    def nodal_gradient(self, u_local: np.ndarray) -> np.ndarray:
        """(len(nodes), 3) gradient of the nodal terms."""
        g = np.zeros((len(self.nodes), 3))
        for t in self.nodal_terms:
            g[self._at[id(t)]] += t.gradient(u_local)
        return g

    def nodal_hessian(self, u_local: np.ndarray, contact: bool = True) -> np.ndarray:
        """(len(nodes), 3, 3) Hessian blocks of the nodal terms (``contact``: with contact)."""
        H = np.zeros((len(self.nodes), 3, 3))
        if self.support is not None:
            H[self._at[id(self.support)]] += self.support.hessian()
        if contact and self.contact is not None:
            H[self._at[id(self.contact)]] += self.contact.hessian(u_local)
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
        """Add K0: the elastic Hessian at u = 0 and the supports (no contact)."""
        zero = np.zeros((self.term.dmesh.nvertices, 3))
        self.term.add_hessian(zero, assembler)
        if self.nodal_terms:
            assembler.add("nodal", self.nodal_hessian(zero, contact=False))
