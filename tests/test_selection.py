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
from petsoft.diagnosis.records import ScoreEntry
from petsoft.diagnosis.selection import (
    MIN_SCORE_SHARE,
    choose,
    fit_simplest_first,
    heldout_noise_level,
    judge,
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
    s = ScoreEntry(physics=physics, parameters=list(parameters), region=None, kind="score",
                   score=1e5, dof=len(parameters), p_value=0.0, log10_p=-np.inf,
                   fit=fit(chi2, heldout, ["material.youngs_modulus", *parameters]))
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


@pytest.mark.serial_only          # numpy draws only: a second rank would repeat them
def test_the_held_out_test_passes_a_term_at_the_rate_its_prediction_law_gives():
    """judge's second test on draws: a one-parameter term g is fitted by least squares on the
    identification window, where the effect a g is far above the noise (its likelihood ratio
    ~400: the first test always passes), and predicts the held-out window with it. Z1, Z2
    standard normals (the noise along g on the held-out and on the identification window), A =
    a |g_h| / sigma and rho = |g_h| / |g_i|, the fitted prediction is (A + rho Z2) sigma along
    g_h. When the held-out data hold the effect too, the held-out rms improves iff
    Z1 > (rho Z2 - A) / 2: at the rate Phi(A / 2 / sqrt(1 + rho^2 / 4)); when they hold only
    noise (the term fits the identification window but extrapolates wrongly), iff
    Z1 > (A + rho Z2) / 2: at the rate Phi(-A / 2 / sqrt(1 + rho^2 / 4)). Rates within the
    binomial interval of those, and a rejected term says why."""
    diag = context()
    seen = np.isfinite(diag.data)
    ident, held = seen & diag.ident[:, None, None], seen & diag.held[:, None, None]
    n_i, n_h = int(ident.sum()), int(held.sum())
    big, A = 20.0, 2.0                          # a |g_i| / sigma and a |g_h| / sigma
    a = big * SIGMA / np.sqrt(n_i)              # g = 1 on the identification window ...
    g_held = A * SIGMA / (a * np.sqrt(n_h))     # ... and g_held on the held-out one
    rho = g_held * np.sqrt(n_h) / np.sqrt(n_i)
    draws = 1000
    rng = np.random.default_rng(11)
    c = Candidate(physics="damping.mass", parameters=["damping.mass"], bounds=[(0.0, 1.0)],
                  region=None, reason="")
    names = ["material.youngs_modulus", "damping.mass"]
    rate = stats.norm.cdf(A / 2.0 / np.sqrt(1.0 + rho ** 2 / 4.0))
    for continues, expected in ((True, rate), (False, 1.0 - rate)):
        noise_i = SIGMA * rng.standard_normal((draws, n_i))
        noise_h = SIGMA * rng.standard_normal((draws, n_h))
        r_i = a + noise_i                                   # the base model's residual
        r_h = (a * g_held if continues else 0.0) + noise_h
        beta = r_i.mean(axis=1)                             # least squares along g = 1
        chi2_base = np.sum(r_i ** 2, axis=1) / SIGMA ** 2
        chi2_new = np.sum((r_i - beta[:, None]) ** 2, axis=1) / SIGMA ** 2
        held_base = np.sqrt(np.mean(r_h ** 2, axis=1))
        held_new = np.sqrt(np.mean((r_h - beta[:, None] * g_held) ** 2, axis=1))
        assert np.all(chi2_base - chi2_new > 100.0)        # the likelihood ratio passes
        added, reasons = 0, []
        for i in range(draws):
            s = ScoreEntry(physics=c.physics, parameters=c.parameters, region=None,
                           kind="score", score=1.0, dof=1, p_value=0.0, log10_p=-np.inf,
                           fit=fit(chi2_new[i], held_new[i], names))
            verdict = judge(diag, fit(chi2_base[i], held_base[i]), s, c)
            added += verdict.added
            assert verdict.added == (held_new[i] < held_base[i])
            if not verdict.added:
                reasons.append(verdict.reason)
        lo, hi = stats.binom.interval(0.999, draws, expected)
        assert lo <= added <= hi, (continues, added / draws, expected)
        assert reasons and all(r.startswith("held-out rms did not improve") for r in reasons)
    assert 0.8 < rate < 0.9                      # the two cases are told apart, not always


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
                s.fit = prepared[c.physics]
        diag.fit_candidates = fit_candidates
        contenders = [contender("material.viscoelastic",
                                ["viscoelastic.ratio", "viscoelastic.relaxation_time"], 0, 0),
                      contender("damping.mass", ["damping.mass"], 0, 0),
                      contender("drag.linear", ["drag.linear"], 0, 0)]
        for s, _ in contenders:
            s.fit = None
        base = fit(100.0 * n, 8.0 * level)
        fit_simplest_first(diag, base, contenders)
        return batches, choose(diag, base, contenders), diag.lines

    # the mass damping predicts the held-out data within the noise level
    batches, choice, lines = run(0.99)
    assert batches == [["damping.mass", "drag.linear"]]
    assert choice.accepted[0].physics == "damping.mass"
    skipped = next(r for r in choice.rejected if r["physics"] == "material.viscoelastic")
    assert skipped["reason"].startswith("not fitted: damping.mass (1 parameter) already "
                                        "predicts the held-out data to the noise")
    assert any(line.startswith("not fitting material.viscoelastic") for line in lines)
    # the simpler ones leave 10 % over the noise level: the flexible term is fitted, and wins
    batches, choice, _ = run(1.10)
    assert batches == [["damping.mass", "drag.linear"], ["material.viscoelastic"]]
    assert choice.accepted[0].physics == "material.viscoelastic"


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
        s.score = score
    keep, rejected = worth_fitting(scored)
    assert [c.physics for _, c in keep] == ["gravity", "material.heterogeneous"]
    assert [r["physics"] for r in rejected] == ["contact.plane", "mass.added"]
    assert rejected[0]["reason"].startswith(
        f"not fitted: its score S = {scores[1]:.4g} is below {MIN_SCORE_SHARE:.0%} of the "
        f"round's best ({best:.4g})")
    assert worth_fitting([]) == ([], [])
