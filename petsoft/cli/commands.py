"""The subcommands behind the `petsoft` console command (PETSc is initialised by then)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from petsc4py import PETSc

from petsoft.calibration.calibrate import Observations, run_calibration
from petsoft.calibration.frequencies import (
    calibrate_frequencies,
    read_measured_modes,
    write_frequency_outputs,
)
from petsoft.calibration.rest_shape import (
    calibrate_rest_shape,
    compute_rest_shape,
    write_rest_mesh,
    write_splitting_outputs,
)
from petsoft.calibration.synth import run_synth
from petsoft.diagnosis.demo import run_diagnosis_demo
from petsoft.diagnosis.diagnose import run_diagnose
from petsoft.diagnosis.story import Story
from petsoft.dynamics import damping_analysis as damping
from petsoft.dynamics.run_simulation import simulate_experiment
from petsoft.errors import ExperimentError, PetsoftError
from petsoft.experiment import experiment_from_dict, load_experiment
from petsoft.io.importers import run_import
from petsoft.io.progress import heartbeat, touch
from petsoft.io.recording import read_recording_on_all_ranks
from petsoft.io.summary import write_summary
from petsoft.io.xdmf import XdmfWriter
from petsoft.physics.model import build_model
from petsoft.solvers.modes import compute_modes
from petsoft.solvers.options import SolverOptions
from petsoft.solvers.run_static import solve_experiment

# The embedded default of `petsoft demo`: a soft neo-Hookean cantilever (silicone-like) clamped
# at x = 0, sagging under gravity with a downward end load large enough to bend it visibly.
DEMO_EXPERIMENT = {
    "mesh": {"box": {"size": [0.40, 0.04, 0.04], "cells": [40, 4, 4]}},
    "material": {"model": "neohookean", "youngs_modulus": 1.0e6, "poisson_ratio": 0.45,
                 "density": 1100.0},
    "gravity": {"acceleration": [0.0, 0.0, -9.81]},
    "boundary": [
        {"kind": "fixed", "where": "x < 1e-6"},
        {"kind": "traction", "where": "x > 0.4 - 1e-6", "value": [0.0, 0.0, -2000.0]},
    ],
    "output": {"directory": "petsoft-demo", "probes": [[0.4, 0.02, 0.02], [0.2, 0.02, 0.02]]},
}


def _print(line: str) -> None:
    touch()                 # a line was said: the heartbeat (below) waits another interval
    if PETSc.COMM_WORLD.rank == 0:
        print(line, flush=True)


def _print_here(line: str) -> None:
    """A progress line of ``petsoft diagnose``, printed by the rank that says it: the diagnosis
    already speaks from one rank per group of ranks (rank 0 for the whole run, a group's first
    rank for a fit or run on a group), so that a group's fit is heard while rank 0 waits."""
    touch()
    print(line, flush=True)


def _pulse(line: str) -> None:
    """The heartbeat's line: where a long simulation is (never silent for more than 10 s)."""
    _print(f"  {line}")


def run(args) -> int:
    if args.command == "static":
        experiment = load_experiment(args.experiment)
        out = Path(args.out) if args.out else experiment.output.directory
        solve_static(experiment, out, args.method, args.load_steps, args.spd)
        return 0
    if args.command == "simulate":
        experiment = load_experiment(args.experiment)
        out = Path(args.out) if args.out else experiment.output.directory
        run_simulation(experiment, out, args)
        return 0
    if args.command == "modes":
        return run_modes(args)
    if args.command == "damping":
        return run_damping(args)
    if args.command == "import":
        return run_import(args)
    if args.command == "synth":
        return run_synth(args)
    if args.command == "rest-shape":
        return run_rest_shape(args)
    if args.command == "calibrate":
        experiment = load_experiment(args.experiment)
        out = Path(args.out) if args.out else experiment.output.directory
        if (args.modes is None) == (args.recording is None):
            raise PetsoftError("petsoft calibrate needs exactly one of a RECORDING (marker "
                               "trajectories) and --modes FILE (measured natural frequencies)")
        if args.modes is not None:
            return run_frequency_calibration(experiment, args.modes, out, args)
        observations = Observations(read_recording_on_all_ranks(args.recording), noise=args.noise)
        if getattr(args, "rest_shape", False):
            return run_rest_shape_calibration(experiment, observations, out, args)
        with heartbeat(_pulse):
            run_calibration(experiment, observations, method=args.method,
                            gradient=args.gradient, integrator=args.integrator,
                            starts=args.multistart, seed=args.seed,
                            regularization=args.regularization, out=out, say=_print,
                            spelled_out=args.spelled_out, check_mesh=args.check_mesh,
                            misfit=args.misfit)
        return 0
    if args.command == "diagnose":
        experiment = load_experiment(args.experiment)
        out = Path(args.out) if args.out else experiment.output.directory
        recording = read_recording_on_all_ranks(args.recording)
        result = run_diagnose(experiment, recording, out=out, fraction=args.fraction,
                              alpha=args.alpha, max_additions=args.max_additions,
                              method=args.method, integrator=args.integrator,
                              noise=args.noise, numerics=not args.no_numerics,
                              say=_print_here, spelled_out=args.spelled_out,
                              budget=args.budget, reduced_trials=args.reduced_trials,
                              **({} if args.one_rank_dofs is None
                                 else {"one_rank_dofs": args.one_rank_dofs}))
        # the console ends with the conclusion, in the report's words and numbers
        _print("")
        for line in Story(result.report).conclusion(out):
            _print(line)
        return 0
    if args.command == "demo":
        out = Path(args.out)
        if args.part in ("all", "static"):
            experiment = experiment_from_dict(DEMO_EXPERIMENT, source="<embedded demo>")
            outcome = solve_static(experiment, out, args.method, args.load_steps, False,
                                   command="demo")
            if PETSc.COMM_WORLD.rank == 0:
                png = plot_deflection(outcome.mesh, outcome.displacement,
                                      out / "deflection.png")["path"]
                _print(f"plot: {png}   (open displacement.xdmf in ParaView for the 3D field)")
        if args.part in ("all", "diagnose"):
            _print("\n== the whole loop: a recording with a hidden effect, diagnosed ==")
            run_diagnosis_demo(out / "diagnose", say=_print)
        return 0
    raise AssertionError(args.command)


def run_frequency_calibration(experiment, path: str, out: Path, args) -> int:
    """``petsoft calibrate --modes FILE``: material parameters from natural frequencies (a
    measured-frequencies file, or a recording whose frequencies are estimated)."""
    measured = read_measured_modes(path)
    fit = calibrate_frequencies(experiment, measured, say=_print)
    if PETSc.COMM_WORLD.rank == 0:
        write_frequency_outputs(out, experiment, fit, spelled_out=args.spelled_out)
        _print(f"wrote {out}/ (calibrated.toml, summary.json, frequencies.png)")
    return 0


def run_rest_shape(args) -> int:
    """``petsoft rest-shape``: write the rest mesh of the experiment's captured mesh."""
    experiment = load_experiment(args.experiment)
    rest = compute_rest_shape(experiment, load_steps=args.load_steps, say=_print)
    if PETSc.COMM_WORLD.rank == 0:
        path = write_rest_mesh(args.out, rest)
        shift = float(np.abs(rest.captured.points - rest.points).max())
        _print(f"wrote {path}: rest mesh ({rest.newton_iterations} Newton iterations; the "
               f"captured shape lies up to {shift:.4g} m from it)")
    return 0


def run_rest_shape_calibration(experiment, observations, out: Path, args) -> int:
    """``petsoft calibrate --rest-shape``: the X/u splitting."""
    if args.method != "gauss-newton" or args.multistart or args.regularization:
        raise ExperimentError("--rest-shape fits by Levenberg-Marquardt on the reduced problem: "
                           "it takes no --method, --multistart or --regularization")
    t0 = time.perf_counter()
    result = calibrate_rest_shape(experiment, observations, say=_print)
    write_splitting_outputs(out, experiment, result, time.perf_counter() - t0, PETSc.COMM_WORLD,
                            spelled_out=args.spelled_out)
    _print(f"rms {result.rms_before:.4e} m -> {result.rms_after:.4e} m; wrote {out}/ "
           "(calibrated.toml, rest.vtu, summary.json)")
    return 0


def solve_static(experiment, out: Path, method: str, load_steps: int, spd: bool,
                 command: str = "static"):
    """`petsoft static` (and the demo's first part): solve and write (all ranks call)."""
    return solve_experiment(experiment, out=out, method=method, load_steps=load_steps, spd=spd,
                            command=command, say=_print)


def plot_deflection(mesh, u: np.ndarray, path: Path) -> dict:
    """Side view (x-z) of the reference and deformed body, coloured by displacement.

    Returns
    -------
    dict
        What was drawn, read back from the figure: ``path``, ``reference`` and ``deformed``
        ((N, 2) x-z points) and ``colour`` (|u| of each deformed point).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.5))
    p, q = mesh.points, mesh.points + u
    ref = ax.scatter(p[:, 0], p[:, 2], s=2, c="0.8", label="reference")
    sc = ax.scatter(q[:, 0], q[:, 2], s=3, c=np.linalg.norm(u, axis=1), cmap="viridis",
                    label="deformed")
    fig.colorbar(sc, ax=ax, label="|u| (m)")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_aspect("equal")
    ax.legend(loc="lower left")
    ax.set_title("petsoft demo: neo-Hookean cantilever, side view")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    drawn = {"path": Path(path), "reference": np.asarray(ref.get_offsets()),
             "deformed": np.asarray(sc.get_offsets()), "colour": np.asarray(sc.get_array())}
    plt.close(fig)
    return drawn


def run_simulation(experiment, out: Path, args) -> None:
    """`petsoft simulate`: build, run and write a dynamic simulation (all ranks call)."""
    simulate_experiment(experiment, out=out, integrator=args.integrator,
                        recording=args.recording, restart=args.restart, solver=args.solver,
                        explicit_scheme=args.explicit_scheme, alpha_backend=args.alpha_backend,
                        spd=args.spd, say=_print)


def run_modes(args) -> int:
    """`petsoft modes`: natural frequencies and mode shapes of an experiment (all ranks call).

    Prints a table, writes ``summary.json`` (``frequencies_hz``, ``eigenvalues``, solver
    statistics) and ``modes.xdmf``/``.h5``: one frame per mode with time = mode number (1, 2,
    ...) and the M-normalised shape as the point field ``mode``, so ParaView's time control steps
    through the modes under one Warp By Vector.
    """
    t0 = time.perf_counter()
    comm = PETSc.COMM_WORLD
    experiment = load_experiment(args.experiment)
    out = Path(args.out) if args.out else experiment.output.directory
    model = build_model(experiment, comm)
    mesh = model.dmesh.mesh
    _print(f"petsoft modes: {len(mesh.tets)} tets, {len(mesh.points)} nodes, "
           f"{3 * len(mesh.points)} dofs ({model.dirichlet.count} constrained) on {comm.size} "
           f"rank(s); {args.num_modes} mode(s)")
    result = compute_modes(model, args.num_modes, monitor=_print,
                           options=SolverOptions("", experiment.petsc))
    writer = XdmfWriter(out / "modes.xdmf", mesh.points, mesh.cells) if comm.rank == 0 else None
    for k, x in enumerate(result.modes):
        shape = model.dmesh.gather_global(x)       # collective; None off rank 0
        if writer is not None:
            writer.write(float(k + 1), {"mode": shape})
    if writer is not None:
        writer.close()
    _print(f"{'mode':>5} {'frequency (Hz)':>16} {'omega^2 (rad/s)^2':>19} {'rel. residual':>14}")
    for k, (f, lam, err) in enumerate(zip(result.frequencies_hz, result.eigenvalues,
                                          result.relative_errors, strict=True)):
        note = "  rigid body" if k < result.rigid_modes else ""
        _print(f"{k + 1:>5} {f:>16.8g} {lam:>19.8g} {err:>14.2e}{note}")
    solver = {**result.solver, "shift": result.shift, "converged": result.converged,
              "iterations": result.iterations,
              "max_relative_residual": float(result.relative_errors.max())}
    results = {"frequencies_hz": [float(f) for f in result.frequencies_hz],
               "eigenvalues": [float(v) for v in result.eigenvalues],
               "rigid_body_modes": result.rigid_modes,
               "mode_shapes": {"file": "modes.xdmf", "field": "mode", "normalisation": "mass"}}
    path = write_summary(out, "modes", results, solver, time.perf_counter() - t0, comm)
    factor = result.solver.get("factor_solver_type", result.solver["pc_type"])
    _print(f"{len(result.modes)} modes, {result.frequencies_hz[0]:.6g} to "
           f"{result.frequencies_hz[-1]:.6g} Hz ({result.rigid_modes} rigid body), "
           f"{result.iterations} iteration(s) of {result.solver['eps_type']} + "
           f"{result.solver['st_type']} ({factor}); wrote {path.parent if path else out}/")
    result.destroy()
    return 0


def run_damping(args) -> int:
    """`petsoft damping`: artificial damping of the integrators (all ranks call).

    Always the scalar analysis (analytic curves, measured on oscillators); with an experiment also
    the per-mode table of its body at ``[time] step`` (see
    :mod:`petsoft.dynamics.damping_analysis`).
    """
    t0 = time.perf_counter()
    comm = PETSc.COMM_WORLD
    schemes = damping.default_schemes(args.radii)
    experiment = load_experiment(args.experiment) if args.experiment else None
    out = Path(args.out) if args.out else (
        experiment.output.directory if experiment else Path("petsoft-damping"))
    _print(f"petsoft damping: {len(schemes)} integrators on {len(damping.MEASURED_TAU_OMEGA)} "
           f"oscillators (tau*w = 1e-2 .. 1e2) on {comm.size} rank(s)")
    rows = damping.scalar_analysis(schemes, comm=comm)
    fem = None
    if experiment is not None:
        if experiment.time is None:
            raise ExperimentError(f"{experiment.source}: petsoft damping needs [time] step")
        model = build_model(experiment, comm)
        _print(f"{experiment.source}: {args.modes} lowest modes at step "
               f"{experiment.time.step:g} s, {args.steps} steps per run")
        fem = damping.fem_mode_damping(model, experiment.time.step, schemes, args.modes,
                                       args.steps, args.amplitude, monitor=_print,
                                       petsc=experiment.petsc)
    damping.report(out, schemes, fem, rows, comm, t0, printer=_print,
                   source=experiment.source if experiment else None)
    return 0
