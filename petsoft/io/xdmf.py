"""XDMF (v3) + HDF5 output of fields on a tetrahedral mesh, for ParaView and meshio.

This module owns petsoft's trajectory and result files: a small XML ``.xdmf`` file that describes
the data, and the heavy arrays in an HDF5 file with the same stem beside it (``out/run.xdmf`` +
``out/run.h5``). It is serial: in a parallel run the caller gathers global arrays on rank 0 and
calls it there only.

Crash consistency is the point of the design. Nothing that looks complete is ever half written:

* Every HDF5 file is written under a temporary name and renamed into place, complete or absent
  (:mod:`petsoft.atomic`): the mesh file (mesh and static cell data) first, then one small file per
  frame in the directory ``<stem>_frames/`` beside it. An existing ``.xdmf`` of the same name is
  removed before, and an old series' frame files with it, so an old series never points into new
  data. (Appending every frame to one HDF5 file was tried and is not crash-safe: a process killed
  while HDF5 updates its group metadata leaves a file whose *earlier* frames can no longer be
  opened, "bad heap free list"; measured in tests/test_xdmf.py.)
* The ``.xdmf`` mentions a frame only after its file is in place, so it only ever references
  complete data; a crash leaves a consistent prefix of the series.
* The ``.xdmf`` is created with its first frame through a temporary file and :func:`os.replace`,
  with a reserve of spaces before the series' closing tags. Every later frame is written into
  that reserve in place, in O(1), so that the document is well-formed at every moment (a test
  kills writers at random moments and parses what they leave). A write to a regular file is
  not atomic as a whole: a process killed during one stops it at a page boundary (Linux
  checks for a fatal signal before copying each page), and a frame's ``<Grid>`` written over
  the old closing tags in one ``pwrite`` was found torn (1 in ~12 runs of that test under
  load). A write within one page is whole or absent. So a frame goes in by five writes, each
  leaving a well-formed document: a stray ``-->`` (text) after the place of the frame, a
  ``<!--`` before it (the place is now a comment), the frame's text inside the comment (torn
  or not, a comment), then the ``<!--`` and the ``-->`` blanked; the two markers' writes each
  within one page. A frame whose text holds ``--`` (not allowed in a comment) and a frame that
  does not fit the reserve re-create the document through a temporary file, with a reserve
  as large as the document (so re-creating stays O(1) a frame on average); :meth:`XdmfWriter.
  close` removes the reserve the same way. (Rewriting the whole file every frame cost
  O(frames) a frame: 13.6 ms a frame between frames 2000 and 4000.) A power loss may still tear
  a write, even with ``fsync``.

Layout (``out/run.xdmf``)::

    out/run.h5:/mesh/geometry               (N, 3) float64   node coordinates (reference)
    out/run.h5:/mesh/topology               (E, 4|10) int64  tetrahedra
    out/run.h5:/mesh/cell_data/<name>       (E, ...)         cell data given once, in every frame
    out/run_frames/<k>.h5:/point/<name>     (N, ...)         point data of frame k (k = 0, 1, ...)
    out/run_frames/<k>.h5:/cell/<name>      (E, ...)         cell data of frame k
    out/run_frames/<k>.h5:/                 attrs: time

A writer that collects frames (``flush_seconds > 0``) writes each batch to one file named after
its first frame, a dataset per field and frame: ``out/run_frames/<k>.h5:/point/<name>/<j>`` (and
``/cell/<name>/<j>``) for the frames j = k, k + 1, ... of the batch (``/`` attrs: times, the
batch's frame times). (A group per frame, with its time as attribute, cost 0.34 ms a frame at
600 dofs in HDF5's object creation, a tenth of a time step; these datasets 0.20 ms.) The
``.xdmf`` mentions them once the file is in place, as for single frames: a crash loses the
frames collected since the last batch (at most ``flush_seconds`` of them), never the
consistency of those written.

Each frame is a ``Uniform`` grid of a ``Temporal`` collection, with its own ``<Time>`` and
references to the shared geometry and topology (no ``xi:include``), which both ParaView's XDMF3
readers and :class:`meshio.xdmf.TimeSeriesReader` read. :func:`write_xdmf` writes one static grid
instead, which :func:`meshio.read` reads.
"""

from __future__ import annotations

import mmap
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from time import perf_counter
from xml.sax.saxutils import escape, quoteattr

import numpy as np

from petsoft.atomic import atomic_path, temporaries, write_bytes

__all__ = ["Series", "XdmfWriter", "read_series", "write_xdmf"]

#: The temporaries of frame files (``<k>.h5``) a killed writer may have left.
_FRAME_TEMPORARY = temporaries(r"\d+\.h5")

# XDMF number type and precision of each dtype we store (others are converted, see _as_storable).
_XDMF_TYPES = {
    "float32": ("Float", 4),
    "float64": ("Float", 8),
    "int32": ("Int", 4),
    "int64": ("Int", 8),
}


def _as_storable(name: str, data: object, n: int, what: str) -> np.ndarray:
    """Check one field's array and convert it to a dtype both ParaView and meshio read.

    Float arrays keep float32/float64 (float16 becomes float32); booleans and integers narrower
    than 32 bits become int32, unsigned 32/64-bit integers int64 (XDMF readers disagree on
    ``UChar``/``UInt`` precisions, so stay with the common ones).
    """
    arr = np.asarray(data)
    if arr.ndim == 0 or arr.shape[0] != n:
        raise ValueError(
            f"{what} {name!r} has shape {arr.shape}; its first dimension must be the number of "
            f"{'nodes' if what.startswith('point') else 'cells'}, {n}"
        )
    if arr.dtype.kind == "f":
        return np.ascontiguousarray(arr, np.float32 if arr.itemsize <= 4 else np.float64)
    if arr.dtype.kind == "b" or (arr.dtype.kind in "iu" and arr.itemsize < 4):
        return np.ascontiguousarray(arr, np.int32)
    if arr.dtype.kind == "i":
        return np.ascontiguousarray(arr)
    if arr.dtype.kind == "u":
        if arr.size and arr.max() > np.iinfo(np.int64).max:
            raise ValueError(f"{what} {name!r} has values too large for int64")
        return np.ascontiguousarray(arr, np.int64)
    raise TypeError(f"{what} {name!r} has dtype {arr.dtype}; XDMF output takes real numbers")


def _attribute_type(arr: np.ndarray) -> str:
    """XDMF AttributeType from an array's shape (as meshio and ParaView understand it)."""
    if arr.ndim == 1 or (arr.ndim == 2 and arr.shape[1] == 1):
        return "Scalar"
    if arr.ndim == 2 and arr.shape[1] in (2, 3):
        return "Vector"
    if (arr.ndim == 2 and arr.shape[1] == 9) or (arr.ndim == 3 and arr.shape[1:] == (3, 3)):
        return "Tensor"
    if arr.ndim == 2 and arr.shape[1] == 6:
        return "Tensor6"
    return "Matrix"


def _dataset_names(names: list[str]) -> list[str]:
    """HDF5 link names for field names: readable, without '/' or ':' (XDMF uses 'file:/path')."""
    out: list[str] = []
    for name in names:
        base = re.sub(r"[^A-Za-z0-9_.\-]", "_", name) or "field"
        if base in (".", ".."):
            base = "field"
        key, i = base, 1
        while key in out:
            key, i = f"{base}_{i}", i + 1
        out.append(key)
    return out


def _check_path(path: Path, h5_path: Path) -> None:
    if h5_path == path:
        raise ValueError(f"XDMF path {path} must not end in .h5")
    if ":" in h5_path.name:
        # XDMF references data as "file.h5:/path": a colon in the file name is ambiguous.
        raise ValueError(f"XDMF output name {path.name!r} must not contain ':'")


#: XDMF topology of cells by nodes per cell: tetrahedra (4-node, and 10-node in the VTK node order
#: petsoft uses, which ParaView draws with curved edges), and the vertices, lines and triangles of
#: mass-spring models.
TOPOLOGIES = {10: "Tetrahedron_10", 4: "Tetrahedron", 3: "Triangle", 2: "Polyline",
              1: "Polyvertex"}


def _check_mesh(points: object, tets: object) -> tuple[np.ndarray, np.ndarray]:
    pts = np.asarray(points, dtype=np.float64)
    cells = np.asarray(tets)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must be an (N, 3) array, got shape {pts.shape}")
    if cells.ndim != 2 or cells.shape[1] not in TOPOLOGIES or cells.dtype.kind not in "iu":
        raise ValueError(f"tets must be an (E, 4|10) integer array (or (E, 1|2|3) vertices, lines, "
                         f"triangles of a mass-spring model), got {cells.shape} {cells.dtype}")
    cells = cells.astype(np.int64)
    if cells.size and (cells.min() < 0 or cells.max() >= len(pts)):
        raise ValueError(f"tets refer to nodes outside 0..{len(pts) - 1}")
    return np.ascontiguousarray(pts), np.ascontiguousarray(cells)


def _check_fields(fields: Mapping[str, object] | None, n: int, what: str) -> dict[str, np.ndarray]:
    if fields is None:
        return {}
    if not isinstance(fields, Mapping):
        raise TypeError(f"{what} must be a dict of name -> array, got {type(fields).__name__}")
    return {str(k): _as_storable(str(k), v, n, what) for k, v in fields.items()}


def _data_item(h5name: str, h5path: str, arr_shape: tuple, dtype: np.dtype) -> str:
    kind, prec = _XDMF_TYPES[dtype.name]
    dims = " ".join(str(s) for s in arr_shape)
    return (
        f'<DataItem DataType="{kind}" Precision="{prec}" Dimensions="{dims}" Format="HDF">'
        f"{escape(h5name)}:{escape(h5path)}</DataItem>"
    )


def _attribute(name: str, center: str, h5name: str, h5path: str, arr: np.ndarray) -> str:
    return (
        f'<Attribute Name={quoteattr(name)} AttributeType="{_attribute_type(arr)}" '
        f'Center="{center}">{_data_item(h5name, h5path, arr.shape, arr.dtype)}</Attribute>'
    )


def _mesh_xml(h5name: str, points: np.ndarray, tets: np.ndarray) -> str:
    """Topology and Geometry elements referencing ``/mesh/topology`` and ``/mesh/geometry``."""
    return (
        f'<Topology TopologyType="{TOPOLOGIES[tets.shape[1]]}" NumberOfElements="{len(tets)}" '
        f'NodesPerElement="{tets.shape[1]}">'
        f'{_data_item(h5name, "/mesh/topology", tets.shape, tets.dtype)}'
        "</Topology>\n"
        f'<Geometry GeometryType="XYZ">'
        f"{_data_item(h5name, '/mesh/geometry', points.shape, points.dtype)}</Geometry>\n"
    )


def _grid(name: str, mesh_xml: str, fields: list[str], time: float | None = None) -> str:
    """A Uniform grid: optional time, the mesh, then one Attribute per field."""
    when = "" if time is None else f'<Time Value="{time!r}"/>\n'
    body = "".join(f + "\n" for f in fields)
    return f'<Grid Name="{name}" GridType="Uniform">\n{when}{mesh_xml}{body}</Grid>\n'


def _replace_text(path: Path, text: str | bytes, fsync: bool) -> None:
    """Write ``text`` to ``path`` atomically (:mod:`petsoft.atomic`)."""
    write_bytes(path, text.encode("utf-8") if isinstance(text, str) else text, fsync=fsync)


def _write_h5_atomically(path: Path, fill, fsync: bool) -> None:
    """Create the HDF5 file ``path`` by ``fill(h5file)`` under a temporary name, then rename
    (:mod:`petsoft.atomic`)."""
    import h5py

    with atomic_path(path, fsync=fsync) as tmp, h5py.File(tmp, "w") as f:
        f.attrs["format"] = "petsoft-xdmf-data"
        f.attrs["version"] = 1
        fill(f)


class _DatasetMaker:
    """``put(group, "a/b", arr)``: a contiguous dataset holding ``arr`` (parent groups made).

    h5py's low-level calls, with the type and dataspace of each (dtype, shape) made once: the
    high-level ``group[name] = arr`` cost ~0.5 ms a dataset, as much as a time step of a small
    model, when a batch holds hundreds of frames."""

    def __init__(self):
        import h5py

        self._h5py = h5py
        self._types: dict = {}
        self._lcpl = h5py.h5p.create(h5py.h5p.LINK_CREATE)
        self._lcpl.set_create_intermediate_group(True)
        self._time_type = h5py.h5t.py_create(np.dtype(np.float64))
        self._scalar = h5py.h5s.create(h5py.h5s.SCALAR)

    def __call__(self, group, name: str, arr: np.ndarray) -> None:
        """Dataset ``name`` under ``group`` (an h5py group or file, or a low-level id)."""
        h5 = self._h5py
        arr = np.ascontiguousarray(arr)
        key = (arr.dtype.str, arr.shape)
        if key not in self._types:
            self._types[key] = (h5.h5t.py_create(arr.dtype), h5.h5s.create_simple(arr.shape))
        tid, sid = self._types[key]
        loc = group.id if isinstance(group, h5.Group) else group
        dset = h5.h5d.create(loc, name.encode(), tid, sid, lcpl=self._lcpl)
        dset.write(h5.h5s.ALL, h5.h5s.ALL, arr)

    def time(self, f, time: float) -> None:
        """Attribute ``time`` of file ``f``: a single frame's time (high-level h5py cost 0.1 ms
        an attribute)."""
        h5 = self._h5py
        attr = h5.h5a.create(f.id, b"time", self._time_type, self._scalar)
        attr.write(np.array(time, dtype=np.float64))


def _remove_old_frames(frames_dir: Path) -> None:
    """Delete an earlier series' frame files (``<k>.h5`` and left-over temporaries), then the
    directory if that emptied it; anything else a user put there is left alone."""
    if not frames_dir.is_dir():
        return
    for f in frames_dir.iterdir():
        # ``.<k>.h5.tmp-<pid>``: a temporary of petsoft before petsoft.atomic
        if (re.fullmatch(r"\d+\.h5|\.\d+\.h5\.tmp-\d+", f.name)
                or _FRAME_TEMPORARY.fullmatch(f.name)):
            f.unlink(missing_ok=True)
    try:
        frames_dir.rmdir()
    except OSError:  # not empty: the user's own files stay
        pass


def _xdmf_document(grids: str) -> str:
    return _DOC_HEAD + grids + _DOC_TAIL


#: a collecting writer writes its frames once they hold this much, however recent the last batch
_MAX_PENDING_BYTES = 64 * 2**20

_DOC_HEAD = '<?xml version="1.0" encoding="utf-8"?>\n<Xdmf Version="3.0">\n<Domain>\n'
_DOC_TAIL = "</Domain>\n</Xdmf>\n"
_SERIES_HEAD = '<Grid Name="TimeSeries" GridType="Collection" CollectionType="Temporal">\n'
#: What follows the last frame of a series: where the next frame is written.
_SERIES_TAIL = ("</Grid>\n" + _DOC_TAIL).encode()


#: Spaces reserved before a series' closing tags for later frames, at least (the reserve is made
#: as large as the document when it is re-created).
_RESERVE_MIN = 16384
_OPEN, _CLOSE = b"<!--", b"-->"


def _within_one_page(offset: int, size: int) -> bool:
    return offset // mmap.PAGESIZE == (offset + size - 1) // mmap.PAGESIZE


def _page_after(offset: int) -> int:
    return (offset // mmap.PAGESIZE + 1) * mmap.PAGESIZE


def _pwrite_all(fd: int, data: bytes, offset: int, path: Path) -> None:
    written = os.pwrite(fd, data, offset)
    if written != len(data):
        raise OSError(f"{path}: short write ({written} of {len(data)} bytes); the frame is not "
                      "added")


def _read_prefix(path: Path, size: int) -> bytes:
    with open(path, "rb") as f:
        data = f.read(size)
    if len(data) != size:
        raise OSError(f"{path}: the series document is shorter ({len(data)} bytes) than written "
                      f"({size}); was it changed by another program?")
    return data


class XdmfWriter:
    """A time series of point and cell data on a fixed tetrahedral mesh, crash-consistent.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.xdmf`` file to write; the mesh goes to ``path.with_suffix(".h5")``, each frame to
        ``<stem>_frames/<k>.h5`` beside it. Existing files of these names are replaced. Missing
        parent directories are created.
    points : numpy.ndarray
        ``(N, 3)`` node coordinates (written once).
    tets : numpy.ndarray
        ``(E, 4)`` tetrahedra (written once).
    cell_data : dict of str to numpy.ndarray, optional
        Cell data that do not change (region tags, material ids): written once and shown in
        every frame.
    fsync : bool, optional
        Also ``fsync`` the data before each ``.xdmf`` update, so that the series survives a power
        loss and not only a crash of the process. Off by default: it costs a disk round trip per
        frame.
    flush_seconds : float, optional
        0 (default): every frame is written by its :meth:`write`. Otherwise frames are collected
        and written together, one file per batch, at most this many seconds apart (and by
        :meth:`flush` and :meth:`close`): a file per frame cost ~2 ms a frame, as much as a
        time step of a small model. A crash loses the frames collected since the last batch.

    Examples
    --------
    >>> with XdmfWriter("out/run.xdmf", mesh.points, mesh.tets) as out:  # doctest: +SKIP
    ...     for t, u in steps:
    ...         out.write(t, {"displacement": u})
    """

    def __init__(
        self,
        path: str | Path,
        points: np.ndarray,
        tets: np.ndarray,
        *,
        cell_data: dict[str, np.ndarray] | None = None,
        fsync: bool = False,
        flush_seconds: float = 0.0,
    ) -> None:
        self.path = Path(path)
        self.h5_path = self.path.with_suffix(".h5")
        self.frames_dir = self.path.with_name(f"{self.path.stem}_frames")
        _check_path(self.path, self.h5_path)
        self.points, self.tets = _check_mesh(points, tets)
        self.static_cell_data = _check_fields(cell_data, len(self.tets), "cell_data")
        self.fsync = bool(fsync)
        if not (np.isfinite(flush_seconds) and flush_seconds >= 0.0):
            raise ValueError(f"{self.path}: flush_seconds must be finite and >= 0, got "
                             f"{flush_seconds!r}")
        self.flush_seconds = float(flush_seconds)
        self.times: list[float] = []
        # frames given to write() and not on disk yet: (time, point data, cell data)
        self._pending: list[tuple[float, dict, dict]] = []
        self._pending_bytes = 0
        self._flushed_at = perf_counter()
        # the .xdmf's reserve of spaces for later frames: [_reserve_at, _tail_at), the series'
        # closing tags at _tail_at (module docstring)
        self._reserve_at = self._tail_at = 0
        self._closed = False

        self.path.parent.mkdir(parents=True, exist_ok=True)
        # An old .xdmf would reference frames the new .h5 does not have: remove it first.
        self.path.unlink(missing_ok=True)
        _remove_old_frames(self.frames_dir)
        static = self.static_cell_data
        keys = _dataset_names(list(static))

        def fill(f):
            f["mesh/geometry"] = self.points
            f["mesh/topology"] = self.tets
            for key, arr in zip(keys, static.values(), strict=True):
                f[f"mesh/cell_data/{key}"] = arr

        _write_h5_atomically(self.h5_path, fill, self.fsync)

        # The part of every frame's grid that never changes: mesh and static cell data.
        h5 = self.h5_path.name
        self._mesh_xml = _mesh_xml(h5, self.points, self.tets)
        self._static_xml = {
            name: _attribute(name, "Cell", h5, f"/mesh/cell_data/{key}", arr)
            for key, (name, arr) in zip(keys, static.items(), strict=True)
        }

    # ---------------------------------------------------------------------------------------

    @property
    def num_frames(self) -> int:
        """Number of frames completely written (and referenced by the ``.xdmf``)."""
        return len(self.times)

    @property
    def num_pending(self) -> int:
        """Number of frames collected and not written yet (:meth:`flush` writes them)."""
        return len(self._pending)

    def write(
        self,
        time: float,
        point_data: dict[str, np.ndarray],
        cell_data: dict[str, np.ndarray] | None = None,
    ) -> None:
        """Append one frame and update the ``.xdmf`` to include it.

        Parameters
        ----------
        time : float
            The frame's time; finite and greater than the previous frame's.
        point_data : dict of str to numpy.ndarray
            Arrays with one row per node, e.g. ``{"displacement": u}`` with ``u`` of shape (N, 3).
        cell_data : dict of str to numpy.ndarray, optional
            Arrays with one row per tetrahedron. A name also given as static cell data shadows it
            in this frame.

        Raises
        ------
        ValueError
            On a closed writer, a bad time or arrays of the wrong length. Nothing is written then.

        Notes
        -----
        With ``flush_seconds`` > 0 the frame is collected and written with the others of its
        batch, once ``flush_seconds`` have passed since the last batch (or 64 MB are
        collected), by :meth:`flush` or by :meth:`close`; the first frame is written at once.
        """
        if self._closed:
            raise ValueError(f"{self.path}: write() after close()")
        t = float(time)
        if not np.isfinite(t):
            raise ValueError(f"{self.path}: frame time must be finite, got {time!r}")
        # Check every array before touching the file, so a bad call writes nothing.
        pdata = _check_fields(point_data, len(self.points), "point_data")
        cdata = _check_fields(cell_data, len(self.tets), "cell_data")

        last = self._pending[-1][0] if self._pending else (self.times[-1] if self.times
                                                              else None)
        if last is not None and not t > last:
            raise ValueError(
                f"{self.path}: frame times must increase; got {t!r} after {last!r}"
            )
        # copies: the caller's arrays (a solver's state) change before the batch is written
        entry = (t, {k: v.copy() for k, v in pdata.items()},
                 {k: v.copy() for k, v in cdata.items()})
        size = sum(v.nbytes for v in pdata.values()) + sum(v.nbytes for v in cdata.values())
        self._pending.append(entry)
        self._pending_bytes += size
        # the first frame at once: the series is viewable from the start
        if (not self.times or perf_counter() - self._flushed_at >= self.flush_seconds
                or self._pending_bytes >= _MAX_PENDING_BYTES):
            try:
                self.flush()
            except BaseException:
                # this frame is not written (the call failed); earlier collected ones wait
                # for the next flush
                if self._pending and self._pending[-1] is entry:
                    self._pending.pop()
                    self._pending_bytes -= size
                raise

    def flush(self) -> None:
        """Write the collected frames (one file) and add them to the ``.xdmf``.

        Nothing is referenced before its file is in place; on an error the frames stay
        collected and the series on disk is as it was."""
        if not self._pending:
            return
        k0 = len(self.times)
        batch = self._pending
        single = len(batch) == 1
        frame_file = f"{k0}.h5"

        def dataset(j: int, center: str, key: str) -> str:
            return f"{center}/{key}" if single else f"{center}/{key}/{k0 + j}"

        def fill(f):
            put = _DatasetMaker()
            if single:
                put.time(f, batch[0][0])
            else:
                f.attrs["times"] = np.array([t for t, _, _ in batch])
            for j, (_, pdata, cdata) in enumerate(batch):
                for key, arr in zip(_dataset_names(list(pdata)), pdata.values(), strict=True):
                    put(f, dataset(j, "point", key), arr)
                for key, arr in zip(_dataset_names(list(cdata)), cdata.values(), strict=True):
                    put(f, dataset(j, "cell", key), arr)

        self.frames_dir.mkdir(exist_ok=True)
        # The batch's file is complete (renamed into place) before the .xdmf mentions it.
        _write_h5_atomically(self.frames_dir / frame_file, fill, self.fsync)

        frame_h5 = f"{self.frames_dir.name}/{frame_file}"
        grids = []
        for j, (t, pdata, cdata) in enumerate(batch):
            pkeys, ckeys = _dataset_names(list(pdata)), _dataset_names(list(cdata))
            # A per-frame cell field replaces a static one of the same name.
            static = [xml for name, xml in self._static_xml.items() if name not in cdata]
            fields = (
                static
                + [
                    _attribute(name, "Node", frame_h5, "/" + dataset(j, "point", key), arr)
                    for key, (name, arr) in zip(pkeys, pdata.items(), strict=True)
                ]
                + [
                    _attribute(name, "Cell", frame_h5, "/" + dataset(j, "cell", key), arr)
                    for key, (name, arr) in zip(ckeys, cdata.items(), strict=True)
                ]
            )
            grids.append(_grid(f"frame_{k0 + j}", self._mesh_xml, fields, time=t))
        text = "".join(grids).encode("utf-8")
        if not (k0 and self._write_into_reserve(text)):
            body = (_read_prefix(self.path, self._reserve_at) if k0
                    else (_DOC_HEAD + _SERIES_HEAD).encode("utf-8")) + text
            self._recreate(body, reserve=max(_RESERVE_MIN, len(body)))
        self.times.extend(t for t, _, _ in batch)
        self._pending, self._pending_bytes = [], 0
        self._flushed_at = perf_counter()

    def _write_into_reserve(self, text: bytes) -> bool:
        """Put ``text`` into the reserve of spaces of the ``.xdmf`` by the commented writes of
        the module docstring; False (nothing written) when ``text`` holds ``--`` or does not
        fit. The reserve starts after this frame's place from the first write on, also when a
        later write fails (the place is a comment or stray text then, never written again)."""
        if b"--" in text:
            return False
        at = self._reserve_at
        opener = at if _within_one_page(at, len(_OPEN)) else _page_after(at)
        closer = opener + len(_OPEN) + len(text)
        if not _within_one_page(closer, len(_CLOSE)):
            closer = _page_after(closer)
        if closer + len(_CLOSE) > self._tail_at:
            return False
        path = self.path
        fd = os.open(path, os.O_WRONLY)
        try:
            self._reserve_at = closer + len(_CLOSE)
            _pwrite_all(fd, _CLOSE, closer, path)
            _pwrite_all(fd, _OPEN, opener, path)
            _pwrite_all(fd, text, opener + len(_OPEN), path)
            if self.fsync:
                os.fsync(fd)    # the frame's text before the writes that make it part of the series
            _pwrite_all(fd, b" " * len(_OPEN), opener, path)
            _pwrite_all(fd, b" " * len(_CLOSE), closer, path)
            if self.fsync:
                os.fsync(fd)
        finally:
            os.close(fd)
        return True

    def _recreate(self, body: bytes, reserve: int) -> None:
        """Write the ``.xdmf`` anew (temporary file, rename): ``body`` (the document up to the
        end of its last frame), ``reserve`` spaces, the closing tags."""
        _replace_text(self.path, body + b" " * reserve + _SERIES_TAIL, self.fsync)
        self._reserve_at, self._tail_at = len(body), len(body) + reserve

    def close(self) -> None:
        """Finish the series (the ``.xdmf`` loses its reserve for later frames). Idempotent.

        Every written frame is already on disk; a writer closed before any frame writes a
        ``.xdmf`` of the bare mesh (with its static cell data) so the output is still viewable.
        """
        if self._closed:
            return
        self.flush()
        self._closed = True
        if not self.times:
            grid = _grid("mesh", self._mesh_xml, list(self._static_xml.values()))
            _replace_text(self.path, _xdmf_document(grid), self.fsync)
        elif self._tail_at > self._reserve_at:
            self._recreate(_read_prefix(self.path, self._reserve_at), reserve=0)

    def __enter__(self) -> XdmfWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"XdmfWriter({str(self.path)!r}, {self.num_frames} frames, {state})"


def write_xdmf(
    path: str | Path,
    points: np.ndarray,
    tets: np.ndarray,
    point_data: dict[str, np.ndarray] | None = None,
    cell_data: dict[str, np.ndarray] | None = None,
    *,
    fsync: bool = False,
) -> None:
    """Write one static result (no time) as ``path`` (.xdmf) + ``path.with_suffix(".h5")``.

    Both files are written under temporary names and renamed into place (the ``.h5`` first, after
    removing any old ``.xdmf``), so a crash never leaves a ``.xdmf`` pointing at missing data.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.xdmf`` file.
    points, tets : numpy.ndarray
        ``(N, 3)`` coordinates and ``(E, 4)`` tetrahedra.
    point_data, cell_data : dict of str to numpy.ndarray, optional
        Fields with one row per node / per tetrahedron.
    fsync : bool, optional
        ``fsync`` both files before renaming them.
    """
    path = Path(path)
    h5_path = path.with_suffix(".h5")
    _check_path(path, h5_path)
    pts, cells = _check_mesh(points, tets)
    pdata = _check_fields(point_data, len(pts), "point_data")
    cdata = _check_fields(cell_data, len(cells), "cell_data")
    pkeys, ckeys = _dataset_names(list(pdata)), _dataset_names(list(cdata))

    def fill(f):
        f["mesh/geometry"] = pts
        f["mesh/topology"] = cells
        for key, arr in zip(pkeys, pdata.values(), strict=True):
            f[f"point_data/{key}"] = arr
        for key, arr in zip(ckeys, cdata.values(), strict=True):
            f[f"cell_data/{key}"] = arr

    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)
    _write_h5_atomically(h5_path, fill, fsync)
    h5 = h5_path.name
    fields = [
        _attribute(name, "Node", h5, f"/point_data/{key}", arr)
        for key, (name, arr) in zip(pkeys, pdata.items(), strict=True)
    ] + [
        _attribute(name, "Cell", h5, f"/cell_data/{key}", arr)
        for key, (name, arr) in zip(ckeys, cdata.items(), strict=True)
    ]
    grid = _grid("mesh", _mesh_xml(h5, pts, cells), fields)
    _replace_text(path, _xdmf_document(grid), fsync)


@dataclass
class Series:
    """A time series as written by :class:`XdmfWriter` (see :func:`read_series`)."""

    points: np.ndarray
    cells: np.ndarray
    times: np.ndarray
    point_data: list[dict[str, np.ndarray]]
    cell_data: list[dict[str, np.ndarray]]


def read_series(path: str | Path) -> Series:
    """Read the frames a ``.xdmf`` written by :class:`XdmfWriter` references (only those: the
    frames a crashed run completed), with the mesh.

    Parameters
    ----------
    path : str or pathlib.Path
        The ``.xdmf`` file.

    Returns
    -------
    Series
        Points (N, 3), cells (E, 4|10), frame times (K,), and per frame the point and cell data
        by field name.
    """
    import h5py

    path = Path(path)
    root = ET.parse(path).getroot()
    grids = [g for g in root.iter("Grid") if g.get("GridType") == "Uniform"]
    if not grids:
        raise ValueError(f"{path}: no grid in this XDMF file")
    files: dict[str, h5py.File] = {}

    def data(item) -> np.ndarray:
        name, h5path = item.text.strip().rsplit(":", 1)
        if name not in files:
            files[name] = h5py.File(path.parent / name, "r")
        return files[name][h5path][()]

    try:
        first = grids[0]
        points = data(first.find("Geometry/DataItem"))
        cells = data(first.find("Topology/DataItem"))
        times, pdata, cdata = [], [], []
        for grid in grids:
            when = grid.find("Time")
            times.append(float(when.get("Value")) if when is not None else np.nan)
            fields = {"Node": {}, "Cell": {}}
            for att in grid.findall("Attribute"):
                fields[att.get("Center")][att.get("Name")] = data(att.find("DataItem"))
            pdata.append(fields["Node"])
            cdata.append(fields["Cell"])
    finally:
        for f in files.values():
            f.close()
    return Series(points, cells, np.array(times), pdata, cdata)
