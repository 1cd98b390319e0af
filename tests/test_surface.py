"""The surface rule of a mass-spring body (petsoft.experiment.surface): one home, two callers.

The experiment reader (which reads the mesh file) and the model builder (which may be handed the
mesh) decide with the same rule whether the body has a surface a drag can act through, refuse a
drag on one without in the same words, and the drag the builder's system applies acts through
exactly the faces the rule names (``SpringMesh.surface``): on a cloth (triangles), a mesh of
triangles and lines, and a rope (lines only: none). Collective (1 or 2 ranks).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from petsoft.dynamics.mass_spring import (
    MassSpringSystem,
    build_mass_spring_model,
    cloth_mesh,
    rope_mesh,
)
from petsoft.errors import ExperimentError
from petsoft.experiment import DragSpec, experiment_from_dict
from petsoft.mesh.springs import SpringMesh, write_spring_mesh
from petsoft.physics.drag import face_pairs, linear_blocks


def _cloth_with_a_tail() -> SpringMesh:
    """A cloth and a rope of two lines hanging from its last node: triangles and lines."""
    cloth = cloth_mesh(4, 3, 1.0, 0.6)
    n = len(cloth.points)
    tail = cloth.points[-1] + np.array([[0.2, 0.0, 0.0], [0.4, 0.0, 0.0]])
    return SpringMesh(np.vstack([cloth.points, tail]), np.array([[n - 1, n], [n, n + 1]]),
                      cloth.triangles, source="<cloth with a tail>")


MESHES = {"cloth": lambda: cloth_mesh(4, 3, 1.0, 0.6), "cloth with a tail": _cloth_with_a_tail,
          "rope": lambda: rope_mesh(4, 1.0)}


@pytest.mark.parametrize("name", list(MESHES))
def test_the_reader_and_the_builder_take_the_same_surface(tmp_path, name):
    mesh = MESHES[name]()
    path = tmp_path / "body.vtu"
    write_spring_mesh(path, mesh.points, mesh.lines, mesh.triangles)
    base = {"mesh": {"file": str(path)}, "springs": {"stiffness": 10.0, "node_mass": 0.1},
            "boundary": [{"kind": "fixed", "where": "x < 0.1"}]}
    np.testing.assert_array_equal(mesh.surface, mesh.triangles)
    has_surface = len(mesh.surface) > 0
    assert has_surface == (name != "rope")
    # the reader: the drag accepted where the mesh has a surface
    with_drag = {**base, "drag": {"linear": 0.5}}
    if has_surface:
        experiment_from_dict(with_drag, source="body.toml")
    else:
        with pytest.raises(ExperimentError, match="drag needs a surface") as reader:
            experiment_from_dict(with_drag, source="body.toml")
    # the builder, handed the mesh, the drag set after reading: the same decision and words
    exp = dataclasses.replace(experiment_from_dict(base, source="body.toml"),
                              drag=DragSpec(linear=0.5))
    if not has_surface:
        with pytest.raises(ExperimentError) as builder:
            build_mass_spring_model(exp, mesh=mesh)
        assert str(builder.value) == str(reader.value).replace(str(path), mesh.source)
        return
    s = MassSpringSystem(build_mass_spring_model(exp, mesh=mesh), 0.0, 0.0)
    try:
        # the drag acts through the rule's faces: S_i of the owned nodes from those faces
        lo, hi = s.node_range
        node_of = np.full(len(mesh.points), -1, dtype=np.int64)
        node_of[lo:hi] = np.arange(hi - lo)
        want = linear_blocks(*face_pairs(mesh.points, mesh.surface, node_of), hi - lo)
        v = np.random.default_rng(0).standard_normal((hi - lo, 3))
        np.testing.assert_array_equal(s.velocity_terms.unit_blocks("drag.linear", v), want)
        assert s.velocity_terms.has_surface and "drag.linear" in s.parameter_names()
    finally:
        s.destroy()
