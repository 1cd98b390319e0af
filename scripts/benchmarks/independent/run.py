"""Run ``petsoft diagnose`` on the independent concealed-effect cases and tabulate the verdicts.

The cases (``cases/<name>/user.toml`` + ``recording.h5``, made by DOLFINx with generate.py) are
diagnosed one after another through the command line a user would type::

    .venv/bin/python scripts/benchmarks/independent/run.py [--cases control-finger,damping-mass]
        [--out out/independent] [--np 2] [--timeout 3600] [--cases-dir DRAW]

Each case runs ``petsoft diagnose cases/<name>/user.toml cases/<name>/recording.h5 --out
<out>/<name>`` (under ``nice``; ``mpiexec -n NP`` when --np > 1), with its log in
``<out>/<name>/diagnose.log``. The table (case, concealed effect(s), verdict, terms added, rank
of the truth in the first round, whether every concealed term was added and nothing else,
held-out rms / noise, what the mesh/step check found, wall time) is printed and written to
``<out>/table.md`` and ``<out>/table.json``; ``--collect`` rebuilds it from the case folders
already run (e.g. by two runs given halves of the cases). ``--cases-dir DRAW`` runs the cases of
a random draw (``generate.py --random N --seed S --out DRAW``) instead of the suite's cases/;
rates.py then scores the draw as rates (draw_and_run.sh does both). ``truth.json`` is read only
here, to score the diagnosis, never by petsoft.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
CASES_DIR = HERE / "cases"
ROOT = HERE.parents[2]


def case_names(cases_dir: Path = CASES_DIR) -> list[str]:
    return sorted(p.name for p in cases_dir.iterdir() if (p / "truth.json").exists())


def chosen_cases(cases: str | None, cases_dir: Path) -> list[str] | None:
    """The ``--cases`` subset (comma-separated; None: all) of the case folders in ``cases_dir``,
    or None after printing which names are unknown and the valid ones."""
    known = case_names(cases_dir)
    names = cases.split(",") if cases else known
    bad = [n for n in names if n not in known]
    if bad:
        print(f"unknown case(s) {bad}; valid: {', '.join(known)}")
        return None
    return names


def petsoft_command(np_: int) -> list[str]:
    # the console script beside this python (the .venv's), as a user types it
    exe = [str(Path(sys.executable).parent / "petsoft")]
    if np_ > 1:
        return ["mpiexec", "-n", str(np_)] + exe
    return exe


def _rank(scores: list[dict], physics: str | None) -> tuple[int | None, list[str]]:
    """Rank of ``physics`` among the significant candidates of the first round (diagnose's own
    final ranking of that round), and that ranking."""
    first = [s for s in scores if s.get("round") == 1 and (s.get("p_value") is not None
                                                           and s["p_value"] < 0.01)]
    first.sort(key=lambda s: (s.get("rank") if s.get("rank") is not None else 1e9,
                              -(s.get("statistic") or 0.0)))
    ranking = [s["physics"] for s in first]
    if physics is None or physics not in ranking:
        return None, ranking
    return ranking.index(physics) + 1, ranking


def mesh_check(numerics: dict, noise: float) -> str:
    """One line of what the step/mesh refinement check found."""
    if not numerics:
        return "not run"
    parts = []
    for label, v in numerics.items():
        if isinstance(v, dict) and "change" in v:
            ratio = v.get("change_over_noise", v["change"] / noise if noise else None)
            parts.append(f"{label}: {ratio:.2g}x noise"
                         f"{' (resolved)' if v.get('resolved') else ''}")
        elif isinstance(v, (str, bool)) and label not in ("base_rms_all",):
            parts.append(f"{label}: {v}")
    return "; ".join(parts) or json.dumps(numerics)[:120]


def partial_log(log: Path, noise: float | None) -> dict:
    """What a diagnose stopped before its report got to: the base fit and the numerics check
    (from its progress lines)."""
    got: dict = {}
    if not log.exists():
        return got
    checks, scores = [], []
    for line in log.read_text().splitlines():
        m = re.search(r"score (\S+)\s+S =\s+([0-9.eE+-]+)\s+dof (\d+)\s+p = ([0-9.eE+-]+)", line)
        if m and got.get("last_round_started") == 1:
            scores.append((m.group(1), float(m.group(2)), float(m.group(4))))
        m = re.search(r"base fit: .*chi2/dof ([0-9.eE+-]+), held-out rms ([0-9.eE+-]+) m", line)
        if m:
            got["chi2_base"] = float(m.group(1))
            got["heldout_base_over_noise"] = float(m.group(2)) / noise if noise else None
        m = re.search(r"material\.youngs_modulus=([0-9.eE+-]+);", line)
        if m and "base fit" in line:
            got["E_base"] = float(m.group(1))
        if "numerics:" in line and "still " not in line:    # not a heartbeat line
            checks.append(line.split("numerics:", 1)[1].strip())
        m = re.search(r"round (\d+): ranking", line)
        if m:
            got["last_round_started"] = int(m.group(1))
    if checks:
        got["mesh_check"] = "; ".join(checks)
    if scores:
        # the first round's score tests only (diagnose then orders close ones by their fits)
        got["score_ranking"] = [f"{n} (S {v:.3g})" for n, v, p in
                                sorted(scores, key=lambda t: -t[1]) if p < 0.01][:4]
    return got


def _final(row: dict) -> str | None:
    """The verdict a case ended with (the first one when the summary has no final verdict)."""
    return row.get("final_verdict") or row["verdict"]


def score_case(name: str, out: Path, wall: float, status: str,
               cases_dir: Path = CASES_DIR) -> dict:
    """The table's row of case ``name`` diagnosed into ``out`` (its truth from ``cases_dir``)."""
    truth = json.loads((cases_dir / name / "truth.json").read_text())
    concealed = truth["concealed"]
    # a random draw's truth names the shape's family (generate.py --random)
    row = {"case": name, "shape": truth.get("shape", truth.get("family", "-")),
           "concealed": "+".join(concealed) or "-",
           "status": status, "wall_s": round(wall, 1), "verdict": None, "added": None,
           "rank": None, "found": None, "extra": None, "heldout_over_noise": None,
           "heldout_base_over_noise": None, "chi2_final": None, "E_rel_err": None,
           "mesh_check": None, "ranking": None}
    rep_path, sum_path = out / "report.json", out / "summary.json"
    if not rep_path.exists():
        row.update(partial_log(out / "diagnose.log",
                               (truth.get("noise") or {}).get("position_std")))
        return row
    rep = json.loads(rep_path.read_text())
    summ = json.loads(sum_path.read_text()) if sum_path.exists() else {}
    res = summ.get("results", summ)
    noise = rep["noise_std"]
    added = [a["physics"] for a in rep["added"]]
    rank, ranking = _rank(res.get("scores", []), concealed[0] if concealed else None)
    val = rep["fit"].get("validation") or {}
    E = rep["parameters"].get("material.youngs_modulus")
    row.update({
        "verdict": rep["verdict"], "added": "+".join(added) or "-", "rank": rank,
        "found": set(concealed) <= set(added), "extra": sorted(set(added) - set(concealed)),
        "heldout_over_noise": (val["final_rms"] / noise if val.get("final_rms") else None),
        "heldout_base_over_noise": (val["base_rms"] / noise if val.get("base_rms") else None),
        "chi2_final": rep["fit"].get("final", {}).get("chi2_per_dof"),
        "E_rel_err": (E / truth["truth"]["youngs_modulus"] - 1.0) if E else None,
        "mesh_check": mesh_check(res.get("numerics") or {}, noise), "ranking": ranking[:4],
        "final_verdict": res.get("final_verdict"),
    })
    return row


def _f(x, fmt):
    return "-" if x is None else format(x, fmt)


def verdict(r: dict) -> str:
    """``first -> final`` verdict, or what a run that wrote no report got to."""
    if r["verdict"]:
        final = r.get("final_verdict")
        return f"{r['verdict']} -> {final}" if final and final != r["verdict"] else r["verdict"]
    got = [f"{r['status']}"]
    if r.get("chi2_base") is not None:
        got.append(f"base chi2/dof {r['chi2_base']:.3g}, E {r['E_base']:.3g}")
    if r.get("score_ranking"):
        got.append("round-1 scores: " + ", ".join(r["score_ranking"]))
    return "; ".join(got)


def table_md(rows: list[dict]) -> str:
    head = ("| case | shape | concealed | verdict (first -> final) | added | truth rank (round 1) "
            "| found, no extra | held-out rms / noise (base -> final) | chi2/dof final | E err "
            "| mesh/step check | wall s |\n|" + "---|" * 12)
    lines = [head]
    for r in rows:
        extra = f", extra {'+'.join(r['extra'])}" if r["extra"] else ""
        ok = "-" if r["found"] is None else f"{'yes' if r['found'] else 'NO'}{extra}"
        lines.append(
            f"| {r['case']} | {r['shape']} | {r['concealed']} | {verdict(r)} "
            f"| {r['added'] or '-'} | {_f(r['rank'], 'd')} | {ok} | "
            f"{_f(r['heldout_base_over_noise'], '.2f')} -> {_f(r['heldout_over_noise'], '.2f')} "
            f"| {_f(r['chi2_final'], '.3g')} | {_f(r['E_rel_err'], '+.1%')} "
            f"| {r['mesh_check'] or '-'} | {r['wall_s']:.0f} |")
    singles = [r for r in rows if r["concealed"] != "-" and "+" not in r["concealed"]]
    combined = [r for r in rows if "+" in r["concealed"]]
    controls = [r for r in rows if r["concealed"] == "-"]
    lines.append("")
    if controls:
        lines.append(f"- controls adding nothing and ending consistent: "
                     f"{sum(r['added'] == '-' and _final(r) == 'consistent' for r in controls)}"
                     f"/{len(controls)}")
    if singles:
        lines.append(f"- single-effect cases with the truth ranked first: "
                     f"{sum(r['rank'] == 1 for r in singles)}/{len(singles)}; truth added: "
                     f"{sum(bool(r['found']) for r in singles)}/{len(singles)}")
    if combined:
        lines.append(f"- combined cases with both effects added: "
                     f"{sum(bool(r['found']) for r in combined)}/{len(combined)}")
    done = [r for r in rows if r["heldout_over_noise"] is not None]
    if done:
        lines.append(f"- held-out rms <= 1.5 x noise: "
                     f"{sum(r['heldout_over_noise'] <= 1.5 for r in done)}/{len(done)}")
    return "\n".join(lines) + "\n"


def run_logged(cmd: list[str], log_path: Path, cwd: Path, timeout: float | None
               ) -> tuple[float, str]:
    """Run ``cmd`` in ``cwd`` with its output to ``log_path`` (the command its first line);
    return the wall time (s) and a status: ok, timeout, failed (exit n), stopped (signal n)."""
    env = dict(os.environ, MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1",
               OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    t0 = time.perf_counter()
    status = "ok"
    with open(log_path, "w") as log:
        log.write(" ".join(cmd) + "\n")
        log.flush()
        # a session of its own: on a timeout the whole group is stopped (killing mpiexec
        # alone would leave its ranks running)
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env,
                                cwd=str(cwd), start_new_session=True)
        # run.py itself stopped (a sitting's end, ^C): its case's group goes with it, else
        # the ranks of an interrupted case would run on beside the resumed job
        previous = {sig: signal.signal(sig, _stop_group_then(proc))
                    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)}
        try:
            code = proc.wait(timeout=timeout)
            if code < 0:
                status = f"stopped (signal {-code})"
            elif code != 0:
                status = f"failed (exit {code})"
        except subprocess.TimeoutExpired:
            status = "timeout"
            _stop_group(proc)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
    return time.perf_counter() - t0, status


def _stop_group(proc: subprocess.Popen) -> None:
    """Stop ``proc``'s process group: SIGTERM, then SIGKILL after 15 s."""
    for sig, grace in ((signal.SIGTERM, 15), (signal.SIGKILL, 15)):
        try:
            os.killpg(proc.pid, sig)
            proc.wait(timeout=grace)
            break
        except ProcessLookupError:
            break
        except subprocess.TimeoutExpired:
            continue


def _stop_group_then(proc: subprocess.Popen):
    """A signal handler: stop ``proc``'s group, then exit as the signal would."""
    def handler(signum, frame):
        _stop_group(proc)
        raise SystemExit(128 + signum)
    return handler


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=None, help="comma-separated subset (default: all)")
    ap.add_argument("--out", default="out/independent")
    ap.add_argument("--np", type=int, default=1, help="MPI ranks per diagnose (default 1)")
    ap.add_argument("--timeout", type=float, default=None,
                    help="seconds after which a case's diagnose is stopped (reported 'timeout')")
    ap.add_argument("--cases-dir", type=Path, default=CASES_DIR,
                    help="folder of the case folders (default: the suite's cases/; a random "
                         "draw's folder from generate.py --random)")
    ap.add_argument("--collect", action="store_true",
                    help="run nothing: tabulate the case folders already in --out")
    ap.add_argument("--resume", action="store_true",
                    help="keep the cases already diagnosed in --out (their row.json) and "
                         "diagnose the rest; a case folder without row.json was interrupted "
                         "and is diagnosed again from its start")
    args = ap.parse_args()
    cases_dir = args.cases_dir.resolve()
    names = chosen_cases(args.cases, cases_dir)
    if names is None:
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for i, name in enumerate(names, 1):
        d = out / name
        if args.collect:
            if (d / "row.json").exists():
                old = json.loads((d / "row.json").read_text())
                rows.append(score_case(name, d, old["wall_s"], old["status"], cases_dir))
            continue
        if args.resume and (d / "row.json").exists():
            old = json.loads((d / "row.json").read_text())
            rows.append(score_case(name, d, old["wall_s"], old["status"], cases_dir))
            print(f"[{i}/{len(names)}] {name}: diagnosed in an earlier sitting ({old['status']}, "
                  f"{old['wall_s']:.0f} s)", flush=True)
            continue
        if args.resume and d.exists():
            # interrupted mid-case: nothing of it was scored, so it starts again clean
            shutil.rmtree(d)
        d.mkdir(parents=True, exist_ok=True)
        truth = json.loads((cases_dir / name / "truth.json").read_text())
        print(f"[{i}/{len(names)}] {name}: {truth.get('shape', truth.get('family'))}, concealed "
              f"{'+'.join(truth['concealed']) or 'nothing'} ...", flush=True)
        cmd = ["nice"] + petsoft_command(args.np) + [
            "diagnose", str(cases_dir / name / "user.toml"),
            str(cases_dir / name / "recording.h5"), "--out", str(d.resolve())]
        wall, status = run_logged(cmd, d / "diagnose.log", cases_dir / name, args.timeout)
        row = score_case(name, d, wall, status, cases_dir)
        (d / "row.json").write_text(json.dumps(row, indent=1) + "\n")
        rows.append(row)
        print(f"    {row['verdict'] or status}; added {row['added']}; truth rank {row['rank']}; "
              f"held-out/noise {_f(row['heldout_over_noise'], '.2f')}; mesh check: "
              f"{row['mesh_check']}; {wall:.0f} s", flush=True)
    md = table_md(rows)
    (out / "table.md").write_text(md)
    (out / "table.json").write_text(json.dumps(rows, indent=1) + "\n")
    print("\n" + md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
