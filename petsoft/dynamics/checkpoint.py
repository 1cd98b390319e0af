"""Checkpoints of a dynamic simulation: atomic HDF5 files a run restarts from.

A checkpoint holds everything the rest of the run depends on, in file (mesh) numbering so that a
run can restart on any number of ranks: t, step number and step size, q, v, the integrator's
internal state (e.g. the generalized-alpha acceleration), the energy ledger, the probe history,
the experiment text and the mesh. Rank 0 writes it to a temporary name, flushes it to disk and
renames it into place (:mod:`petsoft.atomic`), so a crash (even SIGKILL) during the write leaves
the previous checkpoint as the latest valid one. The two most recent checkpoints are kept.

Layout of ``checkpoint-<step>.h5``::

    /                attrs: format = "petsoft-checkpoint", version, step, time, step_size,
                             integrator, ranks, petsoft_version, complete = 1
    /state/q, /state/v               (N, 3)  file numbering
    /state/z                         (N, 3)  the viscoelastic branch's internal variable
                                             (only when [viscoelastic] ratio > 0)
    /integrator/<name>               (N, 3)  integrator state vectors (file numbering; imex:
                                             its slow modes), or
                                     (k,)    small arrays (imex: the slow modal acceleration
                                             and the modes' eigenvalues)
    /ledger/rows                     (S, 7)  energies so far; attrs dissipated, external_work,
                                             initial
    /probes/time, /probes/displacement       probe history
    /mesh/points, /mesh/tets (the cells: 4 or 10 nodes each)
    /experiment                      the experiment's TOML text
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from petsoft.atomic import atomic_path
from petsoft.errors import PetsoftError
from petsoft.version import __version__

FORMAT = "petsoft-checkpoint"
VERSION = 1
KEEP = 2
_NAME = re.compile(r"^checkpoint-(\d+)\.h5$")

# Fault-injection hook for the tests: "STEP:SECONDS" pauses half-way through writing the
# checkpoint of that step, so a test can SIGKILL the process exactly then. Unset in normal use.
_PAUSE_ENV = "PETSOFT_CHECKPOINT_PAUSE"


def checkpoint_files(directory: Path) -> list[tuple[int, Path]]:
    """Complete checkpoints in a directory, oldest first."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    found = []
    for p in directory.iterdir():
        m = _NAME.match(p.name)
        if m:
            found.append((int(m.group(1)), p))
    return sorted(found)


def write_checkpoint(directory: Path, *, step: int, time: float, step_size: float,
                     integrator: str, fields: dict, integrator_state: dict, ledger,
                     probes: tuple, mesh, experiment_text: str, ranks: int) -> Path:
    """Write a checkpoint atomically (call on rank 0 with gathered arrays)."""
    import h5py

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    final = directory / f"checkpoint-{step:08d}.h5"
    # flushed to disk before the rename and the directory after it: the checkpoint a run
    # restarts from must survive a power loss
    with atomic_path(final, fsync=True) as tmp, h5py.File(tmp, "w") as f:
        f.attrs.update(format=FORMAT, version=VERSION, step=step, time=time,
                       step_size=step_size, integrator=integrator, ranks=ranks,
                       petsoft_version=__version__, complete=0)
        for name, arr in fields.items():
            f[f"state/{name}"] = arr
        for name, arr in integrator_state.items():
            f[f"integrator/{name}"] = arr
        rows = f.create_dataset("ledger/rows", data=ledger.array())
        rows.attrs.update(dissipated=ledger.dissipated, external_work=ledger.external_work,
                          initial=ledger.initial)
        pause = os.environ.get(_PAUSE_ENV, "")
        if pause and int(pause.split(":")[0]) == step:
            f.flush()
            import time as _time

            _time.sleep(float(pause.split(":")[1]))
        times, disp = probes
        f["probes/time"] = np.asarray(times, dtype=float)
        disp = np.asarray(disp, dtype=float)
        f["probes/displacement"] = (disp.reshape(len(times), -1, 3) if disp.size
                                    else np.zeros((len(times), 0, 3)))
        f["mesh/points"] = mesh.points
        f["mesh/tets"] = mesh.cells
        f["experiment"] = experiment_text
        f.attrs["complete"] = 1
    for _, old in checkpoint_files(directory)[:-KEEP]:
        old.unlink(missing_ok=True)
    return final


def read_latest(directory: Path) -> dict:
    """The newest complete checkpoint as a dict of arrays and attributes (call on rank 0).

    Raises
    ------
    PetsoftError
        If the directory holds no complete checkpoint.
    """
    import h5py

    for _, path in reversed(checkpoint_files(directory)):
        try:
            with h5py.File(path, "r") as f:
                if f.attrs.get("format") != FORMAT or int(f.attrs.get("complete", 0)) != 1:
                    continue
                data = {k: f.attrs[k] for k in f.attrs}
                data["path"] = str(path)
                data["fields"] = {k: f["state"][k][()] for k in f["state"]}
                data["integrator_state"] = ({k: f["integrator"][k][()] for k in f["integrator"]}
                                            if "integrator" in f else {})
                data["ledger_rows"] = f["ledger/rows"][()]
                data["ledger"] = dict(f["ledger/rows"].attrs)
                data["probe_times"] = f["probes/time"][()]
                data["probe_displacements"] = f["probes/displacement"][()]
                data["mesh_points"] = f["mesh/points"][()]
                data["mesh_tets"] = f["mesh/tets"][()]
                return data
        except OSError:
            continue  # unreadable (should not happen: files are renamed complete)
    raise PetsoftError(f"{directory}: no complete checkpoint to restart from (run without "
                       "--restart, and set [output] checkpoint_every > 0)")
