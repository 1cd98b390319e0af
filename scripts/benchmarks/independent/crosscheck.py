"""Cross-check a control's DOLFINx recording against petsoft itself, with no fitting.

For a case with nothing concealed the user's model at the *true* parameters should reproduce the
recording up to the noise once petsoft's discretisation is fine enough. This simulates the case's
``user.toml`` with the true Young's modulus (from ``truth.json``) through ``petsoft synth`` with
``--refine K`` (file mesh 1 -> 8 subdivided log2 K times, step / K, no noise) at the recording's
markers, and prints the rms of (recording - simulation) over the noise for K = 1 and the K given::

    .venv/bin/python scripts/benchmarks/independent/crosscheck.py control-finger [--refine 2] \
        [--order 2]

A ratio near 1 at the finest K says the two independent codes agree (the DOLFINx truth is what
petsoft's model converges to); the ratio at K = 1 is the user's mesh's own error at the true E.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from petsoft.calibration.synth import SynthOptions, synth
from petsoft.experiment import experiment_from_dict, load_experiment
from petsoft.io.recording import read_recording

HERE = Path(__file__).resolve().parent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case")
    ap.add_argument("--refine", type=int, default=2)
    ap.add_argument("--order", type=int, default=1, choices=(1, 2),
                    help="element order of the user's model (2: 10-node tetrahedra)")
    args = ap.parse_args()
    d = HERE / "cases" / args.case
    truth = json.loads((d / "truth.json").read_text())
    if truth["concealed"]:
        print(f"{args.case} conceals {truth['concealed']}: cross-check the controls only")
        return 2
    rec = read_recording(d / "recording.h5")
    exp = load_experiment(d / "user.toml")
    data = exp.to_dict()
    data["material"]["youngs_modulus"] = truth["truth"]["youngs_modulus"]
    data["mesh"]["order"] = args.order
    data.pop("calibrate", None)
    exp = experiment_from_dict(data, source=exp.source, base_dir=exp.base_dir, path=exp.path)
    noise = truth["noise"]["position_std"]
    with tempfile.TemporaryDirectory() as tmp:
        mfile = Path(tmp) / "markers.txt"
        np.savetxt(mfile, rec.reference)
        for K in sorted({1, args.refine}):
            out = Path(tmp) / f"k{K}" / "sim.h5"
            synth(exp, SynthOptions(out=out, markers_file=mfile, refine=K), say=lambda s: None)
            sim = read_recording(out)
            diff = rec.positions - sim.positions
            rms = float(np.sqrt(np.nanmean(diff ** 2)))
            print(f"{args.case}: petsoft (P{args.order}, refine {K}, step "
                  f"{exp.time.step / K:g} s, true E) vs the DOLFINx recording: rms {rms:.3g} m "
                  f"= {rms / noise:.2f} x noise",
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
