"""The experiment as a typed value (formats.md section 1).

This module owns the frozen dataclasses of every section of an experiment file, with the
defaults in code, and :class:`Experiment`, which holds them; the enumerations the format allows
(:data:`MATERIAL_MODELS`, :data:`INTEGRATORS`, ...); and the dict form of an experiment
(:meth:`Experiment.to_dict`), which :func:`~petsoft.experiment.reader.experiment_from_dict` reads
back equal. Reading and validating is :mod:`petsoft.experiment.reader`, writing TOML
:mod:`petsoft.experiment.writer`.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from petsoft.experiment.expressions import Expression, parse_expression
from petsoft.terms import TERMS, keys_of

FORMAT_VERSION = 1
#: The material laws (declared by the ``material.nonlinear`` term, :mod:`petsoft.terms`).
MATERIAL_MODELS = next(k.choices for k in keys_of("material") if k.key == "model")
INTEGRATORS = ("be", "si", "alpha", "midpoint", "trapezoidal", "ere", "explicit", "imex")
BOUNDARY_KINDS = ("fixed", "prescribed", "traction")
COLLIDER_KINDS = ("sphere", "plane")
COMPONENTS = ("x", "y", "z")
INITIAL_FROM = ("static",)
#: The numeric keys of ``[material]`` (and of a ``[material.<region>]`` override).
MATERIAL_PARAMETERS = ("youngs_modulus", "poisson_ratio", "density")
MATERIAL_KEYS = ("model", *MATERIAL_PARAMETERS)

#: The tables of the velocity laws' keys (``drag``, ``friction``; :mod:`petsoft.terms`), each
#: read into the :class:`Experiment` field of its name: a spec whose fields are those keys, with
#: their declared defaults.
VELOCITY_TABLES = tuple(dict.fromkeys(k.table for t in TERMS.values()
                                      if t.contributes == "velocity" for k in t.keys))

SPACE = ("x", "y", "z")
SPACE_TIME = ("x", "y", "z", "t")

Vec3 = tuple[float, float, float]
Expr3 = tuple[Expression, Expression, Expression]


def _declared(dotted: str) -> Any:
    """The default the terms declare for the key ``table.key`` (:mod:`petsoft.terms`)."""
    table, key = dotted.split(".")
    return next(k.default for k in keys_of(table) if k.key == key)


# ------------------------------------------------------------------------------------------------
# The dataclasses. Frozen; their tuple/dict fields must not be mutated either.


@dataclass(frozen=True)
class BoxSpec:
    """The built-in box mesh generator: ``box = { size = [...], cells = [...] }``.

    Attributes
    ----------
    size : tuple of 3 float
        Edge lengths (in mesh units, before ``scale``), each > 0; the box spans [0, size].
    cells : tuple of 3 int
        Number of cells along each axis, each >= 1.
    """

    size: Vec3
    cells: tuple[int, int, int]


@dataclass(frozen=True)
class MeshSpec:
    """``[mesh]``: exactly one of ``file`` (absolute, existing) and ``box``; ``scale`` > 0;
    ``refine`` >= 0: the mesh is split 1 -> 8 that many times after reading
    (:func:`petsoft.mesh.refine.refine_mesh`); ``order``: 1 for 4-node, 2 for 10-node
    tetrahedra (:mod:`petsoft.mesh.quadratic`)."""

    file: Path | None = None
    box: BoxSpec | None = None
    scale: float = 1.0
    refine: int = 0
    order: int = 1


@dataclass(frozen=True)
class MaterialSpec:
    """``[material]`` or, merged with it, one ``[material.<region>]`` override.

    Attributes
    ----------
    model : str
        One of :data:`MATERIAL_MODELS`.
    youngs_modulus : float
        Pa, > 0.
    poisson_ratio : float
        -1 < nu < 0.5.
    density : float
        kg/m^3, > 0.
    overrides : frozenset of str
        For a region: the keys its table sets (the others follow the default, also when the
        default changes in :func:`with_parameters`). Empty for the default.
    """

    youngs_modulus: float
    poisson_ratio: float
    density: float
    model: str = "linear"
    overrides: frozenset[str] = frozenset()

    @property
    def lame(self) -> tuple[float, float]:
        """The Lame parameters (lambda, mu) in Pa."""
        e, nu = self.youngs_modulus, self.poisson_ratio
        return e * nu / ((1 + nu) * (1 - 2 * nu)), e / (2 * (1 + nu))


@dataclass(frozen=True)
class RegionSpec:
    """``[region.<name>]``: the cells/vertices where the condition ``where`` (of x, y, z) holds."""

    name: str
    where: Expression


@dataclass(frozen=True)
class DampingSpec:
    """``[damping]``: Rayleigh damping D = mass * M + stiffness * K (1/s and s, both >= 0). The
    keys and their defaults are the terms' (``damping.mass``, ``damping.stiffness``)."""

    mass: float = _declared("damping.mass")
    stiffness: float = _declared("damping.stiffness")


@dataclass(frozen=True)
class ViscoelasticSpec:
    """``[viscoelastic]``: a Maxwell branch (standard linear solid) beside the elastic law.

    ``ratio`` = E_M / E >= 0 (0: no branch), ``relaxation_time`` tau > 0 in s. The keys and
    their defaults are the term's (``material.viscoelastic``).
    """

    ratio: float = _declared("viscoelastic.ratio")
    relaxation_time: float = _declared("viscoelastic.relaxation_time")


@dataclass(frozen=True)
class DragSpec:
    """``[drag]``: surface drag per unit area, linear (Pa s/m) and quadratic (kg/m^3) in the
    normal velocity (both >= 0; see :mod:`petsoft.physics.drag`). The keys and their defaults
    are the terms' (``drag.linear``, ``drag.quadratic``; :data:`VELOCITY_TABLES`)."""

    linear: float = _declared("drag.linear")
    quadratic: float = _declared("drag.quadratic")


@dataclass(frozen=True)
class FrictionSpec:
    """``[friction]``: regularised dry friction ``dry`` (m/s^2, force per unit mass, >= 0) with
    regularisation ``speed`` (m/s, > 0) on the nodes of ``where`` (None: all nodes; see
    :mod:`petsoft.physics.friction`). The keys and their defaults are the term's
    (``friction.dry``; :data:`VELOCITY_TABLES`)."""

    dry: float = _declared("friction.dry")
    speed: float = _declared("friction.speed")
    where: str | Expression | None = _declared("friction.where")


@dataclass(frozen=True)
class GravitySpec:
    """``[gravity]``: body acceleration in m/s^2 (default none).

    ``acceleration`` is the one the model uses: the stated one (``stated``; None: the same)
    turned at its own size by the tangents ``tilt_a``, ``tilt_b``
    (:mod:`petsoft.experiment.gravity_tilt`) when they are not zero."""

    acceleration: Vec3 = (0.0, 0.0, 0.0)
    tilt_a: float = 0.0
    tilt_b: float = 0.0
    stated: Vec3 | None = None

    @property
    def as_stated(self) -> Vec3:
        """The acceleration as the file states it (before the tilt)."""
        return self.stated if self.stated is not None else self.acceleration

    @property
    def tilted(self) -> bool:
        """Whether a tilt turns the stated acceleration."""
        return self.tilt_a != 0.0 or self.tilt_b != 0.0


@dataclass(frozen=True)
class BoundarySpec:
    """One ``[[boundary]]``.

    Attributes
    ----------
    kind : str
        ``"fixed"``, ``"prescribed"`` or ``"traction"``.
    where : str or Expression
        A region name (str; see :attr:`Experiment.unresolved_regions`) or a condition of x, y, z.
    components : tuple of str
        Constrained components, a subset of ("x", "y", "z") in that order (fixed, prescribed).
    displacement : tuple of 3 Expression or None
        Prescribed displacement, expressions of x, y, z, t (prescribed, unless ``series``).
    series : str or None
        Name of a measured input in the recording, e.g. ``"inputs/shaker"`` (prescribed).
    value : tuple of 3 Expression or None
        Traction in Pa, expressions of x, y, z, t (traction).
    compliance : float
        m/Pa, >= 0 (fixed only): 0 is a rigid support (Dirichlet rows); > 0 ties each
        constrained component of the boundary's nodes to 0 by a spring of stiffness
        A_i / compliance, A_i the node's lumped area of the boundary faces inside ``where``
        (:mod:`petsoft.physics.support`).
    """

    kind: str
    where: str | Expression
    components: tuple[str, ...] = COMPONENTS
    displacement: Expr3 | None = None
    series: str | None = None
    value: Expr3 | None = None
    compliance: float = 0.0

    @property
    def region(self) -> str | None:
        """The region name, or None when ``where`` is an expression."""
        return self.where if isinstance(self.where, str) else None

    @property
    def component_indices(self) -> tuple[int, ...]:
        """The constrained components as indices 0, 1, 2."""
        return tuple(COMPONENTS.index(c) for c in self.components)


def zero_field(variables: tuple[str, ...]) -> Expr3:
    """The field (0, 0, 0) as three expressions of ``variables`` (the default of a field)."""
    z = parse_expression("0", source="<default>", variables=variables)
    return (z, z, z)


@dataclass(frozen=True)
class InitialSpec:
    """``[initial]``: displacement and velocity (expressions of x, y, z), or ``from_``.

    ``from_`` is the TOML key ``from``: None (use ``displacement``) or ``"static"`` (start from
    the static equilibrium under the loads; ``displacement`` is then not allowed).
    """

    displacement: Expr3 = field(default_factory=lambda: zero_field(SPACE))
    velocity: Expr3 = field(default_factory=lambda: zero_field(SPACE))
    from_: str | None = None


@dataclass(frozen=True)
class TimeSpec:
    """``[time]``: ``end`` > 0 and 0 < ``step`` <= ``end`` (s), the integrator, and the
    generalized-alpha ``alpha_radius`` in [0, 1], and for ``imex`` the number of lowest modes
    integrated explicitly (``imex_slow_modes`` >= 1; the rest implicitly)."""

    end: float
    step: float
    integrator: str = "be"
    alpha_radius: float = 0.5
    imex_slow_modes: int = 6

    @property
    def num_steps(self) -> int:
        """Number of steps to reach ``end`` (the last may end past it by less than a step)."""
        return max(1, math.ceil(self.end / self.step - 1e-9))


@dataclass(frozen=True)
class OutputSpec:
    """``[output]``: directory (absolute), frames ``every`` >= 1 steps, ``checkpoint_every`` >= 0
    steps (0: none), and probe points (reference configuration, after ``mesh.scale``)."""

    directory: Path
    every: int = 1
    checkpoint_every: int = 0
    probes: tuple[Vec3, ...] = ()


@dataclass(frozen=True)
class SpringsSpec:
    """``[springs]`` (mass-spring models, instead of ``[material]``).

    Attributes
    ----------
    stiffness : float
        N/m, > 0.
    damping : float
        N s/m, >= 0.
    bending : float or None
        Bending stiffness (>= 0), None for none.
    pairs : tuple of (int, int) or None
        Explicit node pairs (0-based mesh vertex numbers); None: the edges of the mesh.
    node_mass : float
        kg added at every node, >= 0 (besides ``[[mass]]`` point masses).
    """

    stiffness: float
    damping: float = 0.0
    bending: float | None = None
    pairs: tuple[tuple[int, int], ...] | None = None
    node_mass: float = 0.0


@dataclass(frozen=True)
class MassSpec:
    """One ``[[mass]]``: a point mass ``value`` (kg, > 0) at the reference point ``at``."""

    at: Vec3
    value: float


@dataclass(frozen=True)
class ColliderSpec:
    """One ``[[collider]]``: a rigid ``"sphere"`` (center, radius > 0) or ``"plane"`` (point,
    unit normal pointing to the allowed side; given non-zero, stored normalised), with Coulomb
    ``friction`` >= 0 and an optional penalty ``stiffness`` > 0 (None: the solver's choice).
    A plane's ``offset`` (m, any sign, default 0) moves it along its normal: the surface is
    ``point + offset * normal`` (the calibration parameter ``collider.<i>.offset``; ``point``
    itself is never rewritten)."""

    kind: str
    center: Vec3 | None = None
    radius: float | None = None
    point: Vec3 | None = None
    normal: Vec3 | None = None
    friction: float = 0.0
    stiffness: float | None = None
    offset: float = 0.0


@dataclass(frozen=True)
class Experiment:
    """A validated experiment (formats.md section 1).

    Attributes
    ----------
    path : Path or None
        The file it was read from (absolute), None when built from a dict.
    mesh : MeshSpec
    material : dict of str to MaterialSpec
        ``"default"`` plus one merged spec per ``[material.<region>]``; empty for a mass-spring
        model.
    regions : dict of str to RegionSpec
        The ``[region.<name>]`` definitions.
    damping : DampingSpec
    gravity : GravitySpec
    boundaries : tuple of BoundarySpec
    initial : InitialSpec
    time : TimeSpec or None
        None when the file has no ``[time]``.
    output : OutputSpec
    petsc : dict of str to str
        Default PETSc options, keys without the leading dash.
    calibrate : dict of str to (float, float)
        Parameter name (see :func:`parameter_names`) to (lower, upper), lower < upper.
    springs : SpringsSpec or None
    masses : tuple of MassSpec
    colliders : tuple of ColliderSpec
    viscoelastic : ViscoelasticSpec
        ``[viscoelastic]`` (ratio 0, the default, is the purely elastic model).
    drag : DragSpec
    friction : FrictionSpec
    terms : dict of str to dict
        The tables of terms from other packages (:data:`petsoft.terms.PLUGINS`) the file gives:
        table -> {key: value} with every declared key (its default when absent): numbers as
        floats, vectors as tuples, choices as strings, a ``where`` as a region name or an
        :class:`Expression`. A term whose table is absent is not in the model.
    format_version : int
    source : str
        The name used in messages (the path as given, or ``"<embedded>"``).
    base_dir : Path
        The directory relative paths were resolved against.

    ``path``, ``source`` and ``base_dir`` do not take part in ``==``.
    """

    mesh: MeshSpec
    material: dict[str, MaterialSpec]
    regions: dict[str, RegionSpec]
    damping: DampingSpec
    gravity: GravitySpec
    boundaries: tuple[BoundarySpec, ...]
    initial: InitialSpec
    time: TimeSpec | None
    output: OutputSpec
    petsc: dict[str, str]
    calibrate: dict[str, tuple[float, float]]
    springs: SpringsSpec | None = None
    masses: tuple[MassSpec, ...] = ()
    colliders: tuple[ColliderSpec, ...] = ()
    viscoelastic: ViscoelasticSpec = ViscoelasticSpec()
    drag: DragSpec = DragSpec()
    friction: FrictionSpec = FrictionSpec()
    terms: dict[str, dict[str, Any]] = field(default_factory=dict)
    format_version: int = FORMAT_VERSION
    path: Path | None = field(default=None, compare=False)
    source: str = field(default="<embedded>", compare=False)
    base_dir: Path = field(default=Path("."), compare=False)

    @property
    def is_mass_spring(self) -> bool:
        """True for a ``[springs]`` model, False for a continuum ``[material]`` model."""
        return self.springs is not None

    @property
    def unresolved_regions(self) -> frozenset[str]:
        """Region names used (material overrides, boundary ``where``, calibration keys) but not
        defined in ``[region]``: they must be physical groups of the mesh, which the mesh step
        checks once it has read the mesh."""
        used = {name for name in self.material if name != "default"}
        used |= {b.region for b in self.boundaries if b.region is not None}
        # a velocity law's where (friction.where): a region name, or a condition
        for table in VELOCITY_TABLES:
            for k in keys_of(table):
                where = getattr(getattr(self, table), k.key)
                if k.type == "where" and isinstance(where, str):
                    used.add(where)
        return frozenset(used - set(self.regions))

    def material_for(self, region: str | None = None) -> MaterialSpec:
        """The material of ``region`` (its override merged with the default), or the default."""
        if region is not None and region in self.material:
            return self.material[region]
        return self.material["default"]

    def to_dict(self, relative_to: str | os.PathLike | None = None) -> dict[str, Any]:
        """The experiment as a TOML-ready dict that :func:`experiment_from_dict` reads back equal.

        Parameters
        ----------
        relative_to : path-like, optional
            Write ``mesh.file`` and ``output.directory`` relative to this directory (the
            directory of the file being written); absolute when None.
        """
        return _to_dict(self, relative_to)


# ------------------------------------------------------------------------------------------------
# The dict form (what TOML holds; the writer serialises it, the reader reads it back).


def _path_text(p: Path, relative_to: str | os.PathLike | None) -> str:
    if relative_to is None:
        return p.as_posix()
    try:
        return Path(os.path.relpath(p, Path(relative_to).resolve())).as_posix()
    except ValueError:  # another drive on Windows
        return p.as_posix()


def _literals(exprs: Iterable[Expression]) -> list[str | int | float]:
    return [e.literal for e in exprs]


def _term_table(values: dict[str, Any]) -> dict[str, Any]:
    """A table of terms' keys as TOML holds it: an expression as its text, a vector as a list;
    a None (absent: the term's own choice, e.g. every node) left out."""
    return {k: (list(v) if isinstance(v, tuple) else v.literal if isinstance(v, Expression)
                else v)
            for k, v in values.items() if v is not None}


def _to_dict(exp: Experiment, relative_to: str | os.PathLike | None) -> dict[str, Any]:
    d: dict[str, Any] = {"format_version": exp.format_version}
    mesh: dict[str, Any] = {}
    if exp.mesh.file is not None:
        mesh["file"] = _path_text(exp.mesh.file, relative_to)
    if exp.mesh.box is not None:
        mesh["box"] = {"size": list(exp.mesh.box.size), "cells": list(exp.mesh.box.cells)}
    mesh["scale"] = exp.mesh.scale
    if exp.mesh.refine:
        mesh["refine"] = exp.mesh.refine
    if exp.mesh.order != 1:
        mesh["order"] = exp.mesh.order
    d["mesh"] = mesh
    if exp.material:
        default = exp.material["default"]
        material: dict[str, Any] = {"model": default.model}
        material.update({k: getattr(default, k) for k in MATERIAL_PARAMETERS})
        for name, spec in exp.material.items():
            if name != "default":
                material[name] = {
                    k: getattr(spec, k) for k in MATERIAL_KEYS if k in spec.overrides
                }
        d["material"] = material
    if exp.springs is not None:
        s = exp.springs
        springs: dict[str, Any] = {"stiffness": s.stiffness, "damping": s.damping}
        if s.bending is not None:
            springs["bending"] = s.bending
        if s.pairs is not None:
            springs["pairs"] = [list(p) for p in s.pairs]
        springs["node_mass"] = s.node_mass
        d["springs"] = springs
    if exp.regions:
        d["region"] = {name: {"where": r.where.literal} for name, r in exp.regions.items()}
    d["damping"] = {"mass": exp.damping.mass, "stiffness": exp.damping.stiffness}
    d["gravity"] = {"acceleration": list(exp.gravity.as_stated)}
    if exp.gravity.tilted:
        d["gravity"].update(tilt_a=exp.gravity.tilt_a, tilt_b=exp.gravity.tilt_b)
    if exp.viscoelastic != ViscoelasticSpec():
        d["viscoelastic"] = dataclasses.asdict(exp.viscoelastic)
    for table in VELOCITY_TABLES:  # written when not all defaults
        spec = getattr(exp, table)
        if spec != type(spec)():
            d[table] = _term_table({k.key: getattr(spec, k.key) for k in keys_of(table)})
    for table, values in exp.terms.items():
        d[table] = _term_table(values)
    if exp.boundaries:
        boundaries = []
        for b in exp.boundaries:
            entry: dict[str, Any] = {
                "kind": b.kind,
                "where": b.where if isinstance(b.where, str) else b.where.literal,
            }
            if b.kind != "traction":
                entry["components"] = list(b.components)
            if b.displacement is not None:
                entry["displacement"] = _literals(b.displacement)
            if b.series is not None:
                entry["series"] = b.series
            if b.value is not None:
                entry["value"] = _literals(b.value)
            if b.compliance > 0.0:
                entry["compliance"] = b.compliance
            boundaries.append(entry)
        d["boundary"] = boundaries
    initial: dict[str, Any] = {}
    if exp.initial.from_ is not None:
        initial["from"] = exp.initial.from_
    else:
        initial["displacement"] = _literals(exp.initial.displacement)
    initial["velocity"] = _literals(exp.initial.velocity)
    d["initial"] = initial
    if exp.time is not None:
        d["time"] = dataclasses.asdict(exp.time)
    d["output"] = {
        "directory": _path_text(exp.output.directory, relative_to),
        "every": exp.output.every,
        "checkpoint_every": exp.output.checkpoint_every,
        "probes": [list(p) for p in exp.output.probes],
    }
    if exp.petsc:
        d["petsc"] = dict(exp.petsc)
    if exp.calibrate:
        d["calibrate"] = {k: list(v) for k, v in exp.calibrate.items()}
    if exp.masses:
        d["mass"] = [{"at": list(m.at), "value": m.value} for m in exp.masses]
    if exp.colliders:
        d["collider"] = [
            {
                k: (list(v) if isinstance(v, tuple) else v)
                for k, v in dataclasses.asdict(c).items()
                if v is not None and not (k == "offset" and v == 0.0)
            }
            for c in exp.colliders
        ]
    return d

