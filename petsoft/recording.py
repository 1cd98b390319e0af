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
