"""Multi-start: local minimizations from many starts, run in parallel on groups of ranks.

The calibration misfit is not convex (an oscillation fitted with the wrong frequency or phase
sits in a wrong basin), and every optimizer in :mod:`petsoft.calibration.optimize` is local. The
lecture's remedy is to start from many random points and keep the best. This module owns that:
the communicator is split into groups (``MPI.Comm.Split``), each group builds its own problem on
its sub-communicator, runs the starts assigned to it round-robin, and the results of all starts
are gathered on every rank. Each start is deterministic, so the best answer does not depend on
the number of ranks or groups.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from mpi4py import MPI

from petsoft.calibration.groups import map_on_groups
from petsoft.calibration.optimize import OptimizationError, OptimizeResult, minimize


@dataclass
class StartResult:
    """One start's outcome: its index, the group that ran it, and the optimizer result."""

    index: int
    group: int
    start: np.ndarray
    result: OptimizeResult | None
    error: str = ""


@dataclass
class MultistartResult:
    """All starts (in start order) and the best one (lowest objective; ties: lowest index)."""

    best: StartResult
    starts: list[StartResult]
    groups: int

    @property
    def z(self) -> np.ndarray:
        return self.best.result.z

    @property
    def p(self) -> np.ndarray:
        return self.best.result.p

    @property
    def f(self) -> float:
        return self.best.result.f


def random_starts(lower, upper, count: int, seed: int = 0, include=None) -> np.ndarray:
    """Starts uniform in the scaled box [lower, upper] (log-uniform in p for log parameters).

    Parameters
    ----------
    lower, upper : array_like, shape (n,)
        Finite bounds in z (e.g. ``scaling.bounds()``).
    count : int
        Number of random starts.
    seed : int
        Seed of numpy's default generator (same starts on every rank and every run).
    include : array_like, shape (n,), optional
        A start put first (e.g. the user's initial guess, z = 0).

    Returns
    -------
    ndarray, shape (count (+1), n)
    """
    lo = np.asarray(lower, dtype=float).reshape(-1)
    hi = np.asarray(upper, dtype=float).reshape(-1)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        bad = np.flatnonzero(~(np.isfinite(lo) & np.isfinite(hi))).tolist()
        raise OptimizationError(
            f"random starts need finite bounds; parameters {bad} have an infinite bound: give "
            "them lower and upper bounds (in physical units) in the scaling")
    rng = np.random.default_rng(seed)
    starts = lo + (hi - lo) * rng.random((int(count), lo.size))
    if include is not None:
        starts = np.vstack([np.clip(np.asarray(include, float).reshape(1, -1), lo, hi), starts])
    return starts


def multistart(make_problem: Callable, starts: Sequence, comm=None, method: str = "lbfgs",
               bounds=None, options: dict | None = None, scaling=None, groups: int | None = None,
               prefix: str = "cal_", monitor_factory: Callable | None = None,
               solver_options=None) -> MultistartResult:
    """Minimize from every start on groups of ranks; the best result and all results everywhere.

    Parameters
    ----------
    make_problem : callable(subcomm) -> LeastSquaresProblem
        Builds one group's problem on its sub-communicator (called once per group, collectively).
    starts : array_like, shape (k, n)
        Start points in z; start i runs on group ``i % groups``.
    comm : mpi4py.MPI.Comm, optional
        Communicator of all the ranks (default ``COMM_WORLD``); call collectively.
    method, bounds, options, scaling, prefix, solver_options
        Passed to :func:`petsoft.calibration.optimize.minimize`.
    groups : int, optional
        Number of groups (default: one per rank; at most the number of ranks). Ranks
        ``r * groups // size`` form group r's sub-communicator.
    monitor_factory : callable(index, subcomm) -> monitor, optional
        Gives a per-start monitor (e.g. progress lines).

    Returns
    -------
    MultistartResult
        Identical on every rank.

    Raises
    ------
    OptimizationError
        When every start failed (the messages are included), on every rank.
    """
    comm = MPI.COMM_WORLD if comm is None else comm
    size = comm.Get_size()
    ngroups = size if groups is None else max(1, min(int(groups), size))
    starts = np.atleast_2d(np.asarray(starts, dtype=float))

    def run(i: int, sub, problem) -> OptimizeResult:
        # A start that fails (e.g. the forward model breaks far from the data) raises a
        # PetsoftError on every rank of its group (evaluations are synchronized): map_on_groups
        # records it and the other starts go on.
        mon = monitor_factory(i, sub) if monitor_factory is not None else None
        return minimize(problem, starts[i], method=method, bounds=bounds, options=options,
                        monitor=mon, scaling=scaling, prefix=prefix,
                        solver_options=solver_options)

    try:
        tasks = map_on_groups(run, list(range(len(starts))), comm, groups=ngroups,
                              setup=make_problem)
    except RuntimeError as err:
        raise RuntimeError(f"multistart failed: {err}") from err
    ngroups = max(1, min(ngroups, len(starts)))
    results = [StartResult(t.index, t.group, starts[t.index].copy(), t.value, t.error)
               for t in tasks]
    ok = [s for s in results if s.result is not None and np.isfinite(s.result.f)]
    if not ok:
        raise OptimizationError(
            "multistart: every start failed: "
            + "; ".join(f"start {s.index}: {s.error or 'non-finite objective'}" for s in results))
    best = min(ok, key=lambda s: (s.result.f, s.index))
    return MultistartResult(best, results, ngroups)
