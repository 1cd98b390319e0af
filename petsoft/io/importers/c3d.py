"""A reader of the POINT data of C3D files, as capture systems and C3D libraries write them.

C3D (www.c3d.org) stores 512-byte blocks: a header block, a parameter section, then the data.
This reader understands what a marker recording needs:

* the header: first parameter block, number of points, analog samples per frame, first and last
  frame, scale factor (negative: floating-point storage), first data block, frame rate;
* the parameter section: groups and parameters of type char / byte / int16 / float, with their
  dimensions (zero-width text parameters, as ezc3d writes them, are empty strings); it uses
  POINT:LABELS (and LABELS2...), POINT:RATE, POINT:SCALE, POINT:UNITS, POINT:USED,
  POINT:DATA_START and POINT:FRAMES when present (they override the header);
* more than 65,535 frames: POINT:FRAMES is an unsigned 16-bit count there, so the true count comes
  from POINT:LONG_FRAMES (a float) or TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD (two 16-bit
  words each, low word first), and otherwise from the file's length when the header's count is
  saturated;
* the data: per frame, per point X, Y, Z and a residual word, as int16 (times POINT:SCALE) or
  float32, followed by the analog samples (skipped, with a note in ``attrs["note"]``). A point not
  seen in a frame is NaN in the recording: capture systems mark it with a negative residual,
  ezc3d with NaN coordinates (and residual 0).

Processor types (byte 4 of the parameter header): 84 Intel (little-endian), 85 DEC (little-endian
integers; VAX F floats: the two 16-bit words swapped give IEEE bits 4 times the value) and
86 MIPS/SGI (big-endian). A truncated or corrupt file raises ImportFileError naming the file, the
byte offset or parameter, and what is missing.
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
_PROCESSORS = {84: "intel", 85: "dec", 86: "mips"}
_UNIT_ALIASES = {"millimeters": "mm", "millimetres": "mm", "meters": "m", "metres": "m",
                 "centimeters": "cm", "centimetres": "cm"}


def _floats(blob: bytes | np.ndarray, processor: str) -> np.ndarray:
    """float32 words as float64: IEEE (Intel little-endian, MIPS big-endian) or DEC VAX F."""
    if processor != "dec":
        with np.errstate(invalid="ignore"):   # signalling NaN bit patterns (damaged files)
            return np.frombuffer(blob, dtype=">f4" if processor == "mips" else "<f4").astype(
                float)
    # VAX F: two little-endian 16-bit words, the high one (sign, exponent) first, exponent bias
    # 2 larger than IEEE's; an exponent of 0 is zero
    u = np.frombuffer(blob, dtype="<u4")
    ieee = ((u >> np.uint32(16)) | (u << np.uint32(16))).astype(np.uint32)
    with np.errstate(invalid="ignore"):
        values = ieee.view("<f4").astype(float) / 4.0
    values[(ieee & np.uint32(0x7F800000)) == 0] = 0.0
    return values


def _ints(blob: bytes, code: str, processor: str) -> np.ndarray:
    return np.frombuffer(blob, dtype=np.dtype(code).newbyteorder(
        ">" if processor == "mips" else "<")).astype(np.int64)


def _parameters(raw: bytes, start: int, processor: str, source: str) -> dict:
    """All parameters as {"GROUP:NAME": value} (value: str, list of str, or numpy array)."""
    endian = ">" if processor == "mips" else "<"
    groups: dict[int, str] = {}
    params: list[tuple[int, str, object]] = []
    nblocks = raw[start + 2]
    end = start + max(nblocks, 1) * BLOCK
    if end > len(raw):
        raise ImportFileError(f"{source}: truncated: the parameter section (bytes {start} to "
                              f"{end}, {nblocks} blocks) stops at byte {len(raw)}")
    p = start + 4
    while p + 2 <= end:
        nchar, gid = struct.unpack("bb", raw[p:p + 2])
        if nchar == 0:
            break
        q = p + 2 + abs(nchar)
        if q + 2 > end:
            raise ImportFileError(f"{source}: corrupt parameter section: the record at byte {p} "
                                  f"runs past the end of the section (byte {end})")
        name = raw[p + 2:q].decode("ascii", "replace").strip().upper()
        (offset,) = struct.unpack(endian + "h", raw[q:q + 2])
        body = q + 2
        if gid < 0:
            groups[-gid] = name
        elif gid > 0:
            if body + 2 > end:
                raise ImportFileError(f"{source}: corrupt parameter section: parameter {name!r} "
                                      f"at byte {p} runs past the end of the section")
            dtype = struct.unpack("b", raw[body:body + 1])[0]
            if dtype not in _TYPES:
                raise ImportFileError(f"{source}: parameter {name!r} at byte {p} has data type "
                                      f"{dtype}; C3D types are -1 (char), 1, 2 and 4")
            ndim = raw[body + 1]
            dims = list(raw[body + 2:body + 2 + ndim])
            data_at = body + 2 + ndim
            code, size = _TYPES[dtype]
            count = int(np.prod(dims)) if ndim else 1
            blob = raw[data_at:data_at + count * size]
            if len(blob) < count * size or data_at + count * size > end:
                raise ImportFileError(f"{source}: corrupt parameter section: parameter {name!r} "
                                      f"at byte {p} declares {count * size} bytes of data "
                                      "that the section does not hold")
            if dtype == -1:
                text = blob.decode("latin-1")
                width = dims[0] if ndim else 0
                if ndim <= 1:
                    value: object = text.strip()
                elif width == 0:      # ezc3d writes empty text parameters with width 0
                    value = [""] * int(np.prod(dims[1:]))
                else:
                    value = [text[i:i + width].strip() for i in range(0, len(text), width)]
            elif code == "f4":
                value = _floats(blob, processor)
            else:
                value = _ints(blob, code, processor)
            params.append((gid, name, value))
        if offset == 0:
            break
        if offset < 0:   # a backward link would loop for ever
            raise ImportFileError(f"{source}: corrupt parameter section: the record at byte {p} "
                                  f"points {offset} bytes backwards")
        p = q + offset
    return {f"{groups.get(g, str(g))}:{n}": v for g, n, v in params}


def _scalar(params: dict, key: str, default):
    v = params.get(key)
    if v is None or isinstance(v, str | list) or len(v) == 0:
        return default
    return v[0]


def _frame_count(params: dict, header_count: int, available: int) -> int:
    """The number of frames, beyond the 16-bit POINT:FRAMES when the file says so."""
    count = int(_scalar(params, "POINT:FRAMES", header_count)) & 0xFFFF
    long_frames = _scalar(params, "POINT:LONG_FRAMES", None)
    if long_frames is not None and np.isfinite(long_frames) and long_frames > count:
        return int(round(long_frames))
    start = params.get("TRIAL:ACTUAL_START_FIELD")
    stop = params.get("TRIAL:ACTUAL_END_FIELD")
    if (isinstance(start, np.ndarray) and isinstance(stop, np.ndarray) and len(start) >= 2
            and len(stop) >= 2):
        # two 16-bit words each, low word first, stored as (signed) int16
        first = (int(start[0]) & 0xFFFF) + ((int(start[1]) & 0xFFFF) << 16)
        last = (int(stop[0]) & 0xFFFF) + ((int(stop[1]) & 0xFFFF) << 16)
        if last - first + 1 > count:
            return last - first + 1
    if count == 0xFFFF and available > count:
        # a saturated 16-bit count with more data behind it (ezc3d writes no LONG_FRAMES): the
        # data are the authority
        return available
    return count


def _trim_padding(raw: bytes, start: int, nframes: int, frame_bytes: int) -> int:
    """Drop the zero bytes that pad the last 512-byte block when the frame count came from the
    file's length: trailing all-zero frames within the last block's padding (< 512 bytes)."""
    end = start + nframes * frame_bytes
    while (nframes > 0 and len(raw) - (end - frame_bytes) < BLOCK
           and not any(raw[end - frame_bytes:end])):
        nframes -= 1
        end -= frame_bytes
    return nframes


def _labels(params: dict, npoints: int) -> list[str]:
    """POINT:LABELS, LABELS2... for the used points; missing or repeated names made unique."""
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
    return labels


def _factor(params: dict, units: str | None, scale: float | None, source: str) -> float:
    """The factor to metres: from --units / --scale, else POINT:UNITS (default mm)."""
    factor = unit_scale(units, scale, source)
    if factor is not None:
        return factor
    file_units = params.get("POINT:UNITS", "")
    if isinstance(file_units, list):
        file_units = file_units[0] if file_units else ""
    unit = (file_units or "mm").strip().lower()   # the C3D default unit is millimetres
    unit = _UNIT_ALIASES.get(unit, unit)
    if unit not in UNITS:
        raise ImportFileError(f"{source}: POINT:UNITS = {file_units!r} is not a known "
                              f"length unit ({', '.join(UNITS)}); give --units or --scale")
    return UNITS[unit]


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

    Returns
    -------
    Recording
        ``attrs["note"]`` says what was skipped (analog channels), if anything.

    Raises
    ------
    ImportFileError
        Naming the file and where: not a C3D file, corrupt parameter section, truncated data,
        unknown units, no frame in which every point is seen.
    """
    path = Path(path)
    source = str(path)
    raw = path.read_bytes()
    if len(raw) < 2 or raw[1] != _KEY:
        raise ImportFileError(f"{source}: not a C3D file (byte 2 of the header must be 0x50)")
    if len(raw) < BLOCK:
        raise ImportFileError(f"{source}: truncated: the 512-byte header block has only "
                              f"{len(raw)} bytes")
    pblock = raw[0]
    pstart = (pblock - 1) * BLOCK
    if pblock < 2 or pstart + 4 > len(raw):
        raise ImportFileError(f"{source}: truncated: the parameter section (block {pblock}, "
                              f"byte {max(pstart, 0)}) is missing; the file has {len(raw)} bytes")
    processor = _PROCESSORS.get(raw[pstart + 3])
    if processor is None:
        raise ImportFileError(f"{source}: unknown processor type {raw[pstart + 3]} at byte "
                              f"{pstart + 3} (84 Intel, 85 DEC, 86 MIPS)")
    endian = ">" if processor == "mips" else "<"
    words = struct.unpack(endian + "BBhhhhh", raw[:12])
    npoints_h, nanalog_h, first_h, last_h = words[2], words[3], words[4] & 0xFFFF, words[5] & 0xFFFF
    scale_h = float(_floats(raw[12:16], processor)[0])
    (data_block_h,) = struct.unpack(endian + "H", raw[16:18])
    rate_h = float(_floats(raw[20:24], processor)[0])
    params = _parameters(raw, pstart, processor, source)
    npoints = int(_scalar(params, "POINT:USED", npoints_h))
    point_scale = float(_scalar(params, "POINT:SCALE", scale_h))
    rate = float(_scalar(params, "POINT:RATE", rate_h))
    data_block = int(_scalar(params, "POINT:DATA_START", data_block_h)) & 0xFFFF
    if not (np.isfinite(rate) and rate > 0):
        raise ImportFileError(f"{source}: frame rate {rate} is not positive")
    if npoints <= 0:
        raise ImportFileError(f"{source}: the file has no 3D points (POINT:USED = {npoints})")
    labels = _labels(params, npoints)
    factor = _factor(params, units, scale, source)
    analog_per_frame = int(nanalog_h)
    if analog_per_frame < 0:
        raise ImportFileError(f"{source}: corrupt header: {analog_per_frame} analog samples per "
                              "frame (header word 3, byte 4)")
    floats = point_scale < 0
    itemsize = 4 if floats else 2
    per_frame = 4 * npoints + analog_per_frame
    start = (data_block - 1) * BLOCK
    if data_block < 1:
        raise ImportFileError(f"{source}: corrupt: the data start block is {data_block}")
    available = max(len(raw) - start, 0) // (per_frame * itemsize)
    nframes = _frame_count(params, last_h - first_h + 1, available)
    if nframes == available and nframes > 0xFFFF:
        nframes = _trim_padding(raw, start, nframes, per_frame * itemsize)
    need = start + nframes * per_frame * itemsize
    if need > len(raw):
        raise ImportFileError(
            f"{source}: truncated: {nframes} frames of {npoints} points need {need} bytes, the "
            f"file has {len(raw)}; the data stop in frame {available} "
            f"(byte {start + available * per_frame * itemsize})")
    blob = raw[start:need]
    if floats:
        data = _floats(blob, processor)
    else:
        data = _ints(blob, "i2", processor).astype(float)
    data = data.reshape(nframes, per_frame)[:, :4 * npoints].reshape(nframes, npoints, 4)
    if floats:
        xyz = data[:, :, :3]
        residual = data[:, :, 3]
    else:
        xyz = data[:, :, :3] * point_scale
        # the 4th word: camera mask (high byte) and residual (low byte); negative: not seen
        residual = data[:, :, 3]
    pos = xyz * factor
    # not seen: a negative residual (capture systems) or NaN coordinates (ezc3d writes those
    # with residual 0); a NaN residual is treated as not seen too
    unseen = ~(residual >= 0) | ~np.isfinite(pos).all(axis=2)
    pos[unseen] = np.nan
    first = int(first_h)
    times = (first - 1 + np.arange(nframes)) / rate
    reference, frame = reference_positions(pos, labels, source, rest_frame)
    attrs = {"source": f"imported from {path.name} (C3D)", "reference_frame": frame,
             "unit_scale": factor, "frame_rate": rate}
    if analog_per_frame:
        channels = int(_scalar(params, "ANALOG:USED", 0))
        attrs["note"] = (f"{path.name}: analog data skipped ({channels} channels, "
                         f"{analog_per_frame} samples per frame): petsoft imports the 3D points "
                         "only")
    return Recording(reference, labels, times, pos, attrs=attrs, source=source)
