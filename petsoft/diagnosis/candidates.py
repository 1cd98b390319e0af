"""Candidate physics of ``petsoft diagnose``: each a vocabulary term with its own parameters.

A :class:`Candidate` names a term of the physics vocabulary (formats.md section 3,
:data:`petsoft.diagnosis.report.PHYSICS`), the experiment parameters it adds (or frees) and
how to switch it on: :meth:`Candidate.extend` maps an experiment to the extended experiment
with the term at its *zero* value (the extended model reproduces the base model exactly) and
``[calibrate]`` bounds for the new parameters. The score test
(:mod:`petsoft.diagnosis.score`) is evaluated there, and the re-calibration starts there.

Only the terms that existing differentiable experiment parameters can express are modelled:

* ``damping.mass``: Rayleigh alpha, from 0;
* ``damping.stiffness``: Rayleigh beta, from 0;
* ``gravity``: the three components of ``gravity.acceleration``, freed at their current values;
* ``material.heterogeneous``: a spherical ``[region]`` whose Young's modulus
  ``material.<region>.youngs_modulus`` starts at the surrounding modulus; the sphere is where the
  adjoint per-cell sensitivity map of the misfit to Young's modulus (``ForwardModel.
  cell_gradient``) is largest;
* ``mass.added``: a spherical region whose density ``material.<region>.density`` starts at the
  surrounding density (extra mass = a denser region); the sphere is the residual's
  ``mismatch.region`` (markers), else the sensitivity map's sphere.

Every other term of the vocabulary is reported as not modelled yet (:data:`NOT_MODELLED`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..experiment import experiment_from_dict, get_parameter
from .report import PHYSICS

#: Vocabulary terms without a differentiable parametrisation in petsoft yet (with why).
NOT_MODELLED = {
    "material.nonlinear": "switching the material law (linear -> corotated/neo-Hookean) is a "
                          "discrete model change, not a parameter at a zero value",
    "material.viscoelastic": "no viscoelastic material law yet",
    "boundary.compliance": "no elastic-support (Robin) boundary condition yet",
    "drag.linear": "no drag force on the body surface yet (damping.mass is the closest modelled "
                   "term)",
    "drag.quadratic": "no velocity-squared drag force yet",
    "friction.dry": "no Coulomb friction yet",
    "contact.plane": "contact with a plane exists only as a prescribed collider without "
                     "differentiable parameters",
}

#: Name of the region a spatial candidate adds.
REGION = {"material.heterogeneous": "diag_stiffness", "mass.added": "diag_mass"}


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
    """

    physics: str
    parameters: list[str]
    bounds: list[tuple[float, float]]
    region: dict | None = None
    reason: str = ""
    regions: dict = field(default_factory=dict)

    def extend(self, experiment):
        """The experiment with this term switched on at its zero value and its parameters in
        ``[calibrate]`` (the base model's ``[calibrate]`` entries are kept)."""
        data = experiment.to_dict()
        for name, where in self.regions.items():
            data.setdefault("region", {})[name] = {"where": where}
            # an empty material table makes material.<name>.* parameters (following the default)
            data.setdefault("material", {}).setdefault(name, {})
        cal = dict(data.get("calibrate", {}))
        for name, b in zip(self.parameters, self.bounds, strict=True):
            cal[name] = [float(b[0]), float(b[1])]
        data["calibrate"] = cal
        return experiment_from_dict(data, source=experiment.source,
                                    base_dir=experiment.base_dir, path=experiment.path)

    def zero_values(self, experiment) -> dict[str, float]:
        """The new parameters' values in the extended experiment (the base model)."""
        ext = self.extend(experiment)
        return {n: get_parameter(ext, n) for n in self.parameters}


def sphere_condition(center, radius) -> str:
    """A ``where`` condition of x, y, z selecting the ball (cell centroids inside)."""
    cx, cy, cz = (float(c) for c in center)
    return (f"(x - ({cx!r}))**2 + (y - ({cy!r}))**2 + (z - ({cz!r}))**2 < "
            f"{float(radius)!r}**2")


def sensitivity_region(centroids: np.ndarray, cell_map: np.ndarray, volumes: np.ndarray,
                       share: float = 0.5) -> dict | None:
    """Where the misfit is most sensitive to the local Young's modulus.

    Parameters
    ----------
    centroids : ndarray (E, 3)
    cell_map : ndarray (E,)
        d misfit / d E_cell (adjoint), any sign.
    volumes : ndarray (E,)
        Cell volumes: the map is divided by them so that large cells do not win by size.
    share : float
        Cells with at least this share of the largest density |g| / V form the region.

    Returns
    -------
    dict or None
        ``{"center", "radius", "cells"}`` (the density-weighted centroid of those cells and the
        radius that contains their centroids plus half a cell), None for an all-zero map.
    """
    dens = np.abs(np.asarray(cell_map, dtype=float)) / np.asarray(volumes, dtype=float)
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


def _cells_in(centroids: np.ndarray, region: dict) -> int:
    c = np.asarray(region["center"], dtype=float)
    return int((np.sum((centroids - c) ** 2, axis=1) < float(region["radius"]) ** 2).sum())


def _grow_to_cell(centroids: np.ndarray, region: dict) -> dict:
    """The sphere widened to hold at least the cell nearest its centre: marker-based regions sit
    on the surface, and a radius of one marker spacing can miss every cell centroid."""
    c = np.asarray(region["center"], dtype=float)
    nearest = float(np.sqrt(np.min(np.sum((centroids - c) ** 2, axis=1))))
    return {**region, "radius": max(float(region["radius"]), 1.01 * nearest)}


def build_candidates(experiment, *, evidence_region: dict | None = None,
                     stiffness_region: dict | None = None,
                     centroids: np.ndarray | None = None) -> tuple[list[Candidate], dict]:
    """The candidates that can be modelled for ``experiment``, and the rest with the reason.

    Parameters
    ----------
    experiment : Experiment
        The current (base or already extended) model.
    evidence_region : dict, optional
        The residual's ``mismatch.region`` (:func:`petsoft.diagnosis.locate.mismatch_region`).
    stiffness_region : dict, optional
        :func:`sensitivity_region` of the adjoint Young's-modulus map.
    centroids : ndarray (E, 3), optional
        Cell centroids, to drop a spatial candidate whose sphere holds no cell.

    Returns
    -------
    (list of Candidate, dict)
        The candidates, and ``{physics: reason}`` of the vocabulary terms not tried.
    """
    cands: list[Candidate] = []
    skipped = dict(NOT_MODELLED)
    cal = set(experiment.calibrate or {})
    if experiment.damping.mass == 0.0 and "damping.mass" not in cal:
        cands.append(Candidate("damping.mass", ["damping.mass"], [(0.0, 100.0)],
                               reason=PHYSICS["damping.mass"]))
    else:
        skipped["damping.mass"] = "already in the model"
    if experiment.damping.stiffness == 0.0 and "damping.stiffness" not in cal:
        cands.append(Candidate("damping.stiffness", ["damping.stiffness"], [(0.0, 0.05)],
                               reason=PHYSICS["damping.stiffness"]))
    else:
        skipped["damping.stiffness"] = "already in the model"
    gnames = [f"gravity.acceleration.{c}" for c in "xyz"]
    if not cal.intersection(gnames):
        g = [get_parameter(experiment, n) for n in gnames]
        cands.append(Candidate("gravity", gnames, [(v - 20.0, v + 20.0) for v in g],
                               reason=PHYSICS["gravity"]))
    else:
        skipped["gravity"] = "already calibrated"
    regions = experiment.regions or {}
    for physics, key, where_from in (
            ("material.heterogeneous", "youngs_modulus", stiffness_region),
            ("mass.added", "density", evidence_region or stiffness_region)):
        name = REGION[physics]
        if name in regions:
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
        value = get_parameter(experiment, f"material.{key}")
        hi = 10.0 * value if key == "density" else 5.0 * value
        lo = value if key == "density" else value / 5.0
        region = {"center": [float(c) for c in where_from["center"]],
                  "radius": float(where_from["radius"])}
        origin = ("the residual's mismatch region" if physics == "mass.added" and evidence_region
                  else "the adjoint Young's-modulus sensitivity map")
        cands.append(Candidate(
            physics, [f"material.{name}.{key}"], [(lo, hi)], region=region,
            regions={name: sphere_condition(region["center"], region["radius"])},
            reason=f"{PHYSICS[physics]}; sphere from {origin}"))
    return cands, skipped
