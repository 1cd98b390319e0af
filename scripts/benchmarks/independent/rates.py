"""Truth-finding measured as a rate: score a diagnosed random draw (issue 37, item 3).

Reads every case of a draw (``<cases>/<name>/truth.json``, made by ``generate.py --random``)
with its diagnosis (``<reports>/<name>/report.json``, and ``row.json`` from run.py for the wall
time and status; ``--reports`` defaults to ``<cases>``) and prints one table::

    .venv/bin/python scripts/benchmarks/independent/rates.py DRAW [--reports OUT]
        [--figures DIR] [--label test|training] [--alpha 0.01]
    .venv/bin/python scripts/benchmarks/independent/rates.py --seed-from-commit REV

- the exact-name rate (named set == concealed set, no tie named) with its 95 % Wilson interval,
  overall, by kind of case and per term, and for single effects >= 5x the noise;
- the false-add rate on controls with its interval, beside the significance level (--alpha);
- the confusion matrix concealed term x named term (with ``none``, ``ambiguous``, ``no
  report``), as a table and a heat map (``confusion.png``);
- the power curve of each term: the rate it is named against its effect size in units of the
  noise, in half-decade bins with intervals (``power.png``, log x axis); for an off-vocabulary
  effect the rate a mismatch is blamed on physics (:func:`measures.noticed`);
- the off-vocabulary cases: what was named, whether the report said the fit stays short of the
  noise, held-out rms / noise before and after;
- held-out rms / noise before and after, calibrated E error, wall time (median, max).

The table is also written to ``<figures>/rates.md`` and the numbers to ``rates.json``
(``--figures`` defaults to ``<reports>``). ``--seed-from-commit REV`` prints the test seed of
the protocol (README.md): :func:`measures.seed_from_commit` of REV's full hash.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

import measures as m
import numpy as np

from petsoft.diagnosis.report import read_report

HERE = Path(__file__).resolve().parent


def load_draw(cases: Path, reports: Path | None = None) -> list[dict]:
    """The records of a draw: ``name``, ``truth``, ``report`` (None when diagnose wrote none),
    ``status`` and ``wall_s`` (run.py's row.json; else the report's own total time)."""
    reports = reports or cases
    names = sorted(p.name for p in Path(cases).iterdir() if (p / "truth.json").exists())
    if not names:
        raise SystemExit(f"no case (a folder with truth.json) in {cases}")
    out = []
    for name in names:
        truth = json.loads((cases / name / "truth.json").read_text())
        c = truth.get("concealed")
        if not isinstance(c, list) or not all(isinstance(t, str) for t in c):
            raise SystemExit(f"{cases / name / 'truth.json'}: 'concealed' must be a list of "
                             f"term names, got {c!r}")
        rep_path, row_path = reports / name / "report.json", reports / name / "row.json"
        # validated (formats.md section 3): a malformed report is an error naming its file
        report = read_report(rep_path) if rep_path.exists() else None
        row = json.loads(row_path.read_text()) if row_path.exists() else {}
        wall = row.get("wall_s")
        if wall is None and report is not None:
            wall = (report.get("timings") or {}).get("total")
        status = row.get("status", "ok" if report is not None else "not run")
        out.append({"name": name, "truth": truth, "report": report, "status": status,
                    "wall_s": wall})
    return out


def kind(truth: dict) -> str:
    """control, single, double (two or more vocabulary terms) or offvocab."""
    c = truth["concealed"]
    if any(m.is_offvocab(t) for t in c):
        return "offvocab"
    return {0: "control", 1: "single"}.get(len(c), "double")


def _rate(k: int, n: int) -> dict:
    lo, hi = m.wilson(k, n)
    return {"k": k, "n": n, "rate": k / n if n else None, "ci": [lo, hi]}


def summarize(records: list[dict], alpha: float = 0.01, big: float = 5.0) -> dict:
    """Every measure of the draw (module docstring) as a dict (rates.json)."""
    for r in records:
        r["kind"] = kind(r["truth"])
        r["class"] = m.classify(r["truth"]["concealed"], r["report"])
        r["sizes"] = m.effect_sizes(r["truth"])
    inv = [r for r in records if r["kind"] != "offvocab"]
    by_kind = {k: [r for r in records if r["kind"] == k]
               for k in ("control", "single", "double", "offvocab")}
    exact = {"overall (controls and vocabulary effects)":
             _rate(sum(r["class"]["exact"] for r in inv), len(inv))}
    for k in ("control", "single", "double"):
        exact[k] = _rate(sum(r["class"]["exact"] for r in by_kind[k]), len(by_kind[k]))
    strong = [r for r in by_kind["single"]
              if r["sizes"] and min(r["sizes"].values()) >= big]
    exact[f"single, >= {big:g}x noise"] = _rate(sum(r["class"]["exact"] for r in strong),
                                                len(strong))
    per_term = {}
    terms = sorted({t for r in records for t in r["truth"]["concealed"]})
    for t in (t for t in terms if not m.is_offvocab(t)):
        singles = [r for r in by_kind["single"] if r["truth"]["concealed"] == [t]]
        having = [r for r in records if t in r["truth"]["concealed"]]
        per_term[t] = {"exact_single": _rate(sum(r["class"]["exact"] for r in singles),
                                             len(singles)),
                       "named": _rate(sum(t in r["class"]["named"] for r in having),
                                      len(having))}
    controls = by_kind["control"]
    false_add = _rate(sum(bool(r["class"]["named"]) for r in controls), len(controls))
    false_add["alpha"] = alpha
    false_add["alpha_inside_ci"] = (false_add["ci"][0] <= alpha <= false_add["ci"][1])
    outcomes = {}
    for r in records:
        outcomes[r["class"]["outcome"]] = outcomes.get(r["class"]["outcome"], 0) + 1
    conf = m.confusion((r["truth"]["concealed"], r["report"]) for r in records)
    power = {}
    for t in terms:
        if m.is_offvocab(t):
            # no term can name it: its "detection" is a mismatch blamed on physics
            pts = [(r["sizes"][t], m.noticed(r["report"])) for r in records if t in r["sizes"]]
            key = f"{t} (noticed)"
        else:
            pts = [(r["sizes"][t], t in r["class"]["named"]) for r in records if t in r["sizes"]]
            key = t
        if pts:
            power[key] = pts
    curves = {}
    if power:
        edges = m.log_bins([s for pts in power.values() for s, _ in pts])
        curves = {t: m.power_curve([s for s, _ in pts], [d for _, d in pts], edges)
                  for t, pts in power.items()}
    off = [{"case": r["name"], "concealed": r["truth"]["concealed"], "sizes": r["sizes"],
            **m.offvocab_row(r["report"])} for r in by_kind["offvocab"]]
    cases = []
    for r in records:
        rep = r["report"]
        base, after = m.heldout_over_noise(rep) if rep else (None, None)
        e = (rep or {}).get("parameters", {}).get("material.youngs_modulus")
        e_true = r["truth"].get("truth", {}).get("youngs_modulus")
        cases.append({"case": r["name"], "kind": r["kind"],
                      "concealed": r["truth"]["concealed"], "sizes": r["sizes"],
                      "effect_over_noise": r["truth"].get("effect_over_noise"),
                      "named": r["class"]["named"], "outcome": r["class"]["outcome"],
                      "ties": r["class"]["ambiguous"],
                      "verdict": (rep.get("final_verdict") or rep["verdict"]) if rep else None,
                      "heldout_base": base, "heldout_final": after,
                      "E_rel_err": e / e_true - 1.0 if e and e_true else None,
                      "status": r["status"], "wall_s": r["wall_s"]})
    walls = [c["wall_s"] for c in cases if c["wall_s"] is not None]
    e_err = [abs(c["E_rel_err"]) for c in cases if c["E_rel_err"] is not None]
    return {"n": len(records), "counts": {k: len(v) for k, v in by_kind.items()},
            "exact": exact, "per_term": per_term, "false_add": false_add,
            "outcomes": outcomes, "confusion": conf, "power": curves, "offvocab": off,
            "cases": cases,
            "wall_s": {"median": statistics.median(walls) if walls else None,
                       "max": max(walls) if walls else None, "n": len(walls)},
            "E_abs_rel_err": {"median": statistics.median(e_err) if e_err else None,
                              "max": max(e_err) if e_err else None, "n": len(e_err)}}


def targets(s: dict) -> list[tuple[str, str, bool | None]]:
    """Issue 37's targets on a summary: (target, what the draw gave, met; None when the draw
    has no case to judge it by)."""
    fa, ex = s["false_add"], s["exact"]["single, >= 5x noise"]
    off = [o for o in s["offvocab"] if o["violates"] is not None]
    bad = [o["case"] for o in off if o["violates"]]
    w = s["wall_s"]
    c = s["counts"]
    return [
        ("N >= 40, >= 10 controls, >= 6 off-vocabulary",
         f"N {s['n']}, {c['control']} controls, {c['offvocab']} off-vocabulary",
         s["n"] >= 40 and c["control"] >= 10 and c["offvocab"] >= 6),
        ("false adds on controls <= 10 %", _r(fa), fa["rate"] <= 0.10 if fa["n"] else None),
        ("exact name >= 90 % for single effects >= 5x noise", _r(ex),
         ex["rate"] >= 0.90 if ex["n"] else None),
        ("no off-vocabulary case called consistent above 1.5x noise held-out",
         f"{len(bad)} of {len(off)}" + (f" ({', '.join(bad)})" if bad else ""),
         not bad if off else None),
        ("median case <= 3 min, worst <= 10 min",
         f"median {_f(w['median'], '.0f')} s, max {_f(w['max'], '.0f')} s",
         w["median"] <= 180 and w["max"] <= 600 if w["n"] else None),
    ]


def _f(x, fmt=".2f") -> str:
    return "-" if x is None else format(x, fmt)


def _r(d: dict) -> str:
    if not d["n"]:
        return "- (0 cases)"
    return f"{d['k']}/{d['n']} = {d['rate']:.0%} [{d['ci'][0]:.0%}, {d['ci'][1]:.0%}]"


def confusion_columns(conf: dict) -> tuple[list[str], list[str]]:
    """Rows (concealed: none first, then the vocabulary's order, then off-vocabulary) and
    columns (none, the named terms in the vocabulary's order, ambiguous, no report)."""
    from petsoft.diagnosis.report import PHYSICS

    order = list(PHYSICS)

    def key(t):
        return (t != m.NONE, m.is_offvocab(t), order.index(t) if t in order else 0, t)

    rows = sorted(conf, key=key)
    named = {c for cells in conf.values() for c in cells} - {m.NONE, m.AMBIGUOUS, m.NO_REPORT}
    cols = [m.NONE] + sorted(named, key=key) + [m.AMBIGUOUS, m.NO_REPORT]
    return rows, cols


def table(s: dict, label: str = "") -> str:
    """The markdown table of a summary."""
    L = [f"## {label or 'draw'}: {s['n']} cases ("
         + ", ".join(f"{v} {k}" for k, v in s["counts"].items()) + ")", ""]
    unrun = [c["case"] for c in s["cases"] if c["status"] == "not run"]
    if unrun:
        L += [f"**Incomplete draw**: {len(unrun)} case(s) not run ({', '.join(unrun)}), "
              "counted as failures (no report) in every rate below.", ""]
    L += ["| measure | rate [95 % Wilson] |", "|---|---|"]
    L += [f"| exact name, {k} | {_r(v)} |" for k, v in s["exact"].items()]
    fa = s["false_add"]
    L.append(f"| false add on controls (alpha {fa['alpha']:g}"
             f"{', inside' if fa['alpha_inside_ci'] else ', OUTSIDE'} the interval) | {_r(fa)} |")
    L += ["", "| issue 37 target | this draw | met |", "|---|---|---|"]
    L += [f"| {t} | {v} | {'-' if ok is None else ('yes' if ok else 'NO')} |"
          for t, v, ok in targets(s)]
    L += ["", "| term | exact name (single cases) | named when concealed (all cases) |",
          "|---|---|---|"]
    L += [f"| {t} | {_r(v['exact_single'])} | {_r(v['named'])} |"
          for t, v in s["per_term"].items()]
    L += ["", "Outcomes: " + ", ".join(f"{k} {v}" for k, v in sorted(s["outcomes"].items())),
          "", "Confusion (rows: concealed; columns: named):", ""]
    rows, cols = confusion_columns(s["confusion"])
    L += ["| concealed \\ named | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    L += [f"| {r} | " + " | ".join(str(s["confusion"][r].get(c, "")) for c in cols) + " |"
          for r in rows]
    L += ["", "Power (named / cases per bin of effect size / noise):", ""]
    for t, curve in s["power"].items():
        L.append(f"- {t}: " + "; ".join(
            f"[{b['lo']:.3g}, {b['hi']:.3g}) {b['k']}/{b['n']}" for b in curve))
    if s["offvocab"]:
        L += ["", "| off-vocabulary case | effect / noise | named | fit short of the noise "
              "| held-out / noise (base -> final) | improved | consistent above 1.5x |",
              "|---|---|---|---|---|---|---|"]
        for o in s["offvocab"]:
            sz = ", ".join(f"{v:.3g}" for v in o["sizes"].values()) or "-"
            L.append(f"| {o['case']} ({'+'.join(o['concealed'])}) | {sz} | "
                     f"{'+'.join(o['named']) or '-'} | {o['short_of_noise']} | "
                     f"{_f(o['heldout_base'])} -> {_f(o['heldout_final'])} | {o['improved']} "
                     f"| {'YES' if o['violates'] else o['violates']} |")
    L += ["", "| case | kind | concealed (effect / noise) | named | outcome | final verdict "
          "| held-out / noise | E err | wall s | status |", "|---" * 10 + "|"]
    for c in s["cases"]:
        conc = ", ".join(f"{t} ({c['sizes'][t]:.3g})" if t in c["sizes"] else t
                         for t in c["concealed"]) or "-"
        if isinstance(c["effect_over_noise"], (int, float)) and not c["sizes"]:
            conc += f" (together {c['effect_over_noise']:.3g})"
        L.append(f"| {c['case']} | {c['kind']} | {conc} | {'+'.join(c['named']) or '-'} "
                 f"| {c['outcome']} | {c['verdict'] or '-'} | {_f(c['heldout_base'])} -> "
                 f"{_f(c['heldout_final'])} | {_f(c['E_rel_err'], '+.1%')} "
                 f"| {_f(c['wall_s'], '.0f')} | {c['status']} |")
    w, e = s["wall_s"], s["E_abs_rel_err"]
    L += ["", f"Wall time per case: median {_f(w['median'], '.0f')} s, max "
          f"{_f(w['max'], '.0f')} s ({w['n']} cases). |E error|: median "
          f"{_f(e['median'], '.1%')}, max {_f(e['max'], '.1%')} ({e['n']} cases)."]
    return "\n".join(L) + "\n"


def beside(s: dict, other: dict, label: str, other_label: str) -> str:
    """The headline rates of this draw ``s`` beside another draw's summary ``other`` (its
    rates.json), e.g. the test draw beside the training draw the rules were shaped on, with
    the gap: issue 37 asks that it be visible."""
    def rate(d):
        return d["rate"] if d.get("n") else None

    rows = [(f"exact name, {k}", rate(v), rate(other["exact"].get(k, {})), _r(v),
             _r(other["exact"][k]) if k in other["exact"] else "-")
            for k, v in s["exact"].items()]
    rows.append(("false add on controls", rate(s["false_add"]), rate(other["false_add"]),
                 _r(s["false_add"]), _r(other["false_add"])))
    L = [f"| measure | {label} | {other_label} | gap |", "|---|---|---|---|"]
    for name, a, b, ta, tb in rows:
        gap = "-" if a is None or b is None else f"{a - b:+.0%}"
        L.append(f"| {name} | {ta} | {tb} | {gap} |")
    for key, what, fmt in (("wall_s", "wall time per case, median (s)", ".0f"),
                           ("E_abs_rel_err", "E error (absolute), median", ".1%")):
        a, b = s[key]["median"], other[key]["median"]
        gap = "-" if a is None or b is None else format(a - b, "+" + fmt)
        L.append(f"| {what} | {_f(a, fmt)} ({s[key]['n']} cases) | {_f(b, fmt)} "
                 f"({other[key]['n']} cases) | {gap} |")
    return "\n".join(L) + "\n"


def power_figure(path: Path, curves: dict) -> dict:
    """Detection rate against effect size / noise per term (log x, Wilson intervals as error
    bars); returns what the axes show, per term: ``{"xy": (x, rate) points, "bars": (lo, hi)
    of each error bar}``."""
    from petsoft.diagnosis.report import pyplot_agg, save_figure

    plt = pyplot_agg()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for t, curve in curves.items():
        x = np.array([b["centre"] for b in curve])
        y = np.array([b["rate"] for b in curve])
        err = np.array([[b["rate"] - b["ci"][0] for b in curve],
                        [b["ci"][1] - b["rate"] for b in curve]])
        ax.errorbar(x, y, yerr=err, marker="o", capsize=3, label=t)
    ax.set_xscale("log")
    ax.set_ylim(-0.05, 1.05)
    ax.set_xlabel("effect size (rms change at the markers / noise)")
    ax.set_ylabel("rate named (95 % Wilson interval)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    # read back from the axes: each term's points and its error bars' ends
    drawn = {c.get_label(): {"xy": np.asarray(c.lines[0].get_xydata()),
                             "bars": np.array([[seg[0][1], seg[1][1]]
                                               for seg in c.lines[2][0].get_segments()])}
             for c in ax.containers}
    save_figure(fig, path)
    return drawn


def confusion_figure(path: Path, conf: dict) -> np.ndarray:
    """The confusion matrix as a heat map with its counts written in; returns the array shown
    (rows and columns of :func:`confusion_columns`)."""
    from petsoft.diagnosis.report import pyplot_agg, save_figure

    plt = pyplot_agg()
    rows, cols = confusion_columns(conf)
    a = np.array([[conf[r].get(c, 0) for c in cols] for r in rows], dtype=float)
    fig, ax = plt.subplots(figsize=(1.2 + 0.55 * len(cols), 1.2 + 0.45 * len(rows)))
    im = ax.imshow(a, cmap="Blues")
    for i, j in zip(*np.nonzero(a), strict=True):
        ax.text(j, i, f"{a[i, j]:.0f}", ha="center", va="center", fontsize=8,
                color="white" if a[i, j] > 0.6 * a.max() else "black")
    ax.set_xticks(range(len(cols)), cols, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(rows)), rows, fontsize=7)
    ax.set_xlabel("named")
    ax.set_ylabel("concealed")
    fig.colorbar(im, ax=ax, shrink=0.7)
    shown = np.asarray(im.get_array())
    save_figure(fig, path)
    return shown


def resolve_commit(rev: str) -> str:
    """The full hash of ``rev`` in the repository holding this script."""
    out = subprocess.run(["git", "-C", str(HERE), "rev-parse", "--verify", f"{rev}^{{commit}}"],
                         capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"not a commit: {rev} ({out.stderr.strip()})")
    return out.stdout.strip()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="?", type=Path, help="the draw's folder (case folders)")
    ap.add_argument("--reports", type=Path, default=None,
                    help="folder of the case diagnoses (<name>/report.json); default: cases")
    ap.add_argument("--figures", type=Path, default=None,
                    help="where rates.md, rates.json, power.png, confusion.png go")
    ap.add_argument("--label", default="", help="the table's title (e.g. test draw, seed ...)")
    ap.add_argument("--alpha", type=float, default=0.01,
                    help="the significance level diagnose ran with (its --alpha)")
    ap.add_argument("--beside", nargs=2, metavar=("RATES_JSON", "LABEL"), default=None,
                    help="another draw's rates.json (e.g. the training draw's) and its label: "
                         "the headline rates side by side, with the gap, in rates.md")
    ap.add_argument("--seed-from-commit", metavar="REV", default=None,
                    help="print the protocol's test seed of commit REV and stop")
    args = ap.parse_args(argv)
    if args.seed_from_commit:
        print(m.seed_from_commit(resolve_commit(args.seed_from_commit)))
        return 0
    if args.cases is None:
        ap.error("give the draw's folder (or --seed-from-commit)")
    reports = args.reports or args.cases
    s = summarize(load_draw(args.cases, reports), alpha=args.alpha)
    out = args.figures or reports
    out.mkdir(parents=True, exist_ok=True)
    md = table(s, args.label)
    if args.beside:
        other = json.loads(Path(args.beside[0]).read_text())
        md += ("\n### Beside " + args.beside[1] + "\n\n"
               + beside(s, other, args.label or "this draw", args.beside[1]))
    if s["power"]:
        power_figure(out / "power.png", s["power"])
    confusion_figure(out / "confusion.png", s["confusion"])
    (out / "rates.md").write_text(md)
    (out / "rates.json").write_text(json.dumps(s, indent=1, default=str) + "\n")
    print(md)
    print(f"figures: {out / 'power.png'}, {out / 'confusion.png'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
