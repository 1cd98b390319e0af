"""Orderings of mesh entities (petsoft.mesh.ordering) against their plain numpy definitions."""

import numpy as np
import pytest

from petsoft.mesh.ordering import (
    cell_centroids,
    cell_morton_keys,
    cell_morton_order,
    first_touch_order,
    morton_keys,
    morton_order,
)
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


def test_compiled_cell_keys_equal_the_numpy_definition():
    """The compiled keys (csrc/ordering.c) are bitwise the numpy ones: the centroid's sum in
    order, the bounding box of the centroids, the quantisation, the interleaving; on a box, a
    jittered mesh with flat extents, 10-node cells (corners only) and a single cell."""
    rng = np.random.default_rng(7)
    box = box_mesh([1.0, 0.3, 0.2], [9, 4, 3])
    jitter = box.points * [1.0, 1e-9, 3.0] + rng.normal(scale=1e-3, size=box.points.shape)
    cases = [(box.points, box.tets), (jitter, box.tets),
             (rng.normal(size=(50, 3)), rng.integers(0, 50, size=(200, 10))[:, :4]),
             (box.points, box.tets[:1])]
    for points, cells in cases:
        want = morton_keys(cell_centroids(points, cells))
        np.testing.assert_array_equal(cell_morton_keys(points, cells), want)
        np.testing.assert_array_equal(cell_morton_order(points, cells),
                                      np.argsort(want, kind="stable"))
    assert cell_morton_keys(box.points, box.tets[:0]).shape == (0,)


def test_compiled_cell_keys_refuse_cells_outside_the_points():
    mesh = box_mesh([1.0, 1.0, 1.0], [1, 1, 1])
    bad = mesh.tets.copy()
    bad[0, 2] = len(mesh.points)
    with pytest.raises(ValueError, match="do not exist"):
        cell_morton_keys(mesh.points, bad)
