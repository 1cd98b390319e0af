"""The state at t = 0 of a system built from an experiment, from its ``[initial]`` table.

Shared by the systems' ``initial_state`` (:class:`petsoft.dynamics.interfaces.System`): the
displacement and velocity expressions evaluated at the nodes, then the prescribed values of the
Dirichlet conditions at t = 0 imposed on the displacement.
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc


def initial_from_expressions(system, initial, q0: PETSc.Vec | None = None):
    """(q0, v0) of ``system`` (global vectors) from ``[initial]`` (an ``InitialSpec``).

    ``q0`` given (a static equilibrium) replaces the displacement expressions; either way the
    prescribed displacements at t = 0 are applied to it.
    """
    dm = system.dmesh
    pts = dm.mesh.points
    if q0 is None:
        q0 = dm.from_file_field(np.column_stack([e.evaluate_at(pts) for e in initial.displacement]))
    v0 = dm.from_file_field(np.column_stack([e.evaluate_at(pts) for e in initial.velocity]))
    system.apply_prescribed(q0, 0.0)
    return q0, v0
