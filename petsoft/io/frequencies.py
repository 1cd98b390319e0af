"""Measured natural frequencies: the file ``petsoft calibrate --modes FILE`` reads.

Two layouts, chosen by the extension:

* text or CSV (any other extension): one mode per line, ``frequency_hz`` or
  ``frequency_hz, std_hz`` (comma, semicolon or whitespace separated), in ascending order of the
  body's elastic modes; ``#`` starts a comment; a first line that is not numbers is a header;
* JSON (``.json``): ``{"frequencies_hz": [...], "std_hz": [...]}`` (``std_hz`` optional).

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


@dataclass(frozen=True)
class MeasuredFrequencies:
    """Measured natural frequencies (Hz), ascending, and their standard deviations (or None).

    Attributes
    ----------
    frequencies : ndarray (k,)
    std : ndarray (k,) or None
    source : str
        Where they came from (for messages and reports).
    """

    frequencies: np.ndarray
    std: np.ndarray | None
    source: str

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
        if np.any(np.diff(f) < 0):
            i = int(np.flatnonzero(np.diff(f) < 0)[0])
            raise FrequencyFileError(f"{where}: frequency {i + 2} ({f[i + 1]:g} Hz) is below "
                                     f"frequency {i + 1} ({f[i]:g} Hz); list the modes in "
                                     "ascending order (they are paired with the model's elastic "
                                     "modes in that order)")
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
                                 "(and optionally \"std_hz\": [...])")
    try:
        f = np.asarray(data["frequencies_hz"], dtype=float)
        s = None if data.get("std_hz") is None else np.asarray(data["std_hz"], dtype=float)
    except (TypeError, ValueError):
        raise FrequencyFileError(f"{source}: frequencies_hz and std_hz must be arrays of "
                                 "numbers") from None
    return MeasuredFrequencies(f, s, source)
