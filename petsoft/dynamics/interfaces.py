"""What the integrators, forward models and the local/global solver need of a dynamic system.

A *system* is a semi-discrete model  M q'' = -grad W(q) - D v + f(t)  with Dirichlet conditions:
the FEM body (:class:`~petsoft.dynamics.system.DynamicSystem`), a mass-spring network
(:class:`~petsoft.dynamics.mass_spring.MassSpringSystem`), a set of scalar oscillators
(:class:`~petsoft.dynamics.oscillator.OscillatorSystem`, the damping analysis). :class:`System`
declares the members every integrator calls. Capabilities only some systems have (a viscoelastic
branch, velocity-dependent forces, parameter derivatives, Dirichlet conditions, ...) are declared
too, with a neutral default in :class:`SystemDefaults` that every system inherits, so callers ask
``system.viscoelastic is not None`` instead of probing with ``getattr``. What kind of body a system
is (volume cells, finite element orders, a continuum material) it says by class attributes, which
code that holds only an experiment reads from the class
(:func:`petsoft.dynamics.factory.system_class`) without building the system; the systems of
experiments are built by :func:`petsoft.dynamics.factory.build_system`.

:class:`Stepper` declares what :class:`~petsoft.dynamics.simulate.Simulation` needs of a time
integrator (the objects :mod:`petsoft.dynamics.integrators` builds); :class:`StepperDefaults`
gives the checkpoint members to the integrators that carry nothing between steps but (q, v).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np
from petsc4py import PETSc


@runtime_checkable
class System(Protocol):
    """The interface of a dynamic system (see the module docstring).

    Every method works on PETSc vectors of the system's layout (``create_vec``) and is
    collective on ``comm``.
    """

    comm: PETSc.Comm
    #: the mass matrix (consistent or lumped)
    M: PETSc.Mat

    # -- what only some systems have: None/False when absent (SystemDefaults) --------------------
    #: the Maxwell branch of a standard linear solid, or None
    viscoelastic: Any
    #: velocity-dependent forces (drag, friction) of :mod:`petsoft.dynamics.velocity`, or None
    velocity_terms: Any
    #: Dirichlet conditions (eliminated rows), or None
    dirichlet: Any
    #: the elastic term of a continuum body, or None
    elastic: Any
    #: reference spring lengths of a mass-spring network, or None
    rest_lengths: Any
    #: the step matrix unassembled (:func:`petsoft.dynamics.matrix_free.unassembled`), the node
    #: graph (N, src, dst), the owned nodes' file numbers in the global vector's order, the most
    #: nodes one element couples (:mod:`petsoft.dynamics.nonlinear_gs`); None (0) without nodes
    unassembled: Any
    node_graph: Any
    owned_nodes: Any
    nodes_per_element: int
    #: prescribed displacements change in time / loads change in time / the step matrix is
    #: constant (linear material, no contact or nonlinear velocity terms)
    moving_boundary: bool
    time_dependent_loads: bool
    jacobian_is_constant: bool

    # -- what kind of body it is (class attributes; SystemDefaults: none of them) ----------------
    #: the experiment table that defines such a body, for messages ("[material]", "[springs]")
    defined_by: str
    #: the body is meshed in volume cells (tetrahedra): regions of cells, cell-wise sensitivity
    #: maps, a residual field over the body, a mesh refined by splitting its cells
    volume_cells: bool
    #: the finite element orders the body can be discretised with (empty: not finite elements)
    element_orders: tuple[int, ...]
    #: a continuum material (moduli and density per cell, elastic modes, supports' compliance,
    #: the viscoelastic branch)
    continuum_material: bool

    def initial_state(self, monitor=None) -> tuple[PETSc.Vec, PETSc.Vec]:
        """(q0, v0) at t = 0 as the system's source defines them (an experiment's ``[initial]``);
        ``monitor`` receives progress lines of a solve it needs (a static equilibrium)."""

    def create_vec(self) -> PETSc.Vec: ...

    def create_matrix(self) -> PETSc.Mat: ...

    def near_nullspace(self): ...

    def linear_defaults(self, ksp: PETSc.KSP) -> None: ...

    def assemble_combination(self, q: PETSc.Vec | None, a_mass: float, b_tangent: float,
                             c_reference: float, out: PETSc.Mat, eliminate: bool = True,
                             velocity: float = 0.0, reuse: bool = False) -> PETSc.Mat:
        """out = a M + b K(q) + c K0 (+ velocity x dG/dv), Dirichlet rows eliminated."""

    def internal_gradient(self, q: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec: ...

    def elastic_energy(self, q: PETSc.Vec) -> float: ...

    def kinetic_energy(self, v: PETSc.Vec) -> float: ...

    def gravitational_energy(self, q: PETSc.Vec) -> float: ...

    def damping_apply(self, v: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec: ...

    def tractions(self, t: float, out: PETSc.Vec) -> PETSc.Vec: ...

    def apply_prescribed(self, vec: PETSc.Vec, t: float) -> None: ...

    def zero_prescribed(self, vec: PETSc.Vec) -> None: ...

    def prescribed_offsets(self, vec: PETSc.Vec): ...

    def destroy(self) -> None: ...


class SystemDefaults:
    """Neutral values of the optional capabilities of :class:`System` (a system without them).

    A system class lists this last among its bases; what it has, it defines itself (an
    attribute, a property or a method), which takes precedence.
    """

    viscoelastic = None
    velocity_terms = None
    dirichlet = None
    elastic = None
    rest_lengths = None
    dmesh = None
    #: the discrete model the system was built from (mesh, terms, conditions), or None
    model = None
    #: the physical parameters in place (``values`` by name), or None
    parameters = None
    moving_boundary = False
    time_dependent_loads = False
    jacobian_is_constant = False
    #: linearisation of the velocity terms and its derivatives (VelocityDamping), or None
    set_velocity_state = None
    damping_tangent_apply = None
    damping_second_apply = None
    #: d residual / d parameters of a continuum body, or None
    parameter_derivatives = None
    #: the viscoelastic branch's stored energy, or None
    viscoelastic_energy = None
    #: what the node-wise solvers (matrix-free Jacobian, nonlinear Gauss-Seidel) need of a body
    #: of nodes: its step matrix unassembled, its node graph, its owned nodes' file numbers and
    #: the most nodes one element couples; None (0) for a system without nodes
    unassembled = None
    node_graph = None
    owned_nodes = None
    nodes_per_element = 0
    #: what kind of body: none of the capabilities (see :class:`System`)
    defined_by = "(no experiment table)"
    volume_cells = False
    element_orders: tuple[int, ...] = ()
    continuum_material = False


@runtime_checkable
class Stepper(Protocol):
    """A time integrator: advances (q0, v0) at t0 by h into (q1, v1)."""

    def step(self, t0: float, q0: PETSc.Vec, v0: PETSc.Vec, h: float, q1: PETSc.Vec,
             v1: PETSc.Vec):
        """One step; returns its :class:`~petsoft.dynamics.implicit.StepReport`."""

    def state(self) -> dict:
        """What a checkpoint must keep besides (t, q, v) to continue bit for bit (arrays)."""

    def restore(self, t: float, q: PETSc.Vec, v: PETSc.Vec, state: dict) -> None:
        """Continue from a checkpoint's (t, q, v) and :meth:`state`."""

    def destroy(self) -> None: ...


class StepperDefaults:
    """The checkpoint members of an integrator that carries nothing between steps but (q, v)."""

    def state(self) -> dict:
        return {}

    def restore(self, t: float, q: PETSc.Vec, v: PETSc.Vec, state: dict) -> None:
        """Nothing to restore: the next step starts from (t, q, v) alone."""


def length_scale(system) -> float:
    """A cell size of a system (m): the cube root of the mean cell volume of a continuum body,
    the mean rest length of a spring network, else 1 (collective)."""
    if system.elastic is not None and system.dmesh is not None:
        dm = system.dmesh
        vol = dm.cell_volumes
        count = dm.comm.tompi4py().allreduce(len(vol))
        return float(np.cbrt(dm.allreduce_sum(vol.sum()) / max(count, 1)))
    if system.rest_lengths is not None and len(system.rest_lengths):
        return float(np.mean(system.rest_lengths))   # replicated on every rank
    return 1.0
