"""Running a dynamic simulation of an experiment: the time loop and everything it writes.

Initial state (expressions or static equilibrium), one integrator, steps that are retried with
half the step when Newton fails, energy bookkeeping, trajectory frames (XDMF + HDF5), probe
trajectories as a recording (``probes.h5``), a progress line and ``summary.json``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from petsc4py import PETSc

from petsoft.dynamics.energy import FIELDS, EnergyLedger
from petsoft.dynamics.explicit import ExplicitIntegrator
from petsoft.dynamics.factory import system_class, system_for
from petsoft.dynamics.integrators import SCHEMES, IntegratorOptions, check_viscoelastic, scheme
from petsoft.errors import ExperimentError, PetsoftError, SolverError
from petsoft.io.progress import duration
from petsoft.io.recording import write_recording
from petsoft.io.summary import write_summary
from petsoft.io.xdmf import XdmfWriter
from petsoft.mesh.probes import interpolate
from petsoft.solvers.options import SolverOptions

MAX_HALVINGS = 6
#: trajectory frames are written in batches at most this many seconds apart (and before every
#: checkpoint and at the end): a file per frame cost ~2 ms a frame, as much as a step of a
#: 600-dof model (XdmfWriter's flush_seconds)
FRAME_BATCH_SECONDS = 1.0


@dataclass
class SimulationResult:
    """The outcome of a run: final state, statistics and the energy table."""

    time: float
    steps: int
    q: PETSc.Vec
    v: PETSc.Vec
    energies: np.ndarray
    newton_iterations: int = 0
    linear_iterations: int = 0
    retries: int = 0
    wall_time: float = 0.0
    probe_times: list = field(default_factory=list)
    probe_displacements: list = field(default_factory=list)


def make_integrator(system, name: str, solver: str = "snes", explicit_scheme: str = "verlet",
                    alpha_radius: float = 0.5, alpha_backend: str = "petsoft",
                    imex_slow_modes: int = 6, petsc: Mapping[str, str] | None = None):
    """The integrator object for a name of ``[time] integrator``; ``petsc``: the
    experiment's ``[petsc]`` table, for its solvers (each under its prefix)."""
    entry = scheme(name)
    branch = system.viscoelastic
    check_viscoelastic(branch, name)
    if entry.ts_backend and alpha_backend == "ts" and branch is not None and branch.active:
        raise ExperimentError("--alpha-backend ts does not include the [viscoelastic] branch; "
                              "use petsoft's own generalized-alpha (--alpha-backend petsoft)")
    if solver == "local-global" and branch is not None and branch.active:
        raise ExperimentError("--solver local-global does not include the [viscoelastic] branch; "
                              "use --solver snes or tao")
    if solver == "local-global":
        if not entry.minimization:
            raise ExperimentError(f"--solver local-global solves backward-Euler steps only "
                                  f"(integrator be), not {name!r}")
        terms = system.velocity_terms
        if terms is not None and terms.active:
            raise ExperimentError("--solver local-global handles Rayleigh mass damping only; "
                                  "[drag] and [friction] need --solver snes (or tao)")
        from petsoft.dynamics.local_global import LocalGlobalIntegrator

        return LocalGlobalIntegrator(system, options=SolverOptions("lg_", petsc))
    return entry.build(system, IntegratorOptions(
        solver=solver, explicit_scheme=explicit_scheme, alpha_radius=alpha_radius,
        alpha_backend=alpha_backend, imex_slow_modes=imex_slow_modes, petsc=dict(petsc or {})))


class Simulation:
    """A dynamic run of an experiment (all ranks construct and run it).

    Parameters
    ----------
    model : petsoft.physics.model.Model or petsoft.dynamics.mass_spring.MassSpringModel
        The experiment's model (:func:`petsoft.dynamics.factory.build_model`); the system is made
        from it by :func:`petsoft.dynamics.factory.system_for`.
    experiment : Experiment
        Needs ``[time]``.
    integrator : str, optional
        Overrides ``[time] integrator``.
    solver : {"snes", "tao"}
        Newton on the step equations, or (backward Euler) minimisation of the incremental
        potential.
    out : Path, optional
        Output directory; None writes nothing.
    monitor : callable(str), optional
        Progress lines (printed on rank 0 by the caller's function).
    """

    def __init__(self, model, experiment, *, integrator: str | None = None, solver: str = "snes",
                 out: Path | None = None, monitor=None, explicit_scheme: str = "verlet",
                 alpha_backend: str = "petsoft", progress_every: float = 1.0,
                 spd: bool = False):
        if experiment.time is None:
            raise ExperimentError(f"{experiment.source}: [time] is missing: `simulate` needs "
                                  "end and step (and optionally integrator)")
        self.model, self.experiment = model, experiment
        self.name = integrator or experiment.time.integrator
        entry = scheme(self.name, "integrator")        # a clear error for an unknown name
        body = system_class(experiment)
        if entry.continuum_only and not body.continuum_material:
            raise ExperimentError(
                f"{experiment.source}: integrator {self.name} splits the modes of a "
                f"continuum's reference stiffness and does not apply to {body.defined_by} "
                "models; use " + ", ".join(n for n, e in SCHEMES.items() if not e.continuum_only))
        self.system = system_for(model, experiment, spd=spd)
        self.integrator = make_integrator(self.system, self.name, solver, explicit_scheme,
                                          experiment.time.alpha_radius, alpha_backend,
                                          experiment.time.imex_slow_modes, experiment.petsc)
        self.out = Path(out) if out is not None else None
        self.monitor = monitor
        self.progress_every = progress_every
        self.probes = experiment.output.probes
        self.probe_cells = self.probe_weights = self.probe_connectivity = None
        if self.probes:
            self.probe_connectivity, self.probe_cells, self.probe_weights = (
                self.system.locate_probes(self.probes,
                                          source=f"{experiment.source}: output.probes"))

    def _say(self, line: str) -> None:
        if self.monitor is not None and self.model.dmesh.comm.rank == 0:
            self.monitor(line)

    def _advance(self, n, t, q, v, h, q1, v1, depth=0):
        """Step n (of h from t), as two half steps (recursively) if Newton fails."""
        report = self.integrator.step(t, q, v, h, q1, v1)
        if report.converged:
            return [report]
        if depth >= MAX_HALVINGS:
            raise SolverError(
                f"integrator {self.name}: step {n} at t = {t:.6g} s (h = {h:.3g} s) failed "
                f"{MAX_HALVINGS + 1} times with halved steps: {report.reason}. The last "
                "checkpoint is still valid (--restart). Try a smaller [time] step, more "
                "damping, or another integrator")
        self._say(f"  step {n}, t = {t:.6g} s: Newton failed ({report.reason}); retrying with "
                  f"h = {h / 2:.3g} s")
        qm, vm = q.duplicate(), v.duplicate()
        reports = self._advance(n, t, q, v, h / 2, qm, vm, depth + 1)
        reports += self._advance(n, t + h / 2, qm, vm, h / 2, q1, v1, depth + 1)
        qm.destroy()
        vm.destroy()
        return reports

    def run(self, restart: bool = False) -> SimulationResult:
        """Run to ``[time] end`` (from the latest checkpoint with ``restart``)."""
        t_start = time.perf_counter()
        exp, dm, s = self.experiment, self.model.dmesh, self.system
        rank0 = dm.comm.rank == 0
        h, nsteps = exp.time.step, exp.time.num_steps
        ledger = EnergyLedger()
        if restart:
            q, v, first, result = self._restore(ledger)
        else:
            q, v = s.initial_state(monitor=self.monitor)
            first = 1
            if s.viscoelastic is not None:
                s.viscoelastic.reset(q)   # the branch starts relaxed
            result = SimulationResult(0.0, 0, q, v, np.zeros((0, len(FIELDS))))
        q1, v1 = q.duplicate(), v.duplicate()
        if isinstance(self.integrator, ExplicitIntegrator):
            limit = self.integrator.check_step(q, h, source=f"{exp.source}: time.step")
            self._say(f"explicit stability limit {limit:.4g} s (step {h:g} s)")
        writer = None
        every = exp.output.every
        if self.out is not None and rank0:
            self.out.mkdir(parents=True, exist_ok=True)
            if restart:
                self._archive_trajectory()
            writer = XdmfWriter(self.out / "trajectory.xdmf", dm.mesh.points, dm.mesh.cells,
                                flush_seconds=FRAME_BATCH_SECONDS)
        t = (first - 1) * h
        if restart:
            u0, w0 = dm.gather_global(q), dm.gather_global(v)   # collective
            if writer is not None:
                writer.write(t, {"displacement": u0, "velocity": w0})
            row = ledger.rows[-1]
        else:
            self._frame(writer, 0.0, q, v, result)
            row = ledger.record(s, 0.0, q, v)
        self._say(f"petsoft simulate: {self.name}, {nsteps} steps of {h:g} s to "
                  f"t = {exp.time.end:g} s; {len(dm.mesh.tets)} tets on {dm.comm.size} rank(s); "
                  f"E0 = {row['kinetic'] + row['elastic'] + row['gravitational']:.6g} J"
                  + (f"; restarted at step {first - 1}, t = {t:g} s" if restart else ""))
        last_print = loop_start = time.perf_counter()
        checkpoint_every = exp.output.checkpoint_every if self.out is not None else 0
        # The steps keep their chord's factors for later steps (as ForwardModel.simulate's do:
        # at 46,644 dofs a factorisation a step made simulate 2.3x the forward run's time), and
        # the step after each checkpoint factors afresh, as the first step of a run restarted
        # there does: the restart repeats the uninterrupted run bit for bit.
        keep = getattr(self.integrator, "keep_factors", None)
        if keep is not None:
            keep(True)
        try:
            for n in range(first, nsteps + 1):
                reports = self._advance(n, t, q, v, h, q1, v1)
                for r in reports:
                    ledger.add_step(r)
                    result.newton_iterations += r.newton_iterations
                    result.linear_iterations += r.linear_iterations
                result.retries += len(reports) - 1
                q1.copy(q)
                v1.copy(v)
                t = n * h
                row = ledger.record(s, t, q, v)
                if n % every == 0 or n == nsteps:
                    self._frame(writer, t, q, v, result)
                if checkpoint_every and n % checkpoint_every == 0 and n < nsteps:
                    if writer is not None:
                        writer.flush()      # the trajectory holds every frame up to it
                    self._checkpoint(n, t, q, v, ledger, result)
                    if keep is not None:
                        keep(True)          # the next step factors afresh
                now = time.perf_counter()
                if now - last_print >= self.progress_every or n == nsteps:
                    last_print = now
                    total = row["kinetic"] + row["elastic"] + row["gravitational"]
                    its = reports[-1].newton_iterations
                    left = (now - loop_start) / (n - first + 1) * (nsteps - n)
                    self._say(f"step {n}/{nsteps}  t = {t:.6g} s  Newton {its}  E = "
                              f"{total:.6g} J (kinetic {row['kinetic']:.4g}, dissipated "
                              f"{row['dissipated']:.4g}, numerical {row['numerical']:.3g})"
                              + (f"  ~{duration(left)} left" if n < nsteps else ""))
        finally:
            if keep is not None:
                keep(False)
            # the frames collected so far are written whatever ended the loop
            if writer is not None:
                writer.close()
        result.time, result.steps = t, nsteps
        result.energies = ledger.array()
        result.wall_time = time.perf_counter() - t_start
        if self.out is not None:
            self._write_outputs(result)
        return result

    # -- checkpoints ------------------------------------------------------------------------------
    def _checkpoint(self, n, t, q, v, ledger, result) -> None:
        from petsoft.dynamics.checkpoint import write_checkpoint

        dm = self.model.dmesh
        state = self.integrator.state()
        fields = {"q": q, "v": v}
        branch = self.system.viscoelastic
        if branch is not None and branch.active:
            fields["z"] = branch.z       # the Maxwell branch's internal variable
        # nodal vectors are gathered into file numbering; small arrays (the same on every rank,
        # e.g. modal coefficients) are written as they are
        gathered = {k: dm.gather_global(vec) if isinstance(vec, PETSc.Vec) else np.asarray(vec)
                    for k, vec in
                    {**fields, **{f"integrator:{k}": w for k, w in state.items()}}.items()}
        if dm.comm.rank == 0:
            text = (self.experiment.path.read_text() if self.experiment.path is not None
                    else "")
            path = write_checkpoint(
                self.out / "checkpoints", step=n, time=t, step_size=self.experiment.time.step,
                integrator=self.name,
                fields={k: gathered[k] for k in fields},
                integrator_state={k.split(":", 1)[1]: a for k, a in gathered.items()
                                  if k.startswith("integrator:")},
                ledger=ledger, probes=(result.probe_times, result.probe_displacements),
                mesh=dm.mesh, experiment_text=text, ranks=dm.comm.size)
            self._say(f"checkpoint {path.name} (step {n}, t = {t:.6g} s)")

    def _restore(self, ledger):
        """State, first step and result so far from the latest checkpoint (all ranks)."""
        from petsoft.dynamics.checkpoint import read_latest

        dm = self.model.dmesh
        mpi = dm.comm.tompi4py()
        data, error = None, None
        if mpi.rank == 0:
            try:
                data = read_latest(self.out / "checkpoints")
                if (data["mesh_points"].shape != dm.mesh.points.shape
                        or not np.array_equal(data["mesh_tets"], dm.mesh.cells)
                        or not np.array_equal(data["mesh_points"], dm.mesh.points)):
                    raise PetsoftError(f"{data['path']}: the checkpoint's mesh differs from the "
                                       "experiment's mesh; restart with the same mesh")
                if str(data["integrator"]) != self.name:
                    raise PetsoftError(f"{data['path']}: written by integrator "
                                       f"{data['integrator']}, not {self.name}")
                if float(data["step_size"]) != self.experiment.time.step:
                    raise PetsoftError(f"{data['path']}: step {data['step_size']} s differs from "
                                       f"[time] step {self.experiment.time.step} s")
                branch = self.system.viscoelastic
                if branch is not None and branch.active and "z" not in data["fields"]:
                    raise PetsoftError(f"{data['path']}: written without a [viscoelastic] "
                                       "branch (no /state/z), but the experiment has one "
                                       f"(ratio = {branch.ratio:g}); restart with the "
                                       "experiment that wrote it")
            except PetsoftError as exc:
                error = exc
        error = mpi.bcast(error)
        if error is not None:
            raise error
        data = mpi.bcast(data)
        q = dm.from_file_field(data["fields"]["q"])
        v = dm.from_file_field(data["fields"]["v"])
        state = {k: dm.from_file_field(a) if np.ndim(a) == 2 else np.asarray(a)
                 for k, a in data["integrator_state"].items()}
        branch = self.system.viscoelastic
        if branch is not None:
            if "z" in data["fields"]:
                z = dm.from_file_field(data["fields"]["z"])
                branch.restore(z)
                z.destroy()
            else:
                branch.reset(q)
        t = float(data["time"])
        self.integrator.restore(t, q, v, state)
        rows = data["ledger_rows"]
        ledger.rows = [dict(zip(FIELDS, r, strict=True)) for r in rows]
        ledger.dissipated = float(data["ledger"]["dissipated"])
        ledger.external_work = float(data["ledger"]["external_work"])
        ledger.initial = float(data["ledger"]["initial"])
        result = SimulationResult(t, int(data["step"]), q, v, np.zeros((0, len(FIELDS))))
        result.probe_times = list(data["probe_times"])
        result.probe_displacements = list(data["probe_displacements"])
        self._say(f"restarting from {Path(data['path']).name} (step {int(data['step'])}, "
                  f"t = {t:g} s, written on {int(data['ranks'])} rank(s))")
        return q, v, int(data["step"]) + 1, result

    def _archive_trajectory(self) -> None:
        """Move an earlier segment's trajectory (.xdmf, .h5, frame files) into segments/<k>/,
        where it stays readable (the .xdmf refers to its data by relative paths)."""
        xdmf = self.out / "trajectory.xdmf"
        if not xdmf.exists():
            return
        k = 1
        while (self.out / "segments" / str(k)).exists():
            k += 1
        dest = self.out / "segments" / str(k)
        dest.mkdir(parents=True)
        for name in ("trajectory.xdmf", "trajectory.h5", "trajectory_frames"):
            if (self.out / name).exists():
                (self.out / name).replace(dest / name)
        self._say(f"earlier trajectory moved to {dest}/")

    def _frame(self, writer, t, q, v, result) -> None:
        dm = self.model.dmesh
        u = dm.gather_global(q)
        w = dm.gather_global(v)
        if dm.comm.rank != 0:
            return
        if writer is not None:
            writer.write(t, {"displacement": u, "velocity": w})
        if self.probe_cells is not None:
            result.probe_times.append(t)
            result.probe_displacements.append(
                interpolate(u, self.probe_connectivity, self.probe_cells, self.probe_weights))

    def _write_outputs(self, result: SimulationResult) -> None:
        dm = self.model.dmesh
        u = dm.gather_global(result.q)
        if dm.comm.rank == 0:
            max_u = float(np.linalg.norm(u, axis=1).max())
            header = ",".join(FIELDS)
            np.savetxt(self.out / "energies.csv", result.energies, delimiter=",", header=header,
                       comments="")
            if self.probe_cells is not None:
                ref = np.asarray(self.probes, dtype=float)
                pos = ref[None] + np.array(result.probe_displacements)
                write_recording(self.out / "probes.h5", ref, np.array(result.probe_times), pos,
                                names=[f"probe{i}" for i in range(len(ref))],
                                attrs={"source": f"petsoft simulate {self.experiment.source}"})
        last = dict(zip(FIELDS, result.energies[-1], strict=True))
        summary = {
            "final_time": result.time, "steps": result.steps, "integrator": self.name,
            "energies": {k: float(last[k]) for k in FIELDS if k != "time"},
        }
        if dm.comm.rank == 0:
            summary["max_displacement"] = max_u
        stats = {"newton_iterations": result.newton_iterations,
                 "linear_iterations": result.linear_iterations, "retries": result.retries}
        write_summary(self.out, "simulate", summary, stats, result.wall_time, dm.comm)

    def destroy(self) -> None:
        self.integrator.destroy()
        self.system.destroy()
