"""A missing Debian-packaged module (petsc4py, slepc4py, mpi4py, h5py) is named with its Debian
package before any work; slepc4py only where modes are computed; unused PETSc options are
reported at the end of a run; a CSV or C3D file given as a recording points to `petsoft import`."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from child_process import child_env

from petsoft.dependencies import DEBIAN, PURPOSE, MissingDependencyError, missing, require

ROOT = Path(__file__).resolve().parents[1]

TINY = """
[mesh]
box = { size = [0.1, 0.02, 0.02], cells = [2, 1, 1] }
[material]
model = "linear"
youngs_modulus = 1.0e6
poisson_ratio = 0.3
density = 1000.0
[gravity]
acceleration = [0.0, 0.0, -9.81]
[[boundary]]
kind = "fixed"
where = "x < 1e-9"
"""

# A child that cannot import the named module: a meta-path finder placed first refuses it, as a
# Python without the Debian package would.
BLOCKED_RUN = """
import importlib.abc, sys
class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] == {blocked!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
sys.meta_path.insert(0, Refuse())
from petsoft.cli.main import main
sys.exit(main({argv!r}))
"""


def _run_without(blocked: str, argv: list[str]) -> subprocess.CompletedProcess:
    code = textwrap.dedent(BLOCKED_RUN.format(blocked=blocked, argv=argv))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=child_env(), timeout=300, cwd=ROOT)


@pytest.fixture()
def tiny(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    return path


def test_the_debian_packages_are_the_ones_packaging_declares():
    from test_packaging import FROM_DEBIAN

    assert set(DEBIAN) == FROM_DEBIAN
    assert DEBIAN["h5py"] == "python3-h5py-mpi"        # Debian's MPI build, not PyPI's wheel


def test_require_names_every_missing_module_and_its_package(monkeypatch):
    assert missing(["petsc4py", "mpi4py", "h5py", "slepc4py"]) == []
    # a real absence: a name no Python has, registered as if it were a Debian module
    monkeypatch.setitem(DEBIAN, "no_such_module_xyz", "python3-no-such")
    monkeypatch.setitem(PURPOSE, "no_such_module_xyz", "nothing")
    with pytest.raises(MissingDependencyError, match="a test needs no_such_module_xyz") as err:
        require(["petsc4py", "no_such_module_xyz"], "a test")
    assert "apt-get install python3-no-such" in str(err.value)
    assert "petsc4py" not in str(err.value).split("needs")[1].split("which")[0]
    assert isinstance(err.value, ImportError)


@pytest.mark.serial_only
@pytest.mark.parametrize("blocked", ["petsc4py", "mpi4py", "h5py"])
def test_static_without_a_module_says_which_package_before_any_work(tiny, tmp_path, blocked):
    out = tmp_path / "out"
    run = _run_without(blocked, ["static", str(tiny), "--out", str(out)])
    assert run.returncode == 2, run.stderr[-2000:]
    assert f"apt-get install {DEBIAN[blocked]}" in run.stderr
    assert "Traceback" not in run.stderr
    assert not out.exists()                         # nothing was solved nor written


@pytest.mark.serial_only
def test_slepc4py_is_needed_only_for_modes(tiny, tmp_path):
    static = _run_without("slepc4py", ["static", str(tiny), "--out", str(tmp_path / "s")])
    assert static.returncode == 0, static.stderr[-2000:]
    assert (tmp_path / "s" / "summary.json").is_file()
    modes = _run_without("slepc4py", ["modes", str(tiny), "--out", str(tmp_path / "m")])
    assert modes.returncode == 2
    assert "petsoft modes needs slepc4py" in modes.stderr
    assert "apt-get install python3-slepc4py-real" in modes.stderr
    assert not (tmp_path / "m").exists()


@pytest.mark.serial_only
def test_a_misspelled_petsc_option_is_reported_at_the_end(tiny, tmp_path):
    run = subprocess.run([sys.executable, "-m", "petsoft", "static", str(tiny), "--out",
                          str(tmp_path), "-ksp_tyep", "cg", "-snes_rtol", "1e-9"],
                         capture_output=True, text=True, env=child_env(), timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    warning = [ln for ln in run.stderr.splitlines() if "never used" in ln]
    assert len(warning) == 1 and "-ksp_tyep cg" in warning[0]
    assert "-snes_rtol" not in warning[0]           # read by the SNES: used


def test_unused_options_lists_what_no_rank_read():
    from petsc4py import PETSc

    from petsoft.solvers.options import clear_options, unused_options

    opts = PETSc.Options()
    opts.setValue("petsoft_test_never_read", "3")
    opts.setValue("petsoft_test_read", "4")
    try:
        assert opts.getInt("petsoft_test_read") == 4
        unused = unused_options()
        assert "-petsoft_test_never_read 3" in unused
        assert not any(u.startswith("-petsoft_test_read") for u in unused)
    finally:
        clear_options(["petsoft_test_never_read", "petsoft_test_read"])


@pytest.mark.parametrize("name, content, kind", [
    ("markers.csv", b"time,a_x,a_y,a_z\n0,1,2,3\n", "CSV"),
    ("markers.dat", b"time,a_x,a_y,a_z\n0,1,2,3\n", "CSV"),
    ("walk.c3d", (ROOT / "tests/data/c3d/c3d_float_m.c3d").read_bytes(), "C3D"),
])
def test_a_marker_file_given_as_a_recording_points_to_import(tmp_path, name, content, kind):
    from petsoft.io.recording import RecordingError, read_recording

    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(RecordingError, match=f"a {kind} marker file.*petsoft import"):
        read_recording(path)


def test_a_file_that_is_neither_still_says_what_a_recording_is(tmp_path):
    from petsoft.io.recording import RecordingError, read_recording

    path = tmp_path / "x.h5"
    path.write_bytes(b"\x00\x01 binary junk")
    with pytest.raises(RecordingError, match="not an HDF5 file.*petsoft import"):
        read_recording(path)
