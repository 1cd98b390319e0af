"""Synthetic recovery: calibrate a bar's E, nu, Rayleigh alpha and beta, and a 3-region E field.

The recording is made by ``petsoft synth`` on a 2x refined mesh with half the step and another
integrator (implicit midpoint; the calibration runs generalized-alpha), with 0.5 % noise
(of the largest marker motion), 20 markers on the surface and 10 % of the samples dropped:
no inverse crime. The calibration starts 15-50 % away from the truth.

The bar (0.2 x 0.04 x 0.04 m, linear elastic, 1000 kg/m^3) rests on symmetry rollers: x fixed on
x = 0, y on y = 0, z on z = 0, and vibrates axially from an initial displacement that mixes the
first two axial modes, with the lateral Poisson contraction of that strain (nu = 0.3, as observed
at t = 0). Without it the lateral field starts out of equilibrium and rings in breathing modes
near 400 Hz, which a 0.5 ms step cannot follow (generalized-alpha damps them, the fine midpoint
run keeps them), and the fit of nu absorbs that error (seen: nu 41 % off).

Why not a cantilever: P1 tetrahedra are stiff in bending and torsion (the first bending
frequency of a 20x4x4 Kuhn-split bar is 6 % above the 40x8x8 one), so a calibrated E would absorb
the discretisation error.

What sets the accuracy of alpha and beta is the discretisation error of the *third* axial mode
(about 115 Hz), which carries beta's signature: the calibrated E matches the first mode, and any
error in the ratio of the two frequencies becomes a phase drift of mode 3 that the fit partly
absorbs by damping it differently. Measured with noise-free recordings started at the truth
(so only the model's own error remains), at a light damping alpha = 2 1/s, beta = 2e-5 s
(damping ratios 0.65 % and 0.9 % in modes 1 and 3):

* same mesh and step, midpoint truth: alpha +0.3 %, beta -0.1 %;
* 2x mesh and h/2 (midpoint or generalized-alpha truth alike), 20x2x2 at h = 0.5 ms: nu -4.6 %,
  alpha -5.5 %, beta +7.3 %; 20x4x4: +2.8 % / +3.9 % for alpha / beta; 40x4x4: nu -5.3 %,
  beta +6.3 %. Two errors add up there: the step's (h against h/2 shifts mode 3 by about
  (omega h)^2 / 16 = 0.9 % at 0.5 ms, an estimate) and the section's (the mode-3 frequency of
  the 20x4x4 mesh is 0.44 % above the 40x8x8 one, 40x4x4 0.21 % above 80x8x8, computed with
  ``petsoft.solvers.modes``). Refining the mesh alone did not help (40x4x4 above).

So the bar is damped like the soft solid it is (alpha = 20 1/s, beta = 2e-4 s: damping ratios
6.5 % and 8.8 % in modes 1 and 3, so mode 3 decays before its phase drifts far) and is calibrated
on 40x4x4 at h = 0.25 ms. Noise-free, that leaves E +0.04 %, nu +1.1 %, alpha -0.65 %,
beta +1.3 % (20x4x4 at 0.25 ms: nu +3.5 %; 20x4x4 at 0.5 ms: beta +2.2 %). With the recording's
noise (0.5 %, 20 markers, 10 % dropped): E +0.05 %, nu +1.1 %, alpha -1.0 %, beta +1.5 %, with
2 std of 0.25 % (so the rest is the model's discretisation error), rms after = 1.01 x the noise.
``--damping 0.1`` runs the lightly damped bar on the same model: alpha -6.9 %, beta +5.4 %,
nu -1.7 % (rms after 2x the noise), the 2 % target missed for the reason above.
That mismatch is also what `petsoft diagnose` must attribute to numerics, not physics.

Run::

    python scripts/examples/demo_calibrate_bar.py --out bar-calibration
    mpiexec -n 2 python scripts/examples/demo_calibrate_bar.py --out bar-calibration

Things to try: ``--method lbfgs``; ``--cells 40`` (finer calibration mesh); ``--quick`` (tiny,
for the test suite; no accuracy claim); PETSc options for the forward solves, e.g.
``-fm_ksp_type cg -fm_pc_type gamg``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

BASE = """
[mesh]
box = {{ size = [0.2, 0.04, 0.04], cells = [{nx}, {ny}, {ny}] }}

[material]
model = "linear"
youngs_modulus = {E}
poisson_ratio = {nu}
density = 1000.0
{regions}
[damping]
mass = {alpha}
stiffness = {beta}

[[boundary]]
kind = "fixed"
where = "x < 1e-9"
components = ["x"]

[[boundary]]
kind = "fixed"
where = "y < 1e-9"
components = ["y"]

[[boundary]]
kind = "fixed"
where = "z < 1e-9"
components = ["z"]

[initial]
displacement = ["0.002*sin(pi*x/0.4) + 0.002*sin(3*pi*x/0.4)",
                "-0.3*y*(0.002*pi/0.4*cos(pi*x/0.4) + 0.006*pi/0.4*cos(3*pi*x/0.4))",
                "-0.3*z*(0.002*pi/0.4*cos(pi*x/0.4) + 0.006*pi/0.4*cos(3*pi*x/0.4))"]

[time]
end = {end}
step = {step}
integrator = "alpha"
alpha_radius = 0.9

[petsc]
ksp_type = "preonly"
pc_type = "cholesky"
{calibrate}
"""

CASES = {
    "bar": {
        "truth": {"material.youngs_modulus": 1.0e6, "material.poisson_ratio": 0.30,
                  "damping.mass": 20.0, "damping.stiffness": 2.0e-4},
        "start": {"material.youngs_modulus": 1.2e6, "material.poisson_ratio": 0.25,
                  "damping.mass": 10.0, "damping.stiffness": 3.0e-4},
        "bounds": {"material.youngs_modulus": (1.0e5, 1.0e7),
                   "material.poisson_ratio": (0.05, 0.45),
                   "damping.mass": (0.0, 200.0), "damping.stiffness": (0.0, 1.0e-2)},
        "target": 0.02,
    },
    "regions": {
        "truth": {"material.a.youngs_modulus": 0.8e6, "material.b.youngs_modulus": 1.2e6,
                  "material.c.youngs_modulus": 1.0e6},
        "start": {"material.a.youngs_modulus": 1.0e6, "material.b.youngs_modulus": 1.0e6,
                  "material.c.youngs_modulus": 1.0e6},
        "bounds": {k: (1.0e5, 1.0e7) for k in ("material.a.youngs_modulus",
                                              "material.b.youngs_modulus",
                                              "material.c.youngs_modulus")},
        "target": 0.05,
    },
}

REGIONS = """
[region.a]
where = "x < 0.2/3"
[region.b]
where = "x > 0.2/3 and x < 0.4/3"
[region.c]
where = "x > 0.4/3"
{materials}
"""


def scaled_damping(case: dict, factor: float) -> dict:
    """The case with its Rayleigh alpha and beta (truth, start and upper bound) times factor."""
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in case.items()}
    for key in ("damping.mass", "damping.stiffness"):
        if key in out["truth"]:
            out["truth"][key] *= factor
            out["start"][key] *= factor
            lo, hi = out["bounds"][key]
            out["bounds"][key] = (lo, hi * max(factor, 1.0))
    return out


def experiment_text(case: dict, values: dict, nx: int, ny: int, end: float, step: float,
                    calibrate: bool) -> str:
    regions = ""
    v = {"E": 1.0e6, "nu": 0.3, "alpha": 2.0, "beta": 2.0e-5}
    names = {"material.youngs_modulus": "E", "material.poisson_ratio": "nu",
             "damping.mass": "alpha", "damping.stiffness": "beta"}
    materials = []
    for key, value in values.items():
        if key in names:
            v[names[key]] = value
        else:
            region = key.split(".")[1]
            materials.append(f"[material.{region}]\nyoungs_modulus = {value!r}\n")
    if materials:
        regions = REGIONS.format(materials="\n".join(materials))
    cal = ""
    if calibrate:
        cal = "[calibrate]\n" + "".join(f'"{k}" = [{lo!r}, {hi!r}]\n'
                                        for k, (lo, hi) in case["bounds"].items())
    return BASE.format(nx=nx, ny=ny, end=end, step=step, regions=regions, calibrate=cal,
                       E=v["E"], nu=v["nu"], alpha=v["alpha"], beta=v["beta"])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="bar-calibration")
    p.add_argument("--cases", default="bar,regions")
    p.add_argument("--cells", type=int, default=40, help="cells along the bar (calibration)")
    p.add_argument("--section", type=int, default=4,
                   help="cells across the section (each direction) of the calibration mesh")
    p.add_argument("--step", type=float, default=0.00025,
                   help="calibration time step (s); the recording uses step/2")
    p.add_argument("--damping", type=float, default=1.0,
                   help="factor on the bar's true and starting Rayleigh alpha and beta")
    p.add_argument("--method", default="gauss-newton")
    p.add_argument("--quick", action="store_true", help="tiny and short (smoke test only)")
    args, petsc_args = p.parse_known_args(argv)
    import petsc4py

    import petsoft  # noqa: F401  before petsc4py.init: one BLAS thread (petsoft/__init__.py)

    petsc4py.init([sys.argv[0], *petsc_args])
    from mpi4py import MPI
    from petsc4py import PETSc

    from petsoft.calibration.calibrate import run_calibration
    from petsoft.calibration.synth import SynthOptions, synth
    from petsoft.experiment import load_experiment
    from petsoft.io.recording import read_recording

    comm = MPI.COMM_WORLD
    rank0 = comm.rank == 0

    def say(line):
        if rank0:
            print(line, flush=True)

    out = Path(args.out)
    nx, ny = (6, 1) if args.quick else (args.cells, args.section)
    end, step = (0.02, 0.001) if args.quick else (0.1, args.step)
    markers = 6 if args.quick else 20
    table = []
    for name in args.cases.split(","):
        case = scaled_damping(CASES[name], args.damping)
        d = out / name
        if rank0:
            d.mkdir(parents=True, exist_ok=True)
            (d / "truth.toml").write_text(experiment_text(case, case["truth"], nx, ny, end, step,
                                                          False))
            (d / "start.toml").write_text(experiment_text(case, case["start"], nx, ny, end, step,
                                                          True))
        comm.Barrier()
        # the clean amplitude sets the 0.5 % noise: a noise-free run first (cheap, unrefined)
        synth(load_experiment(d / "truth.toml"), SynthOptions(out=d / "clean.h5", noise=0.0,
                                                              markers=markers, dropout=0.0,
                                                              refine=1, seed=11))
        clean = read_recording(d / "clean.h5")
        motion = float(np.max(np.abs(clean.positions - clean.reference[None])))
        noise = 0.005 * motion
        say(f"== {name}: largest marker motion {motion:.3g} m, noise {noise:.3g} m (0.5 %)")
        synth(load_experiment(d / "truth.toml"), SynthOptions(out=d / "recording.h5", noise=noise,
                                                              markers=markers, dropout=0.1,
                                                              refine=2, integrator="midpoint",
                                                              seed=11))
        exp = load_experiment(d / "start.toml")
        res = run_calibration(exp, d / "recording.h5", method=args.method,
                              out=d / "calibrated", say=say)
        for n, v, s in zip(res.names, res.values, res.std, strict=True):
            true = case["truth"][n]
            table.append({"case": name, "parameter": n, "truth": true, "start": case["start"][n],
                          "calibrated": float(v), "std": float(s),
                          "error": float(v / true - 1.0), "target": case["target"],
                          "rms_after": res.rms_after, "noise": noise})
        PETSc.garbage_cleanup()
    say(f"\n{'case':<8} {'parameter':<28} {'truth':>10} {'start':>10} {'calibrated':>12} "
        f"{'error':>8} {'2 std':>8} {'target':>7}")
    ok = True
    for row in table:
        good = abs(row["error"]) <= row["target"]
        ok &= good
        say(f"{row['case']:<8} {row['parameter']:<28} {row['truth']:>10.4g} {row['start']:>10.4g} "
            f"{row['calibrated']:>12.6g} {row['error']:>8.2%} "
            f"{2 * row['std'] / abs(row['truth']):>8.2%} {row['target']:>7.0%}"
            f"{'' if good else '  MISSED'}")
    if rank0:
        (out / "recovery.json").write_text(json.dumps(table, indent=2) + "\n")
    say(f"all within target: {ok}" + ("" if not args.quick else " (--quick: no accuracy claim)"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
