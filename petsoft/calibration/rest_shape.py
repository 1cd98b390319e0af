"""The X/u splitting: calibrate a body whose mesh is a captured equilibrium, not its rest shape.

Lecture 000 ("Inverse problem for deformable object"): the many rest positions X and the few
material parameters u are only weakly coupled, so alternate

1. X <- the rest shape for which the captured mesh x is a static equilibrium under the current u
   (inverse statics, :class:`petsoft.solvers.rest_shape.RestShapeSolver`);
2. u <- the usual calibration against the recording, with the mesh's reference positions = X
   (markers given on the captured shape are carried to X by their barycentric coordinates in
   the captured mesh: the P1 map between the two shapes is affine per cell);

until u changes by less than a tolerance. This module owns that loop, the rest-shape computation
of an experiment, and writing the rest mesh.
"""

from __future__ import annotations

import dataclasses
import gc
from dataclasses import dataclass, field
from pathlib import Path

import meshio
import numpy as np
from petsc4py import PETSc

from petsoft.calibration.calibrate import (
    CalibrationResult,
    Observations,
    calibration_parameters,
    run_calibration,
)
from petsoft.calibration.observation import locate_in_tets
from petsoft.errors import ExperimentError, PetsoftError
from petsoft.experiment import with_parameters
from petsoft.io.recording import Recording, read_recording_on_all_ranks
from petsoft.physics.model import build_model, load_mesh, on_root
from petsoft.results import FitResult, Result
from petsoft.solvers.options import SolverOptions
from petsoft.solvers.rest_shape import RestShapeError, RestShapeSolver


@dataclass(repr=False)
class RestShape(Result):
    """A computed rest shape (identical on every rank): ``success`` when every rest position is
    finite (no rest shape found raises a ``RestShapeError`` instead of returning).

    Attributes
    ----------
    captured : Mesh
        The experiment's mesh (the captured, deformed shape).
    mesh : Mesh
        The same mesh with the rest positions as its points.
    newton_iterations, load_steps : int
    """

    captured: object
    mesh: object
    newton_iterations: int = 0
    load_steps: int = 0

    @property
    def points(self) -> np.ndarray:
        return self.mesh.points

    @property
    def success(self) -> bool:
        return bool(np.isfinite(self.points).all())

    @property
    def message(self) -> str:
        shift = float(np.abs(self.captured.points - self.points).max())
        return (f"rest shape in {self.load_steps} load step(s), {self.newton_iterations} Newton "
                f"iterations; the captured shape lies up to {shift:.4g} m from it")


def compute_rest_shape(experiment, comm=None, *, captured=None, initial=None,
                       load_steps: int = 1, say=None) -> RestShape:
    """The rest shape of ``experiment``'s body for its current material parameters.

    Parameters
    ----------
    experiment : Experiment
        Its mesh is the captured shape; materials, gravity and fixed supports as given.
    captured : Mesh, optional
        The captured mesh already loaded (default: the experiment's).
    initial : ndarray (N, 3), optional
        Initial guess of the rest positions in file numbering (default: the captured ones).
    load_steps : int
        Gravity increments of the continuation.

    Raises
    ------
    RestShapeError
        No rest shape found (with the residual history).
    """
    comm = comm if comm is not None else PETSc.COMM_WORLD
    if captured is None:
        captured = on_root(comm, load_mesh, experiment)
        captured = comm.tompi4py().bcast(captured, root=0)
    model = build_model(experiment, comm, mesh=captured)
    solver = RestShapeSolver(model, load_steps=load_steps,
                             monitor=say if comm.rank == 0 else None,
                             options=SolverOptions("rest_shape_", experiment.petsc))
    guess = None if initial is None else np.asarray(initial)[model.dmesh.vertex_ids]
    error = None
    try:
        result = solver.solve(guess)
    except RestShapeError as exc:
        error = exc
    finally:
        solver.destroy()
    if error is not None:
        # Drop the traceback's frames: they hold the model's PETSc objects, which a later
        # garbage collection would destroy at different times on different ranks (a hang at
        # exit on 2 ranks); free them here, collectively.
        del solver, model
        gc.collect()               # on every rank at the same point
        if hasattr(PETSc, "garbage_cleanup"):
            PETSc.garbage_cleanup(comm)
        raise error.with_traceback(None)
    points = model.dmesh.gather(result.points)
    points = comm.tompi4py().bcast(points, root=0)
    rest = dataclasses.replace(captured, points=np.ascontiguousarray(points))
    return RestShape(captured, rest, result.newton_iterations, result.load_steps)


def write_rest_mesh(path: str | Path, rest: RestShape) -> Path:
    """Write the rest mesh (points, tets and the cell tags of the captured mesh) with meshio.

    The format follows the suffix (``.vtu``, ``.msh``, ``.xdmf``, ...).
    """
    path = Path(path)
    mesh = rest.mesh
    cell_data = {}
    tags = getattr(mesh, "cell_tags", None)
    if tags is not None and len(tags) == len(mesh.tets):
        cell_data["cell_tags"] = [np.asarray(tags)]
    displacement = rest.captured.points - mesh.points
    try:
        meshio.write(path, meshio.Mesh(mesh.points, [("tetra", np.asarray(mesh.tets))],
                                       point_data={"captured_minus_rest": displacement},
                                       cell_data=cell_data))
    except (KeyError, ValueError) as exc:   # meshio: unknown suffix
        raise ExperimentError(f"cannot write the rest mesh to {path}: {exc} (use .vtu or .msh)"
                              ) from None
    return path


def rest_markers(recording: Recording, captured, rest) -> Recording:
    """The recording with its marker reference positions carried from the captured shape to
    the rest shape (same barycentric coordinates in the same cell)."""
    cells, weights = locate_in_tets(captured.points, captured.tets, recording.reference,
                                     recording.names, str(recording.source))
    ref = np.einsum("mk,mki->mi", weights, rest.points[captured.tets[cells]])
    return dataclasses.replace(recording, reference=ref)


@dataclass(repr=False)
class SplittingResult(FitResult):
    """The splitting's outcome (identical on every rank): ``success`` when the outer iteration
    converged, ``params`` by name (``param_std`` is NaN: the splitting gives no deviations).

    Attributes
    ----------
    names : list of str
    values : ndarray
        Calibrated parameters.
    rest : RestShape
        The rest shape of the calibrated parameters.
    rms_before, rms_after : float
        Marker rms misfit (m) at the start and the end.
    rounds : list of dict
        Per outer iteration: parameters, rms, largest rest shift.
    converged : bool
    calibration : CalibrationResult or None
        ``mode="alternate"``: the last inner calibration.
    """

    names: list
    values: np.ndarray
    rest: RestShape
    rms_before: float
    rms_after: float
    rounds: list[dict] = field(default_factory=list)
    converged: bool = False
    calibration: CalibrationResult | None = None

    @property
    def std(self) -> np.ndarray:
        return np.full(len(self.names), np.nan)

    @property
    def success(self) -> bool:
        return bool(self.converged)

    @property
    def message(self) -> str:
        state = "converged" if self.converged else "not converged"
        return (f"{state} in {len(self.rounds)} rounds: rms {self.rms_before:.4g} -> "
                f"{self.rms_after:.4g} m")


class _Reduced:
    """Marker residuals of the reduced problem u -> (X(u), simulation): every evaluation first
    solves the inverse statics for u (warm-started from the last rest shape), so the captured
    shape stays the equilibrium for every trial u."""

    def __init__(self, experiment, observations, names, comm, load_steps):
        self.experiment, self.names, self.comm = experiment, names, comm
        self.load_steps = load_steps
        self.captured = comm.tompi4py().bcast(on_root(comm, load_mesh, experiment), root=0)
        keep = observations.window(experiment)
        self.recording = observations.recording
        self.times = self.recording.times[keep]
        self.data = self.recording.positions[keep]
        self.seen = np.isfinite(self.data)
        self.sigma = observations.sigma()[0]
        self.guess, self.rest, self.evaluations = None, None, 0

    def simulate(self, p: np.ndarray) -> np.ndarray:
        exp = with_parameters(self.experiment, dict(zip(self.names, map(float, p), strict=True)))
        rest = compute_rest_shape(exp, self.comm, captured=self.captured, initial=self.guess,
                                  load_steps=self.load_steps)
        self.guess, self.rest = rest.points, rest
        rec = rest_markers(self.recording, self.captured, rest.mesh)
        from petsoft.calibration.calibrate import build_forward
        fm = build_forward(exp, self.names, rec, self.times, self.comm, mesh=rest.mesh)
        try:
            sim = fm.simulate(np.asarray(p, float))
        finally:
            fm.destroy()
        self.evaluations += 1
        return sim

    def residual(self, p: np.ndarray) -> np.ndarray:
        return ((self.simulate(p) - self.data) / self.sigma)[self.seen]

    def rms(self, r: np.ndarray) -> float:
        return float(self.sigma * np.sqrt(np.mean(r ** 2)))


def calibrate_rest_shape(experiment, recording, *, rounds: int = 30, rtol: float = 1e-6,
                         load_steps: int = 1, comm=None, say=None, mode: str = "reduced",
                         fd_step: float = 1e-5, **calibrate_options) -> SplittingResult:
    """Calibrate the ``[calibrate]`` parameters u of a body whose mesh is a captured equilibrium.

    Two forms of the notes' X/u splitting:

    ``mode="reduced"`` (default)
        X is eliminated: X = X(u) by inverse statics inside every evaluation, and u is fitted by
        Levenberg-Marquardt in log-parameters (finite-difference Jacobian of the reduced
        residual, one simulation per parameter: for the few material parameters this is cheap).
    ``mode="alternate"``
        Alternate X <- X(u) and u <- the usual calibration with X fixed
        (:func:`run_calibration`). Converges only when the recording's motion outweighs the
        static sag: with X fixed the static initial state pins u to the previous u (measured on
        the demo cantilever with a sag of 7 cm and motions of 0.5 mm: E drifts 1 % a round,
        away from the truth).

    Parameters
    ----------
    experiment : Experiment
        Its mesh is the captured equilibrium; ``[initial] from = "static"`` starts the
        simulation from it; ``[calibrate]`` names the unknowns and their bounds.
    recording : Recording, Observations or path
        Marker reference positions on the captured shape.
    rounds : int
        Most outer iterations.
    rtol : float
        Stop when the relative parameter change of an iteration falls below ``rtol``.
    calibrate_options
        ``mode="alternate"`` only: passed to :func:`run_calibration`; ``noise`` for both.
    """
    if mode not in ("reduced", "alternate"):
        raise ExperimentError(f"rest-shape mode {mode!r}: valid are reduced, alternate")
    comm = comm if comm is not None else PETSc.COMM_WORLD
    if not isinstance(comm, PETSc.Comm):
        comm = PETSc.Comm(comm)
    noise = calibrate_options.pop("noise", None)
    if isinstance(recording, Observations):
        observations = recording
    else:
        if not isinstance(recording, Recording):
            recording = read_recording_on_all_ranks(recording, comm)
        observations = Observations(recording, noise=noise)
    names, start, bounds = calibration_parameters(experiment)

    def tell(line):
        if say is not None and comm.rank == 0:
            say(line)

    if mode == "alternate":
        return _alternate(experiment, observations, names, start, rounds, rtol, load_steps,
                          comm, tell, calibrate_options)
    problem = _Reduced(experiment, observations, names, comm, load_steps)
    lo = np.log([b[0] for b in bounds])
    hi = np.log([b[1] for b in bounds])
    z = np.log(start)
    r = problem.residual(np.exp(z))
    rms_before = problem.rms(r)
    lam, history, converged = 1e-3, [], False
    for k in range(max(1, int(rounds))):
        # forward-difference Jacobian in log-parameters (identical on every rank)
        J = np.empty((r.size, z.size))
        for j in range(z.size):
            zj = z.copy()
            zj[j] += fd_step
            J[:, j] = (problem.residual(np.exp(zj)) - r) / fd_step
        g, A = J.T @ r, J.T @ J
        accepted = False
        for _ in range(12):
            step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-300), -g)
            z_new = np.clip(z + step, lo, hi)
            try:
                r_new = problem.residual(np.exp(z_new))
            except PetsoftError as exc:       # no rest shape for this trial u: shorten
                tell(f"  trial {np.exp(z_new)}: {str(exc).splitlines()[0]}")
                lam *= 10.0
                continue
            if r_new @ r_new < r @ r:
                accepted, lam = True, max(lam / 10.0, 1e-9)
                break
            lam *= 10.0
        if not accepted:
            converged = bool(np.linalg.norm(g) <= 1e-8 * max(1.0, r @ r))
            tell(f"rest-shape calibration: no further decrease (|g| = {np.linalg.norm(g):.3e})")
            break
        change = float(np.max(np.abs(np.expm1(z_new - z))))
        z, r = z_new, r_new
        values = np.exp(z)
        history.append({"round": k + 1, "parameters": values.tolist(), "rms": problem.rms(r),
                        "rest_shift": float(np.abs(problem.rest.points
                                                   - problem.captured.points).max()),
                        "max_relative_change": change})
        tell(f"round {k + 1}: " + ", ".join(f"{n} = {v:.6g}" for n, v in zip(
            names, values, strict=True)) + f"; rms {problem.rms(r):.4e} m; "
             f"relative change {change:.2e}")
        if change < rtol:
            converged = True
            break
    values = np.exp(z)
    problem.residual(values)     # leave the rest shape of the final values
    return SplittingResult(names, values, problem.rest, rms_before, problem.rms(r), history,
                           converged)


def _alternate(experiment, observations, names, values, rounds, rtol, load_steps, comm, tell,
               calibrate_options) -> SplittingResult:
    """Plain alternation X <- X(u), u <- calibration with X fixed (see calibrate_rest_shape)."""
    current = experiment
    captured = comm.tompi4py().bcast(on_root(comm, load_mesh, experiment), root=0)
    guess, history, calib, converged, rms_before = None, [], None, False, None
    for k in range(max(1, int(rounds))):
        rest = compute_rest_shape(current, comm, captured=captured, initial=guess,
                                  load_steps=load_steps)
        guess = rest.points
        obs = dataclasses.replace(
            observations, recording=rest_markers(observations.recording, captured, rest.mesh))
        calib = run_calibration(current, obs, comm=comm, mesh=rest.mesh, **calibrate_options)
        rms_before = calib.rms_before if rms_before is None else rms_before
        change = np.abs(calib.values - values) / np.abs(values)
        values = calib.values
        history.append({"round": k + 1, "parameters": values.tolist(), "rms": calib.rms_after,
                        "rest_shift": float(np.abs(rest.points - captured.points).max()),
                        "max_relative_change": float(change.max())})
        tell(f"round {k + 1}: " + ", ".join(f"{n} = {v:.6g}" for n, v in zip(
            names, values, strict=True)) + f"; relative change {change.max():.2e}")
        current = with_parameters(experiment, dict(zip(names, values.tolist(), strict=True)))
        if change.max() < rtol:
            converged = True
            break
    rest = compute_rest_shape(current, comm, captured=captured, initial=guess,
                              load_steps=load_steps)
    return SplittingResult(names, values, rest, rms_before, calib.rms_after, history, converged,
                           calib)


def write_splitting_outputs(out: Path, experiment, result: SplittingResult, wall_time: float,
                            comm, spelled_out: bool = False) -> None:
    """calibrated.toml, rest.vtu (the rest mesh of the calibrated parameters) and summary.json
    (rank 0 writes)."""
    from petsoft.experiment.writer import write_experiment_update
    from petsoft.io.summary import write_summary

    if comm.rank == 0:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        calibrated = with_parameters(experiment, dict(zip(result.names, result.values.tolist(),
                                                          strict=True)))
        write_experiment_update(experiment, calibrated, out / "calibrated.toml",
                                spelled_out=spelled_out)
        write_rest_mesh(out / "rest.vtu", result.rest)
    results = {"rest_shape": True,
               "parameters": {n: float(v) for n, v in zip(result.names, result.values,
                                                          strict=True)},
               "rms_before": result.rms_before, "rms_after": result.rms_after,
               "rounds": result.rounds,
               "files": {"experiment": "calibrated.toml", "rest_mesh": "rest.vtu"}}
    solver = {"iterations": len(result.rounds), "converged": result.converged}
    write_summary(Path(out), "calibrate", results, solver, wall_time, comm)
