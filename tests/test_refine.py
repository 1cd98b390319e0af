"""1 -> 8 refinement of any tetrahedral mesh (petsoft/mesh/refine.py) and ``[mesh] refine``.

Checked against geometry that does not depend on how the subdivision is coded: volumes (of the
whole mesh and of each parent's children), barycentric containment of every child in its
parent, facet-group areas and normals, the exterior boundary recomputed from the refined
tetrahedra, and the shape quality after two levels.
"""

from pathlib import Path

import numpy as np
import pytest

from petsoft.errors import ExperimentError, MeshError
from petsoft.experiment import experiment_from_dict, load_experiment
from petsoft.mesh.refine import refine_mesh, refine_triangles, refined_cell_count
from petsoft.mesh.serial import Mesh, box_mesh, read_mesh, signed_volumes
from petsoft.mesh.topology import exterior_faces
from petsoft.physics.model import load_mesh

BAR = Path(__file__).resolve().parent.parent / "meshes" / "bar.msh"


def _area_normals(points, tris):
    return 0.5 * np.cross(points[tris[:, 1]] - points[tris[:, 0]],
                          points[tris[:, 2]] - points[tris[:, 0]])


def _tapered(cells=(4, 2, 2)):
    """A box sheared and tapered (no two cells alike), with two regions and a clamp group."""
    m = box_mesh([0.2, 0.04, 0.04], cells)
    x = m.points[:, 0] / 0.2
    m.points[:, 1] *= 1.0 - 0.5 * x
    m.points[:, 2] = m.points[:, 2] * (1.0 - 0.3 * x) + 0.01 * x * x
    centroid_x = m.points[m.tets].mean(axis=1)[:, 0]
    m.cell_tags[:] = np.where(centroid_x < 0.1, 1, 2)
    m.regions.update({"root": 1, "tip": 2})
    faces, _ = exterior_faces(m.tets)
    m.facet_groups["clamp"] = faces[np.isclose(m.points[faces][:, :, 0], 0.0).all(axis=1)]
    m.facet_groups["top"] = faces[:5]
    return m


def _quality(points, tets):
    """6 sqrt(2) V / l_rms^3: 1 for a regular tetrahedron, -> 0 as it flattens."""
    p = points[tets]
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    l2 = sum(np.sum((p[:, i] - p[:, j]) ** 2, axis=1) for i, j in pairs) / 6.0
    return 6.0 * np.sqrt(2.0) * signed_volumes(points, tets) / l2**1.5


@pytest.fixture(params=["tapered box", "bar.msh"])
def mesh(request):
    return _tapered() if request.param == "tapered box" else read_mesh(BAR)


def test_volume_orientation_and_node_numbers(mesh):
    r = refine_mesh(mesh)
    assert len(r.tets) == refined_cell_count(len(mesh.tets)) == 8 * len(mesh.tets)
    vol = signed_volumes(r.points, r.tets)
    assert vol.min() > 0
    # each parent's volume is exactly that of its 8 children, not just the total
    np.testing.assert_allclose(vol.reshape(-1, 8).sum(axis=1),
                               signed_volumes(mesh.points, mesh.tets), rtol=1e-12)
    # the original nodes keep their numbers: a node id of the user's mesh names the same point
    np.testing.assert_array_equal(r.points[:len(mesh.points)], mesh.points)
    # the new nodes are the edge midpoints: one per edge, none repeated
    edges = np.unique(np.sort(mesh.tets[:, [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]]
                              .reshape(-1, 2), axis=1), axis=0)
    assert len(r.points) == len(mesh.points) + len(edges)


def test_every_child_lies_inside_its_parent_and_keeps_its_region(mesh):
    r = refine_mesh(mesh)
    parent = np.repeat(np.arange(len(mesh.tets)), 8)
    np.testing.assert_array_equal(r.cell_tags, mesh.cell_tags[parent])
    assert r.regions == mesh.regions
    # barycentric coordinates of every child vertex in its parent: in [0, 1]
    P = mesh.points[mesh.tets][parent]                       # (8E, 4, 3)
    T = np.transpose(P[:, 1:] - P[:, :1], (0, 2, 1))         # (8E, 3, 3)
    X = r.points[r.tets]                                     # (8E, 4, 3)
    lam = np.linalg.solve(T, np.transpose(X - P[:, :1], (0, 2, 1)))      # (8E, 3, 4)
    lam0 = 1.0 - lam.sum(axis=1)
    assert lam.min() > -1e-12 and lam0.min() > -1e-12
    assert lam.max() < 1 + 1e-12 and lam0.max() < 1 + 1e-12


def test_facet_groups_are_split_with_area_and_normals_kept(mesh):
    r = refine_mesh(mesh)
    assert set(r.facet_groups) == set(mesh.facet_groups) and mesh.facet_groups
    for name, tri in mesh.facet_groups.items():
        new = r.facet_groups[name]
        assert len(new) == 4 * len(tri)
        a_old = _area_normals(mesh.points, tri)
        a_new = _area_normals(r.points, new).reshape(-1, 4, 3)
        # the 4 children's area vectors add up to the parent's: same area, same orientation
        np.testing.assert_allclose(a_new.sum(axis=1), a_old, atol=1e-15)
        assert (np.einsum("fkc,fc->fk", a_new, a_old) > 0).all()


def test_the_boundary_of_the_refined_mesh_is_the_refined_boundary(mesh):
    from petsoft.mesh.refine import _Midpoints

    r = refine_mesh(mesh)
    faces, _ = exterior_faces(mesh.tets)
    split = refine_triangles(faces, _Midpoints(mesh.tets, len(mesh.points)))
    refined_boundary, _ = exterior_faces(r.tets)

    def oriented(t):       # a triangle as its rotation starting at its smallest node
        k = np.argmin(t, axis=1)
        return np.sort(np.stack([t[np.arange(len(t)), (k + i) % 3] for i in range(3)], axis=1)
                       .view([("", t.dtype)] * 3).ravel())
    np.testing.assert_array_equal(oriented(split), oriented(refined_boundary))


def test_refined_twice_is_fine(mesh):
    r2 = refine_mesh(mesh, 2)
    assert r2.source.endswith("refined 1->8 refined 1->8")
    assert len(r2.tets) == 64 * len(mesh.tets)
    np.testing.assert_allclose(signed_volumes(r2.points, r2.tets).sum(),
                               signed_volumes(mesh.points, mesh.tets).sum(), rtol=1e-12)
    q0, q2 = _quality(mesh.points, mesh.tets), _quality(r2.points, r2.tets)
    # the shortest inner diagonal keeps the shapes (a fixed diagonal lost 4x here in 2 levels)
    assert q2.min() > 0.8 * q0.min(), (q0.min(), q2.min())
    for name, tri in mesh.facet_groups.items():
        np.testing.assert_allclose(np.linalg.norm(_area_normals(r2.points, r2.facet_groups[name]),
                                                  axis=1).sum(),
                                   np.linalg.norm(_area_normals(mesh.points, tri), axis=1).sum(),
                                   rtol=1e-12)
    assert refine_mesh(mesh, 0) is mesh


def test_bad_levels_and_a_facet_that_is_no_face_are_clear_errors():
    m = _tapered((2, 1, 1))
    with pytest.raises(MeshError, match="refinement levels must be an integer >= 0"):
        refine_mesh(m, -1)
    with pytest.raises(MeshError, match="refinement levels"):
        refine_mesh(m, 1.5)
    bad = Mesh(points=m.points, tets=m.tets, cell_tags=m.cell_tags,
               facet_groups={"loose": np.array([[0, 7, len(m.points) - 1]])}, source="loose.msh")
    with pytest.raises(MeshError, match=r"loose.msh: the triangle edge .* is not an edge"):
        refine_mesh(bad)


def _experiment(tmp_path, mesh_table: str, extra: str = ""):
    path = tmp_path / "e.toml"
    path.write_text(f"[mesh]\n{mesh_table}\n[material]\nyoungs_modulus = 1e6\npoisson_ratio = "
                    f"0.3\ndensity = 1000.0\n{extra}")
    return load_experiment(path)


def test_mesh_refine_key_is_applied_after_reading_and_round_trips(tmp_path):
    exp = _experiment(tmp_path, f'file = "{BAR}"\nrefine = 1')
    assert exp.mesh.refine == 1
    m = load_mesh(exp)
    assert len(m.tets) == 8 * 1296 and set(m.facet_groups) == {"clamp", "tip"}
    back = experiment_from_dict(exp.to_dict(), source="back")
    assert back.mesh == exp.mesh and back.to_dict()["mesh"]["refine"] == 1
    # a box is refined the same way; refine = 0 (the default) is not written
    box = _experiment(tmp_path, "box = { size = [0.1, 0.02, 0.02], cells = [2, 1, 1] }\nrefine = 2")
    assert len(load_mesh(box).tets) == 12 * 64
    plain = _experiment(tmp_path, f'file = "{BAR}"')
    assert plain.mesh.refine == 0 and "refine" not in plain.to_dict()["mesh"]


def test_mesh_refine_key_errors(tmp_path):
    with pytest.raises(ExperimentError, match=r"refine"):
        _experiment(tmp_path, f'file = "{BAR}"\nrefine = -1')
    with pytest.raises(ExperimentError, match=r"refine"):
        _experiment(tmp_path, f'file = "{BAR}"\nrefine = 1.5')
