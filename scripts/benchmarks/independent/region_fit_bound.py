"""How well can a sphere of added mass fit the independent ``added-mass`` case on the user's mesh?

``petsoft diagnose`` places a spatial candidate's sphere (``mass.added``,
``material.heterogeneous``) where the adjoint map of d misfit / d density (or E) points; up to
da5d4c6 it fitted only its value (since then it fits the sphere too, by a cheaper search:
``petsoft/diagnosis/geometry.py``; this script stays as the bound by a full calibration at every
point). On the independent ``added-mass`` case (the bracket, 513 user tets raised
to 10 nodes; the truth a sphere of 4x density, cells by centroid, on DOLFINx's fine mesh) that
leaves the held-out window at 1.55x the noise, over issue 14's 1.5x. This script asks what
fitting the sphere's *geometry* would give: Nelder-Mead over its centre and radius (cells by
centroid, as petsoft's regions), each point a full Gauss-Newton calibration of E, the sphere's
density and the three gravity components (the terms diagnose's final model has), from the user's
experiment in ``cases/added-mass/user.toml`` raised to 10 nodes, starting from diagnose's final
values. It prints every evaluation (chi2 on the identification window, held-out rms / noise) and
the best point.

Measured at 99d4f12 (60 evaluations, 1802 s on one core beside the test suite): from diagnose's
placement (centre (0.1585, 0.0215, 0.176), r 0.0339: chi2 9854.2, held-out 1.547x the noise, as
diagnose's report) to centre (0.1439, 0.0119, 0.1541), r 0.0495: chi2 7220.9, held-out
**1.30x**, E 20.36 MPa, sphere density 3711 kg/m^3. The truth's own sphere ((0.14, 0.02, 0.18),
r 0.03) with E and density fitted gives 1.94x on this mesh: the fitted sphere, larger and lower,
makes up for how a sphere sits on 513 cells. Radius alone (r 0.0389 at diagnose's centre, an
earlier copy started from E 20 MPa): 1.50x.

Run (the .venv python; minutes per ten evaluations)::

    .venv/bin/python scripts/benchmarks/independent/region_fit_bound.py [--evaluations 60]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from petsoft.api import load_experiment
from petsoft.diagnosis.context import Diagnosis
from petsoft.experiment import experiment_from_dict

CASE = Path(__file__).resolve().parent / "cases" / "added-mass"
#: diagnose's placement at 302bf23 .. 183ce84 (its report's diagnosed.toml) ...
START = (0.1585, 0.0215, 0.176, 0.0339)
#: ... and its final fit there, where each calibration starts (from the user's E, 14 MPa,
#: Gauss-Newton went to E 31 MPa, chi2 58248)
FITTED = {"youngs_modulus": 20446380.0, "density": 4466.85,
          "gravity": [-0.0617, 0.0857, -10.005]}
GRAVITY_BOUNDS = {"gravity.acceleration.x": [-20.0, 20.0],
                  "gravity.acceleration.y": [-20.0, 20.0],
                  "gravity.acceleration.z": [-29.81, 10.19]}


def experiment_with_sphere(base: dict, centre, radius: float):
    """The user's experiment with a sphere region ``sphere`` of its own density, E, the
    density and gravity to calibrate."""
    d = dict(base)
    cx, cy, cz = (float(c) for c in centre)
    d["region"] = {"sphere": {"where": f"(x-({cx}))**2+(y-({cy}))**2+(z-({cz}))**2 "
                                       f"< ({float(radius)})**2"}}
    d["material"] = {**base["material"], "youngs_modulus": FITTED["youngs_modulus"],
                     "sphere": {"density": FITTED["density"]}}
    d["gravity"] = {"acceleration": list(FITTED["gravity"])}
    d["calibrate"] = {"material.youngs_modulus": [2.0e6, 2.0e8],
                      "material.sphere.density": [1000.0, 40000.0], **GRAVITY_BOUNDS}
    return experiment_from_dict(d, source="region_fit_bound")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--evaluations", type=int, default=60)
    args = parser.parse_args()
    base = load_experiment(CASE / "user.toml").to_dict()
    base["mesh"]["order"] = 2               # diagnose raises the user's mesh to 10 nodes
    recording = str(CASE / "recording.h5")
    first = experiment_with_sphere(base, START[:3], START[3])
    diag = Diagnosis(first, recording, fraction=0.7, alpha=0.01, method="gauss-newton",
                     gradient="adjoint", integrator=None, noise=None, comm=None,
                     say=lambda *a: None)
    best = {"chi2": np.inf}
    t0 = time.time()

    def objective(x: np.ndarray) -> float:
        centre, radius = x[:3], abs(x[3])
        fit = diag.calibrate(experiment_with_sphere(base, centre, radius))
        held = fit.heldout_rms / diag.sigma
        if fit.chi2 < best["chi2"]:
            best.update(chi2=fit.chi2, x=x.copy(), held=held,
                        values=dict(zip(fit.names, fit.values, strict=True)))
        print(f"{time.time() - t0:6.0f} s  centre {np.round(centre, 4)}  r {radius:.4f}  "
              f"chi2 {fit.chi2:.1f}  held-out / noise {held:.3f}", flush=True)
        return fit.chi2

    x0 = np.array(START)
    simplex = x0 + np.vstack([np.zeros(4), np.diag([0.01, 0.01, 0.01, 0.005])])
    minimize(objective, x0, method="Nelder-Mead",
             options={"maxfev": args.evaluations, "initial_simplex": simplex})
    print(f"best: centre {np.round(best['x'][:3], 4)} r {abs(best['x'][3]):.4f} chi2 "
          f"{best['chi2']:.1f} held-out / noise {best['held']:.3f} {best['values']}")


if __name__ == "__main__":
    main()
