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
:mod:`petsoft.diagnosis.candidates`). What builds its force or energy is not declared here yet:
that is still physics/, dynamics/velocity.py and the experiment's dataclasses.
"""

from __future__ import annotations

from importlib import import_module

from petsoft.terms.declare import KINDS, RANKINGS, SCALES, Key, Parameter, Proposal, Term

__all__ = ["KINDS", "RANKINGS", "SCALES", "TERMS", "Key", "Parameter", "Proposal", "Term",
           "keys_of", "term"]

#: The term modules, in the vocabulary's order.
_MODULES = ("damping_mass", "damping_stiffness", "gravity", "material_nonlinear",
            "material_heterogeneous", "material_viscoelastic", "boundary_compliance",
            "mass_added", "drag_linear", "drag_quadratic", "friction_dry", "contact_plane")


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


#: name -> Term, in the vocabulary's order.
TERMS: dict[str, Term] = _collect()


def term(name: str) -> Term:
    """The term called ``name``; a KeyError names the known ones."""
    try:
        return TERMS[name]
    except KeyError:
        raise KeyError(f"{name!r} is no physics term (known: {', '.join(TERMS)})") from None


def keys_of(table: str) -> tuple[Key, ...]:
    """Every key the terms declare in the experiment table ``table`` (in the registry's order,
    each once): e.g. ``keys_of("damping")`` is ``[damping] mass`` and ``stiffness``."""
    seen: dict[tuple[str, str], Key] = {}
    for t in TERMS.values():
        for k in t.keys:
            if k.table == table:
                seen.setdefault((k.key, k.section, k.only), k)
    return tuple(seen.values())
