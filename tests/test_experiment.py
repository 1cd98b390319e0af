"""Tests of experiment loading, validation and writing (petsoft.experiment)."""

import copy
import pickle
from pathlib import Path

import numpy as np
import pytest
import tomllib

from petsoft.errors import ExperimentError, ExpressionError
from petsoft.experiment import (
    BoundarySpec,
    Experiment,
    MaterialSpec,
    dumps_toml,
    experiment_from_dict,
    get_parameter,
    load_experiment,
    parameter_names,
    with_parameters,
    write_toml,
)
from petsoft.experiment.expressions import Expression

# The full example of formats.md section 1, verbatim.
SPEC_EXAMPLE = """\
[mesh]
file = "meshes/bar.msh"          # any tetrahedral (or, for cloth, triangle) mesh meshio reads; path relative to this file
# or a built-in generator instead of a file:
# box = { size = [0.40, 0.04, 0.04], cells = [40, 4, 4] }
scale = 1.0                      # multiply coordinates by this to get metres

[material]                       # default for all cells; [material.<region>] overrides per region
model = "corotated"              # linear | stvk | corotated | neohookean
youngs_modulus = 1.0e6           # Pa, > 0
poisson_ratio = 0.45             # -1 < nu < 0.5
density = 1100.0                 # kg/m^3, > 0

[region.inclusion]               # named regions: a mesh physical group, or an expression (see below)
where = "(x - 0.3)**2 + (z - 0.02)**2 < 0.01**2"

[damping]
mass = 0.0                       # Rayleigh alpha, 1/s   (D = alpha M + beta K)
stiffness = 0.0                  # Rayleigh beta, s

[gravity]
acceleration = [0.0, 0.0, -9.81]

[[boundary]]
kind = "fixed"                   # fixed | prescribed | traction
where = "x < 1e-6"               # region name or expression (a face belongs when all its vertices do)
components = ["x", "y", "z"]     # optional: constrain only some components (rollers, symmetry, plane strain)
# kind = "prescribed": displacement = ["0", "0", "0.01*sin(20*t)"]   (expressions of x, y, z, t)
#                      or series = "inputs/shaker" (a measured input in the recording, see 2)
# kind = "traction":   value = [0, 0, -100.0]   (Pa, on the boundary faces inside `where`)

[initial]
displacement = ["0", "0", "0"]   # expressions of x, y, z; or from = "static" (equilibrium under the loads)
velocity = ["0", "0", "0"]

[time]
end = 2.0
step = 0.004
integrator = "be"                # be | si | alpha | midpoint | trapezoidal | ere | explicit | imex
alpha_radius = 0.5               # generalized-alpha spectral radius at infinity, 0 <= r <= 1

[output]
directory = "out"
every = 1                        # trajectory frames (XDMF + HDF5, ParaView-readable)
checkpoint_every = 50            # HDF5 checkpoints; restart with `petsoft simulate ... --restart`
probes = [[0.4, 0.02, 0.02]]     # reference-configuration points whose motion is reported

[petsc]                          # default PETSc options; the command line overrides them
ksp_type = "cg"
pc_type = "gamg"

[calibrate]                      # the unknowns: dotted key = [lower, upper]; start from the value above
"material.youngs_modulus" = [1.0e4, 1.0e8]
"damping.mass" = [0.0, 20.0]
"""  # noqa: E501

EXTRA_BOUNDARIES = """
[[boundary]]
kind = "prescribed"
where = "x > 0.4 - 1e-6"
components = ["z", "x"]
displacement = ["0", 0, "0.01*sin(20*t)"]

[[boundary]]
kind = "prescribed"
where = "clamp"
series = "inputs/shaker"

[[boundary]]
kind = "traction"
where = "inclusion"
value = [0, 0, "-100.0*t"]
"""


@pytest.fixture
def folder(tmp_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "bar.msh").write_text("placeholder: existence is all the loader checks")
    return tmp_path


def write(folder: Path, text: str, name: str = "exp.toml") -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


def base_dict() -> dict:
    """A small valid experiment as the dict tomllib would give."""
    return {
        "mesh": {"box": {"size": [0.4, 0.04, 0.04], "cells": [10, 2, 2]}},
        "material": {"youngs_modulus": 1e6, "poisson_ratio": 0.45, "density": 1100.0},
        "boundary": [{"kind": "fixed", "where": "x < 1e-6"}],
        "time": {"end": 1.0, "step": 0.01},
    }


def from_dict(data: dict, folder: Path = Path(".")) -> Experiment:
    return experiment_from_dict(data, source="exp.toml", base_dir=folder)


def error_of(data: dict, folder: Path = Path(".")) -> str:
    with pytest.raises(ExperimentError) as info:
        from_dict(data, folder)
    return str(info.value)


# --------------------------------------------------------------------------------------------
# Valid experiments


def test_spec_example_loads(folder):
    path = write(folder, SPEC_EXAMPLE)
    e = load_experiment(path)
    assert e.path == path.resolve() and e.source == str(path)
    assert e.format_version == 1
    assert e.mesh.file == (folder / "meshes" / "bar.msh").resolve() and e.mesh.file.is_absolute()
    assert e.mesh.box is None and e.mesh.scale == 1.0
    assert e.material == {
        "default": MaterialSpec(
            youngs_modulus=1e6, poisson_ratio=0.45, density=1100.0, model="corotated"
        )
    }
    assert e.material_for("anything") is e.material["default"]
    inc = e.regions["inclusion"]
    assert inc.name == "inclusion" and inc.where.is_boolean
    assert inc.where.variables == frozenset({"x", "z"})
    inside = inc.where.evaluate(x=np.array([0.3, 0.3]), y=0.0, z=np.array([0.02, 0.04]))
    assert inside.tolist() == [True, False]
    assert e.damping.mass == 0.0 and e.damping.stiffness == 0.0
    assert e.gravity.acceleration == (0.0, 0.0, -9.81)
    (b,) = e.boundaries
    assert b.kind == "fixed" and isinstance(b.where, Expression) and b.region is None
    assert b.components == ("x", "y", "z") and b.component_indices == (0, 1, 2)
    assert e.initial.from_ is None
    assert all(d.is_constant and d.constant_value == 0 for d in e.initial.displacement)
    assert e.time.end == 2.0 and e.time.step == 0.004 and e.time.num_steps == 500
    assert e.time.integrator == "be" and e.time.alpha_radius == 0.5
    assert e.output.directory == (folder / "out").resolve()
    assert e.output.every == 1 and e.output.checkpoint_every == 50
    assert e.output.probes == ((0.4, 0.02, 0.02),)
    assert e.petsc == {"ksp_type": "cg", "pc_type": "gamg"}
    assert e.calibrate == {"material.youngs_modulus": (1e4, 1e8), "damping.mass": (0.0, 20.0)}
    assert e.springs is None and not e.is_mass_spring
    assert e.masses == () and e.colliders == ()
    assert e.unresolved_regions == frozenset()


def test_spec_example_with_all_boundary_kinds(folder):
    e = load_experiment(write(folder, SPEC_EXAMPLE + EXTRA_BOUNDARIES))
    fixed, moving, shaker, traction = e.boundaries
    assert moving.kind == "prescribed" and moving.components == ("x", "z")  # canonical order
    assert moving.component_indices == (0, 2)
    d = moving.displacement
    assert [x.text for x in d] == ["0", "0", "0.01*sin(20*t)"]
    assert d[2].evaluate(t=0.1) == pytest.approx(0.01 * np.sin(2.0))
    assert shaker.series == "inputs/shaker" and shaker.displacement is None
    assert shaker.region == "clamp"
    assert traction.region == "inclusion" and traction.where == "inclusion"
    assert traction.value[2].evaluate(t=2.0) == -200.0
    # "clamp" is not a [region]: it must be a mesh physical group, checked with the mesh.
    assert e.unresolved_regions == frozenset({"clamp"})


def test_defaults_of_absent_sections():
    e = from_dict(
        {
            "mesh": {"box": {"size": [1, 1, 1], "cells": [1, 1, 1]}},
            "material": {"youngs_modulus": 1e5, "poisson_ratio": 0.3, "density": 1000},
        }
    )
    assert e.material["default"].model == "linear"
    assert e.gravity.acceleration == (0.0, 0.0, 0.0)
    assert e.damping.mass == 0.0 and e.boundaries == () and e.time is None
    assert e.output.every == 1 and e.output.checkpoint_every == 0 and e.output.probes == ()
    assert e.output.directory == (Path(".").resolve() / "out")
    assert e.petsc == {} and e.calibrate == {} and e.regions == {}
    assert e.mesh.box.size == (1.0, 1.0, 1.0) and e.mesh.box.cells == (1, 1, 1)
    assert isinstance(e.mesh.box.size[0], float) and isinstance(e.mesh.box.cells[0], int)


def test_material_region_overrides():
    data = base_dict()
    data["material"]["model"] = "corotated"
    data["material"]["inclusion"] = {"youngs_modulus": 5e6, "model": "neohookean"}
    data["material"]["glue"] = {}
    data["region"] = {"inclusion": {"where": "x < 0.1"}}
    e = from_dict(data)
    inc = e.material["inclusion"]
    assert inc.youngs_modulus == 5e6 and inc.model == "neohookean"
    assert inc.poisson_ratio == 0.45 and inc.density == 1100.0
    assert inc.overrides == frozenset({"youngs_modulus", "model"})
    assert e.material["glue"].youngs_modulus == 1e6 and e.material["glue"].overrides == frozenset()
    assert e.unresolved_regions == frozenset({"glue"})
    lam, mu = e.material["default"].lame
    assert mu == pytest.approx(1e6 / 2.9) and lam == pytest.approx(1e6 * 0.45 / (1.45 * 0.1))


def test_where_region_name_or_expression():
    data = base_dict()
    data["boundary"] = [
        {"kind": "fixed", "where": "left_end"},
        {"kind": "fixed", "where": " x < 0 "},
        {"kind": "fixed", "where": "x < 1 and y > 0"},
    ]
    e = from_dict(data)
    assert e.boundaries[0].where == "left_end" and e.boundaries[0].region == "left_end"
    assert isinstance(e.boundaries[1].where, Expression)
    assert isinstance(e.boundaries[2].where, Expression)
    # A bare variable is an expression, and not a condition.
    data["boundary"] = [{"kind": "fixed", "where": "x"}]
    message = error_of(data)
    assert "boundary[0].where" in message and "expected a condition" in message


def test_initial_from_static():
    data = base_dict()
    data["initial"] = {"from": "static", "velocity": ["0", "0", "0.1*x"]}
    e = from_dict(data)
    assert e.initial.from_ == "static"
    assert e.initial.velocity[2].evaluate(x=2.0) == pytest.approx(0.2)


def test_petsc_values_become_strings():
    data = base_dict()
    data["petsc"] = {
        "ksp_type": "cg",
        "-ksp_rtol": 1e-8,
        "ksp_max_it": 200,
        "ksp_monitor": True,
        "snes_lag_jacobian_persists": False,
        "da_grid_x": [1, 2, 3],
    }
    e = from_dict(data)
    assert e.petsc == {
        "ksp_type": "cg",
        "ksp_rtol": "1e-08",
        "ksp_max_it": "200",
        "ksp_monitor": "",
        "snes_lag_jacobian_persists": "false",
        "da_grid_x": "1,2,3",
    }


def test_calibrate_dotted_and_nested_keys(folder):
    text = SPEC_EXAMPLE.replace(
        '"damping.mass" = [0.0, 20.0]',
        'damping.stiffness = [0.0, 0.1]\n"material.inclusion.density" = [500, 2000]',
    )
    e = load_experiment(write(folder, text))
    assert e.calibrate == {
        "material.youngs_modulus": (1e4, 1e8),
        "damping.stiffness": (0.0, 0.1),
        "material.inclusion.density": (500.0, 2000.0),
    }


def test_mass_spring_model():
    data = {
        "mesh": {"box": {"size": [1, 1, 1], "cells": [2, 2, 2]}},
        "springs": {"stiffness": 100.0, "damping": 0.5, "bending": 0.01, "pairs": [[0, 1], [1, 2]]},
        "mass": [{"at": [0, 0, 0], "value": 0.1}, {"at": [1, 1, 1], "value": 2}],
        "collider": [
            {"kind": "sphere", "center": [0.5, 0.5, -1], "radius": 0.5, "friction": 0.3},
            {"kind": "plane", "point": [0, 0, -2], "normal": [0, 0, 2], "stiffness": 1e4},
        ],
        "calibrate": {"springs.stiffness": [1, 1000]},
    }
    e = from_dict(data)
    assert e.is_mass_spring and e.material == {}
    assert e.springs.stiffness == 100.0 and e.springs.pairs == ((0, 1), (1, 2))
    assert e.springs.node_mass == 0.0
    assert [m.value for m in e.masses] == [0.1, 2.0] and e.masses[1].at == (1.0, 1.0, 1.0)
    sphere, plane = e.colliders
    assert sphere.radius == 0.5 and sphere.friction == 0.3 and sphere.stiffness is None
    assert plane.normal == (0.0, 0.0, 1.0) and plane.stiffness == 1e4
    assert "springs.stiffness" in parameter_names(e)
    assert "material.youngs_modulus" not in parameter_names(e)


def test_format_version_accepted():
    data = base_dict()
    data["format_version"] = 1
    assert from_dict(data).format_version == 1


# --------------------------------------------------------------------------------------------
# Errors


def test_toml_syntax_error_gives_line_and_column(folder):
    path = write(folder, '[mesh]\nfile = "meshes/bar.msh"\nscale = = 2\n')
    with pytest.raises(ExperimentError) as info:
        load_experiment(path)
    message = str(info.value)
    assert str(path) in message
    assert "line 3" in message and "column" in message
    assert "scale = = 2" in message  # the offending line is quoted


def test_missing_and_unreadable_files(folder):
    with pytest.raises(ExperimentError, match="experiment file not found"):
        load_experiment(folder / "nope.toml")
    with pytest.raises(ExperimentError, match="directory"):
        load_experiment(folder)
    bad = folder / "latin1.toml"
    bad.write_bytes('a = "\xe9"\n'.encode("latin-1"))
    with pytest.raises(ExperimentError, match="UTF-8"):
        load_experiment(bad)


def test_missing_mesh_file_is_reported(folder):
    path = write(folder, SPEC_EXAMPLE.replace("meshes/bar.msh", "meshes/missing.msh"))
    with pytest.raises(ExperimentError) as info:
        load_experiment(path)
    message = str(info.value)
    assert str(path) in message and "mesh.file" in message and "missing.msh" in message
    assert "does not exist" in message and str(folder.resolve()) in message


def test_relative_paths_are_relative_to_the_file_not_the_cwd(folder, monkeypatch):
    sub = folder / "experiments"
    sub.mkdir()
    path = write(sub, SPEC_EXAMPLE.replace("meshes/bar.msh", "../meshes/bar.msh"))
    monkeypatch.chdir("/")
    e = load_experiment(path)
    assert e.mesh.file == (folder / "meshes" / "bar.msh").resolve()
    assert e.output.directory == (sub / "out").resolve()


def modify(path: str, value):
    """A copy of base_dict() with ``path`` (dotted, list indices as ints) set to value (or
    deleted when value is DELETE)."""
    data = base_dict()
    keys = path.split(".")
    node = data
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node.setdefault(k, {})
    last = int(keys[-1]) if isinstance(node, list) else keys[-1]
    if value is DELETE:
        del node[last]
    else:
        node[last] = value
    return data


DELETE = object()

# (dotted path to modify, new value, substrings the message must contain)
INVALID = [
    # unknown keys: file + dotted key + suggestion + valid keys
    ("materail", {}, ["exp.toml", "unknown key materail", "did you mean material", "mesh,"]),
    ("material.youngs_modulu", 1.0, ["material.youngs_modulu", "material.youngs_modulus?",
                                     "model, youngs_modulus"]),
    ("mesh.scal", 1.0, ["mesh.scal", "did you mean mesh.scale", "file, box, scale"]),
    ("time.stepp", 1.0, ["time.stepp", "did you mean time.step"]),
    ("damping.mas", 1.0, ["damping.mas", "did you mean damping.mass"]),
    ("boundary.0.wher", "x < 0", ["boundary[0].wher", "did you mean boundary[0].where"]),
    ("mesh.box.size_", 1, ["mesh.box.size_", "size, cells"]),
    # out of range: file, key, value, valid range
    ("material.youngs_modulus", 0.0, ["exp.toml", "material.youngs_modulus = 0.0",
                                      "youngs_modulus > 0"]),
    ("material.youngs_modulus", -5, ["material.youngs_modulus = -5", "> 0"]),
    ("material.poisson_ratio", 0.5, ["material.poisson_ratio = 0.5",
                                     "-1 < poisson_ratio < 0.5"]),
    ("material.poisson_ratio", -1.0, ["material.poisson_ratio = -1.0", "-1 < poisson_ratio"]),
    ("material.density", 0, ["material.density = 0", "density > 0"]),
    ("damping.mass", -0.1, ["damping.mass = -0.1", "mass >= 0"]),
    ("damping.stiffness", -1, ["damping.stiffness = -1", "stiffness >= 0"]),
    ("time.step", 0.0, ["time.step = 0.0", "step > 0"]),
    ("time.end", -1.0, ["time.end = -1.0", "end > 0"]),
    ("time.step", 2.0, ["time.step = 2.0", "larger than time.end"]),
    ("time.alpha_radius", 1.5, ["time.alpha_radius = 1.5", "0 <= alpha_radius <= 1"]),
    ("time.alpha_radius", -0.1, ["time.alpha_radius = -0.1", "0 <= alpha_radius <= 1"]),
    ("output.every", 0, ["output.every = 0", "every >= 1"]),
    ("output.checkpoint_every", -1, ["output.checkpoint_every = -1", ">= 0"]),
    ("mesh.box.size", [0.4, 0, 0.04], ["mesh.box.size[1] = 0", "> 0"]),
    ("mesh.box.cells", [10, 0, 2], ["mesh.box.cells[1] = 0", ">= 1"]),
    ("mesh.scale", 0, ["mesh.scale = 0", "scale > 0"]),
    ("material.youngs_modulus", float("nan"), ["material.youngs_modulus = nan", "finite"]),
    ("material.density", float("inf"), ["material.density = inf", "finite"]),
    # wrong types: file, key, value, expected type
    ("material.youngs_modulus", "1e6", ['material.youngs_modulus = "1e6"', "expected a number",
                                        "got a string"]),
    ("material.density", True, ["material.density = true", "expected a number", "boolean"]),
    ("output.every", 1.5, ["output.every = 1.5", "expected an integer"]),
    ("mesh.box.cells", [10, 2.5, 2], ["mesh.box.cells[1] = 2.5", "expected an integer"]),
    ("mesh.box.cells", [10, 2], ["mesh.box.cells = [10, 2] has 2 entries", "3 integers"]),
    ("mesh.box.size", [1, 1], ["mesh.box.size = [1, 1]", "has 2 entries", "3 numbers"]),
    ("gravity.acceleration", "down", ['gravity.acceleration = "down"', "array of 3 numbers"]),
    ("gravity.acceleration", [0, 0, "g"], ['gravity.acceleration[2] = "g"', "a number"]),
    ("output.probes", [[0, 0]], ["output.probes[0] = [0, 0]", "3 numbers"]),
    ("output.probes", 1.0, ["output.probes = 1.0", "array of points"]),
    ("mesh", 3, ["mesh = 3", "expected a table"]),
    ("boundary", {"kind": "fixed", "where": "x < 0"}, ["boundary", "[[boundary]]"]),
    ("boundary", [1, 2], ["boundary = [1, 2]", "array of tables"]),
    ("time.end", "2 s", ['time.end = "2 s"', "a number"]),
    # enumerations list the valid choices
    ("material.model", "neo-hookean", ['material.model = "neo-hookean"',
                                       'did you mean "neohookean"',
                                       '"linear", "stvk", "corotated", "neohookean"']),
    ("time.integrator", "rk4", ['time.integrator = "rk4"', '"be", "si", "alpha"', '"imex"']),
    ("boundary.0.kind", "clamped", ['boundary[0].kind = "clamped"',
                                    '"fixed", "prescribed", "traction"']),
    ("boundary.0.components", ["x", "w"], ['boundary[0].components[1] = "w"', '"x", "y", "z"']),
    ("boundary.0.components", [], ["boundary[0].components = [] is empty"]),
    ("boundary.0.components", ["x", "x"], ["boundary[0].components", "repeats"]),
    ("boundary.0.components", "x", ['boundary[0].components = "x"', "array"]),
    ("initial", {"from": "rest"}, ['initial.from = "rest"', '"static"']),
    # structure
    ("mesh", {}, ["[mesh] needs exactly one of file", "neither"]),
    ("mesh.file", "meshes/bar.msh", ["[mesh] needs exactly one of file", "both"]),
    ("mesh", DELETE, ["mesh is missing", "box ="]),
    ("material", DELETE, ["the model is missing", "[material]", "[springs]"]),
    ("springs", {"stiffness": 1.0}, ["both [material] and [springs]"]),
    ("material.youngs_modulus", DELETE, ["material.youngs_modulus is missing", "Pa, "]),
    ("material.default", {}, ["material.default", "reserved"]),
    ("material.inclusion", {"youngs": 1}, ["material.inclusion.youngs",
                                           "did you mean material.inclusion.youngs_modulus"]),
    ("material.inclusion", {"density": -1}, ["material.inclusion.density = -1", "> 0"]),
    ("material.inclusion", {"sub": {}}, ["material.inclusion.sub is a table"]),
    ("material.youngs_modulus", {"a": 1}, ["material.youngs_modulus", "expected a number"]),
    ("time.end", DELETE, ["time.end is missing"]),
    ("time.step", DELETE, ["time.step is missing"]),
    ("format_version", 2, ["format_version = 2", "format_version = 1"]),
    ("format_version", "1", ['format_version = "1"', "integer"]),
    # boundaries: exactly the keys valid for each kind
    ("boundary.0.value", [0, 0, 1], ["boundary[0].value", 'kind = "fixed"',
                                     'belongs to kind = "traction"', "kind, where, components"]),
    ("boundary.0.displacement", ["0", "0", "0"], ["boundary[0].displacement",
                                                  'belongs to kind = "prescribed"']),
    ("boundary.0.where", DELETE, ["boundary[0].where is missing"]),
    ("boundary.0.where", 1.0, ["boundary[0].where = 1.0", "expected a region name"]),
    ("boundary.0.kind", DELETE, ["boundary[0].kind is missing", '"fixed"']),
    ("boundary.0.kind", "prescribed", ["boundary[0]", "exactly one of displacement", "series",
                                       "neither"]),
    ("boundary.0.kind", "traction", ["boundary[0].value is missing", "x, y, z, t"]),
    # regions
    ("region.x", {"where": "y < 0"}, ["region.x", "identifier"]),
    ("region.my-region", {"where": "y < 0"}, ["region.my-region:", "identifier"]),
    ("region.my region", {"where": "y < 0"}, ['region."my region":', "identifier"]),
    ("region.True", {"where": "y < 0"}, ["region.True:", "identifier"]),
    ("boundary.0.where", "True", ["boundary[0].where", "True", "not allowed"]),
    ("region.inc", "x < 0", ['region.inc = "x < 0"', "[region.inc]"]),
    ("region.inc", {}, ["region.inc.where is missing"]),
    ("region.inc", {"where": "x < 0", "were": 1}, ["region.inc.were", "did you mean"]),
    # springs, masses, colliders
    ("mass", [{"at": [0, 0, 0], "value": 0}], ["mass[0].value = 0", "value > 0"]),
    ("mass", [{"at": [0, 0], "value": 1}], ["mass[0].at = [0, 0]", "3 numbers"]),
    ("mass", [{"value": 1}], ["mass[0].at is missing"]),
    ("collider", [{"kind": "cube"}], ['collider[0].kind = "cube"', '"sphere", "plane"']),
    ("collider", [{"kind": "sphere", "center": [0, 0, 0], "radius": 0}],
     ["collider[0].radius = 0", "radius > 0"]),
    ("collider", [{"kind": "sphere", "center": [0, 0, 0], "radius": 1, "normal": [0, 0, 1]}],
     ["collider[0].normal", 'kind = "sphere"']),
    ("collider", [{"kind": "plane", "point": [0, 0, 0], "normal": [0, 0, 0]}],
     ["collider[0].normal", "non-zero"]),
    ("collider", [{"kind": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "friction": -1}],
     ["collider[0].friction = -1", ">= 0"]),
    # petsc
    ("petsc", {"ksp": {"type": "cg"}}, ["petsc.ksp", "flat"]),
    ("petsc", {"ksp type": "cg"}, ['petsc."ksp type"', "PETSc option name"]),
    ("petsc", {"ksp_rtol": float("nan")}, ["petsc.ksp_rtol = nan", "finite"]),
    ("petsc", {"ksp_type": "cg", "-ksp_type": "gmres"}, ["given twice"]),
    # calibrate
    ("calibrate", {"material.youngs": [1, 2]}, ['"material.youngs"', "not a numeric parameter",
                                                'did you mean "material.youngs_modulus"']),
    ("calibrate", {"material.youngs_modulus": [1e7, 1e5]}, ["material.youngs_modulus",
                                                            "lower < upper"]),
    ("calibrate", {"material.youngs_modulus": [1e7, 1e8]}, ["current value",
                                                            "outside the bounds"]),
    ("calibrate", {"material.youngs_modulus": [0, 1e8]}, ["bound 0.0", "youngs_modulus > 0"]),
    ("calibrate", {"material.poisson_ratio": [0.1, 0.5]}, ["bound 0.5", "poisson_ratio < 0.5"]),
    ("calibrate", {"damping.mass": [-1, 1]}, ["bound -1.0", "mass >= 0"]),
    ("calibrate", {"damping.mass": 3.0}, ['calibrate."damping.mass" = 3.0', "[lower, upper]"]),
    ("calibrate", {"damping.mass": [0, "a"]}, ['bound "a"', "finite number"]),
    ("calibrate", {"material.blob.density": [1, 2000]}, ["material.blob.density",
                                                         "add an empty [material.blob]"]),
    ("calibrate", {"springs.stiffness": [1, 2]}, ['"springs.stiffness"',
                                                  "not a numeric parameter"]),
]  # fmt: skip


@pytest.mark.parametrize(
    "path, value, expected", INVALID,
    # ids stable across processes (pytest-xdist workers must collect the same names)
    ids=[(f"{p} deleted" if v is DELETE else f"{p}={v!r}")[:60] for p, v, _ in INVALID]
)
def test_invalid_experiments_are_explained(path, value, expected):
    message = error_of(modify(path, value))
    assert message.startswith("exp.toml:"), message
    for fragment in expected:
        assert fragment in message, f"{fragment!r} not in {message!r}"


@pytest.mark.parametrize(
    "path, value, token",
    [
        ("boundary.0.where", "x.__class__", "x.__class__"),
        ("boundary.0.where", "__import__('os')", "__import__"),
        ("boundary.0.where", "x < t", "`t`"),
        ("region", {"inc": {"where": "sqrt(y) + open('f')"}}, "open"),
        ("region", {"inc": {"where": "z"}}, "expected a condition"),
        ("initial", {"displacement": ["0", "0", "t"]}, "`t`"),
        ("initial", {"velocity": ["0", "0"]}, "has 2 entries"),
        ("boundary", [{"kind": "prescribed", "where": "x < 0",
                       "displacement": ["0", "0", "sin(20*t"]}], "syntax error"),
        ("boundary", [{"kind": "traction", "where": "x < 0", "value": [0, 0, "x < 1"]}],
         "expected a number-valued"),
        ("boundary", [{"kind": "traction", "where": "x < 0", "value": [0, 0, True]}],
         "expected an expression"),
    ],
)  # fmt: skip
def test_invalid_expressions_name_file_and_key(path, value, token):
    data = modify(path, value)
    with pytest.raises(ExperimentError) as info:
        from_dict(data)
    message = str(info.value)
    assert message.startswith("exp.toml:") and token in message
    key = {
        "boundary": "boundary[0].",
        "region": "region.inc.where",
        "initial": "initial.",
    }[path.split(".")[0]]
    assert key in message
    if "entries" not in token:
        assert isinstance(info.value, ExpressionError)


def test_error_from_a_file_names_the_file(folder):
    path = write(folder, SPEC_EXAMPLE.replace("poisson_ratio = 0.45", "poisson_ratio = 0.6"))
    with pytest.raises(ExperimentError) as info:
        load_experiment(path)
    message = str(info.value)
    assert message.startswith(str(path) + ":")
    assert "material.poisson_ratio = 0.6" in message and "< 0.5" in message


# --------------------------------------------------------------------------------------------
# Round trip and parameters


def full_dict() -> dict:
    data = base_dict()
    data["format_version"] = 1
    data["material"]["inclusion"] = {"youngs_modulus": 2e6}
    data["material"]["mesh group"] = {}
    data["region"] = {"inclusion": {"where": "(x - 0.3)**2 + (z - 0.02)**2 < 0.01**2"}}
    data["damping"] = {"mass": 0.5, "stiffness": 1e-4}
    data["gravity"] = {"acceleration": [0.0, 0.0, -9.81]}
    data["boundary"] = [
        {"kind": "fixed", "where": "x < 1e-6", "components": ["y", "x"]},
        {"kind": "prescribed", "where": "x > 0.4 - 1e-6", "displacement": [0, "0", "1e-2*t"]},
        {"kind": "prescribed", "where": "inclusion", "series": 'inputs/"odd" \\ name'},
        {"kind": "traction", "where": "mesh_top", "value": [0, 0.5, "-100*sin(t)"]},
    ]
    data["initial"] = {"from": "static", "velocity": ["0", "0", "0.1*x"]}
    data["time"] = {"end": 2.0, "step": 0.004, "integrator": "alpha", "alpha_radius": 0.3}
    data["output"] = {"directory": "results/run 1", "every": 5, "checkpoint_every": 50,
                      "probes": [[0.4, 0.02, 0.02], [0.2, 0.0, 0.0]]}  # fmt: skip
    data["petsc"] = {"ksp_type": "cg", "ksp_rtol": 1e-10, "ksp_monitor": True}
    data["calibrate"] = {"material.youngs_modulus": [1e4, 1e8], "damping.mass": [0.0, 20.0]}
    data["mass"] = [{"at": [0.4, 0.02, 0.02], "value": 0.01}]
    data["collider"] = [{"kind": "plane", "point": [0, 0, -0.1], "normal": [0, 0, 1]}]
    return data


def test_round_trip_to_dict():
    e = from_dict(full_dict())
    again = from_dict(e.to_dict())
    assert again == e
    assert again.to_dict() == e.to_dict()
    assert e.boundaries[1].displacement[0].literal == 0  # numbers stay numbers


def test_round_trip_write_toml(folder):
    e = experiment_from_dict(full_dict(), source="exp.toml", base_dir=folder)
    out = folder / "calibrated" / "exp.toml"
    out.parent.mkdir()
    write_toml(e, out)
    text = out.read_text()
    assert "file" not in text.split("[mesh]")[1].split("[")[0] or "../" in text
    loaded = load_experiment(out)
    assert loaded == e
    assert loaded.output.directory == (folder / "results" / "run 1").resolve()
    # The written file is plain TOML with relative paths.
    assert tomllib.loads(text)["output"]["directory"] == "../results/run 1"


def test_round_trip_spec_example_and_mesh_file(folder):
    e = load_experiment(write(folder, SPEC_EXAMPLE + EXTRA_BOUNDARIES))
    out = folder / "copy.toml"
    write_toml(e, out)
    assert tomllib.loads(out.read_text())["mesh"]["file"] == "meshes/bar.msh"
    assert load_experiment(out) == e


def test_round_trip_mass_spring(folder):
    data = {
        "mesh": {"box": {"size": [1, 1, 1], "cells": [2, 2, 2]}, "scale": 0.001},
        "springs": {"stiffness": 100.0, "bending": 0.01, "pairs": [[0, 1]], "node_mass": 0.2},
        "collider": [{"kind": "sphere", "center": [0, 0, 0], "radius": 1.0, "friction": 0.1}],
    }
    e = experiment_from_dict(data, source="s.toml", base_dir=folder)
    write_toml(e, folder / "s.toml")
    assert load_experiment(folder / "s.toml") == e


def test_dumps_toml_is_valid_toml():
    data = {
        "top": 1,
        "s": 'quote " backslash \\ tab \t newline \n unicode é \x01',
        "t": {"a": [1, 2.5, True], "nested": {"deep": [[1, 2], [3, 4]]}, "empty": {}},
        "key with space": {"k": "v"},
        "arr": [{"x": 1}, {"x": 2, "sub": {"y": 3}}],
        "floats": [1e-300, 1.5e300, 0.1, -0.0, 123456789.0],
    }
    assert tomllib.loads(dumps_toml(data)) == data


def test_parameters_and_with_parameters():
    e = from_dict(full_dict())
    names = parameter_names(e)
    for n in [
        "material.youngs_modulus",
        "material.poisson_ratio",
        "material.density",
        "material.inclusion.youngs_modulus",
        'material."mesh group".density',
        "damping.mass",
        "damping.stiffness",
        "gravity.acceleration.z",
    ]:
        assert n in names
    assert get_parameter(e, "material.inclusion.youngs_modulus") == 2e6
    assert get_parameter(e, "gravity.acceleration.z") == -9.81
    e2 = with_parameters(
        e,
        {
            "material.youngs_modulus": 3e6,
            "material.density": 900.0,
            'material."mesh group".poisson_ratio': 0.3,
            "damping.mass": 1.5,
            "gravity.acceleration.z": -9.7,
        },
    )
    # Regions follow the default unless they override the key.
    assert e2.material["default"].youngs_modulus == 3e6
    assert e2.material["inclusion"].youngs_modulus == 2e6
    assert e2.material["inclusion"].density == 900.0
    assert e2.material["mesh group"].poisson_ratio == 0.3
    assert e2.material["mesh group"].youngs_modulus == 3e6
    assert e2.damping.mass == 1.5 and e2.gravity.acceleration == (0.0, 0.0, -9.7)
    assert e == from_dict(full_dict())  # the original is unchanged
    with pytest.raises(ExperimentError, match="not a numeric parameter"):
        with_parameters(e, {"material.stiffness": 1.0})
    with pytest.raises(ExperimentError, match="poisson_ratio = 0.7"):
        with_parameters(e, {"material.poisson_ratio": 0.7})
    with pytest.raises(ExperimentError, match="did you mean"):
        get_parameter(e, "damping.mas")


def test_region_parameter_from_a_region_table_without_override():
    data = full_dict()
    data["region"]["core"] = {"where": "x < 0.2"}
    data["calibrate"]["material.core.youngs_modulus"] = [1e5, 1e7]
    e = from_dict(data)
    assert get_parameter(e, "material.core.youngs_modulus") == 1e6
    e2 = with_parameters(e, {"material.core.youngs_modulus": 4e6})
    assert e2.material["core"].youngs_modulus == 4e6
    assert e2.material["core"].overrides == frozenset({"youngs_modulus"})


def test_experiment_is_frozen_and_picklable():
    e = from_dict(full_dict())
    with pytest.raises(AttributeError):
        e.time = None
    e2 = pickle.loads(pickle.dumps(e))
    assert e2 == e
    assert isinstance(e2.boundaries[0], BoundarySpec)


def test_from_dict_does_not_modify_its_input():
    data = full_dict()
    before = copy.deepcopy(data)
    from_dict(data)
    assert data == before
