"""The benchmark scripts run: a smoke run of each in a subprocess (serial only)."""

import functools
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@functools.cache
def _dolfinx_missing() -> str | None:
    """Why DOLFINx (dolfinx.fem.petsc, ufl) does not import in a fresh interpreter; None when it
    does."""
    proc = subprocess.run([sys.executable, "-c", "import dolfinx.fem.petsc, ufl"],
                          capture_output=True, text=True, timeout=120)
    return None if proc.returncode == 0 else (proc.stderr.strip().splitlines() or ["?"])[-1]


def _dolfinx_cross_check(stdout: str, ran: str) -> None:
    """The script's DOLFINx peer ran (its check line ``ran`` printed) when DOLFINx imports: a
    "DOLFINx: skipped" then fails. Without DOLFINx the test skips, visibly (pytest -rs)."""
    why = _dolfinx_missing()
    if why is None:
        assert "DOLFINx: skipped" not in stdout and ran in stdout, stdout
        return
    assert "DOLFINx: skipped" in stdout, stdout
    pytest.skip(f"DOLFINx does not import ({why}): the cross-check against DOLFINx did not run "
                "(scripts/bootstrap.sh installs python3-dolfinx-real)")


@pytest.mark.serial_only
def test_bench_assembly_quick():
    """``bench_assembly.py --quick`` exits 0, prints its table and checks DOLFINx's assembly."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "benchmarks" / "bench_assembly.py"), "--quick"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "tets ranks  petsoft tets/s  DOLFINx tets/s  ratio" in proc.stdout, proc.stdout
    assert "1 MPI rank(s)" in proc.stdout
    # the DOLFINx peer ran and was checked against petsoft
    _dolfinx_cross_check(proc.stdout, "K x ")


@pytest.mark.serial_only
def test_bench_step_quick():
    """``bench_step.py --quick`` exits 0, prints its table and compares with DOLFINx's step."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "benchmarks" / "bench_step.py"), "--quick"],
        cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "dofs ranks solver" in proc.stdout, proc.stdout
    assert "1 MPI rank(s)" in proc.stdout
    # the DOLFINx peer ran and its q1 was compared with petsoft's
    _dolfinx_cross_check(proc.stdout, "correctness (gamg")


@pytest.mark.serial_only
def test_bench_multigrid_loop_small():
    """``bench_multigrid_loop.py`` on a small bar: both ways end in the same state (the script
    exits non-zero otherwise), and the kept way sets up fewer hierarchies than steps."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "benchmarks" / "bench_multigrid_loop.py"),
         "--cells", "20", "3", "3", "--steps", "6", "--repeat", "1"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "kept / new =" in proc.stdout, proc.stdout
    kept = next(line for line in proc.stdout.splitlines() if " kept:" in line)
    new = next(line for line in proc.stdout.splitlines() if " new :" in line)
    assert "hierarchies 6," in new, proc.stdout
    assert int(kept.split("hierarchies ")[1].split(",")[0]) < 6, proc.stdout


@pytest.mark.serial_only
def test_bench_gradient_quick():
    """``bench_gradient.py --quick`` exits 0 and prints a row per integrator and parameter count,
    each with the adjoint and forward-sensitivity gradients agreeing."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "benchmarks" / "bench_gradient.py"), "--quick"],
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
        [sys.executable, str(ROOT / "scripts" / "benchmarks" / "bench_linear_solvers.py"),
         "--quick"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "cg-gamg" in proc.stdout and "differs" not in proc.stdout, proc.stdout
    rows = [line.split() for line in proc.stdout.splitlines() if line.split()[:1] == ["144"]]
    assert len(rows) == 1 and rows[0][-1] == "(1.00x)", proc.stdout


def test_bench_diagnose_plane_error_is_the_distance_between_the_planes():
    """The contact case's localisation error: the added plane (point + offset along a non-unit
    normal) against the true level, not the offset alone."""
    import importlib.util

    from petsoft.experiment import experiment_from_dict

    spec = importlib.util.spec_from_file_location(
        "bench_diagnose", ROOT / "scripts" / "benchmarks" / "bench_diagnose.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    data = {"mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [2, 1, 1]}},
            "material": {"model": "linear", "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                         "density": 1000.0},
            "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
            "collider": [{"kind": "plane", "point": [0.3, 0.04, -0.0128],
                          "normal": [0.0, 0.0, 2.0], "offset": 0.0008}]}
    exp = experiment_from_dict(data, source="plane", base_dir=ROOT)
    assert bench.plane_error(exp, -0.012) == pytest.approx(0.0, abs=1e-15)
    assert bench.plane_error(exp, -0.0125) == pytest.approx(0.0005, rel=1e-12)


@pytest.mark.serial_only
def test_bench_reduced_short(tmp_path):
    """``bench_reduced.py`` on 5 steps of the realistic control case (P2): exits 0 and reports
    for its level a basis, an ECSW mesh within the mesh, both reduced runs' errors, and
    (``--sensitivities``) their sensitivities' differences from the full model's."""
    out = tmp_path / "reduced.json"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "benchmarks" / "bench_reduced.py"),
         "--end", "0.01", "--levels", "1", "--sensitivities", "--json", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "times under load" in proc.stdout, proc.stdout
    data = json.loads(out.read_text())
    assert data["steps"] == 5 and data["ranks"] == 1
    (level,) = data["levels"]
    assert 1 <= level["r"] <= level["snapshots"]
    assert 0 < level["ecsw_elements"] <= level["cells"]
    for kind in ("full-assembly", "ecsw"):
        row = level[kind]
        assert set(row["checks"]) == {"train", "E-10%", "E+10%", "damping.mass=2"}
        assert all(0.0 <= c["rms"] <= c["max"] for c in row["checks"].values()), row
    sens = level["sensitivities"]
    assert set(sens) == {"train", "E-10%", "E+10%"}
    for check in sens.values():
        for kind in ("full-assembly", "ecsw"):
            cols = check[kind]["columns"]
            assert set(cols) == {"material.youngs_modulus", "damping.mass", "damping.stiffness"}
            # the reduced columns follow the full ones (a sign or scale error would not)
            assert all(0.0 <= c["difference_rms"] < c["column_rms"] for c in cols.values()), cols
