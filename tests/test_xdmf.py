"""Tests of petsoft.io.xdmf: what meshio reads back, and that a crash never leaves a .xdmf that
references incomplete data.

No MPI here: under ``mpiexec -n 2`` each rank runs these independently in its own tmp_path.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import meshio
import numpy as np
import pytest

from petsoft.io import xdmf as xdmf_mod
from petsoft.io.xdmf import XdmfWriter, write_xdmf
from petsoft.mesh.serial import box_mesh

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def mesh():
    return box_mesh([0.4, 0.04, 0.04], [4, 2, 1])


def _frame_fields(mesh, k):
    rng = np.random.default_rng(k)
    return (
        {
            "displacement": rng.standard_normal((mesh.num_points, 3)),
            "speed": rng.random(mesh.num_points),
        },
        {"energy": rng.random(mesh.num_cells)},
    )


def _read_series(path):
    """(points, cells, [(t, point_data, cell_data), ...]) as meshio's TimeSeriesReader sees it."""
    with meshio.xdmf.TimeSeriesReader(path) as reader:
        points, cells = reader.read_points_cells()
        frames = [reader.read_data(k) for k in range(reader.num_steps)]
    return points, cells, frames


def _leftovers(directory):
    """Temporaries left behind (petsoft.atomic names them ``.<name>.<hex>.tmp``)."""
    return sorted(p.name for p in Path(directory).rglob("*") if p.name.endswith(".tmp"))


def test_series_round_trip(tmp_path, mesh):
    path = tmp_path / "out" / "run.xdmf"  # parent directory is created
    tags = np.arange(mesh.num_cells) % 3
    times = [0.0, 0.1 + 0.2, 1.0 / 3.0]  # times that only survive as exact repr
    written = []
    with XdmfWriter(path, mesh.points, mesh.tets, cell_data={"region": tags}) as out:
        assert not path.exists()  # nothing that looks like a result before the first frame
        for k, t in enumerate(times):
            pdata, cdata = _frame_fields(mesh, k)
            out.write(t, pdata, cdata)
            written.append((pdata, cdata))
            # After every frame the file on disk is complete and holds exactly the frames so far.
            _, _, frames = _read_series(path)
            assert len(frames) == k + 1
        assert out.num_frames == 3
    assert path.with_suffix(".h5").exists()
    ET.parse(path)  # well-formed XML

    points, cells, frames = _read_series(path)
    np.testing.assert_array_equal(points, mesh.points)
    assert len(cells) == 1 and cells[0].type == "tetra"
    np.testing.assert_array_equal(cells[0].data, mesh.tets)
    assert [f[0] for f in frames] == times
    for (_, pdata, cdata), (pref, cref) in zip(frames, written, strict=True):
        assert set(pdata) == {"displacement", "speed"}
        for name, arr in pref.items():
            np.testing.assert_array_equal(pdata[name], arr)
            assert pdata[name].dtype == np.float64
        np.testing.assert_array_equal(cdata["energy"][0], cref["energy"])
        np.testing.assert_array_equal(cdata["region"][0], tags)  # static data in every frame
    assert _leftovers(path.parent) == []


def test_h5_layout(tmp_path, mesh):
    path = tmp_path / "run.xdmf"
    with XdmfWriter(path, mesh.points, mesh.tets) as out:
        out.write(0.5, {"u": mesh.points})
    with h5py.File(tmp_path / "run.h5", "r") as f:
        np.testing.assert_array_equal(f["mesh/geometry"][()], mesh.points)
        np.testing.assert_array_equal(f["mesh/topology"][()], mesh.tets)
    with h5py.File(tmp_path / "run_frames" / "0.h5", "r") as f:
        assert f.attrs["time"] == 0.5
        np.testing.assert_array_equal(f["point/u"][()], mesh.points)


def test_a_new_series_removes_the_old_frames_but_not_the_users_files(tmp_path, mesh):
    path = tmp_path / "run.xdmf"
    with XdmfWriter(path, mesh.points, mesh.tets) as out:
        for k in range(3):
            out.write(float(k), {"u": mesh.points * k})
    (tmp_path / "run_frames" / "notes.txt").write_text("mine")
    with XdmfWriter(path, mesh.points, mesh.tets) as out:
        out.write(5.0, {"u": mesh.points})
    names = sorted(p.name for p in (tmp_path / "run_frames").iterdir())
    assert names == ["0.h5", "notes.txt"]
    assert [f[0] for f in _read_series(path)[2]] == [5.0]


def test_read_series_agrees_with_meshio(tmp_path, mesh):
    path = tmp_path / "run.xdmf"
    tags = np.arange(mesh.num_cells) % 3
    with XdmfWriter(path, mesh.points, mesh.tets, cell_data={"region": tags}) as out:
        for k in range(3):
            pdata, cdata = _frame_fields(mesh, k)
            out.write(0.25 * k, pdata, cdata)
    series = xdmf_mod.read_series(path)
    points, _, frames = _read_series(path)
    np.testing.assert_array_equal(series.points, points)
    np.testing.assert_array_equal(series.cells, mesh.tets)
    np.testing.assert_array_equal(series.times, [0.0, 0.25, 0.5])
    for k, (_, pdata, cdata) in enumerate(frames):
        assert series.point_data[k].keys() == pdata.keys()
        for name, arr in pdata.items():
            np.testing.assert_array_equal(series.point_data[k][name], arr)
        np.testing.assert_array_equal(series.cell_data[k]["region"], tags)
        np.testing.assert_array_equal(series.cell_data[k]["energy"], cdata["energy"][0])


def test_static_result_round_trip(tmp_path, mesh):
    path = tmp_path / "static.xdmf"
    u = np.linspace(0, 1, 3 * mesh.num_points).reshape(-1, 3)
    stress = np.arange(9 * mesh.num_cells, dtype=float).reshape(-1, 3, 3)
    write_xdmf(
        path, mesh.points, mesh.tets, {"u": u}, {"stress": stress, "id": np.arange(mesh.num_cells)}
    )
    m = meshio.read(path)
    np.testing.assert_array_equal(m.points, mesh.points)
    np.testing.assert_array_equal(m.cells[0].data, mesh.tets)
    np.testing.assert_array_equal(m.point_data["u"], u)
    np.testing.assert_array_equal(m.cell_data["stress"][0], stress)
    np.testing.assert_array_equal(m.cell_data["id"][0], np.arange(mesh.num_cells))
    assert 'AttributeType="Tensor"' in path.read_text()
    assert _leftovers(tmp_path) == []

    # Overwriting with a different mesh replaces both files consistently.
    small = box_mesh([1, 1, 1], [1, 1, 1])
    write_xdmf(path, small.points, small.tets, {"u": small.points})
    m = meshio.read(path)
    np.testing.assert_array_equal(m.points, small.points)
    np.testing.assert_array_equal(m.point_data["u"], small.points)


def test_static_result_without_fields(tmp_path, mesh):
    path = tmp_path / "bare.xdmf"
    write_xdmf(path, mesh.points, mesh.tets)
    m = meshio.read(path)
    np.testing.assert_array_equal(m.cells[0].data, mesh.tets)


def test_close_without_frames_writes_the_mesh(tmp_path, mesh):
    path = tmp_path / "empty.xdmf"
    tags = np.ones(mesh.num_cells, np.int64)
    out = XdmfWriter(path, mesh.points, mesh.tets, cell_data={"region": tags})
    out.close()
    out.close()  # idempotent
    m = meshio.read(path)
    np.testing.assert_array_equal(m.points, mesh.points)
    np.testing.assert_array_equal(m.cell_data["region"][0], tags)
    with pytest.raises(ValueError, match="after close"):
        out.write(0.0, {})


def test_dtypes_and_names(tmp_path, mesh):
    path = tmp_path / "d.xdmf"
    pdata = {
        "von Mises / Pa": np.arange(mesh.num_points, dtype=np.float32),
        "von Mises _ Pa": np.arange(mesh.num_points, dtype=np.float64),  # same h5 key
        "fixed": np.arange(mesh.num_points) % 2 == 0,
        "small": np.arange(mesh.num_points, dtype=np.uint8),
        'a<b>&"c"': np.zeros((mesh.num_points, 3)),
    }
    with XdmfWriter(path, mesh.points, mesh.tets) as out:
        out.write(1.0, pdata)
    _, _, [(t, got, _)] = _read_series(path)
    assert t == 1.0 and set(got) == set(pdata)
    assert got["von Mises / Pa"].dtype == np.float32
    np.testing.assert_array_equal(got["von Mises / Pa"], pdata["von Mises / Pa"])
    np.testing.assert_array_equal(got["von Mises _ Pa"], pdata["von Mises _ Pa"])
    assert got["fixed"].dtype == np.int32
    np.testing.assert_array_equal(got["fixed"], pdata["fixed"].astype(np.int32))
    np.testing.assert_array_equal(got["small"], pdata["small"].astype(np.int32))


def test_frame_cell_data_shadows_static(tmp_path, mesh):
    path = tmp_path / "s.xdmf"
    with XdmfWriter(path, mesh.points, mesh.tets, cell_data={"c": np.zeros(mesh.num_cells)}) as out:
        out.write(0.0, {}, {"c": np.ones(mesh.num_cells)})
        out.write(1.0, {})
    _, _, frames = _read_series(path)
    np.testing.assert_array_equal(frames[0][2]["c"][0], 1.0)
    np.testing.assert_array_equal(frames[1][2]["c"][0], 0.0)


def test_output_moves_with_its_directory(tmp_path, mesh):
    with XdmfWriter(tmp_path / "a" / "run.xdmf", mesh.points, mesh.tets) as out:
        out.write(0.0, {"u": mesh.points})
    (tmp_path / "a").rename(tmp_path / "b")  # the .h5 is referenced relative to the .xdmf
    _, _, [(_, pdata, _)] = _read_series(tmp_path / "b" / "run.xdmf")
    np.testing.assert_array_equal(pdata["u"], mesh.points)


def test_new_writer_replaces_old_series(tmp_path, mesh):
    path = tmp_path / "run.xdmf"
    with XdmfWriter(path, mesh.points, mesh.tets) as out:
        for k in range(3):
            out.write(k, {"u": mesh.points * k})
    out = XdmfWriter(path, mesh.points, mesh.tets)
    # The old .xdmf referenced frames the new .h5 does not have: it is gone until a frame is in.
    assert not path.exists()
    out.write(5.0, {"u": mesh.points})
    _, _, frames = _read_series(path)
    assert [f[0] for f in frames] == [5.0]
    out.close()


# ------------------------------------------------------------------------------------------------
# bad calls write nothing


def test_bad_calls(tmp_path, mesh):
    path = tmp_path / "bad.xdmf"
    out = XdmfWriter(path, mesh.points, mesh.tets)
    with pytest.raises(ValueError, match=r"point_data 'u' has shape \(3, 3\).*number of nodes"):
        out.write(0.0, {"u": np.zeros((3, 3))})
    with pytest.raises(ValueError, match="cell_data 'e'.*number of cells, 48"):
        out.write(0.0, {"u": mesh.points}, {"e": np.zeros(5)})
    with pytest.raises(TypeError, match="dtype complex128"):
        out.write(0.0, {"u": mesh.points.astype(complex)})
    with pytest.raises(ValueError, match="finite"):
        out.write(float("nan"), {})
    assert not path.exists() and out.num_frames == 0
    out.write(1.0, {"u": mesh.points})
    with pytest.raises(ValueError, match="must increase"):
        out.write(1.0, {"u": mesh.points})
    out.close()
    _, _, frames = _read_series(path)
    assert len(frames) == 1


def test_bad_construction(tmp_path, mesh):
    with pytest.raises(ValueError, match=r"must not end in \.h5"):
        XdmfWriter(tmp_path / "x.h5", mesh.points, mesh.tets)
    with pytest.raises(ValueError, match="must not contain ':'"):
        XdmfWriter(tmp_path / "a:b.xdmf", mesh.points, mesh.tets)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        XdmfWriter(tmp_path / "x.xdmf", mesh.points[:, :2], mesh.tets)
    with pytest.raises(ValueError, match="outside"):
        XdmfWriter(tmp_path / "x.xdmf", mesh.points, mesh.tets + 1000)
    with pytest.raises(ValueError, match="cell_data 'r'"):
        XdmfWriter(tmp_path / "x.xdmf", mesh.points, mesh.tets, cell_data={"r": [1, 2]})


# ------------------------------------------------------------------------------------------------
# crashes


def test_failure_while_writing_frame_data(tmp_path, mesh, monkeypatch):
    """A frame whose HDF5 write fails half-way is never referenced; the next one replaces it."""
    path = tmp_path / "run.xdmf"
    out = XdmfWriter(path, mesh.points, mesh.tets)
    out.write(0.0, {"u": mesh.points, "v": mesh.points})
    before = path.read_bytes()

    import petsoft.io.xdmf as xdmf

    real = xdmf._DatasetMaker.__call__

    def failing(self, group, name, value):
        if str(name).endswith("point/v"):
            raise OSError("disk full (simulated)")
        return real(self, group, name, value)

    monkeypatch.setattr(xdmf._DatasetMaker, "__call__", failing)
    with pytest.raises(OSError, match="simulated"):
        out.write(1.0, {"u": 2 * mesh.points, "v": 2 * mesh.points})
    monkeypatch.undo()

    assert path.read_bytes() == before and out.num_frames == 1
    _, _, frames = _read_series(path)
    assert [f[0] for f in frames] == [0.0]

    out.write(2.0, {"u": 3 * mesh.points, "v": 3 * mesh.points})
    out.close()
    _, _, frames = _read_series(path)
    assert [f[0] for f in frames] == [0.0, 2.0]
    np.testing.assert_array_equal(frames[1][1]["v"], 3 * mesh.points)


def test_failure_while_updating_xdmf(tmp_path, mesh, monkeypatch):
    """The first frame's .xdmf is renamed into place, later frames are written in place: a
    failure of either leaves the previous document as it was, and the next frame goes on."""
    path = tmp_path / "run.xdmf"
    out = XdmfWriter(path, mesh.points, mesh.tets)

    def failing_replace(src, dst):
        raise OSError("rename failed (simulated)")

    monkeypatch.setattr(xdmf_mod.os, "replace", failing_replace)
    with pytest.raises(OSError, match="simulated"):
        out.write(0.0, {"u": mesh.points})
    monkeypatch.undo()
    assert not path.exists() and out.num_frames == 0
    assert _leftovers(tmp_path) == []  # the temporary file is cleaned up
    out.write(0.0, {"u": mesh.points})
    before = path.read_bytes()

    real = os.pwrite

    def short_write(fd, data, offset):      # the disk fills up after 10 bytes
        return real(fd, data[:10], offset) if len(data) > 200 else real(fd, data, offset)

    monkeypatch.setattr(xdmf_mod.os, "pwrite", short_write)
    with pytest.raises(OSError, match="short write"):
        out.write(1.0, {"u": mesh.points})
    monkeypatch.undo()
    # the frame's place is left a comment: the same series, and the next frame goes after it
    assert len(path.read_bytes()) == len(before) and out.num_frames == 1
    assert [f[0] for f in _read_series(path)[2]] == [0.0]
    out.write(2.0, {"u": mesh.points})
    out.close()
    assert [f[0] for f in _read_series(path)[2]] == [0.0, 2.0]


def test_frames_are_written_in_place(tmp_path, mesh):
    """Each frame goes into the reserve of spaces before the closing tags: the file keeps its
    size and every byte before the frame's place (O(1) a frame, not a rewrite of the series)
    until the reserve is used up; then the document is made anew with a reserve as large as
    itself, and close() removes the reserve."""
    path = tmp_path / "run.xdmf"
    out = XdmfWriter(path, mesh.points, mesh.tets)
    docs = []
    for k in range(60):
        out.write(float(k), {"u": mesh.points * k})
        docs.append(path.read_bytes())
    sizes = [len(d) for d in docs]
    remade = [k for k in range(1, 60) if sizes[k] != sizes[k - 1]]
    assert 1 <= len(remade) <= 3, sizes          # 16 kB, then doubling
    assert all(sizes[k] >= 2 * sizes[k - 1] - 4096 for k in remade)
    for k in range(1, 60):
        if k not in remade:
            tail = len(b"</Grid>\n</Domain>\n</Xdmf>\n")
            start = len(docs[k - 1][:-tail].rstrip(b" "))      # where the last frame ends
            assert docs[k][:start] == docs[k - 1][:start]
    assert docs[-1].count(b"<!--") == docs[-1].count(b"-->") == 0
    out.close()
    closed = path.read_bytes()
    assert len(closed) < len(docs[-1]) and b"    \n</Grid>" not in closed
    assert [f[0] for f in _read_series(path)[2]] == [float(k) for k in range(60)]


def test_every_write_of_a_frame_leaves_a_well_formed_document(tmp_path, mesh, monkeypatch):
    """A process killed during a frame's update leaves what its writes made so far, a write to
    a regular file torn at a page boundary: before every write of the .xdmf, the document with
    that write done up to any byte (the markers' writes, within one page, whole or not at all)
    must parse. Also with a name holding "--", which a comment cannot (the document is made
    anew for that frame)."""
    import mmap

    path = tmp_path / "run.xdmf"
    out = XdmfWriter(path, mesh.points, mesh.tets)
    out.write(0.0, {"u": mesh.points})
    real = os.pwrite
    writes = []

    def checked(fd, data, offset):
        doc = bytearray(path.read_bytes())
        small = len(data) <= 4
        if small:
            assert offset // mmap.PAGESIZE == (offset + len(data) - 1) // mmap.PAGESIZE
        for cut in ((0, len(data)) if small else range(0, len(data) + 1, 7)):
            torn = doc.copy()
            torn[offset:offset + cut] = data[:cut]
            ET.fromstring(bytes(torn))
        writes.append(len(data))
        return real(fd, data, offset)

    monkeypatch.setattr(xdmf_mod.os, "pwrite", checked)
    for k in range(1, 25):
        out.write(float(k), {"u": mesh.points * k} if k != 7 else {"a--b": mesh.points})
    monkeypatch.undo()
    assert len(writes) >= 5 * 20        # five writes a frame in place
    out.close()
    frames = _read_series(path)[2]
    assert [f[0] for f in frames] == [float(k) for k in range(25)]
    assert list(frames[7][1]) == ["a--b"]


# Before each frame had its own file, this failed now and then (2 of ~30 CI runs): a writer
# killed while HDF5 updated the shared file's group metadata left earlier, complete frames
# unreadable ("bad heap free list", "addr overflow").
@pytest.mark.parametrize("flush_seconds", [0.0, 0.02])
def test_killed_at_any_moment_leaves_a_valid_series(tmp_path, flush_seconds):
    """Writers killed (SIGKILL) at random moments while writing frames as fast as they can,
    frame by frame or in batches: every .xdmf left behind parses and references only complete
    frames, in order."""
    import signal
    import time

    script = textwrap.dedent(
        """
        import sys, time
        from petsoft.mesh.serial import box_mesh
        from petsoft.io.xdmf import XdmfWriter
        m = box_mesh([1, 1, 1], [2, 2, 2])
        out = XdmfWriter(sys.argv[1], m.points, m.tets, flush_seconds=float(sys.argv[2]))
        print("ready", flush=True)
        k = 0
        while True:
            out.write(0.5 * k, {"u": m.points * k})
            k += 1
            if out.flush_seconds:   # a step's worth of work: batches of ~10 frames
                time.sleep(0.002)
        """
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    rng = np.random.default_rng(7)
    counts = []
    for trial in range(8):
        path = tmp_path / f"killed{trial}.xdmf"
        proc = subprocess.Popen([sys.executable, "-c", script, str(path), str(flush_seconds)],
                                env=env, stdout=subprocess.PIPE, text=True)
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(rng.uniform(0.05, 0.4))
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
        if not path.exists():       # killed before the first frame
            counts.append(0)
            continue
        ET.parse(path)              # well-formed XML, whatever the moment
        points, _, frames = _read_series(path)
        counts.append(len(frames))
        assert [f[0] for f in frames] == [0.5 * k for k in range(len(frames))]
        for k, (_, data, _) in enumerate(frames):
            np.testing.assert_array_equal(data["u"], points * k)
    assert max(counts) > 1, counts      # the kills did land between frames of a running series


def test_collected_frames_are_written_in_batches(tmp_path, mesh, monkeypatch):
    """A collecting writer writes its first frame at once, then batches: one file per batch
    (a dataset per field and frame), referenced once complete, by flush(), by close() and when
    flush_seconds have passed; a failed batch stays collected and is written by the next
    flush. meshio reads the series as it reads one written frame by frame."""
    import time

    import petsoft.io.xdmf as xdmf

    path = tmp_path / "run.xdmf"
    state = np.zeros_like(mesh.points)
    out = XdmfWriter(path, mesh.points, mesh.tets, flush_seconds=3600.0)
    for k in range(5):
        state[:] = mesh.points * k          # the caller's array changes after each write
        out.write(0.1 * k, {"u": state}, {"e": np.full(mesh.num_cells, float(k))})
    assert out.num_frames == 1 and out.num_pending == 4
    assert len(_read_series(path)[2]) == 1           # on disk: the first frame only
    out.flush()
    assert out.num_frames == 5 and out.num_pending == 0
    with h5py.File(tmp_path / "run_frames" / "1.h5", "r") as f:
        assert sorted(f["point/u"]) == ["1", "2", "3", "4"] and sorted(f["cell/e"]) == sorted(
            f["point/u"])
        np.testing.assert_array_equal(f.attrs["times"], [0.1, 0.2, 0.1 * 3, 0.4])
        np.testing.assert_array_equal(f["point/u/3"][()], mesh.points * 3)
    # a batch whose file cannot be written stays collected; the series on disk is unchanged
    out.write(0.5, {"u": mesh.points * 5}, {"e": np.full(mesh.num_cells, 5.0)})
    before = path.read_bytes()
    real = xdmf._write_h5_atomically

    def fail(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(xdmf, "_write_h5_atomically", fail)
    with pytest.raises(OSError, match="disk full"):
        out.flush()
    assert path.read_bytes() == before and out.num_frames == 5 and out.num_pending == 1
    monkeypatch.setattr(xdmf, "_write_h5_atomically", real)
    out.flush_seconds = 0.05
    time.sleep(0.06)
    out.write(0.6, {"u": mesh.points * 6}, {"e": np.full(mesh.num_cells, 6.0)})
    assert out.num_frames == 7 and out.num_pending == 0      # the time had come: written
    out.flush_seconds = 3600.0
    out.write(0.7, {"u": mesh.points * 7}, {"e": np.full(mesh.num_cells, 7.0)})
    assert out.num_pending == 1
    out.close()
    assert out.num_frames == 8
    assert sorted(p.name for p in (tmp_path / "run_frames").iterdir()) == [
        "0.h5", "1.h5", "5.h5", "7.h5"]
    points, _, frames = _read_series(path)
    assert [f[0] for f in frames] == [0.0, 0.1, 0.2, 0.1 * 3, 0.4, 0.5, 0.6, 0.7]
    for k, (_, pdata, cdata) in enumerate(frames):
        np.testing.assert_array_equal(pdata["u"], points * k)
        np.testing.assert_array_equal(cdata["e"][0], np.full(mesh.num_cells, float(k)))
    assert _leftovers(tmp_path) == []
    with pytest.raises(ValueError, match="flush_seconds"):
        XdmfWriter(tmp_path / "bad.xdmf", mesh.points, mesh.tets, flush_seconds=-1.0)


def test_killed_process_leaves_consistent_prefix(tmp_path):
    """A process that dies without closing the writer leaves a readable series of its frames."""
    script = textwrap.dedent(
        """
        import os, sys
        import numpy as np
        from petsoft.mesh.serial import box_mesh
        from petsoft.io.xdmf import XdmfWriter
        m = box_mesh([1, 1, 1], [2, 2, 2])
        out = XdmfWriter(sys.argv[1], m.points, m.tets, fsync=True)
        for k in range(3):
            out.write(0.5 * k, {"u": m.points * k})
        os._exit(3)  # no close(), no atexit, no flushing of Python objects
        """
    )
    path = tmp_path / "killed.xdmf"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run([sys.executable, "-c", script, str(path)], env=env, timeout=60)
    assert proc.returncode == 3
    points, _, frames = _read_series(path)
    assert [f[0] for f in frames] == [0.0, 0.5, 1.0]
    np.testing.assert_array_equal(frames[2][1]["u"], points * 2)


def test_writing_while_another_process_reads(tmp_path, mesh):
    """A viewer holding the .h5 open (shared HDF5 lock) must not make the writer fail."""
    path = tmp_path / "watched.xdmf"
    out = XdmfWriter(path, mesh.points, mesh.tets)
    out.write(0.0, {"u": mesh.points})
    reader = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, h5py; f = h5py.File(sys.argv[1], 'r'); print('open', flush=True); "
            "sys.stdin.read()",
            str(path.with_suffix(".h5")),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert reader.stdout.readline().strip() == "open"
        out.write(1.0, {"u": 2 * mesh.points})
    finally:
        reader.communicate("", timeout=60)
    out.close()
    assert [f[0] for f in _read_series(path)[2]] == [0.0, 1.0]


def test_ten_node_tetrahedra_are_written_as_tetrahedron_10(tmp_path):
    """A mesh of order 2 is written with its 10-node cells (XDMF Tetrahedron_10, VTK node order,
    which ParaView and meshio read): meshio reads tetra10 back, every edge node at the midpoint
    of the corners VTK's order puts it between, and the field on all nodes."""
    from petsoft.mesh.quadratic import TET10_EDGES, raise_order

    mesh = raise_order(box_mesh([1.0, 0.5, 0.5], [2, 1, 1]))
    path = tmp_path / "p2.xdmf"
    write_xdmf(path, mesh.points, mesh.cells, point_data={"u": mesh.points ** 2})
    assert 'TopologyType="Tetrahedron_10"' in path.read_text()
    back = meshio.read(path)
    assert [c.type for c in back.cells] == ["tetra10"]
    cells = back.cells[0].data
    np.testing.assert_array_equal(cells, mesh.cells)
    p = back.points
    mid = 0.5 * (p[cells[:, TET10_EDGES[:, 0]]] + p[cells[:, TET10_EDGES[:, 1]]])
    np.testing.assert_allclose(p[cells[:, 4:]], mid, atol=1e-15)
    np.testing.assert_allclose(back.point_data["u"], mesh.points ** 2)
