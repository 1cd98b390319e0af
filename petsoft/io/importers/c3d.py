"""A minimal reader of the POINT data of C3D motion-capture files.

C3D (www.c3d.org) stores 512-byte blocks: a header block, a parameter section, then the data.
This reader understands what a marker recording needs:

* the header: first parameter block, number of points, analog samples per frame, first and last
  frame, scale factor (negative: floating-point storage), first data block, frame rate;
* the parameter section: groups and parameters of type char / byte / int16 / float, with their
  dimensions; it uses POINT:LABELS (and LABELS2...), POINT:RATE, POINT:SCALE, POINT:UNITS,
  POINT:USED, POINT:DATA_START and POINT:FRAMES when present (they override the header);
* the data: per frame, per point X, Y, Z and a residual word, as int16 (times the scale) or
  float32, followed by the analog samples (skipped). A negative residual marks a point that was
  not seen in that frame (NaN in the recording).

Byte order: processor type 84 (Intel, little-endian) and 86 (MIPS/SGI, big-endian). DEC (85)
files store VAX floats and are refused with a message.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from petsoft.io.importers import UNITS, ImportFileError, reference_positions, unit_scale
from petsoft.io.recording import Recording

BLOCK = 512
_KEY = 0x50
_TYPES = {-1: ("S", 1), 1: ("i1", 1), 2: ("i2", 2), 4: ("f4", 4)}


def _parameters(raw: bytes, start: int, endian: str, source: str) -> dict:
    """All parameters as {"GROUP:NAME": value} (value: str, list of str, or numpy array)."""
    groups: dict[int, str] = {}
    params: list[tuple[int, str, object]] = []
    nblocks = raw[start + 2]
    end = min(len(raw), start + max(nblocks, 1) * BLOCK)
    p = start + 4
    while p + 2 <= end:
        nchar = struct.unpack("b", raw[p:p + 1])[0]
        gid = struct.unpack("b", raw[p + 1:p + 2])[0]
        if nchar == 0:
            break
        name = raw[p + 2:p + 2 + abs(nchar)].decode("ascii", "replace").strip().upper()
        q = p + 2 + abs(nchar)
        (offset,) = struct.unpack(endian + "h", raw[q:q + 2])
        body = q + 2
        if gid < 0:
            groups[-gid] = name
        else:
            dtype = struct.unpack("b", raw[body:body + 1])[0]
            if dtype not in _TYPES:
                raise ImportFileError(f"{source}: parameter {name!r} has data type {dtype}; "
                                      "C3D types are -1 (char), 1, 2 and 4")
            ndim = raw[body + 1]
            dims = list(raw[body + 2:body + 2 + ndim])
            data_at = body + 2 + ndim
            code, size = _TYPES[dtype]
            count = int(np.prod(dims)) if ndim else 1
            blob = raw[data_at:data_at + count * size]
            if dtype == -1:
                text = blob.decode("latin-1")
                if ndim <= 1:
                    value: object = text.strip()
                else:
                    width = dims[0]
                    value = [text[i:i + width].strip() for i in range(0, len(text), width)]
            else:
                value = np.frombuffer(blob, dtype=np.dtype(code).newbyteorder(endian)).astype(
                    float if code == "f4" else np.int64)
            params.append((gid, name, value))
        if offset == 0:
            break
        p = q + offset
    return {f"{groups.get(g, str(g))}:{n}": v for g, n, v in params}


def _scalar(params: dict, key: str, default):
    v = params.get(key)
    if v is None or isinstance(v, str | list) or len(v) == 0:
        return default
    return v[0]


def read_c3d(path: Path, *, units: str | None = None, scale: float | None = None,
             rest_frame: int | None = None) -> Recording:
    """Read the 3D points of a C3D file as a Recording in metres.

    Parameters
    ----------
    units, scale : optional
        Override POINT:UNITS (``"mm"`` ...) or give the factor to metres directly.
    rest_frame : int, optional
        Frame giving the reference positions (default: the first frame in which every point is
        seen).

    Raises
    ------
    ImportFileError
        Naming the file: not a C3D file, DEC byte order, truncated data, unknown units, no
        frame in which every point is seen.
    """
    path = Path(path)
    source = str(path)
    raw = path.read_bytes()
    if len(raw) < 2 * BLOCK or raw[1] != _KEY:
        raise ImportFileError(f"{source}: not a C3D file (byte 2 of the header must be 0x50)")
    pblock = raw[0]
    pstart = (pblock - 1) * BLOCK
    if pblock < 2 or pstart + 4 > len(raw):
        raise ImportFileError(f"{source}: the parameter section (block {pblock}) is missing")
    processor = raw[pstart + 3]
    if processor == 84:
        endian = "<"
    elif processor == 86:
        endian = ">"
    elif processor == 85:
        raise ImportFileError(f"{source}: DEC (VAX) byte order is not supported; convert the "
                              "file to Intel format (processor type 84)")
    else:
        raise ImportFileError(f"{source}: unknown processor type {processor} in the parameter "
                              "header (84 Intel, 85 DEC, 86 MIPS)")
    words = struct.unpack(endian + "BBhhhhh", raw[:12])
    npoints_h, nanalog_h, first_h, last_h = words[2], words[3], words[4], words[5]
    (scale_h,) = struct.unpack(endian + "f", raw[12:16])
    (data_block_h,) = struct.unpack(endian + "h", raw[16:18])
    (rate_h,) = struct.unpack(endian + "f", raw[20:24])
    params = _parameters(raw, pstart, endian, source)
    npoints = int(_scalar(params, "POINT:USED", npoints_h))
    point_scale = float(_scalar(params, "POINT:SCALE", scale_h))
    rate = float(_scalar(params, "POINT:RATE", rate_h))
    data_block = int(_scalar(params, "POINT:DATA_START", data_block_h))
    nframes = int(_scalar(params, "POINT:FRAMES", last_h - first_h + 1)) & 0xFFFF
    if not (np.isfinite(rate) and rate > 0):
        raise ImportFileError(f"{source}: frame rate {rate} is not positive")
    labels: list[str] = []
    for key in ["POINT:LABELS"] + [f"POINT:LABELS{i}" for i in range(2, 10)]:
        v = params.get(key)
        if isinstance(v, list):
            labels += v
        elif isinstance(v, str) and v:
            labels.append(v)
    labels = labels[:npoints]
    labels += [f"p{i}" for i in range(len(labels), npoints)]
    labels = [lab or f"p{i}" for i, lab in enumerate(labels)]
    if len(set(labels)) != len(labels):
        seen: set[str] = set()
        labels = [lab if not (lab in seen or seen.add(lab)) else f"{lab}#{i}"
                  for i, lab in enumerate(labels)]
    file_units = params.get("POINT:UNITS", "")
    factor = unit_scale(units, scale, source)
    if factor is None:
        unit = (file_units or "mm").strip().lower()   # the C3D default unit is millimetres
        if unit not in UNITS:
            raise ImportFileError(f"{source}: POINT:UNITS = {file_units!r} is not a known "
                                  f"length unit ({', '.join(UNITS)}); give --units or --scale")
        factor = UNITS[unit]
    analog_per_frame = int(nanalog_h)
    floats = point_scale < 0
    dtype = np.dtype("f4" if floats else "i2").newbyteorder(endian)
    per_frame = 4 * npoints + analog_per_frame
    start = (data_block - 1) * BLOCK
    need = start + nframes * per_frame * dtype.itemsize
    if npoints == 0:
        raise ImportFileError(f"{source}: the file has no 3D points (POINT:USED = 0)")
    if need > len(raw):
        raise ImportFileError(f"{source}: truncated: {nframes} frames of {npoints} points need "
                              f"{need} bytes, the file has {len(raw)}")
    data = np.frombuffer(raw, dtype=dtype, count=nframes * per_frame, offset=start)
    data = data.reshape(nframes, per_frame)[:, :4 * npoints].reshape(nframes, npoints, 4)
    if floats:
        xyz = data[:, :, :3].astype(float)
        residual = data[:, :, 3].astype(float)
    else:
        xyz = data[:, :, :3].astype(float) * point_scale
        # the 4th word: camera mask (high byte) and residual (low byte); negative: not seen
        residual = data[:, :, 3].astype(float)
    pos = xyz * factor
    pos[residual < 0] = np.nan
    if not np.isfinite(pos[residual >= 0]).all():
        raise ImportFileError(f"{source}: non-finite coordinates in points marked as seen")
    first = int(first_h)
    times = (first - 1 + np.arange(nframes)) / rate
    reference, frame = reference_positions(pos, labels, source, rest_frame)
    attrs = {"source": f"imported from {path.name} (C3D)", "reference_frame": frame,
             "unit_scale": factor, "frame_rate": rate}
    return Recording(reference, labels, times, pos, attrs=attrs, source=source)
