"""scripts/examples/calibrate_pendulum.py on a short span of the real pendulum: it imports,
calibrates,
predicts, writes its files, and its numbers are finite and physically plausible.

Runs serially and under ``mpiexec -n 2`` (the script is collective; rank 0 writes).
"""

import json
from pathlib import Path

import numpy as np
import pytest
from _examples import load_script
from petsc4py import PETSc

ROOT = Path(__file__).resolve().parents[1]
DATA = (ROOT / "scripts" / "examples" / "data" / "pendulum-single"
        / "SinglePendulumDataForParameterEstimation.mat")


@pytest.mark.skipif(not DATA.exists(), reason="the real pendulum data are not in this checkout")
def test_calibrate_pendulum_script_short_span(tmp_path):
    calibrate_pendulum = load_script("calibrate_pendulum", needs=("import_pendulum",))

    out = Path(PETSc.COMM_WORLD.tompi4py().bcast(str(tmp_path), root=0)) / "cal"
    # 1 s of id0 at 50 ms frames, h = 10 ms; 0.5 s of each validation segment
    assert calibrate_pendulum.main(["--out", str(out), "--span", "1.0", "--val-span", "0.5",
                                    "--every", "50", "--step", "0.01"]) == 0
    PETSc.COMM_WORLD.tompi4py().barrier()
    for name in ("summary.json", "id_fit.png", "val_fit.png", "residuals.png",
                 "id/calibrated.toml", "id/summary.json", "data/val1.h5"):
        assert (out / name).stat().st_size > 0, name
    s = json.loads((out / "summary.json").read_text())
    d = s["derived"]
    # a 0.15 m pendulum: g/L ~ 64 1/s^2 (published 64.22); the fit moved off its start (9.81)
    assert 60.0 < d["g_over_L"] < 69.0
    assert d["g_for_L_0.1528"] == pytest.approx(-s["calibrated"]["gravity.acceleration.z"])
    assert d["L_for_g_9.81"] == pytest.approx(9.81 / d["g_over_L"])
    # friction: positive, within a factor 3 of the published k = 2.24e-4 N m s
    assert 0.0 < d["friction_k_Nms"] < 7e-4 and d["friction_k_Nms"] > 7e-5
    assert d["published"]["friction_k_Nms"] == pytest.approx(2.2394e-4)
    assert s["rms_fit_m"] < 5e-3 and np.isfinite(s["rms_fit_m"])
    for seg in ("id0", "val0", "val1"):
        for model in ("calibrated", "published"):
            e = s["prediction"][seg][model]
            assert all(np.isfinite(v) for v in e.values()), (seg, model, e)
            # over 0.5-1 s both models follow the swing to well under 0.1 rad
            assert 0.0 < e["rms_rad"] < 0.1, (seg, model, e)
    # the calibrated model fits its own span better than the published one does
    assert s["prediction"]["id0"]["calibrated"]["rms_m"] < s["prediction"]["id0"]["published"][
        "rms_m"]
    h = s["step_halving"]
    assert 0.0 < h["id0_max_rad"] < 0.1 and 0.0 < h["val0_max_rad"] < 0.1
    assert s["noise"]["angle_std_rad"] == pytest.approx(3.5e-5, rel=0.2)
