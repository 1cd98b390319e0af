#!/usr/bin/env python3
"""Make a split test draw's cases to the end by its stopping rule, in one of several processes.

A test draw generated over several sittings (README.md, "A test draw generated over several
sittings") grows its N until at least ``--written`` cases are written, with at least
``--controls`` controls and ``--off`` off-vocabulary effects among them: a rule that reads only
the generator's verdicts (truth.json / discarded.json on disk), never a diagnosis. Each process
running this driver takes, under a lock the processes share, the lowest index below N that is
neither made nor being made (by another driver's claim, or by a generate.py process still
running from an earlier sitting), and makes it by the rules commit's own ``draw_and_run.sh
test-cases N OUT i`` (``--rules``: a worktree at the draw's commit). When no such index is left
and the rule is not met by the cases finished so far, it raises N by one block of eight
(random_draw.PATTERN: every category keeps its share); when the rule is met it stops once
nothing below N is left to make. A shared queue, not a fixed split of the indices: the
categories sit at fixed positions of a block (the controls at even ones), so a split by parity
let one process run far ahead on the other's categories.

    /usr/bin/python3 grow_draw.py --rules /work/rules3 --out random/test-233281001   # twice
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
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


def running_indices(out: Path) -> set[int]:
    """Indices a generate.py process is making for this draw now (``--only i --out OUT/cases``),
    whoever started it: a driver of this sitting or one cut off in an earlier one."""
    found = set()
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            argv = (Path("/proc") / pid / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        args = [a.decode(errors="replace") for a in argv]
        if any(a.endswith("generate.py") for a in args) and "--only" in args and "--out" in args:
            if Path(args[args.index("--out") + 1]).resolve() == (out / "cases").resolve():
                found.update(int(i) for i in args[args.index("--only") + 1].split(","))
    return found


def claim(out: Path, cases: Path, draw_of, need: dict,
          max_running: int) -> tuple[int, int] | None:
    """Under the draw's lock: the next index to make and the N to make it with (N raised by a
    block when nothing below it is left and the rule is not met), claimed for this process;
    None when nothing is left to make and the rule is met; ``(-1, N)`` to wait: ``max_running``
    cases are being made, or cases inside N still are and may meet the rule."""
    with open(out / ".grow.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        claims_path = out / ".grow.claims.json"
        claims = json.loads(claims_path.read_text()) if claims_path.exists() else {}
        live = {int(i) for i, pid in claims.items() if Path(f"/proc/{pid}").exists()}
        busy = live | running_indices(out)
        while True:
            n = protocol_n(out)
            draw = draw_of(max(n, max(busy, default=-1) + 1))
            making = {c["index"] for c in draw if c["index"] in busy
                      and case_state(cases, c["name"]) == "pending"}
            if len(making) >= max_running:      # e.g. cases left running by an earlier sitting
                return -1, n
            draw = draw[:n]
            todo = [c["index"] for c in draw if case_state(cases, c["name"]) == "pending"
                    and c["index"] not in busy]
            if todo:
                claims = {str(i): claims[str(i)] for i in map(str, live) if str(i) in claims}
                claims[str(todo[0])] = os.getpid()
                claims_path.write_text(json.dumps(claims))
                return todo[0], n
            met, count = rule_met(cases, draw, need)
            if met or making & set(range(n)):
                # the rule is met, or cases inside N are still being made: raise N only once
                # they are finished (they may meet the rule)
                if met:
                    print(f"[grow] stopping rule met at N {n}: {count}", flush=True)
                return None if met else (-1, n)
            p = json.loads((out / "protocol.json").read_text())
            p["N"] = n + BLOCK
            tmp = out / ".protocol.json.tmp"
            tmp.write_text(json.dumps(p, indent=1))
            tmp.replace(out / "protocol.json")
            print(f"[grow] {count} at N {n}: N raised to {n + BLOCK}", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rules", type=Path, required=True,
                    help="a worktree at the draw's rules commit (its generator is used)")
    ap.add_argument("--out", type=Path, required=True, help="the draw's folder")
    ap.add_argument("--written", type=int, default=40)
    ap.add_argument("--controls", type=int, default=10)
    ap.add_argument("--off", type=int, default=6)
    ap.add_argument("--max-running", type=int, default=2,
                    help="cases made at once by all the processes (the machine's cores)")
    a = ap.parse_args()
    out = a.out.resolve()
    cases = out / "cases"
    here = a.rules.resolve() / "scripts" / "benchmarks" / "independent"
    sys.path.insert(0, str(here))
    import random_draw as rd  # the rules commit's draw: names and categories

    p = json.loads((out / "protocol.json").read_text())
    need = {"written": a.written, "controls": a.controls, "off": a.off}
    while True:
        got = claim(out, cases, lambda m: rd.draw(p["seed"], m, p["size"]), need,
                    a.max_running)
        if got is None:
            return 0
        index, n = got
        if index < 0:           # wait for the cases being made before raising N
            time.sleep(30)
            continue
        name = rd.draw(p["seed"], index + 1, p["size"])[index]["name"]
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

if __name__ == "__main__":
    sys.exit(main())
