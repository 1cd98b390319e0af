"""The round's shortlist of candidates to fit (petsoft.diagnosis.selection.shortlist).

The max_tries best scores are fitted, except that the last of them whose first-order change
repeats a better one's (score directions with |cos| >= 0.95) gives its place to the best
candidate outside whose change is new and scores at least half the best: on the independent
L-bracket with an added mass four dissipation laws filled the shortlist and the added mass,
fifth by 0.5 %, was not fitted. And the direction the score test returns is the candidate's
column with the base columns projected out, of unit norm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from petsoft.diagnosis.records import ScoreEntry
from petsoft.diagnosis.score import score_test
from petsoft.diagnosis.selection import shortlist


@dataclass
class _Term:
    physics: str


def _entry(physics: str, score: float, direction) -> tuple[ScoreEntry, _Term]:
    d = None if direction is None else np.asarray(direction, np.float32)
    if d is not None:
        d = d / np.linalg.norm(d)
    return ScoreEntry(physics=physics, parameters=[physics], region=None, kind="score",
                      score=score, dof=1, p_value=0.0, log10_p=-np.inf,
                      direction=d), _Term(physics)


def _ranked(extra_score: float, repeated: bool = True):
    """Four dissipation-like candidates, along nearly one direction (|cos| > 0.99) when
    ``repeated``, else along four orthogonal ones; then a fifth direction scoring
    ``extra_score``, and gravity (three parameters: no direction)."""
    e = np.eye(6)
    laws = [_entry(name, s, (e[0] + 0.05 * k * (e[1] - e[2])) if repeated else e[k])
            for k, (name, s) in enumerate([("friction.dry", 8.41e4), ("drag.quadratic", 7.73e4),
                                            ("damping.mass", 7.60e4), ("drag.linear", 7.12e4)])]
    return laws + [_entry("mass.added", extra_score, e[4] + e[5]), _entry("gravity", 1e4, None)]


def test_a_repeated_change_gives_its_place_to_a_new_one():
    picked, line, left_out = shortlist(_ranked(7.10e4), 4)
    names = [c.physics for _, c in picked]
    assert names == ["friction.dry", "drag.quadratic", "damping.mass", "mass.added"]
    assert "mass.added" in line and "in place of drag.linear" in line
    assert "repeats" in line and "84%" in line
    # the one that gave its place, and whose change it repeats (for the reconsideration)
    assert [(s.repeats, c.physics) for s, c in left_out] == [("friction.dry", "drag.linear")]


def test_the_best_four_stay_when_nothing_new_scores_half_the_best():
    picked, line, left_out = shortlist(_ranked(0.4 * 8.41e4), 4)
    assert [c.physics for _, c in picked] == ["friction.dry", "drag.quadratic", "damping.mass",
                                              "drag.linear"]
    assert line is None and left_out == []


def test_distinct_changes_are_all_kept():
    picked, line, left_out = shortlist(_ranked(7.10e4, repeated=False), 4)
    assert line is None and len(picked) == 4 and left_out == []
    assert "mass.added" not in [c.physics for _, c in picked]


def test_a_candidate_without_a_direction_is_neither_a_repeat_nor_promoted():
    ranked = _ranked(1.0)[:4] + [_entry("gravity", 8e4, None)]
    picked, line, left_out = shortlist(ranked, 4)
    assert line is None and left_out == [] and "gravity" not in [c.physics for _, c in picked]


def test_the_score_direction_is_the_projected_column():
    rng = np.random.default_rng(1)
    Jb = rng.standard_normal((50, 2))
    Jc = rng.standard_normal((50, 1))
    r = rng.standard_normal(50)
    d = score_test(r, Jb, Jc).direction
    assert d is not None and abs(np.linalg.norm(d) - 1.0) < 1e-6
    assert np.abs(Jb.T @ d).max() < 1e-5 * np.abs(Jb).max()
    # the same direction as the column minus its least-squares fit by the base columns
    perp = Jc[:, 0] - Jb @ np.linalg.lstsq(Jb, Jc[:, 0], rcond=None)[0]
    assert abs(abs(np.dot(d, perp / np.linalg.norm(perp))) - 1.0) < 1e-6
    assert score_test(r, Jb, rng.standard_normal((50, 2))).direction is None
