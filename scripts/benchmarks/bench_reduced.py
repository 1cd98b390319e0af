"""A reduced-order forward model on the realistic control case: cost and error against the full
model (issue 40, items 1-2).

The case (``realistic/cases/control``: a 711-tet tapered cantilever, neo-Hookean, under gravity,
clamped at x = 0, kicked by an initial velocity; 1.0 s at 2 ms, generalized-alpha r = 0.9, 24
markers, noise 0.1 mm) is built with petsoft's API with ``[mesh] order = 2`` (10-node elements,
as diagnose adopts them), and its markers are observed as in a calibration (``ForwardModel``,
``MarkerObserver.from_recording``). Then:

1. offline: the full run at the user's parameters (its displacements q_n - q_0 and velocities
   are the snapshots), and -- from level 1 on -- finite-difference sensitivity trajectories
   (q_n(p + dp) - q_n(p)) / dp of ``material.youngs_modulus`` (dp = 1 %) and
   ``damping.mass`` (dp = 0.5 1/s) ("enriched for the candidate terms"); the POD basis
   (:func:`petsoft.reduced.basis.pod_basis`) at the level's energy; the ECSW reduced mesh
   (:func:`petsoft.reduced.ecsw.ecsw_mesh`) trained on every 5th state's reduced coordinates;
2. online: the reduced run with the full system's assembly (no hyper-reduction) and with ECSW,
   against the full run, at the training parameters and at parameters moved (E +-10 %,
   damping.mass 0 -> 2): the marker error rms / noise and max / noise
   (:func:`petsoft.reduced.error.reduced_error`), the basis enriched level by level until the
   worst check is below 0.2x the noise;
3. with ``--sensitivities``: at the last level built, the reduced model's forward
   sensitivities (:func:`petsoft.reduced.sensitivity.sensitivities`) of the markers to
   ``material.youngs_modulus``, ``damping.mass`` and ``damping.stiffness``, against the full
   model's (``ForwardModel.jacobian``), at the training point and at E +-10 %: each column
   scaled by a parameter change (E 10 %, damping.mass 1 1/s, damping.stiffness 1e-4 s), the
   rms of the difference over the noise (and the column's own rms over the noise, for scale);
   and the time of a reduced run with sensitivities against ``ForwardModel.jacobian``.

Run (1 and 2 ranks)::

    .venv/bin/python scripts/benchmarks/bench_reduced.py
    mpiexec -n 2 .venv/bin/python scripts/benchmarks/bench_reduced.py [--levels 3] \\
        [--ecsw-tol 1e-3] [--ecsw-every 5] [--end 0.2] [--sensitivities] [--min-level 2] \\
        [--json out.json]

Times are wall seconds (max over ranks, each bracketed by a barrier). On a shared machine they
are "under load": compare ratios of one run, re-time on a quiet machine.

Things to try: ``--case damping`` (the recording's concealed damping changes nothing here: the
comparison is model against model), ``--end 0.4`` (a shorter record), ``--ecsw-tol 1e-5``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.api import load_experiment, read_recording
from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.experiment import experiment_from_dict
from petsoft.reduced.basis import coordinates_of, pod_basis
from petsoft.reduced.ecsw import SampledForces, ecsw_mesh
from petsoft.reduced.error import TARGET, marker_error, reduced_error
from petsoft.reduced.galerkin import FullForces, ReducedModel, steps_for
from petsoft.reduced.sensitivity import sensitivities

HERE = Path(__file__).resolve().parent
CASES = HERE / "realistic" / "cases"
NAMES = ["material.youngs_modulus", "damping.mass"]
#: --sensitivities: the parameters differentiated and the change each column is scaled by
#: (E: 10 % of its value; the damping coefficients are 0 in the cases: absolute changes)
SENS_NAMES = NAMES + ["damping.stiffness"]
SENS_STEPS = {"material.youngs_modulus": ("relative", 0.1), "damping.mass": ("absolute", 1.0),
              "damping.stiffness": ("absolute", 1e-4)}
#: (energy kept, with sensitivity trajectories) per enrichment level
LEVELS = [(1 - 1e-6, False), (1 - 1e-7, True), (1 - 1e-9, True), (1 - 1e-11, True)]
COMM = PETSc.COMM_WORLD


def say(*args) -> None:
    if COMM.getRank() == 0:
        print(*args, flush=True)


def timed(fn, *args, **kw):
    COMM.barrier()
    t0 = time.perf_counter()
    out = fn(*args, **kw)
    COMM.barrier()
    return out, COMM.tompi4py().allreduce(time.perf_counter() - t0, op=MPI.MAX)


def experiment_of(case: str, end: float | None):
    exp = load_experiment(CASES / case / "user.toml")
    data = exp.to_dict()
    data["mesh"]["order"] = 2
    if end is not None:
        data["time"]["end"] = end
    return experiment_from_dict(data, source=exp.source, base_dir=exp.base_dir, path=exp.path)


def trajectory(fm, p):
    """(q_n list, v_n list, marker frames) of a full run at p (stored states)."""
    states, frames = fm._run(p, store=True)
    qs = [q.copy() for q, _, _ in states]
    vs = [v.copy() for _, v, _ in states]
    fm._free(states)
    return qs, vs, frames


def m_norm(system, x) -> float:
    y = x.duplicate()
    system.M.mult(x, y)
    out = float(np.sqrt(max(x.dot(y), 0.0)))
    y.destroy()
    return out


def scaled(system, vectors, size: float):
    """Copies of ``vectors`` scaled together so that their largest M-norm is ``size`` (a
    snapshot set of another unit -- velocities, sensitivities -- weighs like the
    displacements in the POD)."""
    top = max(m_norm(system, x) for x in vectors)
    out = []
    for x in vectors:
        y = x.copy()
        if top > 0.0:
            y.scale(size / top)
        out.append(y)
    return out


def make_model(s, V, q_ref, mesh, kind, observer, method, radius):
    forces = SampledForces(s, V, q_ref, mesh) if kind == "ecsw" else FullForces(s, V, q_ref)
    return ReducedModel(s, V, q_ref, observer, forces=forces, method=method, radius=radius)


def compare_sensitivities(fm, V, q_ref, mesh, v0, times, noise, seen, names, p0, jacobians):
    """The reduced sensitivities against ForwardModel.jacobian (cached in ``jacobians``) at
    the training point and E +-10 %: per check and force kind, per parameter, the rms over the
    noise of the difference of the columns scaled by SENS_STEPS, and the run times."""
    s, h = fm.system, fm.h
    nsteps = steps_for(times, h)
    dp = np.array([SENS_STEPS[n][1] * (abs(p) if SENS_STEPS[n][0] == "relative" else 1.0)
                   for n, p in zip(names, p0, strict=True)])
    out = {}
    for label, factor in (("train", 1.0), ("E-10%", 0.9), ("E+10%", 1.1)):
        p = p0.copy()
        p[0] *= factor
        if label not in jacobians:
            (_, jac), t = timed(fm.jacobian, p)
            jacobians[label] = (jac, t)
        jac, t_jac = jacobians[label]
        row = {"jacobian_s": t_jac}
        for kind in ("full-assembly", "ecsw"):
            rm = make_model(s, V, q_ref, mesh, kind, fm.observer, fm.method,
                            fm.integrator.radius)
            rm.set_parameters(dict(zip(names, p.tolist(), strict=True)))
            run_plain, t_plain = timed(rm.run, v0, h, nsteps)
            sens, t_sens = timed(sensitivities, rm, v0, h, nsteps, names)
            _, djac = sens.frames(times, h)
            cols = {}
            for j, name in enumerate(names):
                full_col, red_col = jac[..., j] * dp[j], djac[..., j] * dp[j]
                size = marker_error(np.zeros_like(full_col), full_col, noise, seen)[0]
                diff = marker_error(full_col, red_col, noise, seen)[0]
                cols[name] = {"step": float(dp[j]), "column_rms": size, "difference_rms": diff}
            row[kind] = {"run_s": t_plain, "sensitivities_s": t_sens,
                         "jacobian_over_sensitivities": t_jac / t_sens, "columns": cols}
            say(f"  sensitivities {label:6s} {kind:13s}: reduced run {t_plain:.2f} s, with "
                f"sensitivities {t_sens:.2f} s; ForwardModel.jacobian {t_jac:.1f} s "
                f"({t_jac / t_sens:.1f}x); difference rms / noise per column (column rms "
                "/ noise): " + ", ".join(f"{n.split('.')[-1]} {c['difference_rms']:.3g} "
                                         f"({c['column_rms']:.3g})"
                                         for n, c in cols.items()))
            rm.destroy()
        out[label] = row
    s.set_parameters(dict(zip(names, p0.tolist(), strict=True)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", default="control")
    ap.add_argument("--end", type=float, default=None, help="shorten the record (s)")
    ap.add_argument("--levels", type=int, default=len(LEVELS))
    ap.add_argument("--ecsw-tol", type=float, default=1e-3)
    ap.add_argument("--ecsw-every", type=int, default=5, help="ECSW training: every k-th state")
    ap.add_argument("--min-level", type=int, default=0,
                    help="enrich at least to this level, even when an earlier one is below "
                    "the target (e.g. to compare its sensitivities)")
    ap.add_argument("--sensitivities", action="store_true",
                    help="compare the reduced sensitivities with the full model's at the last "
                    "level built")
    ap.add_argument("--json", default=None, help="write the results here (rank 0)")
    args = ap.parse_args()
    exp = experiment_of(args.case, args.end)
    rec = read_recording(CASES / args.case / "recording.h5")
    times = rec.times[rec.times <= exp.time.end + 1e-12]
    seen = rec.seen()[:len(times)]
    noise = float(rec.noise.get("position_std", 1e-4))
    names = SENS_NAMES if args.sensitivities else NAMES
    fm = ForwardModel(exp, names, lambda s: MarkerObserver.from_recording(s, rec), times)
    s, h = fm.system, fm.h
    nsteps = steps_for(times, h)
    dofs = s.create_vec().getSize()
    say(f"bench_reduced: case {args.case}, P2, {dofs} dofs, {nsteps} steps of {h:g} s, "
        f"{len(times)} frames x {rec.num_markers} markers, noise {noise:g} m, "
        f"{COMM.getSize()} rank(s); times under load")
    p0 = fm.p0.copy()
    out = {"case": args.case, "dofs": dofs, "steps": nsteps, "ranks": COMM.getSize(),
           "noise": noise, "levels": []}

    # offline: the training run and the sensitivity trajectories (finite differences)
    (qs, vs, full0), t_train = timed(trajectory, fm, p0)
    say(f"full run (training, stored states): {t_train:.1f} s ({1e3 * t_train / nsteps:.1f} "
        "ms a step)")
    sens, t_sens = [], 0.0
    for j, dp in ((0, 0.01 * p0[0]), (1, 0.5)):
        p = p0.copy()
        p[j] += dp
        (qj, _, _), t = timed(trajectory, fm, p)
        t_sens += t
        for a, b in zip(qj[1:], qs[1:], strict=True):
            a.axpy(-1.0, b)
            a.scale(1.0 / dp)
        sens.append(qj[1:])
        for x in [qj[0]]:
            x.destroy()
    say(f"sensitivity trajectories (2 FD runs): {t_sens:.1f} s")
    q_ref = qs[0]
    disp = []
    for q in qs[1:]:
        d = q.copy()
        d.axpy(-1.0, q_ref)
        disp.append(d)
    size = max(m_norm(s, d) for d in disp)
    vel = scaled(s, vs, size)
    sens = [scaled(s, traj, size) for traj in sens]
    _, v0 = s.initial_state()

    # the checks' full runs (not training data)
    checks = {"train": p0}
    for label, factor in (("E-10%", 0.9), ("E+10%", 1.1)):
        p = p0.copy()
        p[0] *= factor
        checks[label] = p
    p = p0.copy()
    p[1] = 2.0
    checks["damping.mass=2"] = p
    full, t_full = {"train": full0}, [t_train]
    for label, p in checks.items():
        if label == "train":
            continue
        full[label], t = timed(fm.simulate, p)
        t_full.append(t)
    t_full_run = float(np.median(t_full[1:]))
    say(f"full run (simulate, kept factors): median {t_full_run:.1f} s "
        f"({1e3 * t_full_run / nsteps:.1f} ms a step) over {len(t_full) - 1} runs")
    out["full_run_s"] = t_full_run
    out["training_s"] = t_train
    out["sensitivity_runs_s"] = t_sens

    jacobians = {}
    for level in range(min(args.levels, len(LEVELS))):
        energy, enriched = LEVELS[level]
        snaps = disp + vel + ([x for traj in sens for x in traj] if enriched else [])
        V, t_basis = timed(pod_basis, s, snaps, energy=energy)
        # ECSW trains on every --ecsw-every'th state's reduced coordinates
        coords = np.array([coordinates_of(s, V, q, q_ref) for q in qs[1::args.ecsw_every]])
        mesh, t_ecsw = timed(ecsw_mesh, s, V, q_ref, coords, tolerance=args.ecsw_tol)
        ncells = int(s.dmesh.allreduce_sum(len(s.dmesh.cells)))
        row = {"level": level, "energy": energy, "enriched": enriched, "r": V.size,
               "snapshots": len(snaps), "basis_s": t_basis, "ecsw_s": t_ecsw,
               "ecsw_elements": mesh.size, "cells": int(ncells), "ecsw_fit": mesh.error}
        say(f"level {level}: {len(snaps)} snapshots{' (+ sensitivities)' if enriched else ''},"
            f" energy 1-{1 - energy:.0e}: r = {V.size} ({t_basis:.1f} s); ECSW "
            f"{mesh.size} of {ncells} elements, fit {mesh.error:.1e} ({t_ecsw:.1f} s)")
        for kind in ("full-assembly", "ecsw"):
            if kind == "ecsw":
                forces = SampledForces(s, V, q_ref, mesh)
            else:
                forces = FullForces(s, V, q_ref)
            rm = ReducedModel(s, V, q_ref, fm.observer, forces=forces, method=fm.method,
                              radius=fm.integrator.radius)
            pairs, t_red = {}, []
            for label, p in checks.items():
                rm.set_parameters(dict(zip(names, p.tolist(), strict=True)))
                run, t = timed(rm.run, v0, h, nsteps)
                t_red.append(t)
                pairs[label] = (full[label], run.frames(times, h))
            err = reduced_error(pairs, noise, seen)
            t_med = float(np.median(t_red))
            row[kind] = {"run_s": t_med, "speedup": t_full_run / t_med, "rms": err.rms,
                         "max": err.max, "checks": err.checks,
                         "newton": run.newton_iterations}
            say(f"  {kind:13s}: run {t_med:.2f} s (full/reduced {t_full_run / t_med:.1f}x), "
                f"error rms {err.rms:.3f}x noise, max {err.max:.3f}x; "
                + ", ".join(f"{k} {v['rms']:.3f}" for k, v in err.checks.items()))
            rm.destroy()
        # the systems' parameters back at the training point for the next level
        s.set_parameters(dict(zip(names, p0.tolist(), strict=True)))
        out["levels"].append(row)
        below = row["ecsw"]["rms"] <= TARGET and row["full-assembly"]["rms"] <= TARGET
        if below:
            say(f"level {level}: below {TARGET}x the noise on every check")
        done = below and level >= args.min_level
        if args.sensitivities and (done or level == min(args.levels, len(LEVELS)) - 1):
            row["sensitivities"] = compare_sensitivities(fm, V, q_ref, mesh, v0, times, noise,
                                                         seen, names, p0, jacobians)
        if done:
            break
    if args.json and COMM.getRank() == 0:
        Path(args.json).write_text(json.dumps(out, indent=1))
    fm.destroy()


if __name__ == "__main__":
    main()
