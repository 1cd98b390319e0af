"""CSV marker trajectories: ``time, <name>_x, <name>_y, <name>_z, ...``.

* The first non-comment line (``#`` starts a comment) is the header: ``time`` first, then three
  columns per marker named ``<name>_x``, ``<name>_y``, ``<name>_z`` (in this order, case of the
  suffix ignored). Marker names may contain underscores.
* One row per frame; time in seconds, strictly increasing.
* An empty cell or ``NaN`` means the marker was not seen in that frame (all three of its cells
  must then be empty: a marker is seen or not).
* Positions are multiplied by the unit scale (``units="mm"`` or ``scale=0.001`` for millimetres).
* The reference (rest) configuration is the first frame in which every marker is seen, unless a
  rest frame is given.
"""

from __future__ import annotations

import csv as _csv
from pathlib import Path

import numpy as np

from petsoft.io.importers import ImportFileError, reference_positions, unit_scale
from petsoft.io.recording import Recording


def _header(row: list[str], source: str) -> list[str]:
    cells = [c.strip() for c in row]
    if not cells or cells[0].lower() not in ("time", "t"):
        raise ImportFileError(f"{source}: line 1: the first column must be 'time', got "
                              f"{cells[0] if cells else ''!r} (header: time, <name>_x, "
                              "<name>_y, <name>_z, ...)")
    rest = cells[1:]
    if not rest or len(rest) % 3:
        raise ImportFileError(f"{source}: line 1: {len(rest)} columns after 'time'; expected "
                              "three per marker (<name>_x, <name>_y, <name>_z)")
    names = []
    for j in range(0, len(rest), 3):
        triple = rest[j:j + 3]
        stems = [c[:-2] for c in triple]
        suffixes = [c[-2:].lower() for c in triple]
        if suffixes != ["_x", "_y", "_z"] or len(set(stems)) != 1 or not stems[0]:
            raise ImportFileError(f"{source}: line 1: columns {j + 2}-{j + 4} are "
                                  f"{', '.join(triple)}; expected <name>_x, <name>_y, <name>_z "
                                  "of one marker")
        if stems[0] in names:
            raise ImportFileError(f"{source}: line 1: marker {stems[0]!r} appears twice")
        names.append(stems[0])
    return names


def _number(cell: str, source: str, line: int, column: str) -> float:
    c = cell.strip()
    if c == "" or c.lower() == "nan":
        return np.nan
    try:
        v = float(c)
    except ValueError:
        raise ImportFileError(f"{source}: line {line}, column {column}: {c!r} is not a number "
                              "(empty or NaN means 'not seen')") from None
    if not np.isfinite(v):
        raise ImportFileError(f"{source}: line {line}, column {column}: {c!r} is not finite")
    return v


def read_csv(path: Path, *, units: str | None = None, scale: float | None = None,
             rest_frame: int | None = None) -> Recording:
    """Read a CSV marker file (see the module docstring) as a Recording in metres.

    Raises
    ------
    ImportFileError
        Naming the file, line and column: bad header, wrong number of cells, non-numeric cells,
        time missing or not increasing, a marker seen in only some of its coordinates, no frame
        in which every marker is seen.
    """
    path = Path(path)
    source = str(path)
    factor = unit_scale(units, scale, source) or 1.0
    with open(path, newline="", encoding="utf-8-sig") as fh:
        rows = [(i + 1, r) for i, r in enumerate(_csv.reader(fh))
                if r and not r[0].lstrip().startswith("#") and any(c.strip() for c in r)]
    if not rows:
        raise ImportFileError(f"{source}: empty file (expected a header time, <name>_x, ...)")
    header_line, header = rows[0]
    names = _header(header, source)
    columns = ["time"] + [c.strip() for c in header[1:]]
    if len(rows) < 2:
        raise ImportFileError(f"{source}: no data rows after the header")
    table = np.empty((len(rows) - 1, len(columns)))
    for k, (line, row) in enumerate(rows[1:]):
        if len(row) != len(columns):
            raise ImportFileError(f"{source}: line {line} has {len(row)} cells; the header has "
                                  f"{len(columns)}")
        table[k] = [_number(c, source, line, col) for c, col in zip(row, columns, strict=True)]
    lines = [line for line, _ in rows[1:]]
    times = table[:, 0]
    bad = np.flatnonzero(~np.isfinite(times))
    if len(bad):
        raise ImportFileError(f"{source}: line {lines[bad[0]]}: the time is missing")
    dec = np.flatnonzero(np.diff(times) <= 0)
    if len(dec):
        i = int(dec[0])
        raise ImportFileError(f"{source}: line {lines[i + 1]}: time {times[i + 1]:g} s does not "
                              f"increase (previous {times[i]:g} s); times must increase "
                              "strictly")
    pos = table[:, 1:].reshape(len(times), len(names), 3) * factor
    nan = np.isnan(pos)
    partial = nan.any(axis=2) & ~nan.all(axis=2)
    if partial.any():
        k, m = (int(i) for i in np.argwhere(partial)[0])
        raise ImportFileError(f"{source}: line {lines[k]}: marker {names[m]!r} has only some "
                              "of its x, y, z cells; leave all three empty when not seen")
    reference, frame = reference_positions(pos, names, source, rest_frame)
    attrs = {"source": f"imported from {path.name} (CSV)", "reference_frame": frame,
             "unit_scale": factor}
    return Recording(reference, names, times, pos, attrs=attrs, source=source)
