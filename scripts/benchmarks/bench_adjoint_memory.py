"""Peak memory and time of a long adjoint gradient, with and without binomial checkpointing.

What is measured
----------------
A linear-elastic bar (box ``--cells``, 0.3 x 0.04 x 0.04 m, default 40 x 5 x 6 cells: 5,166 dofs)
released from a bend, generalized-alpha (three vectors a state), ``--steps`` steps (default
10,000), 8 markers observed at 20 frames. Each mode runs in its own process (peak resident memory
is per process): ``store`` keeps all N + 1 states, ``checkpoint`` holds ``--snapshots`` of them
(default 100) and recomputes the rest on Griewank's binomial schedule. For each the table gives
the wall time of one forward run (``ForwardModel.simulate``) and of one adjoint gradient, their
ratio, the forward steps the sweep recomputed, the states held at the peak and their bytes
(``ForwardModel.stats["adjoint"]``), and the process's peak resident memory (``ru_maxrss``) after
the gradient minus before it (the model's own memory is the same in both).
The two gradients are compared (relative difference).

Run (about 4 minutes on a quiet 2-core machine; never while another MPI job runs)::

    .venv/bin/python scripts/benchmarks/bench_adjoint_memory.py
    .venv/bin/python scripts/benchmarks/bench_adjoint_memory.py --steps 500 --cells 10 2 2   # smoke
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

L = (0.3, 0.04, 0.04)


def _args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, nargs=3, default=[40, 5, 6])
    ap.add_argument("--steps", type=int, default=10_000)
    ap.add_argument("--step", type=float, default=2e-4, help="time step in s (default 2e-4)")
    ap.add_argument("--snapshots", type=int, default=100)
    ap.add_argument("--mode", choices=["store", "checkpoint"], help=argparse.SUPPRESS)
    return ap.parse_args(argv)


def run_mode(args) -> dict:
    """One mode in this process: timings, the sweep's statistics, the peak memory."""
    import numpy as np

    from petsoft.calibration.forward import ForwardModel
    from petsoft.calibration.observation import MarkerObserver
    from petsoft.experiment import experiment_from_dict

    exp = experiment_from_dict({
        "mesh": {"box": {"size": list(L), "cells": list(args.cells)}},
        "material": {"model": "linear", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "damping": {"mass": 0.5},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"displacement": ["0", "0", "0.5*x**2"]},
        "time": {"end": args.steps * args.step, "step": args.step, "integrator": "alpha"},
    }, source="bench_adjoint_memory")
    markers = np.array([[0.3, 0.0, 0.0], [0.3, 0.04, 0.04], [0.3, 0.02, 0.02], [0.2, 0.0, 0.02],
                        [0.15, 0.04, 0.02], [0.1, 0.02, 0.04], [0.05, 0.02, 0.0],
                        [0.25, 0.04, 0.0]])
    T = args.steps * args.step
    frames = np.linspace(T / 20, T, 20) - 0.37 * args.step
    frames[-1] = T
    snaps = 10**9 if args.mode == "store" else args.snapshots
    fm = ForwardModel(exp, ["material.youngs_modulus", "damping.mass"],
                      lambda s: MarkerObserver(s, markers), frames, checkpoints=snaps)
    t0 = time.perf_counter()
    sim = fm.simulate(fm.p0)
    forward = time.perf_counter() - t0
    target = sim + 1e-4 * np.random.default_rng(1).standard_normal(sim.shape)

    def dphi(x):
        r = x - target
        return 0.5 * float(np.sum(r * r)), r

    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    _, grad = fm.gradient(fm.p0, dphi)
    adjoint = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    stats = dict(fm.stats["adjoint"])
    fm.destroy()
    return {"mode": args.mode, "forward_s": forward, "adjoint_s": adjoint,
            "peak_rss_growth_mb": (after - before) / 1024.0, "gradient": grad.tolist(), **stats}


def main() -> None:
    args = _args()
    if args.mode:
        print(json.dumps(run_mode(args)))
        return
    dofs = 3 * (args.cells[0] + 1) * (args.cells[1] + 1) * (args.cells[2] + 1)
    print(f"adjoint of {args.steps} generalized-alpha steps, {dofs} dofs (incl. the clamped "
          f"ones), {args.snapshots} snapshots when checkpointing", flush=True)
    rows = []
    for mode in ("store", "checkpoint"):
        print(f"[progress] {mode}: one forward run, then one gradient ...", file=sys.stderr,
              flush=True)
        out = subprocess.run([sys.executable, __file__, "--mode", mode, "--cells",
                              *map(str, args.cells), "--steps", str(args.steps), "--step",
                              str(args.step), "--snapshots", str(args.snapshots)],
                             capture_output=True, text=True)
        if out.returncode:
            sys.exit(f"{mode} run failed:\n{out.stderr}")
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    print(f"{'mode':<11}{'forward s':>10}{'adjoint s':>10}{'adj/fwd':>8}{'recomputed':>11}"
          f"{'peak states':>12}{'states MB':>10}{'RSS growth MB':>14}")
    for r in rows:
        print(f"{r['mode']:<11}{r['forward_s']:>10.1f}{r['adjoint_s']:>10.1f}"
              f"{r['adjoint_s'] / r['forward_s']:>8.2f}{r['recomputed_steps']:>11}"
              f"{r['peak_states']:>12}{r['peak_bytes'] / 2**20:>10.1f}"
              f"{r['peak_rss_growth_mb']:>14.1f}")
    g0, g1 = (r["gradient"] for r in rows)
    diff = max(abs(a - b) / max(abs(a), 1e-300) for a, b in zip(g0, g1, strict=True))
    print(f"gradients agree to {diff:.1e} (relative, largest component)")


if __name__ == "__main__":
    main()
