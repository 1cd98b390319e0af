"""Named numeric parameters of an experiment: what ``[calibrate]`` and calibration address.

This module owns the dotted parameter names (``"material.youngs_modulus"``,
``"material.<region>.density"``, ``"damping.mass"``, ...): how a key is written in one
(:func:`key_part`), which an experiment has
(:func:`parameter_names`), their values (:func:`get_parameter`) and valid ranges
(:func:`parameter_table`), how a name splits into keys (:func:`split_parameter`), and the check of
``[calibrate]`` bounds (:func:`read_calibrate`). Copies with parameters changed are made by
:mod:`petsoft.experiment.changes`.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from typing import Any

from petsoft.errors import ExperimentError
from petsoft.experiment.messages import show_value, suggest
from petsoft.experiment.ranges import (
    ANY,
    MATERIAL_RANGES,
    NONNEGATIVE,
    POSITIVE,
    Range,
    key_range,
)
from petsoft.experiment.spec import COMPONENTS, Experiment
from petsoft.terms import keys_of, plugin_tables

# ------------------------------------------------------------------------------------------------
# Named numeric parameters (calibration).

_INDEXED_KEY = re.compile(r"[A-Za-z0-9_-]+(\[\d+\])*")


def key_part(k: str) -> str:
    """One part of a dotted parameter or key name as a message shows it: an array entry as
    ``key[i]``, any other key as TOML writes it (quoted when it needs quotes)."""
    return k if _INDEXED_KEY.fullmatch(k) else json.dumps(k)


def parameter_table(exp: Experiment) -> dict[str, tuple[float, Range]]:
    """All named numeric parameters of ``exp``: name -> (current value, valid range)."""
    params: dict[str, tuple[float, Range]] = {}
    if exp.material:
        default = exp.material["default"]
        for k, (rng, _unit) in MATERIAL_RANGES.items():
            params[f"material.{k}"] = (getattr(default, k), rng)
        regions = [n for n in exp.material if n != "default"]
        regions += [n for n in exp.regions if n not in exp.material]
        for name in regions:
            spec = exp.material_for(name)
            for k, (rng, _unit) in MATERIAL_RANGES.items():
                params[f"material.{key_part(name)}.{k}"] = (getattr(spec, k), rng)
    params["damping.mass"] = (exp.damping.mass, NONNEGATIVE)
    params["damping.stiffness"] = (exp.damping.stiffness, NONNEGATIVE)
    params["drag.linear"] = (exp.drag.linear, NONNEGATIVE)
    params["drag.quadratic"] = (exp.drag.quadratic, NONNEGATIVE)
    params["friction.dry"] = (exp.friction.dry, NONNEGATIVE)
    for i, c in enumerate(COMPONENTS):
        params[f"gravity.acceleration.{c}"] = (exp.gravity.as_stated[i], ANY)
    if exp.material and any(exp.gravity.as_stated):
        # the direction of a stated gravity at its own size (petsoft.experiment.gravity_tilt;
        # continuum models: their systems take its derivative)
        params["gravity.tilt_a"] = (exp.gravity.tilt_a, ANY)
        params["gravity.tilt_b"] = (exp.gravity.tilt_b, ANY)
    compliant = [b.compliance for b in exp.boundaries if b.kind == "fixed" and b.compliance > 0]
    if compliant:
        # one value shared by every elastic support (with_parameters sets them all)
        params["boundary.compliance"] = (compliant[0], POSITIVE)
    for i, c in enumerate(exp.colliders):
        # a differentiable parameter of continuum models (mass-spring models honour the key)
        if c.kind == "plane" and exp.material:
            params[f"collider.{i}.offset"] = (c.offset, ANY)
    if exp.springs is not None:
        s = exp.springs
        params["springs.stiffness"] = (s.stiffness, POSITIVE)
        params["springs.damping"] = (s.damping, NONNEGATIVE)
        params["springs.bending"] = (s.bending or 0.0, NONNEGATIVE)
        params["springs.node_mass"] = (s.node_mass, NONNEGATIVE)
    else:
        params["viscoelastic.ratio"] = (exp.viscoelastic.ratio, NONNEGATIVE)
        params["viscoelastic.relaxation_time"] = (exp.viscoelastic.relaxation_time, POSITIVE)
    # the number keys of the tables of other packages' terms the experiment gives
    for table, values in exp.terms.items():
        for k in keys_of(table):
            if k.type == "number":
                params[f"{table}.{k.key}"] = (values[k.key], key_range(k))
    return params


#: The unit of each parameter kind (the last part of a dotted name; formats.md section 1).
PARAMETER_UNITS = {
    **{k: unit for k, (_rng, unit) in MATERIAL_RANGES.items()},
    "damping.mass": "1/s", "damping.stiffness": "s", "drag.linear": "Pa s/m",
    "drag.quadratic": "kg/m^3", "friction.dry": "m/s^2", "gravity.acceleration": "m/s^2",
    "gravity.tilt_a": "", "gravity.tilt_b": "",
    "boundary.compliance": "m/Pa", "offset": "m", "springs.stiffness": "N/m",
    "springs.damping": "N s/m", "springs.bending": "N/m", "springs.node_mass": "kg",
    "viscoelastic.ratio": "", "viscoelastic.relaxation_time": "s",
}


def parameter_unit(name: str) -> str:
    """The SI unit of a dotted parameter name (``""`` for a ratio), e.g. ``"Pa"`` for
    ``"material.<region>.youngs_modulus"``, ``"1/s"`` for ``"damping.mass"``.

    Raises
    ------
    ExperimentError
        For a name that is no parameter kind of :func:`parameter_table`.
    """
    parts = split_parameter(name)
    plugin = plugin_tables().get(parts[0])
    if plugin is not None and len(parts) == 2:
        for k in plugin.term.keys:
            if k.table == parts[0] and k.key == parts[1] and k.type == "number":
                return k.unit
    for key in (name, ".".join(parts[:2]), parts[-1]):
        if key in PARAMETER_UNITS and (key != parts[-1] or parts[0] in ("material", "collider")):
            return PARAMETER_UNITS[key]
    raise ExperimentError(f'"{name}" is no parameter petsoft knows the unit of (known kinds: '
                          f"{', '.join(PARAMETER_UNITS)})")


def parameter_names(experiment: Experiment) -> list[str]:
    """The dotted names of the numeric parameters that ``[calibrate]`` and
    :func:`with_parameters` accept, e.g. ``"material.youngs_modulus"``,
    ``"material.<region>.density"`` (for regions with a ``[material.<region>]`` table or a
    ``[region.<name>]``), ``"damping.mass"``, ``"gravity.acceleration.z"``,
    ``"springs.stiffness"``, ``"boundary.compliance"`` (when a fixed boundary has
    compliance > 0), ``"collider.<i>.offset"`` (for a plane collider),
    ``"viscoelastic.ratio"`` (continuum models)."""
    return list(parameter_table(experiment))


def get_parameter(experiment: Experiment, name: str) -> float:
    """The current value of the named parameter (see :func:`parameter_names`)."""
    table = parameter_table(experiment)
    if name not in table:
        raise ExperimentError(unknown_parameter(experiment.source, name, table))
    return table[name][0]


def unknown_parameter(source: str, name: str, table: Mapping[str, Any]) -> str:
    close = suggest(name, table)
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
    if parts[0] in plugin_tables() and len(parts) == 2:
        note = (f" (a term of package {plugin_tables()[parts[0]].package!r}: give its "
                f"[{parts[0]}] table in the experiment to use or calibrate it)")
    if parts[0] == "collider":
        note = (
            ' (collider.<i>.offset exists for [[collider]] kind = "plane" of [material] models '
            "only)"
        )
    return (
        f'{source}: "{name}" is not a numeric parameter of this experiment{hint}{note}. '
        f"Valid: {', '.join(table)}"
    )


def split_parameter(name: str) -> list[str]:
    # Region names may be quoted ("material.\"my group\".density"); split outside quotes.
    return [p.strip('"') for p in re.findall(r'"[^"]*"|[^.]+', name)]



def _flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in table.items():
        name = f"{prefix}.{k}" if prefix else k
        if isinstance(v, dict):
            out.update(_flatten(v, name))
        else:
            out[name] = v
    return out


def read_calibrate(
    calibrate: Mapping[str, Any], source: str, exp: Experiment
) -> dict[str, tuple[float, float]]:
    """The ``[calibrate]`` table ``calibrate`` of ``exp`` (read from ``source``) checked, as
    name -> (lower, upper).

    Raises
    ------
    ExperimentError
        For a name that is not a parameter of ``exp``, bounds that are not two finite numbers
        lower < upper within the parameter's range, or a current value outside them.
    """
    table = parameter_table(exp)
    result: dict[str, tuple[float, float]] = {}
    for name, bounds in _flatten(calibrate).items():
        key = f'calibrate."{name}"'
        if name not in table:
            raise ExperimentError(unknown_parameter(f"{source}: {key}", name, table))
        value, rng = table[name]
        expected = "an array [lower, upper] of two numbers with lower < upper"
        if not isinstance(bounds, list) or len(bounds) != 2:
            raise ExperimentError(
                f"{source}: {key} = {show_value(bounds)} has the wrong type: expected {expected}"
            )
        for b in bounds:
            if isinstance(b, bool) or not isinstance(b, (int, float)) or not math.isfinite(b):
                raise ExperimentError(
                    f"{source}: {key} = {show_value(bounds)}: bound {show_value(b)} is not a "
                    "finite "
                    f"number; expected {expected}"
                )
        lo, hi = float(bounds[0]), float(bounds[1])
        if not lo < hi:
            raise ExperimentError(f"{source}: {key} = {show_value(bounds)}: expected lower < upper")
        short = name.rsplit(".", 1)[-1]
        for b in (lo, hi):
            if not rng.contains(b):
                raise ExperimentError(
                    f"{source}: {key} = {show_value(bounds)}: the bound {show_value(b)} is not a "
                    "valid "
                    f"value of {name} (valid is {rng.text(short)})"
                )
        if not lo <= value <= hi:
            raise ExperimentError(
                f"{source}: {key} = {show_value(bounds)}: the current value {name} = "
                f"{show_value(value)} (the starting point of the calibration) is outside the bounds"
            )
        result[name] = (lo, hi)
    both = [n for n in result if n.startswith("gravity.")]
    if any(n.startswith("gravity.tilt") for n in both) and any(
            n.startswith("gravity.acceleration") for n in both):
        raise ExperimentError(
            f"{source}: [calibrate] has both {' and '.join(both)}: calibrate gravity's "
            "components (its size and direction) or its tilt (its direction at the stated "
            "size), not both")
    return result

