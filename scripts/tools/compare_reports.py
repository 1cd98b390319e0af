"""Compare two diagnosis reports (report.json): did two runs reach the same conclusion?

Prints, side by side, the verdicts, the physics added and rejected, and every number of the
reports' ``added`` parameters, final ``parameters`` and ``fit`` (rms and chi2 per dof of the base
and final fits, and of the held-out window) with their relative difference; the last line says
whether the two agree to ``--rtol``. Used to check that a refactor changed nothing (issue 18:
the demo's report and the bench_diagnose control and damping cases before and after).

Run::

    .venv/bin/python scripts/tools/compare_reports.py old/report.json new/report.json
    .venv/bin/python scripts/tools/compare_reports.py a.json b.json --rtol 1e-8   # exit 1 if not
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def summary(report: dict) -> tuple[dict, dict]:
    """(names: verdict, added, rejected), (numbers by a dotted label)."""
    names = {"verdict": report["verdict"],
             "added": [a["physics"] for a in report["added"]],
             "rejected": sorted(r["physics"] if isinstance(r, dict) else str(r)
                                for r in report.get("rejected", []))}
    numbers = {}
    for a in report["added"]:
        for k, v in a["parameters"].items():
            numbers[f"added:{k}"] = v
    for stage, values in report.get("fit", {}).items():
        for k, v in (values or {}).items():
            if isinstance(v, (int, float)):
                numbers[f"fit:{stage}.{k}"] = v
    for k, v in report.get("parameters", {}).items():
        if isinstance(v, (int, float)):
            numbers[f"final:{k}"] = v
    return names, numbers


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("first", type=Path)
    ap.add_argument("second", type=Path)
    ap.add_argument("--rtol", type=float, default=1e-8,
                    help="largest relative difference of a number that counts as equal")
    args = ap.parse_args(argv)
    (na, xa), (nb, xb) = (summary(json.loads(p.read_text())) for p in (args.first, args.second))
    same = True
    for key in na:
        agree = na[key] == nb[key]
        same &= agree
        print(f"{key:9s} {'same' if agree else 'DIFFERENT'}: {na[key]} | {nb[key]}")
    worst = 0.0
    for key in sorted(set(xa) | set(xb)):
        if key not in xa or key not in xb:
            print(f"  {key}: in one report only")
            same = False
            continue
        rel = abs(xa[key] - xb[key]) / max(abs(xa[key]), 1e-300)
        worst = max(worst, rel)
        print(f"  {key:40s} {xa[key]:<22.15g} {xb[key]:<22.15g} rel {rel:.1e}")
    equal = same and worst <= args.rtol
    print(f"largest relative difference {worst:.1e}: "
          f"{'the same' if equal else 'NOT the same'} to {args.rtol:g}")
    return 0 if equal else 1


if __name__ == "__main__":
    sys.exit(main())
