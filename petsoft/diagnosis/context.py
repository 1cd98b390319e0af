"""What a diagnosis run knows and does to one model: the context of :func:`run_diagnose`.

:class:`Diagnosis` holds the recording split into the identification and held-out windows, the
noise level and its source, the communicator and the calibration options, fixed when the run
starts; it calibrates a model on the identification window and predicts the held-out one
(:class:`Fit`), simulates, scores a candidate, and maps where added stiffness or mass would lower
the misfit. :func:`evidence_of` is the mismatch analysis of one fit.
"""

from __future__ import annotations

import functools
import gc
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from petsc4py import PETSc

from petsoft.calibration.calibrate import (
    BY_RECORDING,
    TIME_ROUNDOFF,
    Observations,
    build_forward,
    calibration_parameters,
    frames_up_to,
    run_calibration,
)
from petsoft.calibration.optimize import STOPPED, iteration_limit
from petsoft.diagnosis.budget import FitStop, TimeBudget, Unfinished
from petsoft.diagnosis.pace import CannotWin
from petsoft.diagnosis.placement import ONE_RANK_DOFS, Placement
from petsoft.diagnosis.records import Evidence, ScoreEntry
from petsoft.dynamics.factory import system_class
from petsoft.dynamics.integrators import scheme
from petsoft.dynamics.parameters import VISCOELASTIC
from petsoft.errors import ExperimentError, PetsoftError
from petsoft.experiment import get_parameter, with_parameters
from petsoft.io.progress import doing, touch
from petsoft.io.recording import Recording, read_recording_on_all_ranks
from petsoft.solvers.options import scoped_defaults

#: diagnose's fits stop when Gauss-Newton's next step is below sqrt(FIT_DTOL) = 0.1 of the
#: parameters' standard deviation (``-cal_lm_dtol``; calibrate's own default 1e-6 is 1e-3):
#: chi2 is then within about FIT_DTOL (chi2/dof) of its minimum, far below what decides a
#: likelihood-ratio test or the verdict. The independent L-bracket's viscoelastic candidate
#: (finite-difference gradients, 50 s an iteration) spent its last five of 13 iterations moving
#: chi2 by less than 1.
FIT_DTOL = 1e-2
#: diagnose's forward runs stop a time step's Newton iteration when its residual has fallen by
#: this factor (``-fm_snes_rtol``; the forward model's own default is 1e-12, for gradients as
#: exact as the solves), unless the user set it. The chord's last iterations only chase
#: round-off: on the independent control-plate's 10-node model (3672 dofs, 140 steps of 2 ms,
#: a forward run and its sensitivities: scripts/benchmarks/bench_newton_tolerance.py) 8.4
#: residuals and 7.9 back-substitutions a step at 1e-12, 5.5 and 5.0 at 1e-6, and the markers
#: moved by at most 5e-5 of the recording's noise: a chi2 change of ~1e-3 on ~5,000 samples,
#: where a term is added for 6.6.
NEWTON_RTOL = 1e-6
#: a round's shared scoring run is used when its simulation is within this many noise
#: standard deviations (rms) of the current model's: its candidates' terms then start off.
#: Not tighter: at NEWTON_RTOL a run with sensitivities and a plain forward run of the same
#: model take different chord paths (the tangent's fresh factors) and differ by ~1.4e-5 of the
#: noise (the realistic damping case's 10-node model, 0.2 s); at 1e-6 every shared run of a
#: round whose current fit came from a forward-only refit was thrown away, and its ten
#: candidates scored one by one (45 s spent, 90 s more). A term that does not start off moves
#: the simulation by far more than 1e-3 of the noise where it matters to a score.
SHARED_RUN_TOLERANCE = 1e-3


class DiagnoseError(PetsoftError):
    """``petsoft diagnose`` cannot run on these inputs; the message says what and where."""


@dataclass
class Fit:
    """One calibrated model: experiment (calibrated values set), its parameter names/values/std,
    chi2 and rms on the identification window, rms on the held-out window, simulations."""

    experiment: object
    names: list[str]
    values: np.ndarray
    std: np.ndarray
    chi2: float
    rms: float
    heldout_rms: float | None
    sim: np.ndarray
    iterations: int = 0
    evaluations: int = 0
    #: why the fit was stopped before it converged (:class:`~petsoft.diagnosis.pace.CannotWin`)
    stopped: str = ""
    #: how the fit was made when not by a calibration (:mod:`petsoft.diagnosis.chord_refit`)
    by: str = ""
    #: its wall time (s) on the first rank of the ranks that made it (travels with the fit
    #: gathered from a group: the time budget foresees a calibration by it, geometry.py)
    seconds: float = 0.0
    #: (:func:`sensitivities_key`, d sim / d values (K, M, 3, P) on the identification window)
    #: of the calibration's last Jacobian run, at these values: travels with the fit (every
    #: rank gets it), so that numerics.model_sensitivities needs no run of its own; None when
    #: the fit made none (finite differences). Checked against the key where it is used: a
    #: Fit copied with other values does not pass it on.
    sensitivities: tuple | None = field(default=None, repr=False, compare=False)


def mesh_key(experiment) -> tuple:
    """What identifies ``experiment``'s discretisation in space (mesh file or box, refinement,
    element order): with the step, the key of a measured run (``Diagnosis.measured_meshes``)."""
    m = experiment.mesh
    return (str(m.file), m.refine, m.order, tuple(m.box.cells) if m.box is not None else None)


def sensitivities_key(fit: Fit) -> tuple:
    """The ``Diagnosis.measured_meshes`` key of ``fit``'s forward sensitivities on the
    identification window (its mesh, step and values)."""
    exp = fit.experiment
    return ("sensitivities", mesh_key(exp), exp.time.step, tuple(map(float, fit.values)))


def term_values(fit: Fit, names) -> tuple[dict, dict]:
    """({name: value}, {name: std}) of a term's parameters ``names`` in ``fit`` (the report
    entry's ``parameters`` and ``std``: deviations only where finite; names the fit does not
    calibrate are left out)."""
    have = [n for n in names if n in fit.names]
    values = {n: float(fit.values[fit.names.index(n)]) for n in have}
    std = {n: float(fit.std[fit.names.index(n)]) for n in have
           if np.isfinite(fit.std[fit.names.index(n)])}
    return values, std


def _changed(value, original):
    """``value``, or None when it is ``original`` itself."""
    return None if value is original else value


def position_noise(observations: Observations, data: np.ndarray,
                   times: np.ndarray) -> tuple[float, str]:
    """diagnose's position noise std (m) and where it comes from: the one the inputs state
    (:meth:`Observations.stated_noise <petsoft.calibration.calibrate.Observations.
    stated_noise>`: the recording's ``/noise``, else ``--noise``), else estimated from the
    recorded positions ``data`` at ``times`` (:func:`~petsoft.diagnosis.noise.summary_std`):
    the scores and the verdict need it before any fit."""
    from petsoft.diagnosis.noise import NoiseError, noise_summary, summary_std

    try:
        stated = observations.stated_noise()
    except ExperimentError as exc:
        raise DiagnoseError(str(exc)) from exc
    if stated is not None:
        value, by = stated
        return value, "given by the recording" if by == BY_RECORDING else "given (--noise)"
    try:
        return summary_std(noise_summary(data, times)), "estimated from the data"
    except NoiseError as exc:
        raise DiagnoseError(f"{observations.recording.source}: the recording has no /noise "
                            f"and {exc}; give the noise with --noise") from exc


def petsc_comm(comm):
    if comm is None:
        return PETSc.COMM_WORLD
    return comm if isinstance(comm, PETSc.Comm) else PETSc.Comm(comm)


def gradient_for(experiment, default: str, integrator: str | None = None) -> str:
    """The calibration gradient ``experiment`` allows: once the viscoelastic branch is on or
    calibrated, the forward sensitivities of an integrator that carries its internal variable
    (be, alpha: a 3-parameter branch fit on the independent bracket took ~4 runs an iteration
    by finite differences, 1145 s), else finite differences (the adjoint does not carry it)."""
    cal = set(experiment.calibrate or {})
    try:
        ratio = float(get_parameter(experiment, "viscoelastic.ratio"))
    except ExperimentError:
        ratio = 0.0
    if ratio != 0.0 or any(n.startswith("viscoelastic.") for n in cal):
        carried = scheme(integrator or experiment.time.integrator).branch_sensitivities
        return "sensitivity" if carried and default == "sensitivity" else "fd"
    return default


def model_scales(experiment, times: np.ndarray, data: np.ndarray,
                 evidence: Evidence | None = None) -> dict:
    """Sizes that bound the candidates' new parameters (:func:`~petsoft.diagnosis.candidates.
    build_candidates`): ``mass`` (kg), ``area`` (exterior surface, m^2), ``length`` (bounding-box
    diagonal, m), ``cell`` (mean cell size, m) of the model; ``speed``/``speed_max`` (rms and
    largest marker speed, m/s, by differences of the seen samples) and ``frequency`` (the data's
    dominant modal frequency, Hz, when the evidence found one). The body's sizes are its system
    class's ``body_sizes`` (:class:`petsoft.dynamics.factory.ExperimentSystem`)."""
    out = system_class(experiment).body_sizes(experiment)
    dt = np.diff(times)[:, None, None]
    vel = np.diff(data, axis=0) / dt
    speed = np.linalg.norm(vel, axis=2)
    speed = speed[np.isfinite(speed)]
    out["speed"] = float(np.sqrt(np.mean(speed**2))) if speed.size else 1.0
    out["speed_max"] = float(speed.max()) if speed.size else 1.0
    out["speed"] = out["speed"] or 1.0
    out["speed_max"] = out["speed_max"] or 1.0
    modes = (evidence.data_modes if evidence is not None else None) or []
    osc = [m for m in modes if m["frequency_hz"] > 0]
    out["frequency"] = (float(max(osc, key=lambda m: m["amplitude"])["frequency_hz"])
                        if osc else None)
    return out


def chi2(sim, data, sigma) -> float:
    seen = np.isfinite(data)
    return float(np.sum(((sim[seen] - data[seen]) / sigma) ** 2))


def rms(sim, data) -> float | None:
    seen = np.isfinite(data)
    if not seen.any():
        return None
    return float(np.sqrt(np.mean((sim[seen] - data[seen]) ** 2)))


def fmt(x) -> str:
    return "-" if x is None else f"{x:.4g}"


def format_values(names, values) -> str:
    return ", ".join(f"{n}={v:.6g}" for n, v in zip(names, values, strict=True))


def cell_geometry(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(centroids (E, 3), volumes (E,)) of the whole mesh."""
    p = mesh.points[mesh.tets]
    vol = np.abs(np.linalg.det(p[:, 1:] - p[:, :1])) / 6.0
    return p.mean(axis=1), vol


class Diagnosis:
    """State shared by the steps (recording split, noise, communicator, options)."""

    #: score the sphere searches' trials by a reduced model, each poll's best verified on the
    #: full model (:mod:`petsoft.diagnosis.reduced_trials`; ``diagnose --reduced-trials``)
    reduced_trials: bool = False

    def __init__(self, experiment, recording, *, fraction, alpha, method, gradient,
                 integrator, noise, comm, say, one_rank_dofs: int = ONE_RANK_DOFS):
        self.comm = petsc_comm(comm)
        #: the run's time budget (run_diagnose sets the user's; none by default)
        self.budget = TimeBudget(None, time.perf_counter(), self.comm)
        #: where each model runs: a small one on one rank (placement.py)
        self.placement = Placement(self.comm, one_rank_dofs)
        self.rank0 = self.comm.tompi4py().rank == 0
        self.say = say
        self.t0 = time.perf_counter()
        self.method, self.gradient, self.integrator = method, gradient, integrator
        self.alpha = float(alpha)
        if not 0.0 < fraction <= 1.0:
            raise DiagnoseError(f"--fraction = {fraction}: the identification window's share "
                                "of the record must be in (0, 1]")
        if not 0.0 < self.alpha < 1.0:
            raise DiagnoseError(f"--alpha = {alpha}: the significance level must be in (0, 1)")
        if not isinstance(recording, Recording):
            recording = read_recording_on_all_ranks(recording, self.comm)
        rec = self.recording = recording
        self.path = recording.source
        if rec.positions is None:
            raise DiagnoseError(f"{self.path}: the recording has no /frames/position; diagnose "
                                "needs marker positions")
        if experiment.time is None:
            raise DiagnoseError(f"{experiment.source}: [time] (end, step) is needed")
        if not experiment.calibrate:
            raise DiagnoseError(f"{experiment.source}: diagnose calibrates the model as given "
                                'first: add a [calibrate] table, e.g. "material.youngs_modulus" '
                                "= [1e4, 1e8]")
        keep = frames_up_to(rec.times, experiment.time.end)
        if rec.times[0] < -TIME_ROUNDOFF or keep.sum() < 4:
            raise DiagnoseError(f"{self.path}: need at least 4 frames in [0, "
                                f"{experiment.time.end:g}] s ([time] end of {experiment.source}); "
                                f"the recording has "
                                f"{int(keep.sum())} (first at t = {rec.times[0]:g} s)")
        self.times = rec.times[keep]
        self.data = rec.positions[keep]
        span = self.times[-1]
        self.cut = float(fraction * span)
        ident = frames_up_to(self.times, self.cut)
        if ident.sum() < 4:
            raise DiagnoseError(f"--fraction = {fraction}: the identification window [0, "
                                f"{self.cut:g}] s holds {int(ident.sum())} frames; at least 4 "
                                "are needed")
        self.ident = ident
        self.held = ~ident
        self.base_experiment = experiment
        self.model_error = {}
        #: mesh refinements measured by one run (too large to fit), per (label, mesh): their
        #: options in the numerics rounds (:func:`petsoft.diagnosis.numerics.measure_refinement`)
        self.measured_meshes: dict = {}
        #: typical mass, area, speed... of the model (candidate parameter scales), fixed by
        #: :meth:`fix_scales` once the base model's numerics are settled
        self.scales: dict | None = None
        #: cell centroids of the last sensitivity maps (None before the first)
        self.centroids: np.ndarray | None = None
        #: wall time of every fit so far (what a round of fits is estimated from)
        self.fit_seconds: list[float] = []
        #: (fit, simulation, parameter values, columns) of the last shared scoring run: the
        #: switches' scores of the same fit reuse its current-model columns (:meth:`_score`), and
        #: a candidate fit starting where it was scored begins from them (:meth:`known_start`)
        self._scored: tuple | None = None
        self.sigma, self.sigma_source = position_noise(Observations(rec, noise=noise),
                                                       self.data, self.times)
        #: what every calibration of the run fits: the identification window's frames,
        #: weighed by the noise decided above
        self.observations = Observations(rec, noise=self.sigma, end=self.cut)

    #: Estimated discretisation error (m, rms) of the current model per refinement kind, from
    #: :func:`resolve_numerics` (Richardson: the change under refinement over 2^p - 1).
    model_error: dict

    @property
    def sigma_verdict(self) -> float:
        """The noise plus the measured discretisation error (in quadrature): the level the
        verdict tests the residual against, since a mismatch the model's own numerics can
        explain is no evidence of missing physics."""
        return float(np.sqrt(self.sigma**2 + sum(e**2 for e in self.model_error.values())))

    def fix_scales(self, fit: Fit, ev: Evidence) -> None:
        """The candidates' parameter scales, from ``fit`` on the identification window."""
        self.scales = model_scales(fit.experiment, self.times[self.ident], self.data[self.ident],
                                   ev)

    def dof(self, n_parameters: int) -> int:
        """Degrees of freedom of a fit of ``n_parameters`` on the identification window: its
        seen samples less the parameters (at least 1)."""
        return max(int(np.isfinite(self.data[self.ident]).sum()) - n_parameters, 1)

    def excess(self, fit: Fit) -> float:
        """chi2 above its expectation (the degrees of freedom) on the identification window."""
        return max(fit.chi2 - self.dof(len(fit.names)), 0.0)

    def tell(self, line: str) -> None:
        touch()                         # the heartbeat waits another interval (every rank)
        if self.say is not None and self.rank0:
            self.say(f"[{time.perf_counter() - self.t0:7.1f} s] {line}")

    def group_says(self, comm, line: str) -> None:
        """A progress line of work on a group of ranks (a candidate fit), said by the group's
        first rank and indented as a fit's lines (:meth:`tell` speaks for rank 0 only)."""
        if self.say is not None and petsc_comm(comm).tompi4py().rank == 0:
            touch()
            self.say(f"[{time.perf_counter() - self.t0:7.1f} s]   {line}")

    # -- fitting ----------------------------------------------------------------------------
    def frequency_matched(self, experiment, sim: np.ndarray | None = None, comm=None,
                          label: str = "fit", target: float = 1.0, with_sim: bool = False):
        """``experiment`` with its Young's modulus rescaled so that the dominant oscillation of
        the simulated markers has the data's frequency, when that lowers the misfit; else as it
        is. The misfit of a swinging body is not convex in E: a start off by a fraction of a
        period per record converges to a phase-wrapped minimum (the independent finger with a
        stiff root: the 4-node base fit went from 1.4e7 down to 1.08e7 Pa, chi2/dof 59, and the
        10-node refit from there to 1.59e7, both wrong, and nothing was found). Frequencies go
        as sqrt(E), so E (f_data / f_model)^2 starts in the right basin. ``sim``: the markers
        simulated at ``experiment``'s values, if already made. ``target``: the ratio data /
        simulated to aim at (a refinement aims at its current fit's, which other physics may
        keep off 1: aiming at 1 there cost a run rejected as "kept the start" in most numerics
        refits of the independent suite). ``with_sim`` (with ``comm``): returns (experiment,
        its identification-window simulation)."""
        name = "material.youngs_modulus"
        if name not in (experiment.calibrate or {}):
            return (experiment, sim) if with_sim else experiment
        if comm is None:
            # None for "as it is", so that an unchanged experiment comes back as itself
            moved = self.placement.alone(
                lambda sub: _changed(self.frequency_matched(experiment, sim, comm=sub,
                                                            label=label, target=target),
                                     experiment), experiment)
            return experiment if moved is None else moved
        comm = petsc_comm(comm)
        if sim is None:
            with doing(label):
                sim = self.simulate_identification(experiment, comm=comm)
        current = experiment
        misfit = chi2(sim[self.ident], self.data[self.ident], self.sigma)
        # repeated: on a short window the two estimates share a bias that cancels as the
        # frequencies meet (the test cantilever: 0.25 E -> 0.81 E -> E)
        for _ in range(3):
            ratio = self.frequency_ratio(sim)
            if ratio is None:
                break
            ratio /= target
            E = float(get_parameter(current, name))
            lo, hi = experiment.calibrate[name]
            scaled = float(np.clip(E * ratio**2, lo, hi))
            if abs(scaled / E - 1.0) < 0.02:
                break
            moved = with_parameters(current, {name: scaled})
            with doing(label):
                moved_sim = self.simulate_identification(moved, comm=comm)
            gc.collect()                # every rank, same point (see run_diagnose)
            after = chi2(moved_sim[self.ident], self.data[self.ident], self.sigma)
            of = f" ({ratio:.4g}x the current fit's {target:.4g})" if target != 1.0 else ""
            self.tell(f"  {label}: dominant frequencies data / simulated "
                      f"{ratio * target:.4g}{of}: E {E:.4g} -> {scaled:.4g} Pa, chi2 "
                      f"{misfit:.5g} -> {after:.5g}"
                      + ("" if after < misfit else ": kept the start"))
            if after >= misfit:
                break
            current, sim, misfit = moved, moved_sim, after
        return (current, sim) if with_sim else current

    def frequency_ratio(self, sim: np.ndarray) -> float | None:
        """The data's dominant oscillation frequency over the simulation's (identification
        window), None when either has no oscillation."""
        f_sim = dominant_frequency(self.times[self.ident], sim[self.ident])
        if self.data_frequency is None or f_sim is None:
            return None
        return self.data_frequency / f_sim

    @functools.cached_property
    def data_frequency(self) -> float | None:
        """The data's dominant oscillation frequency (Hz) on the identification window."""
        return dominant_frequency(self.times[self.ident], self.data[self.ident])

    def calibrate(self, experiment, comm=None, label: str = "fit", known=None,
                  stop=None) -> Fit:
        """Calibrate ``experiment`` on the identification window; predict the held-out one.

        ``comm`` (default: the diagnosis' communicator) lets candidate fits run on groups of
        ranks (:func:`petsoft.calibration.groups.map_on_groups`). Each iteration of the fit is
        a progress line naming it by ``label`` (printed by the first rank of ``comm``: fits on
        groups of ranks report side by side), so a round of fits is never silent for long.
        ``known``: the simulation and sensitivity columns at the start (:meth:`known_start`);
        ``stop``: a :class:`~petsoft.diagnosis.pace.CannotWin` ending the fit early (the
        fit's ``stopped`` then says why)."""
        if comm is None:
            return self.placement.alone(
                lambda sub: self.calibrate(experiment, comm=sub, label=label, known=known,
                                           stop=stop), experiment)
        comm = petsc_comm(comm)
        started = time.perf_counter()
        # the identification window travels with the data, not as a rewritten [time] end
        with scoped_defaults(cal_lm_dtol=str(FIT_DTOL)), doing(label):
            res = run_calibration(experiment, self.observations, method=self.method,
                                  gradient=gradient_for(experiment, self.gradient,
                                                        self.integrator),
                                  integrator=self.integrator, comm=comm,
                                  say=self._iteration_lines(label), known=known, stop=stop)
        gc.collect()                    # every rank, same point (see run_diagnose)
        names, _, _ = calibration_parameters(experiment)
        calibrated = with_parameters(experiment, dict(zip(names, res.values, strict=True)))
        sim = self.simulate(calibrated, comm=comm)
        seconds = time.perf_counter() - started
        self.fit_seconds.append(seconds)
        fit = Fit(experiment=calibrated, names=names, values=np.asarray(res.values),
                  std=np.asarray(res.std), chi2=chi2(sim[self.ident], self.data[self.ident],
                                                       self.sigma),
                  rms=rms(sim[self.ident], self.data[self.ident]) or 0.0,
                  heldout_rms=rms(sim[self.held], self.data[self.held]) if self.held.any()
                  else None, sim=sim, iterations=res.iterations, evaluations=res.evaluations,
                  stopped=stop.why if stop is not None and res.reason == STOPPED else "",
                  seconds=seconds)
        # the fit's own sensitivities at its optimum are the numerics checks' and the sphere
        # searches' (numerics.model_sensitivities): carried by the fit (it reaches every
        # rank), they cost those no Jacobian run
        dsim = res.sensitivities_after
        if dsim is not None and dsim.shape[:3] == self.data[self.ident].shape:
            fit = replace(fit, sensitivities=(sensitivities_key(fit), dsim))
        return fit

    def round_estimate(self, names: list[str]) -> str:
        """A line announcing a round of fits and roughly how long it takes: the fits so far
        (the longest) times the fits per group of ranks (they run side by side)."""
        groups = max(1, min(self.comm.getSize(), len(names)))
        per_group = -(-len(names) // groups)
        line = f"fitting {len(names)} candidate(s) ({', '.join(names)}) on {groups} group(s)"
        if self.fit_seconds:
            guess = max(self.fit_seconds) * per_group
            line += (f"; roughly {guess:.0f} s (a fit so far took up to "
                     f"{max(self.fit_seconds):.0f} s; a candidate has more parameters)")
        return line

    def _iteration_lines(self, label: str):
        """What a fit's ``say`` gets: its iteration lines, labelled and timed, to ``self.say``
        (the fit's header and final table stay quiet: the diagnosis reports the result)."""
        if self.say is None:
            return None

        def say(line: str) -> None:
            text = line.strip()
            if text.startswith(("it ", "start ")):
                touch()
                self.say(f"[{time.perf_counter() - self.t0:7.1f} s]   {label}: {text}")

        return say

    def fit_candidates(self, scored: list, current: Fit, rivals: list | None = None) -> None:
        """Calibrate each candidate of ``scored`` ((score entry, candidate) pairs) not fitted
        yet, extending ``current``'s model, concurrently on groups of ranks; each entry's ``fit``
        is set (None when the fit failed) and its ``fit_error``.

        A fit that can no longer win (:class:`~petsoft.diagnosis.pace.CannotWin`) against the
        best finished so far -- among ``rivals`` ((physics, Fit) pairs fitted earlier in the
        round) and the fits before it on its group of ranks -- is stopped; its ``stopped``
        says why. Once the time budget is spent a fit is not started, or stopped at its next
        iteration: its entry then has no ``fit`` but ``unfinished`` (why;
        :mod:`petsoft.diagnosis.budget`)."""
        need = [(s, c) for s, c in scored if not s.tried]
        if need:
            self.tell(self.round_estimate([c.physics for _, c in need]))
        # (f = chi2 / 2, physics) of the best finished fit; each group updates its own copy
        best = min(((f.chi2 / 2.0, name) for name, f in rivals or [] if not f.stopped),
                   default=(np.inf, ""))
        max_it = iteration_limit(self.method)

        def fit(item, sub):
            nonlocal best
            label = f"candidate {item[1].physics}"
            if self.budget.spent(sub):      # a round's fits under the budget: budget.py
                self.group_says(sub, f"{label}: not started: the time budget is spent")
                return Unfinished("not started", self.budget.elapsed())
            ext = item[1].extend(current.experiment)
            known = self.known_start(ext, current)
            if known is None:
                ext = self.scanned_start(ext, item[1], sub, label)
            stop = FitStop(self.budget, sub, CannotWin(*best, max_it=max_it))
            result = self.calibrate(ext, comm=sub, label=label, known=known, stop=stop)
            if stop.cut is not None:
                self.group_says(sub, f"{label}: {stop.why}")
                return Unfinished(stop.why, stop.cut[2])
            if result.stopped:
                self.group_says(sub, f"{label}: {result.stopped}")
            else:
                best = min(best, (result.chi2 / 2.0, item[1].physics))
            return result

        fits = self.placement.on_groups(fit, need, current.experiment)
        gc.collect()                    # every rank, same point (see run_diagnose)
        for (s, _), f in zip(need, fits, strict=True):
            value = f.value if f.ok else None
            if isinstance(value, Unfinished):     # no fit: partial_round.py judges it
                s.unfinished, value = value.why, None
            s.fit, s.fit_error = value, f.error
        self.budget.settle(min((f.value.found_at for f in fits if isinstance(f.value, Unfinished)),
                               default=None))

    def scanned_start(self, ext, candidate, comm, label: str):
        """``ext`` with a one-parameter candidate's value at the best of a scan of its bounds
        by decades (the others at their values), when it starts at its lower bound and that is
        positive (the parameter is log-scaled): a compliant support starts numerically rigid,
        ~4 decades below where a fit ends, and Levenberg-Marquardt's steps in log(p) grow it
        by a factor of a few an iteration (the independent finger's support: 17 iterations,
        40 runs, 340 s). Each decade is one forward run of the identification window."""
        if len(candidate.parameters) != 1:
            return ext
        name, (lo, hi) = candidate.parameters[0], candidate.bounds[0]
        start = get_parameter(ext, name)
        if not (0.0 < lo and start <= lo and hi >= 100.0 * lo):
            return ext
        values = [start * 10.0 ** k for k in range(int(np.log10(hi / start)) + 1)]
        data = self.data[self.ident]
        misfits = [chi2(self.simulate(with_parameters(ext, {name: v}), comm=comm,
                                      times=self.times[self.ident]), data, self.sigma)
                   for v in values]
        gc.collect()                    # every rank, same point (see run_diagnose)
        best = int(np.argmin(misfits))
        self.group_says(comm, f"{label}: {name} by decades {values[0]:.3g} .. "
                               f"{values[-1]:.3g}: chi2 " + " ".join(f"{m:.4g}" for m in misfits)
                         + f"; the fit starts at {values[best]:.3g}")
        return with_parameters(ext, {name: values[best]}) if best else ext

    def known_start(self, ext, current: Fit) -> tuple | None:
        """(simulation, columns) of the round's shared scoring run when they are ``ext``'s at
        its start: that run scored ``current`` with every value-only candidate switched on at
        its start value (the same simulation, checked to :data:`SHARED_RUN_TOLERANCE` of the
        noise) and exact sensitivities to all their parameters -- what a candidate fit's first
        evaluation would compute again (a sensitivity run a fit). None when ``ext`` has a
        parameter that run had not, or at another value."""
        if self._scored is None or self._scored[0] is not current:
            return None
        _, sim, values, cols = self._scored
        names = list(ext.calibrate)
        if not all(n in cols and get_parameter(ext, n) == values.get(n) for n in names):
            return None
        return sim, {n: cols[n] for n in names}

    def simulate(self, experiment, h=None, comm=None, times=None) -> np.ndarray:
        """Marker positions of ``experiment`` at every frame of the record (or ``times``)."""
        if comm is None:
            return self.placement.alone(
                lambda sub: self.simulate(experiment, h=h, comm=sub, times=times), experiment)
        names = list(experiment.calibrate)
        p = np.array([get_parameter(experiment, n) for n in names])
        fm = build_forward(experiment, names, self.recording,
                           self.times if times is None else times,
                           petsc_comm(comm), self.integrator, h=h)
        try:
            return fm.simulate(p)
        finally:
            fm.destroy()

    def simulate_identification(self, experiment, comm=None) -> np.ndarray:
        """Marker positions of ``experiment`` on the identification window only, in an array
        of every frame's shape whose held-out frames are NaN (indexed as :meth:`simulate`'s by
        ``ident``). For the runs only that window is compared on (the numerics check's
        refinements, the frequency matching): the run stops at the cut, 30 % of the record
        earlier by default; a use of a held-out frame gives NaN, not a silent value."""
        sim = self.simulate(experiment, comm=comm, times=self.times[self.ident])
        out = np.full((len(self.times),) + sim.shape[1:], np.nan)
        out[self.ident] = sim
        return out

    def score(self, fit: Fit, candidate, comm=None) -> ScoreEntry:
        """Rank ``candidate`` at ``fit`` (identification window) by its score-test statistic;
        a ``"switch"`` candidate's column is the change the switch makes (see
        :mod:`petsoft.diagnosis.candidates`)."""
        with doing(f"score {candidate.physics}"):
            return self._score(fit, candidate, comm)

    def _score(self, fit: Fit, candidate, comm) -> ScoreEntry:
        comm = self.comm if comm is None else petsc_comm(comm)
        ext = candidate.extend(fit.experiment)
        if candidate.kind == "switch":
            # before: the extended model was fitted here, two calibrations per round that took
            # most of a bench case's scoring time. The current model's columns come from the
            # round's shared scoring run when there was one (its terms start off: the same
            # simulation and columns; on the independent bracket a sensitivity run of 80 s per
            # switch and round)
            cached = self._scored
            if (cached is not None and cached[0] is fit
                    and set(fit.experiment.calibrate) <= set(cached[3])):
                sim, cols = cached[1], {n: cached[3][n] for n in fit.experiment.calibrate}
            else:
                sim, cols = self._columns(fit.experiment, candidate, comm)
            cols["switch"] = self.simulate(ext, comm=comm, times=self.times[self.ident]) - sim
            gc.collect()
            return self._score_entry(fit, candidate, ext, sim, cols, ["switch"])
        sim, cols = self._columns(ext, candidate, comm)
        return self._score_entry(fit, candidate, ext, sim, cols, candidate.tested_parameters)

    def score_together(self, fit: Fit, candidates: list,
                       comm=None) -> list[ScoreEntry] | None:
        """Score several candidates from one run with sensitivities to all their parameters:
        those that only switch settings on at a value that leaves the model as it is (no
        regions, colliders or support compliance: :func:`scored_together`). Their columns are
        those their own runs would give, since at their start values the terms are off; checked:
        the combined model's simulation must equal ``fit``'s to :data:`SHARED_RUN_TOLERANCE` of
        the noise, else None (score them one by one, and say why). Also None when the columns
        would be differences."""
        entries, scored, why = self._shared_run(fit, candidates, comm)
        return self._keep_shared(entries, scored, why)

    def _keep_shared(self, entries, scored, why) -> list[ScoreEntry] | None:
        """Keep a shared scoring run's columns for the round (:attr:`_scored`), or say why
        there are none."""
        if why:
            self.tell(f"  {why}: scoring one by one")
        self._scored = scored
        return entries

    def _shared_run(self, fit: Fit, candidates: list, comm=None) -> tuple:
        """:meth:`score_together`'s run, without touching this object: ``(entries, scored,
        why)``, ``scored`` the value of :attr:`_scored`, ``why`` None or why the entries are
        None (run on a group of ranks by :meth:`regions_and_shared_scores`)."""
        comm = self.comm if comm is None else petsc_comm(comm)
        ext = fit.experiment
        for c in candidates:
            ext = c.extend(ext)
        if self.all_differenced(ext):
            return None, None, None
        try:
            with doing(f"score {', '.join(c.physics for c in candidates)} (one run)"):
                sim, cols = self._columns(ext, candidates[0], comm)
        except PetsoftError as exc:     # (collective: every rank of the group raised it)
            return None, None, f"the shared scoring run failed ({exc})"
        seen = np.isfinite(self.data[self.ident])
        moved = float(np.sqrt(np.mean((sim[seen] - fit.sim[self.ident][seen]) ** 2)))
        if moved > SHARED_RUN_TOLERANCE * self.sigma:
            return None, None, (f"the shared scoring run's simulation is {moved / self.sigma:.3g}x"
                                " the noise from the current model's (its terms should start "
                                "off)")
        scored = (fit, sim, {n: get_parameter(ext, n) for n in ext.calibrate}, cols)
        return ([self._score_entry(fit, c, ext, sim, cols, c.tested_parameters)
                 for c in candidates], scored, None)

    def regions_and_shared_scores(self, fit: Fit, together: list, regions: bool = True,
                                  then: Callable | None = None
                                  ) -> tuple[dict, list[ScoreEntry] | None, dict]:
        """The adjoint's sensitivity regions (:meth:`sensitivity_regions`) and the shared
        scoring run of ``together`` (:meth:`score_together`), concurrently on two groups of
        ranks: neither needs the other (the shared candidates have no regions), and a model
        of a few thousand dofs is solved redundantly on every rank of a group, so two ranks
        on one run buy little (on the realistic damping case the two took 67 s and 45 s one
        after the other on two ranks).

        ``then(kind, maps, sub)``, when given, is called by each group right after its job
        (``kind`` "regions" or "shared"; ``maps`` the regions, :data:`NO_REGIONS` after the
        shared run; ``sub`` the group's communicator), with what that job gives already in
        place on the group's ranks (:attr:`centroids`, :attr:`_scored`): it scores the
        round's candidates that need only that job while the other group still runs -- the
        spatial ones after the maps, the rest after the shared run -- instead of all of them
        after both (on the realistic damping case the maps took 22 s beside the shared run's
        45 s, then three scores 29 s on the two ranks). It returns ``{key: TaskResult}``; the
        groups' dicts are merged.

        Returns
        -------
        (dict, list or None, dict)
            The regions (:data:`NO_REGIONS` when ``regions`` is False), the shared entries
            (None: score one by one; fewer than two candidates are not shared) and what
            ``then`` scored.
        """
        jobs = (["regions"] if regions else []) + (["shared"] if len(together) > 1 else [])

        def job(kind, sub):
            if kind == "regions":
                out = self._regions(fit, sub)
                if then is None:
                    return out, {}
                maps, centroids = out
                if centroids is not None:
                    self.centroids = centroids         # (as the merge below sets it)
                return out, then(kind, maps, sub)
            entries, scored, why = self._shared_run(fit, together, sub)
            extra = {}
            if then is not None:
                self._scored = scored                  # (as _keep_shared sets it below)
                extra = then(kind, dict(NO_REGIONS), sub)
            # the fit itself stays behind: :attr:`_scored` is recognised by identity
            return (entries, None if scored is None else scored[1:], why), extra

        done = dict(zip(jobs, self.placement.on_groups(job, jobs, fit.experiment), strict=True))
        maps, early = dict(NO_REGIONS), {}
        for res in done.values():
            if res.ok:
                early.update(res.value[1])
        if "regions" in done:
            res = done["regions"]
            if not res.ok:
                raise DiagnoseError(f"the sensitivity maps failed: {res.error}")
            maps, centroids = res.value[0]
            if centroids is not None:
                self.centroids = centroids
        entries = None
        if "shared" in done:
            res = done["shared"]
            entries, scored, why = (res.value[0] if res.ok else
                                    (None, None, f"the shared scoring run failed ({res.error})"))
            entries = self._keep_shared(entries, None if scored is None else (fit, *scored),
                                        why)
        return maps, entries, early

    def _score_entry(self, fit: Fit, candidate, ext, sim, cols: dict,
                     tested: list) -> ScoreEntry:
        """The score entry of ``candidate`` from the simulation and columns of ``ext``."""
        from petsoft.diagnosis.score import ScoreError, score_test

        entry = functools.partial(ScoreEntry, physics=candidate.physics,
                                  parameters=candidate.parameters, region=candidate.region,
                                  kind=candidate.kind)
        data = self.data[self.ident]
        seen = np.isfinite(data)
        r = (sim[seen] - data[seen]) / self.sigma
        base_cols = np.stack([cols[n][seen] for n in fit.names], axis=1) / self.sigma
        cand_cols = np.stack([cols[n][seen] for n in tested], axis=1) / self.sigma
        try:
            s = score_test(r, base_cols, cand_cols)
        except ScoreError as exc:
            return entry(score=0.0, dof=len(tested), p_value=1.0, log10_p=0.0, note=str(exc))
        outward = outward_only(candidate, ext, tested, s.gradient)
        if outward:
            return entry(score=0.0, dof=s.dof, p_value=1.0, log10_p=0.0,
                         gradient=s.gradient.tolist(), note=outward)
        return entry(score=s.statistic, dof=s.dof, p_value=s.p_value, log10_p=s.log10_p,
                     gradient=s.gradient.tolist(), direction=s.direction)

    def branch_differentiable(self, ext) -> bool:
        """Whether the integrator's forward sensitivities carry a viscoelastic branch's internal
        variable (backward Euler and generalized-alpha do; si's refuse it)."""
        return scheme(self.integrator or ext.time.integrator).branch_sensitivities

    def all_differenced(self, ext) -> bool:
        """Whether every sensitivity column of ``ext`` must be a difference: a viscoelastic
        branch is in the model (added in an earlier round) and the integrator's exact
        sensitivities refuse it (:meth:`branch_differentiable`)."""
        branch_on = (ext.viscoelastic.ratio > 0.0
                     or any(n in VISCOELASTIC for n in ext.calibrate or {}))
        return branch_on and not self.branch_differentiable(ext)

    def exact_columns(self, candidate, ext) -> bool:
        """Whether ``candidate``'s score columns are exact forward sensitivities: a score term,
        or a ``"score-fd"`` one whose parameters are all the viscoelastic branch's when the
        integrator differentiates the branch (on the independent bracket, alpha: the branch's
        one-sided differences took four to six runs of its own, 240 s of a 563 s scoring)."""
        if candidate.kind == "score":
            return True
        return (candidate.kind == "score-fd" and self.branch_differentiable(ext)
                and all(n in VISCOELASTIC for n in candidate.parameters))

    def _columns(self, ext, candidate, comm) -> tuple[np.ndarray, dict]:
        """Simulation and sensitivity columns of the extended model at its current values:
        exact forward sensitivities, one-sided differences for ``"score-fd"`` parameters."""
        names = list(ext.calibrate)
        p = np.array([get_parameter(ext, n) for n in names])
        # by differences: a score-fd candidate's parameters (unless exact_columns); and every
        # column when a viscoelastic branch is already in the model (added in an earlier
        # round) and the integrator's exact sensitivities refuse it (si)
        fd = [n for n in names if n in candidate.parameters
              and not self.exact_columns(candidate, ext)]
        if self.all_differenced(ext):
            fd = list(names)
        exact = [n for n in names if n not in fd]
        t = self.times[self.ident]
        if exact:
            fm = build_forward(ext, exact, self.recording, t, comm, self.integrator)
            try:
                sim, dsim = fm.jacobian(np.array([p[names.index(n)] for n in exact]))
            finally:
                fm.destroy()
                gc.collect()                # every rank, same point (see run_diagnose)
            cols = {n: dsim[..., i] for i, n in enumerate(exact)}
        else:
            sim, cols = self.simulate(ext, comm=comm, times=t), {}
        # a parameter at zero (a candidate's start) steps by 1e-6 of its upper bound
        upper = {n: max(abs(lo), abs(hi)) for n, (lo, hi) in zip(candidate.parameters,
                                                                  candidate.bounds, strict=True)}
        for n in fd:
            value = get_parameter(ext, n)
            scale = abs(value) if value != 0.0 else upper.get(n, 1.0)
            step = float(candidate.fd_steps.get(n, 1e-6 * scale))
            moved = with_parameters(ext, {n: get_parameter(ext, n) + step})
            cols[n] = (self.simulate(moved, comm=comm, times=t) - sim) / step
            gc.collect()
        return sim, cols

    def sensitivity_regions(self, fit: Fit) -> dict:
        """Spheres from the adjoint per-cell maps of the misfit (one sweep).

        Returns
        -------
        dict
            ``{"stiffness": sphere where |d misfit/d E_cell| is largest, "density": sphere
            where d misfit/d rho_cell is most negative}``, each None when it cannot be made.
        """
        maps, centroids = self.placement.alone(lambda sub: self._regions(fit, sub),
                                               fit.experiment)
        if centroids is not None:
            self.centroids = centroids
        return maps

    def _regions(self, fit: Fit, comm) -> tuple[dict, np.ndarray | None]:
        """:meth:`sensitivity_regions` on ``comm`` without touching this object: (the regions,
        the whole mesh's cell centroids or None)."""
        from petsoft.diagnosis.candidates import sensitivity_region

        names = fit.names
        data = self.data[self.ident]
        seen = np.isfinite(data)
        sigma = self.sigma
        fm = build_forward(fit.experiment, names, self.recording, self.times[self.ident],
                           petsc_comm(comm), self.integrator)

        def dphi(sim):
            diff = np.where(seen, sim - np.where(seen, data, 0.0), 0.0) / sigma
            return 0.5 * float(np.sum(diff * diff)), diff / sigma

        try:
            _, _, maps = fm.cell_gradient(fit.values, dphi)
            centroids, volumes = cell_geometry(fm.system.dmesh.mesh)
        except ExperimentError:
            return dict(NO_REGIONS), None
        finally:
            fm.destroy()
        return ({"stiffness": sensitivity_region(centroids, maps["youngs_modulus"], volumes),
                 "density": sensitivity_region(centroids, maps["density"], volumes,
                                               inward=True)}, centroids)


#: What :meth:`Diagnosis.sensitivity_regions` returns when no map can be made.
NO_REGIONS = {"stiffness": None, "density": None}


def evidence_of(diag: Diagnosis, fit: Fit) -> Evidence:
    from petsoft.diagnosis.evidence import collect_evidence

    rec = diag.recording
    ev = collect(diag, fit, collect_evidence, rec)
    if diag.model_error and ev.verdict != "consistent" and ev.noise_test.level_ok:
        # a discretisation error of the size measured is smooth in time, so the residual
        # cannot be white: with it in the budget only the chi-square level can be tested
        ev = replace(ev, verdict="consistent", notes=[
            *ev.notes, "verdict from the chi-square level only: the residual includes the "
            "measured discretisation error, which is not white"])
    return ev


def collect(diag, fit, collect_evidence, rec) -> Evidence:
    return collect_evidence(diag.data[diag.ident], fit.sim[diag.ident], diag.times[diag.ident],
                            rec.reference, rec.names, sigma=diag.sigma_verdict,
                            num_parameters=len(fit.names), alpha=diag.alpha)


def dominant_frequency(times: np.ndarray, signals: np.ndarray) -> float | None:
    """The frequency (Hz) of the largest oscillation shared by the markers' ``signals``
    (:func:`petsoft.calibration.spectra.dominant_modes`), None without one."""
    from petsoft.calibration.spectra import SpectralError, dominant_modes

    try:
        found = [m["frequency_hz"] for m in dominant_modes(times, signals)
                 if m["frequency_hz"] > 0.0]
    except SpectralError:
        return None
    return found[0] if found else None


def scored_together(candidate, exact: bool | None = None) -> bool:
    """Whether ``candidate`` can share a scoring run with others
    (:meth:`Diagnosis.score_together`): a term that only sets experiment keys, with exact
    sensitivities (``exact``: :meth:`Diagnosis.exact_columns`; default: a score term) (regions
    may overlap another's, a collider or a compliant support changes the model even at its
    start)."""
    exact = candidate.kind == "score" if exact is None else exact
    return (exact and candidate.kind != "switch" and not candidate.regions
            and not candidate.colliders and candidate.compliance is None)


def outward_only(candidate, ext, tested: list[str], gradient) -> str | None:
    """Why a one-parameter candidate starting at its lower bound cannot help, or None.

    The misfit's gradient g = J_c^T r (r = sim - data; J_b^T r = 0 at the base fit, so g is the
    efficient score's) says the misfit falls as the parameter moves by -g. At the lower bound
    (a damping of 0, a region at the surrounding density) only an increase is allowed: with
    g > 0 the fit cannot move (Kuhn-Tucker), and the two-sided score only took a slot of the
    fitted shortlist (seen: four damping laws fitted to LR 4.6e-10 after gravity was added).
    """
    if len(tested) != 1 or tested[0] not in candidate.parameters:
        return None
    name = tested[0]
    lo = candidate.bounds[candidate.parameters.index(name)][0]
    start = get_parameter(ext, name)
    if start <= lo and float(np.asarray(gradient).ravel()[0]) > 0.0:
        return (f"the misfit falls only for {name} below its lower bound {lo:.3g} "
                f"(one-sided score: 0)")
    return None
