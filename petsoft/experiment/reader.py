"""Reading experiment files: loading and strict validation (formats.md section 1).

This module owns the way from TOML to :class:`~petsoft.experiment.spec.Experiment`:
:func:`load_experiment` (from a file) and :func:`experiment_from_dict` (from an already parsed
dict, for embedded defaults, tests and :mod:`petsoft.experiment.changes`), the reading of every
section with its defaults and checks, and the decisions below.

Validation is strict, and every error is an :class:`~petsoft.errors.ExperimentError` whose message
names the file, the dotted key, the value and what would be valid: TOML syntax errors give the line
and column; unknown keys get a "did you mean" and the list of valid keys; numbers are checked
against their physical range; enumerations list their choices; expressions are parsed (see
:mod:`petsoft.experiment.expressions`) with the variables their key allows.

Decisions the format leaves open
--------------------------------
* ``[material]`` and ``[springs]`` are alternatives: exactly one of them is required. In
  ``[material]`` ``youngs_modulus``, ``poisson_ratio`` and ``density`` are required and ``model``
  defaults to ``"linear"`` (the simplest belief; diagnosis can find ``material.nonlinear``).
* A table inside ``[material]`` is a region override (``[material.<region>]``); it inherits every
  key it does not set from the default. Its region may be a ``[region.<name>]`` or a physical group
  of the mesh; the mesh's groups are only known once the mesh is read, so names not defined in
  ``[region]`` are kept and listed by :attr:`Experiment.unresolved_regions` for the mesh step to
  check. The same holds for a boundary's ``where`` that names a region.
* A boundary's ``where`` names a region when it is a bare identifier other than a variable,
  ``pi`` or a function name; otherwise it is a condition of x, y, z. ``[region.<name>]`` names must
  therefore be such identifiers.
* Absent sections take their defaults: no damping, **no gravity** (``[0, 0, 0]``; diagnosis can
  find a missing ``gravity``), zero initial displacement and velocity, output to ``out`` beside the
  experiment file every step and no checkpoints (``checkpoint_every = 0``). ``[time]`` has no
  defaults for ``end`` and ``step``; without ``[time]`` :attr:`Experiment.time` is None (fine for
  ``static`` and ``modes``; ``simulate`` must refuse it).
* Expressions and points (``where``, displacements, tractions, initial fields, ``probes``,
  ``[[mass]] at``, collider geometry) are in the coordinates of the mesh after ``scale``, i.e. in
  metres, like the markers of a recording (formats.md section 2).
* Paths (``mesh.file``, ``output.directory``) are resolved relative to the experiment file's
  directory and stored absolute; the mesh file must exist. :func:`write_toml` writes them relative
  to the new file's directory.
* ``[petsc]`` keys may be written with or without the leading dash (stored without); values are
  stored as strings for the PETSc options database: numbers as written, ``true`` as ``""`` (the
  option is present, like ``-ksp_monitor`` on a command line), ``false`` as ``"false"`` (for
  boolean options; to leave a flag off, omit it), arrays as comma-separated lists.
* ``[calibrate]`` keys may be quoted dotted keys (``"damping.mass" = [0, 20]``) or nested tables;
  each must name a numeric parameter (:func:`parameter_names`), both bounds must be valid values of
  it and the current value must lie between them (it is the starting point).
* Optional keys beyond formats.md (allowed: the format grows only by optional keys):
  ``[springs] pairs`` (explicit node pairs instead of the mesh edges) and ``node_mass`` (kg added at
  every node), and ``[[collider]] friction``, ``stiffness`` (penalty), plus the geometry each kind
  needs (``center``/``radius`` for a sphere, ``point``/``normal`` for a plane), and a plane's
  ``offset`` (m, default 0: the plane moved along its normal, the calibration parameter
  ``collider.<i>.offset`` of ``[material]`` models; calibrated values are written back as this
  key, ``point`` is kept); ``[[boundary]] kind = "fixed"`` ``compliance`` (m/Pa, default 0 =
  rigid; > 0: an elastic support, see :mod:`petsoft.physics.support`; the parameter
  ``boundary.compliance`` sets every elastic support); and the ``[viscoelastic]`` table
  (``ratio`` = E_M/E >= 0, default 0 = no branch; ``relaxation_time``
  > 0 s, default 0.1): a standard linear solid, one Maxwell branch of modulus ratio ``ratio``
  and relaxation time ``relaxation_time`` beside the elastic law (continuum models only; see
  :mod:`petsoft.physics.viscoelastic`);
  and the velocity-dependent forces ``[drag] linear`` (Pa s/m), ``quadratic`` (kg/m^3) on the
  boundary surface (triangles of a mass-spring model) and ``[friction] dry`` (m/s^2), ``speed``
  (m/s, > 0, default 1e-3), ``where`` (region name or condition; default all nodes): see
  :mod:`petsoft.dynamics.velocity`. All default to zero (absent).
* ``format_version = 1`` is optional at the top level; other versions are refused.
"""

from __future__ import annotations

import dataclasses
import keyword
import math
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from petsoft.errors import ExperimentError
from petsoft.experiment.expressions import FUNCTIONS, Expression, parse_expression
from petsoft.experiment.gravity_tilt import tilted
from petsoft.experiment.messages import show_value, suggest, type_name
from petsoft.experiment.parameters import key_part, read_calibrate
from petsoft.experiment.ranges import (
    ANY,
    INT_NONNEGATIVE,
    INT_POSITIVE,
    MATERIAL_RANGES,
    NONNEGATIVE,
    POSITIVE,
    UNIT,
    Range,
    format_number,
    key_range,
)
from petsoft.experiment.spec import (
    BOUNDARY_KINDS,
    COLLIDER_KINDS,
    COMPONENTS,
    FORMAT_VERSION,
    INITIAL_FROM,
    INTEGRATORS,
    MATERIAL_KEYS,
    MATERIAL_MODELS,
    SPACE,
    SPACE_TIME,
    VELOCITY_TABLES,
    BoundarySpec,
    BoxSpec,
    ColliderSpec,
    DampingSpec,
    DragSpec,
    Experiment,
    FrictionSpec,
    GravitySpec,
    InitialSpec,
    MassSpec,
    MaterialSpec,
    MeshSpec,
    OutputSpec,
    RegionSpec,
    SpringsSpec,
    TimeSpec,
    ViscoelasticSpec,
    zero_field,
)
from petsoft.experiment.surface import check_surface_terms, surface_keys
from petsoft.experiment.table import TableReader, describe_range
from petsoft.mesh.springs import read_spring_mesh
from petsoft.terms import keys_of, plugin_tables

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10 (pyproject allows it): the same parser, as a package
    import tomli as tomllib


#: Names a region cannot have: a bare `where` with one of these is an expression.
_RESERVED_NAMES = frozenset({*SPACE_TIME, "pi", *FUNCTIONS, "default", "and", "or", "not"})

TOP_KEYS = (
    "format_version",
    "mesh",
    "material",
    "region",
    "damping",
    "gravity",
    "boundary",
    "initial",
    "time",
    "output",
    "petsc",
    "calibrate",
    "springs",
    "mass",
    "collider",
    "viscoelastic",
    "drag",
    "friction",
)


def _package_tables() -> tuple[str, ...]:
    """The top-level tables of terms from other packages; a table petsoft reads itself is an
    error naming the package (checked once, when this module is imported)."""
    tables = plugin_tables()
    for table, plugin in tables.items():
        if table in TOP_KEYS:
            raise ImportError(f"petsoft.terms entry point {plugin.module!r} of package "
                              f"{plugin.package!r}: term {plugin.term.name!r} reads table "
                              f"[{table}], which is petsoft's own; use a table of its own")
    return tuple(tables)


#: The tables of terms from other packages (:data:`petsoft.terms.PLUGINS`).
PACKAGE_TABLES = _package_tables()
_BOUNDARY_KEYS = {
    "fixed": ("kind", "where", "components", "compliance"),
    "prescribed": ("kind", "where", "components", "displacement", "series"),
    "traction": ("kind", "where", "value"),
}
_COLLIDER_KEYS = {
    "sphere": ("kind", "center", "radius", "friction", "stiffness"),
    "plane": ("kind", "point", "normal", "friction", "stiffness", "offset"),
}

_TOML_POSITION = re.compile(r"\(at line (\d+), column (\d+)\)")


def load_experiment(path: str | os.PathLike) -> Experiment:
    """Read and validate an experiment file.

    Parameters
    ----------
    path : path-like
        The TOML file. Relative paths inside it are relative to its directory.

    Returns
    -------
    Experiment

    Raises
    ------
    ExperimentError
        If the file cannot be read, is not valid TOML (the message gives line and column) or is
        not a valid experiment (the message names the key, the value and what is valid).
    """
    source = os.fspath(path)
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise ExperimentError(f"{source}: experiment file not found") from None
    except IsADirectoryError:
        raise ExperimentError(f"{source}: is a directory, not an experiment file") from None
    except OSError as exc:
        raise ExperimentError(f"{source}: cannot read the experiment file: {exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ExperimentError(
            f"{source}:{line}: not UTF-8 text (byte {exc.start}); TOML files are UTF-8"
        ) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ExperimentError(_toml_error(source, text, exc)) from None
    return experiment_from_dict(data, source=source, base_dir=p.parent, path=p.resolve())


def _toml_error(source: str, text: str, exc: tomllib.TOMLDecodeError) -> str:
    message = str(exc)
    m = _TOML_POSITION.search(message)
    if not m:
        return f"{source}: TOML syntax error: {message}"
    line, col = int(m.group(1)), int(m.group(2))
    reason = _TOML_POSITION.sub("", message).strip()
    lines = text.splitlines()
    excerpt = ""
    if 1 <= line <= len(lines):
        excerpt = f"\n    {lines[line - 1]}\n    {' ' * (col - 1)}^"
    return (
        f"{source}:{line}:{col}: TOML syntax error at line {line}, column {col}: {reason}{excerpt}"
    )


def experiment_from_dict(
    data: Mapping[str, Any],
    *,
    source: str = "<embedded>",
    base_dir: str | os.PathLike = ".",
    path: str | os.PathLike | None = None,
) -> Experiment:
    """Validate an already parsed experiment (the dict ``tomllib`` gives).

    Parameters
    ----------
    data : mapping
        The experiment's tables, as :func:`tomllib.loads` returns them.
    source : str
        Name used in error messages (normally the file's path).
    base_dir : path-like
        Directory relative paths are resolved against.
    path : path-like, optional
        Stored as :attr:`Experiment.path`.

    Returns
    -------
    Experiment

    Raises
    ------
    ExperimentError
        On any invalid, unknown, missing or out-of-range entry.
    """
    if not isinstance(data, Mapping):
        raise ExperimentError(f"{source}: expected a table of sections, got {type_name(data)}")
    base = Path(base_dir).resolve()
    top = TableReader(dict(data), "", source)
    top.check_keys(TOP_KEYS + PACKAGE_TABLES)

    version = top.integer("format_version", FORMAT_VERSION)
    if version != FORMAT_VERSION:
        top.fail(
            "format_version",
            f" = {version} is not supported: this petsoft reads format_version = {FORMAT_VERSION}",
        )

    mesh = _read_mesh(top.table("mesh"), top, base)
    material, springs = _read_model(top, data, source, mesh)
    regions = _read_regions(top.table("region"))
    damping = _read_damping(top.table("damping"))
    gravity = _read_gravity(top.table("gravity"))
    boundaries = _read_boundaries(top, source, springs)
    initial = _read_initial(top.table("initial"))
    time = _read_time(top.table("time"))
    output = _read_output(top.table("output"), base)
    petsc = _read_petsc(top.table("petsc"))
    masses = tuple(_read_mass(r) for r in top.table_array("mass"))
    colliders = tuple(_read_collider(r) for r in top.table_array("collider"))
    viscoelastic = _read_viscoelastic(top.table("viscoelastic"))
    if viscoelastic.ratio > 0.0 and springs is not None:
        _refuse_on_springs(source, f"[viscoelastic] ratio = {format_number(viscoelastic.ratio)}: "
                           "the standard linear solid acts",
                           "; remove [viscoelastic] or set ratio = 0")
    velocity = {t: _read_velocity_table(top.table(t), t) for t in VELOCITY_TABLES}
    terms = {t: _read_package_table(top.table(t), t) for t in PACKAGE_TABLES if t in data}
    if terms and springs is not None:
        _refuse_on_springs(source, f"[{next(iter(terms))}]: the terms of other packages act")

    experiment = Experiment(
        mesh=mesh,
        material=material,
        regions=regions,
        damping=damping,
        gravity=gravity,
        boundaries=boundaries,
        initial=initial,
        time=time,
        output=output,
        petsc=petsc,
        calibrate={},
        springs=springs,
        masses=masses,
        colliders=colliders,
        viscoelastic=viscoelastic,
        **velocity,
        terms=terms,
        format_version=version,
        path=Path(path) if path is not None else None,
        source=source,
        base_dir=base,
    )
    table = top.table("calibrate")
    calibrate = {} if table is None else read_calibrate(table.data, source, experiment)
    experiment = dataclasses.replace(experiment, calibrate=calibrate)
    _check_surface_terms(experiment)
    return experiment


def _read_model(top: TableReader, data: Mapping[str, Any], source: str, mesh: MeshSpec):
    """(material, springs): the model, a continuum (``[material]``, springs None) or a
    mass-spring network (``[springs]``, material empty, its mesh not refined), exactly one."""
    if "material" in data and "springs" in data:
        raise ExperimentError(
            f"{source}: both [material] and [springs] are given: a model is either a continuum "
            "([material]) or mass-spring ([springs]), not both"
        )
    if "material" not in data and "springs" not in data:
        raise ExperimentError(
            f"{source}: the model is missing: give [material] (continuum: model, youngs_modulus, "
            "poisson_ratio, density) or [springs] (mass-spring: stiffness, damping)"
        )
    material = _read_material(top.table("material")) if "material" in data else {}
    springs = _read_springs(top.table("springs")) if "springs" in data else None
    if springs is not None and mesh.refine:
        raise ExperimentError(f"{source}: [mesh] refine = {mesh.refine}: only tetrahedral meshes "
                              "of a [material] model are refined; a [springs] model's springs "
                              "are its mesh's edges: remove refine")
    return material, springs


def _read_boundaries(top: TableReader, source: str, springs) -> tuple:
    """The ``[[boundary]]`` entries; an elastic support (compliance) only on a continuum."""
    boundaries = tuple(_read_boundary(r) for r in top.table_array("boundary"))
    for i, b in enumerate(boundaries):
        if springs is not None and b.compliance > 0.0:
            raise ExperimentError(
                f"{source}: boundary[{i}].compliance = {show_value(b.compliance)}: elastic "
                "supports "
                "are implemented for [material] (continuum) models only; the fixed nodes of a "
                "[springs] model are rigid (remove compliance, or model the support by springs)"
            )
    return boundaries


def _refuse_on_springs(source: str, what: str, advice: str = "") -> None:
    """Refuse on a ``[springs]`` model what acts on a continuum (``what``: its key and words,
    ending with the verb)."""
    raise ExperimentError(f"{source}: {what} on a continuum [material] model, not on "
                          f"[springs]{advice}")


def _check_surface_terms(exp: Experiment) -> None:
    """Refuse a term that acts on the surface on a mass-spring mesh without one
    (:mod:`petsoft.experiment.surface`). Reads the mesh's cells (only when such a term is
    switched on; spring meshes are small)."""
    if exp.springs is None or exp.mesh.file is None or not surface_keys(exp):
        return
    try:
        mesh = read_spring_mesh(exp.mesh.file, scale=exp.mesh.scale)
    except Exception:  # the model builder reports an unreadable mesh with its own message
        return
    check_surface_terms(exp, mesh)


def _read_mesh(r: TableReader | None, top: TableReader, base: Path) -> MeshSpec:
    if r is None:
        top.fail(
            "mesh",
            ' is missing: add [mesh] with file = "<mesh file>" or box = { size = [lx, ly, lz], '
            "cells = [nx, ny, nz] }",
        )
    r.check_keys(("file", "box", "scale", "refine", "order"))
    if ("file" in r.data) == ("box" in r.data):
        both = "both are given" if "file" in r.data else "neither is given"
        raise ExperimentError(
            f'{r.source}: [mesh] needs exactly one of file = "<mesh file>" and box = '
            f"{{ size = [...], cells = [...] }}: {both}"
        )
    scale = r.number("scale", 1.0, POSITIVE)
    refine = r.integer("refine", 0, INT_NONNEGATIVE)
    order = r.integer("order", 1, Range(lo=1, hi=2))
    if "file" in r.data:
        name = r.string("file", what="a path to a mesh file, relative to the experiment file")
        file = (base / name).resolve()
        if not file.exists():
            r.fail(
                "file",
                f' = "{name}": the mesh file does not exist (looked for {file}; a relative path '
                f"is relative to the experiment file's directory {base})",
            )
        if not file.is_file():
            r.fail("file", f' = "{name}": {file} is not a file')
        return MeshSpec(file=file, scale=scale, refine=refine, order=order)
    box = r.table("box", header="an inline table { size = [lx, ly, lz], cells = [nx, ny, nz] }")
    assert box is not None
    box.check_keys(("size", "cells"))
    size = box.vector("size", rng=POSITIVE, unit="mesh units")
    cells_raw = box.get("cells", what="an array of 3 integers >= 1")
    if not isinstance(cells_raw, list):
        box.wrong_type("cells", cells_raw, "an array of 3 integers, each >= 1")
    if len(cells_raw) != 3:
        box.fail(
            "cells",
            f" = {show_value(cells_raw)} has {len(cells_raw)} entries: expected an array of 3 "
            "integers, each >= 1",
        )
    cells = []
    for i, c in enumerate(cells_raw):
        item = TableReader({f"cells[{i}]": c}, box.name, box.source)
        cells.append(item.integer(f"cells[{i}]", rng=INT_POSITIVE))
    return MeshSpec(box=BoxSpec(size=size, cells=tuple(cells)), scale=scale, refine=refine,
                    order=order)


def _material_values(r: TableReader) -> dict[str, Any]:
    values: dict[str, Any] = {}
    if "model" in r.data:
        values["model"] = r.choice("model", MATERIAL_MODELS)
    for k, (rng, unit) in MATERIAL_RANGES.items():
        if k in r.data:
            values[k] = r.number(k, rng=rng, unit=unit)
    return values


def _read_material(r: TableReader | None) -> dict[str, MaterialSpec]:
    assert r is not None
    scalars = TableReader({k: v for k, v in r.data.items() if not isinstance(v, dict)}, r.name,
                      r.source)  # fmt: skip
    scalars.check_keys(MATERIAL_KEYS, note=" (and [material.<region>] tables for regions)")
    for k in MATERIAL_KEYS:
        if isinstance(r.data.get(k), dict):
            r.wrong_type(k, r.data[k], "a string" if k == "model" else "a number")
    values = _material_values(scalars)
    for k, (rng, unit) in MATERIAL_RANGES.items():
        if k not in values:
            r.fail(k, f" is missing ({describe_range(rng.text(k), unit)})")
    default = MaterialSpec(**values)
    result = {"default": default}
    for name, table in r.data.items():
        if not isinstance(table, dict):
            continue
        if name == "default":
            r.fail(name, " is reserved: the default material is [material] itself")
        sub = TableReader(table, r.key(name), r.source)
        for k, v in table.items():
            if isinstance(v, dict):
                sub.fail(
                    k,
                    f" is a table, but [{sub.name}] overrides the material of region "
                    f'"{name}" and takes only {", ".join(MATERIAL_KEYS)}',
                )
        sub.check_keys(MATERIAL_KEYS, note=f' (overrides of the default for region "{name}")')
        override = _material_values(sub)
        result[name] = dataclasses.replace(default, **override, overrides=frozenset(override))
    return result


def _read_regions(r: TableReader | None) -> dict[str, RegionSpec]:
    if r is None:
        return {}
    regions = {}
    for name, table in r.data.items():
        if not isinstance(table, dict):
            r.fail(
                name,
                f" = {show_value(table)}: regions are tables: write [region.{key_part(name)}] "
                'with where = "<condition of x, y, z>"',
            )
        if not _is_region_name(name) or name != name.strip():
            r.fail(
                name,
                ": a region name must be an identifier (letters, digits, _) other than x, y, z, "
                "t, pi, default, Python keywords and the function names, so that a boundary's "
                "where can name it",
            )
        sub = TableReader(table, r.key(name), r.source)
        sub.check_keys(("where",))
        where = sub.string("where", what='a condition of x, y, z, e.g. "x < 0.1"')
        expr = parse_expression(
            where, source=f"{r.source}: {sub.key('where')}", variables=SPACE, expect="condition"
        )
        regions[name] = RegionSpec(name=name, where=expr)
    return regions


def _term_values(r: TableReader, table: str, only: str = "") -> dict[str, Any]:
    """The numbers and vectors the physics terms declare in ``[table]`` (:mod:`petsoft.terms`;
    for an array of tables, those of entries of kind ``only``), each checked against its declared
    range and unit, its default when absent."""
    out: dict[str, Any] = {}
    for k in keys_of(table):
        if k.only != only:
            continue
        if k.type == "number":
            out[k.key] = r.number(k.key, k.default, key_range(k), k.text or k.unit)
        elif k.type == "vector":
            out[k.key] = r.vector(k.key, k.default, unit=k.text or k.unit)
    return out


def _term_keys(table: str) -> tuple[str, ...]:
    """The keys ``[table]`` accepts: those its terms declare."""
    return tuple(k.key for k in keys_of(table))


def _term_wheres(r: TableReader, table: str) -> dict[str, Any]:
    """The ``where`` keys the terms declare in ``[table]``: a region name or a condition of x,
    y, z; absent, the declared default (a region name or condition), or None, which the term
    reads as its own choice of place (the friction: every node)."""
    return {k.key: _read_where(r, k.key) if k.key in r.data else k.default
            for k in keys_of(table) if k.type == "where"}


def _read_package_table(r: TableReader, table: str) -> dict[str, Any]:
    """``[table]`` of a term from another package: every key it declares, checked against its
    declaration (range, unit, choices, a ``where``), its default when absent."""
    r.check_keys(_term_keys(table), note=f" (declared by package "
                 f"{plugin_tables()[table].package!r})")
    out = _term_values(r, table)
    for k in keys_of(table):
        if k.type == "choice":
            out[k.key] = r.choice(k.key, k.choices, k.default)
    return {**out, **_term_wheres(r, table)}


def _read_damping(r: TableReader | None) -> DampingSpec:
    if r is None:
        return DampingSpec()
    r.check_keys(_term_keys("damping"))
    return DampingSpec(**_term_values(r, "damping"))


def _read_viscoelastic(r: TableReader | None) -> ViscoelasticSpec:
    if r is None:
        return ViscoelasticSpec()
    r.check_keys(_term_keys("viscoelastic"))
    return ViscoelasticSpec(**_term_values(r, "viscoelastic"))


def _read_velocity_table(r: TableReader | None, table: str) -> DragSpec | FrictionSpec:
    """``[table]`` of the velocity laws (:data:`~petsoft.experiment.spec.VELOCITY_TABLES`:
    ``[drag]``, ``[friction]``) as its spec: every key the terms declare there, checked against
    its declaration, its default when absent."""
    spec = type(getattr(Experiment, table))  # the class of the Experiment field's default
    if r is None:
        return spec()
    r.check_keys(_term_keys(table))
    return spec(**_term_values(r, table), **_term_wheres(r, table))


def _read_where(r: TableReader, k: str) -> str | Expression:
    """A ``where``: a region name (bare identifier) or a condition of x, y, z."""
    text = r.string(k, what='a region name or a condition of x, y, z, e.g. "x < 1e-6"')
    if _is_region_name(text):
        return text.strip()
    return parse_expression(text, source=f"{r.source}: {r.key(k)}", variables=SPACE,
                            expect="condition")


def _read_gravity(r: TableReader | None) -> GravitySpec:
    if r is None:
        return GravitySpec()
    r.check_keys(_term_keys("gravity"))
    values = _term_values(r, "gravity")
    spec = GravitySpec(**values)
    if not spec.tilted:
        return spec
    if not any(spec.acceleration):
        key = "tilt_a" if spec.tilt_a != 0.0 else "tilt_b"
        r.fail(key, " turns the acceleration's direction at its own size, but the acceleration "
               "is zero: state it (e.g. acceleration = [0, 0, -9.81]) or leave the tilt out")
    return GravitySpec(**{**values, "stated": spec.acceleration,
                          "acceleration": tuple(map(float, tilted(spec.acceleration,
                                                                  spec.tilt_a,
                                                                  spec.tilt_b)))})


def _is_region_name(text: str) -> bool:
    s = text.strip()
    return s.isidentifier() and not keyword.iskeyword(s) and s not in _RESERVED_NAMES


def _read_boundary(r: TableReader) -> BoundarySpec:
    kind = r.choice("kind", BOUNDARY_KINDS)
    allowed = _BOUNDARY_KEYS[kind]
    for k in r.data:
        if k not in allowed:
            owners = [kd for kd, keys in _BOUNDARY_KEYS.items() if k in keys]
            close = suggest(k, allowed)
            hint = f"; did you mean {r.key(close)}?" if close else ""
            quoted = " or ".join(f'"{o}"' for o in owners)
            belongs = f" ({k} belongs to kind = {quoted})" if owners else ""
            raise ExperimentError(
                f'{r.source}: {r.key(k)} is not a key of a boundary with kind = "{kind}"{hint}'
                f"{belongs}. Valid keys for this kind: {', '.join(allowed)}"
            )
    where_text = r.string("where", what='a region name or a condition of x, y, z, e.g. "x < 1e-6"')
    where: str | Expression
    if _is_region_name(where_text):
        where = where_text.strip()
    else:
        where = parse_expression(
            where_text, source=f"{r.source}: {r.key('where')}", variables=SPACE,
            expect="condition",
        )  # fmt: skip
    components = COMPONENTS
    if "components" in r.data:
        comps = r.data["components"]
        expected = 'a non-empty array of distinct components from "x", "y", "z"'
        if not isinstance(comps, list):
            r.wrong_type("components", comps, expected)
        if not comps:
            r.fail("components", f" = [] is empty: expected {expected}")
        for i, c in enumerate(comps):
            item = TableReader({f"components[{i}]": c}, r.name, r.source)
            item.choice(f"components[{i}]", COMPONENTS)
        if len(set(comps)) != len(comps):
            r.fail("components", f" = {show_value(comps)} repeats a component: expected {expected}")
        components = tuple(c for c in COMPONENTS if c in comps)
    spec = BoundarySpec(kind=kind, where=where, components=components)
    if kind == "prescribed":
        if ("displacement" in r.data) == ("series" in r.data):
            both = "both are given" if "displacement" in r.data else "neither is given"
            raise ExperimentError(
                f'{r.source}: {r.name} (kind = "prescribed") needs exactly one of displacement '
                f'= ["<expr>", "<expr>", "<expr>"] (of x, y, z, t) and series = "<input in the '
                f'recording>": {both}'
            )
        if "displacement" in r.data:
            spec = dataclasses.replace(
                spec, displacement=r.expressions("displacement", SPACE_TIME, what="in m")
            )
        else:
            spec = dataclasses.replace(
                spec, series=r.string("series", what='a recording input, e.g. "inputs/shaker"')
            )
    elif kind == "traction":
        spec = dataclasses.replace(spec, value=r.expressions("value", SPACE_TIME, what="in Pa"))
    else:
        spec = dataclasses.replace(spec, **_term_values(r, "boundary", only="fixed"))
    return spec


def _read_initial(r: TableReader | None) -> InitialSpec:
    if r is None:
        return InitialSpec()
    r.check_keys(("displacement", "velocity", "from"))
    from_ = r.choice("from", INITIAL_FROM, None)
    if from_ is not None and "displacement" in r.data:
        raise ExperimentError(
            f'{r.source}: [initial] has both from = "{from_}" and displacement: give one of them'
        )
    zeros = zero_field(SPACE)
    return InitialSpec(
        displacement=r.expressions("displacement", SPACE, zeros, what="in m"),
        velocity=r.expressions("velocity", SPACE, zeros, what="in m/s"),
        from_=from_,
    )


def _read_time(r: TableReader | None) -> TimeSpec | None:
    if r is None:
        return None
    r.check_keys(("end", "step", "integrator", "alpha_radius", "imex_slow_modes"))
    end = r.number("end", rng=POSITIVE, unit="s")
    step = r.number("step", rng=POSITIVE, unit="s")
    if step > end:
        r.fail("step", f" = {show_value(step)} is larger than time.end = {show_value(end)}")
    return TimeSpec(
        end=end,
        step=step,
        integrator=r.choice("integrator", INTEGRATORS, "be"),
        alpha_radius=r.number("alpha_radius", 0.5, UNIT),
        imex_slow_modes=r.integer("imex_slow_modes", 6, INT_POSITIVE),
    )


def _read_output(r: TableReader | None, base: Path) -> OutputSpec:
    if r is None:
        return OutputSpec(directory=(base / "out").resolve())
    r.check_keys(("directory", "every", "checkpoint_every", "probes"))
    directory = r.string("directory", "out", what="a directory, relative to the experiment file")
    probes_raw = r.get("probes", [])
    expected = "an array of points [[x, y, z], ...]"
    if not isinstance(probes_raw, list):
        r.wrong_type("probes", probes_raw, expected)
    probes = tuple(
        TableReader({f"probes[{i}]": p}, r.name, r.source)._vector_value(
            f"probes[{i}]", p, "an array of 3 numbers (a point [x, y, z])", ANY, "", 3
        )
        for i, p in enumerate(probes_raw)
    )
    return OutputSpec(
        directory=(base / directory).resolve(),
        every=r.integer("every", 1, INT_POSITIVE),
        checkpoint_every=r.integer("checkpoint_every", 0, INT_NONNEGATIVE),
        probes=probes,
    )


_PETSC_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


def _petsc_value(r: TableReader, k: str, v: Any) -> str:
    if isinstance(v, bool):
        return "" if v else "false"
    if isinstance(v, str):
        return v
    if isinstance(v, (int, float)):
        if isinstance(v, float) and not math.isfinite(v):
            r.fail(k, f" = {show_value(v)} is not a finite number")
        return str(v) if isinstance(v, int) else repr(v)
    if isinstance(v, list) and all(
        isinstance(item, (str, int, float)) and not isinstance(item, bool) for item in v
    ):
        return ",".join(_petsc_value(r, k, item) for item in v)
    if isinstance(v, dict):
        r.fail(
            k,
            " is a table, but PETSc options are flat: write the whole option name as the key, "
            'e.g. ksp_type = "cg" (a dotted key such as ksp.type makes a table)',
        )
    r.wrong_type(k, v, "a string, number, boolean or array of numbers/strings")


def _read_petsc(r: TableReader | None) -> dict[str, str]:
    if r is None:
        return {}
    options: dict[str, str] = {}
    for k, v in r.data.items():
        name = k.lstrip("-")
        if not _PETSC_NAME.fullmatch(name):
            r.fail(k, ": not a PETSc option name (letters, digits and _, e.g. ksp_type)")
        if name in options:
            r.fail(k, f": the option {name} is given twice (with and without the dash)")
        options[name] = _petsc_value(r, k, v)
    return options


def _read_springs(r: TableReader | None) -> SpringsSpec:
    assert r is not None
    r.check_keys(("stiffness", "damping", "bending", "pairs", "node_mass"))
    pairs = None
    if "pairs" in r.data:
        raw = r.data["pairs"]
        expected = "an array of node pairs [[i, j], ...] (0-based vertex numbers, i != j)"
        if not isinstance(raw, list) or not raw:
            r.wrong_type("pairs", raw, expected)
        out = []
        for n, p in enumerate(raw):
            ok = (
                isinstance(p, list)
                and len(p) == 2
                and all(isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in p)
                and p[0] != p[1]
            )
            if not ok:
                r.fail(f"pairs[{n}]", f" = {show_value(p)} is not valid: expected {expected}")
            out.append((p[0], p[1]))
        pairs = tuple(out)
    return SpringsSpec(
        stiffness=r.number("stiffness", rng=POSITIVE, unit="N/m"),
        damping=r.number("damping", 0.0, NONNEGATIVE, "N s/m"),
        bending=r.number("bending", None, NONNEGATIVE),
        pairs=pairs,
        node_mass=r.number("node_mass", 0.0, NONNEGATIVE, "kg"),
    )


def _read_mass(r: TableReader) -> MassSpec:
    r.check_keys(("at", "value"))
    return MassSpec(
        at=r.vector("at", unit="m, a reference point"),
        value=r.number("value", rng=POSITIVE, unit="kg"),
    )


def _read_collider(r: TableReader) -> ColliderSpec:
    kind = r.choice("kind", COLLIDER_KINDS)
    allowed = _COLLIDER_KEYS[kind]
    r.check_keys(allowed, note=f' (for kind = "{kind}")')
    common = {
        "friction": r.number("friction", 0.0, NONNEGATIVE),
        "stiffness": r.number("stiffness", None, POSITIVE),
    }
    if kind == "sphere":
        return ColliderSpec(
            kind=kind,
            center=r.vector("center", unit="m"),
            radius=r.number("radius", rng=POSITIVE, unit="m"),
            **common,
        )
    normal = r.vector("normal")
    length = math.sqrt(sum(c * c for c in normal))
    if length == 0.0:
        r.fail("normal", " = [0, 0, 0]: the plane's normal must be non-zero")
    return ColliderSpec(
        kind=kind,
        point=r.vector("point", unit="m"),
        normal=tuple(c / length for c in normal),
        offset=r.number("offset", 0.0, ANY, unit="m, along the normal"),
        **common,
    )

