"""The story of a diagnosis (petsoft.diagnosis.story): the verdict says what the mismatch was,
skipped checks are said, the console ends with the conclusion, and no quantity is quoted two
ways (the checker is itself checked on texts that do quote one two ways)."""

from __future__ import annotations

import copy

import pytest
from test_diagnosis_analysis import example_report

from petsoft.diagnosis import report
from petsoft.diagnosis.story import (
    Story,
    mismatch_cause,
    pm,
    quoted_conflicts,
    skipped_numerics,
    ties,
)
from petsoft.errors import ExperimentError
from petsoft.experiment.parameters import parameter_unit


def _report(**extra):
    rep = example_report()
    rep["parameters"]["damping.mass"] = 1.93
    rep["parameters_std"] = {"damping.mass": 0.05, "material.youngs_modulus": 2.1e3}
    rep.update(extra)
    report.validate_report(rep)
    return rep


def test_the_cause_names_numerics_physics_both_or_neither():
    assert mismatch_cause("missing-physics", [], ["P2"]) == "numerics"
    assert mismatch_cause("missing-physics", [{"physics": "gravity"}], []) == "physics"
    assert mismatch_cause("missing-physics", [{"physics": "gravity"}], ["step/2"]) == "both"
    assert mismatch_cause("consistent", [], []) == "none"
    assert mismatch_cause("missing-physics", [], []) == "unexplained"


def test_a_value_is_quoted_to_its_std_with_its_unit():
    assert pm(4.01151, 0.0123) == "4.012 +- 0.012"
    assert pm(2.0005e7, 1.7e3) == "2.00050e+07 +- 1.7e+03"
    assert pm(0.5, float("nan")) == "0.5"
    assert parameter_unit("damping.mass") == "1/s"
    assert parameter_unit('material."soft part".youngs_modulus') == "Pa"
    assert parameter_unit("gravity.acceleration.y") == "m/s^2"
    with pytest.raises(ExperimentError, match="unit"):
        parameter_unit("material.colour")


def test_the_verdict_box_says_a_numerics_only_mismatch_as_such():
    """The issue's control: only the 4-node elements were wrong; nothing was added."""
    rep = _report(added=[], cause="numerics", final_verdict="consistent")
    rep["parameters"].pop("damping.mass")
    rep["parameters_std"].pop("damping.mass")
    rep["numerics"] = {"findings": ["..."], "adopted": ["P2"],
                       "summary": ["Element order: part of the mismatch; 10-node tetrahedra "
                                   "was adopted; refining once more (the mesh split 1->8) "
                                   "changes the simulation by 0.4x the noise."]}
    report.validate_report(rep)
    story = Story(rep)
    box = story.verdict_box()
    assert box.startswith("**Verdict: numerics, no missing physics.**")
    assert "its discretisation (element order)" in box and "No physics was added" in box
    assert "Verdict: missing physics" not in box
    lines = story.conclusion("out")
    assert lines[0] == "verdict: numerics, no missing physics (cause: numerics)"
    assert lines[-1].startswith("report: out/report.html")


def test_skipped_numerics_are_said_with_their_risk(tmp_path):
    rep = _report(cause="physics", skipped=[skipped_numerics()])
    story = Story(rep)
    assert "Not checked: numerics" in story.verdict_box()
    assert "blamed on physics" in story.verdict_box()
    assert any(line.startswith("NOT CHECKED: numerics") for line in story.conclusion())
    md = report.write_report_md(tmp_path / "report.md", rep).read_text()
    first = md.split("\n\n")[1]                              # the verdict paragraph
    assert first.startswith("**Verdict: missing physics.**") and "--no-numerics" in first
    assert "Run again without --no-numerics" in md


def test_added_values_come_from_the_final_parameters_once(tmp_path):
    rep = _report(cause="physics")
    story = Story(rep)
    assert story.added_values == ["damping.mass = 1.930 +- 0.050 1/s"]
    assert story.recalibrated == ["material.youngs_modulus = 1.0200e+06 +- 2.1e+03 Pa"]
    md = report.write_report_md(tmp_path / "report.md", rep).read_text()
    assert md.count("damping.mass = 1.930 +- 0.050 1/s") >= 2      # box and "In short"
    assert quoted_conflicts(md) == []
    # the details are folded: the raw numbers come after <details>
    assert md.index("## In short") < md.index("<details>") < md.index("### Fit")


def test_ties_are_read_from_the_evidence():
    rep = _report()
    rep["added"][0]["evidence"] += ("; ambiguous: drag.linear predicted and fitted as well "
                                    "(held-out rms within 2 %)")
    assert ties(rep) == {"damping.mass": ["drag.linear"]}
    short = " ".join(Story(rep).in_short())
    assert "**Ambiguous:** drag.linear" in short and "record longer" in short


def test_the_checker_finds_a_quantity_quoted_two_ways():
    one = "Added: damping.mass = 3.93 +- 0.0123. Final parameters: damping.mass = 4.01151."
    assert any("damping.mass" in p for p in quoted_conflicts(one))
    same = "Added: damping.mass = 4.012 +- 0.012 1/s. Again damping.mass = 4.012 +- 0.012 1/s."
    assert quoted_conflicts(same) == []
    held = ("rms error: 0.52 mm (10x the noise) with the model as given, 0.05 mm (1x) with the "
            "final model.\nrms error: 0.52 mm (10x the noise) with the model as given, 0.07 mm "
            "(1.4x) with the final model.")
    assert any("held-out" in p for p in quoted_conflicts(held))


def test_the_checker_finds_a_fine_mesh_that_a_refinement_contradicts():
    """The sentences of the issue: the mesh said fine while refining it moves the simulation by
    40x the noise."""
    text = ("**Recommendation:** Your mesh (36 tets) is fine for this recording.\n"
            "- On the final model, the simulation changes by 40x the noise when the mesh is "
            "refined (box cells 6x1x1 -> 12x2x2: 36 -> 288 tets).")
    problems = quoted_conflicts(text)
    assert len(problems) == 1 and "mesh is said to be fine" in problems[0]
    below = text.replace("40x", "0.4x")
    assert quoted_conflicts(below) == []
    # the same in HTML
    page = ("<html><body><p>Your mesh (36 tets) is fine for this recording.</p><ul><li>"
            "Mesh: refining it (36 -&gt; 288 tets) changes the simulation by 40x the noise."
            "</li></ul></body></html>")
    assert quoted_conflicts(page)


def test_new_report_keys_are_validated():
    rep = _report(cause="physics", final_verdict="consistent", skipped=[skipped_numerics()])
    report.validate_report(rep)
    for key, value, message in (("cause", "gremlins", "'cause'"),
                                ("final_verdict", "fine", "'final_verdict'"),
                                ("skipped", [{"check": "numerics"}], r"'skipped\[0\]'"),
                                ("parameters_std", {"gravity": 1.0}, "'parameters_std'")):
        bad = copy.deepcopy(rep)
        bad[key] = value
        with pytest.raises(report.ReportError, match=message):
            report.validate_report(bad)
    # a report without the new keys (an older one) is still valid and tells its story
    old = example_report()
    report.validate_report(old)
    assert Story(old).cause == "physics"


def test_the_formats_md_example_report_is_valid_and_tells_its_story():
    import json
    import re
    from pathlib import Path

    import petsoft

    doc = (Path(petsoft.__file__).parent / "formats.md").read_text()
    block = next(b for b in re.findall(r"```json\n(.*?)```", doc, flags=re.S)
                 if '"petsoft-diagnosis"' in b)
    rep = json.loads(block)
    report.validate_report(rep)
    assert Story(rep).verdict_box().startswith("**Verdict: missing physics.**")


def test_the_console_says_where_the_time_went():
    """report.json's ``timings`` (the phase clock) end the console's conclusion before the path:
    the total and each phase that took half a second or more, in the order they ran."""
    rep = _report(timings={"base_fit": 12.4, "numerics": 95.0, "scoring": 20.2, "fits": 61.0,
                           "final": 0.2, "other": 1.0, "total": 189.8})
    lines = Story(rep).conclusion("out")
    assert lines[-2] == ("time: 190 s (base fit 12 s, numerics 95 s, scoring 20 s, "
                         "fits 61 s)")
    rep.pop("timings")
    assert not any(line.startswith("time:") for line in Story(rep).conclusion("out"))


def test_a_refinement_adopted_twice_is_missed_once():
    """The realistic control adopted 10-node elements and halved the step twice: the model
    missed its element order and its time step, each said once."""
    rep = _report(added=[], cause="numerics", final_verdict="consistent")
    rep["parameters"].pop("damping.mass")
    rep["parameters_std"].pop("damping.mass")
    rep["numerics"] = {"findings": ["..."], "adopted": ["P2", "step/2", "step/2"],
                       "summary": []}
    missed = next(line for line in Story(rep).conclusion() if line.startswith("missed:"))
    assert missed == "missed: its discretisation (element order, time step)"
