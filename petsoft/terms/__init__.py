"""The physics terms, one module each: what each declares about itself (issue 38, item 1).

A term module (``petsoft/terms/<name>.py``) holds one :class:`~petsoft.terms.declare.Term`,
``TERM``: its vocabulary name and meaning (report.json, report.md), the experiment keys that set
it (formats.md section 1), the parameters diagnose proposes for it with their bounds, units and
scales, how diagnose proposes it, and the evidence that points at it. This package imports
nothing else of petsoft, so every layer may read it: the experiment reader (its keys), the
diagnosis (the vocabulary, the candidates' parameters and bounds).

:data:`TERMS` is the registry, in the vocabulary's order (formats.md section 3 lists it; the
order is the diagnosis' tie-break, so a new term goes at the end). Adding a term is one module
here plus its line in :data:`_MODULES`: the report's vocabulary, formats.md's check and the
experiment reader (for keys of the tables terms own) follow, and diagnose proposes a term of
values from its declaration alone (a switch or a region still needs its placement rule in
:mod:`petsoft.diagnosis.candidates`). What builds a term's contribution is declared by name
(``Term.builds``, imported by :func:`builders` when the model is built): the nodal energy terms
(``boundary.compliance``, ``contact.plane``), the velocity laws (``drag.*``, ``friction.dry``)
and the Rayleigh damping (``damping.*``) are made from their declarations alone; the elastic
law's materials, the mass and the loads are still made where their kind of contribution is
assembled (physics/model.py, dynamics/).

**Terms from the user's own package** (formats.md section 1, "Terms from other packages"): an
installed distribution that declares an entry point in the group ``petsoft.terms``::

    [project.entry-points."petsoft.terms"]
    foundation = "petsoft_foundation.term"

names a module that holds ``TERM`` (a :class:`Term`, like a built-in one) and ``build(experiment,
dmesh, resolver, dirichlet)``: the term's force, a :class:`~petsoft.physics.term.NodalTerm` and
:class:`~petsoft.physics.term.ParametricTerm` (or None when the experiment does not use it).
Its values live in its own top-level tables, declared by its keys (``section = "table"`` only):
the reader validates them, ``[calibrate]`` and diagnose name its numbers ``table.key``. The
entry points are loaded once, when this package is first imported, and appended to
:data:`TERMS` after the built-in terms; :data:`PLUGINS` holds them. A malformed module (no
``TERM``, no ``build``, a key in another section, a table a built-in term reads) or a name that
clashes with a built-in or with another package's term is an :class:`ImportError` naming the
package.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from importlib import import_module
from importlib.metadata import entry_points

from petsoft.terms.declare import (
    CONTRIBUTIONS,
    KINDS,
    RANKINGS,
    SCALES,
    Key,
    Parameter,
    Proposal,
    Term,
)

__all__ = ["CONTRIBUTIONS", "GROUP", "KINDS", "PLUGINS", "RANKINGS", "SCALES", "TERMS", "Key",
           "Parameter", "Plugin", "Proposal", "Term", "builders", "coefficients", "keys_of",
           "load_plugin", "plugin_tables", "term", "value_of"]

#: The entry-point group of terms from other packages.
GROUP = "petsoft.terms"

#: The term modules, in the vocabulary's order.
_MODULES = ("damping_mass", "damping_stiffness", "gravity", "material_nonlinear",
            "material_heterogeneous", "material_viscoelastic", "boundary_compliance",
            "mass_added", "drag_linear", "drag_quadratic", "friction_dry", "contact_plane",
            "gravity_direction")


def _collect() -> dict[str, Term]:
    out: dict[str, Term] = {}
    for module in _MODULES:
        t = import_module(f"petsoft.terms.{module}").TERM
        if t.name in out:
            raise ValueError(f"petsoft.terms.{module}: term {t.name!r} is declared twice")
        if module != t.name.replace(".", "_"):
            raise ValueError(f"petsoft.terms.{module} declares {t.name!r}: a term lives in the "
                             "module of its name")
        out[t.name] = t
    return out


@dataclass(frozen=True)
class Plugin:
    """A term from another package (module docstring).

    Attributes
    ----------
    term : Term
        Its declaration (``TERM``).
    build : callable
        ``build(experiment, dmesh, resolver, dirichlet)``: its nodal term on this rank, or None.
    package : str
        The distribution that declares the entry point (what messages name).
    module : str
        The entry point's value (``package.module``).
    """

    term: Term
    build: Callable
    package: str
    module: str

    @property
    def tables(self) -> tuple[str, ...]:
        """The experiment tables its keys live in."""
        return tuple(dict.fromkeys(k.table for k in self.term.keys))

    @property
    def parameter_names(self) -> set[str]:
        """``table.key`` of its number keys: the parameters it may have."""
        return number_keys(self.term)


def number_keys(t: Term) -> set[str]:
    """``table.key`` of term ``t``'s number keys (a package's term's possible parameters)."""
    return {f"{k.table}.{k.key}" for k in t.keys if k.type == "number"}


def load_plugin(ep, builtin: dict[str, Term], found: dict[str, Plugin]) -> Plugin:
    """The :class:`Plugin` of the entry point ``ep`` (an :class:`importlib.metadata.EntryPoint`),
    checked against the built-in terms ``builtin`` and the packages' terms ``found`` so far.

    Raises
    ------
    ImportError
        Naming the package: the module cannot be loaded, has no ``TERM`` or ``build``, its
        term's name or a table of its keys is taken, a key is not of its own table, a
        parameter is none of its number keys, or it is not proposed by its values.
    """
    package = ep.dist.name if getattr(ep, "dist", None) is not None else "?"
    where = f"petsoft.terms entry point {ep.name!r} = {ep.value!r} of package {package!r}"
    try:
        module = ep.load()
    except Exception as exc:   # whatever the user's module raises: say whose it is
        raise ImportError(f"{where}: cannot be loaded: {type(exc).__name__}: {exc}") from exc
    t, build = getattr(module, "TERM", None), getattr(module, "build", None)
    if not isinstance(t, Term):
        raise ImportError(f"{where}: the module has no TERM = petsoft.terms.Term(...) (got "
                          f"{type(t).__name__})")
    if not callable(build):
        raise ImportError(f"{where}: the module has no build(experiment, dmesh, resolver, "
                          "dirichlet) function (the term's force)")
    if t.name in builtin:
        raise ImportError(f"{where}: term {t.name!r} clashes with petsoft's built-in term of "
                          "that name; rename it")
    if t.name in found:
        raise ImportError(f"{where}: term {t.name!r} is also declared by package "
                          f"{found[t.name].package!r}")
    if not t.keys or not t.proposal.parameters:
        raise ImportError(f"{where}: term {t.name!r} declares no keys or no parameters")
    taken = {k.table for b in builtin.values() for k in b.keys}
    taken |= {table for p in found.values() for table in p.tables}
    for k in t.keys:
        if k.section != "table":
            raise ImportError(f"{where}: key {k.dotted}: a package's term reads keys of its own "
                              f'top-level table (section = "table"), not {k.section!r}')
        if k.table in taken:
            raise ImportError(f"{where}: key {k.dotted}: table [{k.table}] belongs to another "
                              "term; a package's term reads a table of its own")
    names = number_keys(t)
    for q in t.proposal.parameters:
        if q.name not in names:
            raise ImportError(f"{where}: parameter {q.name!r} is none of its number keys "
                              f"({', '.join(sorted(names))})")
    if t.builds or t.contributes:
        raise ImportError(f"{where}: term {t.name!r}: a package's term is built by its module's "
                          "build(), not by Term.builds / contributes")
    if t.proposal.kind != "value":
        raise ImportError(f"{where}: term {t.name!r}: a package's term is proposed by its "
                          f'values (kind = "value"), not {t.proposal.kind!r}')
    return Plugin(t, build, package, ep.value)


def _plugins(builtin: dict[str, Term]) -> dict[str, Plugin]:
    found: dict[str, Plugin] = {}
    for ep in sorted(entry_points(group=GROUP), key=lambda e: (e.name, e.value)):
        p = load_plugin(ep, builtin, found)
        found[p.term.name] = p
    return found


_BUILTIN = _collect()
#: name -> Plugin: the terms of other packages (module docstring), loaded once.
PLUGINS: dict[str, Plugin] = _plugins(_BUILTIN)
#: name -> Term, in the vocabulary's order (the built-in terms, then the packages' terms).
TERMS: dict[str, Term] = {**_BUILTIN, **{n: p.term for n, p in PLUGINS.items()}}


def plugin_tables() -> dict[str, Plugin]:
    """table -> the package's term that owns the top-level table ``[table]``."""
    return {table: p for p in PLUGINS.values() for table in p.tables}


def term(name: str) -> Term:
    """The term called ``name``; a KeyError names the known ones."""
    try:
        return TERMS[name]
    except KeyError:
        raise KeyError(f"{name!r} is no physics term (known: {', '.join(TERMS)})") from None


def builders(contribution: str) -> list[tuple[Term, Callable]]:
    """The built-in terms that contribute ``contribution`` (:data:`CONTRIBUTIONS`), in the
    registry's order, each with its builder (``Term.builds``) imported: called by the layer
    that makes that kind of contribution, so this package imports no other at its import."""
    if contribution not in CONTRIBUTIONS:
        raise ValueError(f"contribution {contribution!r} is none of {CONTRIBUTIONS}")
    out = []
    for t in _BUILTIN.values():
        if t.contributes == contribution:
            module, name = t.builds.split(":")
            out.append((t, getattr(import_module(module), name)))
    return out


def coefficients(experiment, names) -> dict[str, float]:
    """name -> the value ``experiment`` (a read experiment) gives the first key of each term of
    ``names``: the coefficient of a term whose force is linear in one number (``[damping]
    mass``, ``[drag] linear``, ...)."""
    return {name: float(value_of(experiment, term(name).keys[0].dotted)) for name in names}


def value_of(experiment, dotted: str):
    """The value ``experiment`` (a read experiment) gives the key ``table.key`` of a table a
    built-in term reads (``"friction.where"``: ``experiment.friction.where``)."""
    table, key = dotted.split(".")
    return getattr(getattr(experiment, table), key)


def keys_of(table: str) -> tuple[Key, ...]:
    """Every key the terms declare in the experiment table ``table`` (in the registry's order,
    each once): e.g. ``keys_of("damping")`` is ``[damping] mass`` and ``stiffness``."""
    seen: dict[tuple[str, str], Key] = {}
    for t in TERMS.values():
        for k in t.keys:
            if k.table == table:
                seen.setdefault((k.key, k.section, k.only), k)
    return tuple(seen.values())
