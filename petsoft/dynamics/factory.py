"""One factory for the systems of experiments: :func:`build_system`.

An experiment describes one kind of body: a continuum (``[material]``, a
:class:`~petsoft.dynamics.system.DynamicSystem` on a tetrahedral mesh of order 1 or 2) or a
mass-spring network (``[springs]``, a :class:`~petsoft.dynamics.mass_spring.MassSpringSystem`).
:func:`kind_of` is the one place that reads which (the experiment reader guarantees exactly one
of the two tables); everything else asks the system, or its class when it has no system yet
(:func:`system_class`), what it has: volume cells, finite element orders, a continuum material
(the class attributes of :class:`~petsoft.dynamics.interfaces.System`), its initial state, its
nodes for the node-wise solvers (``unassembled``, ``node_graph``, ``owned_nodes``), where its
probes sit and how large the body is (:class:`ExperimentSystem`).

A new kind of body is one entry of :data:`KINDS` (its system class, how its model is built, how
the system is made from the model); tests/test_interfaces.py builds every entry through
:func:`build_system` and checks it against both protocols.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from petsc4py import PETSc

from petsoft.dynamics.interfaces import System
from petsoft.dynamics.mass_spring import MassSpringSystem, build_mass_spring_model
from petsoft.dynamics.rayleigh import RayleighDamping
from petsoft.dynamics.system import DynamicSystem
from petsoft.errors import ExperimentError
from petsoft.physics.model import build_model as build_continuum_model


@runtime_checkable
class ExperimentSystem(System, Protocol):
    """What a system built from an experiment offers besides :class:`System`."""

    def locate_probes(self, probes, source: str = "probes"):
        """(connectivity, cells, weights) of ``output.probes`` points: a probe's value is the
        weighted sum of the nodal values ``connectivity[cells[i]]`` with ``weights[i]``; an
        ``ExperimentError`` names a probe off the body."""

    @staticmethod
    def dof_count(experiment) -> int:
        """Unknowns (3 per node) of the model ``experiment`` describes, from its mesh (without
        building the system)."""

    @staticmethod
    def body_sizes(experiment) -> dict:
        """``mass`` (kg), ``area`` (exterior surface, m^2), ``length`` (bounding-box diagonal,
        m) and ``cell`` (mean cell size, m) of the body ``experiment`` describes, from its mesh
        (without building the system)."""


@dataclass(frozen=True)
class Kind:
    """How one kind of body is built from an experiment."""

    #: the System class (its class attributes are the kind's capabilities)
    system: type
    #: (experiment, comm, inputs, mesh) -> the discrete model the system is made from
    model: Callable[..., Any]
    #: (model, experiment, spd) -> the system, with the experiment's Rayleigh damping
    make: Callable[..., System]


def _continuum_model(experiment, comm, inputs, mesh):
    return build_continuum_model(experiment, comm, recording=inputs, mesh=mesh)


def _spring_model(experiment, comm, inputs, mesh):
    if mesh is not None:
        raise ExperimentError(f"{experiment.source}: a [springs] model is built from its own "
                              "mesh file: another mesh (a computed rest shape) applies to "
                              "[material] models only")
    return build_mass_spring_model(experiment, comm, recording=inputs)


#: Every kind of body the factory builds, by name.
KINDS: dict[str, Kind] = {
    "continuum": Kind(DynamicSystem, _continuum_model,
                      lambda model, e, spd: DynamicSystem(
                          model, rayleigh=RayleighDamping.of(e))),
    "mass-spring": Kind(MassSpringSystem, _spring_model,
                        lambda model, e, spd: MassSpringSystem(
                            model, clamp=spd, rayleigh=RayleighDamping.of(e))),
}


def kind_of(experiment) -> Kind:
    """The kind of body ``experiment`` describes (the one place that asks)."""
    return KINDS["mass-spring" if experiment.is_mass_spring else "continuum"]


def system_class(experiment) -> type:
    """The System class of ``experiment``: what the body has, without building it."""
    return kind_of(experiment).system


def build_model(experiment, comm: PETSc.Comm | None = None, inputs=None, *, mesh=None):
    """The discrete model of ``experiment`` on ``comm`` (all ranks call).

    ``inputs`` is the recording (or its path) whose ``/inputs`` drive ``series`` supports;
    ``mesh`` replaces a continuum's mesh (a computed rest shape).
    """
    comm = comm if comm is not None else PETSc.COMM_WORLD
    return kind_of(experiment).model(experiment, comm, inputs, mesh)


def system_for(model, experiment, *, spd: bool = False) -> System:
    """The system of a built ``model`` of ``experiment``, with its ``[damping]``.

    ``spd``: clamped (positive semi-definite) spring Jacobians of a ``[springs]`` model; a
    continuum's Jacobians are projected by its model instead (``build_model(project_spd=...)``
    of :mod:`petsoft.physics.model`), so it does not use ``spd``.
    """
    return kind_of(experiment).make(model, experiment, spd)


def build_system(experiment, comm: PETSc.Comm | None = None, inputs=None, *, mesh=None,
                 spd: bool = False) -> System:
    """The system of ``experiment`` on ``comm``: its model (:func:`build_model`) and the system
    made from it (:func:`system_for`); all ranks call. ``system.model`` is the model."""
    return system_for(build_model(experiment, comm, inputs, mesh=mesh), experiment, spd=spd)
