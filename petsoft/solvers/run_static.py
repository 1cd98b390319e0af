"""An experiment's quasistatic problem from end to end: model, solve, outputs (``petsoft static``).

:class:`~petsoft.solvers.static.StaticSolver` solves a built model; this module builds the model
from an experiment, runs the solver, gathers the displacement to every rank, evaluates the probes
and, when asked, writes ``displacement.xdmf``/``.h5`` and ``summary.json``. The command line and
the Python API (:func:`petsoft.static`) both call :func:`solve_experiment`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from petsc4py import PETSc

from petsoft.io.summary import write_summary
from petsoft.io.xdmf import write_xdmf
from petsoft.mesh.probes import embed, interpolate
from petsoft.physics.model import build_model
from petsoft.solvers.options import SolverOptions
from petsoft.solvers.static import StaticSolver


@dataclass(frozen=True)
class StaticOutcome:
    """What :func:`solve_experiment` found (the same on every rank).

    Attributes
    ----------
    mesh : petsoft.mesh.serial.Mesh
        The serial mesh the displacement lives on.
    displacement : ndarray (N, 3)
    probes : ndarray (P, 3)
        Displacement at the experiment's ``[output] probes`` (shape (0, 3) without probes).
    newton_iterations, linear_iterations, load_steps, retries : int
    ksp_type, pc_type : str
        The linear solver that ran.
    """

    mesh: object
    displacement: np.ndarray
    probes: np.ndarray
    newton_iterations: int
    linear_iterations: int
    load_steps: int
    retries: int
    ksp_type: str
    pc_type: str


def solve_experiment(experiment, *, out: Path | None = None, method: str = "snes",
                     load_steps: int = 1, spd: bool = False, command: str = "static",
                     say=None) -> StaticOutcome:
    """Solve ``experiment``'s quasistatic problem; write its outputs into ``out`` if given.

    Parameters
    ----------
    experiment : Experiment
    out : Path, optional
        Output directory for ``displacement.xdmf``/``.h5`` and ``summary.json``.
    method : {"snes", "tao"}
    load_steps : int
    spd : bool
        Project element Hessians to positive semi-definite.
    command : str
        The command named in ``summary.json``.
    say : callable(str), optional
        Progress lines (rank 0).
    """
    t0 = time.perf_counter()
    comm = PETSc.COMM_WORLD

    def tell(line: str) -> None:
        if say is not None and comm.rank == 0:
            say(line)

    model = build_model(experiment, comm, project_spd=spd)
    mesh = model.dmesh.mesh
    probe_cells, probe_weights = (
        embed(mesh, experiment.output.probes, source=f"{experiment.source}: output.probes")
        if experiment.output.probes else (None, None))
    tell(f"petsoft {command}: {len(mesh.tets)} tets, {len(mesh.points)} nodes, "
         f"{3 * len(mesh.points)} dofs on {comm.size} rank(s); {method.upper()}, "
         f"{load_steps} load step(s)")
    solver = StaticSolver(model, method=method, load_steps=load_steps, monitor=tell,
                          options=SolverOptions("", experiment.petsc))
    try:
        result = solver.solve()
        u = comm.tompi4py().bcast(model.dmesh.gather_global(result.displacement), root=0)
        probes = (interpolate(u, mesh.cells, probe_cells, probe_weights)
                  if probe_cells is not None else np.zeros((0, 3)))
        outcome = StaticOutcome(
            mesh=mesh, displacement=u, probes=np.asarray(probes),
            load_steps=result.load_steps,
            newton_iterations=result.newton_iterations,
            linear_iterations=result.linear_iterations, retries=result.retries,
            ksp_type=solver.ksp.getType(), pc_type=solver.ksp.getPC().getType())
    finally:
        solver.destroy()
    if out is not None and comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        write_xdmf(out / "displacement.xdmf", mesh.points, mesh.cells,
                   point_data={"displacement": u})
        summary = {"max_displacement": float(np.linalg.norm(u, axis=1).max()),
                   "probes": [{"point": list(map(float, p)), "displacement": list(map(float, v))}
                              for p, v in zip(experiment.output.probes or [], outcome.probes,
                                              strict=True)]}
        stats = {"method": method, "load_steps": outcome.load_steps,
                 "newton_iterations": outcome.newton_iterations,
                 "linear_iterations": outcome.linear_iterations, "retries": outcome.retries,
                 "ksp_type": outcome.ksp_type, "pc_type": outcome.pc_type}
        path = write_summary(out, command, summary, stats, time.perf_counter() - t0, comm)
        tell(f"max displacement {summary['max_displacement']:.6g} m after "
             f"{outcome.newton_iterations} Newton / {outcome.linear_iterations} linear "
             f"iterations ({outcome.ksp_type}+{outcome.pc_type}); wrote {path.parent}/")
    return outcome
