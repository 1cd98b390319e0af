"""C3D files written by other tools (ezc3d, c3d): tests/data/c3d/, made by make_fixtures.py.

The tests read the committed files; neither library is needed to run them.
"""

import gzip
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from petsoft.io.importers import ImportFileError
from petsoft.io.importers.c3d import read_c3d

DATA = Path(__file__).parent / "data" / "c3d"
LABELS = ["RHEE", "LHEE", "T10"]


def _positions(K, M):
    """The positions make_fixtures.py wrote, in millimetres (the same formula)."""
    k = np.arange(K, dtype=float)[:, None]
    m = np.arange(M, dtype=float)[None, :]
    return np.stack([100 * m + 10 * k + 0.123, 200 + m - 0.5 * k, 1000.25 + 3 * k + 0 * m],
                    axis=2)


def _expected_small():
    pos = _positions(10, 3)
    pos[3:5, 1] = np.nan                                # marker LHEE not seen in frames 3, 4
    return 1e-3 * pos


@pytest.mark.parametrize("name, atol", [
    ("ezc3d_float_mm_analog.c3d", 1e-6),              # ezc3d: float, NaN coordinates
    ("c3d_float_m.c3d", 1e-6),                         # c3d: float, in metres, residual -1
    ("c3d_int_mm.c3d", 0.1e-3 / 2 + 1e-9),             # c3d: int16 at POINT:SCALE 0.1 mm
    ("c3d_float_m_dec.c3d", 1e-6),                     # the c3d float file as DEC (VAX F)
    ("c3d_float_m_mips.c3d", 1e-6),                    # ... and as MIPS (big-endian)
])
def test_other_writers(name, atol):
    rec = read_c3d(DATA / name)
    expected = _expected_small()
    seen = np.isfinite(expected).all(axis=2)
    assert rec.names == LABELS
    np.testing.assert_array_equal(rec.seen(), seen)
    assert np.isnan(rec.positions[~seen]).all()
    np.testing.assert_allclose(rec.positions[seen], expected[seen], rtol=0, atol=atol)
    np.testing.assert_allclose(rec.times, np.arange(10) / 100.0)
    assert rec.attrs["unit_scale"] == (1.0 if name.startswith("c3d_float_m") else 1e-3)


@pytest.mark.serial_only  # a subprocess of the CLI
def test_analog_skipped_with_a_note(tmp_path):
    rec = read_c3d(DATA / "ezc3d_float_mm_analog.c3d")
    assert "analog data skipped (2 channels" in rec.attrs["note"]
    assert "note" not in read_c3d(DATA / "c3d_int_mm.c3d").attrs
    run = subprocess.run([sys.executable, "-m", "petsoft.cli.main", "import",
                          str(DATA / "ezc3d_float_mm_analog.c3d"), "--out",
                          str(tmp_path / "r.h5")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "note: ezc3d_float_mm_analog.c3d: analog data skipped" in run.stdout
    assert "3 markers, 10 frames" in run.stdout


def test_more_than_65535_frames(tmp_path):
    # c3d writes POINT:LONG_FRAMES / TRIAL:ACTUAL_*_FIELD; ezc3d only POINT:FRAMES = 65535,
    # with the data (and block padding) behind it
    ezc3d_file = tmp_path / "ezc3d_long_70000.c3d"
    ezc3d_file.write_bytes(gzip.decompress((DATA / "ezc3d_long_70000.c3d.gz").read_bytes()))
    expected = 1e-3 * _positions(70000, 1) / 100
    for path in (DATA / "c3d_long_70000.c3d", ezc3d_file):
        rec = read_c3d(path)
        assert rec.num_frames == 70000, path
        assert rec.seen().all()
        np.testing.assert_allclose(rec.times[[0, -1]], [0.0, 69.999])
        np.testing.assert_allclose(rec.positions, expected, rtol=0, atol=1e-6)


@pytest.mark.parametrize("cut, message", [
    (300, "truncated: the 512-byte header block has only 300 bytes"),
    (600, "truncated: the parameter section (bytes 512 to 2048, 3 blocks) stops at byte 600"),
    (2200, "truncated: 10 frames of 3 points need 2288 bytes, the file has 2200; the data stop "
           "in frame 6 (byte 2192)"),
])
def test_truncated_file(tmp_path, cut, message):
    raw = (DATA / "c3d_int_mm.c3d").read_bytes()
    path = tmp_path / "cut.c3d"
    path.write_bytes(raw[:cut])
    with pytest.raises(ImportFileError) as err:
        read_c3d(path)
    assert str(path) in str(err.value) and message in str(err.value)


def test_corrupt_file(tmp_path):
    raw = bytearray((DATA / "c3d_int_mm.c3d").read_bytes())
    path = tmp_path / "bad.c3d"
    bad = bytearray(raw)
    bad[4:6] = (-3).to_bytes(2, "little", signed=True)      # analog samples per frame
    path.write_bytes(bad)
    with pytest.raises(ImportFileError, match="corrupt header: -3 analog samples per frame"):
        read_c3d(path)
    bad = bytearray(raw)
    name_len = bad[512 + 4]                                  # first record's link: backwards
    at = 512 + 4 + 2 + name_len
    bad[at:at + 2] = (-40).to_bytes(2, "little", signed=True)
    path.write_bytes(bad)
    with pytest.raises(ImportFileError) as err:
        read_c3d(path)
    assert str(path) in str(err.value)
    assert "corrupt parameter section: the record at byte 516 points -40 bytes" in str(err.value)
