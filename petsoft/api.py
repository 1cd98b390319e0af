"""petsoft's public Python API: what the ``petsoft`` command does, as functions on values.

Every function takes values (an :class:`~petsoft.experiment.Experiment`, a
:class:`~petsoft.io.recording.Recording`) with explicit keyword options, and returns a result
object; files are read only by :func:`load_experiment` and :func:`read_recording`, and written
only where ``out`` says. All ranks call every function (run a script under ``mpiexec -n N``), and
every rank gets the same result.

>>> import petsoft
>>> exp = petsoft.load_experiment("experiment.toml")          # doctest: +SKIP
>>> rec = petsoft.read_recording("recording.h5")               # doctest: +SKIP
>>> fit = petsoft.calibrate(exp, rec)                          # doctest: +SKIP
>>> report = petsoft.diagnose(exp, rec, out="diagnosis")       # doctest: +SKIP

PETSc options (solvers) come from the experiment's ``[petsc]`` table and from
``petsc4py.init(sys.argv)`` called before the first petsoft function, as on the command line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from petsc4py import PETSc

from petsoft.calibration.calibrate import CalibrationResult, run_calibration
from petsoft.calibration.rest_shape import calibrate_rest_shape as _calibrate_rest_shape
from petsoft.calibration.rest_shape import compute_rest_shape, write_rest_mesh
from petsoft.calibration.synth import SynthOptions, SynthResult
from petsoft.calibration.synth import synth as _synth
from petsoft.diagnosis.budget import DEFAULT_BUDGET
from petsoft.diagnosis.diagnose import DiagnoseResult, run_diagnose
from petsoft.diagnosis.placement import ONE_RANK_DOFS
from petsoft.dynamics.run_simulation import SimulationRun, simulate_experiment
from petsoft.experiment import Experiment
from petsoft.experiment import load_experiment as _load_experiment
from petsoft.experiment import with_parameters as _with_parameters
from petsoft.io.recording import Recording, read_recording_on_all_ranks
from petsoft.results import Result
from petsoft.solvers.options import SolverOptions
from petsoft.solvers.run_static import StaticOutcome, solve_experiment

__all__ = ["load_experiment", "with_parameters", "read_recording", "static", "simulate",
           "modes", "synth", "calibrate", "calibrate_modes", "calibrate_rest_shape",
           "rest_shape", "diagnose",
           "Experiment", "Recording", "StaticResult", "SimulationRun", "Modes",
           "SynthOptions", "SynthResult", "CalibrationResult", "DiagnoseResult"]


def _quiet(line: str) -> None:
    """The default progress sink of the API: nothing (pass ``say=print`` to follow a run)."""


def load_experiment(path: str | Path) -> Experiment:
    """Read and validate an experiment file (TOML; the keys: ``petsoft/formats.md``).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    Experiment
        A frozen value; :func:`petsoft.experiment.with_parameters` makes changed copies.

    Raises
    ------
    petsoft.errors.ExperimentError
        Naming the file, the key and line, and what would be valid.
    """
    return _load_experiment(path)


def with_parameters(experiment: Experiment, values: dict[str, float]) -> Experiment:
    """A copy of ``experiment`` with parameters changed by their dotted names.

    Parameters
    ----------
    experiment : Experiment
    values : dict of str to float
        E.g. ``{"material.youngs_modulus": 1.4e6, "damping.mass": 0.5}`` (the names of a
        ``[calibrate]`` table).

    Returns
    -------
    Experiment
    """
    return _with_parameters(experiment, values)


def read_recording(path: str | Path) -> Recording:
    """Read a recording (HDF5; the layout: ``petsoft/formats.md`` section 2) on every rank.

    Rank 0 reads the file and every rank receives the same value (one file read per job).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    Recording
        Marker reference positions and names, frame times, positions (NaN where unseen), the
        noise when the file states it, and measured inputs.

    Raises
    ------
    petsoft.io.recording.RecordingError
        Naming the file and the dataset that is wrong.
    """
    return read_recording_on_all_ranks(path)


@dataclass(frozen=True, repr=False)
class StaticResult(Result):
    """The quasistatic solution of :func:`static` (the same on every rank).

    ``success`` when the displacement is finite (a diverged Newton solve raises a
    :class:`~petsoft.errors.SolverError` instead of returning).

    Attributes
    ----------
    displacement : ndarray (N, 3)
        Nodal displacements (m) in the mesh's node order.
    max_displacement : float
        The largest nodal displacement magnitude (m).
    probes : ndarray (P, 3)
        Displacements at ``[output] probes`` (empty without probes).
    newton_iterations, linear_iterations, load_steps : int
    out : Path or None
        Where ``displacement.xdmf`` and ``summary.json`` were written.
    """

    displacement: np.ndarray
    max_displacement: float
    probes: np.ndarray
    newton_iterations: int
    linear_iterations: int
    load_steps: int
    out: Path | None

    @property
    def success(self) -> bool:
        return bool(np.isfinite(self.displacement).all())

    @property
    def message(self) -> str:
        return (f"equilibrium in {self.load_steps} load step(s), {self.newton_iterations} Newton "
                f"iterations; largest displacement {self.max_displacement:.4g} m")


def static(experiment: Experiment, *, out: str | Path | None = None, method: str = "snes",
           load_steps: int = 1, spd: bool = False, say=_quiet) -> StaticResult:
    """Quasistatic equilibrium of ``experiment`` (``petsoft static``).

    Parameters
    ----------
    experiment : Experiment
    out : str or Path, optional
        Write ``displacement.xdmf``/``.h5`` and ``summary.json`` here; None writes nothing.
    method : {"snes", "tao"}
        Newton on the residual, or minimisation of the potential energy.
    load_steps : int
        Apply loads and prescribed displacements in this many equal increments (>= 1).
    spd : bool
        Project element Hessians to positive semi-definite (robust far from equilibrium).
    say : callable(str)
        Progress lines (rank 0); default silent.

    Returns
    -------
    StaticResult
    """
    outcome: StaticOutcome = solve_experiment(
        experiment, out=None if out is None else Path(out), method=method,
        load_steps=load_steps, spd=spd, say=say)
    return StaticResult(displacement=outcome.displacement,
                        max_displacement=float(np.linalg.norm(outcome.displacement,
                                                              axis=1).max()),
                        probes=outcome.probes, newton_iterations=outcome.newton_iterations,
                        linear_iterations=outcome.linear_iterations,
                        load_steps=outcome.load_steps,
                        out=None if out is None else Path(out))


def simulate(experiment: Experiment, *, out: str | Path | None = None,
             integrator: str | None = None, recording: Recording | str | Path | None = None,
             restart: bool = False, solver: str = "snes", explicit_scheme: str = "verlet",
             alpha_backend: str = "petsoft", spd: bool = False,
             say=_quiet) -> SimulationRun:
    """Integrate ``experiment`` in time (``petsoft simulate``).

    Parameters
    ----------
    experiment : Experiment
        With ``[time]`` (end, step, integrator).
    out : str or Path, optional
        Output directory (trajectory.xdmf, probes.h5, energy, checkpoints, summary.json);
        default the experiment's ``[output] directory``.
    integrator : str, optional
        Overrides ``[time] integrator``: be, si, alpha, midpoint, trapezoidal, ere, explicit,
        imex.
    recording : Recording or path, optional
        The recording whose ``/inputs`` drive ``series`` supports.
    restart : bool
        Continue from the latest checkpoint in ``out``.
    solver : {"snes", "tao", "local-global"}
        How backward Euler solves a step: Newton, minimisation of the incremental potential, or
        (mass-spring models) the local/global iteration.
    explicit_scheme : {"verlet", "euler"}
        The explicit integrator's scheme.
    alpha_backend : {"petsoft", "ts"}
        Generalized-alpha by petsoft's own stepper or PETSc TS alpha2.
    spd : bool
        Clamped (positive semi-definite) spring Jacobians for mass-spring models.
    say : callable(str)
        Progress lines (rank 0); default silent.

    Returns
    -------
    SimulationRun
        Final time, state, steps, iterations, energies and probe trajectories (numpy arrays).
    """
    return simulate_experiment(
        experiment, out=None if out is None else Path(out), integrator=integrator,
        recording=recording, restart=restart, solver=solver, explicit_scheme=explicit_scheme,
        alpha_backend=alpha_backend, spd=spd, say=say)


@dataclass(frozen=True, repr=False)
class Modes(Result):
    """Natural frequencies and mode shapes of :func:`modes`, ascending (the same on every rank).

    ``success`` when every requested mode was found with a finite frequency (an inaccurate pair
    raises a :class:`~petsoft.errors.SolverError` instead of returning).

    Attributes
    ----------
    frequencies_hz : ndarray (n,)
    eigenvalues : ndarray (n,)
        omega^2 in (rad/s)^2; exactly 0 for rigid-body modes.
    shapes : ndarray (n, N, 3)
        Mass-normalised mode shapes at the mesh's nodes (zero on supported components).
    relative_errors : ndarray (n,)
        ||K x - omega^2 M x|| / (omega^2 ||M x||) of each pair.
    rigid_modes : int
        How many of the modes are rigid-body modes (the first ones).
    requested : int
    iterations : int
        Krylov-Schur restarts.
    """

    frequencies_hz: np.ndarray
    eigenvalues: np.ndarray
    shapes: np.ndarray
    relative_errors: np.ndarray
    rigid_modes: int
    requested: int
    iterations: int

    @property
    def success(self) -> bool:
        return bool(len(self.frequencies_hz) == self.requested
                    and np.isfinite(self.frequencies_hz).all())

    @property
    def message(self) -> str:
        f = self.frequencies_hz
        span = f"{f[0]:.6g} to {f[-1]:.6g} Hz" if len(f) else "none"
        return (f"{len(f)} of {self.requested} modes, {span} ({self.rigid_modes} rigid body), "
                f"largest relative residual {self.relative_errors.max(initial=0.0):.2g}")


def modes(experiment: Experiment, n: int = 6, *, say=_quiet) -> Modes:
    """The ``n`` lowest natural frequencies and mode shapes of ``experiment`` (``petsoft
    modes``): K x = omega^2 M x at the unloaded reference state, consistent mass, the
    experiment's supports held at zero, solved by SLEPc (options ``-eps_type``, ``-eps_tol``,
    ``-st_pc_factor_mat_solver_type``...). Unsupported rigid motions come first at 0 Hz.

    Parameters
    ----------
    experiment : Experiment
        A continuum ([material]) model.
    n : int
        Number of modes (>= 1).
    say : callable(str)
        Progress lines (rank 0); default silent.

    Returns
    -------
    Modes
    """
    from petsoft.physics.model import build_model
    from petsoft.solvers.modes import compute_modes

    if int(n) < 1:
        raise ValueError(f"modes: n must be >= 1, not {n}")
    comm = PETSc.COMM_WORLD
    mpi = comm.tompi4py()
    model = build_model(experiment, comm)
    result = compute_modes(model, int(n), monitor=say if comm.rank == 0 else None,
                           options=SolverOptions("", experiment.petsc))
    try:
        # gather is collective; rank 0 receives (N, 3) per mode and shares the stack
        shapes = [model.dmesh.gather_global(x) for x in result.modes]
        shapes = mpi.bcast(np.array(shapes) if comm.rank == 0 else None, root=0)
    finally:
        result.destroy()
    return Modes(frequencies_hz=np.asarray(result.frequencies_hz, float),
                 eigenvalues=np.asarray(result.eigenvalues, float), shapes=shapes,
                 relative_errors=np.asarray(result.relative_errors, float),
                 rigid_modes=int(result.rigid_modes), requested=int(n),
                 iterations=int(result.iterations))


def synth(experiment: Experiment, *, out: str | Path, noise: float = 0.0, markers: int = 8,
          markers_file: str | Path | None = None, dropout: float = 0.0, refine: int = 1,
          integrator: str | None = None, seed: int = 0, say=_quiet) -> SynthResult:
    """A synthetic recording of ``experiment`` (``petsoft synth``), truth in ``truth.json``.

    Parameters
    ----------
    experiment : Experiment
        The truth, with ``[time]``.
    out : str or Path
        The recording to write (HDF5).
    noise : float
        Gaussian position noise std (m).
    markers : int
        Random surface-node markers (ignored with ``markers_file``).
    markers_file : str or Path, optional
        Marker reference positions, x y z per line.
    dropout : float
        Fraction of samples dropped (NaN), in [0, 1).
    refine : int
        Simulate on a mesh and step refined by this factor (against the inverse crime).
    integrator : str, optional
        Overrides ``[time] integrator`` for the truth's simulation.
    seed : int
        Seed of the markers, the noise and the dropout.
    say : callable(str)
        Progress lines (rank 0); default silent.

    Returns
    -------
    SynthResult
    """
    options = SynthOptions(out=Path(out), noise=noise, markers=markers,
                           markers_file=markers_file, dropout=dropout, refine=refine,
                           integrator=integrator, seed=seed)
    return _synth(experiment, options, say=say)


def calibrate(experiment: Experiment, recording: Recording | str | Path, *,
              method: str = "gauss-newton", gradient: str = "adjoint",
              integrator: str | None = None, starts: int = 0, seed: int = 0,
              regularization: float = 0.0, noise: float | None = None,
              out: str | Path | None = None, spelled_out: bool = False,
              check_mesh: bool = False, say=_quiet,
              misfit: str = "l2") -> CalibrationResult:
    """Fit the ``[calibrate]`` parameters of ``experiment`` to a recording (``petsoft calibrate``).

    Parameters
    ----------
    experiment : Experiment
        With ``[time]`` and ``[calibrate]`` (dotted keys with bounds; the start is the value in
        the experiment).
    recording : Recording or path
    method : str
        gauss-newton, lbfgs, newton, gd (also spelled gradient-descent), brgn or nelder-mead.
    gradient : str
        adjoint, sensitivity or fd (finite differences).
    integrator : str, optional
        Overrides ``[time] integrator`` (be, si or alpha: those with gradients).
    starts : int
        Extra random starts in the bounds (multi-start for non-convex fits), 0 for none.
    seed : int
        Seed of the random starts.
    regularization : float
        Tikhonov weight towards the start (in scaled parameters).
    noise : float, optional
        Position noise std (m) when the recording has no ``/noise``.
    out : str or Path, optional
        Write calibrated.toml, summary.json and figures here; None writes nothing.
    spelled_out : bool
        calibrated.toml with every value written out, instead of the user's own file with only
        the calibrated values changed.
    check_mesh : bool
        Calibrate again on the mesh refined once (a box's cells doubled, a mesh file split
        1 -> 8) and warn when that moves a parameter by more than its standard deviation
        (``result.mesh_check``: values, shifts in standard deviations, warnings).
    say : callable(str)
        Progress lines (rank 0); default silent.
    misfit : {"l2", "spectral"}
        "spectral": the phase-robust spectral misfit first, then an l2 polish.

    Returns
    -------
    CalibrationResult
        ``names``, ``values``, ``std``, rms before/after, iterations, the fit history.
    """
    return run_calibration(experiment, recording, method=method, gradient=gradient,
                           integrator=integrator, starts=starts, seed=seed,
                           regularization=regularization, noise=noise,
                           out=None if out is None else Path(out), say=say,
                           spelled_out=spelled_out, check_mesh=check_mesh,
                           misfit=misfit)


def calibrate_modes(experiment: Experiment, frequencies, *, out: str | Path | None = None,
                    spelled_out: bool = False, say=_quiet):
    """Fit the ``[calibrate]`` material parameters to measured natural frequencies
    (``petsoft calibrate --modes``).

    Parameters
    ----------
    experiment : Experiment
        A [material] model with its supports; ``[calibrate]`` names material parameters
        (``material[.<region>].youngs_modulus``, ``poisson_ratio``, ``density``).
    frequencies : MeasuredFrequencies, str or Path
        The measured frequencies (Hz, optionally with std and mode shapes at markers), their
        file (:mod:`petsoft.io.frequencies`), or a recording (HDF5) whose frequencies and
        shapes are estimated (:func:`petsoft.calibration.spectra.frequencies_from_recording`).
    out : str or Path, optional
        Write calibrated.toml, summary.json and frequencies.png here; None writes nothing.
    say : callable(str)
        Progress lines (rank 0); default silent.

    Returns
    -------
    FrequencyFit
        ``names``, ``values``, ``std``, the frequencies before and after.
    """
    from petsoft.calibration.frequencies import (
        calibrate_frequencies,
        read_measured_modes,
        write_frequency_outputs,
    )
    from petsoft.io.frequencies import MeasuredFrequencies

    if not isinstance(frequencies, MeasuredFrequencies):
        frequencies = read_measured_modes(frequencies)
    fit = calibrate_frequencies(experiment, frequencies, say=say)
    if out is not None and PETSc.COMM_WORLD.rank == 0:
        write_frequency_outputs(out, experiment, fit, spelled_out=spelled_out)
    return fit


def rest_shape(experiment: Experiment, *, out: str | Path | None = None, load_steps: int = 1,
               say=_quiet):
    """The rest mesh whose static equilibrium is the experiment's (captured) mesh
    (``petsoft rest-shape``): returns a :class:`~petsoft.calibration.rest_shape.RestShape`
    (``.mesh``, ``.points``); ``out`` also writes it (``.vtu``, ``.msh``)."""
    rest = compute_rest_shape(experiment, load_steps=load_steps, say=say)
    if out is not None and PETSc.COMM_WORLD.rank == 0:
        write_rest_mesh(out, rest)
    return rest


def calibrate_rest_shape(experiment: Experiment, recording: Recording | str | Path, *,
                         noise: float | None = None, mode: str = "reduced", say=_quiet):
    """Calibrate when the mesh is a captured equilibrium (``petsoft calibrate --rest-shape``):
    the X/u splitting of :func:`petsoft.calibration.rest_shape.calibrate_rest_shape`; returns
    its ``SplittingResult`` (``values``, ``rest``, ``rms_after``, ``rounds``)."""
    return _calibrate_rest_shape(experiment, recording, noise=noise, mode=mode, say=say)


def diagnose(experiment: Experiment, recording: Recording | str | Path, *,
             out: str | Path | None = None, fraction: float = 0.7, alpha: float = 0.01,
             max_additions: int = 3, max_tries: int = 4, method: str = "gauss-newton",
             gradient: str = "sensitivity", integrator: str | None = None,
             noise: float | None = None, numerics: bool = True, spelled_out: bool = False,
             one_rank_dofs: int = ONE_RANK_DOFS, budget: float | None = DEFAULT_BUDGET,
             reduced_trials: bool = False, say=_quiet) -> DiagnoseResult:
    """Find, model and verify the physics ``experiment`` lacks (``petsoft diagnose``).

    Calibrates the model on the first ``fraction`` of the record, tests the residual against
    the noise, checks the numerics (step and mesh refinement), locates the mismatch, ranks the
    candidate physics terms by score tests, fits the best and keeps one when it predicts the
    held-out rest of the record better; repeats until the residual is noise.

    Parameters
    ----------
    experiment : Experiment
        The user's model, with ``[time]`` and ``[calibrate]``.
    recording : Recording or path
    out : str or Path, optional
        Write report.json, report.md, figures, diagnosed.toml and summary.json here.
    fraction : float
        Share of the record used for identification, in (0, 1]; the rest is held out.
    alpha : float
        Significance level of the verdict and the tests.
    max_additions : int
        At most this many physics terms are added.
    max_tries : int
        At most this many significant candidates are fitted per round.
    method, gradient, integrator
        Calibration options, as for :func:`calibrate`.
    noise : float, optional
        Position noise std (m) when the recording has no ``/noise``.
    numerics : bool
        Run the step and mesh refinement checks.
    spelled_out : bool
        diagnosed.toml with every value written out, instead of the user's own file with the
        calibrated values changed and the added physics appended.
    one_rank_dofs : int
        Under mpiexec, a model of at most this many unknowns runs on one rank (faster: one
        rank solves it directly, several iteratively or each factoring the whole matrix
        anyway); 0 spreads every model over all the ranks.
    budget : float or None
        Wall seconds after which no new piece of work starts; the report then says what was
        left out. None: no budget.
    reduced_trials : bool
        Score an added region's sphere-search trials by a reduced-order model, each poll's
        best verified on the full model (:mod:`petsoft.diagnosis.reduced_trials`).
    say : callable(str)
        Progress lines (rank 0); default silent.

    Returns
    -------
    DiagnoseResult
        ``verdict``, ``added``, ``rejected``, the base and final fits, and the report.
    """
    return run_diagnose(experiment, recording, out=None if out is None else Path(out),
                        fraction=fraction, alpha=alpha, max_additions=max_additions,
                        max_tries=max_tries, method=method, gradient=gradient,
                        integrator=integrator, noise=noise, numerics=numerics, say=say,
                        spelled_out=spelled_out, one_rank_dofs=one_rank_dofs,
                        budget=budget, reduced_trials=reduced_trials)
