"""The realistic payload's E-density valley: why the added mass's sphere search stops at the tip.

Prints, for the payload case (``cases/payload``: a 711-tet taper, 10-node elements, 2 ms, the
identification window of ``petsoft diagnose``):

1. the misfit and the first natural frequency along the straight line in (E, density) between
   two points at the truth's sphere (centre x = 0.24 m, r = 30 mm): a start that keeps the
   frequency the search's sphere had, and the end of a calibration at that sphere. A constant
   frequency along the line says the valley is straight in (E, rho) (E ~ m_rest + Q rho), which
   the calibration's log-scaled steps cut across;
2. with ``--calibrate``, the calibrations of (E, density) at the truth's sphere from the truth
   and from that start, and at the sphere the search ended at (diagnose at 36ac3b8: centre
   (0.2785, -0.0003, -0.0135), r 38 mm) from its values: chi2 and held-out rms of each.

Run from the project root on one rank (about 45 s; ``--calibrate`` about 15 minutes)::

    .venv/bin/python scripts/benchmarks/realistic/payload_valley.py [--calibrate]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import tomllib
from petsc4py import PETSc

from petsoft.diagnosis.candidates import sphere_condition
from petsoft.diagnosis.context import Diagnosis, chi2
from petsoft.dynamics.system import DynamicSystem
from petsoft.experiment.reader import experiment_from_dict
from petsoft.io.recording import read_recording
from petsoft.physics.model import build_model
from petsoft.solvers.modes import compute_modes

CASE = Path(__file__).resolve().parent / "cases" / "payload"
TRUTH_SPHERE = ([0.24, 0.0, 0.0], 0.03)
SEARCH_SPHERE = ([0.2785, -0.0003, -0.0135], 0.03795)
#: the line's ends (E Pa, density kg/m^3): the search's values with the density rescaled to
#: keep the two lowest modes' modal mass at the truth's sphere, and the calibration's end there
VALLEY = (np.array([1.264e7, 2029.17]), np.array([1.94777e7, 3892.87]))


def experiment(center, radius, E: float, rho: float):
    """The user's payload model, 10-node elements, with a heavier sphere ``diag_mass``."""
    data = tomllib.loads((CASE / "user.toml").read_text())
    data["mesh"]["file"] = str((CASE / data["mesh"]["file"]).resolve())
    data["mesh"]["order"] = 2
    data["material"]["youngs_modulus"] = float(E)
    data["material"]["diag_mass"] = {"density": float(rho)}
    data["region"] = {"diag_mass": {"where": sphere_condition(center, radius)}}
    data["calibrate"]["material.diag_mass.density"] = [1000.0, 1e6]
    return experiment_from_dict(data, source="payload_valley")


def first_frequency(exp) -> float:
    """The lowest elastic natural frequency (Hz) of ``exp``'s model at rest."""
    system = DynamicSystem(build_model(exp, PETSc.COMM_SELF), 0.0, 0.0)
    res = compute_modes(system.model, 2)
    try:
        return float(res.frequencies_hz[res.rigid_modes])
    finally:
        res.destroy()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calibrate", action="store_true",
                    help="also calibrate (E, density) at the two spheres (about 15 minutes)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()

    def say(line: str) -> None:
        print(f"[{time.perf_counter() - t0:7.1f} s] {line}", flush=True)

    diag = Diagnosis(experiment(*TRUTH_SPHERE, *VALLEY[1]), read_recording(CASE / "recording.h5"),
                     fraction=0.7, alpha=0.01, method="gauss-newton", gradient="sensitivity",
                     integrator=None, noise=None, comm=PETSc.COMM_SELF, say=None)
    print("| s | E (Pa) | density (kg/m^3) | f1 (Hz) | chi2 |\n|---:|---:|---:|---:|---:|")
    a, b = VALLEY
    for s in np.linspace(0.0, 1.2, 7):
        E, rho = a + s * (b - a)
        exp = experiment(*TRUTH_SPHERE, E, rho)
        sim = diag.simulate_identification(exp, comm=PETSc.COMM_SELF)
        print(f"| {s:.1f} | {E:.4g} | {rho:.5g} | {first_frequency(exp):.4f} | "
              f"{chi2(sim[diag.ident], diag.data[diag.ident], diag.sigma):.6g} |", flush=True)
    if args.calibrate:
        for label, (center, radius), (E, rho) in (
                ("truth's sphere from the truth", TRUTH_SPHERE, (2e7, 4000.0)),
                ("truth's sphere from the valley's start", TRUTH_SPHERE, tuple(a)),
                ("search's sphere from its values", SEARCH_SPHERE, (1.264e7, 1804.0))):
            diag.say = None
            fit = diag.calibrate(experiment(center, radius, E, rho), label=label,
                                 comm=PETSc.COMM_SELF)
            say(f"{label}: E {fit.values[0]:.6g} Pa, density {fit.values[1]:.6g} kg/m^3, "
                f"chi2 {fit.chi2:.6g}, {fit.iterations} iterations, held-out rms "
                f"{fit.heldout_rms / diag.sigma:.3f}x the noise")
    return 0


if __name__ == "__main__":
    sys.exit(main())
