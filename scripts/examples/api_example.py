"""petsoft from Python: a cantilever solved, swung, recorded and calibrated, by the public API only.

1. ``petsoft.static``: the bar sagging under gravity;
2. ``petsoft.simulate``: the bar swinging after a kick (generalized-alpha);
3. ``petsoft.synth``: a synthetic recording of that swing (6 surface markers, 20 um noise). It is
   made on the model's own mesh and step, so the fit can be exact; with ``--refine 2`` it is made
   on a 2x finer mesh at half the step, and the fitted E absorbs this coarse P1 mesh's bending
   stiffness (about 40 % low: the discretisation error that ``petsoft diagnose``'s numerics check
   measures);
4. ``petsoft.calibrate``: Young's modulus recovered from the recording, starting 30 % low.

Run (writes into ``--out``, default ``api-example/``; a few seconds on one core)::

    .venv/bin/python scripts/examples/api_example.py
    mpiexec -n 2 .venv/bin/python scripts/examples/api_example.py

Things to try: ``-ksp_type cg -pc_type gamg`` (PETSc options are read from the command line by
``petsc4py.init`` before the first petsoft call); ``--noise 2e-4`` (a noisier recording: a wider
uncertainty).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import petsc4py

import petsoft

#: The body: scripts/examples/cantilever.toml (E = 2 MPa, swung by an initial velocity).
EXPERIMENT = Path(__file__).resolve().parent / "cantilever.toml"


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=Path("api-example"))
    ap.add_argument("--noise", type=float, default=2e-5, help="marker noise std (m)")
    ap.add_argument("--refine", type=int, default=1,
                    help="make the recording on a mesh and step refined by this factor")
    args, petsc_args = ap.parse_known_args(argv)
    petsc4py.init([sys.argv[0], *petsc_args])          # PETSc options before the first call
    from mpi4py import MPI

    rank0 = MPI.COMM_WORLD.rank == 0
    say = print if rank0 else (lambda line: None)

    truth = petsoft.load_experiment(EXPERIMENT)
    true_e = 2.0e6                                      # the file's material.youngs_modulus

    sag = petsoft.static(truth, out=args.out / "static")
    say(f"static: tip sags {sag.probes[0][2] * 1e3:.3f} mm "
        f"({sag.newton_iterations} Newton iterations)")

    swing = petsoft.simulate(truth, out=args.out / "swing")
    tip = swing.probe_displacements[:, 0, 2]
    say(f"simulate: {swing.steps} steps with {swing.integrator}; tip z between "
        f"{tip.min() * 1e3:.2f} and {tip.max() * 1e3:.2f} mm")

    made = petsoft.synth(truth, out=args.out / "recording.h5", noise=args.noise, markers=6,
                         refine=args.refine, seed=1)
    recording = petsoft.read_recording(made.recording)
    say(f"synth: {made.markers} markers x {made.frames} frames -> {made.recording}")

    start = petsoft.with_parameters(truth, {"material.youngs_modulus": 0.7 * true_e})
    fit = petsoft.calibrate(start, recording, out=args.out / "calibration")
    E, std = fit.values[0], fit.std[0]
    say(f"calibrate: E = {E:.5g} Pa +- {std:.2g} (truth {true_e:.5g}; error "
        f"{abs(E / true_e - 1) * 100:.2f} %), rms {fit.rms_before:.3g} -> {fit.rms_after:.3g} m")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
