"""CSV and C3D importers and `petsoft import`."""

import subprocess
import sys

import numpy as np
import pytest
from _c3d_writer import write_c3d

from petsoft.io.importers import ImportFileError, import_file
from petsoft.io.importers.c3d import read_c3d
from petsoft.io.importers.csv import read_csv
from petsoft.io.recording import read_recording

pytestmark = pytest.mark.serial_only  # rank-local files and a subprocess


def _positions(K=6, M=3, seed=0):
    rng = np.random.default_rng(seed)
    return 100.0 * rng.random((K, M, 3)) + 50.0          # millimetres


def test_csv_mm_with_gaps(tmp_path):
    text = ("# exported by a lab tool\n"
            "time,left_knee_x,left_knee_y,left_knee_z,b_x,b_y,b_z\n"
            "0.00,  ,  ,  ,10,20,30\n"
            "0.01,1,2,3,11,21,31\n"
            "0.03,1.5,2.5,3.5,NaN,NaN,NaN\n")
    (tmp_path / "m.csv").write_text(text)
    rec = read_csv(tmp_path / "m.csv", units="mm")
    assert rec.names == ["left_knee", "b"]
    np.testing.assert_array_equal(rec.times, [0.0, 0.01, 0.03])
    assert np.isnan(rec.positions[0, 0]).all() and np.isnan(rec.positions[2, 1]).all()
    np.testing.assert_allclose(rec.positions[1], [[1e-3, 2e-3, 3e-3], [0.011, 0.021, 0.031]])
    # reference: first frame where all are seen (frame 1)
    np.testing.assert_allclose(rec.reference, rec.positions[1])
    assert rec.attrs["reference_frame"] == 1
    rec0 = read_csv(tmp_path / "m.csv", scale=2.0, rest_frame=1)
    np.testing.assert_allclose(rec0.reference, 2000 * rec.positions[1])
    with pytest.raises(ImportFileError, match="marker 'left_knee' is not seen in the rest "
                                              "frame 0"):
        read_csv(tmp_path / "m.csv", rest_frame=0)


@pytest.mark.parametrize("text, message", [
    ("x,a_x,a_y,a_z\n0,1,2,3\n", "line 1: the first column must be 'time'"),
    ("time,a_x,a_y\n0,1,2\n", "2 columns after 'time'; expected three per marker"),
    ("time,a_x,a_z,a_y\n0,1,2,3\n", "columns 2-4 are a_x, a_z, a_y"),
    ("time,a_x,a_y,a_z,a_x,a_y,a_z\n0,1,2,3,4,5,6\n", "marker 'a' appears twice"),
    ("time,a_x,a_y,a_z\n0,1,2\n", "line 2 has 3 cells; the header has 4"),
    ("time,a_x,a_y,a_z\n0,1,two,3\n", "line 2, column a_y: 'two' is not a number"),
    ("time,a_x,a_y,a_z\n0,1,2,3\n0.2,1,2,3\n0.1,1,2,3\n",
     "line 4: time 0.1 s does not increase (previous 0.2 s)"),
    ("time,a_x,a_y,a_z\n0,1,2,3\n,1,2,3\n", "line 3: the time is missing"),
    ("time,a_x,a_y,a_z\n0,1,,3\n", "line 2: marker 'a' has only some of its x, y, z cells"),
    ("time,a_x,a_y,a_z,b_x,b_y,b_z\n0,1,2,3,,,\n1,,,,1,2,3\n",
     "no frame sees every marker (marker 'a' is seen in 1 of 2 frames)"),
    ("time,a_x,a_y,a_z\n0,1,inf,3\n", "'inf' is not finite"),
])
def test_csv_errors(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ImportFileError) as err:
        read_csv(path)
    assert str(path) in str(err.value) and message in str(err.value)


@pytest.mark.parametrize("storage, endian", [("float", "<"), ("int", "<"), ("float", ">")])
def test_c3d_round_trip(tmp_path, storage, endian):
    pos = _positions()
    pos[2, 1] = np.nan                                   # marker 1 not seen in frame 2
    pos[0, 0] = np.nan                                   # marker 0 not seen in frame 0
    path = write_c3d(tmp_path / "t.c3d", ["RHEE", "LHEE", "T10"], 120.0, pos, units="mm",
                     storage=storage, scale=0.05, first_frame=11, analog_per_frame=4,
                     endian=endian)
    rec = read_c3d(path)
    assert rec.names == ["RHEE", "LHEE", "T10"]
    np.testing.assert_allclose(rec.times, (10 + np.arange(6)) / 120.0)
    seen = np.isfinite(pos).all(axis=2)
    np.testing.assert_array_equal(rec.seen(), seen)
    tol = 1e-5 if storage == "float" else 0.05 / 2 + 1e-9     # float32, or int16 rounding
    np.testing.assert_allclose(rec.positions[seen], 1e-3 * pos[seen], rtol=0, atol=tol * 1e-3)
    np.testing.assert_allclose(rec.reference, rec.positions[1])   # first frame all seen
    rec_m = read_c3d(path, units="m")
    np.testing.assert_allclose(rec_m.positions[seen], 1000 * rec.positions[seen])


def test_c3d_errors(tmp_path):
    (tmp_path / "x.c3d").write_bytes(b"\0" * 1024)
    with pytest.raises(ImportFileError, match="not a C3D file"):
        read_c3d(tmp_path / "x.c3d")
    pos = _positions()
    path = write_c3d(tmp_path / "u.c3d", ["a", "b", "c"], 100.0, pos, units="furlong")
    with pytest.raises(ImportFileError, match="POINT:UNITS = 'furlong' is not a known length "
                                              "unit"):
        read_c3d(path)
    raw = path.read_bytes()
    (tmp_path / "cut.c3d").write_bytes(raw[:2 * 512 + 100])
    with pytest.raises(ImportFileError, match="truncated: 6 frames of 3 points"):
        read_c3d(tmp_path / "cut.c3d", units="mm")
    with pytest.raises(ImportFileError, match="give --units or --scale, not both"):
        read_c3d(path, units="mm", scale=0.001)


def test_import_command(tmp_path):
    pos = _positions()
    pos[3, 2] = np.nan
    c3d = write_c3d(tmp_path / "walk.c3d", ["a", "b", "c"], 100.0, pos)
    out = tmp_path / "rec.h5"
    run = subprocess.run([sys.executable, "-m", "petsoft.cli.main", "import", str(c3d), "--out",
                          str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "3 markers, 6 frames" in run.stdout
    rec = read_recording(out)
    assert np.isnan(rec.positions[3, 2]).all()
    np.testing.assert_allclose(rec.positions[0], 1e-3 * pos[0], atol=1e-8)
    assert import_file(c3d).names == rec.names
    bad = tmp_path / "bad.txt"
    bad.write_text("time,a_x\n")
    run = subprocess.run([sys.executable, "-m", "petsoft.cli.main", "import", str(bad), "--out",
                          str(out), "--format", "csv"], capture_output=True, text=True)
    assert run.returncode == 2
    assert run.stderr.startswith("petsoft: error: ") and "expected three per marker" in run.stderr
