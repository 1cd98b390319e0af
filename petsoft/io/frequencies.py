"""Measured natural frequencies: the file ``petsoft calibrate --modes FILE`` reads.

Two layouts, chosen by the extension:

* text or CSV (any other extension): one mode per line, ``frequency_hz`` or
  ``frequency_hz, std_hz`` (comma, semicolon or whitespace separated), in ascending order of the
  body's elastic modes; ``#`` starts a comment; a first line that is not numbers is a header;
* JSON (``.json``): ``{"frequencies_hz": [...], "std_hz": [...], "markers": {...},
  "mode_shapes": [...]}``; only ``frequencies_hz`` is required. ``markers`` maps a name to the
  marker's reference position ``[x, y, z]`` (m, inside the body); ``mode_shapes`` gives, per
  measured mode, one ``[ux, uy, uz]`` per marker (in the order of ``markers``): shape (modes,
  markers, 3), any scale and sign per mode, ``null`` (or ``NaN``) for a component not seen. With
  mode shapes the measured modes need not be the lowest ones nor be listed in ascending order:
  each is paired with the model mode of the largest MAC (:mod:`petsoft.calibration.frequencies`).

A standard deviation is the frequency's measurement noise (Hz); without one every frequency is
weighed the same and the noise is estimated from the fit. Errors name the file, the line and what
would be valid.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from petsoft.errors import PetsoftError

__all__ = ["FrequencyFileError", "MeasuredFrequencies", "read_frequencies"]


class FrequencyFileError(PetsoftError):
    """A measured-frequencies file that cannot be used (the message says where and why)."""


#: The keys of the JSON layout (module docstring); ``comment`` is free text.
JSON_KEYS = ("frequencies_hz", "std_hz", "markers", "mode_shapes", "comment")


@dataclass(frozen=True)
class MeasuredFrequencies:
    """Measured natural frequencies (Hz), their standard deviations (or None) and, optionally,
    the mode shapes at markers.

    Attributes
    ----------
    frequencies : ndarray (k,)
        Ascending unless ``shapes`` are given (then paired by shape, in any order).
    std : ndarray (k,) or None
    source : str
        Where they came from (for messages and reports).
    markers : ndarray (m, 3) or None
        Reference positions (m) of the markers the shapes are given at.
    marker_names : tuple of str or None
        One name per marker (``m0``, ``m1``, ... when none are given).
    shapes : ndarray (k, m, 3) or None
        Mode shape of each measured mode at the markers, real or complex (an operational shape
        from a recording), any scale per mode; NaN where a component was not seen. Each mode
        needs at least two seen components, not all zero.
    details : dict or None
        How the frequencies were obtained (e.g. from a recording: the method and every
        estimated mode); reported in summary.json.
    """

    frequencies: np.ndarray
    std: np.ndarray | None
    source: str
    markers: np.ndarray | None = None
    marker_names: tuple | None = None
    shapes: np.ndarray | None = None
    details: dict | None = None

    def __post_init__(self):
        f = np.asarray(self.frequencies, dtype=float).reshape(-1)
        where = self.source
        if f.size == 0:
            raise FrequencyFileError(f"{where}: no frequency given; list one natural frequency "
                                     "(Hz) per line")
        bad = np.flatnonzero(~(np.isfinite(f) & (f > 0)))
        if bad.size:
            raise FrequencyFileError(f"{where}: frequency {bad[0] + 1} is {f[bad[0]]!r}; "
                                     "frequencies must be finite numbers > 0 (Hz)")
        if self.shapes is not None or self.markers is not None:
            self._check_shapes(f)
        elif np.any(np.diff(f) < 0):
            i = int(np.flatnonzero(np.diff(f) < 0)[0])
            raise FrequencyFileError(f"{where}: frequency {i + 2} ({f[i + 1]:g} Hz) is below "
                                     f"frequency {i + 1} ({f[i]:g} Hz); list the modes in "
                                     "ascending order (they are paired with the model's elastic "
                                     "modes in that order), or give their mode shapes at "
                                     "markers (JSON) to pair them by shape")
        object.__setattr__(self, "frequencies", f)
        if self.std is not None:
            s = np.asarray(self.std, dtype=float).reshape(-1)
            if s.size != f.size:
                raise FrequencyFileError(f"{where}: {s.size} standard deviations for {f.size} "
                                         "frequencies; give one per frequency or none")
            bad = np.flatnonzero(~(np.isfinite(s) & (s > 0)))
            if bad.size:
                raise FrequencyFileError(f"{where}: the standard deviation of frequency "
                                         f"{bad[0] + 1} is {s[bad[0]]!r}; it must be > 0 (Hz)")
            object.__setattr__(self, "std", s)

    def _check_shapes(self, f: np.ndarray) -> None:
        """Validate markers and shapes together (the messages name the mode and the marker)."""
        where, count = self.source, f.size
        if self.shapes is None or self.markers is None:
            given, missing = (("mode_shapes", "markers") if self.markers is None
                              else ("markers", "mode_shapes"))
            raise FrequencyFileError(
                f"{where}: \"{given}\" is given without \"{missing}\"; mode shapes need the "
                "markers' reference positions ({\"name\": [x, y, z], ...}) and markers are only "
                "used with mode shapes (one [ux, uy, uz] per marker per measured mode)")
        X = np.asarray(self.markers, dtype=float)
        if X.ndim != 2 or X.shape[1] != 3 or len(X) == 0:
            raise FrequencyFileError(f"{where}: markers have shape {X.shape}; give one "
                                     "reference position [x, y, z] (m) per marker")
        names = (tuple(str(n) for n in self.marker_names) if self.marker_names is not None
                 else tuple(f"m{i}" for i in range(len(X))))
        if len(names) != len(X) or len(set(names)) != len(names):
            raise FrequencyFileError(f"{where}: {len(names)} marker names for {len(X)} markers "
                                     "(names must be distinct, one per marker)")
        bad = np.flatnonzero(~np.isfinite(X).all(axis=1))
        if bad.size:
            raise FrequencyFileError(f"{where}: markers[\"{names[bad[0]]}\"] is "
                                     f"{X[bad[0]].tolist()}; a reference position is three "
                                     "finite numbers (m)")
        U = np.asarray(self.shapes)
        U = U.astype(complex if np.iscomplexobj(U) else float)
        if U.shape != (count, len(X), 3):
            raise FrequencyFileError(
                f"{where}: mode_shapes has shape {U.shape}; expected ({count} modes, "
                f"{len(X)} markers, 3): one [ux, uy, uz] per marker (in the order of "
                "\"markers\") for each measured frequency")
        inf = np.argwhere(np.isinf(U))
        if len(inf):
            i, j, _ = inf[0]
            raise FrequencyFileError(f"{where}: mode_shapes: mode {i + 1}, marker "
                                     f"\"{names[j]}\" has an infinite component; use finite "
                                     "numbers, or null for a component not seen")
        seen = np.isfinite(U)
        norm = np.sum(np.abs(np.where(seen, U, 0.0)) ** 2, axis=(1, 2))
        poor = np.flatnonzero((seen.sum(axis=(1, 2)) < 2) | ~(norm > 0))
        if poor.size:
            i = int(poor[0])
            raise FrequencyFileError(
                f"{where}: mode_shapes: mode {i + 1} ({f[i]:g} Hz) has "
                f"{int(seen[i].sum())} seen component(s), all zero or fewer than two; a mode "
                "shape needs at least two seen components, not all zero (null = not seen)")
        object.__setattr__(self, "markers", X)
        object.__setattr__(self, "marker_names", names)
        object.__setattr__(self, "shapes", U)


def read_frequencies(path: str | Path) -> MeasuredFrequencies:
    """Read a measured-frequencies file (module docstring).

    Raises
    ------
    FrequencyFileError
        Missing or unreadable file, a line that is not one or two numbers (named by its number),
        a non-positive frequency or std, frequencies not ascending, mixed rows with and without
        a std.
    """
    path = Path(path)
    if not path.is_file():
        raise FrequencyFileError(f"measured frequencies file {path} does not exist")
    text = path.read_text(errors="replace")
    if path.suffix.lower() == ".json":
        return _from_json(text, str(path))
    rows: list[list[float]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = [f for f in re.split(r"[,;\s]+", line) if f]
        try:
            values = [float(f) for f in fields]
        except ValueError:
            if not rows and number == _first_content_line(text):
                continue            # a header
            raise FrequencyFileError(
                f"{path}: line {number}: {line!r} is not a number; each line is frequency_hz "
                "or frequency_hz, std_hz") from None
        if len(values) not in (1, 2) or not all(math.isfinite(v) for v in values):
            raise FrequencyFileError(
                f"{path}: line {number}: {line!r} has {len(values)} values; each line is "
                "frequency_hz or frequency_hz, std_hz (finite numbers)")
        rows.append(values)
    if not rows:
        raise FrequencyFileError(f"{path}: no frequency found; list one natural frequency (Hz) "
                                 "per line")
    widths = {len(r) for r in rows}
    if len(widths) > 1:
        raise FrequencyFileError(f"{path}: some lines give a standard deviation and some do not; "
                                 "give it on every line or on none")
    data = np.array(rows)
    return MeasuredFrequencies(data[:, 0], data[:, 1] if data.shape[1] == 2 else None,
                               str(path))


def _first_content_line(text: str) -> int:
    for number, line in enumerate(text.splitlines(), start=1):
        if line.split("#", 1)[0].strip():
            return number
    return 0


def _from_json(text: str, source: str) -> MeasuredFrequencies:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FrequencyFileError(f"{source}: not valid JSON ({exc.msg} at line {exc.lineno})") \
            from None
    if not isinstance(data, dict) or "frequencies_hz" not in data:
        raise FrequencyFileError(f"{source}: expected an object with \"frequencies_hz\": [...] "
                                 "(and optionally \"std_hz\", \"markers\", \"mode_shapes\")")
    unknown = [k for k in data if k not in JSON_KEYS]
    if unknown:
        # a misspelt "mode_shapes" would silently fall back to pairing in ascending order
        raise FrequencyFileError(f"{source}: unknown key \"{unknown[0]}\"; the keys are "
                                 + ", ".join(JSON_KEYS))
    try:
        f = np.asarray(data["frequencies_hz"], dtype=float)
        s = None if data.get("std_hz") is None else np.asarray(data["std_hz"], dtype=float)
    except (TypeError, ValueError):
        raise FrequencyFileError(f"{source}: frequencies_hz and std_hz must be arrays of "
                                 "numbers") from None
    markers = names = shapes = None
    if data.get("markers") is not None:
        names, markers = _json_markers(data["markers"], source)
    if data.get("mode_shapes") is not None:
        shapes = _json_shapes(data["mode_shapes"], f.size, names, source)
    return MeasuredFrequencies(f, s, source, markers=markers, marker_names=names, shapes=shapes)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _json_markers(markers, source: str) -> tuple[tuple, np.ndarray]:
    if not isinstance(markers, dict) or not markers:
        raise FrequencyFileError(f"{source}: \"markers\" must be an object {{\"name\": "
                                 "[x, y, z], ...}} of reference positions (m)")
    for name, x in markers.items():
        if not (isinstance(x, list) and len(x) == 3 and all(_is_number(v) and math.isfinite(v)
                                                            for v in x)):
            raise FrequencyFileError(f"{source}: markers[\"{name}\"] is {x!r}; a marker's "
                                     "reference position is [x, y, z], three finite numbers (m)")
    return tuple(markers), np.array(list(markers.values()), dtype=float)


def _json_shapes(shapes, count: int, names, source: str) -> np.ndarray:
    """(k, m, 3) floats, NaN for null; the messages name the mode and the marker."""
    if names is None:
        raise FrequencyFileError(f"{source}: \"mode_shapes\" is given without \"markers\"; "
                                 "give the markers' reference positions {\"name\": [x, y, z], "
                                 "...} (m), in the order the shapes list them")
    if not isinstance(shapes, list) or len(shapes) != count:
        n = len(shapes) if isinstance(shapes, list) else "no"
        raise FrequencyFileError(f"{source}: mode_shapes lists {n} modes for {count} "
                                 "frequencies; give one shape per measured frequency, in the "
                                 "same order")
    out = np.full((count, len(names), 3), np.nan)
    for i, mode in enumerate(shapes):       # a user file: a few modes x markers
        if not isinstance(mode, list) or len(mode) != len(names):
            n = len(mode) if isinstance(mode, list) else "no"
            raise FrequencyFileError(
                f"{source}: mode_shapes: mode {i + 1} has {n} markers, \"markers\" has "
                f"{len(names)}; give one [ux, uy, uz] per marker, in the order of \"markers\"")
        for j, u in enumerate(mode):
            if not (isinstance(u, list) and len(u) == 3
                    and all(v is None or _is_number(v) for v in u)):
                raise FrequencyFileError(
                    f"{source}: mode_shapes: mode {i + 1}, marker \"{names[j]}\" is {u!r}; "
                    "give [ux, uy, uz]: numbers, or null for a component not seen")
            out[i, j] = [np.nan if v is None else v for v in u]
    return out
