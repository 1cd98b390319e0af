"""Regenerate the C3D fixtures of tests/test_c3d_tools.py with two maintained C3D writers.

Run from the repository root with ezc3d and c3d installed (``pip install ezc3d c3d``; the tests
themselves need neither)::

    python tests/data/c3d/make_fixtures.py

The positions written are ``positions(K, M)`` below (millimetres); tests/test_c3d_tools.py
repeats the same formula to check what the reader returns.
"""

import gzip
import struct
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


def _to_processor(raw: bytes, processor: int) -> bytes:
    """An Intel float-storage C3D file rewritten as DEC (85: VAX F floats) or MIPS (86:
    big-endian): no maintained writer makes these, so the result is checked with c3d's reader."""
    out = bytearray(raw)

    def floats(at, n):
        v = np.frombuffer(raw, "<f4", n, at)
        if processor == 86:
            out[at:at + 4 * n] = v.astype(">f4").tobytes()
        else:   # VAX F = 4 x IEEE, with the two 16-bit words swapped
            u = (v * 4).astype("<f4").view("<u4")
            out[at:at + 4 * n] = ((u >> 16) | (u << 16)).astype("<u4").tobytes()

    def ints(at, n):
        if processor == 86:
            out[at:at + 2 * n] = np.frombuffer(raw, "<i2", n, at).astype(">i2").tobytes()

    ints(2, 5)
    floats(12, 1)
    ints(16, 2)
    floats(20, 1)
    pstart = (raw[0] - 1) * 512
    out[pstart + 3] = processor
    p = pstart + 4
    while True:
        nchar, gid = struct.unpack("bb", raw[p:p + 2])
        if nchar == 0:
            break
        q = p + 2 + abs(nchar)
        (offset,) = struct.unpack("<h", raw[q:q + 2])
        ints(q, 1)
        if gid > 0:
            code, ndim = struct.unpack("bB", raw[q + 2:q + 4])
            count = int(np.prod(list(raw[q + 4:q + 4 + ndim]))) if ndim else 1
            at = q + 4 + ndim
            if code == 4:
                floats(at, count)
            elif code == 2:
                ints(at, count)
        if offset == 0:
            break
        p = q + offset
    dstart = (struct.unpack("<H", raw[16:18])[0] - 1) * 512
    floats(dstart, (len(raw) - dstart) // 4)
    return bytes(out)


def main() -> None:
    pos = positions(10, 3)
    pos[MISSING] = np.nan
    write_ezc3d(HERE / "ezc3d_float_mm_analog.c3d", pos, LABELS, 100.0, analog=10)
    write_c3d_lib(HERE / "c3d_float_m.c3d", pos / 1000, LABELS, 100.0, scale=-1.0, units="m")
    write_c3d_lib(HERE / "c3d_int_mm.c3d", pos, LABELS, 100.0, scale=0.1)
    intel = (HERE / "c3d_float_m.c3d").read_bytes()
    for proc, name in ((85, "dec"), (86, "mips")):
        path = HERE / f"c3d_float_m_{name}.c3d"
        path.write_bytes(_to_processor(intel, proc))
        if name == "mips":   # c3d's own reader agrees
            with open(path, "rb") as h:
                got = np.array([p[:, :3] for _, p, _ in c3d.Reader(h).read_frames()])
        else:   # c3d's Reader refuses a DEC zero (ANALOG:RATE); its DEC float decoder agrees
            data = path.read_bytes()[2048:2048 + 10 * 3 * 16]
            got = c3d.c3d.DEC_to_IEEE_BYTES(data).reshape(10, 3, 4)[:, :, :3]
        ok = np.isfinite(pos).all(axis=2)
        assert np.allclose(got[ok], pos[ok] / 1000, atol=1e-7), name
    # 70,000 frames at 1 kHz, one marker: c3d writes POINT:LONG_FRAMES and the TRIAL fields;
    # ezc3d writes POINT:FRAMES = -1 (65,535) and nothing else, so only the file's length tells
    # (ezc3d 1.7.2 itself reads its own file back as 65,535 frames); gzipped, it is 0.3 MB
    long = positions(70000, 1) / 100
    write_c3d_lib(HERE / "c3d_long_70000.c3d", long, ["M0"], 1000.0, scale=-1.0)
    write_ezc3d(HERE / "ezc3d_long_70000.c3d", long, ["M0"], 1000.0)
    raw = (HERE / "ezc3d_long_70000.c3d").read_bytes()
    (HERE / "ezc3d_long_70000.c3d").unlink()
    with open(HERE / "ezc3d_long_70000.c3d.gz", "wb") as f:
        f.write(gzip.compress(raw, mtime=0))   # mtime 0: the same bytes on every run


if __name__ == "__main__":
    main()
