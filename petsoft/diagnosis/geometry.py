"""The sphere of an added spatial term fitted too: its centre and radius, not only its value.

``petsoft diagnose`` places a spatial candidate (``mass.added``, ``material.heterogeneous``)
where the adjoint per-cell map points (:func:`~petsoft.diagnosis.candidates.sensitivity_region`)
and calibrates its value. The map's sphere is a first guess: on the independent ``added-mass``
bracket (513 user cells raised to 10 nodes, the truth a sphere of 4x density on DOLFINx's fine
mesh) the added term predicted the held-out window to 1.55x the noise; the same term with its
sphere fitted as well reaches 1.30x (``scripts/benchmarks/independent/region_fit_bound.py``).

Once such a term is added, :func:`fit_sphere` searches its centre and radius by a compass
(pattern) search: from the placed sphere, the centre moved by +-h along each axis and the radius
scaled by f and 1/f; the best trial that lowers the misfit becomes the new point and h and log f
double (at most twice their start), else they halve. A region holds cells by centroid, so the
misfit is piecewise constant in the geometry: a derivative-free search with steps of a cell's
size is the method that fits it, and trials holding the same cells as one already seen cost
nothing. Each trial is one run of the identification window with the model's values kept (an
added mass's density rescaled so that its extra mass stays the same: radius and density trade
off) and the sensitivity to the sphere's own value, scored by its *linearised refit*: the
residual less its least-squares part, within the parameters' bounds, in the sensitivities (the
sphere's value's own column, the others the current model's), i.e. what re-calibrating every
parameter would absorb, to first order. The best sphere is then calibrated in full and kept
only if it passes the tests a term passes to be added
(:func:`~petsoft.diagnosis.selection.judge`): a significant likelihood ratio for its four
geometry parameters **and** a better held-out prediction.

A second search (:func:`refit_added_sphere`, :data:`MAX_SEARCHES`) runs from the calibrated
sphere of the first, whose recalibration changed the sensitivities that score a trial. It
starts at the step (centre step and radius factor) of the first search's last poll that moved
the sphere, at most a fresh search's (half the new radius), and grows to at most twice it: the
first search has tried the coarser steps around nearly the same sphere, and the second is
there to follow what the recalibration moved, not to explore again. On the realistic payload
case (issue 40, 711 tets, 2 ranks) the second search restarted at 0.019 m (half its radius)
where the first had last moved at 0.0136 m, and its two polls at 0.038 m moved nothing; from
0.0136 m it made 43 trial runs in 8 polls (24 rounds on 2 ranks) instead of 53 (29 rounds),
and ended at another sphere (held-out rms 0.1331 instead of 0.1375 mm, noise 0.1 mm; its
closing calibration 9 iterations instead of 7). On the sphere tests' 288-tet bar
(``scripts/benchmarks/sphere_search_work.py``) the two searches made 92 and 105 runs instead
of 102 and 101. Trial scores are not reused across searches: a trial's linearised refit
depends on the model it starts from (its residual and the other parameters' columns), which
the recalibration changed.

**The time budget** (:mod:`petsoft.diagnosis.budget`). Neither a search nor a poll starts
when it could not end inside the budget together with the search's closing calibration: a
poll is costed by the rounds of trial runs it makes (its trials over the ranks, side by side)
at the longest a round took in this run's polls so far, and the closing calibration by the
calibration of the model the search starts from (:func:`_poll_needs` says why); a search's
start adds the model-sensitivities run it makes before its first poll (:func:`_search_needs`;
left out of it before, it let a search start ~a run too late). A search or
polls left out are ``skipped`` entries of the report; a search stopped between polls keeps its
best sphere so far.

With ``diagnose --reduced-trials`` (``Diagnosis.reduced_trials``; off by default) the trials
are scored by a reduced-order model of the fitted model and only each poll's best is run on the
full model, which decides, and only when it would move the sphere
(:mod:`petsoft.diagnosis.reduced_trials`).
"""

from __future__ import annotations

import dataclasses
import functools
import gc

import numpy as np
from scipy import stats
from scipy.optimize import lsq_linear

from petsoft.calibration.calibrate import build_forward
from petsoft.diagnosis.candidates import REGION, cells_in_sphere, sphere_condition
from petsoft.diagnosis.chord_refit import refit_step
from petsoft.diagnosis.context import (
    Diagnosis,
    Fit,
    cell_geometry,
    fmt,
    petsc_comm,
    term_values,
)
from petsoft.diagnosis.numerics import has_sensitivities, model_sensitivities
from petsoft.diagnosis.records import AddedTerm
from petsoft.diagnosis.reduced_trials import ReducedTrials
from petsoft.experiment import experiment_from_dict, get_parameter, with_parameters
from petsoft.physics.model import load_mesh

#: The sphere's degrees of freedom (centre x, y, z and radius): the likelihood-ratio test's.
GEOMETRY_DOF = 4
#: At most this many polls (rounds of eight trials) of the compass search.
MAX_POLLS = 8
#: The radius' first trial factor (then its log halves with the centre step).
RADIUS_FACTOR = 1.4


#: The budget's kind (:meth:`~petsoft.diagnosis.budget.TimeBudget.record`) of a round of a
#: poll's trial runs (one trial per group of ranks, side by side).
TRIAL_ROUND = "sphere trial runs"
#: A poll's trials at most (:func:`_polls`): what a search not started yet is costed at.
POLL_TRIALS = 8
#: What a poll the budget leaves out risks.
POLLS_RISK = ("the sphere is the best of the polls made: its centre and size may be further "
              "from the data's than a full search would find")
#: What a search the budget leaves out risks.
SEARCH_RISK = ("the sphere stays where the last search left it (the map's placement if none "
               "ran): its centre and size are a first guess")


@dataclasses.dataclass
class SphereFit:
    """A spatial term's fitted sphere: the new candidate (region moved), its calibrated fit
    and what the search did (for the report); ``scale``: the centre step and radius factor
    of the last poll that moved the sphere (where a next search starts,
    :func:`refit_added_sphere`)."""

    candidate: object
    fit: Fit
    region: dict
    summary: str
    scale: tuple[float, float] | None = None


class _Sphere:
    """Trials of one added term's sphere: the model with the sphere moved, simulated on the
    identification window and scored by its linearised refit."""

    def __init__(self, diag: Diagnosis, fit: Fit, candidate):
        self.diag, self.fit = diag, fit
        self.name = REGION[candidate.physics]
        key = "density" if candidate.physics == "mass.added" else "youngs_modulus"
        self.parameter = f"material.{self.name}.{key}"
        self.background = get_parameter(fit.experiment, f"material.{key}")
        self.value = get_parameter(fit.experiment, self.parameter)
        self.centroids, self.volumes = cell_geometry(load_mesh(fit.experiment))
        #: a typical cell's size (the model's ``scales["cell"]``): the search's step scale
        self.cell = float(np.cbrt(np.mean(self.volumes)))
        self.volume = float(self.volumes[self.cells(candidate.region)].sum())
        self.data = diag.data[diag.ident]
        self.seen = np.isfinite(self.data)
        self.names = list(fit.names)
        self.index = self.names.index(self.parameter)
        bounds = np.array([fit.experiment.calibrate[n] for n in self.names], dtype=float)
        self.lower, self.upper = bounds[:, 0], bounds[:, 1]

    @functools.cached_property
    def cols(self) -> np.ndarray:
        """The current model's sensitivity columns (seen samples, parameters): asked for when
        first scored (:mod:`petsoft.diagnosis.reduced_trials` may have kept them by then)."""
        return model_sensitivities(self.diag, self.fit)[self.seen]

    def cells(self, region: dict) -> np.ndarray:
        """(E,) bool: the cells whose centroid is inside ``region`` (as the model's regions)."""
        return cells_in_sphere(self.centroids, region)

    def experiment(self, region: dict, values: dict | None = None):
        """The fitted model with the sphere at ``region`` (an added mass keeps its extra mass:
        the density rescaled by the volumes of the cells held, within its bounds), or at
        ``values`` when given."""
        data = self.fit.experiment.to_dict()
        data["region"][self.name] = {"where": sphere_condition(region["center"],
                                                               region["radius"])}
        exp = experiment_from_dict(data, source=self.fit.experiment.source,
                                   base_dir=self.fit.experiment.base_dir,
                                   path=self.fit.experiment.path)
        if values is not None:
            return with_parameters(exp, values)
        if self.parameter.endswith("density"):
            volume = float(self.volumes[self.cells(region)].sum())
            value = self.background + (self.value - self.background) * self.volume / volume
            i = self.index
            exp = with_parameters(exp, {self.parameter: float(np.clip(value, self.lower[i],
                                                                       self.upper[i]))})
        return exp

    def misfit(self, sim: np.ndarray, cols: np.ndarray, values: np.ndarray
               ) -> tuple[float, np.ndarray]:
        """(chi2 after the linearised refit, the refit's parameter step) of a simulation of
        the identification window at parameter ``values`` with sensitivities ``cols`` (seen
        samples, parameters): the least-squares step within the parameters' bounds (a trial's
        refit must not count on a density below the surrounding one)."""
        r = (sim - np.where(self.seen, self.data, 0.0))[self.seen]
        scale = np.linalg.norm(cols, axis=0)
        scale[scale == 0.0] = 1.0
        lo, hi = self.lower - values, self.upper - values
        if np.all(hi > lo):
            step = lsq_linear(cols / scale, -r, bounds=(lo * scale, hi * scale)).x / scale
        else:
            step = refit_step(cols, r)
        return float(np.sum(((r + cols @ step) / self.diag.sigma) ** 2)), step

    def full_run(self, region: dict, comm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(sim, d sim/d the sphere's value (K, M, 3, 1), start values) of the full model with
        the sphere at ``region``: one run of the identification window with the sensitivity
        to the sphere's own value."""
        diag = self.diag
        exp = self.experiment(region)
        values = np.array([get_parameter(exp, n) for n in self.names])
        fm = build_forward(exp, [self.parameter], diag.recording, diag.times[diag.ident],
                           petsc_comm(comm), diag.integrator)
        try:
            sim, own = fm.jacobian(values[[self.index]])
        finally:
            fm.destroy()
        return sim, np.asarray(own), values

    def trial_columns(self, own: np.ndarray) -> np.ndarray:
        """The refit's columns of a trial: the sphere's value's its own ``own`` (seen
        samples), the other parameters' the current model's (the sphere's place changes its
        own column most)."""
        cols = self.cols.copy()
        cols[:, self.index] = own[self.seen][:, 0]
        return cols

    def trial(self, region: dict, comm) -> tuple[float, np.ndarray, dict]:
        """One trial sphere on the full model (:meth:`full_run`): its linearised refit's chi2
        and step, and its start values."""
        sim, own, values = self.full_run(region, comm)
        chi2_lin, step = self.misfit(sim, self.trial_columns(own), values)
        return chi2_lin, step, dict(zip(self.names, map(float, values), strict=True))


def _polls(region: dict, h: float, f: float) -> list[dict]:
    """The compass search's trials around ``region``: its centre +-h along each axis, its
    radius times f and 1/f."""
    c = np.asarray(region["center"], dtype=float)
    out = []
    for axis in range(3):
        for sign in (1.0, -1.0):
            moved = c.copy()
            moved[axis] += sign * h
            out.append({"center": moved.tolist(), "radius": float(region["radius"])})
    for g in (f, 1.0 / f):
        out.append({"center": c.tolist(), "radius": float(region["radius"]) * g})
    return out


def _rounds(trials: int, ranks: int) -> int:
    """Rounds of ``trials`` runs side by side on ``ranks`` ranks
    (:func:`~petsoft.calibration.groups.map_on_groups`: at most one group a rank, task i on
    group i mod groups)."""
    return -(-int(trials) // max(int(ranks), 1))


def _poll_needs(diag: Diagnosis, fit: Fit, trials: int) -> tuple[float, str]:
    """(seconds, what they are) a poll of ``trials`` trial runs and the search's closing
    calibration need, to decide whether they fit in the time budget (module docstring).

    A poll costs its rounds of runs side by side (:func:`_rounds`) at the longest a round took
    in this run's polls so far (each rank's own clock; the first rank's decides); before any
    poll, at a run of ``fit``'s calibration (its wall time over its runs: a calibration's
    iteration is a run with sensitivities, as a trial is). The closing calibration is
    foreseen by ``fit``'s own, the calibration of the model the search starts from: the
    term's candidate fit for a first search, the previous search's closing calibration for a
    second (the same model, calibrated from a sphere's linearised refit, as the next one
    will be). The candidate fit started from the term's default value, further from its
    optimum, so it errs long (the payload case: 114 s for a closing calibration of 70 s);
    the previous search's is the nearest measure of the next, though the machine's load may
    make it err short (70 s for the next 84 s)."""
    per = diag.budget.cost(TRIAL_ROUND)
    basis = "as the polls so far"
    if per is None:
        per = fit.seconds / max(int(fit.evaluations), 1)
        basis = "a run each as the last calibration's"
    rounds = _rounds(trials, diag.comm.getSize())
    poll = per * rounds
    return poll + fit.seconds, (f"a poll of {trials} trial run(s) (~{poll:.0f} s, {rounds} "
                                f"round(s) side by side, {basis}) and the search's closing "
                                f"calibration (~{fit.seconds:.0f} s, as the last "
                                "calibration's) need")


def _search_needs(diag: Diagnosis, fit: Fit) -> tuple[float, str]:
    """(seconds, what they are) a sphere search from ``fit`` needs at least: its first poll
    and closing calibration (:func:`_poll_needs`, at most :data:`POLL_TRIALS` trials) and,
    unless they are kept, the model's sensitivities it runs before that poll (a trial's
    linearised refit scores in them, :attr:`_Sphere.cols`): a run with sensitivities, costed
    as a run of ``fit``'s calibration, whose iterations are such runs."""
    needs, words = _poll_needs(diag, fit, POLL_TRIALS)
    if has_sensitivities(diag, fit):
        return needs, words
    run = fit.seconds / max(int(fit.evaluations), 1)
    return needs + run, (f"the model's sensitivities (~{run:.0f} s, a run as the last "
                         f"calibration's), {words}")


def fit_sphere(diag: Diagnosis, fit: Fit, candidate, max_polls: int = MAX_POLLS,
               notes: list | None = None,
               scale: tuple[float, float] | None = None) -> SphereFit | None:
    """Fit the centre and radius of ``candidate``'s sphere (module docstring).

    Parameters
    ----------
    diag : Diagnosis
    fit : Fit
        The calibrated model with ``candidate`` just added (its region as placed).
    candidate : Candidate
        A spatial candidate (``region`` set).
    max_polls : int
        Rounds of the compass search.
    notes : list, optional
        With ``diag.reduced_trials``, what the reduced trials did is appended here
        (:meth:`~petsoft.diagnosis.reduced_trials.ReducedTrials.note`).
    scale : (float, float), optional
        The centre step and radius factor to start from (a previous search's
        :attr:`SphereFit.scale`), at most a fresh search's; they grow to at most twice (the
        factor squared) that. None: a fresh search's (half the radius, at least a cell;
        :data:`RADIUS_FACTOR`).

    Returns
    -------
    SphereFit or None
        The refitted term when the fitted sphere passes both tests, else None (the placed
        sphere stays; the reason is said).
    """
    search = _Sphere(diag, fit, candidate)
    label = f"{candidate.physics} sphere"
    best = dict(candidate.region)
    best_chi2, best_step = search.misfit(fit.sim[diag.ident], search.cols,
                                         np.asarray(fit.values, dtype=float))
    best_values = dict(zip(search.names, map(float, fit.values), strict=True))
    seen = {search.cells(best).tobytes()}
    h0, f0 = max(0.5 * float(best["radius"]), search.cell), RADIUS_FACTOR
    if scale is not None:
        h0, f0 = min(float(scale[0]), h0), min(float(scale[1]), f0)
        diag.tell(f"  {label}: from the last step that moved it (centre step {h0:.3g} m, "
                  f"radius x {f0:.3g})")
    h, f = h0, f0
    moved_at = None
    min_h = 0.25 * search.cell
    start_chi2 = best_chi2
    reduced = None
    if diag.reduced_trials:
        reduced = ReducedTrials.start(diag, search)
        gc.collect()                    # every rank, same point (see run_diagnose)
        if not reduced.active:
            diag.tell(f"  {label}: full trials: {reduced.why}")

    def full_trials(regions: list) -> list:
        results = diag.placement.on_groups(lambda r, sub: search.trial(r, sub), regions,
                                           fit.experiment)
        gc.collect()                    # every rank, same point (see run_diagnose)
        return [(*res.value, r) for res, r in zip(results, regions, strict=True) if res.ok]

    for poll in range(1, max_polls + 1):
        if h < min_h:
            break
        trials = []
        for region in _polls(best, h, f):
            cells = search.cells(region)
            key = cells.tobytes()
            if cells.any() and key not in seen:
                seen.add(key)
                trials.append(region)
        # the first poll was decided by the caller; a poll without trials costs nothing more
        needs, needs_for = _poll_needs(diag, fit, len(trials)) if trials else (None, "")
        if poll > 1 and diag.budget.stops(f"{label}'s polls {poll}-{max_polls}", POLLS_RISK,
                                          needs=needs, needs_for=needs_for):
            # the search so far is kept (its best sphere calibrated below)
            diag.tell(f"  {label}: stopped after poll {poll - 1} of at most {max_polls}: "
                      + ("the time budget is spent" if diag.budget.spent_at is not None else
                         "the next poll and the closing calibration would end past the time "
                         "budget"))
            break
        started = diag.budget.elapsed()
        if reduced is not None and reduced.active:
            scored = reduced.poll(poll, trials, full_trials, best, best_chi2)
        else:
            scored = full_trials(trials)
        if trials:
            diag.budget.record(TRIAL_ROUND, diag.budget.elapsed() - started,
                               _rounds(len(trials), diag.comm.getSize()))
        moved = False
        if scored:
            c2, step, values, region = min(scored, key=lambda t: t[0])
            if c2 < best_chi2:
                best_chi2, best_step, best_values, best, moved = c2, step, values, region, True
        diag.tell(f"  {label}: poll {poll}: {len(trials)} new cell sets (centre step "
                  f"{h:.3g} m, radius x {f:.3g}); best centre "
                  f"{np.round(best['center'], 4).tolist()} r {best['radius']:.4g}, chi2 "
                  f"{best_chi2:.6g} (linearised refit)"
                  + (reduced.poll_words(poll) if reduced is not None else ""))
        if moved:               # a step that worked may be too short: try a longer one next
            moved_at = (h, f)
            h, f = min(2.0 * h, 2.0 * h0), min(f * f, f0 ** 2)
        else:
            h, f = 0.5 * h, float(np.sqrt(f))
    if reduced is not None:
        reduced.destroy()
        gc.collect()                    # every rank, same point (see run_diagnose)
        diag.tell(f"  {label}: {reduced.timing()}")
        if notes is not None:
            notes.append(reduced.note())
    if best_chi2 >= start_chi2:
        diag.tell(f"  {label}: the placed sphere is the best the search found")
        return None
    start = {n: float(np.clip(best_values[n] + s, lo, hi)) for n, s, lo, hi in
             zip(search.names, best_step, search.lower, search.upper, strict=True)}
    ext = search.experiment(best, values=start)
    new = diag.calibrate(ext, label=label)
    lr = fit.chi2 - new.chi2
    p = float(stats.chi2.sf(max(lr, 0.0), GEOMETRY_DOF))
    better = (new.heldout_rms is None or fit.heldout_rms is None
              or new.heldout_rms < fit.heldout_rms)
    what = (f"sphere centre {np.round(candidate.region['center'], 4).tolist()} r "
            f"{candidate.region['radius']:.4g} -> {np.round(best['center'], 4).tolist()} r "
            f"{best['radius']:.4g}: likelihood ratio {lr:.4g} (p = {p:.3g}, {GEOMETRY_DOF} "
            f"dof), held-out rms {fmt(fit.heldout_rms)} -> {fmt(new.heldout_rms)} m")
    if not (p < diag.alpha and better):
        diag.tell(f"  {label}: not moved ({what})")
        return None
    diag.tell(f"  {label}: fitted ({what})")
    region = {"center": [float(c) for c in best["center"]], "radius": float(best["radius"])}
    placed = dataclasses.replace(
        candidate, region=region,
        regions={search.name: sphere_condition(region["center"], region["radius"])})
    return SphereFit(placed, new, region, f"sphere fitted: {what}", scale=moved_at)


#: At most this many searches in a row (each from the last calibrated sphere: the
#: sensitivities that score a trial are those of the model it starts from).
MAX_SEARCHES = 2


def refit_added_sphere(diag: Diagnosis, entry: AddedTerm, fit: Fit, candidate,
                       searches: int = MAX_SEARCHES) -> tuple[AddedTerm, Fit, object]:
    """The added spatial term ``candidate`` (``entry``, calibrated ``fit``) with
    its sphere fitted by up to ``searches`` runs of :func:`fit_sphere`, each from the last
    one's sphere and the step that last moved it (module docstring); the entry's values,
    region and evidence follow. A search whose first poll and closing calibration would not
    end inside the time budget is not started (a ``skipped`` entry). A term without a region
    is returned as it is."""
    if candidate.region is None:
        return entry, fit, candidate
    if diag.all_differenced(fit.experiment):
        # a trial is scored with exact sensitivities, which this integrator refuses for the
        # viscoelastic branch in the model
        diag.tell(f"  {candidate.physics} sphere: not fitted (no exact sensitivities with the "
                  "viscoelastic branch under this integrator)")
        return entry, fit, candidate
    said, notes = [], []
    scale = None
    for search in range(1, searches + 1):
        # not started when its first poll and its closing calibration would end past the
        # budget (a poll's trials are at most POLL_TRIALS)
        needs, needs_for = _search_needs(diag, fit)
        if diag.budget.stops(f"{candidate.physics}'s sphere search {search} of {searches}",
                             SEARCH_RISK, diag.tell, needs=needs, needs_for=needs_for):
            break
        moved = fit_sphere(diag, fit, candidate, notes=notes, scale=scale)
        if moved is None:
            break
        fit, candidate, scale = moved.fit, moved.candidate, moved.scale
        said.append(moved.summary)
    # (notes: the reduced trials' words, only with diag.reduced_trials)
    tail = "".join(f"; {words}" for words in (["; then ".join(said)] if said else []) + notes)
    if not said:
        if notes:
            entry = dataclasses.replace(entry, evidence=entry.evidence + tail)
        return entry, fit, candidate
    values, std = term_values(fit, candidate.parameters)
    entry = dataclasses.replace(entry, parameters=values, std=std, rms_after=fit.rms,
                                region=candidate.region, evidence=entry.evidence + tail)
    return entry, fit, candidate
