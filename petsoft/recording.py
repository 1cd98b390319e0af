"""The recording format (formats.md section 2): writing marker trajectories to HDF5.

Any simulation's probes become a recording, so a simulation can serve as data.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

FORMAT = "petsoft-recording"
VERSION = 1


def write_recording(path: Path, reference: np.ndarray, times: np.ndarray,
                    positions: np.ndarray, names: list[str] | None = None,
                    attrs: dict | None = None) -> Path:
    """Write a recording atomically (a temporary file renamed into place).

    Parameters
    ----------
    reference : (M, 3) marker positions in the reference configuration.
    times : (K,) strictly increasing times (s).
    positions : (K, M, 3) measured (here: simulated) positions; NaN where not seen.
    """
    import h5py

    path = Path(path)
    times = np.asarray(times, dtype=np.float64)
    positions = np.asarray(positions, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    if positions.shape != (len(times), len(reference), 3):
        raise ValueError(f"positions {positions.shape} do not match {len(times)} times and "
                         f"{len(reference)} markers")
    if len(times) > 1 and np.any(np.diff(times) <= 0):
        raise ValueError("recording times must be strictly increasing")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = FORMAT
            f.attrs["version"] = VERSION
            for k, v in (attrs or {}).items():
                f.attrs[k] = v
            f["markers/reference"] = reference
            if names is not None:
                f.create_dataset("markers/name", data=np.array(names, dtype=object),
                                 dtype=h5py.string_dtype("utf-8"))
            f["frames/time"] = times
            f["frames/position"] = positions
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; a recording is shared data
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


class SeriesComponent:
    """One component of a measured input series, usable where an Expression of t is expected.

    Linear interpolation in time; asking for a time outside the recorded span is an error (no
    silent extrapolation of a measurement).
    """

    variables = frozenset({"t"})

    def __init__(self, times: np.ndarray, values: np.ndarray, source: str):
        self.times, self.values, self.source = times, values, source

    def evaluate_at(self, points, t: float | None = None) -> np.ndarray:
        from .errors import ExperimentError

        t = 0.0 if t is None else float(t)
        span = self.times[-1] - self.times[0]
        if t < self.times[0] - 1e-12 * max(span, 1.0) or t > self.times[-1] + 1e-12 * max(
                span, 1.0):
            raise ExperimentError(
                f"{self.source}: t = {t:g} s is outside the recorded input "
                f"[{self.times[0]:g}, {self.times[-1]:g}] s; shorten [time] end or record longer")
        return np.full(len(points), np.interp(t, self.times, self.values))


def read_input_series(path: Path, name: str) -> tuple[SeriesComponent, ...]:
    """The measured input ``/inputs/<name>`` of a recording as three time series (x, y, z).

    ``name`` may be given as ``"inputs/shaker"`` or ``"shaker"``.

    Raises
    ------
    ExperimentError
        Naming the file and dataset: missing file, unknown input (listing the available ones),
        wrong shapes, non-finite values or times that do not strictly increase.
    """
    import h5py

    from .errors import ExperimentError

    path = Path(path)
    key = name.split("/", 1)[1] if name.startswith("inputs/") else name
    if not path.is_file():
        raise ExperimentError(f"{path}: recording not found (needed for the input {name!r})")
    with h5py.File(path, "r") as f:
        inputs = f.get("inputs")
        available = sorted(inputs.keys()) if inputs is not None else []
        if key not in available:
            raise ExperimentError(f"{path}: no measured input {name!r}; the recording has "
                                  f"{', '.join('inputs/' + a for a in available) or 'none'}")
        times = np.asarray(inputs[key]["time"][()], dtype=float)
        values = np.asarray(inputs[key]["value"][()], dtype=float)
    where = f"{path}: /inputs/{key}"
    if times.ndim != 1 or len(times) < 2:
        raise ExperimentError(f"{where}/time must be a 1-D array of at least 2 times, "
                              f"got shape {times.shape}")
    if values.shape != (len(times), 3):
        raise ExperimentError(f"{where}/value must have shape ({len(times)}, 3), got "
                              f"{values.shape}")
    if not (np.isfinite(times).all() and np.isfinite(values).all()):
        raise ExperimentError(f"{where}: NaN or infinite entries (a support input must be "
                              "complete)")
    bad = np.flatnonzero(np.diff(times) <= 0)
    if len(bad):
        raise ExperimentError(f"{where}/time must increase strictly; it does not after index "
                              f"{bad[0]} (t = {times[bad[0]]:g} s)")
    return tuple(SeriesComponent(times, values[:, c], f"{where} ({'xyz'[c]})") for c in range(3))
