"""Candidate physics of ``petsoft diagnose``: each a vocabulary term with its own parameters.

A :class:`Candidate` names a term of the physics vocabulary (formats.md section 3,
:data:`petsoft.diagnosis.report.PHYSICS`), the experiment parameters it adds (or frees) and
how to switch it on: :meth:`Candidate.extend` maps an experiment to the extended experiment
with the term at its *zero* value (the extended model reproduces the base model, exactly or to
a negligible penalty) and ``[calibrate]`` bounds for the new parameters. How a candidate is
ranked (``Candidate.kind``):

* ``"score"``: the efficient score test (:mod:`petsoft.diagnosis.score`) at the zero value, from
  the forward model's exact sensitivities;
* ``"score-fd"``: the same test with the new parameters' columns by one-sided finite differences
  (terms the sensitivities do not cover, e.g. the viscoelastic branch's internal variable);
* ``"switch"``: no derivative at a zero value exists (a model switch, a contact placed where the
  simulation leaves the data), so the column of the test is the whole change the switch makes
  (the derivative at t = 0 of base + t (switch - base), exact when the change is linear in t):
  one more simulation instead of a fit. Like every candidate, it is fitted only if it ranks
  among the best.

The terms and how each is placed and bounded (``scales`` are the model's size, mass, surface, the
data's speed and dominant frequency, :func:`petsoft.diagnosis.diagnose.model_scales`). Each term's
parameters, bounds, starting values, settings and words are declared by its module in
:mod:`petsoft.terms` (:func:`propose` evaluates them); this module decides whether a term applies
to the model and where a placed one goes:

* ``damping.mass`` / ``damping.stiffness``: Rayleigh alpha / beta from 0;
* ``gravity``: the three components of ``gravity.acceleration``, freed at their current values;
* ``material.heterogeneous``: a spherical ``[region]`` whose Young's modulus starts at the
  surrounding modulus, placed where the adjoint per-cell map of d misfit/d E is largest (once
  added, its sphere is fitted too: :mod:`petsoft.diagnosis.geometry`; likewise an added mass');
* ``mass.added``: a spherical region whose density starts at the surrounding one (extra mass =
  a denser region, so the density can only grow), placed where the adjoint per-cell map of
  d misfit/d rho is most negative, i.e. where added mass lowers the misfit most (else at the
  residual's ``mismatch.region``, else the Young's-modulus map's sphere);
* ``drag.linear`` / ``drag.quadratic``: ``[drag]`` on the body's surface, from 0;
* ``friction.dry``: ``[friction] dry`` from 0, regularised at 1 % of the data's rms speed;
* ``boundary.compliance``: the fixed supports made elastic, from a compliance 1e-3 x (cell size
  / E), i.e. a support displacement a thousandth of a cell's strain (numerically rigid);
* ``material.viscoelastic``: a standard-linear-solid branch (``[viscoelastic]``) of modulus ratio
  from 0, relaxation time starting at 1/(2 pi f) of the data's dominant frequency;
* ``material.nonlinear``: the linear law switched to the corotated one (a fit, no parameter);
* ``contact.plane``: a plane where the base simulation leaves the extent of the data by more than
  the noise (normal along that axis, at the data's extreme), its offset fitted.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from petsoft.dynamics.factory import system_class
from petsoft.errors import ExperimentError
from petsoft.experiment import experiment_from_dict, get_parameter, with_parameters
from petsoft.experiment.expressions import parse_expression
from petsoft.terms import TERMS

#: Why a vocabulary term may not be tried (the reasons are filled in by build_candidates).
NOT_APPLICABLE = "not applicable to this model"

#: Name of the region a spatial candidate adds (declared by its term).
REGION = {name: t.proposal.region for name, t in TERMS.items() if t.proposal.kind == "region"}

#: Ranking methods (module docstring).
KINDS = ("score", "score-fd", "switch")


def _merge(data: dict, settings: dict) -> None:
    """Deep-merge ``settings`` (nested dicts) into the experiment dict ``data``."""
    for key, value in settings.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict):
            _merge(data[key], value)
        else:
            data[key] = value


@dataclass
class Candidate:
    """One hypothesis: a vocabulary term, its new parameters and the extended experiment.

    Attributes
    ----------
    physics : str
        Vocabulary name.
    parameters : list of str
        Experiment parameter names the term adds or frees (``[calibrate]`` keys).
    bounds : list of (float, float)
        Their calibration bounds.
    region : dict or None
        ``{"center", "radius"}`` of a spatial candidate.
    reason : str
        Why it was placed there / what it means (for the report).
    regions : dict
        ``{name: where}`` regions the extension adds.
    kind : {"score", "score-fd", "switch"}
        How it is ranked (module docstring).
    settings : dict
        Nested experiment keys the extension sets (deep-merged), e.g. ``{"drag": {"linear":
        0.0}}``.
    colliders : list of dict
        ``[[collider]]`` tables the extension appends.
    compliance : float or None
        Set as ``compliance`` on every rigid fixed support.
    tested : list of str
        The parameters the score test is about (default: all of ``parameters``); the others are
        fitted but not tested (a relaxation time is undefined while the branch is off).
    fd_steps : dict
        Finite-difference step per parameter of a ``"score-fd"`` candidate.
    """

    physics: str
    parameters: list[str]
    bounds: list[tuple[float, float]]
    region: dict | None = None
    reason: str = ""
    regions: dict = field(default_factory=dict)
    kind: str = "score"
    settings: dict = field(default_factory=dict)
    colliders: list = field(default_factory=list)
    compliance: float | None = None
    tested: list[str] | None = None
    fd_steps: dict = field(default_factory=dict)

    def extend(self, experiment):
        """The experiment with this term switched on at its zero value and its parameters in
        ``[calibrate]`` (the base model's ``[calibrate]`` entries are kept)."""
        data = experiment.to_dict()
        for name, where in self.regions.items():
            data.setdefault("region", {})[name] = {"where": where}
            # an empty material table makes material.<name>.* parameters (following the default)
            data.setdefault("material", {}).setdefault(name, {})
        _merge(data, self.settings)
        if self.colliders:
            data["collider"] = list(data.get("collider", [])) + [dict(c) for c in
                                                                 self.colliders]
        if self.compliance is not None:
            for b in data.get("boundary", []):
                if b.get("kind") == "fixed" and not b.get("compliance"):
                    b["compliance"] = float(self.compliance)
        cal = dict(data.get("calibrate", {}))
        for name, b in zip(self.parameters, self.bounds, strict=True):
            cal[name] = [float(b[0]), float(b[1])]
        data["calibrate"] = cal
        return experiment_from_dict(data, source=experiment.source,
                                    base_dir=experiment.base_dir, path=experiment.path)

    @property
    def retractable(self) -> bool:
        """Whether :meth:`retract` can take the term out again: a term of values only (a
        damping, drag or friction coefficient, gravity), not a region, collider, support
        compliance or model switch."""
        return (self.kind != "switch" and not self.regions and not self.colliders
                and self.compliance is None)

    def retract(self, experiment, zeros: dict[str, float]):
        """``experiment`` (extended by this term, perhaps by later ones too) with this term's
        parameters back at ``zeros`` (:meth:`zero_values` of the experiment it extended) and
        out of ``[calibrate]``."""
        if not self.retractable:
            raise ValueError(f"{self.physics}: only a term of values can be retracted")
        back = with_parameters(experiment, zeros)
        data = back.to_dict()
        data["calibrate"] = {k: v for k, v in data.get("calibrate", {}).items()
                             if k not in self.parameters}
        return experiment_from_dict(data, source=experiment.source,
                                    base_dir=experiment.base_dir, path=experiment.path)

    def zero_values(self, experiment) -> dict[str, float]:
        """The new parameters' values in the extended experiment (the base model)."""
        ext = self.extend(experiment)
        return {n: get_parameter(ext, n) for n in self.parameters}

    @property
    def tested_parameters(self) -> list[str]:
        return list(self.tested) if self.tested else list(self.parameters)


def sphere_condition(center, radius) -> str:
    """A ``where`` condition of x, y, z selecting the ball (cell centroids inside)."""
    cx, cy, cz = (float(c) for c in center)
    return (f"(x - ({cx!r}))**2 + (y - ({cy!r}))**2 + (z - ({cz!r}))**2 < "
            f"{float(radius)!r}**2")


def sensitivity_region(centroids: np.ndarray, cell_map: np.ndarray, volumes: np.ndarray,
                       share: float = 0.5, inward: bool = False) -> dict | None:
    """Where the misfit is most sensitive to a local material value.

    Parameters
    ----------
    centroids : ndarray (E, 3)
    cell_map : ndarray (E,)
        d misfit / d value_cell (adjoint), any sign.
    volumes : ndarray (E,)
        Cell volumes: the map is divided by them so that large cells do not win by size.
    share : float
        Cells with at least this share of the largest density |g| / V form the region.
    inward : bool
        Count only cells where the misfit falls as the value grows (g < 0): for a value that
        may only increase (added mass), cells where it would have to fall cannot help.

    Returns
    -------
    dict or None
        ``{"center", "radius", "cells"}`` (the density-weighted centroid of those cells and the
        radius that contains their centroids plus half a cell), None for an all-zero map (or,
        inward, one without a negative entry).
    """
    g = np.asarray(cell_map, dtype=float)
    dens = (np.maximum(-g, 0.0) if inward else np.abs(g)) / np.asarray(volumes, dtype=float)
    top = dens.max(initial=0.0)
    if not np.isfinite(top) or top <= 0.0:
        return None
    pick = dens >= share * top
    w = dens[pick]
    center = (centroids[pick] * w[:, None]).sum(axis=0) / w.sum()
    # half a typical cell beyond the farthest chosen centroid, so the chosen cells are inside
    size = float(np.cbrt(np.mean(volumes)))
    radius = float(np.max(np.linalg.norm(centroids[pick] - center, axis=1))) + 0.5 * size
    return {"center": center.tolist(), "radius": radius, "cells": int(pick.sum())}


def cells_in_sphere(centroids: np.ndarray, region: dict) -> np.ndarray:
    """(E,) bool: the cells whose centroid is inside the sphere ``region`` ({"center",
    "radius"}), as :func:`sphere_condition` selects them."""
    c = np.asarray(region["center"], dtype=float)
    return np.sum((centroids - c) ** 2, axis=1) < float(region["radius"]) ** 2


def _cells_in(centroids: np.ndarray, region: dict) -> int:
    return int(cells_in_sphere(centroids, region).sum())


def _grow_to_cell(centroids: np.ndarray, region: dict) -> dict:
    """The sphere widened to hold at least the cell nearest its centre: marker-based regions sit
    on the surface, and a radius of one marker spacing can miss every cell centroid."""
    c = np.asarray(region["center"], dtype=float)
    nearest = float(np.sqrt(np.min(np.sum((centroids - c) ** 2, axis=1))))
    return {**region, "radius": max(float(region["radius"]), 1.01 * nearest)}


def _value(experiment, name: str, default: float = 0.0) -> float:
    """A parameter's current value, ``default`` when this experiment has no such parameter."""
    try:
        return float(get_parameter(experiment, name))
    except ExperimentError:
        return default


def _off(experiment, name: str, cal: set) -> bool:
    """Whether the term of parameter ``name`` is absent (zero and not calibrated)."""
    return name not in cal and _value(experiment, name) == 0.0


def _evaluate(text: str, env: dict, source: str) -> float:
    """A declared bound or value (an expression of the scales in ``env``) as a float."""
    expr = parse_expression(text, source=source, variables=tuple(env), expect="number")
    return float(expr.evaluate(**{k: env[k] for k in expr.variables}))


def _gravity_candidate(experiment, cal: set, sc: dict, offer, skipped: dict,
                       continuum: bool) -> None:
    """Offer ``gravity`` (its three components from the model's, each +-20 m/s^2) where the
    model states none, else ``gravity.direction`` (the stated gravity turned at its size:
    :mod:`petsoft.experiment.gravity_tilt`), unless gravity is calibrated already. A model
    without a continuum material (a spring network, whose system does not take the tilt's
    derivative) is offered ``gravity`` as before.

    On the Earth's surface |g| is 9.78-9.83 m/s^2: a stated gravity may point the wrong way
    (a mount or a camera frame that is not level), but a fit of its size stands in for other
    physics. Seen: the realistic payload taper (a concealed added mass, gravity stated) took
    gravity at |g| = 15.5 m/s^2, 12.9 of it along the bar, as its first term, and the added
    mass only in a second round."""
    names = {q.name for t in ("gravity", "gravity.direction")
             for q in TERMS[t].proposal.parameters}
    stated = np.asarray(experiment.gravity.as_stated, dtype=float)
    if cal.intersection(names):
        skipped["gravity"] = skipped["gravity.direction"] = "already calibrated"
    elif not stated.any() or not continuum:
        # (a model without a continuum material: gravity.direction is continuum_only, said
        # with the others by build_candidates)
        offer(propose("gravity", experiment, sc))
        if continuum:
            skipped["gravity.direction"] = "the model states no gravity to turn"
    else:
        skipped["gravity"] = (f"the model states gravity (|g| = {np.linalg.norm(stated):.4g} "
                              "m/s^2): its direction is tried at that size "
                              "(gravity.direction), not its size")
        offer(propose("gravity.direction", experiment, sc))


def propose(name: str, experiment, env: dict, *, words: dict | None = None,
            region: dict | None = None, **labels) -> Candidate:
    """The candidate of the registered term ``name`` (:mod:`petsoft.terms`) for ``experiment``.

    Parameters
    ----------
    name : str
        Vocabulary name.
    experiment : Experiment
        The model it extends (``current``, the value a parameter has in it, starts bounds).
    env : dict
        The scales the term's declared expressions use (``mass``, ``area``, ``speed``, ...).
    words : dict, optional
        More values for the reason's template (``origin``, ``normal``).
    region : dict, optional
        ``{"center", "radius"}`` of a region proposal.
    **labels
        ``index`` (of the collider a switch adds) for parameter names that hold it.
    """
    term = TERMS[name]
    p = term.proposal
    env = dict(env)
    if p.start:
        env["start"] = _evaluate(p.start, env, f"petsoft.terms {name}: start")
    labels = {"region": p.region, **labels}
    names, bounds, tested, steps = [], [], [], {}
    for q in p.parameters:
        pname = q.name.format(**labels)
        # a region's parameter starts at the surrounding (default) material's value
        base = f"material.{pname.rsplit('.', 1)[1]}" if p.kind == "region" else pname
        e = {**env, "current": _value(experiment, base)}
        bounds.append(tuple(_evaluate(getattr(q, end), e, f"petsoft.terms {name}: {q.name} "
                                      f"{end}") for end in ("lower", "upper")))
        names.append(pname)
        if q.tested:
            tested.append(pname)
        if q.fd_step is not None:
            steps[pname] = q.fd_step
    choices = {f"{k.table}.{k.key}" for k in term.keys if k.type == "choice"}
    settings: dict = {}
    compliance = None
    for key, value in p.settings:
        if key == "boundary.compliance":   # every rigid fixed support, not one table's key
            compliance = _evaluate(value, env, f"petsoft.terms {name}: {key}")
            continue
        table, k = key.split(".")
        settings.setdefault(table, {})[k] = (value if key in choices else
                                             _evaluate(value, env, f"petsoft.terms {name}: "
                                                       f"{key}"))
    regions = {}
    if region is not None:
        regions = {p.region: sphere_condition(region["center"], region["radius"])}
    return Candidate(name, names, bounds, region=region, regions=regions, kind=p.ranking,
                     settings=settings, compliance=compliance,
                     tested=tested if len(tested) < len(names) else None, fd_steps=steps,
                     reason=term.meaning + p.note.format(**env, **(words or {})))


def build_candidates(experiment, *, evidence_region: dict | None = None,
                     stiffness_region: dict | None = None, density_region: dict | None = None,
                     centroids: np.ndarray | None = None, scales: dict | None = None,
                     plane: dict | None = None) -> tuple[list[Candidate], dict]:
    """The candidates that can be modelled for ``experiment``, and the rest with the reason.

    Parameters
    ----------
    experiment : Experiment
        The current (base or already extended) model.
    evidence_region : dict, optional
        The residual's ``mismatch.region`` (:func:`petsoft.diagnosis.locate.mismatch_region`).
    stiffness_region : dict, optional
        :func:`sensitivity_region` of the adjoint Young's-modulus map.
    density_region : dict, optional
        :func:`sensitivity_region` (inward) of the adjoint density map.
    centroids : ndarray (E, 3), optional
        Cell centroids, to drop a spatial candidate whose sphere holds no cell.
    scales : dict, optional
        ``mass`` (kg), ``area`` (m^2, surface), ``length`` (m), ``cell`` (m), ``speed`` (m/s, rms
        marker speed), ``speed_max``, ``frequency`` (Hz or None): they size the bounds of the
        new parameters (:func:`petsoft.diagnosis.diagnose.model_scales`).
    plane : dict, optional
        ``{"point", "normal", "excess"}``: where the simulation leaves the data's extent
        (:func:`petsoft.diagnosis.diagnose.escape_plane`); the ``contact.plane`` candidate.

    Returns
    -------
    (list of Candidate, dict)
        The candidates, and ``{physics: reason}`` of the vocabulary terms not tried. Candidates
        whose extension the experiment reader refuses (e.g. drag on a spring network without a
        surface) are listed there with the reader's message.
    """
    sc = {"mass": 1.0, "area": 1.0, "length": 1.0, "cell": 1.0, "speed": 1.0,
          "speed_max": 1.0, "frequency": None}
    sc.update({k: v for k, v in (scales or {}).items() if v is not None})
    # the dominant frequency, else one period over the record
    sc["frequency"] = sc["frequency"] or 1.0 / max(experiment.time.end, 1e-12)
    cands: list[Candidate] = []
    skipped: dict[str, str] = {}
    cal = set(experiment.calibrate or {})
    body = system_class(experiment)

    def offer(c: Candidate) -> None:
        try:
            c.extend(experiment)
        except ExperimentError as exc:
            skipped[c.physics] = f"cannot be added to this model: {exc}"
            return
        cands.append(c)

    for physics in ("damping.mass", "damping.stiffness"):
        if _off(experiment, physics, cal):
            offer(propose(physics, experiment, sc))
        else:
            skipped[physics] = "already in the model"
    _gravity_candidate(experiment, cal, sc, offer, skipped, body.continuum_material)
    for physics in ("drag.linear", "drag.quadratic", "friction.dry"):
        if _off(experiment, physics, cal):
            offer(propose(physics, experiment, sc))
        else:
            skipped[physics] = "already in the model"
    if not body.continuum_material:
        for physics, t in TERMS.items():
            if t.proposal.continuum_only:
                skipped[physics] = (f"{NOT_APPLICABLE}: a {body.defined_by} model has no "
                                    "continuum material")
    else:
        stiffness = (stiffness_region, "the adjoint Young's-modulus map")
        mass = [(density_region, "the adjoint density map (where added mass lowers the misfit "
                                 "most)"),
                (evidence_region, "the residual's mismatch region"), stiffness]
        _continuum_candidates(experiment, cal, sc, offer, skipped, centroids, {
            "material.heterogeneous": stiffness,
            "mass.added": next((m for m in mass if m[0] is not None), (None, ""))})
    if plane is None:
        skipped["contact.plane"] = ("the simulation stays within the extent of the data "
                                    "(no side where a plane could stop it)")
    else:
        n = np.asarray(plane["normal"], dtype=float)
        c = propose("contact.plane", experiment, {**sc, "depth": float(plane["excess"])},
                    words={"normal": n.tolist()}, index=len(experiment.colliders))
        c.colliders = [{"kind": "plane", "point": [float(x) for x in plane["point"]],
                        "normal": n.tolist()}]
        offer(c)
    # A registered term the rules above do not name: a term of values is proposed from its zero
    # value like a damping coefficient; a switch or a region needs a placement rule here.
    for physics, t in TERMS.items():
        if physics in skipped or any(c.physics == physics for c in cands):
            continue
        tested = [q.name for q in t.proposal.parameters if q.tested]
        if t.proposal.continuum_only and not body.continuum_material:
            skipped[physics] = (f"{NOT_APPLICABLE}: a {body.defined_by} model has no continuum "
                                "material")
        elif t.proposal.kind != "value" or not tested:
            skipped[physics] = (f"petsoft.diagnosis.candidates has no rule to place a "
                                f"{t.proposal.kind} term")
        elif all(_off(experiment, n, cal) for n in tested):
            offer(propose(physics, experiment, sc))
        else:
            skipped[physics] = "already in the model"
    return cands, skipped


def _continuum_candidates(experiment, cal, sc, offer, skipped, centroids, placed) -> None:
    """The FEM-only terms: spatial ones (``placed``: physics -> (sphere or None, where it comes
    from)), supports, viscoelasticity, the nonlinear law."""
    regions = experiment.regions or {}
    for physics in ("material.heterogeneous", "mass.added"):
        where_from, origin = placed[physics]
        if REGION[physics] in regions:
            skipped[physics] = "already in the model"
            continue
        if where_from is None:
            skipped[physics] = ("no region to place it: the residual is not localised and no "
                                "sensitivity map was computed")
            continue
        if centroids is not None and _cells_in(centroids, where_from) == 0:
            where_from = _grow_to_cell(centroids, where_from)
        if centroids is not None and _cells_in(centroids, where_from) == 0:
            skipped[physics] = (f"the located sphere (centre {where_from['center']}, radius "
                                f"{where_from['radius']:.3g}) holds no cell")
            continue
        region = {"center": [float(c) for c in where_from["center"]],
                  "radius": float(where_from["radius"])}
        offer(propose(physics, experiment, sc, region=region, words={"origin": origin}))
    E = get_parameter(experiment, "material.youngs_modulus")
    rigid = [b for b in experiment.boundaries
             if b.kind == "fixed" and not getattr(b, "compliance", 0.0)]
    if "boundary.compliance" in cal or len(rigid) < len([b for b in experiment.boundaries
                                                         if b.kind == "fixed"]):
        skipped["boundary.compliance"] = "already in the model"
    elif not rigid:
        skipped["boundary.compliance"] = f"{NOT_APPLICABLE}: no fixed support"
    else:
        offer(propose("boundary.compliance", experiment, {**sc, "youngs_modulus": E}))
    if _off(experiment, "viscoelastic.ratio", cal):
        offer(propose("material.viscoelastic", experiment, sc))
    else:
        skipped["material.viscoelastic"] = "already in the model"
    linear = [name for name, m in experiment.material.items() if m.model == "linear"]
    if linear:
        c = propose("material.nonlinear", experiment, sc)
        # the switch reaches every linear material: the default and each region's own
        law = dict(c.settings["material"])
        for name in linear:
            if name != "default":
                c.settings["material"][name] = dict(law)
        offer(c)
    else:
        skipped["material.nonlinear"] = "the material law is already nonlinear"
