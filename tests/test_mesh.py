"""Tests of petsoft.mesh.serial: reading every supported format, the box generator, and every
error and
warning a broken mesh file triggers (each crafted as a small file in tmp_path).

No MPI here: under ``mpiexec -n 2`` each rank runs these independently in its own tmp_path.
"""

from __future__ import annotations

import importlib.util
import warnings
from pathlib import Path

import meshio
import numpy as np
import pytest

from petsoft.errors import MeshError, PetsoftError
from petsoft.mesh.serial import (
    Mesh,
    MeshWarning,
    boundary_facets,
    box_mesh,
    read_mesh,
    signed_volumes,
    validate,
)

ROOT = Path(__file__).resolve().parent.parent


def _load_make_meshes():
    spec = importlib.util.spec_from_file_location("make_meshes",
                                                  ROOT / "scripts/tools/make_meshes.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


make_meshes = _load_make_meshes()


# ------------------------------------------------------------------------------------------------
# helpers


def _normals(points, tris):
    p = points[tris]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) / 2.0  # length = area


def _two_tets():
    """5 nodes, 2 positively oriented tetrahedra sharing face (1, 2, 3)."""
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1.0]])
    return pts, np.array([[0, 1, 2, 3], [1, 2, 3, 4]])


def _tagged_bar():
    """meshio mesh of a small tagged box (left/right regions, clamp/tip facet groups)."""
    return make_meshes.tagged_box(
        [0.4, 0.04, 0.04],
        [4, 1, 1],
        regions={
            "left": (1, lambda m: m.points[m.tets, 0].mean(1) < 0.2),
            "right": (2, lambda m: m.points[m.tets, 0].mean(1) >= 0.2),
        },
        facets={"clamp": (3, (0, 0.0)), "tip": (4, (0, 0.4))},
    )


def _write_gmsh41(path, m: meshio.Mesh):
    """Write a gmsh 4.1 ASCII file the way gmsh does: one entity per physical group.

    meshio's own gmsh 4.1 writer cannot attach physical groups to entities, so the test writes
    the format itself (nodes in one block, elements in one block per (dimension, tag)).
    """
    names = {(int(v[1]), int(v[0])): k for k, v in m.field_data.items()}
    blocks = []  # (dim, entity, gmsh type, cells, physical tag)
    gmsh_type = {"triangle": (2, 2), "tetra": (3, 4)}
    for block, tags in zip(m.cells, m.cell_data["gmsh:physical"], strict=True):
        dim, etype = gmsh_type[block.type]
        for t in np.unique(tags):
            blocks.append((dim, etype, block.data[tags == t], int(t)))
    surfaces = [b for b in blocks if b[0] == 2]
    volumes = [b for b in blocks if b[0] == 3]
    lines = ["$MeshFormat", "4.1 0 8", "$EndMeshFormat", "$PhysicalNames", str(len(names))]
    lines += [f'{d} {t} "{n}"' for (d, t), n in names.items()]
    lines += ["$EndPhysicalNames", "$Entities", f"0 0 {len(surfaces)} {len(volumes)}"]
    for i, b in enumerate(surfaces + volumes):
        ent = i + 1 if b[0] == 2 else i + 1 - len(surfaces)
        lines.append(f"{ent} 0 0 0 1 1 1 1 {b[3]} 0")
    n = len(m.points)
    lines += ["$EndEntities", "$Nodes", f"1 {n} 1 {n}", f"3 1 0 {n}"]
    lines += [str(i + 1) for i in range(n)]
    lines += [" ".join(repr(float(c)) for c in p) for p in m.points]
    ne = sum(len(b[2]) for b in blocks)
    lines += ["$EndNodes", "$Elements", f"{len(blocks)} {ne} 1 {ne}"]
    tag = 1
    for i, (dim, etype, cells, _) in enumerate(blocks):
        ent = i + 1 if dim == 2 else i + 1 - len(surfaces)
        lines.append(f"{dim} {ent} {etype} {len(cells)}")
        for c in cells:
            lines.append(f"{tag} " + " ".join(str(int(v) + 1) for v in c))
            tag += 1
    lines += ["$EndElements", ""]
    Path(path).write_text("\n".join(lines))


def _read_quiet(path, **kw):
    """read_mesh, failing on any warning (a clean file must read silently)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", MeshWarning)
        return read_mesh(path, **kw)


def _check_tagged_bar(mesh: Mesh, named: bool):
    ref = box_mesh([0.4, 0.04, 0.04], [4, 1, 1])
    np.testing.assert_array_equal(mesh.points, ref.points)
    np.testing.assert_array_equal(mesh.tets, ref.tets)
    left = ref.points[ref.tets, 0].mean(1) < 0.2
    np.testing.assert_array_equal(mesh.cell_tags, np.where(left, 1, 2))
    if named:
        assert mesh.regions == {"left": 1, "right": 2}
        assert set(mesh.facet_groups) == {"clamp", "tip"}
        clamp, tip = mesh.facet_groups["clamp"], mesh.facet_groups["tip"]
    else:
        assert mesh.regions == {"group1": 1, "group2": 2}
        assert set(mesh.facet_groups) == {"group3", "group4"}
        clamp, tip = mesh.facet_groups["group3"], mesh.facet_groups["group4"]
    assert clamp.shape == (2, 3) and tip.shape == (2, 3)
    assert np.all(mesh.points[clamp, 0] == 0.0) and np.all(mesh.points[tip, 0] == 0.4)
    # Boundary facet groups come out with outward normals.
    assert np.all(_normals(mesh.points, clamp)[:, 0] < 0)
    assert np.all(_normals(mesh.points, tip)[:, 0] > 0)
    assert mesh.tets.dtype == np.int64 and mesh.cell_tags.dtype == np.int64
    assert mesh.points.dtype == np.float64


# ------------------------------------------------------------------------------------------------
# round trips


def test_gmsh22_round_trip(tmp_path):
    path = tmp_path / "bar.msh"
    meshio.write(path, _tagged_bar(), file_format="gmsh22", binary=False)
    mesh = _read_quiet(path)
    _check_tagged_bar(mesh, named=True)
    assert mesh.source == str(path)


def test_gmsh22_binary_round_trip(tmp_path):
    path = tmp_path / "bar.msh"
    meshio.write(path, _tagged_bar(), file_format="gmsh22", binary=True)
    _check_tagged_bar(_read_quiet(path), named=True)


def test_gmsh41_round_trip(tmp_path):
    path = tmp_path / "bar41.msh"
    _write_gmsh41(path, _tagged_bar())
    assert path.read_text().startswith("$MeshFormat\n4.1")
    _check_tagged_bar(_read_quiet(path), named=True)


@pytest.mark.parametrize("key", ["gmsh:physical", "CellEntityIds", "region"])
@pytest.mark.parametrize("ext", [".vtu", ".xdmf"])
def test_vtu_xdmf_round_trip(tmp_path, ext, key):
    m = _tagged_bar()
    tags = m.cell_data["gmsh:physical"]
    m = meshio.Mesh(m.points, m.cells, cell_data={key: tags})
    path = tmp_path / f"bar{ext}"
    meshio.write(path, m)
    # These formats have no group names: groups are called group<tag>.
    _check_tagged_bar(_read_quiet(path), named=False)


def test_medit_round_trip(tmp_path):
    m = _tagged_bar()
    m = meshio.Mesh(m.points, m.cells, cell_data={"medit:ref": m.cell_data["gmsh:physical"]})
    path = tmp_path / "bar.mesh"
    meshio.write(path, m)
    _check_tagged_bar(_read_quiet(path), named=False)


def test_untagged_file_has_no_groups(tmp_path):
    ref = box_mesh([1, 2, 3], [1, 2, 1])
    path = tmp_path / "plain.vtu"
    meshio.write(path, meshio.Mesh(ref.points, [("tetra", ref.tets)]))
    mesh = _read_quiet(path)
    assert mesh.regions == {} and mesh.facet_groups == {}
    np.testing.assert_array_equal(mesh.cell_tags, 0)
    np.testing.assert_array_equal(mesh.tets, ref.tets)


def test_scale(tmp_path):
    ref = box_mesh([10, 10, 10], [1, 1, 1])
    path = tmp_path / "mm.vtu"
    meshio.write(path, meshio.Mesh(ref.points, [("tetra", ref.tets)]))
    mesh = _read_quiet(path, scale=1e-3)
    np.testing.assert_allclose(mesh.points, ref.points * 1e-3)
    np.testing.assert_allclose(signed_volumes(mesh.points, mesh.tets).sum(), 1e-6)


def test_committed_meshes_match_generator(tmp_path):
    for path in make_meshes.main(tmp_path):
        assert (ROOT / "meshes" / path.name).read_bytes() == path.read_bytes(), (
            f"meshes/{path.name} differs from scripts/tools/make_meshes.py output: rerun the script"
        )


def test_committed_bar():
    mesh = _read_quiet(ROOT / "meshes/bar.msh")
    assert mesh.num_points == 400 and mesh.num_cells == 1296
    assert mesh.regions == {"left": 1, "right": 2}
    vol = signed_volumes(mesh.points, mesh.tets)
    assert np.all(vol > 0)
    np.testing.assert_allclose(vol.sum(), 0.4 * 0.04 * 0.04)
    np.testing.assert_allclose(vol[mesh.cell_tags == 1].sum(), 0.2 * 0.04 * 0.04)
    for name, x, sign in [("clamp", 0.0, -1), ("tip", 0.4, 1)]:
        tris = mesh.facet_groups[name]
        n = _normals(mesh.points, tris)
        np.testing.assert_allclose(mesh.points[tris, 0], x)
        np.testing.assert_allclose(n[:, 0].sum(), sign * 0.04 * 0.04)  # area, outward
        np.testing.assert_allclose(n[:, 1:], 0, atol=1e-18)


def test_committed_cube_mm():
    mesh = _read_quiet(ROOT / "meshes/cube_mm.msh", scale=1e-3)
    np.testing.assert_allclose(mesh.points.max(axis=0), 0.01)
    assert mesh.regions == {"body": 1}
    assert set(mesh.facet_groups) == {"bottom", "top"}
    np.testing.assert_allclose(_normals(mesh.points, mesh.facet_groups["top"])[:, 2].sum(), 1e-4)


# ------------------------------------------------------------------------------------------------
# file-level errors


def test_missing_file(tmp_path):
    path = tmp_path / "nope.msh"
    with pytest.raises(MeshError, match="nope.msh.*does not exist"):
        read_mesh(path)


def test_directory_is_not_a_mesh(tmp_path):
    with pytest.raises(MeshError, match="not a regular file"):
        read_mesh(tmp_path)


def test_unreadable_file_names_file(tmp_path):
    path = tmp_path / "garbage.msh"
    path.write_text("this is not a gmsh file\n")
    with pytest.raises(MeshError, match=r"cannot read mesh file .*garbage\.msh") as err:
        read_mesh(path)
    assert isinstance(err.value, PetsoftError)
    assert err.value.__cause__ is not None  # meshio's exception is kept for debugging


def test_unknown_extension(tmp_path):
    path = tmp_path / "mesh.unknownext"
    path.write_text("1 2 3\n")
    with pytest.raises(MeshError, match=r"cannot read mesh file .*mesh\.unknownext"):
        read_mesh(path)


@pytest.mark.parametrize("scale", [0, -1.0, float("nan"), float("inf"), "1", True, None])
def test_bad_scale(tmp_path, scale):
    path = tmp_path / "m.vtu"
    pts, tets = _two_tets()
    meshio.write(path, meshio.Mesh(pts, [("tetra", tets)]))
    with pytest.raises(MeshError, match=r"m\.vtu: mesh scale must be a finite number > 0"):
        read_mesh(path, scale=scale)


def test_no_tetrahedra_says_what_was_found(tmp_path):
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    m = meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2], [0, 1, 3]])), ("line", [[0, 1]])])
    path = tmp_path / "surface.vtu"
    meshio.write(path, m)
    with pytest.raises(MeshError, match=r"surface\.vtu: contains no tetrahedra") as err:
        read_mesh(path)
    assert "2 triangle" in str(err.value) and "1 line" in str(err.value)


def test_two_dimensional_points(tmp_path):
    pts = np.array([[0, 0], [1, 0], [0, 1.0], [1, 1]])
    m = meshio.Mesh(pts, [("tetra", [[0, 1, 2, 3]])])
    path = tmp_path / "flat.xdmf"  # keeps 2D points (VTU would pad them with zeros)
    meshio.write(path, m)
    with pytest.raises(MeshError, match=r"flat\.xdmf: nodes have 2 coordinates"):
        read_mesh(path)


# ------------------------------------------------------------------------------------------------
# element and node errors


def test_nan_coordinate_names_node(tmp_path):
    pts, tets = _two_tets()
    pts[3, 1] = np.nan
    path = tmp_path / "nan.vtu"
    meshio.write(path, meshio.Mesh(pts, [("tetra", tets)]))
    with pytest.raises(MeshError, match=r"nan\.vtu: node 3 \(0-based\) has non-finite") as err:
        read_mesh(path)
    assert "finite" in str(err.value)


def test_inf_coordinate_names_node(tmp_path):
    pts, tets = _two_tets()
    pts[4, 0] = np.inf
    path = tmp_path / "inf.mesh"
    meshio.write(path, meshio.Mesh(pts, [("tetra", tets)]))
    with pytest.raises(MeshError, match=r"inf\.mesh: node 4 \(0-based\)"):
        read_mesh(path)


@pytest.mark.parametrize("ext", [".vtu", ".mesh"])
def test_missing_node_names_cell_and_index(tmp_path, ext):
    pts, tets = _two_tets()
    tets[1, 3] = 7  # the file has 5 nodes
    path = tmp_path / f"dangling{ext}"
    meshio.write(path, meshio.Mesh(pts, [("tetra", tets)]))
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    msg = str(err.value)
    assert f"dangling{ext}" in msg
    assert "tetrahedron 1 (0-based" in msg and "node 7" in msg and "0..4" in msg


def test_missing_node_gmsh_is_wrapped(tmp_path):
    # meshio's gmsh reader itself fails on an undefined node tag: still a MeshError naming the file.
    pts, tets = _two_tets()
    path = tmp_path / "dangling.msh"
    path.write_text(
        "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n"
        + "".join(f"{i + 1} {p[0]} {p[1]} {p[2]}\n" for i, p in enumerate(pts[:4]))
        + "$EndNodes\n$Elements\n1\n1 4 2 0 1 1 2 3 9\n$EndElements\n"
    )
    with pytest.raises(MeshError, match=r"dangling\.msh"):
        read_mesh(path)


def test_degenerate_tet_names_element_and_volume(tmp_path):
    pts, tets = _two_tets()
    pts[4] = [0.5, 0.5, 0.0]  # coplanar with 1 and 2... and 3? make it exactly coplanar:
    pts[4] = (pts[1] + pts[2] + pts[3]) / 3.0  # on the face (1, 2, 3): volume 0
    path = tmp_path / "flat_tet.vtu"
    meshio.write(path, meshio.Mesh(pts, [("tetra", tets)]))
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    msg = str(err.value)
    assert "flat_tet.vtu" in msg and "tetrahedron 1 (0-based" in msg and "degenerate" in msg
    assert "volume" in msg and "non-coplanar" in msg


def test_repeated_node_is_degenerate(tmp_path):
    pts, tets = _two_tets()
    tets[0] = [0, 1, 1, 3]
    path = tmp_path / "rep.vtu"
    meshio.write(path, meshio.Mesh(pts, [("tetra", tets)]))
    with pytest.raises(MeshError, match=r"tetrahedron 0 \(0-based.*degenerate"):
        read_mesh(path)


def test_some_inverted_is_an_error(tmp_path):
    ref = box_mesh([1, 1, 1], [2, 1, 1])
    tets = ref.tets.copy()
    tets[[3, 8]] = tets[[3, 8]][:, [1, 0, 2, 3]]
    path = tmp_path / "twisted.vtu"
    meshio.write(path, meshio.Mesh(ref.points, [("tetra", tets)]))
    with pytest.raises(MeshError) as err:
        read_mesh(path)
    msg = str(err.value)
    assert "twisted.vtu" in msg and "2 of 12 tetrahedra are inverted" in msg
    assert "tetrahedra 3 (volume -" in msg and "8 (volume -" in msg and "0-based" in msg


def test_all_inverted_is_flipped_with_warning(tmp_path):
    ref = box_mesh([1, 1, 1], [2, 1, 1])
    path = tmp_path / "lefthanded.vtu"
    meshio.write(path, meshio.Mesh(ref.points, [("tetra", ref.tets[:, [1, 0, 2, 3]])]))
    with pytest.warns(MeshWarning, match=r"lefthanded\.vtu: all 12 tetrahedra are negatively"):
        mesh = read_mesh(path)
    assert np.all(signed_volumes(mesh.points, mesh.tets) > 0)
    np.testing.assert_array_equal(np.sort(mesh.tets, 1), np.sort(ref.tets, 1))


def test_overlapping_tets(tmp_path):
    pts, tets = _two_tets()
    pts = np.vstack([pts, [[1.2, 1.1, 0.9]]])
    tets = np.vstack([tets, [[1, 2, 3, 5]]])  # a third tet on face (1, 2, 3)
    path = tmp_path / "overlap.vtu"
    meshio.write(path, meshio.Mesh(pts, [("tetra", tets)]))
    with pytest.raises(MeshError, match=r"overlap\.vtu: the face with nodes \[1, 2, 3\]"):
        read_mesh(path)


def test_non_integer_tags(tmp_path):
    pts, tets = _two_tets()
    m = meshio.Mesh(pts, [("tetra", tets)], cell_data={"region": [np.array([1.0, 2.5])]})
    path = tmp_path / "floattags.vtu"
    meshio.write(path, m)
    with pytest.raises(MeshError, match=r"floattags\.vtu: cell data 'region'.*non-integer"):
        read_mesh(path)


def test_integral_float_tags_accepted(tmp_path):
    pts, tets = _two_tets()
    m = meshio.Mesh(pts, [("tetra", tets)], cell_data={"region": [np.array([1.0, 2.0])]})
    path = tmp_path / "floattags.vtu"
    meshio.write(path, m)
    mesh = _read_quiet(path)
    assert mesh.regions == {"group1": 1, "group2": 2}


# ------------------------------------------------------------------------------------------------
# warnings


def test_mixed_cells_warn_and_keep_facet_groups(tmp_path):
    ref = box_mesh([1, 1, 1], [1, 1, 1])
    bottom = boundary_facets(ref.tets)
    bottom = bottom[np.all(ref.points[bottom, 2] == 0, axis=1)]
    free_tris = np.array([[0, 1, 2], [1, 2, 3], [4, 5, 6]])
    cells = [
        ("vertex", np.array([[0]])),
        ("line", np.array([[0, 1], [1, 3]])),
        ("triangle", np.vstack([bottom, free_tris])),
        ("tetra", ref.tets),
    ]
    tags = [np.array([0]), np.array([0, 0]), np.array([7, 7, 0, 0, 0]), np.ones(6, int) * 5]
    m = meshio.Mesh(
        ref.points,
        cells,
        cell_data={"gmsh:physical": tags, "gmsh:geometrical": tags},
        field_data={"bottom": np.array([7, 2]), "solid": np.array([5, 3])},
    )
    path = tmp_path / "mixed.msh"
    meshio.write(path, m, file_format="gmsh22", binary=False)
    with pytest.warns(MeshWarning) as rec:
        mesh = read_mesh(path)
    msgs = [str(w.message) for w in rec]
    assert len(msgs) == 1, msgs
    msg = msgs[0]
    assert "mixed.msh: ignored 1 vertex, 2 line, 3 triangle cells" in msg
    assert "2 triangles in 2D physical groups 'bottom' are kept as facet groups" in msg
    assert mesh.regions == {"solid": 5}
    assert mesh.facet_groups["bottom"].shape == (2, 3)
    assert np.all(_normals(mesh.points, mesh.facet_groups["bottom"])[:, 2] < 0)


def test_tetra10_uses_corners_with_warning(tmp_path):
    ref = box_mesh([1, 1, 1], [1, 1, 1])
    # A tetra10 mesh with a separate mid-edge node per tetrahedron edge (enough for this test).
    edges = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])  # gmsh/VTK edge order
    mids = ref.points[ref.tets[:, edges]].mean(axis=2).reshape(-1, 3)
    pts = np.vstack([ref.points, mids])
    mid_idx = (len(ref.points) + np.arange(6 * ref.num_cells)).reshape(-1, 6)
    m = meshio.Mesh(pts, [("tetra10", np.hstack([ref.tets, mid_idx]))])
    path = tmp_path / "quadratic.vtu"
    meshio.write(path, m)
    with pytest.warns(MeshWarning) as rec:
        mesh = read_mesh(path)
    msgs = " | ".join(str(w.message) for w in rec)
    assert "6 quadratic tetrahedra (tetra10)" in msgs and "corner nodes" in msgs
    assert "dropped 36 node(s)" in msgs
    np.testing.assert_array_equal(mesh.points, ref.points)
    np.testing.assert_array_equal(mesh.tets, ref.tets)


def test_unreferenced_nodes_dropped_and_renumbered(tmp_path):
    ref = box_mesh([1, 1, 1], [1, 1, 1])
    extra = np.array([[5.0, 5, 5], [6.0, 6, 6], [7.0, 7, 7]])
    # Put unused nodes first and last, so every index shifts.
    pts = np.vstack([extra[:2], ref.points, extra[2:]])
    tets = ref.tets + 2
    top = boundary_facets(ref.tets)
    top = top[np.all(ref.points[top, 2] == 1, axis=1)] + 2
    tris = np.vstack([top, [[0, 2, 3]]])  # the last one touches dropped node 0
    tags = [np.array([4, 4, 4]), np.zeros(6, int)]
    m = meshio.Mesh(
        pts,
        [("triangle", tris), ("tetra", tets)],
        cell_data={"gmsh:physical": tags, "gmsh:geometrical": tags},
        field_data={"top": np.array([4, 2])},
    )
    path = tmp_path / "unused.msh"
    meshio.write(path, m, file_format="gmsh22", binary=False)
    with pytest.warns(MeshWarning) as rec:
        mesh = read_mesh(path)
    msg = " | ".join(str(w.message) for w in rec)
    assert "unused.msh: dropped 3 node(s) used by no tetrahedron" in msg
    assert "node 0, node 1, node 10" in msg
    assert "1 facet-group triangle(s) touching them were removed" in msg
    np.testing.assert_array_equal(mesh.points, ref.points)
    np.testing.assert_array_equal(mesh.tets, ref.tets)
    top_tris = mesh.facet_groups["top"]
    assert top_tris.shape == (2, 3) and top_tris.max() < mesh.num_points
    np.testing.assert_array_equal(mesh.points[top_tris, 2], 1.0)
    np.testing.assert_allclose(_normals(mesh.points, top_tris)[:, 2].sum(), 1.0)


def test_facet_triangle_not_a_face_warns(tmp_path):
    ref = box_mesh([1, 1, 1], [1, 1, 1])
    # (1, 2, 4) cuts through the cube but is no face; (0, 7, 1) is an interior face (kept as is).
    tris = np.array([[1, 2, 4], [0, 7, 1]])
    tags = [np.array([3, 3]), np.zeros(6, int)]
    m = meshio.Mesh(
        ref.points,
        [("triangle", tris), ("tetra", ref.tets)],
        cell_data={"gmsh:physical": tags, "gmsh:geometrical": tags},
        field_data={"cut": np.array([3, 2])},
    )
    path = tmp_path / "cut.msh"
    meshio.write(path, m, file_format="gmsh22", binary=False)
    with pytest.warns(
        MeshWarning, match=r"cut\.msh: facet group 'cut': 1 of 2 triangles.*triangles 0"
    ):
        mesh = read_mesh(path)
    np.testing.assert_array_equal(mesh.facet_groups["cut"], tris)


# ------------------------------------------------------------------------------------------------
# validate() on in-memory meshes


def test_validate_names_source_and_checks_facet_groups():
    pts, tets = _two_tets()
    mesh = Mesh(pts, tets, np.zeros(2, np.int64), {}, {"g": np.array([[0, 1, 9]])}, "here")
    with pytest.raises(MeshError, match=r"here: triangle 0 \(0-based, within facet group 'g'"):
        validate(mesh)


def test_validate_shape_errors():
    pts, tets = _two_tets()
    with pytest.raises(MeshError, match="integer array"):
        validate(Mesh(pts, tets.astype(float), np.zeros(2, np.int64)))
    with pytest.raises(MeshError, match=r"\(N, 3\)"):
        validate(Mesh(pts[:, :2], tets, np.zeros(2, np.int64)))
    with pytest.raises(MeshError, match="3 cell tags for 2 tetrahedra"):
        validate(Mesh(pts, tets, np.zeros(3, np.int64)))
    with pytest.raises(MeshError, match="no tetrahedra"):
        validate(Mesh(pts, np.zeros((0, 4), np.int64), np.zeros(0, np.int64)))


def test_validate_keeps_a_good_mesh():
    ref = box_mesh([1, 2, 3], [2, 2, 2])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = validate(ref)
    np.testing.assert_array_equal(out.points, ref.points)
    np.testing.assert_array_equal(out.tets, ref.tets)


# ------------------------------------------------------------------------------------------------
# box_mesh and boundary_facets


@pytest.mark.parametrize(
    "size,cells,origin",
    [([1, 1, 1], [1, 1, 1], (0, 0, 0)), ([0.4, 0.04, 0.04], [8, 2, 3], (0.1, -2, 5))],
)
def test_box_mesh_geometry(size, cells, origin):
    mesh = box_mesh(size, cells, origin)
    nx, ny, nz = cells
    assert mesh.points.shape == ((nx + 1) * (ny + 1) * (nz + 1), 3)
    assert mesh.tets.shape == (6 * nx * ny * nz, 4) and mesh.tets.dtype == np.int64
    np.testing.assert_array_equal(mesh.cell_tags, 0)
    assert mesh.regions == {} and mesh.facet_groups == {}
    np.testing.assert_allclose(mesh.points.min(0), origin)
    np.testing.assert_allclose(mesh.points.max(0), np.add(origin, size))

    vol = signed_volumes(mesh.points, mesh.tets)
    assert np.all(vol > 0)
    np.testing.assert_allclose(vol.sum(), np.prod(size), rtol=1e-12)

    # Conformity: every face is shared by 1 (boundary) or 2 (interior) tetrahedra, and the
    # boundary faces are exactly the 2 triangles per hexahedron face on the box surface.
    faces = np.sort(mesh.tets[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3), 1)
    _, counts = np.unique(faces, axis=0, return_counts=True)
    assert set(counts.tolist()) <= {1, 2}
    n_boundary = 4 * (nx * ny + ny * nz + nx * nz)
    assert np.count_nonzero(counts == 1) == n_boundary

    bf = boundary_facets(mesh.tets)
    assert bf.shape == (n_boundary, 3)
    n = _normals(mesh.points, bf)
    area = np.linalg.norm(n, axis=1)
    lx, ly, lz = size
    np.testing.assert_allclose(area.sum(), 2 * (lx * ly + ly * lz + lx * lz), rtol=1e-12)
    # Outward: each normal is axis-aligned and points away from the box centre on its side.
    centre = np.add(origin, np.divide(size, 2))
    c = mesh.points[bf].mean(axis=1) - centre
    axis = np.argmax(np.abs(n), axis=1)
    rows = np.arange(len(bf))
    np.testing.assert_allclose(np.abs(n[rows, axis]), area)
    assert np.all(np.sign(n[rows, axis]) == np.sign(c[rows, axis]))
    # Divergence theorem: sum of outward area vectors vanishes on a closed surface.
    np.testing.assert_allclose(n.sum(0), 0, atol=1e-12 * area.sum())


def test_box_mesh_is_valid():
    mesh = box_mesh([0.4, 0.04, 0.04], [10, 2, 2])
    assert mesh.source == "box(size=[0.4, 0.04, 0.04], cells=[10, 2, 2])"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        validate(mesh)


@pytest.mark.parametrize(
    "size,cells,match",
    [
        ([1, 1, 0], [1, 1, 1], "size must be 3 finite lengths > 0"),
        ([1, -1, 1], [1, 1, 1], "size must be 3 finite lengths > 0"),
        ([1, 1], [1, 1, 1], "size must be 3 finite lengths"),
        ([1, 1, float("nan")], [1, 1, 1], "size must be 3 finite lengths"),
        ("abc", [1, 1, 1], "size must be"),
        (5, [1, 1, 1], "size must be"),
        ([1, 1, 1], [1, 0, 1], "cells must be 3 integers >= 1"),
        ([1, 1, 1], [1, 1.5, 1], "cells must be 3 integers >= 1"),
        ([1, 1, 1], [1, 1, True], "cells must be 3 integers >= 1"),
        ([1, 1, 1], [2, 2], "cells must be 3 integers >= 1"),
    ],
)
def test_box_mesh_errors(size, cells, match):
    with pytest.raises(MeshError, match=match) as err:
        box_mesh(size, cells)
    assert str(err.value).startswith("box(")


def test_box_mesh_bad_origin():
    with pytest.raises(MeshError, match="origin must be 3 finite coordinates"):
        box_mesh([1, 1, 1], [1, 1, 1], origin=(0, 0, float("inf")))


def test_box_mesh_accepts_numpy_types():
    mesh = box_mesh(np.array([1.0, 2.0, 3.0]), np.array([1, 2, 3]))
    assert mesh.num_cells == 36


def test_boundary_facets_single_tet():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    tets = np.array([[0, 1, 2, 3]])
    bf = boundary_facets(tets)
    assert bf.shape == (4, 3)
    n = _normals(pts, bf)
    out = pts[bf].mean(1) - pts.mean(0)
    assert np.all(np.einsum("ij,ij->i", n, out) > 0)
    assert boundary_facets(np.zeros((0, 4), np.int64)).shape == (0, 3)


def test_boundary_facets_fast_enough():
    # vectorised: ~100k tetrahedra well under a second
    mesh = box_mesh([1, 1, 1], [20, 20, 40])
    bf = boundary_facets(mesh.tets)
    assert len(bf) == 4 * (400 + 800 + 800)


def test_unique_rows_matches_numpy():
    from petsoft.mesh.topology import unique_rows

    rows = np.random.default_rng(0).integers(0, 4, size=(500, 3))
    keys, inverse, counts = unique_rows(rows)
    k2, i2, c2 = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
    np.testing.assert_array_equal(keys, k2)
    np.testing.assert_array_equal(inverse, i2.reshape(-1))
    np.testing.assert_array_equal(counts, c2)
