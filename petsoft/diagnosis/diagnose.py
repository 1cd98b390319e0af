"""`petsoft diagnose`: calibrate the user's model, test the residual, add missing physics.

The loop (issue 6, first increment):

1. **Base fit.** The recording is split in time: the frames up to ``fraction`` (70 %) of its span
   identify the parameters, the rest is held out for prediction. The user's ``[calibrate]``
   parameters are fitted on the identification window (:func:`run_calibration`).
2. **Verdict.** :func:`~petsoft.diagnosis.evidence.collect_evidence` on the identification
   window: chi-square level and whiteness of the noise-scaled residual; the mismatch's markers,
   region, time windows and frequencies.
3. **Candidates.** If the verdict is not ``consistent``, every modelled candidate
   (:mod:`petsoft.diagnosis.candidates`) is scored at the base fit by the efficient score test
   (:mod:`petsoft.diagnosis.score`) from forward sensitivities of the base and the candidate's
   parameters (candidate at its zero value). Spatial candidates are placed with the adjoint
   per-cell sensitivity maps (Young's modulus: largest |g|; added mass: most negative g).
4. **Model it.** Candidates with a significant score are tried in the order of their p-value
   (then S): the extended model is re-calibrated (all parameters), and kept only if the
   likelihood-ratio statistic chi2_old - chi2_new is significant (chi-square with k dof at
   ``alpha``) **and** the held-out rms improves. An added spatial term's sphere (placed by the
   map) is then fitted too, its centre and radius, and moved when that passes the same two tests
   (:mod:`petsoft.diagnosis.geometry`). Once two or more terms are in, each earlier term of
   values is reconsidered beside the later ones (:mod:`petsoft.diagnosis.reconsider`) before
   the next round. Repeat (at most ``max_additions``) until the
   verdict is consistent or nothing is accepted. A consistent verdict that counts an estimated
   discretisation error (measured while a large physical misfit dominated) is checked once more
   by :func:`resolve_numerics` on the final model; if a refinement now matters it is adopted,
   and the loop goes on if the verdict opens again.
5. **Numerics.** The final model is simulated with the step halved and the mesh refined (a box's
   cells doubled per axis, a mesh file split 1 -> 8, within a cell limit); the change of the
   residual is reported in units of the noise, and what every check found is said in words with
   a recommended mesh (report.json ``numerics``, :mod:`petsoft.diagnosis.numerics_findings`).
   On a mesh file the refinement check also runs before any physics is tried, even when the
   base fit looks consistent.
6. **Report.** report.json (formats.md section 3), report.md, figures, the calibrated extended
   experiment (``diagnosed.toml``) and summary.json.

Noise: the recording's ``/noise position_std`` when present; otherwise it is estimated from the
data (:func:`petsoft.diagnosis.noise.noise_summary`) before the base fit and kept fixed.
"""

from __future__ import annotations

import functools
import gc
import pickle
import time
from pathlib import Path

from petsoft.calibration.calibrate import canonical_method
from petsoft.calibration.forward import forward_defaults
from petsoft.calibration.groups import TaskResult
from petsoft.diagnosis.budget import (
    CANDIDATE_FIT,
    DEFAULT_BUDGET,
    ROUND_SCORING,
    TimeBudget,
    final_check_needs,
    round_needs,
)
from petsoft.diagnosis.clock import PhaseClock

# names the tests and scripts import from here
from petsoft.diagnosis.context import (  # noqa: F401
    NEWTON_RTOL,
    NO_REGIONS,
    DiagnoseError,
    Diagnosis,
    Fit,
    evidence_of,
    fmt,
    format_values,
    model_scales,
    outward_only,
    petsc_comm,
    scored_together,
)
from petsoft.diagnosis.geometry import refit_added_sphere
from petsoft.diagnosis.numerics import (  # noqa: F401
    NumericsChecks,
    final_estimates,
    numerics_check,
    numerics_due,
)
from petsoft.diagnosis.numerics_findings import numerics_findings, refinement_words
from petsoft.diagnosis.numerics_records import NumericsOutcome
from petsoft.diagnosis.outputs import build_diagnosis_report, write_outputs
from petsoft.diagnosis.partial_round import conclude
from petsoft.diagnosis.placement import ONE_RANK_DOFS
from petsoft.diagnosis.reconsider import Added, reconsider
from petsoft.diagnosis.records import AddedTerm, Evidence, ScoreEntry
from petsoft.diagnosis.result import DiagnoseResult
from petsoft.diagnosis.selection import (
    choose,
    escape_plane,
    fit_simplest_first,
    rank_round,
    shortlist,
    worth_fitting,
)
from petsoft.diagnosis.story import NUMERICS_RISK, skipped_numerics
from petsoft.dynamics.factory import system_class
from petsoft.errors import PetsoftError
from petsoft.io.progress import heartbeat


def run_diagnose(experiment, recording, *, out: Path | None = None, fraction: float = 0.7,
                 alpha: float = 0.01, max_additions: int = 3, max_tries: int = 4,
                 method: str = "gauss-newton", gradient: str = "sensitivity",
                 integrator: str | None = None, noise: float | None = None,
                 numerics: bool = True, comm=None, say=None,
                 spelled_out: bool = False, one_rank_dofs: int = ONE_RANK_DOFS,
                 budget: float | None = DEFAULT_BUDGET,
                 reduced_trials: bool = False) -> DiagnoseResult:
    """Diagnose ``experiment`` against a recording (module docstring). All ranks call.

    Parameters
    ----------
    experiment : Experiment
        The user's model, with ``[time]`` and ``[calibrate]``.
    recording : Recording or path
        The data: a :class:`~petsoft.io.recording.Recording` every rank holds, or the path of
        one (read once, on rank 0, and shared).
    out : Path, optional
        Output directory (report.json, report.md, figures, diagnosed.toml, summary.json); None
        writes nothing.
    fraction : float
        Share of the record's span used for identification; the rest is held out.
    alpha : float
        Significance level of the verdict, the score tests and the likelihood-ratio tests.
    max_additions : int
        At most this many terms are added.
    max_tries : int
        At most this many significant candidates are re-calibrated per round.
    method : str
        Calibration method (:data:`petsoft.calibration.calibrate.METHODS`, or an alias of
        :data:`~petsoft.calibration.calibrate.METHOD_ALIASES`).
    gradient : str
        Calibration gradient (:data:`petsoft.calibration.calibrate.GRADIENTS`); finite
        differences are used where a candidate allows no other.
    integrator : str, optional
        Overrides ``[time] integrator`` for every simulation.
    noise : float, optional
        Position noise std (m) when the recording has no ``/noise`` (else estimated from it).
    numerics : bool
        Run the step/mesh refinement check.
    comm : PETSc.Comm or mpi4py communicator, optional
        Default: PETSc.COMM_WORLD.
    say : callable(str), optional
        Progress lines (rank 0).
    spelled_out : bool
        Write diagnosed.toml with every value spelled out instead of as the user's file with
        the calibrated values replaced and the added physics appended.
    one_rank_dofs : int
        On several ranks, a model of at most this many unknowns runs on one rank (a single run
        on the first rank while the others wait; independent runs one per rank): faster, since
        one rank solves it directly (:mod:`petsoft.diagnosis.placement`).
        0 runs every model on all the ranks.
    budget : float or None
        Wall seconds after which no new piece of work starts (a round of candidates, a
        candidate's fit, a sphere search, a numerics check, a reconsideration) and a
        candidate fit under way stops at its next iteration; the report is then written from
        the model reached and says what was left out (:mod:`petsoft.diagnosis.budget`).
        None: no budget.
    reduced_trials : bool
        Score the trials of an added region's sphere search (:mod:`.geometry`) by a
        reduced-order model of the fitted model, each poll's best verified on the full model
        (:mod:`petsoft.diagnosis.reduced_trials`); off, every trial is a full run.

    Returns
    -------
    DiagnoseResult

    Notes
    -----
    Python's cyclic garbage collector is paused for the run and run explicitly at the same
    program points on every rank (after each calibration and score): freeing PETSc objects
    of a parallel communicator is collective (petsc4py's garbage cleanup, communicator
    destruction), and an automatic collection triggered on one rank only (rank 0 alone writes
    files and figures) interleaved those collectives with the solvers' on 2 ranks (seen:
    ranks stuck in VecCreate_MPI vs VecNorm).
    """
    method = canonical_method(method)     # a bad name fails before any work
    enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    t0 = time.perf_counter()

    def pulse(line: str) -> None:
        # where a long simulation is, when no other line was said for 10 s (a refined model's
        # single run took 138 s on the independent L-bracket, a scoring round 108 s); said by
        # the first rank of the running model's communicator (the forward model beats there
        # only), so a run on a group of ranks is heard while rank 0 waits for it
        if say is not None:
            say(f"[{time.perf_counter() - t0:7.1f} s]   {line}")

    try:
        # every forward run of the diagnosis (context.NEWTON_RTOL): one place, the whole run,
        # as a caller's default (the forward model's own, 1e-12 for gradients as exact as the
        # solves, gives way to it; the experiment's [petsc] fm_snes_rtol and the user's
        # -fm_snes_rtol win over both)
        with heartbeat(pulse, interval=10.0), forward_defaults(snes_rtol=repr(NEWTON_RTOL)):
            return _run_diagnose(experiment, recording, out=out, fraction=fraction, alpha=alpha,
                                 max_additions=max_additions, max_tries=max_tries,
                                 method=method, gradient=gradient, integrator=integrator,
                                 noise=noise, numerics=numerics, comm=comm, say=say,
                                 spelled_out=spelled_out, t0=t0,
                                 one_rank_dofs=one_rank_dofs, budget=budget,
                                 reduced_trials=reduced_trials)
    finally:
        gc.collect()
        if enabled:
            gc.enable()


def _run_diagnose(experiment, recording, *, out, fraction, alpha, max_additions, max_tries,
                  method, gradient, integrator, noise, numerics, comm, say,
                  spelled_out, t0: float, one_rank_dofs: int,
                  budget: float | None, reduced_trials: bool) -> DiagnoseResult:
    """The diagnosis of :func:`run_diagnose` (call that: it handles the garbage collector and
    the heartbeat); its log's times count from ``t0``."""
    diag = Diagnosis(experiment, recording, fraction=fraction, alpha=alpha, method=method,
                      gradient=gradient, integrator=integrator, noise=noise, comm=comm,
                      say=say, one_rank_dofs=one_rank_dofs)
    diag.t0 = t0
    diag.budget = TimeBudget(budget, t0, diag.comm)
    diag.reduced_trials = bool(reduced_trials)
    clock = PhaseClock(start=t0)     # its total is the log's clock
    diag.tell(f"petsoft diagnose: {len(diag.times)} frames, identification t <= {diag.cut:.4g} s "
              f"({int(diag.ident.sum())} frames), held out {int(diag.held.sum())}; noise "
              f"{diag.sigma:.3g} m ({diag.sigma_source})")
    if diag.comm.getSize() > 1:
        place = diag.placement
        diag.tell(f"{diag.comm.getSize()} ranks: a model of at most {place.one_rank_dofs} "
                  f"unknowns runs on one rank (this one has {place.dofs(experiment)}; "
                  "independent runs side by side)" if place.one_rank_dofs > 0 else
                  f"{diag.comm.getSize()} ranks: every model runs on all of them")
    with clock.phase("base_fit"):
        base = diag.calibrate(diag.frequency_matched(experiment, label="base fit"),
                              label="base fit")
    dof = diag.dof(len(base.names))
    diag.tell(f"base fit: {format_values(base.names, base.values)}; chi2/dof "
              f"{base.chi2 / dof:.4g}, held-out rms {fmt(base.heldout_rms)} m")
    ev = base_ev = evidence_of(diag, base)
    diag.tell(f"verdict: {ev.verdict} (chi2/dof {ev.noise_test.chi2_per_dof:.4g}, "
              f"whiteness p {ev.noise_test.whiteness_p_value:.3g})")
    current = base
    added: list[AddedTerm] = []
    history: list[Added] = []
    rejected: list[dict] = []
    all_scores: list[dict] = []
    not_modelled: dict = {}
    checks = NumericsChecks(diag, numerics)
    reconsidered = None             # the fit the earlier terms were last reconsidered beside

    if not (numerics and over_budget(diag, "numerics check before the first round",
                                     NUMERICS_RISK)):
        with clock.phase("numerics"):
            current, ev = checks.first(current, ev, len(added))
    diag.fix_scales(current, ev)
    rechecked = False
    while True:
        if ev.verdict == "consistent" or len(added) >= max_additions:
            if rechecked or over_budget(
                    diag, "numerics check again on the final model", RECHECK_RISK,
                    when=numerics and bool(diag.model_error) and ev.verdict == "consistent"):
                break
            rechecked = True
            with clock.phase("numerics"):
                current, ev, ran = checks.recheck_final(current, ev, len(added))
            if not (ran and ev.verdict != "consistent" and len(added) < max_additions):
                break
        rnd = len(added) + 1
        if round_stops(diag, rnd, ev):
            break
        if rnd > 1:
            with clock.phase("numerics"):
                current, ev = checks.first(current, ev, len(added))
            if ev.verdict == "consistent":
                break
        clock.switch("scoring")
        scoring_from = diag.budget.elapsed()
        scores, not_modelled = _score_round(diag, current, ev, rnd)
        # the round's report entries, in the candidates' order (ranked below)
        reported = [s for s, _ in scores]
        significant, left_out, not_tried = _sift(diag, scores, max_tries)
        rejected += not_tried
        # The max_tries best-scoring significant candidates are all fitted (concurrently on
        # groups of ranks) and the best fit among those that pass both tests is added: on a
        # short record every dissipation law (viscous, drag, dry friction, a viscoelastic
        # branch) makes nearly the same first-order change, and a score's p-value favours
        # terms of several parameters (gravity's 3 components out-scored a hidden added mass
        # on a cantilever), so the score alone decides neither.
        diag.budget.record(ROUND_SCORING, diag.budget.elapsed() - scoring_from)
        clock.switch("fits")
        contenders, hopeless = worth_fitting(significant)
        rejected += hopeless
        fit_simplest_first(diag, current, contenders)
        record_shortest_fit(diag, contenders)
        # fits the time budget left unfinished are not judged (partial_round.py)
        contenders, decide = conclude(diag, current, contenders, rnd)
        choice = choose(diag, current, contenders, decide)
        accepted = choice.accepted
        rejected += choice.rejected
        if choice.switch is not None:
            checks.switch_since_check = choice.switch
        rank_round(scores, accepted)
        all_scores += [s.as_report() for s in reported]
        if accepted is None:
            clock.switch(None)
            break
        # a spatial term's sphere is where the map placed it: fit its centre and radius too
        entry, fitted, candidate = refit_added_sphere(diag, *accepted, choice.candidate)
        added.append(entry)
        history.append(Added(entry, candidate, choice.alternatives,
                             candidate.zero_values(current.experiment), untried=left_out))
        current = fitted
        ev = evidence_of(diag, current)
        diag.tell(f"verdict: {ev.verdict} (chi2/dof {ev.noise_test.chi2_per_dof:.4g})")
        if len(history) > 1:
            # before the next round: a term an earlier round took for the one just added
            # must not call for a third (reconsider.py); a piece of work as the one after the
            # last round, which this stands for when left out (said once)
            if not over_budget(diag, "reconsideration of the earlier terms beside the last",
                               RECONSIDER_RISK):
                current, added, ev = _reconsidered(diag, current, history, rejected, added, ev)
            reconsidered = current
        clock.switch(None)
    if (len(history) > 1 and current is not reconsidered
            and not over_budget(diag, "reconsideration of the earlier terms beside the last",
                                RECONSIDER_RISK)):
        with clock.phase("fits"):
            current, added, ev = _reconsidered(diag, current, history, rejected, added, ev)
    result = _conclude(diag, numerics, checks, clock, base, base_ev, current, ev, added,
                       rejected, all_scores, not_modelled)
    # Collect the garbage of this run's PETSc objects on every rank *now*, at the same point:
    # freeing the last object of a communicator is collective (PETSc's garbage cleanup), and
    # rank 0's plotting alone would otherwise trigger Python's collector there only (observed:
    # a 2-rank deadlock in DMPlex creation vs PetscGarbageCleanup).
    gc.collect()
    if out is not None:
        write_outputs(Path(out), diag, result, base_ev, time.perf_counter() - t0,
                      spelled_out=spelled_out)
        diag.tell(f"wrote {out}/ (report.html, report.md, report.json, figures, diagnosed.toml, "
                  "summary.json)")
    return result


def _score_round(diag, current, ev, rnd: int) -> tuple[list, dict]:
    """Round ``rnd``'s candidates for ``current`` (evidence ``ev``) scored: the misfit's
    sensitivity maps beside one shared scoring run, then each candidate's score (early on
    single-rank groups where it can, else on the groups of ranks); returns the (score entry,
    candidate) pairs in the candidates' order, and what the round could not model."""
    plane = escape_plane(diag.data[diag.ident], current.sim[diag.ident], diag.sigma)

    # the shared run's candidates need no sensitivity region: it runs beside the adjoint
    together = _shareable(diag, current, _round_candidates(diag, current, ev, plane,
                                                          NO_REGIONS)[0])
    diag.tell(f"round {rnd}: the misfit's sensitivity maps"
              + (f" beside one scoring run of {', '.join(c.physics for c in together)}"
                 if len(together) > 1 else ""))
    # each group scores what its own job allows while the other's still runs (one rank a
    # group: the runs the scoring below would make, on the same ranks)
    early_scores = (functools.partial(_score_early, diag, current, ev, plane)
                    if diag.placement.one_rank_each(current.experiment) else None)
    maps, shared, early = diag.regions_and_shared_scores(
        current, together, regions=system_class(current.experiment).volume_cells,
        then=early_scores)
    cands, not_modelled = _round_candidates(diag, current, ev, plane, maps)
    diag.tell(f"round {rnd}: ranking {len(cands)} candidates "
              f"({', '.join(c.physics for c in cands)})")
    gc.collect()
    entry_of = ({c.physics: e for c, e in zip(together, shared, strict=True)}
                if shared is not None else {})
    ranked = {i: TaskResult(i, 0, entry_of[c.physics]) for i, c in enumerate(cands)
              if c.physics in entry_of and _shareable(diag, current, [c])}
    ranked.update({i: early[_candidate_key(c)] for i, c in enumerate(cands)
                   if i not in ranked and _candidate_key(c) in early})
    alone = [i for i in range(len(cands)) if i not in ranked]
    ranked.update(zip(alone, diag.placement.on_groups(
        lambda c, sub, cur=current: diag.score(cur, c, comm=sub),
        [cands[i] for i in alone], current.experiment), strict=True))
    gc.collect()
    scores = []
    for i, c in enumerate(cands):
        res = ranked[i]
        s = res.value if res.ok else ScoreEntry.unscored(c, res.error)
        s.round = rnd
        scores.append((s, c))
        diag.tell(f"  {'switch' if c.kind == 'switch' else 'score'} {c.physics:<24} "
                  f"S = {s.score:10.4g}  dof {s.dof}  p = {s.p_value:.3g}"
                  + (f"  ({s.note})" if s.note else ""))
    return scores, not_modelled


def _sift(diag, scores: list, max_tries: int) -> tuple[list, list, list[dict]]:
    """Sort a round's (score entry, candidate) pairs in place (by log p, then S) and short-list
    the significant ones to fit (at most ``max_tries``; :func:`shortlist`); returns the short
    list, the significant ones left out of it, and the rejected entries of the others."""
    rejected: list[dict] = []
    # by log p (p underflows to 0 for strong candidates of different dof), then S
    scores.sort(key=lambda sc: (sc[0].log10_p, -sc[0].score))
    ranked_significant = [(s, c) for s, c in scores if s.p_value < diag.alpha]
    significant, exchanged, left_out = shortlist(ranked_significant, max_tries)
    if exchanged:
        diag.tell(exchanged)
    for s, _ in scores:
        s.direction = None
    for s, c in scores:
        if s.p_value >= diag.alpha:
            rejected.append({"physics": c.physics, "score": s.score,
                             "reason": f"score not significant (p = {s.p_value:.3g})"
                             + (f": {s.note}" if s.note else "")})
    for s, c in ranked_significant:
        if not any(s is t for t, _ in significant):
            rejected.append({"physics": c.physics, "score": s.score,
                             "reason": f"not tried: max {max_tries} tries per round"
                             + (f" ({exchanged})" if exchanged else "")})
    return significant, left_out, rejected


def _conclude(diag, numerics: bool, checks, clock, base, base_ev, current, ev, added,
              rejected, all_scores, not_modelled) -> DiagnoseResult:
    """After the last round: the rejected list cleaned (a physics added later is not
    rejected), the final numerics check if it is made and its findings, and the report."""
    # a physics rejected in one round and added in a later one is reported as added only
    names_added = {a.physics for a in added}
    rejected = [r for r in rejected if r["physics"] not in names_added]
    seen_r: dict[str, dict] = {}
    for r in rejected:
        seen_r.setdefault(r["physics"], r)
    rejected = list(seen_r.values())
    clock.switch("final")
    final_check = numerics and not final_check_stops(diag)
    num = (numerics_check(diag, current, final_estimates(diag, checks.refinements, current))
           if final_check else None)
    findings = None
    if numerics:
        findings = numerics_findings(diag, num, checks.refinements, base, current)
        # one sentence per refinement (the rounds' own findings are in the report's appendix)
        for line in findings.summary + [findings.recommendation or ""]:
            if line:
                diag.tell(f"numerics: {line}")
    outcome = NumericsOutcome(final=num, rounds=list(checks.refinements),
                              model_error=dict(diag.model_error),
                              sigma_verdict=diag.sigma_verdict, findings=findings)
    # a check not made is said in the verdict box and on the console, with what it risks
    skipped = ([] if numerics else [skipped_numerics()]) + diag.budget.skipped
    for label, why in (findings.unchecked if findings is not None else {}).items():
        noun = refinement_words(label)[1]
        skipped.append({"check": f"{noun} refinement", "why": why,
                        "risk": f"the {noun}'s error is not known: a mismatch it causes may be "
                                "blamed on physics"})
    report = build_diagnosis_report(diag, base, current, base_ev, ev, added, rejected,
                                    numerics=findings.as_report() if findings else None,
                                    skipped=skipped)
    # where the time went (report.json ``timings``): the report and figures are written after
    # this split is taken, so ``final`` leaves them out and ``total`` is the run up to here
    report["timings"] = clock.seconds()
    report["budget"] = diag.budget.summary()
    result = DiagnoseResult(verdict=base_ev.verdict, final_verdict=ev.verdict,
                            report=report, base=base, final=current,
                            added=[a.as_report() for a in added],
                            rejected=rejected, scores=all_scores,
                            not_modelled=not_modelled, numerics=outcome.as_report(),
                            evidence=ev)
    return result


#: What a reader risks when a piece of work is left out for the time budget (report.json
#: ``skipped``).
ROUND_RISK = ("the model's verdict is {verdict} (chi2/dof {chi2:.3g}): physics the data still "
              "show may be missing from it and is not named")
RECHECK_RISK = ("the verdict counts a discretisation error estimated on an earlier model; "
                "measured on the final one it may matter")
RECONSIDER_RISK = ("an earlier term may be one a later term makes unnecessary; it is kept "
                   "without that check")


def over_budget(diag, what: str, risk: str, when: bool = True,
                needs: tuple[float | None, str] = (None, "")) -> bool:
    """:meth:`TimeBudget.stops <petsoft.diagnosis.budget.TimeBudget.stops>` of the diagnosis'
    budget, said on its log (collective); ``needs``: (seconds, what they are) the piece is
    foreseen to need, seconds None when it is not foreseen."""
    return diag.budget.stops(what, risk, diag.tell, when, needs=needs[0], needs_for=needs[1])


def round_stops(diag, rnd: int, ev) -> bool:
    """Whether round ``rnd`` of candidate physics is not to start (collective): the budget is
    spent, or the round is foreseen to end past it (:func:`~petsoft.diagnosis.budget.
    round_needs`; round 1 is not foreseen: nothing of its kind was made)."""
    return over_budget(diag, f"round {rnd} of candidate physics", ROUND_RISK.format(
        verdict=ev.verdict, chi2=ev.noise_test.chi2_per_dof),
        needs=round_needs(diag.budget) if rnd > 1 else (None, ""))


def final_check_stops(diag) -> bool:
    """Whether the numerics check of the final model is not to start (collective): the
    budget is spent, or the check's refined runs, as long as a numerics check's before it,
    would end past it (:func:`~petsoft.diagnosis.budget.final_check_needs`)."""
    return over_budget(diag, "numerics check of the final model", NUMERICS_RISK,
                       needs=final_check_needs(diag.budget))


def record_shortest_fit(diag, contenders: list) -> None:
    """Record a round's shortest finished candidate fit (its wall time, the same on every
    rank: it travels with the fit) for :func:`~petsoft.diagnosis.budget.round_needs`. A fit
    the budget left unfinished or that was stopped as unable to win says nothing of what a
    fit that can add a term takes; a round without a finished one records nothing."""
    done = [s.fit.seconds for s, _ in contenders
            if s.fit is not None and not s.fit.stopped and not s.unfinished]
    if done:
        diag.budget.record(CANDIDATE_FIT, min(done))


def _reconsidered(diag, current, history, rejected, added, ev):
    """(fit, added entries, evidence) after :func:`reconsider` tried each earlier term's
    runners-up in its place beside the later ones (the verdict is new only when a term was
    replaced or taken out; the entries are the history's, which may also have said a tie)."""
    before = [h.candidate.physics for h in history]
    current = reconsider(diag, current, history, rejected)
    # (the entries are frozen: reconsider puts a changed copy in the history)
    added = [h.entry for h in history]
    if [h.candidate.physics for h in history] != before:
        ev = evidence_of(diag, current)
        diag.tell(f"verdict: {ev.verdict} (chi2/dof {ev.noise_test.chi2_per_dof:.4g})")
    return current, added, ev


def _round_candidates(diag, current, ev: Evidence, plane, maps: dict) -> tuple[list, dict]:
    """A round's candidates for ``current`` (:func:`build_candidates`) with the sensitivity
    regions ``maps`` (:data:`NO_REGIONS`: the non-spatial ones and the evidence's)."""
    from petsoft.diagnosis.candidates import build_candidates

    return build_candidates(
        current.experiment, evidence_region=ev.region, stiffness_region=maps["stiffness"],
        density_region=maps["density"], centroids=diag.centroids, scales=diag.scales,
        plane=plane)


def _candidate_key(candidate) -> bytes:
    """What identifies a candidate across ranks: its pickled fields (candidates built from
    the same values on different ranks are equal; a region's centre is an array)."""
    return pickle.dumps(candidate)


def _score_early(diag, current, ev: Evidence, plane, kind: str, maps: dict, sub) -> dict:
    """The scores one group makes right after its job of
    :meth:`~petsoft.diagnosis.context.Diagnosis.regions_and_shared_scores` (``kind``): after
    the sensitivity maps the spatial candidates (placed by them), after the shared scoring run
    the others it did not score (a compliant support, switches, whose current columns that
    run gave). ``{candidate key: TaskResult}``, a failed score with its error as the scoring's
    own groups give it."""
    cands = _round_candidates(diag, current, ev, plane, maps)[0]
    if kind == "regions":
        chosen = [c for c in cands if c.region is not None]
    else:
        chosen = [c for c in cands if c.region is None and not _shareable(diag, current, [c])]
    out = {}
    for i, c in enumerate(chosen):
        try:
            out[_candidate_key(c)] = TaskResult(i, 0, diag.score(current, c, comm=sub))
        except PetsoftError as err:     # (every rank of the group raised it)
            out[_candidate_key(c)] = TaskResult(i, 0, None, str(err) or type(err).__name__)
    return out


def _shareable(diag, current, candidates: list) -> list:
    """Those of ``candidates`` that one scoring run can score together
    (:func:`scored_together`)."""
    return [c for c in candidates
            if scored_together(c, diag.exact_columns(c, current.experiment))]
