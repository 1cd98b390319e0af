"""The demo scripts run (small) and produce their figures and outputs."""

import subprocess
import sys
from pathlib import Path

import pytest
from child_process import child_env  # tests/child_process.py
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
serial_only = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns processes")


@serial_only
def test_twisted_bar_demo_quick(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "examples" / "demo_twisted_bar.py"),
                        "--quick",
                        "--out", str(tmp_path), "--methods", "be", "midpoint"],
                       capture_output=True, text=True, env=child_env(), timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert (tmp_path / "energy.png").stat().st_size > 10_000
    assert (tmp_path / "midpoint" / "trajectory.xdmf").exists()
    table = {line.split()[0]: float(line.split()[1]) for line in r.stdout.splitlines()
             if line.split() and line.split()[0] in ("be", "midpoint")}
    assert table["midpoint"] == pytest.approx(1.0, abs=1e-6)   # no numerical damping
    assert table["be"] < table["midpoint"]                       # backward Euler damps
