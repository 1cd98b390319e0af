"""`petsoft calibrate`: fit an experiment's ``[calibrate]`` parameters to a recording.

The pipeline: read and validate the recording, embed its markers in the experiment's body,
build the forward model (simulation + marker observation + gradients), minimise the marker
misfit in scaled parameters with the chosen method (optionally from several starts on
sub-communicators), estimate the parameters' uncertainty from the Gauss-Newton approximation,
and write the results (see :func:`write_outputs`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from petsc4py import PETSc

from petsoft.calibration.check_mesh import check_mesh as check_mesh_refinement
from petsoft.calibration.methods import METHOD_ALIASES, METHODS
from petsoft.calibration.misfit import make_misfit
from petsoft.errors import ExperimentError
from petsoft.experiment import get_parameter, with_parameters
from petsoft.experiment.writer import write_experiment_update
from petsoft.io.progress import IterationPace
from petsoft.io.recording import Recording, read_recording_on_all_ranks
from petsoft.io.summary import write_summary
from petsoft.results import OptimizerFit
from petsoft.solvers.options import SolverOptions

if TYPE_CHECKING:
    from petsoft.calibration.optimize import OptimizeResult

GRADIENTS = ("adjoint", "sensitivity", "fd")


def canonical_method(method: str) -> str:
    """The calibration method ``method`` names (one of :data:`METHODS`; an alias of
    :data:`METHOD_ALIASES` is translated).

    Raises
    ------
    ExperimentError
        For a name that is neither, listing the valid ones.
    """
    method = METHOD_ALIASES.get(method, method)
    if method not in METHODS:
        aliases = ", ".join(f"{a} (= {m})" for a, m in METHOD_ALIASES.items())
        raise ExperimentError(f"unknown calibration method {method!r}; valid: "
                              f"{', '.join(METHODS)}, or {aliases}")
    return method


@dataclass(repr=False)
class CalibrationResult(OptimizerFit):
    """What a calibration found (identical on every rank).

    ``success`` when the optimizer stopped on a convergence test (``reason`` CONVERGED_...);
    ``params`` and ``param_std`` give ``values`` and ``std`` by the ``[calibrate]`` names.
    """

    names: list[str]
    start: np.ndarray
    values: np.ndarray
    std: np.ndarray
    bounds: list[tuple[float, float]]
    rms_before: float
    rms_after: float
    objective_before: float
    objective_after: float
    iterations: int
    evaluations: int
    reason: str
    sigma: float
    sigma_source: str
    noise_estimate: float
    history: list[dict] = field(default_factory=list)
    starts: list[dict] = field(default_factory=list)
    correlation: np.ndarray | None = None
    simulated_before: np.ndarray | None = None
    simulated_after: np.ndarray | None = None
    #: d simulated_after / d values (K, M, 3, P) on the fitted window: the forward
    #: sensitivities at the optimum (None with finite-difference gradients)
    sensitivities_after: np.ndarray | None = None
    #: ``check_mesh=True``: the fit on the refined mesh and the parameters' shifts in standard
    #: deviations (:func:`petsoft.calibration.check_mesh.check_mesh`)
    mesh_check: dict | None = None

    evaluation = "simulations"

    @property
    def message(self) -> str:
        return f"{super().message}: rms {self.rms_before:.4g} -> {self.rms_after:.4g} m"


def calibration_parameters(experiment) -> tuple[list[str], np.ndarray, list[tuple[float, float]]]:
    """Names, start values and bounds of the experiment's ``[calibrate]`` table."""
    if not experiment.calibrate:
        raise ExperimentError(
            f"{experiment.source}: there is nothing to calibrate: add a [calibrate] table with "
            'the unknowns, e.g. "material.youngs_modulus" = [1e4, 1e8]')
    names = list(experiment.calibrate)
    start = np.array([get_parameter(experiment, n) for n in names], dtype=float)
    bounds = [tuple(map(float, experiment.calibrate[n])) for n in names]
    return names, start, bounds


#: Recorded times carry round-off: a frame this share of a window's end past it is in the
#: window, and a first frame this far (s) before t = 0 is at 0.
TIME_ROUNDOFF = 1e-12


def frames_up_to(times: np.ndarray, end: float) -> np.ndarray:
    """Boolean mask of the frames at ``times`` that a window ending at ``end`` (s) holds, to
    :data:`TIME_ROUNDOFF`: the one rule for calibrate's window and diagnose's (the recording
    within ``[time] end``, the identification window within it)."""
    return np.asarray(times) <= end * (1 + TIME_ROUNDOFF)


def frames_in_window(experiment, times: np.ndarray, source: str,
                     end: float | None = None) -> np.ndarray:
    """Boolean mask of the recording frames the simulation covers: 0 <= t <= ``end`` (default
    ``[time] end``).

    Raises
    ------
    ExperimentError
        When frames start before t = 0 (the experiment's initial state is at t = 0) or no frame
        lies in the simulated window.
    """
    if experiment.time is None:
        raise ExperimentError(f"{experiment.source}: [time] (end, step) is needed to calibrate "
                              "against a recording")
    end = experiment.time.end if end is None else float(end)
    if times[0] < -TIME_ROUNDOFF:
        raise ExperimentError(
            f"{source}: the first frame is at t = {times[0]:g} s, before the experiment's initial "
            "state at t = 0: shift the recording's times so that t = 0 is the initial state")
    keep = frames_up_to(times, end)
    if not keep.any():
        raise ExperimentError(
            f"{source}: no frame lies in the simulated window [0, {end:g}] s (the window's end "
            f"or [time] end of {experiment.source}); the recording starts at t = "
            f"{times[0]:g} s")
    return keep


ESTIMATED = "unknown (estimated from the fit)"
#: Who states the position noise (:meth:`Observations.stated_noise`): the recording's
#: ``/noise``, or the caller (``--noise``, ``noise=``).
BY_RECORDING, BY_CALLER = "recording", "caller"


@dataclass(frozen=True)
class Observations:
    """What a calibration fits: a recording's marker positions and the noise to weigh them by.

    The one home of the window checks (:meth:`window`) and the noise policy
    (:meth:`stated_noise`), so that calibrate and its callers (diagnose) do not each re-derive
    them.

    Attributes
    ----------
    recording : Recording
        The data, held by every rank.
    noise : float, optional
        Position noise std (m) to use when the recording has no ``/noise``.
    end : float, optional
        End (s) of the identification window: only frames up to it are fitted (diagnose holds
        the rest out). Default: the experiment's ``[time] end``.
    """

    recording: Recording
    noise: float | None = None
    end: float | None = None

    def window(self, experiment) -> np.ndarray:
        """Boolean mask of the frames ``experiment`` simulates (:func:`frames_in_window`)."""
        if self.recording.positions is None:
            raise ExperimentError(f"{self.recording.source}: the recording has no "
                                  "/frames/position; calibrating against accelerations only is "
                                  "not supported yet")
        return frames_in_window(experiment, self.recording.times, str(self.recording.source),
                                end=self.end)

    def stated_noise(self) -> tuple[float, str] | None:
        """The position noise std (m) the inputs state, and who states it: the recording's
        ``/noise`` (:data:`BY_RECORDING`), else :attr:`noise` (:data:`BY_CALLER`; it must be
        finite and > 0); None when neither does (calibrate then estimates the noise from the
        fit's residual, diagnose from the data before any fit).

        Raises
        ------
        ExperimentError
            When the recording states none and :attr:`noise` is not a positive number.
        """
        recorded = self.recording.noise.get("position_std") if self.recording.noise else None
        if recorded:
            return float(recorded), BY_RECORDING
        if self.noise is None:
            return None
        if not (np.isfinite(self.noise) and self.noise > 0):
            raise ExperimentError(f"--noise = {self.noise}: the position noise std (m) must be "
                                  "> 0")
        return float(self.noise), BY_CALLER

    def sigma(self) -> tuple[float, str]:
        """calibrate's position noise std (m) and where it comes from (:meth:`stated_noise`),
        else 1 with source :data:`ESTIMATED` (the fit's residual then gives it,
        :func:`noise_from_residual`)."""
        stated = self.stated_noise()
        if stated is None:
            return 1.0, ESTIMATED
        value, by = stated
        return value, "the recording's /noise" if by == BY_RECORDING else "--noise"


def noise_from_residual(residual_m: np.ndarray, num_parameters: int) -> float:
    """Noise std estimated from the fit's residual (m): |r|^2 / (m - n)."""
    dof = max(residual_m.size - num_parameters, 1)
    return float(np.sqrt(np.sum(residual_m ** 2) / dof))


def _print_table(say, result: CalibrationResult) -> None:
    say(f"{'parameter':<34} {'start':>12} {'calibrated':>12} {'std':>10} {'rel.std':>8} "
        f"{'bounds':>24}")
    for name, s, v, sd, (lo, hi) in zip(result.names, result.start, result.values, result.std,
                                       result.bounds, strict=True):
        rel = f"{sd / abs(v):.2%}" if v != 0 and np.isfinite(sd) else "-"
        at = " (at bound)" if np.isclose(v, lo, rtol=1e-6) or np.isclose(v, hi, rtol=1e-6) else ""
        say(f"{name:<34} {s:>12.6g} {v:>12.6g} {sd:>10.3g} {rel:>8} "
            f"{f'[{lo:.3g}, {hi:.3g}]':>24}{at}")
    say(f"rms position error {result.rms_before:.4g} m -> {result.rms_after:.4g} m "
        f"(noise {result.sigma:.3g} m, {result.sigma_source}; estimated from the fit "
        f"{result.noise_estimate:.3g} m); {result.iterations} iterations, "
        f"{result.evaluations} simulations; {result.reason}")


def write_outputs(out: Path, experiment, recording_path, result: CalibrationResult,
                  times: np.ndarray, data: np.ndarray, marker_names: list[str],
                  method: str, gradient: str, wall_time: float, comm,
                  spelled_out: bool = False) -> None:
    """calibrated.toml, summary.json, trajectories.png, residuals.png (rank 0 writes).

    calibrated.toml is the user's experiment file with the calibrated values replaced
    (comments and order kept), or with ``spelled_out`` every value written out."""
    from petsoft.calibration.plots import plot_residuals, plot_trajectories

    if comm.rank != 0:
        return
    out.mkdir(parents=True, exist_ok=True)
    calibrated = with_parameters(experiment, dict(zip(result.names, result.values, strict=True)))
    write_experiment_update(experiment, calibrated, out / "calibrated.toml",
                            spelled_out=spelled_out)
    plot_trajectories(out / "trajectories.png", times, data, result.simulated_before,
                      result.simulated_after, marker_names)
    plot_residuals(out / "residuals.png", times, data, result.simulated_before,
                   result.simulated_after, marker_names, result.sigma)
    results = {
        "recording": str(recording_path),
        "method": method,
        "gradient": gradient,
        "parameters": {n: float(v) for n, v in zip(result.names, result.values, strict=True)},
        "std": {n: float(s) for n, s in zip(result.names, result.std, strict=True)},
        "start": {n: float(v) for n, v in zip(result.names, result.start, strict=True)},
        "bounds": {n: list(b) for n, b in zip(result.names, result.bounds, strict=True)},
        "correlation": None if result.correlation is None else result.correlation.tolist(),
        "rms_before": result.rms_before,
        "rms_after": result.rms_after,
        "objective_before": result.objective_before,
        "objective_after": result.objective_after,
        "noise_std": result.sigma,
        "noise_source": result.sigma_source,
        "noise_estimate_from_fit": result.noise_estimate,
        "starts": result.starts,
        "history": result.history,
        "mesh_check": result.mesh_check,
        "files": {"experiment": "calibrated.toml", "trajectories": "trajectories.png",
                  "residuals": "residuals.png"},
    }
    solver = {"iterations": result.iterations, "simulations": result.evaluations,
              "converged_reason": result.reason}
    write_summary(out, "calibrate", results, solver, wall_time, comm)


def _petsc_comm(comm):
    """A PETSc communicator from a PETSc or mpi4py one."""
    return comm if isinstance(comm, PETSc.Comm) else PETSc.Comm(comm)


def build_forward(experiment, names, recording, frame_times, comm, integrator=None, h=None,
                  mesh=None):
    """The forward model of ``experiment`` observing the recording's markers on ``comm``.

    The one factory of calibration's forward models (calibrate, diagnose's fits and scoring
    runs): the experiment's ``[petsc]`` solver options, the recording's measured inputs for
    ``series`` supports, the experiment's system (:func:`petsoft.dynamics.factory.build_system`:
    a continuum or a mass-spring network). ``h`` overrides ``[time] step`` (the numerics check's
    refined step).
    """
    from petsoft.calibration.forward import ForwardModel
    from petsoft.calibration.observation import MarkerObserver

    def observer(system):
        return MarkerObserver(system, recording.reference, recording.names,
                              source=str(recording.source))

    comm = _petsc_comm(comm)
    # the experiment's [petsc] solver choice also for the forward model's own solvers
    return ForwardModel(experiment, names, observer, frame_times, comm=comm,
                        integrator=integrator, h=h, solver_options=experiment.petsc,
                        recording=recording, mesh=mesh)


def _observations(recording, noise: float | None, comm) -> Observations:
    """``recording`` as :class:`Observations`: as given, or a Recording (read from its path
    on rank 0 and shared) with the ``noise`` given."""
    if isinstance(recording, Observations):
        if noise is not None:
            raise ExperimentError("give the noise in the Observations, not also as noise=")
        return recording
    if not isinstance(recording, Recording):
        recording = read_recording_on_all_ranks(recording, comm)
    return Observations(recording, noise=noise)


def _best_of_starts(make_problem, zs, mpi, *, method, scaling, monitor_for, optimizer_options,
                    tell) -> tuple[OptimizeResult, list[dict]]:
    """Fit from each scaled start of ``zs`` on groups of ranks
    (:func:`~petsoft.calibration.multistart.multistart`); returns the best fit and every
    start's report entry (summary.json ``starts``)."""
    from petsoft.calibration.multistart import multistart

    zlo, zhi = scaling.bounds()
    ms = multistart(make_problem, zs, comm=mpi, method=method, bounds=(zlo, zhi),
                    scaling=scaling, monitor_factory=lambda i, sub: monitor_for(i),
                    solver_options=optimizer_options)
    all_starts = [{"index": s.index, "group": s.group,
                   "start": scaling.to_physical(s.start).tolist(),
                   "objective": None if s.result is None else float(s.result.f),
                   "parameters": None if s.result is None else s.result.p.tolist(),
                   "error": s.error} for s in ms.starts]
    opt = ms.best.result
    tell(f"multistart: best of {len(zs)} starts is start {ms.best.index} (f = {opt.f:.6e})")
    return opt, all_starts


def _result_at_optimum(problem, opt, scaling, names, start, bounds, data, sigma, sigma_source,
                       all_starts, tell) -> CalibrationResult:
    """The calibration's result at the optimizer's ``opt``: the fit before (at the user's
    start) and after, the noise estimated from the residual, and the parameters' standard
    deviations and correlations from the Jacobian at the optimum."""
    from petsoft.calibration.uncertainty import UnidentifiableError, uncertainty

    # the user's start, not a polish start; with one start from it, the optimizer's first
    # evaluation (remembered by the problem, as is its last Jacobian at the optimum)
    before = problem.simulate(scaling.to_scaled(start))
    f_before = 0.5 * float(np.sum(problem.data_residual(before) ** 2))
    z = opt.z
    r, J = problem.residual_jacobian(z)
    after = problem.last_simulation
    residual_m = (after - data)[np.isfinite(data)]
    noise_estimate = noise_from_residual(residual_m, len(names))
    try:
        unc = uncertainty(J, r, scaling=scaling, z=z,
                          noise_std=1.0 if sigma_source != ESTIMATED else None)
        std, corr = unc.std, unc.correlation
    except UnidentifiableError as exc:
        tell(f"warning: {exc}")
        std, corr = np.full(len(names), np.inf), None
    if sigma_source == ESTIMATED:
        sigma = noise_estimate
    result = CalibrationResult(
        names=names, start=start, values=scaling.to_physical(z), std=np.asarray(std),
        bounds=bounds, rms_before=problem.rms(before), rms_after=problem.rms(after),
        objective_before=f_before, objective_after=float(opt.f), iterations=opt.iterations,
        evaluations=opt.evaluations, reason=opt.reason, sigma=sigma, sigma_source=sigma_source,
        noise_estimate=noise_estimate,
        history=[{"iteration": h.iteration, "objective": float(h.f), "gradient_norm":
                  float(h.gnorm), "parameters": h.p.tolist()} for h in opt.history],
        starts=all_starts, correlation=None if corr is None else np.asarray(corr),
        simulated_before=before, simulated_after=after,
        sensitivities_after=problem.sensitivities(z))
    return result



def run_calibration(experiment, recording, *, method: str = "gauss-newton",
                    gradient: str = "adjoint", integrator: str | None = None, starts: int = 0,
                    seed: int = 0, regularization: float = 0.0, noise: float | None = None,
                    out: Path | None = None, comm=None, say=None,
                    spelled_out: bool = False, check_mesh: bool = False, mesh=None,
                    misfit: str = "l2", known=None, stop=None) -> CalibrationResult:
    """Calibrate the ``[calibrate]`` parameters of ``experiment`` against a recording.

    Parameters
    ----------
    experiment : Experiment
        The model, with ``[time]`` and ``[calibrate]``.
    recording : Observations, Recording or path
        The data: :class:`Observations` (recording and noise), a
        :class:`~petsoft.io.recording.Recording` already read (every rank holds it), or the
        path of one (read once here, on rank 0, and shared).
    method : one of :data:`METHODS` or :data:`METHOD_ALIASES`
    gradient : one of :data:`GRADIENTS`
    integrator : {"be", "si", "alpha"}, optional
        Overrides ``[time] integrator`` for the forward model.
    starts : int
        0: one start from the experiment's values; k > 0: that start plus k random starts in
        the bounds, spread over sub-communicators (one group per rank).
    noise : float, optional
        Position noise std (m) to use when the recording has no ``/noise``; otherwise it is
        estimated from the calibrated residual. Not with ``Observations`` (they carry it).
    out : Path, optional
        Where to write the results (:func:`write_outputs`); None writes nothing.
    spelled_out : bool
        Write calibrated.toml with every value spelled out instead of as the user's file with
        the calibrated values replaced.
    say : callable(str), optional
        Progress lines (called on rank 0 only).
    check_mesh : bool
        After the fit, calibrate again on the mesh refined once (from the calibrated values)
        and warn when that moves a parameter by more than its standard deviation
        (:func:`petsoft.calibration.check_mesh.check_mesh`; ``result.mesh_check``).
    misfit : {"l2", "spectral"}
        "spectral": first minimise the phase-robust spectral misfit
        (:mod:`petsoft.calibration.misfit`, a wider basin), then polish with l2 from there, so
        the result is l2's minimiser.
    mesh : Mesh, optional
        The body's reference mesh instead of the experiment's (the rest shape of
        :func:`petsoft.calibration.rest_shape.calibrate_rest_shape`).
    known : (sim, columns), optional
        The simulation of the window's frames at the start values (K, M, 3) and its forward
        sensitivities ``{parameter: (K, M, 3)}`` for every ``[calibrate]`` parameter, computed
        elsewhere (diagnose's scoring run): the fit's first evaluation then costs no run.
    stop : callable(IterationRecord) -> bool, optional
        Ends the fit early (:func:`~petsoft.calibration.optimize.minimize`'s ``stop``; the
        result's ``reason`` is then ``STOPPED_BY_CALLER``); one start only.
    """
    from petsoft.calibration.multistart import random_starts
    from petsoft.calibration.objective import MarkerMisfit
    from petsoft.calibration.optimize import minimize
    from petsoft.calibration.scaling import ParameterScaling

    t_start = time.perf_counter()
    comm = _petsc_comm(comm if comm is not None else PETSc.COMM_WORLD)
    mpi = comm.tompi4py()
    rank0 = mpi.rank == 0

    def tell(line):
        if say is not None and rank0:
            say(line)

    method = canonical_method(method)
    if gradient not in GRADIENTS:
        raise ExperimentError(f"unknown gradient method {gradient!r}; valid: "
                              f"{', '.join(GRADIENTS)}")
    observations = _observations(recording, noise, comm)
    recording = observations.recording
    recording_path = recording.source
    names, start, bounds = calibration_parameters(experiment)
    keep = observations.window(experiment)
    times, data = recording.times[keep], recording.positions[keep]
    sigma, sigma_source = observations.sigma()
    lower = np.array([b[0] for b in bounds])
    upper = np.array([b[1] for b in bounds])
    scaling = ParameterScaling(names, start, lower, upper)
    zlo, zhi = scaling.bounds()
    # the optimizer's options (prefix cal_) from the experiment's [petsc] table
    optimizer_options = SolverOptions("cal_", experiment.petsc)
    tell(f"petsoft calibrate: {len(names)} parameter(s) {', '.join(names)}; "
         f"{len(times)} frames x {recording.num_markers} markers "
         f"({int(np.isfinite(data).all(axis=2).sum())} seen samples); method {method}, "
         f"gradient {gradient}; {mpi.size} rank(s)")

    def make_problem(subcomm, transform=None):
        fm = build_forward(experiment, names, recording, times, subcomm, integrator, mesh=mesh)
        return MarkerMisfit(fm, data, scaling, sigma=sigma, gradient=gradient,
                            regularization=regularization, misfit=transform)

    def monitor_for(index):
        pace = IterationPace()

        def monitor(rec):
            label = f"start {index}: " if starts else ""
            params = ", ".join(f"{n}={v:.6g}" for n, v in zip(names, rec.p, strict=True))
            tell(f"  {label}it {rec.iteration:3d}  f {rec.f:.6e}  |g| {rec.gnorm:.3e}  "
                 f"sims {rec.evaluations:3d}  {params}  ({pace.update(rec.iteration, rec.f)})")
        return monitor

    z0 = scaling.to_scaled(start)
    transform = make_misfit(misfit, data, f"{experiment.source}: misfit")
    if transform is not None:
        if starts > 0:
            raise ExperimentError("misfit = \"spectral\" with random starts: choose one")
        wide = make_problem(comm, transform)
        opt = minimize(wide, z0, method=method, bounds=(zlo, zhi), scaling=scaling,
                       monitor=monitor_for(0), solver_options=optimizer_options)
        wide.forward.destroy()
        tell("spectral misfit: minimum at " + ", ".join(
            f"{n}={v:.6g}" for n, v in zip(names, scaling.to_physical(opt.z), strict=True))
             + "; polishing with l2")
        z0 = opt.z
    all_starts: list[dict] = []
    if starts > 0:
        opt, all_starts = _best_of_starts(
            make_problem, random_starts(zlo, zhi, starts, seed=seed, include=z0), mpi,
            method=method, scaling=scaling, monitor_for=monitor_for,
            optimizer_options=optimizer_options, tell=tell)
    problem = make_problem(comm)
    if known is not None and starts == 0 and transform is None:
        sim0, columns = known
        problem.remember_sensitivities(z0, sim0, np.stack([columns[n] for n in names],
                                                          axis=-1))
    if starts == 0:
        opt = minimize(problem, z0, method=method, bounds=(zlo, zhi), scaling=scaling,
                       monitor=monitor_for(0), stop=stop, solver_options=optimizer_options)
    result = _result_at_optimum(problem, opt, scaling, names, start, bounds, data, sigma,
                                sigma_source, all_starts, tell)
    if say is not None and rank0:
        _print_table(say, result)
    if check_mesh:
        result.mesh_check = check_mesh_refinement(
            experiment, result,
            lambda fine: run_calibration(fine, observations, method=method, gradient=gradient,
                                         integrator=integrator, regularization=regularization,
                                         comm=comm),
            tell)
    if out is not None:
        write_outputs(Path(out), experiment, recording_path, result, times, data,
                      recording.names, method, gradient, time.perf_counter() - t_start, comm,
                      spelled_out=spelled_out)
        tell(f"wrote {out}/ (calibrated.toml, summary.json, trajectories.png, residuals.png)")
    problem.forward.destroy()
    return result
