"""`summary.json`: what every command writes beside its results (formats.md section 1)."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from petsc4py import PETSc

from petsoft.version import __version__


def write_summary(directory: Path, command: str, results: dict, solver: dict, wall_time: float,
                  comm: PETSc.Comm) -> Path | None:
    """Write summary.json atomically on rank 0; returns its path there."""
    if comm.rank != 0:
        return None
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    data = {
        "command": command,
        "petsoft_version": __version__,
        "petsc_version": ".".join(map(str, PETSc.Sys.getVersion())),
        "ranks": comm.size,
        "wall_time_s": wall_time,
        "solver": solver,
        **results,
    }
    path = directory / "summary.json"
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=".summary.", suffix=".json")
    with os.fdopen(fd, "w") as f:
        json.dump(data, f, indent=2)
        f.write("\n")
    os.chmod(tmp, 0o644)  # mkstemp creates 0600; a summary is for everyone to read
    os.replace(tmp, path)
    return path
