"""The interfaces of potential-energy terms: what solvers, integrators and calibration call.

Two kinds of term make up a continuum model's potential (:class:`~petsoft.physics.potential.
ModelPotential` sums them):

- a :class:`Term` acts on elements: it names its element sets (``connectivities``: the matrix
  pattern is built from them once) and adds its gradient and Hessian blocks into local arrays and
  the shared :class:`~petsoft.fem.assembly.MatrixAssembler` (the elastic law,
  :class:`~petsoft.physics.elastic.ElasticTerm`; the model's whole potential);
- a :class:`NodalTerm` acts on single vertices (elastic supports, collider contact): it returns
  per-node gradients and 3x3 Hessian blocks for its ``nodes``, which the potential adds through
  one shared one-vertex element set.

A term with scalar parameters (named as in ``petsoft.experiment.get_parameter``: the supports'
``boundary.compliance``, the planes' ``collider.<i>.offset``) also implements
:class:`ParametricTerm`: their values, setting them, and the derivative of the term's gradient
with respect to one, which the sensitivities need. (The elastic law's Lame parameters vary per
cell: :meth:`petsoft.physics.elastic.ElasticTerm.lame_derivatives`.)

A new physics term is one new module implementing one of these, appended where the model is
built (:func:`petsoft.physics.model.build_model`). ``tests/test_interfaces.py`` checks every
implementation against these declarations.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Term(Protocol):
    """An element-level potential term W(u) on this rank's cells (u: local (nv, 3) array)."""

    name: str

    def connectivities(self) -> dict[str, np.ndarray]:
        """Element sets (name -> (ne, nodes per element) local vertex indices) it assembles."""

    def energy(self, u_local: np.ndarray) -> float:
        """This rank's share of W(u)."""

    def add_gradient(self, u_local: np.ndarray, out: np.ndarray | None,
                     assembler=None) -> None:
        """Add dW/du into ``out`` (local (nv*3,) array); with ``assembler`` also d2W/du2."""

    def add_hessian(self, u_local: np.ndarray, assembler) -> None:
        """Add d2W/du2 into ``assembler``."""

    def add_reference_hessian(self, assembler) -> None:
        """Add the reference stiffness K0 (the part of d2W/du2 at u = 0 that defines it)."""


@runtime_checkable
class NodalTerm(Protocol):
    """A potential on single vertices (local indices ``nodes``)."""

    #: what it models ("support", "contact"): the potential finds a term by it
    kind: str
    nodes: np.ndarray
    #: whether its Hessian at u = 0 belongs to the reference stiffness K0 (a support's springs
    #: do; contact, a state-dependent constraint, does not)
    in_reference: bool

    def energy(self, u_local: np.ndarray) -> float:
        """This rank's share of the term's energy."""

    def gradient(self, u_local: np.ndarray) -> np.ndarray:
        """(len(nodes), 3) dW/du at the nodes."""

    def hessian(self, u_local: np.ndarray) -> np.ndarray:
        """(len(nodes), 3, 3) Hessian blocks at the nodes."""


@runtime_checkable
class ParametricTerm(Protocol):
    """A term with scalar parameters the calibration may set and differentiate."""

    def parameters(self) -> dict[str, float]:
        """The term's parameters (experiment names) and their current values."""

    def set_parameter(self, name: str, value: float) -> None:
        """Set one of :meth:`parameters` (KeyError for a name that is not one)."""

    def add_parameter_derivative(self, name: str, u_local: np.ndarray,
                                 out: np.ndarray) -> None:
        """Add d(dW/du)/dp at ``u_local``, p the parameter ``name``, into the local (nv, 3)
        array ``out`` (for a term linear in u, pass y = u + w + beta v for d(K y)/dp).

        A term of another package (:data:`petsoft.terms.PLUGINS`) takes a fourth argument,
        ``w_local`` (local (nv, 3) or None): it adds d/dp (dW/du + d2W/du2 w) at ``u_local``
        (the semi-implicit step's derivative needs the Hessian's part; None: w = 0)."""
