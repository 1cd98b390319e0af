"""The measures of a random draw of diagnosed cases (issue 37): rates, intervals, outcomes.

Pure functions of report.json (petsoft/formats.md section 3) and truth.json (generate.py
``--random``) dicts, used by rates.py and tested by tests/test_rates_measures.py:

- :func:`wilson`, the 95 % Wilson score interval of a rate k/n;
- :func:`seed_from_commit`, the test draw's seed from the hash of the commit that froze the rules;
- :func:`classify`, one case's outcome: the set of terms named, whether it equals the concealed
  set, whether the report names a tie (``ambiguous``);
- :func:`confusion`, the concealed-term x named-term counts;
- :func:`log_bins` and :func:`power_curve`, the detection rate against the effect size in units
  of the noise.

Off-vocabulary effects are named in truth.json with the prefix :data:`OFFVOCAB` (e.g.
``offvocab.hysteretic``): no vocabulary term is their exact name, so they are scored apart
(:func:`offvocab_row`), never in the exact-name rate.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np

from petsoft.diagnosis.report import PHYSICS
from petsoft.diagnosis.story import ties

#: truth.json's prefix of an effect outside the vocabulary
OFFVOCAB = "offvocab."
#: the two-sided 95 % point of the standard normal (scipy.stats.norm.ppf(0.975))
Z95 = 1.959963984540054
#: confusion-matrix columns besides the vocabulary's terms
NONE, AMBIGUOUS, NO_REPORT = "none", "ambiguous", "no report"


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a binomial rate with ``k`` successes in ``n`` trials.

    (p + z^2/2n -+ z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n), p = k/n: unlike p -+ z sqrt(p(1-p)/n)
    it keeps inside [0, 1] and does not shrink to a point at k = 0 or k = n, which is where
    a false-add rate on a few controls sits.

    Returns
    -------
    (lo, hi) : tuple of float
        (0, 1) when ``n`` is 0 (nothing measured).
    """
    if n < 0 or k < 0 or k > n:
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    if n == 0:
        return 0.0, 1.0
    p = k / n
    centre = p + z * z / (2 * n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    scale = 1 + z * z / n
    # exact ends at k = 0 and k = n (the formula gives them up to rounding)
    lo = 0.0 if k == 0 else (centre - half) / scale
    hi = 1.0 if k == n else (centre + half) / scale
    return lo, hi


def seed_from_commit(sha: str) -> int:
    """The test draw's seed: the first 8 hex digits of the rules' commit, modulo 2^31.

    Chosen after the commit exists, so the rules cannot have been tuned on the draw it makes.
    """
    if len(sha) < 8 or any(c not in "0123456789abcdefABCDEF" for c in sha):
        raise ValueError(f"not a commit hash: {sha!r}")
    return int(sha[:8], 16) % 2 ** 31


def is_offvocab(term: str) -> bool:
    """An effect no term of diagnose's vocabulary names: prefixed :data:`OFFVOCAB`, or any name
    outside the vocabulary (random_draw.py's ``inclusion.slab``, ``viscoelastic.two_branch``)."""
    return term.startswith(OFFVOCAB) or term not in PHYSICS


def named(report: Mapping) -> list[str]:
    """The terms a report added (formats.md section 3 ``added``), in the order added."""
    return [a["physics"] for a in report["added"]]


def classify(concealed: Iterable[str], report: Mapping | None) -> dict:
    """One case's outcome.

    Parameters
    ----------
    concealed : iterable of str
        truth.json's ``concealed`` (empty for a control).
    report : mapping or None
        The case's report.json; None when diagnose wrote none (timeout, failure).

    Returns
    -------
    dict
        ``named`` (sorted), ``exact`` (the named set equals the concealed set and no tie is
        named: a tie is not a win), ``ambiguous`` (the report names a tie on an added term:
        ``{term: [terms it ties with]}``, empty when none), ``found`` (concealed terms named),
        ``extra`` (named terms not concealed), ``outcome``: ``no report``, ``ambiguous``,
        ``exact``, ``missed`` (nothing named while something was concealed), ``false add``
        (something named on a control), ``partial`` (some of the concealed terms named and
        nothing else) or ``wrong`` (any other mismatch).
    """
    concealed = set(concealed)
    if report is None:
        return {"named": [], "exact": False, "ambiguous": {}, "found": [], "extra": [],
                "outcome": NO_REPORT}
    got = set(named(report))
    tied = ties(report)
    exact = got == concealed and not tied
    if tied:
        outcome = AMBIGUOUS
    elif exact:
        outcome = "exact"
    elif not concealed:
        outcome = "false add"
    elif not got:
        outcome = "missed"
    elif got < concealed:
        outcome = "partial"
    else:
        outcome = "wrong"
    return {"named": sorted(got), "exact": exact, "ambiguous": tied,
            "found": sorted(got & concealed), "extra": sorted(got - concealed),
            "outcome": outcome}


def confusion(cases: Iterable[tuple[Iterable[str], Mapping | None]]) -> dict[str, dict[str, int]]:
    """Concealed term x named term counts over ``cases`` ((concealed, report) pairs).

    Each concealed term of a case (``none`` for a control) is a row; the case adds one to that
    row's column ``ambiguous`` when its report names a tie, ``no report`` when there is none,
    else one to each named term that is not one of the case's *other* concealed terms (the term
    itself when named, and any extra), or to ``none`` when that leaves nothing. So a single
    effect found alone counts once on the diagonal; a two-term case found exactly counts once on
    each of its two diagonal cells; a term taken for another counts in that other's column.

    Returns
    -------
    dict
        ``{row: {column: count}}``, only nonzero cells.
    """
    out: dict[str, dict[str, int]] = {}
    for concealed, report in cases:
        concealed = list(concealed)
        c = classify(concealed, report)
        for row in concealed or [NONE]:
            cells = out.setdefault(row, {})
            if c["outcome"] in (NO_REPORT, AMBIGUOUS):
                cols = [c["outcome"]]
            else:
                cols = [n for n in c["named"] if n == row or n not in concealed] or [NONE]
            for col in cols:
                cells[col] = cells.get(col, 0) + 1
    return out


def log_bins(values: Iterable[float], per_decade: int = 2) -> np.ndarray:
    """Edges of logarithmic bins covering ``values`` (positive), ``per_decade`` to a decade,
    on the grid 10^(j / per_decade) (so draws of one protocol share their edges)."""
    v = np.asarray(list(values), dtype=float)
    if v.size == 0:
        raise ValueError("no values to bin")
    if not np.all(np.isfinite(v)) or np.any(v <= 0):
        raise ValueError(f"effect sizes must be finite and positive, got {v[~(v > 0)]}")
    lo = math.floor(np.log10(v.min()) * per_decade)
    hi = math.ceil(np.log10(v.max()) * per_decade)
    if hi == lo:
        hi += 1
    return 10.0 ** (np.arange(lo, hi + 1) / per_decade)


def power_curve(sizes: Iterable[float], detected: Iterable[bool],
                edges: np.ndarray) -> list[dict]:
    """Detection rate per bin of effect size: ``{lo, hi, centre (geometric), n, k, rate,
    ci}`` for each bin holding at least one case (bins are [lo, hi), the last closed)."""
    s = np.asarray(list(sizes), dtype=float)
    d = np.asarray(list(detected), dtype=bool)
    if s.shape != d.shape:
        raise ValueError("sizes and detected differ in length")
    idx = np.clip(np.searchsorted(edges, s, side="right") - 1, 0, len(edges) - 2)
    outside = (s < edges[0]) | (s > edges[-1])
    if outside.any():
        raise ValueError(f"effect sizes {s[outside]} outside the bins [{edges[0]}, {edges[-1]}]")
    rows = []
    for b in range(len(edges) - 1):
        here = idx == b
        n, k = int(here.sum()), int(d[here].sum())
        if n:
            rows.append({"lo": float(edges[b]), "hi": float(edges[b + 1]),
                         "centre": float(np.sqrt(edges[b] * edges[b + 1])), "n": n, "k": k,
                         "rate": k / n, "ci": wilson(k, n)})
    return rows


def effect_sizes(truth: Mapping) -> dict[str, float]:
    """Each concealed term's effect size in units of the noise (truth.json
    ``effect_over_noise``: a mapping term -> size, or one number). One number for two or more
    terms is their combined effect, no term's own: no term gets a size then (the case stays
    out of the power curves)."""
    concealed = truth["concealed"]
    eff = truth.get("effect_over_noise")
    if eff is None and isinstance(truth.get("effect_size_over_noise"), Mapping):
        # random_cases.py's: the rms over markers, frames and components of (truth - the
        # effect-free run) / noise, of all the concealed terms together
        eff = truth["effect_size_over_noise"].get("rms")
    if not concealed or eff is None:
        return {}
    if isinstance(eff, Mapping):
        return {t: float(eff[t]) for t in concealed if t in eff}
    return {concealed[0]: float(eff)} if len(concealed) == 1 else {}


def heldout_over_noise(report: Mapping) -> tuple[float | None, float | None]:
    """Held-out rms / noise of the model as given and of the final model (None if absent)."""
    val = report["fit"].get("validation") or {}
    sigma = report["noise_std"]
    return tuple(val[k] / sigma if val.get(k) is not None else None
                 for k in ("base_rms", "final_rms"))


def noticed(report: Mapping | None) -> bool:
    """Whether a report blames physics for a mismatch (what an off-vocabulary effect can get:
    no term names it): its ``cause`` is ``physics``, ``both`` or ``unexplained``; a mismatch a
    refinement of the numerics removed (``numerics``) is not. Reports without ``cause`` (before
    issue 39): the final verdict is missing-physics or a term was added."""
    if report is None:
        return False
    if "cause" in report:
        return report["cause"] in ("physics", "both", "unexplained")
    return (report.get("final_verdict") or report["verdict"]) == "missing-physics" or bool(
        report["added"])


def offvocab_row(report: Mapping | None) -> dict:
    """What a report said about an off-vocabulary effect: ``named``, ``short_of_noise`` (the
    final model's verdict is missing-physics, or the cause unexplained: the report says the fit
    stays short of the noise), ``consistent`` (the final verdict is consistent),
    ``heldout_base``/``heldout_final`` (/ noise), ``improved`` (final < base), ``violates``
    (called consistent with a held-out rms over 1.5x the noise: issue 37's target; None
    without a held-out window)."""
    if report is None:
        return {"named": [], "short_of_noise": None, "consistent": None,
                "heldout_base": None, "heldout_final": None, "improved": None,
                "violates": None}
    final = report.get("final_verdict") or report["verdict"]
    base, after = heldout_over_noise(report)
    consistent = final == "consistent"
    return {"named": named(report),
            "short_of_noise": final == "missing-physics" or report.get("cause") == "unexplained",
            "consistent": consistent, "heldout_base": base, "heldout_final": after,
            "improved": None if base is None or after is None else after < base,
            "violates": None if after is None else consistent and after > 1.5}
