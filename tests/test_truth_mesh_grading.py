"""The random cases' truth meshes are graded towards the clamped face's edges (issue 37;
scripts/benchmarks/independent/random_shapes.py, generate.py's ``clamp_edges``).

Uniform P2 truth meshes of a clamped bar converged at ~h^1.5 at its markers, because of the stress
singularity where the clamped face meets the free faces (scripts/benchmarks/realistic/README.md);
the truths' meshes are therefore refined there. Checked here with gmsh alone (no DOLFINx, no
petsoft): the curves found are the clamp face's whole boundary (their length is its perimeter,
computed from the drawn dimensions), and the graded mesh's nodes along them are about h / 4
(a bracket's h / 10) apart where the uniform mesh's are about h apart; the families with curved
faces get curved (second-order) cells with a positive Jacobian everywhere.
"""


import numpy as np
import pytest
from _independent import load

gmsh = pytest.importorskip("gmsh")

#: rank-local (gmsh in each process): once, serially
pytestmark = pytest.mark.serial_only



rd, rs = load("random_draw"), load("random_shapes")
indep = rs.indep        # the generate.py random_shapes uses


def perimeter(family: str, g: dict) -> float:
    """The clamp face's perimeter from the drawn dimensions (independent of gmsh)."""
    if family == "bar":
        return 2 * (g["width"] + g["height"])
    if family in ("bracket", "fillet"):
        return 4 * g["thickness"]
    if family == "plate":
        return 2 * (g["width"] + g["thickness"])
    if family == "shell":       # two arcs of radii R -/+ t/2 over the angle width / R, two sides
        return 2 * g["width"] + 2 * g["thickness"]
    raise ValueError(family)


@pytest.fixture(scope="module")
def session():
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    yield gmsh
    gmsh.finalize()


def spacing(gmsh, curves: list[int]) -> float:
    """The mean distance between consecutive mesh nodes along ``curves`` (their length over
    their segments)."""
    length = sum(gmsh.model.occ.getMass(1, c) for c in curves)
    segments = 0
    for c in curves:
        _, tags, _ = gmsh.model.mesh.getElements(1, c)
        segments += len(tags[0])
    return length / segments


@pytest.mark.parametrize("family", rd.FAMILIES)
def test_the_clamp_edges_are_found_and_graded(session, family):
    g = rd.draw_geometry(np.random.default_rng(3), family)
    h = rs.truth_h(g)
    axis = "xyz".index(g["axis"])
    spaced = {}
    for graded in (False, True):
        rs.mesh(session, family, g, h, graded=graded)
        curves = indep.clamp_edges(session, axis)
        # every curve lies in the clamp's plane, and together they are the face's boundary
        for c in curves:
            box = session.model.getBoundingBox(1, c)
            assert abs(box[axis]) < 1e-6 and abs(box[axis + 3]) < 1e-6
        total = sum(session.model.occ.getMass(1, c) for c in curves)
        assert total == pytest.approx(perimeter(family, g), rel=1e-6)
        spaced[graded] = spacing(session, curves)
        types = session.model.mesh.getElementTypes(3)
        if graded and family in rs.CURVED:
            # curved (10-node) tets, none turned inside out by the curving
            assert list(types) == [11]
            points, _ = session.model.mesh.getIntegrationPoints(11, "Gauss4")
            _, dets, _ = session.model.mesh.getJacobians(11, points)
            assert dets.min() > 0
        else:
            assert list(types) == [4]
        session.model.remove()
    # uniform: about h along the edges; graded: about h / finest (4; a bracket's 10), gmsh
    # meets sizes loosely
    finest = rs.GRADING.get(family, rs.GRADING["default"])[0]
    assert 0.6 * h < spaced[False] < 1.2 * h
    assert 0.6 * h / finest < spaced[True] < 1.4 * h / finest
    # gmsh's options are left as they were (the user's mesh made next is not graded)
    assert session.option.getNumber("Mesh.MeshSizeExtendFromBoundary") == 1
    assert session.option.getNumber("Mesh.MeshSizeFromPoints") == 1


def test_no_curve_in_the_plane_is_an_error(session):
    session.model.add("box")
    session.model.occ.addBox(0.01, 0.0, 0.0, 0.1, 0.02, 0.02)
    session.model.occ.synchronize()
    with pytest.raises(RuntimeError, match="no curve in the clamp's plane"):
        indep.clamp_edges(session, 0)
    session.model.remove()
