"""Experiment files: loading, strict validation, and writing back (formats.md section 1).

This module owns the experiment as a Python object: typed, frozen dataclasses for every section of
the TOML file, with the defaults in code, built by :func:`load_experiment` (from a file) or
:func:`experiment_from_dict` (from an already parsed dict, for embedded defaults and tests), and
written back by :meth:`Experiment.to_dict` and :func:`write_toml` (calibration writes calibrated
experiments). :func:`with_parameters` changes named numeric parameters (the dotted keys of
``[calibrate]``) and re-validates.

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
import difflib
import json
import keyword
import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

from petsoft.errors import ExperimentError
from petsoft.experiment.expressions import FUNCTIONS, Expression, parse_expression
from petsoft.mesh.springs import read_spring_mesh

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10 (pyproject allows it): the same parser, as a package
    import tomli as tomllib

__all__ = [
    "BOUNDARY_KINDS",
    "COLLIDER_KINDS",
    "COMPONENTS",
    "FORMAT_VERSION",
    "INTEGRATORS",
    "MATERIAL_MODELS",
    "BoundarySpec",
    "BoxSpec",
    "ColliderSpec",
    "DampingSpec",
    "DragSpec",
    "FrictionSpec",
    "Experiment",
    "GravitySpec",
    "InitialSpec",
    "MassSpec",
    "MaterialSpec",
    "MeshSpec",
    "OutputSpec",
    "RegionSpec",
    "SpringsSpec",
    "TimeSpec",
    "ViscoelasticSpec",
    "dumps_toml",
    "experiment_from_dict",
    "get_parameter",
    "load_experiment",
    "parameter_names",
    "with_compliance",
    "with_parameters",
    "with_plane_collider",
    "write_toml",
]

FORMAT_VERSION = 1
MATERIAL_MODELS = ("linear", "stvk", "corotated", "neohookean")
INTEGRATORS = ("be", "si", "alpha", "midpoint", "trapezoidal", "ere", "explicit", "imex")
BOUNDARY_KINDS = ("fixed", "prescribed", "traction")
COLLIDER_KINDS = ("sphere", "plane")
COMPONENTS = ("x", "y", "z")
INITIAL_FROM = ("static",)

SPACE = ("x", "y", "z")
SPACE_TIME = ("x", "y", "z", "t")
#: Names a region cannot have: a bare `where` with one of these is an expression.
_RESERVED_NAMES = frozenset({*SPACE_TIME, "pi", *FUNCTIONS, "default", "and", "or", "not"})

Vec3 = tuple[float, float, float]
Expr3 = tuple[Expression, Expression, Expression]


# ------------------------------------------------------------------------------------------------
# Ranges of numeric values, shared by the loader and the [calibrate] bounds check.


@dataclass(frozen=True)
class _Range:
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def contains(self, v: float) -> bool:
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        return not (self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi))

    def text(self, name: str) -> str:
        lo = "" if self.lo is None else f"{_num(self.lo)} {'<' if self.lo_open else '<='} "
        hi = "" if self.hi is None else f" {'<' if self.hi_open else '<='} {_num(self.hi)}"
        if self.lo is not None and self.hi is None:
            return f"{name} {'>' if self.lo_open else '>='} {_num(self.lo)}"
        return f"{lo}{name}{hi}" if (lo or hi) else f"{name} any finite number"


_ANY = _Range()
_POSITIVE = _Range(lo=0.0, lo_open=True)
_NONNEGATIVE = _Range(lo=0.0)
_POISSON = _Range(lo=-1.0, hi=0.5, lo_open=True, hi_open=True)
_UNIT = _Range(lo=0.0, hi=1.0)
_INT_POSITIVE = _Range(lo=1)
_INT_NONNEGATIVE = _Range(lo=0)

_MATERIAL_RANGES = {
    "youngs_modulus": (_POSITIVE, "Pa"),
    "poisson_ratio": (_POISSON, ""),
    "density": (_POSITIVE, "kg/m^3"),
}


def _num(v: float) -> str:
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e15 else repr(float(v))


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
    """``[mesh]``: exactly one of ``file`` (absolute, existing) and ``box``; ``scale`` > 0."""

    file: Path | None = None
    box: BoxSpec | None = None
    scale: float = 1.0


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
    """``[damping]``: Rayleigh damping D = mass * M + stiffness * K (1/s and s, both >= 0)."""

    mass: float = 0.0
    stiffness: float = 0.0


@dataclass(frozen=True)
class ViscoelasticSpec:
    """``[viscoelastic]``: a Maxwell branch (standard linear solid) beside the elastic law.

    ``ratio`` = E_M / E >= 0 (0: no branch), ``relaxation_time`` tau > 0 in s.
    """

    ratio: float = 0.0
    relaxation_time: float = 0.1


@dataclass(frozen=True)
class DragSpec:
    """``[drag]``: surface drag per unit area, linear (Pa s/m) and quadratic (kg/m^3) in the
    normal velocity (both >= 0; see :mod:`petsoft.physics.drag`)."""

    linear: float = 0.0
    quadratic: float = 0.0


@dataclass(frozen=True)
class FrictionSpec:
    """``[friction]``: regularised dry friction ``dry`` (m/s^2, force per unit mass, >= 0) with
    regularisation ``speed`` (m/s, > 0) on the nodes of ``where`` (None: all nodes; see
    :mod:`petsoft.physics.friction`)."""

    dry: float = 0.0
    speed: float = 1e-3
    where: str | Expression | None = None


@dataclass(frozen=True)
class GravitySpec:
    """``[gravity]``: body acceleration in m/s^2 (default none)."""

    acceleration: Vec3 = (0.0, 0.0, 0.0)


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


def _zeros(variables: tuple[str, ...]) -> Expr3:
    z = parse_expression("0", source="<default>", variables=variables)
    return (z, z, z)


@dataclass(frozen=True)
class InitialSpec:
    """``[initial]``: displacement and velocity (expressions of x, y, z), or ``from_``.

    ``from_`` is the TOML key ``from``: None (use ``displacement``) or ``"static"`` (start from
    the static equilibrium under the loads; ``displacement`` is then not allowed).
    """

    displacement: Expr3 = field(default_factory=lambda: _zeros(SPACE))
    velocity: Expr3 = field(default_factory=lambda: _zeros(SPACE))
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
        if isinstance(self.friction.where, str):
            used.add(self.friction.where)
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
# Messages.

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_INDEXED_KEY = re.compile(r"[A-Za-z0-9_-]+(\[\d+\])*")


def key_part(k: str) -> str:
    """One part of a dotted parameter or key name as a message shows it: an array entry as
    ``key[i]``, any other key as TOML writes it (quoted when it needs quotes)."""
    return k if _INDEXED_KEY.fullmatch(k) else json.dumps(k)


def _type_name(v: Any) -> str:
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, int):
        return "an integer"
    if isinstance(v, float):
        return "a float"
    if isinstance(v, str):
        return "a string"
    if isinstance(v, list):
        return "an array"
    if isinstance(v, dict):
        return "a table"
    return f"a {type(v).__name__}"


def _show(v: Any) -> str:
    """A value as it would appear in the TOML file (shortened)."""
    try:
        text = _toml_value(v)
    except (TypeError, ValueError):
        text = repr(v)
    return text if len(text) <= 80 else text[:77] + "..."


def _suggest(word: str, choices: Iterable[str]) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return close[0] if close else ""


_MISSING: Any = object()


class _Reader:
    """Reads one TOML table ``name`` of file ``source``, with typed, range-checked getters."""

    def __init__(self, data: Mapping[str, Any], name: str, source: str):
        self.data = data
        self.name = name
        self.source = source

    def key(self, k: str | None = None) -> str:
        if k is None:
            return self.name
        return f"{self.name}.{key_part(k)}" if self.name else key_part(k)

    def header(self) -> str:
        if not self.name:
            return "the top level"
        return self.name if self.name.endswith("]") else f"[{self.name}]"

    def fail(self, k: str | None, message: str) -> NoReturn:
        raise ExperimentError(f"{self.source}: {self.key(k)}{message}")

    def wrong_type(self, k: str, value: Any, expected: str) -> NoReturn:
        self.fail(
            k,
            f" = {_show(value)} has the wrong type: expected {expected}, got {_type_name(value)}",
        )

    def check_keys(self, allowed: Sequence[str], note: str = "") -> None:
        for k in self.data:
            if k not in allowed:
                close = _suggest(k, allowed)
                hint = f"; did you mean {self.key(close)}?" if close else "."
                raise ExperimentError(
                    f"{self.source}: unknown key {self.key(k)}{hint} Valid keys in "
                    f"{self.header()}: {', '.join(allowed)}{note}"
                )

    def get(self, k: str, default: Any = _MISSING, what: str = "") -> Any:
        if k not in self.data:
            if default is _MISSING:
                self.fail(k, f" is missing{f' ({what})' if what else ''}")
            return default
        return self.data[k]

    def _check_number(self, k: str, v: Any, expected: str, rng: _Range, unit: str) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.wrong_type(k, v, expected)
        if not math.isfinite(v):
            self.fail(k, f" = {_show(v)} is not a finite number")
        if not rng.contains(v):
            unit_text = f" ({unit})" if unit else ""
            self.fail(
                k,
                f" = {_show(v)} is out of range: valid is {rng.text(k)}{unit_text}",
            )
        return v

    def number(self, k: str, default: Any = _MISSING, rng: _Range = _ANY, unit: str = "") -> Any:
        v = self.get(k, default, what=_describe(rng.text(k), unit))
        if v is default and k not in self.data:
            return default
        return float(self._check_number(k, v, "a number", rng, unit))

    def integer(self, k: str, default: Any = _MISSING, rng: _Range = _ANY) -> Any:
        v = self.get(k, default, what=f"an integer, {rng.text(k)}")
        if v is default and k not in self.data:
            return default
        if isinstance(v, bool) or not isinstance(v, int):
            self.wrong_type(k, v, f"an integer ({rng.text(k)})")
        return int(self._check_number(k, v, "an integer", rng, ""))

    def string(self, k: str, default: Any = _MISSING, what: str = "a string") -> Any:
        v = self.get(k, default, what=what)
        if v is default and k not in self.data:
            return default
        if not isinstance(v, str):
            self.wrong_type(k, v, what)
        if not v.strip():
            self.fail(k, f" is empty: expected {what}")
        return v

    def choice(self, k: str, choices: Sequence[str], default: Any = _MISSING) -> Any:
        listing = ", ".join(f'"{c}"' for c in choices)
        v = self.get(k, default, what=f"one of {listing}")
        if v is default and k not in self.data:
            return default
        if not isinstance(v, str):
            self.wrong_type(k, v, f"a string, one of {listing}")
        if v not in choices:
            close = _suggest(v, choices) or _suggest(v.lower(), choices)
            hint = f'; did you mean "{close}"?' if close else "."
            self.fail(k, f" = {_show(v)} is not a valid choice{hint} Valid: {listing}")
        return v

    def vector(
        self, k: str, default: Any = _MISSING, rng: _Range = _ANY, unit: str = "", n: int = 3
    ) -> Any:
        expected = f"an array of {n} numbers" + (f" ({unit})" if unit else "")
        v = self.get(k, default, what=expected)
        if v is default and k not in self.data:
            return default
        return self._vector_value(k, v, expected, rng, unit, n)

    def _vector_value(self, k, v, expected, rng, unit, n) -> tuple[float, ...]:
        if not isinstance(v, list) or len(v) != n:
            if isinstance(v, list):
                self.fail(k, f" = {_show(v)} has {len(v)} entries: expected {expected}")
            self.wrong_type(k, v, expected)
        for i, item in enumerate(v):
            self._check_number(f"{k}[{i}]", item, "a number", rng, unit)
        return tuple(float(item) for item in v)

    def expressions(
        self, k: str, variables: tuple[str, ...], default: Any = _MISSING, what: str = ""
    ) -> Any:
        expected = (
            f"an array of 3 expressions of {', '.join(variables)} (strings such as "
            f'"0.01*sin(20*t)", or numbers){f", {what}" if what else ""}'
        )
        v = self.get(k, default, what=expected)
        if v is default and k not in self.data:
            return default
        if not isinstance(v, list):
            self.wrong_type(k, v, expected)
        if len(v) != 3:
            self.fail(k, f" = {_show(v)} has {len(v)} entries: expected {expected}")
        return tuple(
            parse_expression(
                item,
                source=f"{self.source}: {self.key(k)}[{i}]",
                variables=variables,
                expect="number",
            )
            for i, item in enumerate(v)
        )

    def table(self, k: str, header: str | None = None) -> _Reader | None:
        """The sub-table ``k`` as a reader, or None when absent."""
        if k not in self.data:
            return None
        v = self.data[k]
        if not isinstance(v, dict):
            self.wrong_type(k, v, f"a table ({header or '[' + self.key(k) + ']'})")
        return _Reader(v, self.key(k), self.source)

    def table_array(self, k: str) -> list[_Reader]:
        """The array of tables ``[[k]]`` as readers (empty when absent)."""
        if k not in self.data:
            return []
        v = self.data[k]
        if isinstance(v, dict):
            self.fail(
                k,
                f" is a single table: write [[{self.key(k)}]] (double brackets), once per entry",
            )
        if not isinstance(v, list) or not all(isinstance(item, dict) for item in v):
            self.wrong_type(k, v, f"an array of tables ([[{self.key(k)}]])")
        return [_Reader(item, f"{self.key(k)}[{i}]", self.source) for i, item in enumerate(v)]


def _describe(range_text: str, unit: str) -> str:
    return f"{unit}, {range_text}" if unit else range_text


# ------------------------------------------------------------------------------------------------
# Loading.

_TOP_KEYS = (
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
_MATERIAL_KEYS = ("model", "youngs_modulus", "poisson_ratio", "density")
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
        raise ExperimentError(f"{source}: expected a table of sections, got {_type_name(data)}")
    base = Path(base_dir).resolve()
    top = _Reader(dict(data), "", source)
    top.check_keys(_TOP_KEYS)

    version = top.integer("format_version", FORMAT_VERSION)
    if version != FORMAT_VERSION:
        top.fail(
            "format_version",
            f" = {version} is not supported: this petsoft reads format_version = {FORMAT_VERSION}",
        )

    mesh = _read_mesh(top.table("mesh"), top, base)
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
    regions = _read_regions(top.table("region"))
    damping = _read_damping(top.table("damping"))
    gravity = _read_gravity(top.table("gravity"))
    boundaries = tuple(_read_boundary(r) for r in top.table_array("boundary"))
    for i, b in enumerate(boundaries):
        if springs is not None and b.compliance > 0.0:
            raise ExperimentError(
                f"{source}: boundary[{i}].compliance = {_show(b.compliance)}: elastic supports "
                "are implemented for [material] (continuum) models only; the fixed nodes of a "
                "[springs] model are rigid (remove compliance, or model the support by springs)"
            )
    initial = _read_initial(top.table("initial"))
    time = _read_time(top.table("time"))
    output = _read_output(top.table("output"), base)
    petsc = _read_petsc(top.table("petsc"))
    masses = tuple(_read_mass(r) for r in top.table_array("mass"))
    colliders = tuple(_read_collider(r) for r in top.table_array("collider"))
    viscoelastic = _read_viscoelastic(top.table("viscoelastic"))
    if viscoelastic.ratio > 0.0 and springs is not None:
        raise ExperimentError(
            f"{source}: [viscoelastic] ratio = {_num(viscoelastic.ratio)}: the standard linear "
            "solid acts on a continuum [material] model, not on [springs]; remove "
            "[viscoelastic] or set ratio = 0")
    drag = _read_drag(top.table("drag"))
    friction = _read_friction(top.table("friction"))

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
        drag=drag,
        friction=friction,
        format_version=version,
        path=Path(path) if path is not None else None,
        source=source,
        base_dir=base,
    )
    calibrate = _read_calibrate(top.table("calibrate"), experiment)
    experiment = dataclasses.replace(experiment, calibrate=calibrate)
    _check_drag_surface(experiment)
    return experiment


def _check_drag_surface(exp: Experiment) -> None:
    """Refuse drag (non-zero or calibrated) on a mass-spring mesh without triangles: drag acts
    on a surface. Reads the mesh's cells (only in that case; spring meshes are small)."""
    if exp.springs is None or exp.mesh.file is None:
        return
    keys = [f"drag.{k}" for k in ("linear", "quadratic")
            if getattr(exp.drag, k) != 0.0 or f"drag.{k}" in exp.calibrate]
    if not keys:
        return

    try:
        mesh = read_spring_mesh(exp.mesh.file, scale=exp.mesh.scale)
    except Exception:  # the model builder reports an unreadable mesh with its own message
        return
    if len(mesh.triangles) == 0:
        where = (f"{keys[0]} = {get_parameter(exp, keys[0]):g}" if keys[0] not in exp.calibrate
                 else f'calibrate."{keys[0]}"')
        raise ExperimentError(
            f"{exp.source}: {where}: drag needs a surface, and the mass-spring mesh "
            f"{exp.mesh.file} has no triangle cells (a line-only spring network); use "
            "[friction] dry or [damping] mass for a rope or pendulum")


def _read_mesh(r: _Reader | None, top: _Reader, base: Path) -> MeshSpec:
    if r is None:
        top.fail(
            "mesh",
            ' is missing: add [mesh] with file = "<mesh file>" or box = { size = [lx, ly, lz], '
            "cells = [nx, ny, nz] }",
        )
    r.check_keys(("file", "box", "scale"))
    if ("file" in r.data) == ("box" in r.data):
        both = "both are given" if "file" in r.data else "neither is given"
        raise ExperimentError(
            f'{r.source}: [mesh] needs exactly one of file = "<mesh file>" and box = '
            f"{{ size = [...], cells = [...] }}: {both}"
        )
    scale = r.number("scale", 1.0, _POSITIVE)
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
        return MeshSpec(file=file, scale=scale)
    box = r.table("box", header="an inline table { size = [lx, ly, lz], cells = [nx, ny, nz] }")
    assert box is not None
    box.check_keys(("size", "cells"))
    size = box.vector("size", rng=_POSITIVE, unit="mesh units")
    cells_raw = box.get("cells", what="an array of 3 integers >= 1")
    if not isinstance(cells_raw, list):
        box.wrong_type("cells", cells_raw, "an array of 3 integers, each >= 1")
    if len(cells_raw) != 3:
        box.fail(
            "cells",
            f" = {_show(cells_raw)} has {len(cells_raw)} entries: expected an array of 3 "
            "integers, each >= 1",
        )
    cells = []
    for i, c in enumerate(cells_raw):
        item = _Reader({f"cells[{i}]": c}, box.name, box.source)
        cells.append(item.integer(f"cells[{i}]", rng=_INT_POSITIVE))
    return MeshSpec(box=BoxSpec(size=size, cells=tuple(cells)), scale=scale)


def _material_values(r: _Reader) -> dict[str, Any]:
    values: dict[str, Any] = {}
    if "model" in r.data:
        values["model"] = r.choice("model", MATERIAL_MODELS)
    for k, (rng, unit) in _MATERIAL_RANGES.items():
        if k in r.data:
            values[k] = r.number(k, rng=rng, unit=unit)
    return values


def _read_material(r: _Reader | None) -> dict[str, MaterialSpec]:
    assert r is not None
    scalars = _Reader({k: v for k, v in r.data.items() if not isinstance(v, dict)}, r.name,
                      r.source)  # fmt: skip
    scalars.check_keys(_MATERIAL_KEYS, note=" (and [material.<region>] tables for regions)")
    for k in _MATERIAL_KEYS:
        if isinstance(r.data.get(k), dict):
            r.wrong_type(k, r.data[k], "a string" if k == "model" else "a number")
    values = _material_values(scalars)
    for k, (rng, unit) in _MATERIAL_RANGES.items():
        if k not in values:
            r.fail(k, f" is missing ({_describe(rng.text(k), unit)})")
    default = MaterialSpec(**values)
    result = {"default": default}
    for name, table in r.data.items():
        if not isinstance(table, dict):
            continue
        if name == "default":
            r.fail(name, " is reserved: the default material is [material] itself")
        sub = _Reader(table, r.key(name), r.source)
        for k, v in table.items():
            if isinstance(v, dict):
                sub.fail(
                    k,
                    f" is a table, but [{sub.name}] overrides the material of region "
                    f'"{name}" and takes only {", ".join(_MATERIAL_KEYS)}',
                )
        sub.check_keys(_MATERIAL_KEYS, note=f' (overrides of the default for region "{name}")')
        override = _material_values(sub)
        result[name] = dataclasses.replace(default, **override, overrides=frozenset(override))
    return result


def _read_regions(r: _Reader | None) -> dict[str, RegionSpec]:
    if r is None:
        return {}
    regions = {}
    for name, table in r.data.items():
        if not isinstance(table, dict):
            r.fail(
                name,
                f" = {_show(table)}: regions are tables: write [region.{key_part(name)}] "
                'with where = "<condition of x, y, z>"',
            )
        if not _is_region_name(name) or name != name.strip():
            r.fail(
                name,
                ": a region name must be an identifier (letters, digits, _) other than x, y, z, "
                "t, pi, default, Python keywords and the function names, so that a boundary's "
                "where can name it",
            )
        sub = _Reader(table, r.key(name), r.source)
        sub.check_keys(("where",))
        where = sub.string("where", what='a condition of x, y, z, e.g. "x < 0.1"')
        expr = parse_expression(
            where, source=f"{r.source}: {sub.key('where')}", variables=SPACE, expect="condition"
        )
        regions[name] = RegionSpec(name=name, where=expr)
    return regions


def _read_damping(r: _Reader | None) -> DampingSpec:
    if r is None:
        return DampingSpec()
    r.check_keys(("mass", "stiffness"))
    return DampingSpec(
        mass=r.number("mass", 0.0, _NONNEGATIVE, "1/s"),
        stiffness=r.number("stiffness", 0.0, _NONNEGATIVE, "s"),
    )


def _read_viscoelastic(r: _Reader | None) -> ViscoelasticSpec:
    if r is None:
        return ViscoelasticSpec()
    r.check_keys(("ratio", "relaxation_time"))
    return ViscoelasticSpec(
        ratio=r.number("ratio", 0.0, _NONNEGATIVE, "E_M / E"),
        relaxation_time=r.number("relaxation_time", 0.1, _POSITIVE, "s"),
    )


def _read_drag(r: _Reader | None) -> DragSpec:
    if r is None:
        return DragSpec()
    r.check_keys(("linear", "quadratic"))
    return DragSpec(
        linear=r.number("linear", 0.0, _NONNEGATIVE, "Pa s/m"),
        quadratic=r.number("quadratic", 0.0, _NONNEGATIVE, "kg/m^3"),
    )


def _read_where(r: _Reader, k: str) -> str | Expression:
    """A ``where``: a region name (bare identifier) or a condition of x, y, z."""
    text = r.string(k, what='a region name or a condition of x, y, z, e.g. "x < 1e-6"')
    if _is_region_name(text):
        return text.strip()
    return parse_expression(text, source=f"{r.source}: {r.key(k)}", variables=SPACE,
                            expect="condition")


def _read_friction(r: _Reader | None) -> FrictionSpec:
    if r is None:
        return FrictionSpec()
    r.check_keys(("dry", "speed", "where"))
    return FrictionSpec(
        dry=r.number("dry", 0.0, _NONNEGATIVE, "m/s^2"),
        speed=r.number("speed", 1e-3, _POSITIVE, "m/s"),
        where=_read_where(r, "where") if "where" in r.data else None,
    )


def _read_gravity(r: _Reader | None) -> GravitySpec:
    if r is None:
        return GravitySpec()
    r.check_keys(("acceleration",))
    return GravitySpec(acceleration=r.vector("acceleration", (0.0, 0.0, 0.0), unit="m/s^2"))


def _is_region_name(text: str) -> bool:
    s = text.strip()
    return s.isidentifier() and not keyword.iskeyword(s) and s not in _RESERVED_NAMES


def _read_boundary(r: _Reader) -> BoundarySpec:
    kind = r.choice("kind", BOUNDARY_KINDS)
    allowed = _BOUNDARY_KEYS[kind]
    for k in r.data:
        if k not in allowed:
            owners = [kd for kd, keys in _BOUNDARY_KEYS.items() if k in keys]
            close = _suggest(k, allowed)
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
            item = _Reader({f"components[{i}]": c}, r.name, r.source)
            item.choice(f"components[{i}]", COMPONENTS)
        if len(set(comps)) != len(comps):
            r.fail("components", f" = {_show(comps)} repeats a component: expected {expected}")
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
        spec = dataclasses.replace(
            spec, compliance=r.number("compliance", 0.0, _NONNEGATIVE, unit="m/Pa")
        )
    return spec


def _read_initial(r: _Reader | None) -> InitialSpec:
    if r is None:
        return InitialSpec()
    r.check_keys(("displacement", "velocity", "from"))
    from_ = r.choice("from", INITIAL_FROM, None)
    if from_ is not None and "displacement" in r.data:
        raise ExperimentError(
            f'{r.source}: [initial] has both from = "{from_}" and displacement: give one of them'
        )
    zeros = _zeros(SPACE)
    return InitialSpec(
        displacement=r.expressions("displacement", SPACE, zeros, what="in m"),
        velocity=r.expressions("velocity", SPACE, zeros, what="in m/s"),
        from_=from_,
    )


def _read_time(r: _Reader | None) -> TimeSpec | None:
    if r is None:
        return None
    r.check_keys(("end", "step", "integrator", "alpha_radius", "imex_slow_modes"))
    end = r.number("end", rng=_POSITIVE, unit="s")
    step = r.number("step", rng=_POSITIVE, unit="s")
    if step > end:
        r.fail("step", f" = {_show(step)} is larger than time.end = {_show(end)}")
    return TimeSpec(
        end=end,
        step=step,
        integrator=r.choice("integrator", INTEGRATORS, "be"),
        alpha_radius=r.number("alpha_radius", 0.5, _UNIT),
        imex_slow_modes=r.integer("imex_slow_modes", 6, _INT_POSITIVE),
    )


def _read_output(r: _Reader | None, base: Path) -> OutputSpec:
    if r is None:
        return OutputSpec(directory=(base / "out").resolve())
    r.check_keys(("directory", "every", "checkpoint_every", "probes"))
    directory = r.string("directory", "out", what="a directory, relative to the experiment file")
    probes_raw = r.get("probes", [])
    expected = "an array of points [[x, y, z], ...]"
    if not isinstance(probes_raw, list):
        r.wrong_type("probes", probes_raw, expected)
    probes = tuple(
        _Reader({f"probes[{i}]": p}, r.name, r.source)._vector_value(
            f"probes[{i}]", p, "an array of 3 numbers (a point [x, y, z])", _ANY, "", 3
        )
        for i, p in enumerate(probes_raw)
    )
    return OutputSpec(
        directory=(base / directory).resolve(),
        every=r.integer("every", 1, _INT_POSITIVE),
        checkpoint_every=r.integer("checkpoint_every", 0, _INT_NONNEGATIVE),
        probes=probes,
    )


_PETSC_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


def _petsc_value(r: _Reader, k: str, v: Any) -> str:
    if isinstance(v, bool):
        return "" if v else "false"
    if isinstance(v, str):
        return v
    if isinstance(v, (int, float)):
        if isinstance(v, float) and not math.isfinite(v):
            r.fail(k, f" = {_show(v)} is not a finite number")
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


def _read_petsc(r: _Reader | None) -> dict[str, str]:
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


def _read_springs(r: _Reader | None) -> SpringsSpec:
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
                r.fail(f"pairs[{n}]", f" = {_show(p)} is not valid: expected {expected}")
            out.append((p[0], p[1]))
        pairs = tuple(out)
    return SpringsSpec(
        stiffness=r.number("stiffness", rng=_POSITIVE, unit="N/m"),
        damping=r.number("damping", 0.0, _NONNEGATIVE, "N s/m"),
        bending=r.number("bending", None, _NONNEGATIVE),
        pairs=pairs,
        node_mass=r.number("node_mass", 0.0, _NONNEGATIVE, "kg"),
    )


def _read_mass(r: _Reader) -> MassSpec:
    r.check_keys(("at", "value"))
    return MassSpec(
        at=r.vector("at", unit="m, a reference point"),
        value=r.number("value", rng=_POSITIVE, unit="kg"),
    )


def _read_collider(r: _Reader) -> ColliderSpec:
    kind = r.choice("kind", COLLIDER_KINDS)
    allowed = _COLLIDER_KEYS[kind]
    r.check_keys(allowed, note=f' (for kind = "{kind}")')
    common = {
        "friction": r.number("friction", 0.0, _NONNEGATIVE),
        "stiffness": r.number("stiffness", None, _POSITIVE),
    }
    if kind == "sphere":
        return ColliderSpec(
            kind=kind,
            center=r.vector("center", unit="m"),
            radius=r.number("radius", rng=_POSITIVE, unit="m"),
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
        offset=r.number("offset", 0.0, _ANY, unit="m, along the normal"),
        **common,
    )


# ------------------------------------------------------------------------------------------------
# Named numeric parameters (calibration).


def _parameter_table(exp: Experiment) -> dict[str, tuple[float, _Range]]:
    """All named numeric parameters of ``exp``: name -> (current value, valid range)."""
    params: dict[str, tuple[float, _Range]] = {}
    if exp.material:
        default = exp.material["default"]
        for k, (rng, _unit) in _MATERIAL_RANGES.items():
            params[f"material.{k}"] = (getattr(default, k), rng)
        regions = [n for n in exp.material if n != "default"]
        regions += [n for n in exp.regions if n not in exp.material]
        for name in regions:
            spec = exp.material_for(name)
            for k, (rng, _unit) in _MATERIAL_RANGES.items():
                params[f"material.{key_part(name)}.{k}"] = (getattr(spec, k), rng)
    params["damping.mass"] = (exp.damping.mass, _NONNEGATIVE)
    params["damping.stiffness"] = (exp.damping.stiffness, _NONNEGATIVE)
    params["drag.linear"] = (exp.drag.linear, _NONNEGATIVE)
    params["drag.quadratic"] = (exp.drag.quadratic, _NONNEGATIVE)
    params["friction.dry"] = (exp.friction.dry, _NONNEGATIVE)
    for i, c in enumerate(COMPONENTS):
        params[f"gravity.acceleration.{c}"] = (exp.gravity.acceleration[i], _ANY)
    compliant = [b.compliance for b in exp.boundaries if b.kind == "fixed" and b.compliance > 0]
    if compliant:
        # one value shared by every elastic support (with_parameters sets them all)
        params["boundary.compliance"] = (compliant[0], _POSITIVE)
    for i, c in enumerate(exp.colliders):
        # a differentiable parameter of continuum models (mass-spring models honour the key)
        if c.kind == "plane" and exp.material:
            params[f"collider.{i}.offset"] = (c.offset, _ANY)
    if exp.springs is not None:
        s = exp.springs
        params["springs.stiffness"] = (s.stiffness, _POSITIVE)
        params["springs.damping"] = (s.damping, _NONNEGATIVE)
        params["springs.bending"] = (s.bending or 0.0, _NONNEGATIVE)
        params["springs.node_mass"] = (s.node_mass, _NONNEGATIVE)
    else:
        params["viscoelastic.ratio"] = (exp.viscoelastic.ratio, _NONNEGATIVE)
        params["viscoelastic.relaxation_time"] = (exp.viscoelastic.relaxation_time, _POSITIVE)
    return params


def parameter_names(experiment: Experiment) -> list[str]:
    """The dotted names of the numeric parameters that ``[calibrate]`` and
    :func:`with_parameters` accept, e.g. ``"material.youngs_modulus"``,
    ``"material.<region>.density"`` (for regions with a ``[material.<region>]`` table or a
    ``[region.<name>]``), ``"damping.mass"``, ``"gravity.acceleration.z"``,
    ``"springs.stiffness"``, ``"boundary.compliance"`` (when a fixed boundary has
    compliance > 0), ``"collider.<i>.offset"`` (for a plane collider),
    ``"viscoelastic.ratio"`` (continuum models)."""
    return list(_parameter_table(experiment))


def get_parameter(experiment: Experiment, name: str) -> float:
    """The current value of the named parameter (see :func:`parameter_names`)."""
    table = _parameter_table(experiment)
    if name not in table:
        raise ExperimentError(_unknown_parameter(experiment.source, name, table))
    return table[name][0]


def _unknown_parameter(source: str, name: str, table: Mapping[str, Any]) -> str:
    close = _suggest(name, table)
    hint = f'; did you mean "{close}"?' if close else ""
    note = ""
    parts = name.split(".")
    if parts[0] == "material" and len(parts) == 3:
        note = (
            f" (for a region that is a mesh physical group, add an empty [material.{parts[1]}] "
            "table so it can be calibrated)"
        )
    if name == "boundary.compliance":
        note = (
            ' (no [[boundary]] kind = "fixed" has compliance > 0: give the support an elastic '
            "compliance > 0 in the experiment to calibrate it)"
        )
    if parts[0] == "collider":
        note = (
            ' (collider.<i>.offset exists for [[collider]] kind = "plane" of [material] models '
            "only)"
        )
    return (
        f'{source}: "{name}" is not a numeric parameter of this experiment{hint}{note}. '
        f"Valid: {', '.join(table)}"
    )


def _split_parameter(name: str) -> list[str]:
    # Region names may be quoted ("material.\"my group\".density"); split outside quotes.
    return [p.strip('"') for p in re.findall(r'"[^"]*"|[^.]+', name)]


def with_parameters(experiment: Experiment, values: Mapping[str, float]) -> Experiment:
    """A copy of ``experiment`` with the named parameters set, validated again.

    Region materials that do not override a changed default parameter follow it.

    Raises
    ------
    ExperimentError
        For an unknown parameter name or an invalid value.
    """
    table = _parameter_table(experiment)
    data = experiment.to_dict()
    for name, value in values.items():
        if name not in table:
            raise ExperimentError(_unknown_parameter(experiment.source, name, table))
        parts = _split_parameter(name)
        if parts[0] == "boundary":
            # every elastic support shares the compliance
            for entry in data["boundary"]:
                if entry["kind"] == "fixed" and entry.get("compliance", 0.0) > 0.0:
                    entry["compliance"] = float(value)
            continue
        if parts[0] == "collider":
            data["collider"][int(parts[1])]["offset"] = float(value)
            continue
        if parts[0] == "gravity":
            acc = list(data.setdefault("gravity", {}).get("acceleration", [0.0, 0.0, 0.0]))
            acc[COMPONENTS.index(parts[2])] = float(value)
            data["gravity"]["acceleration"] = acc
            continue
        node = data
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = float(value)
    return experiment_from_dict(
        data, source=experiment.source, base_dir=experiment.base_dir, path=experiment.path
    )


def with_compliance(
    experiment: Experiment, compliance: float, boundaries: Sequence[int] | None = None
) -> Experiment:
    """A copy with ``compliance`` (m/Pa, > 0) on fixed boundaries: every one, or the
    ``[[boundary]]`` indices given. Turns rigid supports elastic (which ``set_parameters``
    cannot do in place), e.g. to try the ``boundary.compliance`` term.

    Raises
    ------
    ExperimentError
        For a compliance <= 0, an index that is not a fixed boundary, or no fixed boundary.
    """
    c = float(compliance)
    if not (math.isfinite(c) and c > 0.0):
        raise ExperimentError(
            f"{experiment.source}: compliance = {compliance!r}: an elastic support needs a "
            "finite compliance > 0 (m/Pa)"
        )
    fixed = [i for i, b in enumerate(experiment.boundaries) if b.kind == "fixed"]
    chosen = fixed if boundaries is None else [int(i) for i in boundaries]
    if not chosen:
        raise ExperimentError(
            f'{experiment.source}: no [[boundary]] kind = "fixed" to make elastic (compliance '
            "applies to fixed boundaries only)"
        )
    bad = [i for i in chosen if i not in fixed]
    if bad:
        raise ExperimentError(
            f'{experiment.source}: boundary[{bad[0]}] is not a [[boundary]] kind = "fixed": '
            f"compliance applies to fixed boundaries (here: {fixed})"
        )
    data = experiment.to_dict()
    for i in chosen:
        data["boundary"][i]["compliance"] = c
    return experiment_from_dict(
        data, source=experiment.source, base_dir=experiment.base_dir, path=experiment.path
    )


def with_plane_collider(
    experiment: Experiment,
    point: Sequence[float],
    normal: Sequence[float],
    stiffness: float | None = None,
    offset: float = 0.0,
) -> tuple[Experiment, int]:
    """A copy with one more ``[[collider]] kind = "plane"`` (validated like a file's); returns
    it and the new collider's index i (its parameter is ``collider.<i>.offset``)."""
    data = experiment.to_dict()
    plane: dict[str, Any] = {"kind": "plane", "point": [float(x) for x in point],
                             "normal": [float(x) for x in normal], "offset": float(offset)}
    if stiffness is not None:
        plane["stiffness"] = float(stiffness)
    data.setdefault("collider", []).append(plane)
    new = experiment_from_dict(
        data, source=experiment.source, base_dir=experiment.base_dir, path=experiment.path
    )
    return new, len(new.colliders) - 1


def _flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in table.items():
        name = f"{prefix}.{k}" if prefix else k
        if isinstance(v, dict):
            out.update(_flatten(v, name))
        else:
            out[name] = v
    return out


def _read_calibrate(r: _Reader | None, exp: Experiment) -> dict[str, tuple[float, float]]:
    if r is None:
        return {}
    table = _parameter_table(exp)
    result: dict[str, tuple[float, float]] = {}
    for name, bounds in _flatten(r.data).items():
        key = f'calibrate."{name}"'
        if name not in table:
            raise ExperimentError(_unknown_parameter(f"{r.source}: {key}", name, table))
        value, rng = table[name]
        expected = "an array [lower, upper] of two numbers with lower < upper"
        if not isinstance(bounds, list) or len(bounds) != 2:
            raise ExperimentError(
                f"{r.source}: {key} = {_show(bounds)} has the wrong type: expected {expected}"
            )
        for b in bounds:
            if isinstance(b, bool) or not isinstance(b, (int, float)) or not math.isfinite(b):
                raise ExperimentError(
                    f"{r.source}: {key} = {_show(bounds)}: bound {_show(b)} is not a finite "
                    f"number; expected {expected}"
                )
        lo, hi = float(bounds[0]), float(bounds[1])
        if not lo < hi:
            raise ExperimentError(f"{r.source}: {key} = {_show(bounds)}: expected lower < upper")
        short = name.rsplit(".", 1)[-1]
        for b in (lo, hi):
            if not rng.contains(b):
                raise ExperimentError(
                    f"{r.source}: {key} = {_show(bounds)}: the bound {_show(b)} is not a valid "
                    f"value of {name} (valid is {rng.text(short)})"
                )
        if not lo <= value <= hi:
            raise ExperimentError(
                f"{r.source}: {key} = {_show(bounds)}: the current value {name} = "
                f"{_show(value)} (the starting point of the calibration) is outside the bounds"
            )
        result[name] = (lo, hi)
    return result


# ------------------------------------------------------------------------------------------------
# Writing.


def _path_text(p: Path, relative_to: str | os.PathLike | None) -> str:
    if relative_to is None:
        return p.as_posix()
    try:
        return Path(os.path.relpath(p, Path(relative_to).resolve())).as_posix()
    except ValueError:  # another drive on Windows
        return p.as_posix()


def _literals(exprs: Iterable[Expression]) -> list[str | int | float]:
    return [e.literal for e in exprs]


def _to_dict(exp: Experiment, relative_to: str | os.PathLike | None) -> dict[str, Any]:
    d: dict[str, Any] = {"format_version": exp.format_version}
    mesh: dict[str, Any] = {}
    if exp.mesh.file is not None:
        mesh["file"] = _path_text(exp.mesh.file, relative_to)
    if exp.mesh.box is not None:
        mesh["box"] = {"size": list(exp.mesh.box.size), "cells": list(exp.mesh.box.cells)}
    mesh["scale"] = exp.mesh.scale
    d["mesh"] = mesh
    if exp.material:
        default = exp.material["default"]
        material: dict[str, Any] = {"model": default.model}
        material.update({k: getattr(default, k) for k in _MATERIAL_RANGES})
        for name, spec in exp.material.items():
            if name != "default":
                material[name] = {
                    k: getattr(spec, k) for k in _MATERIAL_KEYS if k in spec.overrides
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
    d["gravity"] = {"acceleration": list(exp.gravity.acceleration)}
    if exp.viscoelastic != ViscoelasticSpec():
        d["viscoelastic"] = dataclasses.asdict(exp.viscoelastic)
    if exp.drag != DragSpec():
        d["drag"] = {"linear": exp.drag.linear, "quadratic": exp.drag.quadratic}
    if exp.friction != FrictionSpec():
        fr: dict[str, Any] = {"dry": exp.friction.dry, "speed": exp.friction.speed}
        if exp.friction.where is not None:
            w = exp.friction.where
            fr["where"] = w if isinstance(w, str) else w.literal
        d["friction"] = fr
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


def _toml_string(s: str) -> str:
    out = []
    for ch in s:
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ch in "\b\t\n\f\r":
            out.append({"\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_key(k: str) -> str:
    return k if _BARE_KEY.fullmatch(k) else _toml_string(k)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)  # shortest round-trip repr; always a valid TOML float
    if isinstance(v, str):
        return _toml_string(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, os.PathLike):
        return _toml_string(os.fspath(v))
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _is_table_array(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def _dump_table(lines: list[str], table: Mapping[str, Any], path: list[str]) -> None:
    for k, v in table.items():
        if not isinstance(v, dict) and not _is_table_array(v):
            lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
    for k, v in table.items():
        name = ".".join(_toml_key(p) for p in [*path, k])
        if isinstance(v, dict):
            scalars = any(not isinstance(x, dict) and not _is_table_array(x) for x in v.values())
            if scalars or not v:  # a table holding only sub-tables needs no header of its own
                lines.extend(["", f"[{name}]"])
            _dump_table(lines, v, [*path, k])
        elif _is_table_array(v):
            for item in v:
                lines.extend(["", f"[[{name}]]"])
                _dump_table(lines, item, [*path, k])


def dumps_toml(data: Mapping[str, Any]) -> str:
    """Serialise a dict of TOML values (tables, arrays of tables, scalars, arrays) to TOML text."""
    lines: list[str] = []
    _dump_table(lines, data, [])
    return "\n".join(lines).lstrip("\n") + "\n"


def write_toml(experiment: Experiment, path: str | os.PathLike) -> None:
    """Write ``experiment`` as a TOML experiment file that :func:`load_experiment` reads back
    equal; paths inside it are written relative to the file's directory."""
    target = Path(path)
    text = "# petsoft experiment (formats.md section 1), written by petsoft\n" + dumps_toml(
        experiment.to_dict(relative_to=target.parent.resolve())
    )
    target.write_text(text, encoding="utf-8")
