"""Choosing among candidate physics terms: the tests a fitted candidate must pass and the
tie-breaks between those that pass (held-out prediction, then the fewest parameters, then
chi2 + k ln n, then the vocabulary's order), fitting the simplest first
(:func:`fit_simplest_first`); :func:`escape_plane` proposes the plane a body left the data on.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import stats

from petsoft.diagnosis.context import Diagnosis, Fit, fmt, term_values
from petsoft.diagnosis.records import AddedTerm, Judgement, ScoreEntry

#: Fitted chi2 values within this of the best are statistically tied (see _run_diagnose).
TIE_CHI2 = 2.0


def escape_plane(data: np.ndarray, sim: np.ndarray, sigma: float,
                 threshold: float = 3.0) -> dict | None:
    """Where the simulation leaves the extent of the data: a plane that could have stopped it.

    For each axis and side, ``excess`` = how far the simulated markers go beyond the farthest
    recorded position on that side (seen samples). The side with the largest excess above
    ``threshold`` x the noise gives a plane through the data's extreme, its unit normal
    pointing back into the data (the allowed side).

    Returns
    -------
    dict or None
        ``{"point", "normal", "excess"}``, None when the simulation stays within the data.
    """
    seen = np.isfinite(data)
    best = None
    for axis in range(3):
        ok = seen[..., axis]
        if not ok.any():
            continue
        d, s = data[..., axis][ok], sim[..., axis][ok]
        for sign in (1.0, -1.0):
            excess = float(np.max(sign * s) - np.max(sign * d))
            if excess > threshold * sigma and (best is None or excess > best[0]):
                at = np.unravel_index(np.argmax(np.where(ok, sign * data[..., axis], -np.inf)),
                                      ok.shape)
                point = np.nan_to_num(data[at[0], at[1]]).astype(float)
                normal = np.zeros(3)
                normal[axis] = -sign
                best = (excess, point, normal)
    if best is None:
        return None
    return {"point": best[1].tolist(), "normal": best[2].tolist(), "excess": best[0]}


def _tests(diag: Diagnosis, current: Fit, new: Fit, c) -> tuple[float, float, bool]:
    """The likelihood ratio of ``new`` over ``current``, its p-value (chi2 with as many
    degrees of freedom as ``c`` has parameters) and whether the held-out rms improved."""
    lr = current.chi2 - new.chi2
    p_lr = float(stats.chi2.sf(max(lr, 0.0), n_parameters(c)))
    better = (new.heldout_rms is None or current.heldout_rms is None
              or new.heldout_rms < current.heldout_rms)
    return lr, p_lr, better


def passes_both(diag: Diagnosis, current: Fit, new: Fit, c) -> bool:
    """Whether ``new``, the fit of candidate ``c`` extending ``current``, passes both tests
    (the likelihood ratio's at ``alpha``, and the held-out rms improves), quietly."""
    _, p_lr, better = _tests(diag, current, new, c)
    return p_lr < diag.alpha and better


def n_parameters(c) -> int:
    """How many parameters candidate ``c`` adds (at least 1: a switch adds one choice)."""
    return max(len(c.parameters), 1)


def judge(diag: Diagnosis, current: Fit, s: ScoreEntry, c) -> Judgement:
    """Keep candidate ``c`` (score entry ``s`` with its fit) only if the likelihood ratio is
    significant AND the held-out rms improves: the term to add, or why not."""
    if s.skipped:
        diag.tell(f"  try {c.physics}: not fitted ({s.skipped})")
        return Judgement(reason=f"not fitted: {s.skipped}")
    new = s.fit
    if new is not None and new.stopped:
        diag.tell(f"  try {c.physics}: not added: its fit was {new.stopped}")
        return Judgement(reason=f"its fit was {new.stopped}")
    if new is None:
        diag.tell(f"  try {c.physics}: the fit failed ({s.fit_error})")
        return Judgement(reason=f"the fit failed: {s.fit_error}")
    lr, p_lr, better = _tests(diag, current, new, c)
    ok = p_lr < diag.alpha and better
    diag.tell(f"  try {c.physics}: LR {lr:.4g} (p {p_lr:.3g}), held-out rms "
              f"{fmt(current.heldout_rms)} -> {fmt(new.heldout_rms)} m: "
              f"{'passes both tests' if ok else 'rejected'}")
    if not ok:
        why = []
        if p_lr >= diag.alpha:
            why.append(f"no significant improvement (likelihood ratio {lr:.3g}, p = "
                       f"{p_lr:.3g})")
        if not better:
            why.append(f"held-out rms did not improve ({fmt(current.heldout_rms)} -> "
                       f"{fmt(new.heldout_rms)} m)")
        return Judgement(reason="; ".join(why))
    what = "switch score test" if c.kind == "switch" else "score test"
    values, std = term_values(new, c.parameters)
    entry = AddedTerm(physics=c.physics, parameters=values, std=std, score=s.score,
                      rms_after=new.rms,
                      evidence=(f"{what} S = {s.score:.4g} (p = {s.p_value:.3g}); likelihood "
                                f"ratio {lr:.4g} (p = {p_lr:.3g}); held-out rms "
                                f"{fmt(current.heldout_rms)} -> {fmt(new.heldout_rms)} m"
                                + (f"; region {c.region}" if c.region else "")
                                + (f"; {c.reason}" if c.reason else "")),
                      region=c.region)
    return Judgement(entry)


@dataclass
class Choice:
    """The outcome of one round's choice among the fitted candidates.

    Attributes
    ----------
    accepted : (AddedTerm, Fit) or None
        The added term and its fit.
    rejected : list of dict
        Fitted candidates not added, with the reason.
    switch : str or None
        The physics of an accepted model switch (contact, a nonlinear law): the numerics must
        be checked again after it.
    candidate : Candidate or None
        The added term's candidate.
    alternatives : list of (ScoreEntry, Candidate)
        The round's other candidates that passed both tests (score entry with its fit,
        candidate), best first: what :mod:`petsoft.diagnosis.reconsider` tries in its place
        once later terms are in.
    """

    accepted: tuple | None
    rejected: list
    switch: str | None
    candidate: object = None
    alternatives: list = field(default_factory=list)


#: A significant candidate whose score is below this share of the round's best is not fitted.
MIN_SCORE_SHARE = 0.01
#: Two one-parameter candidates whose score directions (:attr:`petsoft.diagnosis.score.
#: ScoreResult.direction`) have |cos| at least this make the same first-order change: one
#: repeats the other (:func:`shortlist`)
DUPLICATE_COS = 0.95
#: A candidate outside a round's best scores takes the place of one that repeats a better one
#: when it scores at least this share of the round's best (:func:`shortlist`)
DISTINCT_SHARE = 0.5


def _repeats(entry: ScoreEntry,
             others: list[ScoreEntry]) -> tuple[ScoreEntry, float] | None:
    """The first of ``others`` whose score direction ``entry``'s repeats, with |cos|; None."""
    d = entry.direction
    if d is None:
        return None
    for other in others:
        e = other.direction
        if e is not None and e.shape == d.shape:
            c = abs(float(np.dot(d.astype(float), e.astype(float))))
            if c >= DUPLICATE_COS:
                return other, c
    return None


def shortlist(ranked: list, max_tries: int) -> tuple[list, str | None, list]:
    """The candidates of a round to fit: the ``max_tries`` best of ``ranked`` (significant
    (score entry, candidate) pairs, best first), except that the last of them whose first-order
    change repeats a better one's (:data:`DUPLICATE_COS`) gives its place to the best candidate
    outside them whose change is new and whose score is at least :data:`DISTINCT_SHARE` of the
    round's best. On the independent L-bracket with an added mass, four dissipation laws
    (dry friction, quadratic and linear drag, mass damping; scores 7.1e4-8.4e4, directions
    |cos| 0.96-0.996 apart) filled the shortlist two runs in a row and the added mass (7.1e4,
    fifth by 0.5 %, |cos| 0.38-0.43 with them) was not fitted in round 1, which then took a
    drag for it; now the linear drag gives it its place.

    Returns
    -------
    picked : list
        The (score entry, candidate) pairs to fit.
    line : str or None
        What was exchanged, for the log and the report.
    left_out : list
        The (score entry, candidate) pair that gave its place (empty when none did): a twin
        of a fitted candidate to first order (its entry's ``repeats`` names which), which
        :mod:`petsoft.diagnosis.reconsider` still tries in the place of the term its round
        adds.
    """
    top, rest = list(ranked[:max_tries]), ranked[max_tries:]
    if not rest or not top:
        return top, None, []
    best = max(s.score for s, _ in ranked)
    repeating = [i for i in range(1, len(top))
                 if _repeats(top[i][0], [s for s, _ in top[:i]]) is not None]
    if not repeating:
        return top, None, []
    new = next(((s, c) for s, c in rest
                if s.score >= DISTINCT_SHARE * best and s.direction is not None
                and _repeats(s, [e for e, _ in top]) is None), None)
    if new is None:
        return top, None, []
    i = repeating[-1]
    (_, out_c), (twin, cos) = top[i], _repeats(top[i][0], [s for s, _ in top[:i]])
    picked = top[:i] + top[i + 1:] + [new]
    top[i][0].repeats = twin.physics
    return picked, (f"shortlist: {new[1].physics} (S = {new[0].score:.4g}, "
                    f"{new[0].score / best:.0%} of the best) is fitted in place of "
                    f"{out_c.physics}, whose first-order change repeats {twin.physics}'s "
                    f"(|cos| {cos:.3f})"), [top[i]]


def worth_fitting(significant: list) -> tuple[list, list]:
    """Split the round's significant (score entry, candidate) pairs into those worth fitting
    and the rejected entries of the others: a score is the misfit the term removes to first
    order (chi2 units, the likelihood ratio's approximation), so a term scoring below
    :data:`MIN_SCORE_SHARE` of the best explains, to first order, at most that share of what
    the best does (on the independent suite's plate with gravity concealed: gravity 4.5e6,
    then a contact plane, an added mass and a stiffness region at 0.05-0.2 %, whose fits took
    longer than gravity's)."""
    if not significant:
        return [], []
    best = max(s.score for s, _ in significant)
    keep, rejected = [], []
    for s, c in significant:
        if s.score >= MIN_SCORE_SHARE * best:
            keep.append((s, c))
            continue
        rejected.append({"physics": c.physics, "score": s.score,
                         "reason": f"not fitted: its score S = {s.score:.4g} is below "
                                   f"{MIN_SCORE_SHARE:.0%} of the round's best ({best:.4g}): "
                                   "to first order it explains at most that share of what the "
                                   "best does"})
    return keep, rejected


def fit_simplest_first(diag: Diagnosis, current: Fit, contenders: list) -> None:
    """Fit the contenders ((score entry, candidate) pairs) in batches of as many parameters,
    fewest first; a batch is not fitted when a fitted contender with fewer parameters already
    passes both tests and predicts the held-out data to the noise (:func:`choose` would keep
    that one whatever the batch fitted). A skipped entry's ``skipped`` says why."""
    counts = sorted({n_parameters(c) for _, c in contenders})
    level = heldout_noise_level(diag)
    for k in counts:
        batch = [(s, c) for s, c in contenders if n_parameters(c) == k]
        enough = sufficient(diag, current, contenders, k)
        if enough is None:
            diag.fit_candidates(batch, current,
                                rivals=[(c.physics, s.fit) for s, c in contenders
                                        if s.fit is not None])
            continue
        simpler, rms_h = enough
        why = (f"{simpler.physics} ({n_parameters(simpler)} parameter"
               f"{'s' if n_parameters(simpler) > 1 else ''}) already predicts the held-out data "
               f"to the noise (rms {fmt(rms_h)} m <= {fmt(level)} m); "
               f"with {k} parameters this term could not be preferred")
        for s, _ in batch:
            s.skipped = why
        diag.tell(f"not fitting {', '.join(c.physics for _, c in batch)}: {why}")


def sufficient(diag: Diagnosis, current: Fit, contenders: list, k: int) -> tuple | None:
    """(candidate, held-out rms) of the first fitted contender with fewer than ``k``
    parameters that passes both tests and predicts the held-out data to the noise
    (:func:`heldout_noise_level`); None when there is none. :func:`choose` then keeps a
    contender of at most its parameters, whatever a contender of ``k`` or more parameters
    fits: it stays among the best held-out predictions (within the noise) with fewer."""
    level = heldout_noise_level(diag)
    for s, c in contenders:
        new = s.fit
        if (n_parameters(c) >= k or new is None or new.stopped
                or new.heldout_rms is None):
            continue
        if passes_both(diag, current, new, c) and new.heldout_rms <= level:
            return c, new.heldout_rms
    return None


def heldout_noise_level(diag: Diagnosis) -> float:
    """The held-out rms (m) below which a prediction is as good as the noise lets one tell:
    the upper ``1 - alpha`` point of the rms of pure noise on the held-out window's seen
    samples (chi2 test, n samples: sigma sqrt(chi2_{1-alpha}(n) / n)); 0 without a held-out
    window."""
    n = int(np.isfinite(diag.data[diag.held]).sum())
    if n == 0:
        return 0.0
    return float(diag.sigma * np.sqrt(stats.chi2.ppf(1.0 - diag.alpha, n) / n))


def choose(diag: Diagnosis, current: Fit, contenders: list, decide: bool = True) -> Choice:
    """Among fitted (score entry, candidate) pairs, the one to add (if any passes both tests).

    Each entry's ``fitted_chi2`` is set. The best held-out predictions (within 2 % of the best, or
    within the noise: :func:`heldout_noise_level`) are equally good; among those the fewest
    parameters, then the lowest chi2 + k ln n; within :data:`TIE_CHI2` of it, the
    vocabulary's order. ``decide`` False: each is judged (those failing a test rejected), but
    none is chosen (a round the time budget left undecided: :mod:`.partial_round`).
    """
    from petsoft.diagnosis.report import PHYSICS

    # Schwarz's (Bayesian) criterion chi2 + k ln(n), n the identification samples: with
    # thousands of samples Akaike's 2 per parameter let a standard linear solid (2 parameters,
    # stiffness damping as its short-relaxation limit) win by 6 in chi2 over the hidden
    # stiffness damping itself (scripts/benchmarks/bench_diagnose.py, stiffness-damping)
    rejected: list[dict] = []
    accepted = None
    switch = None
    penalty = float(np.log(max(np.isfinite(diag.data[diag.ident]).sum(), 2)))
    passed = []
    for s, c in contenders:
        verdict = judge(diag, current, s, c)
        s.fitted_chi2 = s.fit.chi2 if s.fit is not None else None
        if verdict.added:
            # a term must not win by its number of parameters alone
            bic = s.fit.chi2 + penalty * n_parameters(c)
            passed.append((bic, s.fit.heldout_rms or 0.0, s, c, verdict))
        else:
            rejected.append({"physics": c.physics, "score": s.score,
                             "reason": verdict.reason})
    if passed and not decide:
        diag.tell(f"  none chosen: {', '.join(t[3].physics for t in passed)} passed both tests, "
                  "but the round cannot choose without its unfinished fits")
        return Choice(None, rejected, None)
    if passed:
        # The better held-out prediction (by more than 2 %) decides: the second test of a
        # term, and the one a flexible term cannot pass by fitting the model's own errors
        # (a standard linear solid fitted a hidden viscous damping 90 better in chi2 than
        # the viscous damping itself, because alpha's numerical damping had to be
        # compensated too, and then predicted 5 % worse). Predictions within 2 % of the best,
        # or that leave no more than the noise on the held-out window (its chi2 test), are
        # equally good; among those the fewest parameters, then the lowest chi2 + k ln n;
        # within TIE_CHI2 of it, the vocabulary's order (the more common explanation first).
        top = min(t[1] for t in passed)
        noise_level = heldout_noise_level(diag)
        close = [t for t in passed if t[1] <= max(1.02 * top, noise_level)]
        fewest = min(n_parameters(t[3]) for t in close)
        simplest = [t for t in close if n_parameters(t[3]) == fewest]
        low = min(t[0] for t in simplest)
        tied = [t for t in simplest if t[0] <= low + TIE_CHI2]
        order = list(PHYSICS)
        tied.sort(key=lambda t: order.index(t[3].physics))
        first = tied[0]
        passed.sort(key=lambda t: (t[1], t[0]))
        passed.remove(first)
        passed.insert(0, first)
        chi2_best, _, s_best, c_best, v_best = passed[0]
        # what it was preferred to, said after the tests' words
        evidence = v_best.entry.evidence
        if len(tied) > 1:
            evidence += (
                "; ambiguous: " + ", ".join(t[3].physics for t in tied if t is not first)
                + f" predicted and fitted as well (held-out rms within 2 % or the noise, "
                f"as many parameters, chi2 + k ln n within {TIE_CHI2:g}); chosen by the "
                "vocabulary's order")
        simpler = [t for t in close if t not in simplest]
        if simpler:
            evidence += (
                "; " + ", ".join(t[3].physics for t in simpler) + " (more parameters) "
                "predicted the held-out data no better (within 2 % or the noise): the "
                "explanation with fewer parameters is kept")
        if len(passed) > 1:
            evidence += (
                "; among the best-scoring candidates it predicted the held-out data best ("
                + ", ".join(f"{c.physics} held-out rms {fmt(h)} m, chi2 + k ln n "
                            f"{chi2:.6g}" for chi2, h, _, c, _ in passed)
                + ")")
        accepted = (replace(v_best.entry, evidence=evidence), s_best.fit)
        diag.tell(f"  chosen: {c_best.physics}" + (
            f" (of {len(passed)} that pass both tests: the best held-out prediction, then the "
            "fewest parameters)" if len(passed) > 1 else ""))
        if c_best.kind == "switch":
            switch = c_best.physics
        for chi2, _, s, c, _ in passed[1:]:
            rejected.append({"physics": c.physics, "score": s.score,
                             "reason": f"fitted too, {c_best.physics} was preferred "
                                       f"(held-out rms {fmt(s_best.fit.heldout_rms)} "
                                       f"vs {fmt(s.fit.heldout_rms)} m; chi2 + k ln n "
                                       f"{chi2_best:.6g} vs {chi2:.6g})"})
    if accepted is None:
        return Choice(accepted, rejected, switch)
    return Choice(accepted, rejected, switch, c_best, [(s, c) for _, _, s, c, _ in passed[1:]])


def rank_round(scores: list, accepted) -> None:
    """Number the round's (score entry, candidate) pairs ``scores`` (each entry's ``rank``):
    the added term (``accepted``: the AddedTerm and its fit, or None), the other fitted ones by
    chi2, then the rest by score (the order ``scores`` comes in)."""
    ranking = sorted((sc for sc in scores if sc[0].fitted_chi2 is not None),
                     key=lambda sc: (accepted is None or sc[0].fit is not accepted[1],
                                     sc[0].fitted_chi2))
    ranking += [sc for sc in scores if sc not in ranking]
    for i, (s, _) in enumerate(ranking, 1):
        s.rank = i
