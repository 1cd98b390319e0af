"""Resolving `where` selections (region names or expressions) to vertices, cells and faces.

Works on the full serial mesh (every rank has it), so a selection is the same on any number of
ranks; callers index the result with their local file numbers.
"""

from __future__ import annotations

import numpy as np

from petsoft.errors import ExperimentError
from petsoft.experiment.expressions import Expression
from petsoft.mesh.quadratic import face_nodes
from petsoft.mesh.topology import exterior_faces


class RegionResolver:
    """Selections on a mesh for an experiment.

    Parameters
    ----------
    mesh : Mesh
    regions : dict of str to RegionSpec
        The experiment's ``[region.<name>]`` definitions (conditions of x, y, z).
    source : str
        The experiment's name for messages.
    """

    def __init__(self, mesh, regions, source: str = "<experiment>"):
        self.mesh = mesh
        self.regions = dict(regions)
        self.source = source
        self._exterior = None

    @property
    def names(self) -> list[str]:
        return sorted(set(self.regions) | set(self.mesh.regions) | set(self.mesh.facet_groups))

    def _unknown(self, name: str, key: str) -> ExperimentError:
        valid = ", ".join(self.names) or "none (no mesh physical groups, no [region])"
        return ExperimentError(
            f"{self.source}: {key}: unknown region {name!r}; defined regions are: {valid} "
            "(or give a condition of x, y, z such as \"x < 1e-6\")")

    def vertex_mask(self, where: str | Expression, key: str = "where") -> np.ndarray:
        """(N,) bool: nodes in the selection (edge nodes of 10-node tetrahedra included: a
        condition tests their position, a region or facet group holds the edge nodes of its
        cells or triangles)."""
        m = self.mesh
        if isinstance(where, Expression):
            return where.evaluate_at(m.points).astype(bool)
        if where in self.regions:
            return self.regions[where].where.evaluate_at(m.points).astype(bool)
        mask = np.zeros(len(m.points), dtype=bool)
        if where in m.regions:
            mask[m.cells[m.cell_tags == m.regions[where]].ravel()] = True
            return mask
        if where in m.facet_groups:
            mask[face_nodes(m, m.facet_groups[where]).ravel()] = True
            return mask
        raise self._unknown(where, key)

    def cell_mask(self, where: str | Expression, key: str = "region") -> np.ndarray:
        """(E,) bool: cells in the selection (an expression region tests the cell centroid)."""
        m = self.mesh
        if isinstance(where, Expression):
            return where.evaluate_at(m.points[m.tets].mean(axis=1)).astype(bool)
        if where in self.regions:
            return self.cell_mask(self.regions[where].where, key)
        if where in m.regions:
            return m.cell_tags == m.regions[where]
        if where in m.facet_groups:
            raise ExperimentError(
                f"{self.source}: {key}: region {where!r} is a surface (2D physical group); "
                "a material needs a volume region (3D physical group or a [region] condition)")
        raise self._unknown(where, key)

    def faces(self, where: str | Expression, key: str = "where") -> np.ndarray:
        """(F, 3) boundary faces in the selection (a face belongs when all its vertices do)."""
        m = self.mesh
        if isinstance(where, str) and where in m.facet_groups:
            return np.asarray(m.facet_groups[where], dtype=np.int64)
        if self._exterior is None:
            self._exterior = exterior_faces(m.tets)[0]
        mask = self.vertex_mask(where, key)
        return self._exterior[mask[self._exterior].all(axis=1)]
