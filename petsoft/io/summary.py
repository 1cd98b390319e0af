"""`summary.json`: what every command writes beside its results (formats.md section 1)."""

from __future__ import annotations

import json
from pathlib import Path

from petsc4py import PETSc

from petsoft.atomic import write_text
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
    # readable by everyone whatever the umask: a summary is for everyone to read
    return write_text(directory / "summary.json", json.dumps(data, indent=2) + "\n",
                      mode=0o644)
