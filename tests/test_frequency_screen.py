"""The random cases' truth-level screen (scripts/benchmarks/independent/frequency_screen.py):
the natural frequencies' extrapolated error, the marker error it predicts, and the choice of
the cheapest affordable level, on synthetic frequency ladders whose error is known
(f(h) = f0 + c h^p; no DOLFINx: the eigen solve is replaced by the power law)."""

import math

import numpy as np
import pytest
from _independent import load

fs = load("frequency_screen")
rd = fs.rd


#: a synthetic case: what choose reads of it
CASE = {"name": "x", "geometry": {}, "excitation": {"kind": "velocity"}, "end": 0.5}


def ladder(f0, c, p, hs):
    """Frequencies (len(hs), 2) of two modes following f0 + c h^p."""
    return np.array([[f0 + c * h ** p, 1.5 * f0 + 2 * c * h ** p] for h in hs])


@pytest.mark.parametrize("p", [1.0, 2.0, 3.5])
def test_a_power_law_frequency_error_is_recovered(p):
    h = 0.01
    f = ladder(10.0, 3e3, p, [h, 1.4 * h, 1.96 * h])
    assert fs.frequency_error(f[:, 0]) == pytest.approx(3e3 * h ** p, rel=1e-9)
    assert fs.frequency_error(f[:, 1]) == pytest.approx(6e3 * h ** p, rel=1e-9)


def test_an_order_above_four_is_capped_so_the_error_is_overestimated():
    h = 0.01
    f = ladder(10.0, 3e7, 6.0, [h, 1.4 * h, 1.96 * h])
    assert fs.frequency_error(f[:, 0]) > 3e7 * h ** 6


def test_a_mode_not_converging_is_no_estimate():
    assert fs.frequency_error([10.0, 10.1, 10.15]) is None     # 0.1 then 0.05


def test_the_prediction_follows_record_noise_and_step():
    case = {"end": 0.5, "noise_fraction": 0.02, "excitation": {"kind": "velocity"}}
    k_space, k_time = fs.K["velocity"]
    f, err = 12.0, 1e-3
    p4 = fs.predicted(case, f, err, 4)
    scale = 2 * math.pi * 0.5 / 0.02
    assert p4["space"] == pytest.approx(k_space * scale * 1e-3)
    wdt = 2 * math.pi * 12.0 * rd.STEP / 4
    assert p4["time"] == pytest.approx(k_time * scale * 12.0 * wdt ** 2 / 12)
    p8 = fs.predicted(case, f, err, 8)
    assert p8["time"] == pytest.approx(p4["time"] / 4)   # second order in the step
    assert p8["space"] == p4["space"]
    twice = fs.predicted(dict(case, end=1.0), f, err, 4)
    assert twice["bound"] == pytest.approx(2 * p4["bound"])   # phase error grows with T
    base = fs.predicted(dict(case, excitation={"kind": "base"}), f, err, 4)
    assert base["bound"] < p4["bound"]       # a drive's motion does not drift as freely


def synthetic(monkeypatch, f0=10.0, c=5.0, p=2.0, volume=2e-3, calls=None, p3=None):
    """frequency_screen.frequencies replaced by f0 + c h^p (P3: f0 + c h^p3) and volume / h^3
    tets."""
    def frequencies(gmsh, case, h, modes=2, degree=2):
        if calls is not None:
            calls.append(h)
        return ladder(f0, c, p if degree == 2 else p3, [h])[0], int(volume / h ** 3)
    monkeypatch.setattr(fs, "frequencies", frequencies)
    monkeypatch.setattr(fs.rs, "truth_h", lambda g: 0.01)


def test_the_cheapest_level_predicted_within_the_margin_is_chosen(monkeypatch):
    synthetic(monkeypatch)
    case = dict(CASE, noise_fraction=0.05)
    tol = 0.2
    got = fs.choose(None, case, tol, say=lambda s: None)
    # brute force from the exact error (the power law's extrapolation is exact)
    best, passing = None, 0
    for k in range(fs.FINEST, fs.COARSEST - 1):   # a level needs two coarser rungs
        h = 0.01 * fs.LADDER ** k
        tets = int(2e-3 / h ** 3)
        f = ladder(10.0, 5.0, 2.0, [h])[0, 0]
        err = 5.0 * h ** 2
        for s in fs.SUBSTEPS:
            cost = tets * case["end"] / rd.STEP * s
            bound = fs.predicted(case, f, err, s)["bound"]
            if bound < fs.MARGIN * tol and cost <= fs.MAX_TET_STEPS:
                passing += 1
                if best is None or cost < best[2]:
                    best = (h, s, cost)
    assert passing >= 3       # a choice to make
    assert got["h"] == pytest.approx(best[0]) and got["substeps"] == best[1]
    assert got["chosen"]["predicted"]["bound"] < fs.MARGIN * tol


def test_no_affordable_level_is_a_discard(monkeypatch):
    synthetic(monkeypatch)
    # a noise of 0.1 % of the motion: every level within the cost misses the margin
    case = dict(CASE, noise_fraction=0.001)
    got = fs.choose(None, case, 0.2, say=lambda s: None)
    assert got["h"] is None and got["chosen"] is None
    levels = [lv for lv in got["levels"] if lv["predicted"]]
    assert levels and all(lv["predicted"]["bound"] >= fs.MARGIN * 0.2
                          for lv in levels if lv["tet_steps"] <= fs.MAX_TET_STEPS)


@pytest.mark.parametrize("p3, chosen", [(1.6, 2), (4.0, 3)])
def test_a_degree_is_chosen_by_its_cost_weighted_tet_steps(monkeypatch, p3, chosen):
    # P2 converging at order 1.5 (a clamped plate's) needs h at 16 steps a frame; P3 at
    # order 1.6 passes at 1.4 h, cheaper per tet-step but not at COST[3] a tet (P2 chosen);
    # at order 4 its coarsest level passes and is cheaper even at 4x a tet (P3 chosen)
    synthetic(monkeypatch, p=1.5, p3=p3)
    case = dict(CASE, noise_fraction=0.02)
    got = fs.choose(None, case, 0.2, say=lambda s: None, degrees=(2, 3))
    assert got["degree"] == chosen
    ch = got["chosen"]
    assert ch["tet_steps"] == pytest.approx(
        ch["tets"] * case["end"] / rd.STEP * ch["substeps"] * fs.COST[chosen])
    same = [lv for lv in got["levels"] if lv["degree"] != chosen and lv["predicted"]
            and lv["predicted"]["bound"] < fs.MARGIN * 0.2 and lv["tet_steps"] <= fs.MAX_TET_STEPS]
    assert all(lv["tet_steps"] >= ch["tet_steps"] for lv in same)


@pytest.mark.parametrize("limit", ["tets", "cost"])
def test_the_ladder_stops_before_a_mesh_no_level_could_afford(monkeypatch, limit):
    calls = []
    synthetic(monkeypatch, calls=calls)
    case = dict(CASE, noise_fraction=0.02)
    if limit == "tets":
        monkeypatch.setattr(fs, "MAX_TETS", 5000)
        affordable = 5000
    else:           # 250 steps at 4 a frame: 1e6 tet-steps afford 1,000 tets
        monkeypatch.setattr(fs, "MAX_TET_STEPS", 1e6)
        affordable = 1000
    fs.choose(None, case, 0.2, say=lambda s: None)
    tets = [int(2e-3 / h ** 3) for h in calls]
    # meshed coarse to fine, stopping at the last rung predicted (x 1.4^3) within 1.25x
    assert calls == sorted(calls, reverse=True)
    assert all(t * fs.LADDER ** 3 <= 1.25 * affordable for t in tets[:-1])
    assert tets[-1] * fs.LADDER ** 3 > 1.25 * affordable
