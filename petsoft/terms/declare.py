"""What a physics term declares about itself, as plain data.

This module owns the record types of the term registry (:mod:`petsoft.terms`): :class:`Key` (one
key of the experiment file a term reads), :class:`Parameter` (one parameter diagnose proposes and
calibration fits), :class:`Proposal` (how ``petsoft diagnose`` offers the term) and :class:`Term`
(all of it under the vocabulary name). They hold numbers, strings and tuples only, so that every
layer may read them (the experiment reader, physics, calibration, diagnosis) and none depends on
another through them.

Bounds and starting values of a proposal are expressions of the experiment-file language
(:mod:`petsoft.experiment.expressions`) in the *scales* the diagnosis measures on the model and
the data (``mass``, ``area``, ``length``, ``cell``, ``speed``, ``speed_max``, ``frequency``,
``end``, ``youngs_modulus``, ``start``, ...); the diagnosis evaluates them. Keeping them as text
keeps the declaration data (no code runs at import) and lets a message quote them.
"""

from __future__ import annotations

from dataclasses import dataclass

#: What a key's table is: ``"table"`` (``[name]``), ``"array"`` (``[[name]]``, one entry of an
#: array of tables) or ``"named"`` (``[name.<label>]``, one table per user-chosen label).
SECTIONS = ("table", "array", "named")
#: The value types of a key.
TYPES = ("number", "vector", "choice", "where")
#: How a parameter varies over its bounds for an optimiser that scales them.
SCALES = ("linear", "log")
#: How diagnose proposes a term: ``"value"`` (coefficients from their zero value), ``"switch"``
#: (a model switch or a placed object: one more simulation, no derivative at zero) or
#: ``"region"`` (a region placed in space with its own material value).
KINDS = ("value", "switch", "region")
#: How a proposed term is ranked (:mod:`petsoft.diagnosis.candidates`): the score test from the
#: exact sensitivities, the same with finite-difference columns, or the whole change of a switch.
RANKINGS = ("score", "score-fd", "switch")
#: What a term's builder (``Term.builds``) makes: ``"potential"``, a nodal energy term of the
#: model's potential (``build(experiment, dmesh, resolver, dirichlet)`` -> a
#: :class:`~petsoft.physics.term.NodalTerm` or None, as a package's term:
#: :func:`petsoft.physics.model.build_model`); ``"velocity"``, a velocity law's class
#: (:mod:`petsoft.physics.velocity_law`, summed by
#: :class:`petsoft.dynamics.velocity.VelocityTerms`); ``"rayleigh"``, the matrix a Rayleigh
#: term's coefficient scales in D (a :class:`petsoft.dynamics.rayleigh.RayleighLaw`).
CONTRIBUTIONS = ("potential", "velocity", "rayleigh")


@dataclass(frozen=True)
class Key:
    """One key of the experiment file (formats.md section 1) that a term reads.

    Attributes
    ----------
    table : str
        The table, as TOML names it: ``"damping"``, ``"boundary"``, ``"region"``, ...
    key : str
        The key in it.
    type : {"number", "vector", "choice", "where"}
        A float, three floats, one of ``choices``, or a region name / condition of x, y, z.
    default : float, tuple, str or None
        Its value when absent (None: no default, e.g. a required ``where``).
    unit : str
        SI unit (``""`` for a ratio or a non-number).
    minimum : float or None
        The smallest valid value (None: unbounded below).
    open : bool
        Whether ``minimum`` itself is excluded (``> 0`` rather than ``>= 0``).
    section : {"table", "array", "named"}
        What ``table`` is (:data:`SECTIONS`).
    only : str
        For an array of tables, the ``kind`` of entry the key belongs to (``"fixed"``,
        ``"plane"``), else ``""``.
    choices : tuple of str
        The valid values of a ``"choice"`` key.
    text : str
        How messages say the unit when it is more than ``unit`` (``"E_M / E"``), else ``""``.
    at_minimum : str
        What the term is at ``minimum`` when that is another model, built otherwise (a rigid
        support is a Dirichlet condition, not a spring), in words for messages; ``""`` when the
        minimum is a value like any other. A model cannot be changed into the other in place,
        so a parameter set in place (``set_parameters``) must then exceed the minimum.
    """

    table: str
    key: str
    type: str = "number"
    default: float | tuple | str | None = 0.0
    unit: str = ""
    minimum: float | None = None
    open: bool = False
    section: str = "table"
    only: str = ""
    choices: tuple[str, ...] = ()
    text: str = ""
    at_minimum: str = ""

    @property
    def dotted(self) -> str:
        """``table.key`` (``table.<label>.key`` for a named table)."""
        return (f"{self.table}.<label>.{self.key}" if self.section == "named"
                else f"{self.table}.{self.key}")


@dataclass(frozen=True)
class Parameter:
    """One parameter a term adds to ``[calibrate]`` when diagnose proposes it.

    Attributes
    ----------
    name : str
        The dotted parameter name (:func:`petsoft.experiment.parameter_names`); ``{region}`` and
        ``{index}`` stand for the region or collider the proposal adds.
    unit : str
        SI unit.
    lower, upper : str
        Calibration bounds: expressions of the scales (module docstring).
    scale : {"linear", "log"}
        Whether the bounds span orders of magnitude (``"log"``).
    tested : bool
        Whether the score test is about it (a relaxation time is fitted, not tested: it is
        undefined while its branch is off).
    fd_step : float or None
        The finite-difference step of a ``"score-fd"`` ranking.
    """

    name: str
    unit: str
    lower: str
    upper: str
    scale: str = "linear"
    tested: bool = True
    fd_step: float | None = None


@dataclass(frozen=True)
class Proposal:
    """How ``petsoft diagnose`` proposes a term.

    Attributes
    ----------
    kind : {"value", "switch", "region"}
        :data:`KINDS`.
    ranking : {"score", "score-fd", "switch"}
        :data:`RANKINGS`.
    parameters : tuple of Parameter
        What it adds to ``[calibrate]``.
    settings : tuple of (str, str or float)
        Dotted experiment keys it sets and their values (expressions of the scales, or a
        string value such as a material model).
    start : str
        An expression of the scales the parameters' bounds may use as ``start`` (the value the
        term is switched on at), ``""`` when they use none.
    region : str
        The name of the region a ``"region"`` proposal adds.
    note : str
        Words added to the vocabulary's meaning in the candidate's reason, a
        :meth:`str.format` template of the scales.
    continuum_only : bool
        Whether only a continuum model (``[material]``) can carry the term.
    """

    kind: str
    ranking: str = "score"
    parameters: tuple[Parameter, ...] = ()
    settings: tuple[tuple[str, str | float], ...] = ()
    start: str = ""
    region: str = ""
    note: str = ""
    continuum_only: bool = False


@dataclass(frozen=True)
class Term:
    """Everything petsoft knows about one physics term, under its vocabulary name.

    Attributes
    ----------
    name : str
        The vocabulary name (formats.md section 3), e.g. ``"damping.mass"``.
    meaning : str
        What the report says it is (report.json's vocabulary, report.md).
    keys : tuple of Key
        The experiment keys that set it.
    proposal : Proposal
        How diagnose proposes it.
    hints : tuple of (str, str)
        ``(evidence, words)``: what the hints (:func:`petsoft.diagnosis.evidence.suggest_physics`)
        say when that evidence points at the term, a :meth:`str.format` template of the
        evidence's numbers (:meth:`hint`).
    contributes : str
        What its builder makes (:data:`CONTRIBUTIONS`), ``""`` when it has none declared.
    builds : str
        ``"module:name"`` of its builder, imported by the layer that builds it (this package
        imports nothing else of petsoft: a name, not the object).
    surface : bool
        Whether it acts through the body's surface only: a mass-spring network of edges (no
        triangles) cannot carry it, and the experiment reader refuses it there; its law's
        ``on_surface`` (:mod:`petsoft.physics.velocity_law`) is this.
    """

    name: str
    meaning: str
    keys: tuple[Key, ...]
    proposal: Proposal
    hints: tuple[tuple[str, str], ...] = ()
    contributes: str = ""
    builds: str = ""
    surface: bool = False

    @property
    def where_key(self) -> str:
        """The dotted key of its ``"where"`` key in a table of its own (``"friction.where"``):
        the nodes it acts on; ``""`` when it has none. A velocity law's ``where``
        (:mod:`petsoft.physics.velocity_law`)."""
        return next((k.dotted for k in self.keys if k.type == "where" and k.section == "table"),
                    "")

    @property
    def setting_keys(self) -> tuple[tuple[str, str], ...]:
        """``((key, dotted key), ...)`` of its number keys after the first, its coefficient
        (``(("speed", "friction.speed"),)``): the numbers a velocity law is built with besides
        its coefficient, its ``settings`` (:mod:`petsoft.physics.velocity_law`)."""
        return tuple((k.key, k.dotted) for k in self.keys[1:] if k.type == "number")

    def hint(self, evidence: str, **values) -> str:
        """The hint's words for ``evidence`` with ``values`` filled in; a KeyError names the
        evidence this term declares."""
        for name, words in self.hints:
            if name == evidence:
                return words.format(**values)
        raise KeyError(f"{self.name}: no hint for evidence {evidence!r} (declared: "
                       f"{[n for n, _ in self.hints]})")

    def __post_init__(self):
        # A declaration error is a programming error of the term's module: fail at import.
        for k in self.keys:
            if k.type not in TYPES or k.section not in SECTIONS:
                raise ValueError(f"{self.name}: key {k.dotted}: type {k.type!r} / section "
                                 f"{k.section!r} not in {TYPES} / {SECTIONS}")
            if k.at_minimum and (k.type != "number" or k.minimum is None or k.open):
                raise ValueError(f"{self.name}: key {k.dotted}: at_minimum describes a number's "
                                 "closed minimum (minimum given, open False)")
        p = self.proposal
        if p.kind not in KINDS or p.ranking not in RANKINGS:
            raise ValueError(f"{self.name}: proposal kind {p.kind!r} / ranking {p.ranking!r} "
                             f"not in {KINDS} / {RANKINGS}")
        for q in p.parameters:
            if q.scale not in SCALES:
                raise ValueError(f"{self.name}: parameter {q.name}: scale {q.scale!r} not in "
                                 f"{SCALES}")
        if bool(self.contributes) != bool(self.builds) or (
                self.contributes and (self.contributes not in CONTRIBUTIONS
                                      or self.builds.count(":") != 1)):
            raise ValueError(f"{self.name}: contributes {self.contributes!r} (one of "
                             f"{CONTRIBUTIONS}) and builds {self.builds!r} ('module:name') "
                             "are given together")
        if (p.kind == "region") != bool(p.region):
            raise ValueError(f"{self.name}: a region proposal, and only one, names its region")
