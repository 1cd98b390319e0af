"""A sphere search's trials scored by a reduced model, verified on the full model (issue 40).

Opt-in (``petsoft diagnose --reduced-trials``; :func:`~petsoft.diagnosis.diagnose.run_diagnose`
``reduced_trials=True``); off, the search (:mod:`petsoft.diagnosis.geometry`) runs every trial
on the full model as it always did.

Each trial of :func:`~petsoft.diagnosis.geometry.fit_sphere` is one full run of the
identification window with the sensitivity to the sphere's own value, scored by its linearised
refit: on the realistic ``payload`` case the searches took ~600 s of ~914 s. Here, once per
search, one reduced model of the fitted model is built
(:func:`petsoft.reduced.build.build_reduced`):

* snapshots: the states of the fitted model's full run of the identification window and the
  tangent trajectories dq/dp of every fitted parameter (the sphere's value among them) and of
  the surrounding material's value (a trial moves the term into those cells: on the tests'
  bar this tangent lowered the verified trials' error), from one
  :meth:`~petsoft.calibration.forward.ForwardModel.jacobian` run -- the run whose marker
  sensitivities the search needs anyway (:func:`~petsoft.diagnosis.numerics.model_sensitivities`
  keeps them), so the training costs one more tangent a step, no extra full run;
* checks: that run's markers and its sphere-value column (times :data:`COLUMN_STEP` of the
  surrounding value, a refit step's size), the basis enriched until their error is below
  :data:`~petsoft.reduced.error.TARGET` (0.2) times the noise; ECSW hyper-reduction of the
  elastic forces (the density is not in them; the mass matrix is projected whole).

Added masses only: a stiffness region (``material.heterogeneous``) moved changes the mode
shapes beyond such a basis -- on a 288-tet bar with a 3x stiffer sphere, the reduced model built
to 0.017x the noise at the placed sphere was 6.7x the noise off on the first poll's best trial
(the full assembly projected, not ECSW) -- so its search runs full trials and says why.

A trial then moves the region's cells on the reduced model's own system
(:meth:`~petsoft.dynamics.parameters.ParameterMap.move_regions`: the trial's experiment, the
region's condition and the density rescaled as the full trial's, evaluated as a system built
for it would be), runs the reduced model with the reduced sensitivity of the sphere's value
(:mod:`petsoft.reduced.sensitivity`) and is scored by the same linearised refit. No forward
model is built per trial.

Verification: a poll's best reduced trial is also run on the full model (one Jacobian run,
as a full trial) when it would move the sphere: when its reduced chi2 is below the current
sphere's chi2 on the full model or on the reduced one (the placed sphere's scored by one more
reduced trial at the first poll, a moved-to one's by its own trial). Either comparison alone
could miss a move: on the tests' bar the reduced chi2 differs from the full one by up to ~30
(0.5 %), lower on most polls, higher on the first. The full chi2 of the verified trial decides
whether the search moves, as before; a poll whose best would not move the sphere makes no full
run (the verification was the dearest part of a reduced search: 66 s of a search's ~100 s on
the realistic payload case; on the tests' bar 3 of 8 polls), the sphere stays and its line
says so. The reduced-vs-full marker error of a verified trial (rms over the noise,
:mod:`petsoft.reduced.error`) is recorded, said in the poll's line and in the search's note
(the added term's evidence). The error is
the worse of what the trial is scored on: its run, and its linearised refit's prediction
(the run plus the sphere-value column times the full trial's refit step; the other columns
are the same in both). On the tests' bar the refit's column scaled by the term's whole excess
instead (5x the surrounding density) failed polls whose run and refit were within 0.11x the
noise. Once that error exceeds the target the search falls back to full trials for
the rest of that search (the poll's other trials too) and says so; a model the reduced path
does not cover (another integrator than alpha or be, a static start, the viscoelastic branch,
nonlinear velocity terms, moving supports) or whose built error is above the target gets full
trials from the start (a stiffness region too, above).

Parallel: where the diagnosis runs each model on one rank
(:meth:`~petsoft.diagnosis.placement.Placement.one_rank_each`), every rank builds the same
reduced model on its own (the same run as the one rank alone would make) and the trials are
shared out one per rank; else the model spans the diagnosis' ranks and they run each trial
together. Either way every rank gets every score.
"""

from __future__ import annotations

import contextlib
import gc
import time

import numpy as np
from petsc4py import PETSc

from petsoft.calibration.calibrate import build_forward
from petsoft.calibration.groups import map_on_groups
from petsoft.diagnosis.numerics import keep_sensitivities
from petsoft.errors import PetsoftError
from petsoft.experiment import get_parameter
from petsoft.io.progress import doing, heartbeat
from petsoft.reduced.basis import BasisError
from petsoft.reduced.build import ENERGIES as BUILD_ENERGIES
from petsoft.reduced.build import build_reduced
from petsoft.reduced.error import TARGET, reduced_error
from petsoft.reduced.galerkin import METHODS, steps_for
from petsoft.reduced.sensitivity import sensitivities

#: The POD energy fractions the reduced model is enriched over (build_reduced's).
ENERGIES = BUILD_ENERGIES
#: The built model's sphere-value column is checked scaled by this share of the surrounding
#: material's value: the size of the refit steps trials take (on the tests' bar, 25-770
#: kg/m^3 about a density of 1000).
COLUMN_STEP = 0.1
#: ECSW's training tolerance (build_reduced's ecsw_tolerance).
ECSW_TOLERANCE = 1e-3


class ReducedTrials:
    """One sphere search's reduced model and what its trials and verifications found.

    Build with :meth:`start` (collective); :attr:`active` says whether trials are still
    scored by it (False once it fell back, or when it was never built: :attr:`why` says).

    Attributes
    ----------
    active : bool
    why : str
        Why the search runs full trials (empty while active).
    size : int
        The reduced basis' size r (0 when not built).
    built_error : float
        The built model's error at the fitted model (rms over the noise; NaN when not built).
    verified : list of (int, float, float, float)
        (poll, the reduced-vs-full error of its verified trial (rms over the noise), its
        full and its reduced chi2).
    unverified : list of (int, float, float, float)
        (poll, its best reduced chi2, the current sphere's full and reduced chi2) of the
        polls whose best would not move the sphere (no full run).
    seconds : dict
        Wall time of the build, the reduced trials and the full verifications.
    """

    def __init__(self, diag, search):
        self.diag, self.search = diag, search
        self.active = False
        self.why = ""
        self.size = 0
        self.built_error = float("nan")
        self.verified: list[tuple[int, float, float, float]] = []
        self.unverified: list[tuple[int, float, float, float]] = []
        #: the reduced chi2 of the sphere the search stands at (None before the first poll)
        self.current: float | None = None
        self.fell_back_at: int | None = None
        self.seconds = {"build": 0.0, "trials": 0.0, "verification": 0.0}
        self.trials = 0
        self.fm = self.model = self.v0 = None
        #: whether every rank holds its own model (the trials shared out one per rank)
        self.split = diag.placement.one_rank_each(search.fit.experiment)
        mpi = diag.comm.tompi4py()
        self._quiet = mpi.rank != 0 and self.split
        #: the markers the recording saw (frames, markers): what the error is measured on
        self.seen = search.seen.all(axis=-1)
        self.times = diag.times[diag.ident]
        #: the sphere value's change its column is checked at when built: a refit step of
        #: the size a trial takes (:data:`COLUMN_STEP` of the surrounding value)
        self.column_step = COLUMN_STEP * abs(search.background)

    # -- building -----------------------------------------------------------------------------
    @classmethod
    def start(cls, diag, search, energies=None) -> ReducedTrials:
        """The search's reduced trials, built from the fitted model (``search.fit``); not
        active, with :attr:`why` said, where the reduced path does not apply or its error is
        above the target. Seeds :func:`~petsoft.diagnosis.numerics.model_sensitivities` of
        the fit with the training run's columns. Collective."""
        out = cls(diag, search)
        energies = ENERGIES if energies is None else energies
        t0 = time.perf_counter()
        comm = PETSc.COMM_SELF if out.split else diag.comm
        try:
            with out._speech(), doing("sphere search: the reduced model's training run"):
                why = out._build(comm, energies)
        except (PetsoftError, BasisError) as err:
            why = f"the reduced model could not be built ({err})"
        # (the same on every rank: a rank's own model failing fails them all)
        whys = [w for w in diag.comm.tompi4py().allgather(why) if w]
        out.seconds["build"] = time.perf_counter() - t0
        if whys:
            out.why = whys[0]
            out.destroy()
            return out
        out.active = True
        return out

    def _speech(self):
        """The heartbeat of a rank that repeats rank 0's run stays quiet (one voice a run)."""
        return heartbeat(lambda line: None) if self._quiet else contextlib.nullcontext()

    def _build(self, comm, energies) -> str:
        """Build the model on ``comm``; '' when built below the target, else why not."""
        diag, search, fit = self.diag, self.search, self.search.fit
        exp = fit.experiment
        if not search.parameter.endswith(".density"):
            return ("a moved stiffness region changes the model's mode shapes beyond a basis "
                    "trained at the placed sphere (on the tests' bar the first verified trial "
                    "was 6.7x the noise off)")
        if exp.initial.from_ == "static":
            return ("the model starts from its static equilibrium, which a trial's mass moves "
                    "and the reduced model's reference state does not follow")
        # the surrounding material's value too (a trial moves the term into its cells): its
        # tangent trajectory enriches the basis for what the placed sphere's does not hold
        around = f"material.{search.parameter.rsplit('.', 1)[1]}"
        names = list(fit.names) + ([around] if around not in fit.names else [])
        fm = self.fm = build_forward(exp, names, diag.recording, self.times, comm,
                                     diag.integrator)
        if fm.method not in METHODS:
            return f"integrator {fm.method} is not reduced (only {', '.join(METHODS)})"
        values = np.array([get_parameter(exp, n) for n in names])
        states, tangents = [], [[] for _ in names]

        def watch(n, state, dq):
            states.append(state[0].copy())
            if n == 0:
                self.v0 = state[1].copy()
            else:
                for kept, x in zip(tangents, dq, strict=True):
                    kept.append(x.copy())

        try:
            sim, jac = fm.jacobian(values, watch=watch)
            keep_sensitivities(diag, fit, jac[..., :len(fit.names)])
            parameters = dict(zip(names, map(float, values), strict=True))
            name, i = search.parameter, search.index
            step = [self.column_step]
            self.model, error = build_reduced(
                fm.system, fm.observer, states, self.v0, fm.h, self.times, parameters,
                {"fitted": (parameters, sim)}, diag.sigma, extra=tangents, seen=self.seen,
                method=fm.method,
                radius=fm.integrator.radius if fm.method == "alpha" else 0.5,
                energies=energies, target=TARGET, ecsw_tolerance=ECSW_TOLERANCE,
                ecsw=not fm.system.elastic.nodal_terms,
                sensitivity_checks={"fitted": (parameters, [name], jac[..., [i]], step)})
        finally:
            for x in states + [x for t in tangents for x in t]:
                x.destroy()
        self.size = self.model.basis.size
        self.built_error = error.rms
        if not error.below(TARGET):
            return (f"the reduced model's error at the fitted model is {error.rms:.3g}x the "
                    f"noise at its richest (r = {self.size}), above the target {TARGET:g}x")
        return ""

    # -- trials -------------------------------------------------------------------------------
    def _run(self, region: dict):
        """(sim, d sim/d value (K, M, 3, 1), values) of the reduced model with the sphere at
        ``region`` (the trial's experiment: its cells, its rescaled density)."""
        search = self.search
        exp = search.experiment(region)
        values = np.array([get_parameter(exp, n) for n in search.names])
        model = self.model
        model.system.parameters.move_regions(exp)
        model.set_parameters({})            # the matrices of the moved cells
        sens = sensitivities(model, self.v0, self.fm.h, steps_for(self.times, self.fm.h),
                             [search.parameter])
        sim, own = sens.frames(self.times, self.fm.h)
        return sim, own, values

    def score(self, regions: list) -> list:
        """The reduced trials of ``regions``: per region a
        :class:`~petsoft.calibration.groups.TaskResult` whose value is (chi2 of the linearised
        refit, its step, start values, sim, own column), as the full trials' (the same on
        every rank)."""
        search = self.search
        t0 = time.perf_counter()

        def task(region, _sub):
            with self._speech():
                sim, own, values = self._run(region)
            cols = search.cols.copy()
            cols[:, search.index] = own[search.seen][:, 0]
            chi2, step = search.misfit(sim, cols, values)
            return (chi2, step, dict(zip(search.names, map(float, values), strict=True)), sim,
                    own)

        out = map_on_groups(task, regions, self.diag.comm, groups=None if self.split else 1,
                            one_rank_each=self.split)
        self.trials += len(regions)
        self.seconds["trials"] += time.perf_counter() - t0
        return out

    def verify(self, poll: int, region: dict, reduced: tuple) -> tuple:
        """Run the poll's best reduced trial ``region`` (``reduced``: its :meth:`score`
        value) on the full model; returns the full trial's (chi2, step, values) and records
        the reduced-vs-full error, falling back (:attr:`active` False) where it is above the
        target."""
        search = self.search
        t0 = time.perf_counter()
        sim, own, values = self.diag.placement.alone(lambda sub: search.full_run(region, sub),
                                                     search.fit.experiment)
        self.seconds["verification"] += time.perf_counter() - t0
        chi2, step = search.misfit(sim, search.trial_columns(own), values)
        _, _, _, red_sim, red_own = reduced
        # what the trial is scored on: its run, and its refit's prediction (the other
        # columns are the same in both), at the full trial's step
        s = float(step[search.index])
        error = reduced_error({"run": (sim, red_sim),
                               "refit": (sim + own[..., 0] * s, red_sim + red_own[..., 0] * s)},
                              self.diag.sigma, self.seen)
        self.verified.append((poll, error.rms, chi2, float(reduced[0])))
        if not error.below(TARGET):
            self.active = False
            self.fell_back_at = poll
            self.why = (f"the reduced model's error on poll {poll}'s best trial is "
                        f"{error.rms:.3g}x the noise, above the target {TARGET:g}x")
        return chi2, step, dict(zip(search.names, map(float, values), strict=True))

    def poll(self, number: int, regions: list, full_trials, at: dict, chi2: float) -> list:
        """Poll ``number`` of the search standing at sphere ``at`` (full chi2 ``chi2``):
        ``regions`` scored by the reduced model, the best run on the full model when it would
        move the sphere (module docstring); returns [(chi2, step, values, region)] of
        full-model trials only (what decides the move): the verified one, and where the
        verification fell back, the poll's other trials by ``full_trials(regions)`` (the same
        list); none when the best would not move the sphere."""
        if self.current is None:        # the placed sphere on the reduced model
            placed = self.score([at])[0]
            self.current = placed.value[0] if placed.ok else np.inf
        results = self.score(regions)
        gc.collect()                    # every rank, same point (see run_diagnose)
        scored = [(res.value, r) for res, r in zip(results, regions, strict=True) if res.ok]
        if not scored:
            return []
        value, best = min(scored, key=lambda t: t[0][0])
        if not value[0] < max(chi2, self.current):
            self.unverified.append((number, float(value[0]), float(chi2), self.current))
            return []
        out = [(*self.verify(number, best, value), best)]
        gc.collect()
        if not self.active:
            out += full_trials([r for r in regions if r is not best])
        elif out[0][0] < chi2:          # the search moves there (geometry.fit_sphere)
            self.current = float(value[0])
        return out

    # -- words --------------------------------------------------------------------------------
    def poll_words(self, number: int) -> str:
        """Poll ``number``'s line's addition: its verification, or why it made none (none on
        a full poll)."""
        if self.unverified and self.unverified[-1][0] == number:
            _, red, chi2, current = self.unverified[-1]
            return (f"; reduced trials (r = {self.size}): the best's reduced chi2 {red:.6g} "
                    f"does not beat the current sphere's ({chi2:.6g}, reduced {current:.6g}): "
                    "not verified, the sphere stays")
        if not self.verified or self.verified[-1][0] != number:
            return ""
        poll, err, chi2, red = self.verified[-1]
        words = (f"; reduced trials (r = {self.size}), the best verified on the full model: "
                 f"chi2 {chi2:.6g} (reduced {red:.6g}), reduced-model error {err:.3g}x the "
                 "noise")
        if self.fell_back_at == poll:
            words += f", above the target {TARGET:g}x: full trials from here on"
        return words

    def note(self) -> str:
        """What the reduced trials did in this search (the added term's evidence)."""
        if not self.verified:
            return f"sphere trials on the full model: {self.why}"
        head = (f"sphere trials scored by a reduced model (r = {self.size}, error at the "
                f"fitted model {self.built_error:.3g}x the noise)")
        worst = max(v[1] for v in self.verified)
        skipped = (f"; {len(self.unverified)} poll(s) whose best would not move the sphere "
                   "not verified" if self.unverified else "")
        words = (f"{head}, each poll's best verified on the full model (error up to "
                 f"{worst:.3g}x the noise over {len(self.verified)} poll(s), target "
                 f"{TARGET:g}x{skipped})")
        if self.fell_back_at is not None:
            words += f"; full trials from poll {self.fell_back_at} on: {self.why}"
        return words

    def timing(self) -> str:
        s = self.seconds
        return (f"reduced trials: build {s['build']:.1f} s, {self.trials} reduced trial(s) "
                f"{s['trials']:.1f} s, {len(self.verified)} full verification(s) "
                f"{s['verification']:.1f} s")

    def destroy(self) -> None:
        """Free the reduced model and its forward model (collective on their ranks)."""
        if self.model is not None:
            self.model.destroy()
            self.model = None
        if self.v0 is not None:
            self.v0.destroy()
            self.v0 = None
        if self.fm is not None:
            self.fm.destroy()
            self.fm = None
