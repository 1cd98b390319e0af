"""Regenerate the C3D fixtures of tests/test_c3d_tools.py with two maintained C3D writers.

Run from the repository root with ezc3d and c3d installed (``pip install ezc3d c3d``; the tests
themselves need neither)::

    python tests/data/c3d/make_fixtures.py

The positions written are ``positions(K, M)`` below (millimetres); tests/test_c3d_tools.py
repeats the same formula to check what the reader returns.
"""

import gzip
from pathlib import Path

import c3d
import ezc3d
import numpy as np

HERE = Path(__file__).parent
LABELS = ["RHEE", "LHEE", "T10"]
MISSING = (slice(3, 5), 1)         # marker 1 is not seen in frames 3 and 4


def positions(K: int, M: int) -> np.ndarray:
    """(K, M, 3) marker positions in millimetres (within int16 range at scale 0.1)."""
    k = np.arange(K, dtype=float)[:, None]
    m = np.arange(M, dtype=float)[None, :]
    return np.stack([100 * m + 10 * k + 0.123, 200 + m - 0.5 * k, 1000.25 + 3 * k + 0 * m],
                    axis=2)


def write_ezc3d(path: Path, pos: np.ndarray, labels, rate: float, units: str = "mm",
                analog: int = 0) -> None:
    """ezc3d (float storage, always): a missing marker is NaN coordinates with residual 0."""
    K, M, _ = pos.shape
    f = ezc3d.c3d()
    f["parameters"]["POINT"]["RATE"]["value"] = [rate]
    f["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    f["parameters"]["POINT"]["UNITS"]["value"] = [units]
    pts = np.ones((4, M, K))
    pts[:3] = pos.transpose(2, 1, 0)
    f["data"]["points"] = pts
    if analog:
        f["parameters"]["ANALOG"]["RATE"]["value"] = [rate * analog]
        f["parameters"]["ANALOG"]["LABELS"]["value"] = ("EMG1", "EMG2")
        f["data"]["analogs"] = np.random.default_rng(0).normal(size=(1, 2, K * analog))
    f.write(str(path))


def write_c3d_lib(path: Path, pos: np.ndarray, labels, rate: float, scale: float,
                  units: str = "mm") -> None:
    """c3d (EKF, pure Python): float (scale -1) or int16 (scale > 0) storage; a missing marker
    gets residual -1."""
    K, M, _ = pos.shape
    w = c3d.Writer(point_rate=rate, point_scale=scale, point_units=units.ljust(4))
    w.set_point_labels(labels)
    frames = []
    for k in range(K):
        p = np.zeros((M, 5), dtype=np.float32)
        p[:, :3] = pos[k]
        seen = np.isfinite(pos[k]).all(axis=1)
        p[~seen, :3] = 0
        p[~seen, 3] = -1
        frames.append((p, np.zeros((0, 0), dtype=np.float32)))
    w.add_frames(frames)
    with open(path, "wb") as h:
        w.write(h)


def main() -> None:
    pos = positions(10, 3)
    pos[MISSING] = np.nan
    write_ezc3d(HERE / "ezc3d_float_mm_analog.c3d", pos, LABELS, 100.0, analog=10)
    write_c3d_lib(HERE / "c3d_float_m.c3d", pos / 1000, LABELS, 100.0, scale=-1.0, units="m")
    write_c3d_lib(HERE / "c3d_int_mm.c3d", pos, LABELS, 100.0, scale=0.1)
    # 70,000 frames at 1 kHz, one marker: c3d writes POINT:LONG_FRAMES and the TRIAL fields;
    # ezc3d writes POINT:FRAMES = -1 (65,535) and nothing else, so only the file's length tells
    # (ezc3d 1.7.2 itself reads its own file back as 65,535 frames); gzipped, it is 0.3 MB
    long = positions(70000, 1) / 100
    write_c3d_lib(HERE / "c3d_long_70000.c3d", long, ["M0"], 1000.0, scale=-1.0)
    write_ezc3d(HERE / "ezc3d_long_70000.c3d", long, ["M0"], 1000.0)
    raw = (HERE / "ezc3d_long_70000.c3d").read_bytes()
    (HERE / "ezc3d_long_70000.c3d").unlink()
    with gzip.open(HERE / "ezc3d_long_70000.c3d.gz", "wb") as h:
        h.write(raw)


if __name__ == "__main__":
    main()
