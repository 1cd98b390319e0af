"""The term registry (petsoft.terms) is the one place a physics term is declared.

The names it declares are the report's vocabulary, the vocabulary table of formats.md section 3,
what the candidates of ``petsoft diagnose`` build, and its keys are what the experiment reader
accepts (and formats.md's full example shows) for those terms; :func:`mismatches` checks all of
it, and is shown to catch a term declared in the registry but nowhere else, and one taken out of
the registry but still built elsewhere. The declared bounds are checked against the closed forms
their comments state. No PETSc solve: a mesh is never built.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import tomllib

import petsoft
from petsoft.calibration.scaling import ParameterScaling
from petsoft.diagnosis.candidates import build_candidates
from petsoft.diagnosis.report import PHYSICS
from petsoft.errors import ExperimentError
from petsoft.experiment import experiment_from_dict
from petsoft.experiment.parameters import parameter_table, parameter_unit
from petsoft.experiment.ranges import key_range
from petsoft.terms import TERMS, Key, Parameter, Proposal, Term, keys_of

DOC = (Path(petsoft.__file__).parent / "formats.md").read_text()

#: The tables whose every key belongs to a term (formats.md's full example shows them all).
OWNED = ("damping", "drag", "friction", "viscoelastic", "gravity")

SCALES = {"mass": 2.0, "area": 0.5, "length": 0.4, "cell": 0.02, "speed": 0.03,
          "speed_max": 0.2, "frequency": 5.0}


def _base() -> dict:
    """A continuum model where every term can be proposed: linear law, a rigid fixed support,
    no damping, drag, friction or viscoelastic branch."""
    return {"mesh": {"box": {"size": [0.4, 0.04, 0.04], "cells": [4, 1, 1]}},
            "material": {"model": "linear", "youngs_modulus": 1.0e6, "poisson_ratio": 0.3,
                         "density": 1000.0},
            "gravity": {"acceleration": [0.0, 0.0, -9.81]},
            "boundary": [{"kind": "fixed", "where": "x < 1e-6"}],
            "time": {"end": 0.1, "step": 0.01}}


def _candidates(gravity=(0.0, 0.0, -9.81)):
    """The candidates of :func:`_base` with ``gravity`` stated: every term but one of gravity's
    two (``gravity.direction`` where gravity is stated, ``gravity`` where it is not)."""
    exp = experiment_from_dict({**_base(), "gravity": {"acceleration": list(gravity)}},
                               source="terms-test", base_dir=Path.cwd())
    sphere = {"center": [0.3, 0.02, 0.02], "radius": 0.05}
    plane = {"point": [0.0, 0.0, -0.01], "normal": [0.0, 0.0, 1.0], "excess": 0.003}
    return exp, *build_candidates(exp, evidence_region=sphere, stiffness_region=sphere,
                                  density_region=sphere, scales=SCALES, plane=plane)


def _valid(k: Key):
    """A valid value of ``k`` other than its default."""
    if k.type == "vector":
        return [0.1, 0.2, 0.3] if k.key != "normal" else [0.0, 0.0, 1.0]
    if k.type == "choice":
        return k.choices[-1]
    if k.type == "where":
        return "x > 0.1"
    return (k.minimum or 0.0) + 0.5


def _set_every_key(data: dict, keys) -> None:
    """Write ``keys`` into the experiment dict ``data`` where each section puts them."""
    for k in keys:
        v = _valid(k)
        if k.section == "table":
            data.setdefault(k.table, {})[k.key] = v
        elif k.section == "named":
            data.setdefault(k.table, {}).setdefault("probe", {})[k.key] = v
        else:
            entries = [e for e in data.setdefault(k.table, []) if e.get("kind") == k.only]
            if not entries:
                entries = [{"kind": k.only}]
                data[k.table].append(entries[0])
            entries[0][k.key] = v
    for e in data.get("collider", []):   # a plane needs both its point and normal
        e.setdefault("point", [0.0, 0.0, -0.1])
        e.setdefault("normal", [0.0, 0.0, 1.0])


def _key_cell(k: Key) -> str:
    if k.section == "table":
        return f"`[{k.table}] {k.key}`"
    if k.section == "array":
        return f"`[[{k.table}]] {k.key}` ({k.only})"
    return f"`[{k.table}.<name>] {k.key}`"


def _term_row(t: Term) -> tuple[str, str]:
    """How formats.md's table of terms says ``t``'s keys and parameters."""
    p = t.proposal
    params = ", ".join(f"`{q.name.format(region=p.region, index='<i>')}`"
                       + (f" ({q.unit})" if q.unit else "") for q in p.parameters)
    return ", ".join(_key_cell(k) for k in t.keys), params or "none (a switch)"


def mismatches() -> list[str]:
    """Every way the registry disagrees with a place that names terms or their keys."""
    out = []
    names = set(TERMS)
    if list(PHYSICS) != list(TERMS):
        out.append(f"report vocabulary {list(PHYSICS)} != registry {list(TERMS)}")
    section3 = DOC[DOC.index("## 3."):]
    table = re.findall(r"^\| (`[^|]+`) \|", section3, flags=re.M)
    documented = {n for cell in table for n in re.findall(r"`([a-z.]+)`", cell)} - {"name"}
    if documented != names:
        out.append(f"formats.md section 3 lists {sorted(documented ^ names)} differently")
    rows = DOC[DOC.index("| name | experiment keys |"):].splitlines()[2:]
    shown = {}
    for row in rows:
        cells = [c.strip() for c in row.strip().strip("|").split(" | ")]
        shown[cells[0].strip("`")] = tuple(cells[1:])
    if list(shown) != list(TERMS):
        out.append(f"formats.md's table of terms lists {list(shown)}")
    for name, t in TERMS.items():
        if name in shown and shown[name] != _term_row(t):
            out.append(f"formats.md's table of terms says {name}: {shown[name]}, the registry "
                       f"{_term_row(t)}")
    # the candidates: on a model where every term applies (gravity stated, and once not: its
    # two terms exclude each other), each is built, as declared
    try:
        _exp, cands, skipped = _candidates()
        _exp, free, free_skipped = _candidates(gravity=(0.0, 0.0, 0.0))
    except Exception as exc:   # noqa: BLE001 - a registry the code cannot use is the finding
        out.append(f"build_candidates fails: {exc!r}")
    else:
        if set(skipped) != {"gravity"} or "gravity.direction" not in free_skipped:
            out.append(f"terms not proposed on the all-terms model: {skipped}, without "
                       f"gravity: {free_skipped}")
        built = {c.physics for c in cands} | {c.physics for c in free}
        if built != names:
            out.append(f"candidates build {sorted(built ^ names)} differently from the registry")
        for c in cands + [c for c in free if c.physics == "gravity"]:
            if c.physics not in TERMS:
                continue
            p = TERMS[c.physics].proposal
            labels = {"region": p.region, "index": 0}
            if c.parameters != [q.name.format(**labels) for q in p.parameters]:
                out.append(f"{c.physics}: candidate parameters {c.parameters}")
            if c.kind != p.ranking:
                out.append(f"{c.physics}: ranked by {c.kind}, declared {p.ranking}")
            for name, q in zip(c.parameters, p.parameters, strict=False):
                if parameter_unit(name) != q.unit:
                    out.append(f"{name}: unit {parameter_unit(name)!r}, declared {q.unit!r}")
    # a key that is also a parameter has the same valid range for [calibrate] as in its table
    table_of = parameter_table(experiment_from_dict(_base(), source="ranges",
                                                    base_dir=Path.cwd()))
    for k in (k for t in TERMS.values() for k in t.keys):
        if k.section == "table" and k.dotted in table_of and table_of[k.dotted][1] != \
                key_range(k):
            out.append(f"{k.dotted}: [calibrate] range {table_of[k.dotted][1]}, declared "
                       f"{key_range(k)}")
    # the reader: every declared key is accepted and read back; absent, it takes its default
    data = _base()
    data.pop("gravity")
    keys = [k for t in TERMS.values() for k in t.keys]
    try:
        plain = experiment_from_dict(data, source="defaults", base_dir=Path.cwd())
        for k in keys:
            if k.section == "table" and k.default is not None:
                section = getattr(plain, k.table)
                got = getattr(section["default"] if k.table == "material" else section, k.key)
                if got != k.default:
                    out.append(f"[{k.table}] {k.key}: absent, it reads {got!r}, declared "
                               f"{k.default!r}")
        _set_every_key(data, keys)
        back = experiment_from_dict(data, source="all-keys", base_dir=Path.cwd()).to_dict()
        for k in keys:
            if k.section == "table" and k.table in OWNED and back[k.table][k.key] != _valid(k):
                out.append(f"[{k.table}] {k.key} = {_valid(k)!r} reads back as "
                           f"{back[k.table][k.key]!r}")
    except (ExperimentError, TypeError, AttributeError) as exc:
        out.append(f"the reader does not read the declared keys: {exc}")
    # formats.md's full example shows exactly the keys of the tables terms own
    full = tomllib.loads(re.findall(r"```toml\n(.*?)```", DOC, flags=re.S)[0])
    for table in OWNED:
        shown, declared = set(full.get(table, {})), {k.key for k in keys_of(table)}
        if shown != declared:
            out.append(f"formats.md [{table}] shows {sorted(shown)}, the terms declare "
                       f"{sorted(declared)}")
    section1 = DOC[:DOC.index("## 2.")]
    for k in keys:
        if k.section == "array" and not re.search(rf"^#? ?{k.key} =", section1, flags=re.M):
            out.append(f"formats.md section 1 never shows [[{k.table}]] {k.key}")
    return out


@pytest.fixture
def registry():
    """TERMS, to change in a test: put back afterwards in its order (the vocabulary's)."""
    saved = dict(TERMS)
    yield TERMS
    TERMS.clear()
    TERMS.update(saved)


def test_the_registry_agrees_with_every_place_that_names_terms():
    assert mismatches() == []


def test_a_term_declared_only_in_the_registry_is_caught(registry):
    extra = Term(name="damping.hysteretic", meaning="structural damping",
                 keys=(Key("hysteresis", "loss_factor", minimum=0.0),),
                 proposal=Proposal(kind="value", parameters=(
                     Parameter("hysteresis.loss_factor", "", lower="0", upper="1"),)))
    registry[extra.name] = extra
    found = "\n".join(mismatches())
    assert "report vocabulary" in found         # PHYSICS was read from the registry at import
    assert "formats.md section 3 lists ['damping.hysteretic']" in found
    assert "formats.md's table of terms lists" in found
    assert "candidates build ['damping.hysteretic'] differently" in found
    assert "the reader does not read the declared keys" in found
    assert "hysteresis" in found


def test_a_term_built_elsewhere_but_not_registered_is_caught(registry):
    del registry["drag.quadratic"]
    found = "\n".join(mismatches())
    assert "formats.md section 3 lists ['drag.quadratic']" in found
    assert "build_candidates fails: KeyError('drag.quadratic')" in found
    # its key is gone from what [drag] accepts, while formats.md still shows it
    assert "formats.md [drag] shows ['linear', 'quadratic'], the terms declare ['linear']" in found
    with pytest.raises(ExperimentError, match="quadratic"):
        experiment_from_dict({**_base(), "drag": {"quadratic": 0.1}}, source="x",
                             base_dir=Path.cwd())


def test_a_unit_declared_differently_from_the_doc_and_the_parameters_is_caught(registry):
    t = TERMS["damping.mass"]
    wrong = dataclasses.replace(t, proposal=dataclasses.replace(t.proposal, parameters=(
        dataclasses.replace(t.proposal.parameters[0], unit="1/min"),)))
    registry["damping.mass"] = wrong
    found = mismatches()
    assert "damping.mass: unit '1/s', declared '1/min'" in found
    assert any(m.startswith("formats.md's table of terms says damping.mass") for m in found)
    assert len(found) == 2, found


def test_a_new_term_of_values_is_proposed_from_its_declaration_alone(registry):
    """No rule in candidates.py names it: the declaration is enough for diagnose to propose it
    (on a mass-spring model, whose springs' damping is a parameter of the experiment)."""
    new = Term(name="springs.viscous", meaning="viscous dashpots along the springs",
               keys=(Key("springs", "damping", unit="N s/m", minimum=0.0),),
               proposal=Proposal(kind="value", parameters=(
                   Parameter("springs.damping", "N s/m", lower="0", upper="10 * mass"),)))
    registry[new.name] = new
    ms = experiment_from_dict(
        {"mesh": {"box": {"size": [0.4, 0.04, 0.04], "cells": [4, 1, 1]}},
         "springs": {"stiffness": 100.0, "node_mass": 0.01},
         "boundary": [{"kind": "fixed", "where": "x < 1e-6"}],
         "time": {"end": 0.1, "step": 0.01}}, source="springs", base_dir=Path.cwd())
    cands, skipped = build_candidates(ms, scales=SCALES)
    (c,) = [c for c in cands if c.physics == "springs.viscous"]
    assert (c.parameters, c.bounds, c.reason) == (["springs.damping"], [(0.0, 20.0)],
                                                   "viscous dashpots along the springs")
    assert c.extend(ms).calibrate == {"springs.damping": (0.0, 20.0)}
    # the continuum-only terms stay out of a spring network, with the reason
    assert set(skipped) == {n for n, t in TERMS.items() if t.proposal.continuum_only} | {
        "contact.plane"}
    # ... and a term already in the model is not proposed again
    with_damping = experiment_from_dict({**ms.to_dict(), "springs": {
        **ms.to_dict()["springs"], "damping": 0.5}}, source="springs", base_dir=Path.cwd())
    assert build_candidates(with_damping, scales=SCALES)[1]["springs.viscous"] == \
        "already in the model"


def test_declared_bounds_are_the_closed_forms_their_comments_state():
    exp, cands, _ = _candidates()
    by = {c.physics: c for c in cands}
    by["gravity"] = next(c for c in _candidates(gravity=(0.0, 0.0, 0.0))[1]
                         if c.physics == "gravity")
    E, rate = 1.0e6, 100.0
    tau = 1.0 / (2.0 * 3.141592653589793 * SCALES["frequency"])
    c0 = 1e-3 * SCALES["cell"] / E
    expect = {
        "damping.mass": [(0.0, 100.0)],
        "damping.stiffness": [(0.0, 0.05)],
        "gravity": [(-20.0, 20.0), (-20.0, 20.0), (-20.0, 20.0)],     # from no gravity
        "gravity.direction": [(-1.0, 1.0), (-1.0, 1.0)],               # 45 degrees
        "drag.linear": [(0.0, rate * 2.0 / 0.5)],
        "drag.quadratic": [(0.0, rate * 2.0 / (0.5 * 0.2))],
        "friction.dry": [(0.0, rate * 0.03)],
        "material.heterogeneous": [(E / 5, 5 * E)],
        "mass.added": [(1000.0, 10000.0)],
        "boundary.compliance": [(c0, max(10 * 0.4 / E, 10 * c0))],
        "material.viscoelastic": [(0.0, 2.0), (tau / 30, 30 * tau)],
        "material.nonlinear": [],
        "contact.plane": [(-0.003, 0.003)],
    }
    assert set(expect) == set(by)
    for name, bounds in expect.items():
        flat = [b for pair in by[name].bounds for b in pair]
        assert flat == pytest.approx([b for pair in bounds for b in pair], rel=1e-12,
                                     abs=1e-15), name
    assert by["friction.dry"].settings == {"friction": {"dry": 0.0, "speed": 0.01 * 0.03}}
    assert by["boundary.compliance"].compliance == pytest.approx(c0, rel=1e-15)
    assert by["material.viscoelastic"].tested_parameters == ["viscoelastic.ratio"]
    assert by["material.nonlinear"].settings == {"material": {"model": "corotated"}}
    assert by["friction.dry"].reason == (TERMS["friction.dry"].meaning + " (per unit mass, "
                                         "regularised below 0.0003 m/s)")


def test_the_declared_scale_is_the_one_calibration_uses():
    """A parameter declared ``log`` is log-scaled by the calibration (ParameterScaling: a
    positive lower bound), a ``linear`` one is not, with the bounds the candidates propose."""
    exp, cands, _ = _candidates()
    for c in cands:
        if not c.parameters:
            continue
        declared = [q.scale for q in TERMS[c.physics].proposal.parameters]
        start = [c.zero_values(exp)[n] for n in c.parameters]
        lo, hi = (np.array(b) for b in zip(*c.bounds, strict=True))
        used = ParameterScaling(c.parameters, start, lo, hi).is_log
        assert [("log" if u else "linear") for u in used] == declared, c.physics


def test_a_malformed_declaration_fails_at_import_time():
    with pytest.raises(ValueError, match="proposal kind 'guess'"):
        Term("x.y", "?", (), Proposal(kind="guess"))
    with pytest.raises(ValueError, match="region proposal"):
        Term("x.y", "?", (), Proposal(kind="region"))
    with pytest.raises(ValueError, match="scale 'cubic'"):
        Term("x.y", "?", (), Proposal(kind="value", parameters=(
            Parameter("x.y", "", "0", "1", scale="cubic"),)))
    for bad in (Key("x", "y", minimum=0.0, open=True, at_minimum="off"),
                Key("x", "y", minimum=None, at_minimum="off"),
                Key("x", "y", type="vector", minimum=0.0, at_minimum="off")):
        with pytest.raises(ValueError, match="at_minimum describes"):
            Term("x.y", "?", (bad,), Proposal(kind="value"))
