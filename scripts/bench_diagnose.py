"""Concealed-effect benchmark of ``petsoft diagnose`` (issue 6; a first skeleton).

Each case: ``petsoft synth`` makes a recording from a *truth* experiment on a refined mesh
(``--refine 2``: 2x cells, step/2) with noise, 8 markers and 10 % dropped samples; ``diagnose``
then starts from the *user's* model (the truth without the effect, E off by 10 %, calibrating E
only). Cases so far: mass damping, stiffness damping, missing gravity (the bar is started with a
velocity), a stiff inclusion near the clamp (material.heterogeneous) and a control with nothing
missing. Printed per case: true effect, named effect(s), rank of the truth in the first round's
score ranking, localisation error (spatial cases), rms before/after on the held-out window (and
over the noise), relative error of the effect's parameter, runtime.

Not yet: one case per vocabulary term (most terms are not modelled), combined effects, a second
control, other integrators in synth. Usage::

    .venv/bin/python scripts/bench_diagnose.py --dir out/bench_diagnose [--cases damping,control]
    mpiexec -n 2 .venv/bin/python scripts/bench_diagnose.py --dir out/bench_diagnose
"""

from __future__ import annotations

import argparse
import time
from argparse import Namespace
from pathlib import Path

import numpy as np
from mpi4py import MPI

MODEL = """
[mesh]
box = {{ size = [0.3, 0.04, 0.04], cells = [6, 1, 1] }}

[material]
model = "linear"
youngs_modulus = {E}
poisson_ratio = 0.3
density = 1000.0
{region}
[damping]
mass = {alpha}
stiffness = {beta}

[gravity]
acceleration = [0.0, 0.0, {g}]

[initial]
velocity = ["0", "0", "{v}"]

[[boundary]]
kind = "fixed"
where = "x < 1e-9"

[time]
end = 0.2
step = 0.004
integrator = "alpha"
alpha_radius = 0.9

[output]
directory = "out"
{calibrate}
"""
E_TRUE, NOISE = 2.0e7, 5e-5
INCLUSION = {"center": [0.075, 0.02, 0.02], "radius": 0.05}

#: case -> (truth overrides, user overrides, true physics, (parameter, true value) or None)
CASES = {
    "damping": (dict(alpha=4.0), {}, "damping.mass", ("damping.mass", 4.0)),
    "stiffness-damping": (dict(beta=2e-4), {}, "damping.stiffness",
                          ("damping.stiffness", 2e-4)),
    "gravity": (dict(g=-9.81, v="2*x"), dict(g=0.0, v="2*x"), "gravity",
                ("gravity.acceleration.z", -9.81)),
    "inclusion": (dict(region=True), {}, "material.heterogeneous", None),
    "control": ({}, {}, None, None),
}


def _model(alpha=0.0, beta=0.0, g=-9.81, v="0", region=False, E=E_TRUE, calibrate=""):
    reg = ""
    if region:
        c, r = INCLUSION["center"], INCLUSION["radius"]
        reg = (f'\n[region.inclusion]\nwhere = "(x - {c[0]})**2 + (y - {c[1]})**2 + '
               f'(z - {c[2]})**2 < {r}**2"\n\n[material.inclusion]\nyoungs_modulus = '
               f"{2 * E_TRUE}\n")
    return MODEL.format(alpha=alpha, beta=beta, g=g, v=v, region=reg, E=E, calibrate=calibrate)


def run_case(name: str, folder: Path, comm) -> dict:
    from petsoft.diagnosis.diagnose import run_diagnose
    from petsoft.experiment import load_experiment
    from petsoft.synth import run_synth

    truth_kw, user_kw, physics, param = CASES[name]
    d = folder / name
    if comm.rank == 0:
        d.mkdir(parents=True, exist_ok=True)
        (d / "truth.toml").write_text(_model(**truth_kw))
        (d / "user.toml").write_text(_model(**{**user_kw, "E": 0.9 * E_TRUE,
                                               "calibrate": '[calibrate]\n"material.youngs_'
                                                            'modulus" = [1e6, 1e8]\n'}))
    comm.Barrier()
    run_synth(Namespace(experiment=str(d / "truth.toml"), out=str(d / "rec.h5"), noise=NOISE,
                        markers=8, markers_file=None, dropout=0.1, refine=2, integrator=None,
                        seed=11))
    comm.Barrier()
    t0 = time.perf_counter()
    res = run_diagnose(load_experiment(d / "user.toml"), d / "rec.h5", out=d / "diagnose")
    wall = time.perf_counter() - t0
    first = sorted([s for s in res.scores if s["round"] == 1], key=lambda s: s["log10_p"])
    ranking = [s["physics"] for s in first]
    rank = ranking.index(physics) + 1 if physics in ranking else None
    loc = None
    for a in res.added:
        if a["physics"] == physics and a.get("region"):
            loc = float(np.linalg.norm(np.subtract(a["region"]["center"], INCLUSION["center"])))
    perr = None
    if param is not None and param[0] in res.final.names:
        value = res.final.values[res.final.names.index(param[0])]
        perr = abs(value - param[1]) / abs(param[1])
    val = res.report["fit"].get("validation", {})
    return {"case": name, "truth": physics or "-",
            "named": ",".join(a["physics"] for a in res.added) or "-",
            "rank": rank, "loc_err": loc, "rms_before": val.get("base_rms"),
            "rms_after": val.get("final_rms"), "param_err": perr, "wall": wall}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", default="out/bench_diagnose")
    ap.add_argument("--cases", default=",".join(CASES),
                    help=f"comma-separated subset of {', '.join(CASES)}")
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    rows = [run_case(c, Path(args.dir), comm) for c in args.cases.split(",")]
    if comm.rank == 0:
        def f(x, fmt):
            return "-" if x is None else format(x, fmt)

        print(f"\n{comm.size} rank(s); noise {NOISE:g} m; rms on the held-out 30 % of the record")
        print(f"{'case':<18} {'true':<24} {'named':<30} {'rank':>4} {'loc.err':>8} "
              f"{'rms before':>10} {'after':>9} {'after/noise':>11} {'par.err':>8} {'wall s':>7}")
        for r in rows:
            print(f"{r['case']:<18} {r['truth']:<24} {r['named']:<30} {f(r['rank'], 'd'):>4} "
                  f"{f(r['loc_err'], '.3g'):>8} {f(r['rms_before'], '.3g'):>10} "
                  f"{f(r['rms_after'], '.3g'):>9} "
                  f"{f(r['rms_after'] / NOISE if r['rms_after'] else None, '.3g'):>11} "
                  f"{f(r['param_err'], '.2%'):>8} {r['wall']:>7.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
