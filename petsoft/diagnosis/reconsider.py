"""An earlier addition reconsidered once later terms are in (replacement in stepwise selection).

Each round adds the candidate that best predicts the held-out data *given the terms added so
far*. With two effects concealed, the first round chooses while the second effect is still
missing, and a term that absorbs part of it can win: on the independent L-bracket with a mass
damping and an added mass, round 1 chose quadratic drag (held-out rms 0.363 mm against the mass
damping's 0.421 mm, the added mass still missing) and round 2 the added mass.

So, after every round that leaves two or more terms (before the next round is ranked) and
after the last one (when the model changed since), each earlier term of values only
(:attr:`Candidate.retractable`) is taken out, alone and with each of its round's runners-up
(candidates that passed both tests, up to :data:`MAX_ALTERNATIVES`; for a term that replaced
another, the one it replaced) in its place, every later term kept, and refitted. Alone: on
the bracket with an added mass only, round 1 took a quadratic drag for it, which the added
mass of round 2 left at zero. The best option by chi2 + k ln n replaces the term when it fits
the identification window better by that criterion (by more than
:data:`~petsoft.diagnosis.selection.TIE_CHI2`) and predicts the held-out data as well (within
2 % or the noise level). Both tests: on the first bracket, linear drag in place of the
quadratic one predicted the held-out window 8 % better but fitted 2450 worse in chi2; a rule
on the held-out window alone took it (the verdict went from consistent to missing-physics)
before the true mass damping, third in round 1, was tried.

After every round, not only the last: with the added mass's sphere fitted
(:mod:`petsoft.diagnosis.geometry`, 3734038), the same bracket's verdict after round 2 stayed
missing-physics, round 3 added a dry friction beside the quadratic drag, and reconsidered only
then, beside the friction, the mass damping in the drag's place fitted 80 worse in chi2: two
terms stood in for the one missing.

A candidate its round's shortlist left out because its first-order change repeated a fitted
one's (:func:`~petsoft.diagnosis.selection.shortlist`, :attr:`Added.untried`) is tried in the
term's place too, after the runners-up: to first order it is the same change as a fitted
candidate, but the fit beside the later terms may tell them apart. On ``bench_diagnose``'s
cantilever with a mass damping and an added mass (6b0005d), the mass damping gave its place in
round 1 as a repeat of the quadratic drag (|cos| 1.000), round 1 added a stiffness damping and
round 2 the added mass, and the mass damping was never tried in the stiffness damping's place.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from petsoft.diagnosis.context import Diagnosis, Fit, fmt, term_values
from petsoft.diagnosis.records import AddedTerm, ScoreEntry
from petsoft.diagnosis.selection import TIE_CHI2, heldout_noise_level, n_parameters
from petsoft.errors import PetsoftError

#: Runners-up tried in place of each earlier term (its round's best first).
MAX_ALTERNATIVES = 3


@dataclass
class Added:
    """One round's addition: the term added, its candidate, the round's runners-up (score
    entry, candidate), its parameters' values before it was added (to take it out) and the
    round's candidates left out of its shortlist as repeats of a fitted one (score entry with
    ``repeats``, candidate)."""

    entry: AddedTerm
    candidate: object
    alternatives: list
    zeros: dict
    untried: list = field(default_factory=list)


def _what(s: ScoreEntry, i: int) -> str:
    """What an option of round ``i`` (0-based) was: a runner-up, or a candidate the shortlist
    left out as a repeat of another's first-order change."""
    if s.replaced:
        return f"the term it replaced (round {i + 1})"
    if s.repeats:
        return (f"round {i + 1}'s candidate not fitted there (its first-order change repeated "
                f"{s.repeats}'s)")
    return f"round {i + 1}'s runner-up"


def _penalty(diag: Diagnosis) -> float:
    """Schwarz's ln n per parameter, n the identification window's seen samples."""
    return float(np.log(max(np.isfinite(diag.data[diag.ident]).sum(), 2)))


def better_replacement(diag: Diagnosis, new: Fit, old: Fit, extra: int) -> bool:
    """Whether ``new`` (``extra`` parameters more than ``old``, may be negative) replaces
    ``old``: chi2 + k ln n lower by more than TIE_CHI2, and a held-out rms no worse than 2 %
    (or within the noise level)."""
    if new.heldout_rms is None or old.heldout_rms is None:
        return False
    fits = new.chi2 + _penalty(diag) * extra < old.chi2 - TIE_CHI2
    predicts = new.heldout_rms <= max(1.02 * old.heldout_rms, heldout_noise_level(diag))
    return fits and predicts


def as_good(diag: Diagnosis, new: Fit, old: Fit, extra: int) -> bool:
    """Whether ``new`` (``extra`` parameters more than ``old``) explains the data as well as
    ``old`` without replacing it: chi2 + k ln n within TIE_CHI2 either way, and each held-out
    rms no worse than the other's by 2 % (or within the noise level). On the independent
    suite's thin plate a linear drag in place of a mass damping: chi2 6328.09 vs 6329.31, the
    same held-out rms (a node's surface follows its mass there: the same force)."""
    if new.heldout_rms is None or old.heldout_rms is None:
        return False
    level = heldout_noise_level(diag)
    return (abs(new.chi2 + _penalty(diag) * extra - old.chi2) <= TIE_CHI2
            and new.heldout_rms <= max(1.02 * old.heldout_rms, level)
            and old.heldout_rms <= max(1.02 * new.heldout_rms, level))


def reconsider(diag: Diagnosis, current: Fit, history: list[Added],
               rejected: list[dict]) -> Fit:
    """Try each earlier retractable term's runners-up in its place (module docstring); updates
    ``history`` (entries, candidates) and ``rejected`` in place; returns the final fit."""
    swapped = False
    for i, added in enumerate(history[:-1]):
        cand = added.candidate if added is not None else None
        if cand is None or not cand.retractable:
            continue
        later = ", ".join(h.candidate.physics for h in history[i + 1:])
        best = None
        # None: the term taken out with nothing in its place (it may have stood in for a
        # later one: the bracket's added mass was first taken for a quadratic drag, which
        # the added mass then left at zero)
        options = [(None, None)] + [
            (s, alt) for s, alt in added.alternatives[:MAX_ALTERNATIVES] + added.untried
            if alt.retractable and not any(h is not None and h.candidate.physics == alt.physics
                                           for h in history)]
        for s, alt in options:
            label = (f"reconsider {cand.physics} -> {alt.physics}" if alt is not None
                     else f"reconsider without {cand.physics}")
            diag.tell(f"{label}: " + (_what(s, i) + " in its place" if alt is not None
                                      else "taken out") + f", with {later} in")
            without = cand.retract(current.experiment, added.zeros)
            try:
                fit = diag.calibrate(alt.extend(without) if alt is not None else without,
                                     label=label)
            except PetsoftError as err:      # collective, as every fit
                diag.tell(f"{label}: the fit failed ({err}); kept {cand.physics}")
                continue
            extra = (n_parameters(alt) if alt is not None else 0) - n_parameters(cand)
            ok = better_replacement(diag, fit, current, extra)
            diag.tell(f"{label}: held-out rms {fmt(current.heldout_rms)} -> "
                      f"{fmt(fit.heldout_rms)} m, chi2 {current.chi2:.6g} -> {fit.chi2:.6g}: "
                      + ("better" if ok else f"{cand.physics} stays"))
            bic = fit.chi2 + _penalty(diag) * extra
            if ok and (best is None or bic < best[0]):
                best = (bic, s, alt, fit)
            elif alt is not None and as_good(diag, fit, current, extra):
                # kept by the tie-break, but the user must know the data cannot tell
                added.entry = replace(added.entry, evidence=added.entry.evidence + (
                    f"; ambiguous: with {later} in, {alt.physics} in its place fits and "
                    f"predicts as well (chi2 {fit.chi2:.6g} vs {current.chi2:.6g}, held-out "
                    f"rms {fmt(fit.heldout_rms)} vs {fmt(current.heldout_rms)} m): the data "
                    f"do not tell the two apart; {cand.physics} is kept (added first)"))
        if best is None:
            continue
        _, s, alt, fit = best
        change = (f"chi2 {current.chi2:.6g} -> {fit.chi2:.6g}, held-out rms "
                  f"{fmt(current.heldout_rms)} -> {fmt(fit.heldout_rms)} m")
        if alt is None:
            diag.tell(f"reconsider: {cand.physics} (round {i + 1}) taken out")
            rejected.append({"physics": cand.physics, "score": added.entry.score,
                             "reason": f"added in round {i + 1}, taken out once {later} were "
                                       f"in ({change})"})
            history[i] = None
            current = fit
            swapped = True
            continue
        diag.tell(f"reconsider: {alt.physics} replaces {cand.physics} (round {i + 1})")
        rejected.append({"physics": cand.physics, "score": added.entry.score,
                         "reason": f"added in round {i + 1}, replaced by {alt.physics} once "
                                   f"{later} were in ({change})"})
        entry = replace(added.entry, physics=alt.physics, score=s.score, region=alt.region,
                        rms_after=fit.rms,
                        evidence=(f"{_what(s, i)} (score S = {s.score:.4g}); "
                                  f"replaced {cand.physics} once {later} were in: chi2 "
                                  f"{current.chi2:.6g} -> {fit.chi2:.6g}, held-out rms "
                                  f"{fmt(current.heldout_rms)} -> {fmt(fit.heldout_rms)} m"
                                  + (f"; {alt.reason}" if alt.reason else "")))
        # the replaced term is the replacement's runner-up: a later reconsideration (after
        # another round, or on a refined model) tries it back and says when they tie
        back = ScoreEntry.replaced_term(cand, added.entry.score)
        history[i] = Added(entry, alt, [(back, cand)], alt.zero_values(current.experiment))
        current = fit
        swapped = True
    history[:] = [h for h in history if h is not None]
    if swapped:
        # every term's values and deviations from the final fit: the later terms were
        # refitted beside the replacement
        for h in history:
            values, std = term_values(current, h.candidate.parameters)
            h.entry = replace(h.entry, parameters=values, std=std)
    return current
