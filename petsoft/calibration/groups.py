"""Independent tasks run concurrently on groups of MPI ranks (sub-communicators).

:func:`map_on_groups` splits a communicator into groups (``MPI.Comm.Split``), gives task i to group
``i % groups``, and gathers every task's result on every rank, in task order. It is what
multi-start calibration and the diagnosis' candidate fits use: each task builds its own PETSc
objects on its group's communicator, so the tasks never synchronise with each other, and the
answer does not depend on how many groups there are (each task is deterministic).
``one_rank_each`` makes every group a single rank even when there are fewer tasks than ranks
(the ranks without a task wait): for a model so small that one rank runs it faster than several
together (the diagnosis' :meth:`~petsoft.diagnosis.context.Diagnosis.one_rank_each`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from mpi4py import MPI

from petsoft.errors import PetsoftError


@dataclass
class TaskResult:
    """The outcome of one task: ``value`` (None when it failed) or the user-level ``error``."""

    index: int
    group: int
    value: Any = None
    error: str = ""

    @property
    def ok(self) -> bool:
        return not self.error


def _mpi(comm) -> MPI.Comm:
    if comm is None:
        return MPI.COMM_WORLD
    return comm.tompi4py() if hasattr(comm, "tompi4py") else comm


def map_on_groups(task: Callable[[Any, MPI.Comm], Any], items: Sequence, comm=None,
                  groups: int | None = None, setup: Callable[[MPI.Comm], Any] | None = None,
                  one_rank_each: bool = False) -> list[TaskResult]:
    """Run ``task(item, subcomm)`` for every item on groups of ranks; results on every rank.

    Parameters
    ----------
    task : callable(item, subcomm) -> picklable
        Called collectively by the ranks of one group (``subcomm``: an mpi4py communicator; use
        ``PETSc.Comm(subcomm)`` for PETSc objects). With ``setup``, called as
        ``task(item, subcomm, state)``.
    items : sequence
    comm : mpi4py or petsc4py communicator, optional
        All the ranks (default ``COMM_WORLD``); call collectively.
    groups : int, optional
        Number of groups (default: one per rank, at most one per item, at least 1).
    setup : callable(subcomm) -> state, optional
        Called once per group before its tasks (e.g. to build a shared problem).
    one_rank_each : bool
        One group per rank, whatever the number of items (``groups`` is then ignored): a
        single task runs on the first rank alone while the others wait for its result.

    Returns
    -------
    list of TaskResult
        One per item, in item order, identical on every rank. A task raising a
        :class:`~petsoft.errors.PetsoftError` gives a result with ``error`` set (the other tasks
        go on); any other exception is re-raised on every rank after the gather, so that one
        group's bug cannot leave the others waiting.
    """
    comm = _mpi(comm)
    size, rank = comm.Get_size(), comm.Get_rank()
    ngroups = (size if one_rank_each else
               max(1, min(size if groups is None else int(groups), size, max(len(items), 1))))
    color = rank * ngroups // size
    sub = comm.Split(color, rank) if ngroups > 1 else comm
    local: list[TaskResult] = []
    bug = ""
    try:
        state = setup(sub) if setup is not None else None
        for i in range(color, len(items), ngroups):
            try:
                value = (task(items[i], sub) if setup is None else task(items[i], sub, state))
                local.append(TaskResult(i, color, value))
            except PetsoftError as err:
                # every rank of the group raised it (the group's computations are collective)
                local.append(TaskResult(i, color, None, str(err) or type(err).__name__))
    except Exception as err:  # noqa: BLE001 - re-raised on every rank after the gather
        bug = f"group {color}, rank {rank}: {type(err).__name__}: {err}"
    if ngroups == 1:
        bugs = [b for b in comm.allgather(bug) if b]
        if bugs:
            raise RuntimeError("tasks failed: " + "; ".join(bugs))
        return local
    gathered = comm.allgather((local if sub.Get_rank() == 0 else [], bug))
    sub.Free()
    bugs = [b for _, b in gathered if b]
    if bugs:
        raise RuntimeError("tasks on groups failed: " + "; ".join(bugs))
    return sorted((r for part, _ in gathered for r in part), key=lambda r: r.index)
