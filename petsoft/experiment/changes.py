"""Copies of an experiment with something changed, validated again like a file.

This module owns the edits calibration and diagnosis make to an experiment: setting named
parameters (:func:`with_parameters`), turning rigid supports elastic (:func:`with_compliance`)
and adding a plane collider (:func:`with_plane_collider`). Each goes through the dict form and
:func:`~petsoft.experiment.reader.experiment_from_dict`, so a changed experiment is as valid as a
loaded one.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from petsoft.errors import ExperimentError
from petsoft.experiment.parameters import parameter_table, split_parameter, unknown_parameter
from petsoft.experiment.reader import experiment_from_dict
from petsoft.experiment.spec import COMPONENTS, Experiment


def with_parameters(experiment: Experiment, values: Mapping[str, float]) -> Experiment:
    """A copy of ``experiment`` with the named parameters set, validated again.

    Region materials that do not override a changed default parameter follow it.

    Raises
    ------
    ExperimentError
        For an unknown parameter name or an invalid value.
    """
    table = parameter_table(experiment)
    data = experiment.to_dict()
    for name, value in values.items():
        if name not in table:
            raise ExperimentError(unknown_parameter(experiment.source, name, table))
        parts = split_parameter(name)
        if parts[0] == "boundary":
            # every elastic support shares the compliance
            for entry in data["boundary"]:
                if entry["kind"] == "fixed" and entry.get("compliance", 0.0) > 0.0:
                    entry["compliance"] = float(value)
            continue
        if parts[0] == "collider":
            data["collider"][int(parts[1])]["offset"] = float(value)
            continue
        if parts[:2] == ["gravity", "acceleration"]:
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

