"""The numerics check's typed records (petsoft.diagnosis.numerics_records): their report forms.

report.json's ``numerics`` is :meth:`NumericsFindings.as_report`, whose keys formats.md section
3 documents; summary.json's ``numerics`` (and :attr:`DiagnoseResult.numerics`) is
:meth:`NumericsOutcome.as_report`, the rounds' and options' dicts the checks wrote before they
had records: their keys, in their order, are pinned here as a diagnosis wrote them (the
tests' cantilever with a step error under a missing gravity, issue 38).
"""

import dataclasses
import json
import re
from pathlib import Path

import pytest
from _numerics_records import linearised, numerics_round, refitted

import petsoft
from petsoft.diagnosis.numerics_records import (
    FailedOption,
    FinalChange,
    FinalCheck,
    NumericsFindings,
    NumericsOutcome,
)

#: An option's keys up to ``how``, both kinds.
CHANGES = ["chi2", "chi2_per_dof", "gain", "matters", "change_rms", "change_over_noise",
           "change_same_parameters", "change_same_parameters_over_noise", "how"]
ESTIMATES = ["error_estimate", "remaining_estimate"]


def _documented_numerics() -> dict:
    """The ``numerics`` of formats.md's report.json example."""
    doc = (Path(petsoft.__file__).parent / "formats.md").read_text()
    (example,) = [json.loads(b) for b in re.findall(r"```json\n(.*?)```", doc, flags=re.S)
                  if '"petsoft-diagnosis"' in b]
    return example["numerics"]


def _findings(mesh=None) -> NumericsFindings:
    return NumericsFindings(findings=["The simulation changes by 0.12x the noise ..."],
                            recommendation="Your mesh (648 tets) is fine for this recording.",
                            summary=["Mesh: ... fine for this recording."], adopted=[],
                            unchecked={"P2": "over the limit"}, mesh=mesh)


def test_report_numerics_has_the_keys_formats_md_documents():
    documented = _documented_numerics()
    out = _findings(mesh={"tets": 648, "tets_final": 648}).as_report()
    assert set(out) == set(documented)
    assert set(out["mesh"]) == set(documented["mesh"])
    assert list(out) == ["findings", "recommendation", "mesh", "summary", "adopted"]
    # a model without tets has no ``mesh``; ``unchecked`` is a ``skipped`` entry, not here
    assert list(_findings().as_report()) == ["findings", "recommendation", "summary",
                                             "adopted"]


def test_summary_numerics_keeps_the_findings_keys_in_their_order():
    out = _findings(mesh={"tets": 36, "tets_final": 36}).as_summary()
    assert list(out) == ["findings", "recommendation", "summary", "adopted", "unchecked",
                         "mesh"]
    assert out["unchecked"] == {"P2": "over the limit"}


def test_a_refitted_option_reports_every_field_in_order():
    o = refitted(gain=12.0, deferred=7.5, same_parameters_from="step/2", remaining_bound=1e-6)
    assert list(o.as_report()) == CHANGES + ["parameters", "refit"] + ESTIMATES + [
        "deferred", "same_parameters_from", "remaining_bound"]
    # a key appears only once the round set it
    assert list(refitted().as_report()) == CHANGES + ["parameters", "refit"] + ESTIMATES
    assert refitted(remaining_bound=0.0).as_report()["remaining_bound"] == 0.0


def test_a_linearised_option_reports_every_field_in_order():
    o = linearised(screened=True, deferred=4.0, measured_only=True)
    assert list(o.as_report()) == CHANGES + ["refit", "parameters"] + ESTIMATES + [
        "screened", "deferred", "measured_only"]
    assert o.as_report()["screened"] is True and o.as_report()["measured_only"] is True
    assert list(linearised().as_report()) == CHANGES + ["refit", "parameters"] + ESTIMATES


def test_a_failed_option_is_its_error():
    assert FailedOption("the run failed").as_report() == {"error": "the run failed"}
    assert FailedOption("x").failed and not refitted().failed and not linearised().failed


def test_a_round_reports_as_the_checks_wrote_it():
    options = {"step/2": linearised(screened=True), "P2": refitted(),
               "mesh x2": FailedOption("the refined simulation failed")}
    r = numerics_round(options, tets=36, not_tried={"mesh x2": "P2 instead"}, adopted="P2",
                       remaining_counted="over the limit", after_additions=1, why="first",
                       final_check=True)
    out = r.as_report()
    assert list(out) == ["chi2", "dof", "step", "options", "parameters", "tets", "not_tried",
                         "adopted", "remaining_counted", "after_additions", "why",
                         "final_check"]
    assert out["options"] == {label: o.as_report() for label, o in options.items()}
    assert out["final_check"] is True
    assert list(numerics_round({}).as_report()) == ["chi2", "dof", "step", "options",
                                                    "parameters"]
    # a round of measurements only: its tets and flag before its parameters
    measured = numerics_round({}, tets=1536, measured_only=True, after_additions=0, why="w")
    assert list(measured.as_report()) == ["chi2", "dof", "step", "options", "tets",
                                          "measured_only", "parameters", "after_additions",
                                          "why"]
    # a list of refinements not tried that the measurements emptied stays, empty
    assert numerics_round({}, not_tried={}).as_report()["not_tried"] == {}


def test_the_final_check_and_the_outcome_report_as_summary_json_has_them():
    change = FinalChange(rms=1e-4, change=2e-5, change_over_noise=0.4, how="h",
                         resolved=True)
    assert list(change.as_report()) == ["rms", "change", "change_over_noise", "how",
                                        "resolved"]
    estimated = dataclasses.replace(change, rms=None, estimated=True)
    assert estimated.as_report()["estimated"] is True and estimated.as_report()["rms"] is None
    final = FinalCheck(base_rms_all=1e-4, changes={"step/2": estimated,
                                                   "mesh x2": "not done: over the limit"})
    assert final.as_report() == {"base_rms_all": 1e-4, "step/2": estimated.as_report(),
                                 "mesh x2": "not done: over the limit"}
    assert final.made() == {"step/2": estimated}
    rounds = [numerics_round({"P2": refitted()}, adopted="P2")]
    outcome = NumericsOutcome(final=final, rounds=rounds, model_error={"P2": 1e-6},
                              sigma_verdict=5e-5, findings=_findings())
    assert list(outcome.as_report()) == ["base_rms_all", "step/2", "mesh x2", "refinements",
                                         "model_error", "sigma_verdict", "findings",
                                         "recommendation", "summary", "adopted", "unchecked"]
    assert outcome.as_report()["refinements"] == [rounds[0].as_report()]
    # no final check, no rounds, nothing counted, --no-numerics: nothing at all
    assert NumericsOutcome(None, [], {}, 5e-5, None).as_report() == {}


@pytest.mark.parametrize("record", [refitted(), linearised(), FailedOption("x"),
                                    numerics_round({}), _findings(),
                                    FinalChange(None, 0.0, 0.0, "h", True)])
def test_the_records_are_frozen(record):
    """A round's code makes a changed copy (dataclasses.replace) where it once set a key."""
    name = dataclasses.fields(record)[0].name
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(record, name, None)
