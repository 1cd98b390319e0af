"""Importers: lab and motion-capture files (CSV, C3D) turned into petsoft recordings.

Every importer returns a :class:`~petsoft.io.recording.Recording` in metres and seconds; unreadable
or inconsistent input raises :class:`ImportFileError` naming the file, the line/frame and what would
be valid.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from petsoft.errors import PetsoftError

#: Length units a file may be in, and their size in metres.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


class ImportFileError(PetsoftError):
    """A file to import is unreadable or inconsistent."""


def unit_scale(units: str | None, scale: float | None, source: str) -> float | None:
    """The factor to metres from ``--units`` or ``--scale`` (None when neither is given)."""
    if units is not None and scale is not None:
        raise ImportFileError(f"{source}: give --units or --scale, not both")
    if units is not None:
        if units not in UNITS:
            raise ImportFileError(f"{source}: unknown units {units!r}; valid: "
                                  f"{', '.join(UNITS)}")
        return UNITS[units]
    if scale is not None:
        if not (np.isfinite(scale) and scale > 0):
            raise ImportFileError(f"{source}: --scale = {scale} must be finite and > 0")
        return float(scale)
    return None


def reference_positions(positions: np.ndarray, names: list[str], source: str,
                        rest_frame: int | None = None) -> tuple[np.ndarray, int]:
    """Reference (rest) positions of the markers: a given frame, else the first frame in which
    every marker is seen.

    Returns
    -------
    reference : (M, 3) array
    frame : int
        The frame used.
    """
    seen = np.isfinite(positions).all(axis=2)
    K = len(positions)
    if rest_frame is not None:
        if not -K <= rest_frame < K:
            raise ImportFileError(f"{source}: rest frame {rest_frame} does not exist (the file "
                                  f"has {K} frames, 0 to {K - 1})")
        rest_frame %= K
        missing = np.flatnonzero(~seen[rest_frame])
        if len(missing):
            raise ImportFileError(
                f"{source}: marker {names[missing[0]]!r} is not seen in the rest frame "
                f"{rest_frame}; choose a frame where every marker is seen")
        return positions[rest_frame].copy(), rest_frame
    full = np.flatnonzero(seen.all(axis=1))
    if not len(full):
        counts = seen.sum(axis=0)
        worst = int(np.argmin(counts))
        raise ImportFileError(
            f"{source}: no frame sees every marker (marker {names[worst]!r} is seen in "
            f"{int(counts[worst])} of {K} frames), so the reference positions are undefined; "
            "give a rest frame (--rest-frame) in which all are seen, or drop that marker")
    return positions[full[0]].copy(), int(full[0])


def import_file(path: Path, fmt: str | None = None, *, units: str | None = None,
                scale: float | None = None, rest_frame: int | None = None):
    """Read a CSV or C3D file (format from ``fmt`` or the file extension) as a Recording."""
    path = Path(path)
    if not path.is_file():
        raise ImportFileError(f"{path}: file not found")
    fmt = fmt or {".csv": "csv", ".txt": "csv", ".c3d": "c3d"}.get(path.suffix.lower())
    if fmt == "csv":
        from petsoft.io.importers.csv import read_csv

        return read_csv(path, units=units, scale=scale, rest_frame=rest_frame)
    if fmt == "c3d":
        from petsoft.io.importers.c3d import read_c3d

        return read_c3d(path, units=units, scale=scale, rest_frame=rest_frame)
    raise ImportFileError(f"{path}: cannot tell the format from the extension "
                          f"{path.suffix!r}; give --format csv or --format c3d")


def run_import(args) -> int:
    """`petsoft import FILE --out RECORDING.h5 ...` (every rank reads, rank 0 writes)."""
    from petsc4py import PETSc

    rec = import_file(Path(args.file), args.format, units=args.units, scale=args.scale,
                      rest_frame=args.rest_frame)
    if args.position_std is not None:
        if not (np.isfinite(args.position_std) and args.position_std >= 0):
            raise ImportFileError(f"--position-std = {args.position_std} must be >= 0")
        rec.noise["position_std"] = float(args.position_std)
    if PETSc.COMM_WORLD.rank == 0:
        if rec.attrs.get("note"):
            print(f"petsoft import: note: {rec.attrs['note']}", flush=True)
        path = rec.write(Path(args.out))
        seen = rec.seen()
        print(f"petsoft import: {rec.num_markers} markers, {rec.num_frames} frames "
              f"({rec.times[0]:g} to {rec.times[-1]:g} s), {seen.mean():.1%} of samples seen, "
              f"reference = frame {rec.attrs['reference_frame']}; wrote {path}", flush=True)
    return 0
