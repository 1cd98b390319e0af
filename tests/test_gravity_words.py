"""An added gravity term said as a vector (report.json ``added[i].gravity``, report.md): a turned
gravity's tangents are what diagnose fits, but a reader wants the vector and the angle; a fitted
acceleration's size says whether it is the Earth's.

The angle is checked against the tilt map's own geometry (the tangents a, b turn the stated
direction by atan(hypot(a, b)), tests/test_gravity_tilt.py), not against the code's formula.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_diagnosis_analysis import example_report

from petsoft.diagnosis import report
from petsoft.diagnosis.outputs import gravity_words
from petsoft.diagnosis.story import Story, gravity_said
from petsoft.experiment.gravity_tilt import tilted
from petsoft.experiment.spec import GravitySpec


def _turned(a=0.3, b=-0.1, stated=(0.0, 0.0, -9.81)):
    return GravitySpec(acceleration=tuple(tilted(stated, a, b)), tilt_a=a, tilt_b=b,
                       stated=stated)


def test_a_turned_gravity_is_said_as_its_vector_and_angle():
    g = gravity_words(_turned(0.3, -0.1))
    assert g["turned_degrees"] == pytest.approx(math.degrees(math.atan(math.hypot(0.3, 0.1))),
                                                rel=1e-12)
    assert g["stated"] == [0.0, 0.0, -9.81]
    assert np.linalg.norm(g["acceleration"]) == pytest.approx(9.81, rel=1e-12)
    # not the stated vector: turned
    assert not np.allclose(g["acceleration"], g["stated"])
    words = gravity_said(g)
    assert words.startswith("gravity turned by 17.5 degrees: (")
    assert "stated (0, 0, -9.81)" in words


def test_an_untilted_gravity_says_its_size():
    g = gravity_words(GravitySpec(acceleration=(10.85, 0.0, -9.81)))
    assert g == {"acceleration": [10.85, 0.0, -9.81]}
    assert gravity_said(g) == "(10.8, 0, -9.81) m/s^2, |g| = 14.6 m/s^2"


def _with_gravity(entry):
    rep = example_report()
    rep["added"] = [{"physics": "gravity.direction",
                     "parameters": {"gravity.tilt_a": 0.3, "gravity.tilt_b": -0.1},
                     "std": {"gravity.tilt_a": 0.01, "gravity.tilt_b": 0.01}, "score": 300.0,
                     "rms_after": 4.2e-4, "evidence": "a common offset along x",
                     "gravity": entry}]
    rep["parameters"].update({"gravity.tilt_a": 0.3, "gravity.tilt_b": -0.1})
    return rep


def test_the_report_carries_it_and_the_story_says_it():
    rep = _with_gravity(gravity_words(_turned()))
    report.validate_report(rep)
    story = Story(rep)
    assert any("gravity.tilt_b = -0.1" in v and "gravity turned by 17.5 degrees" in v
               for v in story.added_values), story.added_values


@pytest.mark.parametrize("entry, message", [
    ({"acceleration": [1.0, 2.0]}, r"acceleration.*\[x, y, z\]"),
    ({"acceleration": [0.0, 0.0, -9.81], "stated": [0.0, 0.0, -9.81]}, "come together"),
    ({"acceleration": [0.0, 0.0, -9.81], "stated": [0.0, 0.0, -9.81],
      "turned_degrees": 200.0}, r"\[0, 180\]"),
    ({"acceleration": [0.0, float("nan"), -9.81]}, "finite"),
    ({"acceleration": [0.0, 0.0, -9.81], "size": 9.81}, "unknown size"),
])
def test_a_malformed_gravity_entry_is_refused(entry, message):
    with pytest.raises(report.ReportError, match=message):
        report.validate_report(_with_gravity(entry))
