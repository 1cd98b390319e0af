"""The measures of a random draw (scripts/benchmarks/independent/measures.py and rates.py, issue
37): the Wilson interval against its definition, the seed from a commit hash, the outcome of a
case, the confusion matrix and the power curve on hand-made reports, and the figures by the data
they show. Reports are built by petsoft's own build_report (so they are valid report.json)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from _examples import load_script
from scipy import stats

from petsoft.diagnosis.report import build_report

#: pure Python and files: the same on every rank
pytestmark = pytest.mark.serial_only

FOLDER = "benchmarks/independent"
m = load_script("measures", FOLDER)
rates = load_script("rates", FOLDER, needs=("measures",))

SIGMA = 1e-4


def report(added=(), ties_with=None, verdict="consistent", final_verdict=None,
           held=(8.0, 1.0), E=2.0e7):
    """A valid report.json naming ``added``; ``ties_with`` puts selection's tie sentence on the
    first added term."""
    entries = []
    for i, physics in enumerate(added):
        evidence = "score test S = 100 (p = 0); likelihood ratio 99 (p = 0)"
        if i == 0 and ties_with:
            evidence += (f"; ambiguous: {ties_with} predicted and fitted as well (held-out rms "
                         "within 2 % or the noise, as many parameters, chi2 + k ln n within 2)"
                         "; chosen by the vocabulary's order")
        entries.append({"physics": physics, "parameters": {physics: 1.0},
                        "std": {physics: 0.1}, "score": 100.0, "rms_after": SIGMA,
                        "evidence": evidence})
    return build_report(verdict=verdict, noise_std=SIGMA,
                        base={"rms": 8 * SIGMA, "chi2_per_dof": 64.0},
                        final={"rms": SIGMA, "chi2_per_dof": 1.0},
                        validation={"base_rms": held[0] * SIGMA, "final_rms": held[1] * SIGMA},
                        parameters={"material.youngs_modulus": E}, added=entries,
                        final_verdict=final_verdict)


# -- the Wilson interval ------------------------------------------------------------------------
@pytest.mark.parametrize("k,n", [(3, 10), (0, 12), (12, 12), (1, 40), (27, 40)])
def test_wilson_interval_is_where_the_score_test_does_not_reject(k, n):
    """The Wilson interval is the set of p whose score test accepts k/n at 5 %:
    (k/n - p)^2 <= z^2 p (1 - p) / n, a quadratic in p whose roots are the ends (solved here
    with numpy's polynomial roots, not with the closed form measures.wilson uses)."""
    z = stats.norm.ppf(0.975)
    ph = k / n
    roots = np.sort(np.roots([1 + z * z / n, -(2 * ph + z * z / n), ph * ph]).real)
    lo, hi = m.wilson(k, n)
    assert lo == pytest.approx(max(roots[0], 0.0), abs=1e-12)
    assert hi == pytest.approx(min(roots[1], 1.0), abs=1e-12)
    # at the ends the score statistic equals z (inside, less)
    for p in (lo, hi):
        if 0.0 < p < 1.0:
            assert abs(ph - p) / math.sqrt(p * (1 - p) / n) == pytest.approx(z, rel=1e-9)
    assert 0.0 <= lo <= ph <= hi <= 1.0


def test_wilson_interval_by_hand_and_its_coverage():
    """3 of 10 by hand from the formula; no success in n: upper end z^2 / (n + z^2); and the
    exact coverage of the 95 % interval for p = 0.1, n = 40 (sum of the binomial pmf over the
    k whose interval holds p) is close to 95 % (the Wald interval's is 0.91 there)."""
    z = 1.959963984540054
    n, k = 10, 3
    p = k / n
    centre = (p + z * z / 20) / (1 + z * z / 10)
    half = z / (1 + z * z / 10) * math.sqrt(p * (1 - p) / 10 + z * z / 400)
    assert m.wilson(3, 10) == pytest.approx((centre - half, centre + half), abs=1e-12)
    assert m.wilson(3, 10) == pytest.approx((0.1078, 0.6032), abs=1e-4)
    assert m.wilson(0, 10) == pytest.approx((0.0, z * z / (10 + z * z)), abs=1e-12)
    cover = sum(stats.binom.pmf(j, 40, 0.1) for j in range(41)
                if m.wilson(j, 40)[0] <= 0.1 <= m.wilson(j, 40)[1])
    assert 0.93 < cover < 0.99, cover
    assert m.wilson(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError, match="0 <= k <= n"):
        m.wilson(5, 4)


def test_seed_from_commit_is_the_first_eight_hex_digits_mod_2_31():
    assert m.seed_from_commit("0000000a" + "f" * 32) == 10
    assert m.seed_from_commit("80000001" + "0" * 32) == 1            # 2^31 + 1 mod 2^31
    assert m.seed_from_commit("7fffffff0123") == 2 ** 31 - 1
    with pytest.raises(ValueError, match="not a commit hash"):
        m.seed_from_commit("HEAD")


def test_rates_prints_the_seed_of_a_commit(capsys):
    sha = rates.resolve_commit("HEAD")
    assert len(sha) == 40
    assert rates.main(["--seed-from-commit", "HEAD"]) == 0
    assert int(capsys.readouterr().out) == int(sha[:8], 16) % 2 ** 31


# -- outcomes and the confusion matrix -----------------------------------------------------------
def test_classify_counts_a_tie_as_ambiguous_not_as_a_win():
    tie = report(["damping.mass"], ties_with="drag.linear")
    c = m.classify(["damping.mass"], tie)
    assert c["outcome"] == "ambiguous" and not c["exact"]
    assert c["ambiguous"] == {"damping.mass": ["drag.linear"]}
    assert m.classify(["damping.mass"], report(["damping.mass"]))["outcome"] == "exact"
    assert m.classify([], report())["outcome"] == "exact"
    assert m.classify([], report(["gravity"]))["outcome"] == "false add"
    assert m.classify(["gravity"], report())["outcome"] == "missed"
    wrong = m.classify(["gravity", "mass.added"], report(["gravity", "drag.linear"]))
    assert wrong["outcome"] == "wrong"
    assert wrong["found"] == ["gravity"] and wrong["extra"] == ["drag.linear"]
    assert m.classify(["gravity"], None)["outcome"] == "no report"
    assert m.classify(["gravity", "mass.added"], report(["gravity"]))["outcome"] == "partial"


def test_confusion_matrix_of_three_hand_made_reports():
    """A control with a false add, a mass damping taken (in a tie) with a linear drag, and a
    gravity + added mass case where the added mass was taken for a quadratic drag."""
    cases = [([], report(["friction.dry"], verdict="missing-physics")),
             (["damping.mass"], report(["damping.mass"], ties_with="drag.linear")),
             (["gravity", "mass.added"], report(["gravity", "drag.quadratic"]))]
    assert m.confusion(cases) == {
        "none": {"friction.dry": 1},
        "damping.mass": {"ambiguous": 1},
        "gravity": {"gravity": 1, "drag.quadratic": 1},
        "mass.added": {"drag.quadratic": 1}}
    # found exactly, a two-term case counts once on each diagonal cell; no report, its column
    assert m.confusion([(["gravity", "mass.added"], report(["mass.added", "gravity"])),
                        (["gravity"], None), ([], report())]) == {
        "gravity": {"gravity": 1, "no report": 1}, "mass.added": {"mass.added": 1},
        "none": {"none": 1}}


def test_power_curve_bins_on_the_half_decade_grid():
    edges = m.log_bins([0.3, 1.0, 4.0, 40.0, 35.0])
    assert edges == pytest.approx(10.0 ** (np.arange(-2, 5) / 2))
    curve = m.power_curve([0.3, 1.0, 4.0, 40.0, 35.0], [False, True, True, True, False], edges)
    assert [b["lo"] for b in curve] == pytest.approx([0.1, 1.0, 10 ** 0.5, 10 ** 1.5])
    assert [(b["n"], b["k"]) for b in curve] == [(1, 0), (1, 1), (1, 1), (2, 1)]
    assert curve[-1]["rate"] == 0.5 and curve[-1]["ci"] == pytest.approx(m.wilson(1, 2))
    assert curve[0]["centre"] == pytest.approx(10 ** -0.75)
    with pytest.raises(ValueError, match="finite and positive"):
        m.log_bins([1.0, 0.0])
    with pytest.raises(ValueError, match="outside the bins"):
        m.power_curve([200.0], [True], edges)


def test_effect_sizes_per_term_or_one_number():
    assert m.effect_sizes({"concealed": ["gravity"], "effect_over_noise": 3.0}) == {
        "gravity": 3.0}
    both = {"concealed": ["gravity", "mass.added"],
            "effect_over_noise": {"gravity": 3.0, "mass.added": 0.2}}
    assert m.effect_sizes(both) == {"gravity": 3.0, "mass.added": 0.2}
    both["effect_over_noise"] = 4.0            # combined: no term's own size
    assert m.effect_sizes(both) == {}
    assert m.effect_sizes({"concealed": [], "effect_over_noise": {}}) == {}


def test_noticed_is_a_mismatch_blamed_on_physics_not_on_the_numerics():
    assert m.noticed(report(["damping.mass"], verdict="missing-physics"))    # no cause: added
    assert not m.noticed(report())
    numerics = report(verdict="missing-physics", final_verdict="consistent")
    numerics["cause"] = "numerics"                 # a refinement removed the mismatch
    assert not m.noticed(numerics)
    for cause in ("physics", "both", "unexplained"):
        numerics["cause"] = cause
        assert m.noticed(numerics)
    assert not m.noticed(None)


def test_offvocab_row_flags_a_consistent_verdict_above_one_and_a_half_noise():
    short = m.offvocab_row(report(["damping.stiffness"], verdict="missing-physics",
                                  final_verdict="missing-physics", held=(6.0, 2.5)))
    assert short["short_of_noise"] and not short["consistent"] and short["improved"]
    assert short["violates"] is False and short["heldout_final"] == pytest.approx(2.5)
    bad = m.offvocab_row(report(["damping.stiffness"], held=(6.0, 1.6)))
    assert bad["consistent"] and bad["violates"]
    assert m.offvocab_row(report(["damping.stiffness"], held=(6.0, 1.2)))["violates"] is False


# -- a whole draw on disk: the table's numbers and the figures' data ----------------------------
def _case(root, name, concealed, rep, effect=None, wall=60.0, E_true=2.0e7):
    d = root / name
    d.mkdir()
    truth = {"concealed": concealed, "truth": {"youngs_modulus": E_true}}
    if effect is not None:
        truth["effect_over_noise"] = effect
    (d / "truth.json").write_text(json.dumps(truth))
    if rep is not None:
        (d / "report.json").write_text(json.dumps(rep))
        (d / "row.json").write_text(json.dumps({"wall_s": wall, "status": "ok"}))


def test_a_draw_is_scored_and_its_figures_show_those_numbers(tmp_path):
    _case(tmp_path, "c0", [], report(), wall=50.0)
    _case(tmp_path, "c1", [], report(["gravity"], verdict="missing-physics"), wall=70.0)
    _case(tmp_path, "s0", ["damping.mass"], report(["damping.mass"], E=2.2e7),
          {"damping.mass": 12.0}, wall=100.0)
    _case(tmp_path, "s1", ["damping.mass"], report(), {"damping.mass": 0.5}, wall=400.0)
    _case(tmp_path, "s2", ["damping.mass"], report(["damping.mass"], ties_with="drag.linear"),
          {"damping.mass": 8.0}, wall=90.0)
    _case(tmp_path, "o0", ["offvocab.hysteretic"],
          report(["damping.stiffness"], verdict="missing-physics",
                 final_verdict="missing-physics", held=(5.0, 2.0)),
          {"offvocab.hysteretic": 20.0}, wall=200.0)
    _case(tmp_path, "t0", ["gravity"], None, {"gravity": 3.0})       # timed out: no report
    s = rates.summarize(rates.load_draw(tmp_path), alpha=0.01)
    assert s["counts"] == {"control": 2, "single": 4, "double": 0, "offvocab": 1}
    ex = s["exact"]
    assert (ex["control"]["k"], ex["control"]["n"]) == (1, 2)
    assert (ex["single"]["k"], ex["single"]["n"]) == (1, 4)
    assert (ex["single, >= 5x noise"]["k"], ex["single, >= 5x noise"]["n"]) == (1, 2)
    assert ex["overall (controls and vocabulary effects)"]["n"] == 6
    assert s["false_add"]["k"] == 1 and s["false_add"]["ci"] == pytest.approx(m.wilson(1, 2))
    assert s["per_term"]["damping.mass"]["named"]["k"] == 2           # the tie names it too
    assert s["outcomes"] == {"exact": 2, "false add": 1, "missed": 1, "ambiguous": 1,
                             "wrong": 1, "no report": 1}
    assert s["wall_s"]["median"] == 95.0 and s["wall_s"]["max"] == 400.0
    case = {c["case"]: c for c in s["cases"]}
    assert case["s0"]["E_rel_err"] == pytest.approx(0.1)
    assert s["offvocab"][0]["named"] == ["damping.stiffness"] and s["offvocab"][0]["improved"]

    met = {t: ok for t, _, ok in rates.targets(s)}
    assert met == {"N >= 40, >= 10 controls, >= 6 off-vocabulary": False,
                   "false adds on controls <= 10 %": False,          # 1 of 2
                   "exact name >= 90 % for single effects >= 5x noise": False,   # 1 of 2
                   "no off-vocabulary case called consistent above 1.5x noise held-out": True,
                   "median case <= 3 min, worst <= 10 min": True}     # 95 s, 400 s

    drawn = rates.power_figure(tmp_path / "power.png", s["power"])
    mass = s["power"]["damping.mass"]
    assert [b["n"] for b in mass] == [1, 1, 1] and [b["k"] for b in mass] == [0, 1, 1]
    np.testing.assert_allclose(drawn["damping.mass"]["xy"],
                               [[b["centre"], b["rate"]] for b in mass])
    np.testing.assert_allclose(drawn["damping.mass"]["bars"], [b["ci"] for b in mass])
    assert drawn["damping.mass"]["bars"][0] == pytest.approx(m.wilson(0, 1))
    assert set(drawn) == {"damping.mass", "gravity", "offvocab.hysteretic (noticed)"}
    noticed = s["power"]["offvocab.hysteretic (noticed)"]
    assert [(b["n"], b["k"]) for b in noticed] == [(1, 1)]          # its verdict: missing
    assert "offvocab.hysteretic" not in s["per_term"]
    shown = rates.confusion_figure(tmp_path / "confusion.png", s["confusion"])
    rows, cols = rates.confusion_columns(s["confusion"])
    assert rows[0] == "none" and cols[0] == "none" and cols[-2:] == ["ambiguous", "no report"]
    expected = np.zeros((len(rows), len(cols)))
    for r, c in [("none", "none"), ("none", "gravity"), ("damping.mass", "damping.mass"),
                 ("damping.mass", "none"), ("damping.mass", "ambiguous"),
                 ("gravity", "no report"), ("offvocab.hysteretic", "damping.stiffness")]:
        expected[rows.index(r), cols.index(c)] += 1
    np.testing.assert_array_equal(shown, expected)
    assert (tmp_path / "power.png").exists() and (tmp_path / "confusion.png").exists()


def test_the_command_line_writes_the_table_and_refuses_a_malformed_report(tmp_path, capsys):
    draw, out = tmp_path / "draw", tmp_path / "out"
    draw.mkdir()
    _case(draw, "c0", [], report())
    _case(draw, "s0", ["gravity"], report(["gravity"], verdict="missing-physics"),
          {"gravity": 40.0})
    _case(draw, "d0", ["gravity", "mass.added"], report(["gravity"], verdict="missing-physics"),
          7.5)
    assert rates.main([str(draw), "--figures", str(out), "--label", "unit"]) == 0
    printed = capsys.readouterr().out
    assert "## unit: 3 cases" in printed
    assert "| d0 | double | gravity, mass.added (together 7.5) | gravity | partial |" in printed
    assert "| exact name, single | 1/1 = 100%" in printed
    saved = json.loads((out / "rates.json").read_text())
    assert saved["false_add"]["k"] == 0 and saved["power"]["gravity"][0]["k"] == 1
    assert (out / "rates.md").read_text() == printed.rstrip("\n") + "\n"
    # the same draw beside another (a training draw's rates.json): both rates and the gap
    train = dict(saved, false_add={**saved["false_add"], "k": 1, "n": 4, "rate": 0.25},
                 wall_s={"median": 100.0, "max": 100.0, "n": 3})
    (tmp_path / "train.json").write_text(json.dumps(train))
    assert rates.main([str(draw), "--figures", str(out), "--label", "test",
                       "--beside", str(tmp_path / "train.json"), "training"]) == 0
    printed = capsys.readouterr().out
    assert "| measure | test | training | gap |" in printed
    assert "| false add on controls | 0/1 = 0% [0%, 79%] | 1/4 = 25% " in printed
    assert printed.split("| false add on controls |")[1].split("\n")[0].endswith("| -25% |")
    assert "| exact name, single | 1/1 = 100% [21%, 100%] | 1/1 = 100% [21%, 100%] | +0% |" \
        in printed
    wall = json.loads((out / "rates.json").read_text())["wall_s"]["median"]
    assert f"| wall time per case, median (s) | {wall:.0f} (3 cases) | 100 (3 cases) | " \
           f"{wall - 100:+.0f} |" in printed
    bad = report()
    del bad["fit"]
    (draw / "c0" / "report.json").write_text(json.dumps(bad))
    with pytest.raises(Exception, match="c0/report.json"):
        rates.main([str(draw), "--figures", str(out)])


def test_draw_and_run_refuses_what_the_protocol_forbids(tmp_path):
    """draw_and_run.sh stops before generating anything: a training draw given the current
    commit's test seed, a folder already used, a count that is not one."""
    import subprocess

    script = m.__file__.replace("measures.py", "draw_and_run.sh")
    seed = m.seed_from_commit(rates.resolve_commit("HEAD"))

    def run(*args):
        return subprocess.run(["bash", script, *map(str, args)], capture_output=True,
                              text=True, timeout=120)

    used = tmp_path / "used"
    used.mkdir()
    for args, said in [(("training", 4, seed, tmp_path / "new"), "this commit's test seed"),
                       (("test", 4, used), "exists"),
                       (("training", 4, seed + 1, used), "exists"),
                       (("test", "x", tmp_path / "new"), "positive integer")]:
        out = run(*args)
        assert out.returncode == 2 and said in out.stderr, (args, out.stderr)
    assert not (tmp_path / "new").exists()


def test_split_test_draw_refuses_another_commits_folder_and_pending_cases(tmp_path):
    """The test draw made over several sittings (draw_and_run.sh test-cases / test-diagnose):
    its folder is bound to the commit it was started at, N may not shrink, and it is not
    diagnosed while a case is pending or before it has a protocol."""
    import json
    import subprocess

    script = m.__file__.replace("measures.py", "draw_and_run.sh")
    head = rates.resolve_commit("HEAD")

    def run(*args):
        return subprocess.run(["bash", script, *map(str, args)], capture_output=True,
                              text=True, timeout=120)

    other = tmp_path / "other"
    other.mkdir()
    (other / "protocol.json").write_text(json.dumps({"commit": "0" * 40, "N": 4}))
    mine = tmp_path / "mine"
    (mine / "cases").mkdir(parents=True)
    (mine / "protocol.json").write_text(json.dumps({"commit": head, "N": 8, "seed": 1,
                                                    "size": "small"}))
    (mine / "cases" / "draw.json").write_text(json.dumps({"status": {"pending": 3}}))
    for args, said in [(("test-cases", 4, other), "worktree at that commit"),
                       (("test-diagnose", other), "worktree at that commit"),
                       (("test-cases", 4, mine), "never shrink"),
                       (("test-diagnose", mine), "3 cases are still pending"),
                       (("test-diagnose", tmp_path / "none"), "protocol.json is missing")]:
        out = run(*args)
        assert out.returncode == 2 and said in out.stderr, (args, out.stderr)
    assert not (mine / "diagnoses").exists() and not (mine / "job.log").exists()
    # diagnosed already: a finished job, or a folder no job of this protocol started, is
    # never run again (only a job cut short, with its sittings recorded, is resumed)
    (mine / "cases" / "draw.json").write_text(json.dumps({"status": {"pending": 0}}))
    (mine / "diagnoses").mkdir()
    for protocol, said in [({"ended": None}, "without a recorded start"),
                           ({"ended": "2026-11-29T10:00:00Z", "sittings": ["x"]},
                            "was finished")]:
        (mine / "protocol.json").write_text(json.dumps({"commit": head, "N": 8, "seed": 1,
                                                        "size": "small", **protocol}))
        out = run("test-diagnose", mine)
        assert out.returncode == 2 and said in out.stderr, (protocol, out.stderr)
    assert not (mine / "job.log").exists()


def test_the_random_generators_truth_format_is_read():
    """random_cases.py writes the combined effect as ``effect_size_over_noise: {"rms", "max"}``
    and names its off-vocabulary effects without the prefix: both are understood."""
    assert m.is_offvocab("inclusion.slab") and m.is_offvocab("offvocab.x")
    assert not m.is_offvocab("damping.mass")
    one = {"concealed": ["damping.mass"], "effect_size_over_noise": {"rms": 3.5, "max": 9.0}}
    assert m.effect_sizes(one) == {"damping.mass": 3.5}
    two = {"concealed": ["damping.mass", "gravity"],
           "effect_size_over_noise": {"rms": 3.5, "max": 9.0}}
    assert m.effect_sizes(two) == {}
