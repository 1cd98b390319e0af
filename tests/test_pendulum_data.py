"""The real pendulum data: the importer script runs on the real file and its outputs validate."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _examples import load_script

from petsoft.experiment import load_experiment
from petsoft.io.recording import read_recording

pytestmark = pytest.mark.serial_only   # runs a script in a subprocess

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "examples" / "import_pendulum.py"


def test_data_and_licence_are_in_the_project():
    folder = ROOT / "scripts" / "examples" / "data" / "pendulum-single"
    assert "MIT License" in (folder / "LICENSE").read_text()
    assert "arXiv:2205.06231" in (folder / "README.md").read_text()


def test_sign_convention():
    pendulum = load_script("import_pendulum")
    marker_positions, marker_velocities = pendulum.marker_positions, pendulum.marker_velocities

    L = 0.2
    np.testing.assert_allclose(marker_positions(np.array([np.pi]), L), [[0, 0, -L]], atol=1e-15)
    # velocity is the time derivative of the position (finite difference, independent)
    th = np.array([2.0])
    h = 1e-6
    fd = (marker_positions(th + h, L) - marker_positions(th - h, L)) / (2 * h)
    np.testing.assert_allclose(marker_velocities(th, np.array([1.0]), L), fd, rtol=1e-8)


def test_import_pendulum(tmp_path):
    run = subprocess.run([sys.executable, str(SCRIPT), "--out", str(tmp_path), "--every", "10"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    from scipy.io import loadmat

    raw = loadmat(ROOT / "scripts/examples/data/pendulum-single"
                  / "SinglePendulumDataForParameterEstimation.mat", squeeze_me=True)
    theta_id = np.concatenate([y[0] for y in raw["Y_id"]])[::10]
    L = 0.1528
    ident = read_recording(tmp_path / "identification.h5")
    val = read_recording(tmp_path / "validation.h5")
    assert ident.names == ["bob"] and ident.num_frames == len(theta_id)
    np.testing.assert_allclose(np.diff(ident.times), 0.01, atol=1e-9)   # 100 Hz
    assert val.times[0] == 0.0 and abs(val.attrs["time_offset"] - 36.668) < 1e-9
    for rec in (ident, val):
        r = np.linalg.norm(rec.positions[:, 0], axis=1)                # pivot at the origin
        np.testing.assert_allclose(r, L, rtol=1e-12)
        np.testing.assert_allclose(rec.positions[:, 0, 1], 0.0)        # x-z swing plane
        np.testing.assert_allclose(rec.reference, [[0, 0, -L]])
    # the angle is recovered from the marker (theta = pi is straight down)
    back = np.arctan2(ident.positions[:, 0, 0], ident.positions[:, 0, 2]) % (2 * np.pi)
    np.testing.assert_allclose(back, theta_id % (2 * np.pi), atol=1e-12)
    pub = json.loads((tmp_path / "published.json").read_text())
    est = pub["angle_noise_rad"]
    # three independent noise estimators agree within 20 %
    vals = np.array([est["savgol"], est["second_difference"], est["third_difference"]])
    assert vals.max() < 1.2 * vals.min()
    assert ident.noise["position_std"] == pytest.approx(L * est["savgol"])
    # experiments parse with the formats.md schema
    exp = load_experiment(tmp_path / "pendulum_id.toml")
    assert exp.is_mass_spring and exp.springs.pairs == ((0, 1),)
    assert set(exp.calibrate) == {"damping.mass", "gravity.acceleration.z"}
    assert exp.time.step == 0.01 and abs(exp.time.end - ident.times[-1]) < 1e-9
    assert exp.masses[0].at == (0.0, 0.0, -L)
    assert pub["equivalent_point_mass_model"]["equivalent_length"] == pytest.approx(L, rel=1e-3)
    # initial displacement puts the bob at the first sample and leaves the pivot at rest
    pts = np.array([[0, 0, 0.0], [0, 0, -L]])
    u0 = np.column_stack([e.evaluate_at(pts) for e in exp.initial.displacement])
    np.testing.assert_allclose(u0[0], 0, atol=1e-15)
    np.testing.assert_allclose(pts[1] + u0[1], ident.positions[0, 0], atol=1e-12)
    png = tmp_path / "pendulum.png"
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"
