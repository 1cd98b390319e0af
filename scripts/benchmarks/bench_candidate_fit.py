"""One candidate fit of diagnose, alone: its iterations and simulations (issue 40's crawl).

What is measured
----------------
A realistic case (``scripts/benchmarks/realistic/cases/<case>``: the user's experiment and the
recording) is fitted the way ``petsoft diagnose`` fits a candidate in round 1: the base model
(the user's ``[calibrate]``, by default only the Young's modulus) is calibrated on the
identification window (the first ``--fraction`` of the record), then extended by the
candidate's term (:func:`petsoft.diagnosis.candidates.propose`, the term's declared start and
bounds; the viscoelastic branch's relaxation time starts at 1/(2 pi f) of the data's dominant
frequency) and calibrated from the base fit with diagnose's options: Levenberg-Marquardt
(``gauss-newton``), its stop ``-cal_lm_dtol`` = ``FIT_DTOL``, the forward runs' Newton
tolerance ``NEWTON_RTOL``, the gradient diagnose would take (forward sensitivities for the
viscoelastic branch). Diagnose's scanned start and its "cannot win" stop are left out, so the
fit runs to its own end.

One line per iteration (f = chi2/2, simulations so far, parameters) and a summary line
(iterations, simulations, chi2, reason). No timings: count iterations and runs.

In round 1 of the damping-5k case (5,007 tets, concealed mass damping) the viscoelastic fit took
41 iterations, following the valley ratio * relaxation_time ~ constant towards the Kelvin-Voigt
limit (issue 40).

Measured (2 ranks, linear tets, ``damping --base-E 1.33989e7``, the base fit's value): the
viscoelastic candidate took 43 iterations and 76 simulations to chi2 1.744673e5 when
Levenberg-Marquardt stepped the ratio (affine, from 0) in p and the relaxation time in log p
(the valley curved in those variables: each step ~8 % of each parameter, and 15 runs for the last
5 iterations, whose steps were clipped at the time's lower bound); along straight lines in log p
and held at the bound (:func:`petsoft.calibration.optimize._trial_point`), 18 iterations and 27
simulations to the same chi2 1.744673e5 and the same parameters (4 digits).

Run (two ranks; the 711-tet ``damping`` case on linear tets is the cheap one)::

    mpiexec -n 2 .venv/bin/python scripts/benchmarks/bench_candidate_fit.py damping
    mpiexec -n 2 .venv/bin/python scripts/benchmarks/bench_candidate_fit.py damping-5k \\
        --base-E 1.7843e7          # skip the base fit: diagnose's base value of that case

Things to try: ``--candidate damping.stiffness``; ``-cal_tao_max_it 10``; ``-cal_lm_dtol 1e-6``
(calibrate's own stop).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

CASES = Path(__file__).resolve().parent / "realistic" / "cases"


def _args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", help="a case directory name under realistic/cases, or a path")
    ap.add_argument("--candidate", default="material.viscoelastic")
    ap.add_argument("--fraction", type=float, default=0.7,
                    help="identification window's share of the record (diagnose's default)")
    ap.add_argument("--base-E", type=float, default=None,
                    help="the base model's Young's modulus (skips the base fit)")
    return ap.parse_known_args(argv)[0]


def main(argv=None) -> int:
    args = _args(argv)
    import numpy as np
    from petsc4py import PETSc

    from petsoft.calibration.calibrate import Observations, run_calibration
    from petsoft.calibration.forward import forward_defaults
    from petsoft.diagnosis.candidates import propose
    from petsoft.diagnosis.context import (
        FIT_DTOL,
        NEWTON_RTOL,
        dominant_frequency,
        gradient_for,
        model_scales,
    )
    from petsoft.experiment import load_experiment, with_parameters
    from petsoft.io.recording import read_recording_on_all_ranks
    from petsoft.solvers.options import scoped_defaults

    comm = PETSc.COMM_WORLD
    rank0 = comm.getRank() == 0

    def say(line):
        if rank0:
            print(line, flush=True)

    case = Path(args.case) if Path(args.case).is_dir() else CASES / args.case
    experiment = load_experiment(case / "user.toml")
    recording = read_recording_on_all_ranks(case / "recording.h5", comm)
    times, data = recording.times, recording.positions
    keep = times <= experiment.time.end * (1 + 1e-12)
    cut = float(args.fraction * times[keep][-1])
    ident = times <= cut * (1 + 1e-12)
    observations = Observations(recording, end=cut)
    sigma = observations.sigma()[0]

    def fit(exp, label):
        say(f"{label}: {', '.join(exp.calibrate)}")
        with scoped_defaults(cal_lm_dtol=str(FIT_DTOL)):
            res = run_calibration(exp, observations, method="gauss-newton",
                                  gradient=gradient_for(exp, "sensitivity"), comm=comm,
                                  say=say)
        say(f"{label}: {res.iterations} iterations, {res.evaluations} simulations, chi2 "
            f"{2.0 * res.objective_after:.6e}, reason {res.reason}; "
            + ", ".join(f"{n}={v:.6g}" for n, v in zip(res.names, res.values, strict=True)))
        return with_parameters(exp, dict(zip(res.names, res.values, strict=True))), res

    with forward_defaults(snes_rtol=repr(NEWTON_RTOL)):
        if args.base_E is not None:
            base = with_parameters(experiment, {"material.youngs_modulus": args.base_E})
        else:
            base, _ = fit(experiment, "base fit")
        scales = model_scales(base, times[ident], data[ident])
        frequency = dominant_frequency(times[ident], data[ident])
        if frequency is not None:
            scales["frequency"] = frequency
        candidate = propose(args.candidate, base, scales)
        say(f"candidate {candidate.physics}: {candidate.reason}; parameters "
            + ", ".join(f"{n} in [{lo:.4g}, {hi:.4g}]"
                        for n, (lo, hi) in zip(candidate.parameters, candidate.bounds,
                                               strict=True))
            + f"; noise {sigma:.3g} m")
        fit(candidate.extend(base), f"candidate {candidate.physics}")
    del np
    return 0


if __name__ == "__main__":
    sys.exit(main())
