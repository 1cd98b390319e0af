"""Calibrated and diagnosed experiments stay the user's file: comments, order and layout kept,
only the calibrated values and the added sections changed (petsoft.experiment.writer)."""

from __future__ import annotations

import difflib

from petsoft.experiment import load_experiment, with_parameters
from petsoft.experiment.writer import write_experiment_update

USER = """# my soft bar, measured on 2026-11-20
[mesh]
box = { size = [0.3, 0.04, 0.04], cells = [6, 1, 1] }   # coarse on purpose

[material]
model = "linear"
youngs_modulus = 2.0e6      # from the datasheet
poisson_ratio = 0.3
density = 1000.0

# clamped at the wall
[[boundary]]
kind = "fixed"
where = "x < 1e-9"

[time]
end = 0.1
step = 0.002
integrator = "alpha"

[calibrate]
"material.youngs_modulus" = [1.0e5, 1.0e8]
"""


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def test_a_diagnosed_experiment_differs_from_the_users_only_where_it_changed(tmp_path):
    (tmp_path / "user").mkdir()
    source = tmp_path / "user" / "bar.toml"
    source.write_text(USER)
    original = load_experiment(source)
    # a calibrated E, and two physics terms the user's file does not have
    updated = with_parameters(original, {"material.youngs_modulus": 1.8e6, "damping.mass": 0.5,
                                         "viscoelastic.ratio": 0.2,
                                         "viscoelastic.relaxation_time": 0.01})
    out = tmp_path / "out" / "diagnosed.toml"
    out.parent.mkdir()
    assert write_experiment_update(original, updated, out) == "edited"
    text = out.read_text()
    back, want = load_experiment(out).to_dict(), updated.to_dict()
    # the default output directory is "out" beside each file
    assert back["output"].pop("directory") == str(out.parent / "out")
    want["output"].pop("directory")
    assert back == want
    diff = [d for d in difflib.ndiff(_lines(USER), _lines(text)) if d[:1] in "+-"]
    removed = [d[2:] for d in diff if d.startswith("-")]
    added = [d[2:].strip() for d in diff if d.startswith("+")]
    assert removed == ["youngs_modulus = 2.0e6      # from the datasheet"]
    assert added[0].startswith("youngs_modulus = 18") and "# from the datasheet" in added[0]
    assert set(added[1:]) == {"[damping]", "mass = 0.5", "[viscoelastic]", "ratio = 0.2",
                              "relaxation_time = 0.01"}
    for comment in ("# my soft bar, measured on 2026-11-20", "# coarse on purpose",
                    "# clamped at the wall"):
        assert comment in text


def test_the_spelled_out_form_on_request_and_for_an_experiment_without_a_file(tmp_path):
    source = tmp_path / "bar.toml"
    source.write_text(USER)
    original = load_experiment(source)
    updated = with_parameters(original, {"material.youngs_modulus": 1.8e6})
    out = tmp_path / "calibrated.toml"
    assert write_experiment_update(original, updated, out, spelled_out=True) == "spelled out"
    assert out.read_text().startswith("# petsoft experiment")
    assert "# from the datasheet" not in out.read_text()
    assert load_experiment(out).to_dict() == updated.to_dict()
