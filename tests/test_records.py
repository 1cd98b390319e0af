"""The diagnosis' typed records (petsoft.diagnosis.records): a score entry's report form.

``scores`` in diagnose's summary.json and :attr:`DiagnoseResult.scores` are
:meth:`ScoreEntry.as_report`: its keys, their order and values are a public contract; the
round's working fields (the fit, the score direction, why a fit was skipped) stay out of it.
"""

import dataclasses

import numpy as np
import pytest

from petsoft.diagnosis.candidates import Candidate
from petsoft.diagnosis.evidence import collect_evidence
from petsoft.diagnosis.records import AddedTerm, Evidence, Judgement, ScoreEntry

#: The report's keys in their order, each as the round sets it.
REPORTED = ["physics", "parameters", "region", "kind", "score", "dof", "p_value", "log10_p",
            "gradient", "note", "round", "rank", "fitted_chi2"]


def _scored(**later) -> ScoreEntry:
    return ScoreEntry(physics="damping.mass", parameters=["damping.mass"], region=None,
                      kind="score", score=812.0, dof=1, p_value=1e-12, log10_p=-12.0,
                      gradient=[-3.5], direction=np.ones(4), **later)


def test_every_reported_field_is_written_under_its_name_in_order():
    s = _scored(note="one-sided", round=2, rank=1, fitted_chi2=48.5, repeats="drag.linear",
                skipped="", fit_error="it diverged", replaced=True)
    s.fit = object()
    out = s.as_report()
    assert list(out) == REPORTED
    assert out == {"physics": "damping.mass", "parameters": ["damping.mass"], "region": None,
                   "kind": "score", "score": 812.0, "dof": 1, "p_value": 1e-12,
                   "log10_p": -12.0, "gradient": [-3.5], "note": "one-sided", "round": 2,
                   "rank": 1, "fitted_chi2": 48.5}


def test_fields_not_set_yet_are_left_out():
    """As the round's dicts had them: a key appears once its step set it (a candidate not
    fitted has no fitted_chi2; a score test that failed has a note and no gradient)."""
    s = _scored(round=1, rank=3)
    assert list(s.as_report()) == [k for k in REPORTED if k not in ("note", "fitted_chi2")]
    c = Candidate(physics="gravity", parameters=["gravity.x", "gravity.y"],
                  bounds=[(-20.0, 20.0)] * 2, region={"center": [0.0, 0.0, 0.0], "radius": 1.0})
    failed = ScoreEntry.unscored(c, "the scoring run failed")
    assert failed.as_report() == {"physics": "gravity", "parameters": ["gravity.x", "gravity.y"],
                                  "region": {"center": [0.0, 0.0, 0.0], "radius": 1.0},
                                  "kind": "score", "score": 0.0, "dof": 2, "p_value": 1.0,
                                  "log10_p": 0.0, "note": "the scoring run failed"}


def test_tried_says_whether_the_fit_was_made():
    s = _scored()
    assert not s.tried
    s.fit_error = "the forward run diverged"
    assert s.tried
    back = ScoreEntry.replaced_term(Candidate(physics="drag.linear", parameters=["drag.linear"],
                                              bounds=[(0.0, 1.0)]), 7.5)
    assert back.replaced and back.score == 7.5 and not back.tried
    assert np.isnan(back.p_value)


def test_an_entry_is_recognised_by_identity():
    """Two entries with the same numbers are two candidates' (a round searches its lists with
    ``in``), and comparing them never compares their arrays."""
    a, b = _scored(), _scored()
    assert a != b and a == a
    assert [a, b].index(b) == 1 and len({a, b}) == 2


def test_an_added_term_reports_every_field_under_its_name_in_order():
    """DiagnoseResult.added and report.json's ``added`` read AddedTerm.as_report."""
    a = AddedTerm(physics="mass.added", parameters={"material.diag_mass.density": 3000.0},
                  std={"material.diag_mass.density": 40.0}, score=900.0, rms_after=2e-5,
                  evidence="score test S = 900", region={"center": [0.2, 0.0, 0.0],
                                                         "radius": 0.03})
    assert list(a.as_report()) == ["physics", "parameters", "std", "score", "rms_after",
                                   "evidence", "region"]
    assert a.as_report() == {"physics": "mass.added",
                             "parameters": {"material.diag_mass.density": 3000.0},
                             "std": {"material.diag_mass.density": 40.0}, "score": 900.0,
                             "rms_after": 2e-5, "evidence": "score test S = 900",
                             "region": {"center": [0.2, 0.0, 0.0], "radius": 0.03}}


def test_a_judgement_adds_its_term_or_says_why_not():
    term = AddedTerm(physics="drag.linear", parameters={}, std={}, score=1.0, rms_after=1e-5,
                     evidence="")
    assert Judgement(term).added and Judgement(term).reason == ""
    no = Judgement(reason="held-out rms did not improve")
    assert not no.added and no.entry is None


#: The evidence's keys in their order, as collect_evidence's dict had them (issue 38).
EVIDENCE = ["noise_std", "noise_source", "noise_summary", "noise_test", "verdict", "fit",
            "markers", "region", "windows", "data_modes", "sim_modes", "modes",
            "residual_modes", "frequencies_hz", "envelope", "friction_terms",
            "sim_friction_terms", "notes", "field", "mismatch", "offset", "offset_z",
            "axis_rms", "offset_halves", "duration"]


def test_the_evidence_reports_every_field_under_its_name_in_order():
    """report.md's writer and the figures read Evidence.as_report(): the same objects under
    the names collect_evidence's dict gave them; a verdict changed is a new record."""
    rng = np.random.default_rng(9)
    t = np.linspace(0.0, 2.0, 200)
    ref = rng.uniform(0.0, 0.1, (4, 3))
    sim = ref[None] + 0.01 * np.sin(2 * np.pi * t)[:, None, None]
    ev = collect_evidence(sim + rng.normal(0.0, 1e-4, sim.shape), sim, t, ref,
                          ["a", "b", "c", "d"], sigma=1e-4)
    assert isinstance(ev, Evidence)
    out = ev.as_report()
    assert list(out) == EVIDENCE
    assert all(out[k] is getattr(ev, k) for k in EVIDENCE)
    with pytest.raises(dataclasses.FrozenInstanceError):
        ev.verdict = "consistent"
    changed = dataclasses.replace(ev, verdict="missing-physics")
    assert changed.verdict == "missing-physics" and ev.as_report()["verdict"] == ev.verdict
