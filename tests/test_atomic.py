"""petsoft.atomic: one home for "write a file so that a reader never sees half of it".

1. The rule: while the block runs the target is the old file (or absent); the new file appears
   whole at the end; an exception, or a failed rename, leaves the old file (or none) and no
   temporary; the permissions are the umask's or the ones asked for; ``fsync`` flushes the file
   and its directory; an HDF5 file is written through the temporary like any other.
2. Every writer of petsoft goes through it: each one, made to fail at the rename, raises and
   leaves the old file untouched and no temporary (a writer that wrote its target directly would
   have changed it, or not failed); and no module but petsoft.atomic renames a file into place.

Rank-local file work: serial only.
"""

from __future__ import annotations

import os
import re
import types
from pathlib import Path

import h5py
import numpy as np
import pytest
from petsc4py import PETSc
from test_diagnosis_analysis import example_report

from petsoft.atomic import atomic_path, temporaries, write_bytes, write_text

pytestmark = pytest.mark.serial_only

ROOT = Path(__file__).resolve().parents[1]


def _temporaries(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.endswith(".tmp"))


@pytest.fixture
def umask():
    """Set the process's umask for a test (restored after)."""
    old = os.umask(0o022)
    os.umask(old)
    yield lambda mask: os.umask(mask)
    os.umask(old)


# -- 1. the rule ----------------------------------------------------------------------------------
def test_the_target_is_old_until_the_block_ends_then_new(tmp_path):
    target = tmp_path / "out.json"
    target.write_text("old")
    with atomic_path(target) as tmp:
        tmp.write_text("new, half")
        # a reader meanwhile: the old file, whole
        assert target.read_text() == "old"
        assert tmp.parent == tmp_path and tmp != target and tmp.name.startswith(".")
        assert temporaries(re.escape(target.name)).fullmatch(tmp.name)
        tmp.write_text("new, whole")
    assert target.read_text() == "new, whole"
    assert _temporaries(tmp_path) == []


@pytest.mark.parametrize("old", [None, "old"])
def test_an_exception_leaves_the_old_file_or_none_and_no_temporary(tmp_path, old):
    target = tmp_path / "out.txt"
    if old is not None:
        target.write_text(old)
    with pytest.raises(RuntimeError, match="half-way"), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("half-way")
    assert (target.read_text() if target.exists() else None) == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ([] if old is None else ["out.txt"])


def test_a_failed_rename_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    target = tmp_path / "out.txt"
    target.write_text("old")

    def failing(src, dst):
        raise OSError("rename failed (simulated)")

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(OSError, match="simulated"):
        write_text(target, "new")
    monkeypatch.undo()
    assert target.read_text() == "old" and _temporaries(tmp_path) == []


def test_permissions_are_the_umask_s_or_the_ones_asked_for(tmp_path, umask):
    umask(0o077)
    assert (write_text(tmp_path / "a", "x").stat().st_mode & 0o777) == 0o600
    assert (write_text(tmp_path / "b", "x", mode=0o644).stat().st_mode & 0o777) == 0o644
    umask(0o022)
    assert (write_bytes(tmp_path / "c", b"x").stat().st_mode & 0o777) == 0o644
    # a replaced file takes the new one's permissions, as a file written anew
    (tmp_path / "d").write_text("old")
    (tmp_path / "d").chmod(0o600)
    assert (write_text(tmp_path / "d", "x").stat().st_mode & 0o777) == 0o644


@pytest.mark.parametrize("fsync", [False, True])
def test_fsync_flushes_the_file_before_the_rename_and_the_directory_after(
        tmp_path, monkeypatch, fsync):
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync_spy(fd):
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    def replace_spy(src, dst):
        events.append(("replace", str(dst)))
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync_spy)
    monkeypatch.setattr(os, "replace", replace_spy)
    target = tmp_path / "out.txt"
    write_text(target, "new", fsync=fsync)
    monkeypatch.undo()
    if not fsync:
        assert events == [("replace", str(target))]
    else:
        (_, file), replaced, (_, directory) = events
        assert Path(file).parent == tmp_path and Path(file).name.endswith(".tmp")
        assert replaced == ("replace", str(target)) and directory == str(tmp_path)


def test_an_hdf5_file_through_the_temporary(tmp_path):
    target = tmp_path / "data.h5"
    with atomic_path(target) as tmp, h5py.File(tmp, "w") as f:
        f["x"] = np.arange(3.0)
    with h5py.File(target, "r") as f:
        np.testing.assert_array_equal(f["x"][()], np.arange(3.0))
    with pytest.raises(KeyError), atomic_path(target) as tmp, h5py.File(tmp, "w") as f:
        f["y"] = np.arange(4.0)
        raise KeyError("while writing")
    with h5py.File(target, "r") as f:
        assert list(f) == ["x"]
    assert _temporaries(tmp_path) == []


def test_the_temporaries_pattern_is_the_names_given():
    pat = temporaries(r"\d+\.h5")
    assert pat.fullmatch(".12.h5.0a1b2c3d.tmp")
    for name in ("12.h5", ".12.h5.tmp", ".x.h5.0a1b2c3d.tmp", ".12.h5.notes.tmp",
                 ".12.h5.0a1b2c3d.tmp.bak"):
        assert not pat.fullmatch(name), name


# -- 2. every writer goes through it --------------------------------------------------------------
def _mesh():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1.0]])
    return pts, np.array([[0, 1, 2, 3], [1, 2, 3, 4]])


def _report_json(d):
    from petsoft.diagnosis.report import write_report
    write_report(d / "report.json", example_report())


def _report_md(d):
    from petsoft.diagnosis.report import write_report_md
    write_report_md(d / "report.md", example_report())


def _report_html(d):
    from petsoft.diagnosis.html import write_report_html
    write_report_html(d / "report.html", d / "source.md")


def _summary(d):
    from petsoft.io.summary import write_summary
    write_summary(d, "simulate", {}, {}, 1.0, PETSc.COMM_SELF)


def _recording(d):
    from petsoft.io.recording import write_recording
    write_recording(d / "r.h5", np.zeros((2, 3)), np.array([0.0, 1.0]), np.zeros((2, 2, 3)))


def _checkpoint(d):
    from petsoft.dynamics.checkpoint import write_checkpoint
    ledger = types.SimpleNamespace(dissipated=0.0, external_work=0.0, initial=0.0,
                                   array=lambda: np.zeros((1, 7)))
    pts, tets = _mesh()
    write_checkpoint(d, step=1, time=0.1, step_size=0.1, integrator="be",
                     fields={"q": pts, "v": pts}, integrator_state={}, ledger=ledger,
                     probes=([0.0], np.zeros(0)), mesh=types.SimpleNamespace(points=pts,
                                                                            cells=tets),
                     experiment_text="", ranks=1)


def _xdmf_series(d):
    from petsoft.io.xdmf import XdmfWriter
    XdmfWriter(d / "run.xdmf", *_mesh())


def _xdmf_static(d):
    from petsoft.io.xdmf import write_xdmf
    write_xdmf(d / "s.xdmf", *_mesh())


def _experiment_update(d):
    from petsoft.experiment import load_experiment, with_parameters
    from petsoft.experiment.writer import write_experiment_update
    exp = load_experiment(ROOT / "scripts" / "examples" / "cantilever.toml")
    write_experiment_update(exp, with_parameters(exp, {"material.youngs_modulus": 5e6}),
                            d / "e.toml")


def _experiment_file(d):
    from petsoft.experiment import load_experiment
    from petsoft.experiment.writer import write_toml
    write_toml(load_experiment(ROOT / "scripts" / "examples" / "cantilever.toml"), d / "w.toml")


#: Every writer of petsoft that writes a file as a whole, and that file (in the directory given).
#: (An .xdmf document is removed before its series or static grid is written, by design: its
#: temporary and rename are tests/test_xdmf.py's test_failure_while_updating_xdmf.)
WRITERS = {
    "report.json": (_report_json, "report.json"),
    "report.md": (_report_md, "report.md"),
    "report.html": (_report_html, "report.html"),
    "summary.json": (_summary, "summary.json"),
    "recording": (_recording, "r.h5"),
    "checkpoint": (_checkpoint, "checkpoint-00000001.h5"),
    "xdmf series mesh file": (_xdmf_series, "run.h5"),
    "xdmf static data": (_xdmf_static, "s.h5"),
    "edited experiment": (_experiment_update, "e.toml"),
    "experiment file": (_experiment_file, "w.toml"),
}


@pytest.mark.parametrize("name", list(WRITERS))
def test_every_writer_leaves_its_old_file_whole_when_the_rename_fails(tmp_path, monkeypatch,
                                                                      name):
    write, target = WRITERS[name]
    (tmp_path / "source.md").write_text("# Diagnosis report\n\nIn short.\n")
    old = b"the old file, whole\n"
    (tmp_path / target).write_bytes(old)

    def failing(src, dst):
        raise OSError("rename failed (simulated)")

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(OSError, match="simulated"):
        write(tmp_path)
    monkeypatch.undo()
    assert (tmp_path / target).read_bytes() == old, f"{name} wrote {target} in place"
    assert _temporaries(tmp_path) == []
    # and written for real: the new file, no temporary
    write(tmp_path)
    assert (tmp_path / target).read_bytes() != old
    assert _temporaries(tmp_path) == []


def test_no_module_but_petsoft_atomic_renames_a_file_into_place():
    homes = [p.relative_to(ROOT).as_posix() for p in (ROOT / "petsoft").rglob("*.py")
             if re.search(r"os\.(replace|rename)\(", p.read_text())]
    assert homes == ["petsoft/atomic.py"]


def test_no_module_writes_a_file_in_place():
    """Path.write_text/write_bytes, open(..., "w") and h5py.File(..., "w") appear in petsoft only
    on a temporary of :func:`petsoft.atomic.atomic_path` (named ``tmp``): a writer that wrote its
    target in place would leave a half file that looks whole when killed."""
    in_place = re.compile(r"""(?P<who>[\w.()/" ]+)\.write_(?:text|bytes)\("""
                          r"""|open\((?P<a>[^,)]+),\s*["'][wa]"""
                          r"""|h5py\.File\((?P<b>[^,)]+),\s*["'][wa]""")
    found = []
    for p in (ROOT / "petsoft").rglob("*.py"):
        if p.name == "atomic.py":
            continue
        for n, line in enumerate(p.read_text().splitlines(), 1):
            for m in in_place.finditer(line):
                target = (m.group("who") or m.group("a") or m.group("b")).strip()
                if target != "tmp":
                    found.append(f"{p.relative_to(ROOT)}:{n}: {line.strip()}")
    assert found == []
