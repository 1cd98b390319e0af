"""The benchmark scripts run: a smoke run of each in a subprocess (serial only)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.serial_only
def test_bench_assembly_quick():
    """``bench_assembly.py --quick`` exits 0 and prints its table (with or without DOLFINx)."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "bench_assembly.py"), "--quick"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "tets ranks  petsoft tets/s  DOLFINx tets/s  ratio" in proc.stdout, proc.stdout
    assert "1 MPI rank(s)" in proc.stdout
    # The DOLFINx peer either ran (and then was checked against petsoft) or says why not.
    assert "DOLFINx: skipped" in proc.stdout or "K x " in proc.stdout, proc.stdout


@pytest.mark.serial_only
def test_bench_step_quick():
    """``bench_step.py --quick`` exits 0 and prints its table (with or without DOLFINx)."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "bench_step.py"), "--quick"],
        cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "dofs ranks solver" in proc.stdout, proc.stdout
    assert "1 MPI rank(s)" in proc.stdout
    # The DOLFINx peer either ran (and its q1 was compared with petsoft's) or says why not.
    assert "DOLFINx: skipped" in proc.stdout or "correctness (gamg" in proc.stdout, proc.stdout


@pytest.mark.serial_only
def test_bench_gradient_quick():
    """``bench_gradient.py --quick`` exits 0 and prints a row per integrator and parameter count,
    each with the adjoint and forward-sensitivity gradients agreeing."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "bench_gradient.py"), "--quick"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "sens/fwd  adj/fwd" in proc.stdout, proc.stdout
    rows = [line.split() for line in proc.stdout.splitlines()
            if line.split()[:1] in (["be"], ["si"], ["alpha"])]
    assert [(r[0], int(r[1])) for r in rows] == [
        (m, P) for m in ("be", "si", "alpha") for P in (2, 10, 100)], proc.stdout
    assert all(float(r[-1]) < 1e-7 for r in rows), proc.stdout


@pytest.mark.serial_only
def test_bench_linear_solvers_quick():
    """``bench_linear_solvers.py --quick`` exits 0 and prints one row with a time per solver, every
    solver's trajectory matching the default's (the script says when one differs)."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "bench_linear_solvers.py"), "--quick"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "cg-gamg" in proc.stdout and "differs" not in proc.stdout, proc.stdout
    rows = [line.split() for line in proc.stdout.splitlines() if line.split()[:1] == ["144"]]
    assert len(rows) == 1 and rows[0][-1] == "(1.00x)", proc.stdout
