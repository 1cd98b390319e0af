"""The cloth demos run (tiny) and pass their own checks: penetration below the stated tolerance,
backward Euler and semi-implicit never gaining energy, Newton and local/global BE agreeing."""

import re
import subprocess
import sys
from pathlib import Path

import pytest
from child_process import child_env  # tests/child_process.py
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
serial_only = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns processes")


def _run(script, out, *args):
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "examples" / script), "--quick",
                        "--out", str(out), *args], capture_output=True, text=True, env=child_env(),
                       timeout=300)
    return r, {line.split()[0]: line.split() for line in r.stdout.splitlines()
               if line.split() and line.split()[0] in ("be", "be-lg", "si", "midpoint", "ere")}


@serial_only
def test_cloth_sphere_demo_quick(tmp_path):
    r, table = _run("demo_cloth_sphere.py", tmp_path, "--methods", "be", "be-lg", "si")
    assert r.returncode == 0, r.stdout + r.stderr
    assert (tmp_path / "energy.png").stat().st_size > 10_000
    assert (tmp_path / "frames-be-lg.png").stat().st_size > 10_000
    for method in ("be", "be-lg", "si"):
        assert (tmp_path / method / "trajectory.xdmf").exists()
        row = table[method]
        assert 0.0 < float(row[1]) <= 2e-2            # contact happened, within tolerance
        assert float(row[2]) <= 1e-9                  # energy never grows
        assert "FAIL" not in " ".join(row)
    cost = re.search(r"Newton ([\d.]+) ms, local/global ([\d.]+) ms.*differ by ([\d.e+-]+) m",
                     r.stdout)
    assert cost, r.stdout
    # no step was retried, so both solve the same step equations: same trajectory
    assert table["be"][4] == table["be-lg"][4] == "0"
    assert float(cost.group(3)) < 1e-5


@serial_only
def test_cloth_mixed_demo_quick(tmp_path):
    r, table = _run("demo_cloth_mixed.py", tmp_path, "--methods", "be", "midpoint")
    assert r.returncode == 0, r.stdout + r.stderr
    assert (tmp_path / "energy.png").stat().st_size > 10_000
    assert (tmp_path / "midpoint" / "trajectory.xdmf").exists()
    assert float(table["be"][2]) <= 1e-9
    # the midpoint rule conserves energy (no numerical damping), backward Euler dissipates
    assert abs(float(table["midpoint"][2])) < 1e-6
