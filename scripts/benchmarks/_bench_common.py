"""Helpers shared by the benchmark scripts (rank-0 printing, timing, DOLFINx import, dof matching).

Import this module only after ``petsc4py.init(...)`` when PETSc options matter: it imports
mpi4py (not petsc4py) at import time, and DOLFINx only inside :func:`import_dolfinx`.
"""

from __future__ import annotations

import logging
import sys
import time

import numpy as np
from mpi4py import MPI

COMM = MPI.COMM_WORLD
RANK, NRANKS = COMM.rank, COMM.size


def say(*args, **kwargs) -> None:
    """Print on rank 0 only."""
    if RANK == 0:
        print(*args, **kwargs, flush=True)


def wall(fn) -> float:
    """Wall time of one collective call of ``fn``: barrier before, max over ranks."""
    COMM.Barrier()
    t0 = time.perf_counter()
    fn()
    return COMM.allreduce(time.perf_counter() - t0, op=MPI.MAX)


def timed_interleaved(fns: list, repeat: int, report=None) -> list[np.ndarray]:
    """``repeat`` rounds, each calling every function of ``fns`` once (in turn, so slow phases of
    a shared machine hit all of them alike); returns each function's wall times.
    ``report(round, k, seconds)`` is called after each (outside the timing)."""
    times = [np.empty(repeat) for _ in fns]
    for i in range(repeat):
        for k, fn in enumerate(fns):
            times[k][i] = wall(fn)
            if report is not None:
                report(i, k, times[k][i])
    return times


def progress(*args) -> None:
    """A progress line on rank 0's stderr (long runs say what they are doing)."""
    if RANK == 0:
        print("[progress]", *args, file=sys.stderr, flush=True)


def setup_clock():
    """A stopwatch for collective set-up phases (barrier, then max over ranks)."""
    COMM.Barrier()
    t0 = time.perf_counter()

    def stop() -> float:
        return COMM.allreduce(time.perf_counter() - t0, op=MPI.MAX)

    return stop


def import_dolfinx():
    """(dolfinx modules (dolfinx, ufl), None) when DOLFINx imports, else (None, the reason)."""
    try:
        import dolfinx
        import dolfinx.fem.petsc
        import dolfinx.nls.petsc
        import ufl
    except Exception as exc:  # ImportError, or a PETSc/MPI mismatch at import time
        return None, f"{type(exc).__name__}: {exc}"
    # FFCx installs a root log handler and the JIT's setuptools build logs every compiler
    # command at INFO through it: keep warnings and errors only.
    for handler in logging.getLogger().handlers:
        handler.addFilter(lambda record: record.levelno >= logging.WARNING)
    return (dolfinx, ufl), None


def match_points(ref: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Index into ``ref`` of each row of ``query`` with the same coordinates (vectorised)."""
    tol = 1e-9 * float(np.ptp(ref, axis=0).max())
    keys = np.round(np.concatenate([ref, query[:, :3]]) / tol).astype(np.int64)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    ref_of_key = np.full(inverse.max() + 1, -1, np.int64)
    ref_of_key[inverse[: len(ref)]] = np.arange(len(ref))
    found = ref_of_key[inverse[len(ref):]]
    if (found < 0).any() or np.abs(ref[found] - query[:, :3]).max() > 10 * tol:
        raise RuntimeError("DOLFINx dof coordinates do not match the mesh vertices")
    return found


def gather_owned(ids: np.ndarray, values: np.ndarray, n: int) -> np.ndarray | None:
    """Owned rows of every rank gathered on rank 0 into an (n, k) array indexed by ``ids``."""
    parts = COMM.gather((ids, np.array(values)), root=0)
    if RANK != 0:
        return None
    out = np.full((n,) + np.shape(values)[1:], np.nan)
    for i, v in parts:
        out[i] = v
    return out
