"""The recording format (formats.md section 2): round trip and strict validation on read."""

import os
from pathlib import Path

import h5py
import numpy as np
import pytest

from petsoft.io.recording import (
    Recording,
    RecordingError,
    RecordingWarning,
    read_recording,
    write_recording,
)

pytestmark = pytest.mark.serial_only  # rank-local file I/O in tmp_path


def _sample(K=5, M=3, seed=0):
    rng = np.random.default_rng(seed)
    ref = rng.random((M, 3))
    t = np.cumsum(rng.random(K) + 0.01)
    pos = ref[None] + 0.01 * rng.standard_normal((K, M, 3))
    return ref, t, pos


def _write_raw(path, **over):
    """A recording written with h5py directly, so invalid files can be made."""
    ref, t, pos = _sample()
    data = {"markers/reference": ref, "frames/time": t, "frames/position": pos}
    attrs = {"format": "petsoft-recording", "version": 1}
    for k, v in over.items():
        if k in ("format", "version"):
            attrs[k] = v
        else:
            data[k.replace("__", "/")] = v
    with h5py.File(path, "w") as f:
        for k, v in attrs.items():
            if v is not None:
                f.attrs[k] = v
        for k, v in data.items():
            if v is not None:
                f[k] = v
    return path


def test_round_trip_with_all_optional_parts(tmp_path):
    ref, t, pos = _sample()
    pos[1, 2] = np.nan                                   # marker 2 not seen in frame 1
    acc = np.random.default_rng(1).standard_normal(pos.shape)
    tin = np.linspace(0, 1, 7)
    vin = np.column_stack([tin, 2 * tin, 0 * tin])
    path = write_recording(tmp_path / "r.h5", ref, t, pos, names=["a", "b", "c"],
                           attrs={"source": "test"}, accelerations=acc,
                           noise={"position_std": 1e-3, "acceleration_std": 0.1},
                           inputs={"shaker": (tin, vin)})
    rec = read_recording(path)
    assert rec.names == ["a", "b", "c"]
    np.testing.assert_array_equal(rec.reference, ref)
    np.testing.assert_array_equal(rec.times, t)
    np.testing.assert_array_equal(rec.positions, pos)          # NaN kept where not seen
    np.testing.assert_array_equal(rec.accelerations, acc)
    assert rec.noise == {"position_std": 1e-3, "acceleration_std": 0.1}
    np.testing.assert_array_equal(rec.inputs["shaker"][1], vin)
    assert rec.attrs["source"] == "test"
    assert rec.seen().sum() == 5 * 3 - 1 and not rec.seen()[1, 2]
    again = rec.write(tmp_path / "again.h5")                     # Recording.write round trip
    rec2 = read_recording(again)
    np.testing.assert_array_equal(rec2.positions, pos)
    assert rec2.noise == rec.noise and rec2.names == rec.names


def test_accelerations_only_and_default_names(tmp_path):
    ref, t, pos = _sample()
    path = write_recording(tmp_path / "a.h5", ref, t, None, accelerations=pos)
    rec = read_recording(path)
    assert rec.positions is None and rec.names == ["m0", "m1", "m2"]
    assert not rec.seen().any()


def test_write_is_atomic(tmp_path, monkeypatch):
    """A failure while writing leaves no file under the final name and no temporary file."""
    ref, t, pos = _sample()
    bad_attrs = {"source": object()}                  # h5py cannot store this: fails mid-write
    with pytest.raises(TypeError):
        write_recording(tmp_path / "x.h5", ref, t, pos, attrs=bad_attrs)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("over, message", [
    ({"format": "something-else"}, "format = 'something-else'"),
    ({"format": None}, "format = None"),
    ({"version": 7}, "version = 7 is not supported"),
    ({"markers__reference": None}, "/markers/reference is missing"),
    ({"frames__time": None}, "/frames/time is missing"),
    ({"frames__position": None}, "neither /frames/position nor /frames/acceleration"),
    ({"markers__reference": np.zeros((3, 2))}, "expected (M, 3)"),
    ({"markers__reference": np.array([[0, 0, 0], [np.nan, 0, 0], [1, 1, 1.0]])},
     "reference of marker 1"),
    ({"frames__time": np.array([0.0, 0.1, 0.1, 0.3, 0.4])}, "at index 2 (t[1] = 0.1"),
    ({"frames__time": np.array([0.0, 0.2, 0.1, 0.3, 0.4])}, "at index 2"),
    ({"frames__time": np.array([0.0, 0.1, np.nan, 0.3, 0.4])}, "/frames/time[2] = nan"),
    ({"frames__position": np.zeros((5, 2, 3))}, "has shape (5, 2, 3); expected (5, 3, 3)"),
    ({"markers__name": np.array([b"a", b"b", b"a"])}, "'a' names markers 0 and 2"),
    ({"markers__name": np.array([b"a", b"b"])}, "one name per marker"),
    ({"markers__name": np.array([b"a", b" ", b"c"])}, "/markers/name[1] is empty"),
])
def test_invalid_recordings_are_named(tmp_path, over, message):
    path = _write_raw(tmp_path / "bad.h5", **over)
    with pytest.raises(RecordingError) as err:
        read_recording(path)
    assert str(path) in str(err.value)
    assert message in str(err.value)


def test_infinite_and_partial_nan_frames(tmp_path):
    ref, t, pos = _sample()
    inf = pos.copy()
    inf[3, 1, 2] = np.inf
    path = _write_raw(tmp_path / "inf.h5", frames__position=inf)
    with pytest.raises(RecordingError, match=r"infinite value at frame 3.*'m1' \(index 1\), "
                                             r"component z"):
        read_recording(path)
    half = pos.copy()
    half[2, 0, 0] = np.nan
    path = _write_raw(tmp_path / "half.h5", frames__position=half)
    with pytest.raises(RecordingError, match="frame 2, marker 'm0'.*NaN in some components"):
        read_recording(path)


def test_noise_and_inputs_validation(tmp_path):
    path = _write_raw(tmp_path / "n.h5")
    with h5py.File(path, "a") as f:
        f.create_group("noise").attrs["position_std"] = -1.0
    with pytest.raises(RecordingError, match="position_std = -1.0; must be finite and >= 0"):
        read_recording(path)
    path = _write_raw(tmp_path / "n2.h5")
    with h5py.File(path, "a") as f:
        f.create_group("noise").attrs["posiiton_std"] = 1.0
    with pytest.raises(RecordingError, match="unknown attribute.*posiiton_std"):
        read_recording(path)
    path = _write_raw(tmp_path / "i.h5")
    with h5py.File(path, "a") as f:
        f["inputs/shaker/time"] = np.array([0.0, 1.0, 0.5])
        f["inputs/shaker/value"] = np.zeros((3, 3))
    with pytest.raises(RecordingError, match="/inputs/shaker/time must increase strictly"):
        read_recording(path)


def test_never_seen_marker_warns(tmp_path):
    ref, t, pos = _sample()
    pos[:, 1] = np.nan
    path = write_recording(tmp_path / "w.h5", ref, t, pos, names=["a", "ghost", "c"])
    with pytest.warns(RecordingWarning, match="'ghost' \\(index 1\\) are never seen"):
        rec = read_recording(path)
    assert np.isnan(rec.positions[:, 1]).all()


def test_missing_and_non_hdf5_files(tmp_path):
    with pytest.raises(RecordingError, match="recording not found"):
        read_recording(tmp_path / "nope.h5")
    (tmp_path / "text.h5").write_text("hello")
    with pytest.raises(RecordingError, match="not an HDF5 file"):
        read_recording(tmp_path / "text.h5")


def test_dataclass_defaults():
    ref, t, pos = _sample()
    rec = Recording(ref, ["a", "b", "c"], t, pos)
    assert rec.num_markers == 3 and rec.num_frames == 5 and rec.noise == {}
    assert Path(rec.source).name == "<memory>"
