"""The surface rule of a mass-spring body: which terms need a surface, and the refusal of one on
a spring mesh that has none.

A term declared on the surface (``Term.surface``: the drag; :mod:`petsoft.terms`) acts through
the faces of the body's surface. A spring mesh's surface is its triangle cells
(:attr:`~petsoft.mesh.springs.SpringMesh.surface`); a network of lines (a rope, a pendulum) has
none and cannot carry such a term. The experiment reader applies the rule as soon as it knows
the mesh file, the mass-spring model builder to the mesh it builds on (which may be handed to
it): both through :func:`check_surface_terms`, so they refuse the same experiments with the
same words. (A continuum's surface is its exterior faces, which every tetrahedral mesh has.)
"""

from __future__ import annotations

from petsoft.errors import ExperimentError
from petsoft.experiment.parameters import get_parameter
from petsoft.mesh.springs import SpringMesh
from petsoft.terms import TERMS

__all__ = ["check_surface_terms", "surface_keys"]


def surface_keys(experiment) -> list[str]:
    """The dotted keys of the surface terms ``experiment`` switches on: a non-zero value, or a
    key ``[calibrate]`` fits (from 0 too), in the registry's order."""
    return [k.dotted for t in TERMS.values() if t.surface for k in t.keys
            if get_parameter(experiment, k.dotted) != 0.0 or k.dotted in experiment.calibrate]


def check_surface_terms(experiment, mesh: SpringMesh) -> None:
    """Refuse the surface terms ``experiment`` switches on (:func:`surface_keys`) when the spring
    mesh ``mesh`` has no surface (no triangle cells), naming the first one's key and the terms a
    rope can carry (those acting on the nodes: the velocity laws and Rayleigh terms not on the
    surface).

    Raises
    ------
    ExperimentError
        ``<source>: drag.linear = 0.5: drag needs a surface, and the mass-spring mesh <mesh>
        has no triangle cells ...`` (``calibrate."drag.linear"`` for a key fitted from 0).
    """
    keys = surface_keys(experiment)
    if not keys or len(mesh.surface):
        return
    key = keys[0]
    where = (f"{key} = {get_parameter(experiment, key):g}" if key not in experiment.calibrate
             else f'calibrate."{key}"')
    nodal = [f"[{k.table}] {k.key}" for t in TERMS.values()
             if t.contributes in ("velocity", "rayleigh") and not t.surface for k in t.keys[:1]]
    raise ExperimentError(
        f"{experiment.source}: {where}: {key.split('.')[0]} needs a surface, and the "
        f"mass-spring mesh {mesh.source} has no triangle cells (a line-only spring network); "
        f"use {', '.join(nodal[:-1])} or {nodal[-1]} for a rope or pendulum")
