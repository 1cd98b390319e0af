"""The declared layering holds: no module imports from a higher layer or from a package of its
own layer, and no private name crosses modules (scripts/tools/architecture.py --check); and the
check itself catches a violation."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "scripts" / "tools" / "architecture.py"

pytestmark = pytest.mark.serial_only


def _check(root: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(TOOL), "--root", str(root), "--check"],
                          capture_output=True, text=True, timeout=120)


def test_the_package_follows_its_layers():
    run = _check(ROOT)
    assert run.returncode == 0, run.stdout


def test_the_check_fails_on_an_upward_import(tmp_path):
    shutil.copytree(ROOT / "petsoft", tmp_path / "petsoft",
                    ignore=shutil.ignore_patterns("*.so", "__pycache__"))
    bad = tmp_path / "petsoft" / "mesh" / "serial.py"
    bad.write_text(bad.read_text() + "\nfrom petsoft.diagnosis.report import PHYSICS  # noqa\n")
    run = _check(tmp_path)
    assert run.returncode == 1
    assert "up       petsoft.mesh.serial" in run.stdout
