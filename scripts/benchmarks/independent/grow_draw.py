#!/usr/bin/env python3
"""Make a split test draw's cases to the end by its stopping rule, in one of several processes.

A test draw generated over several sittings (README.md, "A test draw generated over several
sittings") grows its N until at least ``--written`` cases are written, with at least
``--controls`` controls and ``--off`` off-vocabulary effects among them: a rule that reads only
the generator's verdicts (truth.json / discarded.json on disk), never a diagnosis. This driver
runs one process's share of it: the indices ``i = K, K + S, K + 2S, ...`` (``--stride S
--offset K``), each by the rules commit's own ``draw_and_run.sh test-cases N OUT i`` (given
by ``--rules``, a worktree at the draw's commit), skipping the cases already made. When its
next index is at or past the protocol's N and the rule is not met by the cases finished so
far, it raises N by one block of eight (random_draw.PATTERN: every category keeps its share)
under a lock shared by the processes; when the rule is met it stops. Cases already inside N
are always made, so a draw stops with none pending.

    /usr/bin/python3 grow_draw.py --rules /work/rules3 --out random/test-233281001 \\
        --stride 2 --offset 0      # and --offset 1 in a second process
"""

from __future__ import annotations

import argparse
import fcntl
import json
import subprocess
import sys
import time
from pathlib import Path

BLOCK = 8


def case_state(cases: Path, name: str) -> str:
    """written, discarded or pending, from the files the generator leaves."""
    if (cases / name / "truth.json").exists():
        return "written"
    if (cases / name / "discarded.json").exists():
        return "discarded"
    return "pending"


def rule_met(cases: Path, draw: list[dict], need: dict) -> tuple[bool, dict]:
    """Whether the written cases among ``draw`` meet the stopping rule, and their counts."""
    written = [c for c in draw if case_state(cases, c["name"]) == "written"]
    count = {"written": len(written),
             "controls": sum(c["category"] == "control" for c in written),
             "off": sum(c["category"] == "off" for c in written)}
    return all(count[k] >= need[k] for k in need), count


def protocol_n(out: Path) -> int:
    return int(json.loads((out / "protocol.json").read_text())["N"])


def raise_n(out: Path, index: int, cases: Path, draw_of, need: dict) -> int | None:
    """Under the draw's lock: the N to generate ``index`` with, raised by a block when needed;
    None when the stopping rule is met and ``index`` lies outside N."""
    with open(out / ".grow.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        n = protocol_n(out)
        if index < n:
            return n
        met, count = rule_met(cases, draw_of(n), need)
        if met:
            print(f"[grow] stopping rule met at N {n}: {count}", flush=True)
            return None
        new = (index // BLOCK + 1) * BLOCK
        p = json.loads((out / "protocol.json").read_text())
        p["N"] = new
        tmp = out / ".protocol.json.tmp"
        tmp.write_text(json.dumps(p, indent=1))
        tmp.replace(out / "protocol.json")
        print(f"[grow] {count} at N {n}: N raised to {new}", flush=True)
        return new


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rules", type=Path, required=True,
                    help="a worktree at the draw's rules commit (its generator is used)")
    ap.add_argument("--out", type=Path, required=True, help="the draw's folder")
    ap.add_argument("--stride", type=int, default=2)
    ap.add_argument("--offset", type=int, default=0)
    ap.add_argument("--written", type=int, default=40)
    ap.add_argument("--controls", type=int, default=10)
    ap.add_argument("--off", type=int, default=6)
    a = ap.parse_args()
    out = a.out.resolve()
    cases = out / "cases"
    here = a.rules.resolve() / "scripts" / "benchmarks" / "independent"
    sys.path.insert(0, str(here))
    import random_draw as rd  # the rules commit's draw: names and categories

    p = json.loads((out / "protocol.json").read_text())
    need = {"written": a.written, "controls": a.controls, "off": a.off}
    index = a.offset
    while True:
        n = raise_n(out, index, cases, lambda m: rd.draw(p["seed"], m, p["size"]), need)
        if n is None:
            return 0
        name = rd.draw(p["seed"], index + 1, p["size"])[index]["name"]
        if case_state(cases, name) == "pending":
            for _attempt in range(5):
                # another process may raise N between our read and the script's check
                n = max(n, protocol_n(out))
                r = subprocess.run([str(here / "draw_and_run.sh"), "test-cases", str(n), str(out),
                                    str(index)])
                if r.returncode == 0:
                    break
                print(f"[grow] {name}: draw_and_run.sh exited {r.returncode}; again", flush=True)
                time.sleep(5)
            else:
                return 1
        index += a.stride


if __name__ == "__main__":
    sys.exit(main())
