"""Choosing among fitted candidates (petsoft.diagnosis.selection): the held-out noise level,
the held-out test, fitting the simplest first, the score share worth fitting. The fits are
built directly (chi2, held-out rms): the choice reads nothing else. The rules' rates on draws
from their null and alternative distributions (the likelihood ratio's false alarms and power,
the fewest parameters, the tie band) are in tests/test_decision_rules.py."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from petsoft.diagnosis.candidates import Candidate
from petsoft.diagnosis.context import Fit
from petsoft.diagnosis.selection import (
    MIN_SCORE_SHARE,
    choose,
    fit_simplest_first,
    heldout_noise_level,
    worth_fitting,
)

SIGMA = 1e-4


def context(frames=201, markers=16, held_from=141):
    """What choose reads of a Diagnosis: the data's shape and windows, noise, alpha."""
    data = np.zeros((frames, markers, 3))
    data[::10, 0, :] = np.nan                       # a few dropouts
    ident = np.arange(frames) < held_from
    lines = []
    return SimpleNamespace(data=data, ident=ident, held=~ident, sigma=SIGMA, alpha=0.01,
                           tell=lines.append, lines=lines)


def fit(chi2, heldout, names=("material.youngs_modulus",)):
    names = list(names)
    return Fit(experiment=None, names=names, values=np.ones(len(names)),
               std=np.full(len(names), 0.1), chi2=chi2, rms=SIGMA, heldout_rms=heldout,
               sim=np.zeros(1))


def contender(physics, parameters, chi2, heldout):
    c = Candidate(physics=physics, parameters=list(parameters),
                  bounds=[(0.0, 1.0)] * len(parameters), region=None, reason="")
    s = {"physics": physics, "score": 1e5, "p_value": 0.0,
         "fit": fit(chi2, heldout, ["material.youngs_modulus", *parameters])}
    return s, c


def test_noise_level_is_the_chi2_bound_on_the_held_out_samples():
    diag = context()
    n = int(np.isfinite(diag.data[diag.held]).sum())
    assert n == 60 * 48 - 6 * 3                     # 6 held-out frames lose marker 0
    expected = SIGMA * np.sqrt(stats.chi2.ppf(0.99, n) / n)
    assert heldout_noise_level(diag) == pytest.approx(expected, rel=1e-12)
    assert 1.02 < heldout_noise_level(diag) / SIGMA < 1.04
    # pure noise passes it at about the rate alpha says
    rng = np.random.default_rng(1)
    rms = np.sqrt(np.mean(rng.normal(0, SIGMA, (2000, n)) ** 2, axis=1))
    assert 0.003 < np.mean(rms > heldout_noise_level(diag)) < 0.02
    empty = context(held_from=201)
    assert heldout_noise_level(empty) == 0.0


def test_a_candidate_whose_held_out_rms_does_not_improve_is_rejected():
    diag = context()
    base = fit(2.4e5, 1.0e-4)
    contenders = [contender("damping.mass", ["damping.mass"], 6400.0, 1.05e-4)]
    choice = choose(diag, base, contenders)
    assert choice.accepted is None
    assert "held-out rms did not improve" in choice.rejected[0]["reason"]


def test_terms_with_more_parameters_are_not_fitted_once_a_simpler_one_predicts_to_the_noise():
    """fit_simplest_first: the batch of one-parameter candidates is fitted first; the
    two-parameter one is fitted only when none of those passes and predicts to the noise."""
    def run(mass_over_level):
        diag = context()
        level = heldout_noise_level(diag)
        n = int(np.isfinite(diag.data[diag.ident]).sum())     # chi2 of a fit to the noise
        e = "material.youngs_modulus"
        # made-up fits: the flexible term fits best, the drag predicts worse than the noise
        prepared = {"damping.mass": fit(n + 10.0, mass_over_level * level, [e, "damping.mass"]),
                    "drag.linear": fit(n + 30.0, 1.05 * level, [e, "drag.linear"]),
                    "material.viscoelastic": fit(n - 100.0, 0.97 * level, [
                        e, "viscoelastic.ratio", "viscoelastic.relaxation_time"])}
        batches = []

        def fit_candidates(batch, current, rivals=None):
            batches.append([c.physics for _, c in batch])
            for s, c in batch:
                s["fit"] = prepared[c.physics]
        diag.fit_candidates = fit_candidates
        contenders = [contender("material.viscoelastic",
                                ["viscoelastic.ratio", "viscoelastic.relaxation_time"], 0, 0),
                      contender("damping.mass", ["damping.mass"], 0, 0),
                      contender("drag.linear", ["drag.linear"], 0, 0)]
        for s, _ in contenders:
            del s["fit"]
        base = fit(100.0 * n, 8.0 * level)
        fit_simplest_first(diag, base, contenders)
        return batches, choose(diag, base, contenders), diag.lines

    # the mass damping predicts the held-out data within the noise level
    batches, choice, lines = run(0.99)
    assert batches == [["damping.mass", "drag.linear"]]
    assert choice.accepted[0]["physics"] == "damping.mass"
    skipped = next(r for r in choice.rejected if r["physics"] == "material.viscoelastic")
    assert skipped["reason"].startswith("not fitted: damping.mass (1 parameter) already "
                                        "predicts the held-out data to the noise")
    assert any(line.startswith("not fitting material.viscoelastic") for line in lines)
    # the simpler ones leave 10 % over the noise level: the flexible term is fitted, and wins
    batches, choice, _ = run(1.10)
    assert batches == [["damping.mass", "drag.linear"], ["material.viscoelastic"]]
    assert choice.accepted[0]["physics"] == "material.viscoelastic"


def test_candidates_scoring_below_a_percent_of_the_best_are_not_fitted():
    """A score below MIN_SCORE_SHARE of the round's best is not fitted, one just above it is
    (made-up scores on either side of the share)."""
    scored = [contender("gravity", ["gravity.acceleration.x", "gravity.acceleration.y",
                                    "gravity.acceleration.z"], 0, 0),
              contender("contact.plane", ["collider.0.offset"], 0, 0),
              contender("mass.added", ["mass.added"], 0, 0),
              contender("material.heterogeneous", ["material.youngs_modulus#1"], 0, 0)]
    best = 4.0e6
    scores = [best, 0.97 * MIN_SCORE_SHARE * best, 0.5 * MIN_SCORE_SHARE * best,
              1.03 * MIN_SCORE_SHARE * best]
    for (s, _), score in zip(scored, scores, strict=True):
        s["score"] = score
    keep, rejected = worth_fitting(scored)
    assert [c.physics for _, c in keep] == ["gravity", "material.heterogeneous"]
    assert [r["physics"] for r in rejected] == ["contact.plane", "mass.added"]
    assert rejected[0]["reason"].startswith(
        f"not fitted: its score S = {scores[1]:.4g} is below {MIN_SCORE_SHARE:.0%} of the "
        f"round's best ({best:.4g})")
    assert worth_fitting([]) == ([], [])
