"""An experiment's dynamics from end to end: model, integrator, outputs (``petsoft simulate``).

:class:`~petsoft.dynamics.simulate.Simulation` runs a built model; this module builds the model
(continuum or mass-spring, with the recording whose ``/inputs`` drive ``series`` supports), runs
it, and returns a :class:`SimulationRun` of plain arrays that outlives the PETSc objects. The
command line and the Python API (:func:`petsoft.simulate`) both call :func:`simulate_experiment`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from petsc4py import PETSc

from petsoft.dynamics.factory import build_model
from petsoft.dynamics.simulate import Simulation
from petsoft.results import Result


@dataclass(frozen=True, repr=False)
class SimulationRun(Result):
    """What :func:`simulate_experiment` computed (the same on every rank).

    ``success`` when the run reached ``[time] end`` with a finite state (a diverged step raises
    a :class:`~petsoft.errors.SolverError` instead of returning).

    Attributes
    ----------
    time : float
        The final time (s).
    end : float
        The end time the run was asked for (``[time] end``, s).
    steps, retries, newton_iterations, linear_iterations : int
    wall_time : float
        Seconds.
    displacement, velocity : ndarray (N, 3)
        The final state at the nodes, in the mesh's node order.
    energies : ndarray
        The energy table (one row per output frame: time, kinetic, elastic, ..., see
        :data:`petsoft.dynamics.energy.FIELDS`).
    probe_times : ndarray (S,)
    probe_displacements : ndarray (S, P, 3)
        Displacement at ``[output] probes`` at every step.
    integrator : str
        The scheme that ran.
    """

    time: float
    steps: int
    retries: int
    newton_iterations: int
    linear_iterations: int
    wall_time: float
    displacement: np.ndarray
    velocity: np.ndarray
    energies: np.ndarray
    probe_times: np.ndarray
    probe_displacements: np.ndarray
    integrator: str
    end: float

    @property
    def success(self) -> bool:
        reached = self.time >= self.end * (1 - 1e-9)
        return bool(reached and np.isfinite(self.displacement).all()
                    and np.isfinite(self.velocity).all())

    @property
    def message(self) -> str:
        where = "reached" if self.time >= self.end * (1 - 1e-9) else "stopped before"
        return (f"{where} t = {self.end:g} s ({self.integrator}: {self.steps} steps, "
                f"{self.retries} retries, {self.newton_iterations} Newton iterations)")


def simulate_experiment(experiment, *, out: Path | None = None, integrator: str | None = None,
                        recording=None, restart: bool = False, solver: str = "snes",
                        explicit_scheme: str = "verlet", alpha_backend: str = "petsoft",
                        spd: bool = False, say=None) -> SimulationRun:
    """Integrate ``experiment`` in time; write its outputs into ``out`` (default: the
    experiment's ``[output] directory``). All ranks call.

    Parameters
    ----------
    experiment : Experiment
        With ``[time]``.
    out : Path, optional
    integrator : str, optional
        Overrides ``[time] integrator``.
    recording : Recording or path, optional
        Drives ``series`` supports.
    restart : bool
        Continue from the latest checkpoint in ``out``.
    solver : {"snes", "tao", "local-global"}
    explicit_scheme : {"verlet", "euler"}
    alpha_backend : {"petsoft", "ts"}
    spd : bool
        Clamped spring Jacobians (mass-spring models).
    say : callable(str), optional
        Progress lines (rank 0).
    """
    comm = PETSc.COMM_WORLD
    out = Path(out) if out is not None else Path(experiment.output.directory)

    def tell(line: str) -> None:
        if say is not None and comm.rank == 0:
            say(line)

    model = build_model(experiment, comm, recording)
    sim = Simulation(model, experiment, integrator=integrator, solver=solver, out=out,
                     monitor=tell, explicit_scheme=explicit_scheme,
                     alpha_backend=alpha_backend, spd=spd)
    try:
        result = sim.run(restart=restart)
        gather = model.dmesh.gather_global   # DistributedMesh or a mass-spring NodeLayout
        mpi = comm.tompi4py()
        q = mpi.bcast(gather(result.q), root=0)
        v = mpi.bcast(gather(result.v), root=0)
        run = SimulationRun(
            time=float(result.time), steps=int(result.steps), retries=int(result.retries),
            newton_iterations=int(result.newton_iterations),
            linear_iterations=int(result.linear_iterations), wall_time=float(result.wall_time),
            displacement=np.asarray(q).reshape(-1, 3), velocity=np.asarray(v).reshape(-1, 3),
            energies=np.asarray(mpi.bcast(result.energies, root=0)),
            probe_times=np.asarray(mpi.bcast(result.probe_times, root=0)),
            probe_displacements=np.asarray(mpi.bcast(result.probe_displacements, root=0)),
            integrator=sim.name, end=float(experiment.time.end))
    finally:
        sim.destroy()
    tell(f"t = {run.time:g} s after {run.steps} steps ({run.retries} retried), "
         f"{run.newton_iterations} Newton / {run.linear_iterations} linear iterations, "
         f"{run.wall_time:.3g} s; wrote {out}/")
    return run
