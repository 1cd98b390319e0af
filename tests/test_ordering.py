"""Orderings of mesh entities (petsoft.mesh.ordering) against their plain numpy definitions."""

import numpy as np

from petsoft.mesh.ordering import cell_centroids, first_touch_order, morton_order
from petsoft.mesh.serial import box_mesh


def _first_touch_by_sorting(cells, nvertices):
    """The definition: vertices by first appearance (np.unique), unused ones last, ascending."""
    flat = cells.ravel()
    _, first = np.unique(flat, return_index=True)
    used = flat[np.sort(first)]
    return np.concatenate([used, np.setdiff1d(np.arange(nvertices), used)])


def test_first_touch_order_equals_its_definition():
    rng = np.random.default_rng(4)
    for nvertices, ncells in ((10, 3), (200, 150), (5000, 900)):
        cells = rng.integers(0, nvertices, size=(ncells, 4))     # repeats, unused vertices
        perm = first_touch_order(cells, nvertices)
        np.testing.assert_array_equal(perm, _first_touch_by_sorting(cells, nvertices))
        assert sorted(perm.tolist()) == list(range(nvertices))


def test_centroids_are_bitwise_the_mean():
    """The distribution's cell order (Morton keys of the centroids) stays what it was."""
    mesh = box_mesh([1.0, 0.3, 0.2], [7, 3, 2])
    c = cell_centroids(mesh.points, mesh.tets)
    np.testing.assert_array_equal(c, mesh.points[mesh.tets].mean(axis=1))
    np.testing.assert_array_equal(morton_order(c),
                                  morton_order(mesh.points[mesh.tets].mean(axis=1)))
