"""Refits of a refined model by forward runs only: Gauss-Newton on the current sensitivities.

The numerics check (:mod:`petsoft.diagnosis.numerics`) re-calibrates the model with the time step
halved to see whether the step, not physics, is what the data see. A calibration makes one
forward run *with sensitivities* per Gauss-Newton iteration, and at half the step every run is
twice as long: on the realistic taper's 10-node model (4641 dofs, generalized-alpha, 700 steps of
1 ms) such a refit took three iterations of about 65 s each on 2 ranks, while a plain forward run
(which keeps its factorisation across steps) took about 13 s.

Halving the step changes the simulation's dependence on the parameters little, so the
sensitivities of the current model (already computed to screen the refinements,
:func:`petsoft.diagnosis.numerics.model_sensitivities`) are a good first Jacobian for the refined
one. :func:`chord_refit` iterates Gauss-Newton from them, each iteration one forward run of the
refined model, and corrects them after every run by Broyden's rank-one update (with one
parameter: the secant through the last two runs), since a coarse step's error can move E by
10 % or more and the columns with it: on the test taper at 8 ms -> 4 ms (E 24.5 -> 21.0 MPa)
the fixed columns converged linearly at a rate of 0.67 and had not converged after 6 runs; the
updated ones converged in 5 (tests/test_chord_refit.py). A step-halving line search keeps chi2
from rising, and it stops by the rule diagnose's calibrations stop by (the next step below
sqrt(FIT_DTOL) = 0.1 of each parameter's standard deviation, here from the updated columns).

What it converges to: the point where the residual is orthogonal to the updated columns, which
match the refined model's sensitivities along the steps taken (exactly, with one parameter, up
to the secant's error); a remaining difference eps moves chi2 by O(eps^2) of the misfit (chi2 is
stationary at its minimum), far below the 10 % of the excess that decides whether a refinement
matters. It gives up (None; the caller then calibrates as before) when a step leaves the
bounds, when the line search cannot lower chi2, when the columns become dependent, or after
:data:`MAX_RUNS` runs.

Only the halved step is refitted this way. Raising the element order moves E by tens of per cent
and, at a large misfit, the iteration converges only linearly, as Gauss-Newton itself does
there: the test taper's 4-node -> 10-node refit (0.3 s, chi2 2.8e6) from its frequency-matched
start had not converged after 6 runs (steps shrinking by about half a run), where the
calibration took 4 sensitivity runs.
"""

from __future__ import annotations

import gc
import time

import numpy as np

from petsoft.calibration.calibrate import build_forward, calibration_parameters
from petsoft.calibration.uncertainty import uncertainty
from petsoft.diagnosis.context import FIT_DTOL, Diagnosis, Fit, chi2, petsc_comm, rms
from petsoft.errors import PetsoftError
from petsoft.experiment import with_parameters
from petsoft.io.progress import doing

#: At most this many forward runs of the refined model (line-search trials included) before the
#: chord refit gives up and the model is calibrated instead.
MAX_RUNS = 6
#: Step halvings of the line search before the chord refit gives up.
MAX_HALVINGS = 2
#: After its first run, a step whose linear model lowers chi2 by at most this much is taken
#: without a run of its own at the identification window: the refit's run over the whole record
#: (made anyway, for the held-out prediction) checks it. A chi2 change of 1 moves no test (a
#: term is added for 6.6 at p = 0.01; a refinement matters for 10). Seen: every halved-step
#: refit of the realistic cases made a second run for a step of a fraction of E's standard
#: deviation (chi2 2.343109e4 -> 2.343098e4 on the nonlinear taper at 0.5 ms), 13-42 s each.
CHECKED_BY_FINAL_RUN = 1.0


def refit_step(cols: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """The linearised refit's parameter step: minus the least-squares coefficients of
    ``residual`` (simulation - data, seen samples) in the span of ``cols`` (samples, parameters),
    the columns scaled to unit norm first (parameters of very different sizes)."""
    scale = np.linalg.norm(cols, axis=0)
    scale[scale == 0.0] = 1.0
    return -np.linalg.lstsq(cols / scale, residual, rcond=None)[0] / scale


def broyden_update(cols: np.ndarray, step: np.ndarray, change: np.ndarray) -> np.ndarray:
    """Broyden's rank-one update of the sensitivity columns ``cols`` (samples, parameters) by a
    parameter ``step`` and the residual ``change`` it made: the updated columns map ``step`` to
    ``change`` exactly and are unchanged across it. In each parameter's own scale (the columns'
    norms), so that parameters of very different sizes weigh alike; with one parameter it is
    the secant: the column becomes change / step."""
    scale = np.linalg.norm(cols, axis=0)
    scale[scale == 0.0] = 1.0
    z = step * scale                                       # the step in unit-column variables
    unit = cols / scale
    unit = unit + np.outer(change - unit @ z, z) / float(z @ z)
    return unit * scale


def parameter_std(cols: np.ndarray, residual: np.ndarray, sigma: float) -> np.ndarray:
    """Gauss-Newton standard deviations of the parameters from the sensitivity columns ``cols``
    (seen samples, parameters) and the noise ``sigma`` (m); raises
    :class:`~petsoft.calibration.uncertainty.UnidentifiableError` when they are dependent."""
    return np.asarray(uncertainty(cols / sigma, residual / sigma, noise_std=1.0).std)


def chord_refit(diag: Diagnosis, experiment, cols: np.ndarray, moved: np.ndarray,
                comm=None, label: str = "chord refit") -> Fit | None:
    """Calibrate ``experiment`` (a refinement of a fitted model, from its own parameter values,
    at which its identification-window simulation is ``moved``) by Gauss-Newton on ``cols``,
    the fitted model's sensitivities to the same parameters on the identification window
    (frames, markers, 3, parameters).

    Returns the refitted :class:`~petsoft.diagnosis.context.Fit` (its ``by`` says how it was
    made), or None when the chord iteration does not converge (see the module docstring).
    """
    started = time.perf_counter()
    ident = diag.ident
    data = diag.data[ident]
    seen = np.isfinite(data)
    c = cols[seen]
    names, p, bounds = calibration_parameters(experiment)
    if c.shape[-1] != len(names):
        return None
    lo, hi = np.array(bounds, dtype=float).T
    p = np.asarray(p, dtype=float)
    r = (moved[ident] - data)[seen]
    f = float(np.sum((r / diag.sigma) ** 2))
    comm = diag.comm if comm is None else petsc_comm(comm)
    fm = build_forward(experiment, names, diag.recording, diag.times[ident], comm,
                       diag.integrator)
    runs = iterations = 0
    before = None                   # (p, r, f) before a step the final run checks
    try:
        with doing(label):
            while True:
                try:
                    std = parameter_std(c, r, diag.sigma)
                except PetsoftError:              # dependent columns: let the calibration say
                    return None
                step = refit_step(c, r)
                if np.all(np.abs(step) <= np.sqrt(FIT_DTOL) * std):
                    break                                # converged: the calibration's rule
                trial = p + step
                predicted = float(np.sum((c @ step / diag.sigma) ** 2))
                if (iterations > 0 and predicted <= CHECKED_BY_FINAL_RUN
                        and np.all(trial >= lo) and np.all(trial <= hi)):
                    before, p = (p, f), trial
                    break
                for _ in range(MAX_HALVINGS + 1):
                    trial = p + step
                    if np.any(trial < lo) or np.any(trial > hi) or runs >= MAX_RUNS:
                        return None
                    try:
                        sim = fm.simulate(trial)
                    except PetsoftError:      # (the group's ranks alike: the run is collective)
                        return None
                    runs += 1
                    r_trial = (sim - data)[seen]
                    f_trial = float(np.sum((r_trial / diag.sigma) ** 2))
                    if not np.isfinite(f_trial):
                        return None
                    # what the run showed along the step, accepted or not: the secant
                    c = broyden_update(c, step, r_trial - r)
                    if f_trial <= f:
                        break
                    step = 0.5 * step
                else:
                    return None
                p, r, f = trial, r_trial, f_trial
                iterations += 1
                diag.group_says(comm, f"{label}: it {iterations:3d}  chi2 {f:.6e}  "
                                + ", ".join(f"{n}={v:.6g}"
                                            for n, v in zip(names, p, strict=True))
                                + f"  ({runs} run(s), {time.perf_counter() - started:.0f} s)")
    finally:
        fm.destroy()
        gc.collect()
    calibrated = with_parameters(experiment, dict(zip(names, map(float, p), strict=True)))
    sim = diag.simulate(calibrated, comm=comm)
    final_runs = 1
    if before is not None and chi2(sim[ident], data, diag.sigma) > before[1]:
        # the unchecked last step did not lower chi2 (its linear model said by at most
        # CHECKED_BY_FINAL_RUN): the point before it
        p = before[0]
        calibrated = with_parameters(experiment, dict(zip(names, map(float, p), strict=True)))
        sim = diag.simulate(calibrated, comm=comm)
        final_runs = 2
    seconds = time.perf_counter() - started
    diag.fit_seconds.append(seconds)
    return Fit(experiment=calibrated, names=list(names), values=p, std=std,
               chi2=chi2(sim[ident], data, diag.sigma), rms=rms(sim[ident], data) or 0.0,
               heldout_rms=rms(sim[diag.held], diag.data[diag.held]) if diag.held.any()
               else None, sim=sim, iterations=iterations, evaluations=runs + final_runs,
               by=f"chord Gauss-Newton on the current model's sensitivities ({runs} forward "
                  f"run(s), no sensitivity run"
                  + (", its last step checked by the run of the whole record"
                     if before is not None else "") + ")",
               seconds=seconds)
