"""A small C3D writer for tests, written from the C3D format description (www.c3d.org): header
block, one parameter section (groups POINT and ANALOG), point data as int16 or float32."""

import struct

import numpy as np

BLOCK = 512


def _record(name, gid, body, endian="<", desc=b""):
    name = name.encode()
    offset = 2 + len(body) + 1 + len(desc)
    return (struct.pack("bb", len(name), gid) + name + struct.pack(endian + "h", offset) + body
            + struct.pack("B", len(desc)) + desc)


def _param(name, gid, kind, values, endian):
    """A parameter record: kind 'char' (list of str), 'int' (int16) or 'float'."""
    if kind == "char":
        if isinstance(values, str):
            data, dims = values.encode(), [len(values)]
        else:
            width = max(1, max(len(v) for v in values))
            data = b"".join(v.ljust(width).encode() for v in values)
            dims = [width, len(values)]
        code = -1
    else:
        arr = np.atleast_1d(np.asarray(values, dtype="i2" if kind == "int" else "f4"))
        data = arr.astype(arr.dtype.newbyteorder(endian)).tobytes()
        dims = [] if arr.size == 1 else [arr.size]
        code = 2 if kind == "int" else 4
    body = struct.pack("bB", code, len(dims)) + bytes(dims) + data
    return _record(name, gid, body, endian)


def write_c3d(path, labels, rate, positions, *, units="mm", storage="float", scale=0.1,
              first_frame=1, analog_per_frame=0, endian="<"):
    """positions: (K, M, 3) in the file's units, NaN where a point was not seen."""
    K, M, _ = positions.shape
    floats = storage == "float"
    point_scale = -abs(scale) if floats else abs(scale)
    recs = [_record("POINT", -1, b"", endian), _record("ANALOG", -2, b"", endian)]
    recs += [_param("USED", 1, "int", M, endian), _param("SCALE", 1, "float", point_scale, endian),
             _param("RATE", 1, "float", rate, endian), _param("FRAMES", 1, "int", K, endian),
             _param("LABELS", 1, "char", list(labels), endian),
             _param("UNITS", 1, "char", units, endian),
             _param("USED", 2, "int", 1 if analog_per_frame else 0, endian)]
    # the last record's offset is 0 (end of the parameter section)
    last = bytearray(recs[-1])
    nlen = abs(struct.unpack("b", last[:1])[0])
    last[2 + nlen:4 + nlen] = b"\0\0"
    recs[-1] = bytes(last)
    processor = 84 if endian == "<" else 86
    section = bytes([1, 0x50, 0, processor]) + b"".join(recs)
    nblocks = -(-len(section) // BLOCK)
    section = bytearray(section.ljust(nblocks * BLOCK, b"\0"))
    section[2] = nblocks
    data_block = 2 + nblocks
    e = endian
    header = bytearray(BLOCK)
    header[0], header[1] = 2, 0x50
    header[2:12] = struct.pack(e + "hhhhh", M, analog_per_frame, first_frame,
                               first_frame + K - 1, 10)
    header[12:16] = struct.pack(e + "f", point_scale)
    header[16:18] = struct.pack(e + "h", data_block)
    header[18:20] = struct.pack(e + "h", analog_per_frame)
    header[20:24] = struct.pack(e + "f", rate)
    seen = np.isfinite(positions).all(axis=2)
    frames = np.zeros((K, M, 4))
    if floats:
        frames[..., :3] = np.where(seen[..., None], positions, 0.0)
        frames[..., 3] = np.where(seen, 0.25, -1.0)
        dtype = np.dtype("f4")
    else:
        frames[..., :3] = np.where(seen[..., None], np.round(positions / scale), 0)
        frames[..., 3] = np.where(seen, 3 * 256 + 2, -1)      # camera mask 3, residual 2
        dtype = np.dtype("i2")
    analog = np.random.default_rng(0).integers(-100, 100, (K, analog_per_frame))
    body = np.concatenate([frames.reshape(K, 4 * M), analog], axis=1).astype(dtype)
    data = body.astype(dtype.newbyteorder(endian)).tobytes()
    with open(path, "wb") as f:
        f.write(bytes(header) + bytes(section) + data.ljust(-(-len(data) // BLOCK) * BLOCK,
                                                            b"\0"))
    return path
