"""Calibrate the real single pendulum and predict its validation segments (issue 5).

Run (serial; about 4 minutes with the defaults on a loaded 2-core machine, of which the
calibration is 2.5; 7 minutes with --step 0.0025)::

    .venv/bin/python scripts/examples/calibrate_pendulum.py [--out out/pendulum-cal] [--span 6]
        [--step 0.005] [--every 10] [--val-span 9.16] [--no-halving]

What it does
------------
1. Runs ``scripts/examples/import_pendulum.py --per-segment`` into ``OUT/data`` (or reuses it): one
   recording and one mass-spring experiment per segment (``id0`` ... ``val1``), each starting
   from its segment's first sample (angle and filtered angular velocity), a point mass
   M = (I + m a^2) / L^2 on a stiff spring of length L = 0.1528 m from a fixed pivot.
2. Calibrates ``damping.mass`` (viscous pivot friction) and ``gravity.acceleration.z`` with
   ``petsoft calibrate``'s driver (Gauss-Newton, adjoint/sensitivity gradients) on the first
   ``--span`` seconds of identification segment ``id0`` (released at 1.6 rad), with forward step
   ``--step`` and frames every ``--every`` ms of data (default: 6 s, h = 5 ms, 100 Hz frames:
   2.5 minutes per calibration on a loaded machine). Results of the driver go to ``OUT/id/``.
3. From angle data alone only g/L and the damping rate are identifiable (the mass cancels and
   only the ratio of gravity to length sets the period), so it reports g/L, L for g = 9.81,
   g for L = 0.1528 and the friction coefficient k = damping.mass * M L^2 next to the published
   fit (k = 2.2394e-4 N m s, g = 9.81, equivalent length 0.15275 m).
4. Predicts both validation segments (``--val-span`` s each) with the calibrated model and with
   the published one (initial state from each segment's first sample) and reports the rms
   prediction error in metres (marker) and radians (angle) against the noise level.
5. Step-halving check: the identification and first validation runs are repeated with h / 2;
   the maximum angle difference is reported (large angles, 1.6 rad, make the pendulum
   nonlinear; the period error of the second-order scheme is absorbed into g/L by the fit).

Outputs in ``OUT``: ``summary.json`` (everything printed), ``id_fit.png`` and ``val_fit.png``
(angle trajectories: data, calibrated, published), ``residuals.png`` (angle residuals of both
models on all segments), and ``id/`` (calibrated.toml, the driver's summary and plots).

Expect the viscous-only model to leave a systematic residual on the validation segments: the
data's decay has a dry-friction (Coulomb) component besides the viscous one
(``scripts/examples/pendulum_envelope.py``). Dry friction's equivalent viscous rate grows as the
amplitude falls, so a viscous fit on the large early swings (id0) underestimates the damping of
the small late ones: on val1 both viscous models (ours and the published one, fitted on all four
identification segments) predict too large a swing, the residual envelope growing linearly to
~0.07 rad after 9 s. That residual is reported, not hidden; ``friction.dry`` is the diagnosis
issue's.

Things to try
-------------
* ``--span 9.16`` (the whole of id0) or a coarser ``--every 20``: more or fewer frames.
* ``--step 0.0025``: halves the forward step; compare g/L (the step's bias) with the default.
* ``--method lbfgs`` or ``--multistart 4``: other optimizers (passed to the driver).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

LENGTH = 0.1528          # m, the importer's marker distance (the published equivalent length)
G_STANDARD = 9.81


def angles(positions: np.ndarray) -> np.ndarray:
    """theta - pi (rad, 0 hanging down) of marker positions (K, 1, 3) or (K, 3)."""
    p = np.asarray(positions).reshape(len(positions), -1)[:, :3]
    return np.arctan2(-p[:, 0], -p[:, 2])


def with_time(experiment, end: float, step: float):
    """The experiment with ``[time] end`` and ``step`` replaced (same integrator)."""
    return dataclasses.replace(experiment, time=dataclasses.replace(experiment.time, end=end,
                                                                    step=step))


def simulate(experiment, recording, frames: np.ndarray, params: dict, step: float, comm):
    """Marker positions (K, 1, 3) of ``experiment`` at ``params`` for the recording's frames."""
    from petsoft.calibration.calibrate import build_forward

    exp = with_time(experiment, float(recording.times[frames][-1]), step)
    fm = build_forward(exp, list(params), recording, recording.times[frames], comm)
    try:
        return fm.simulate(np.array(list(params.values()), dtype=float))
    finally:
        fm.destroy()


def errors(sim: np.ndarray, data: np.ndarray) -> dict:
    """rms (m) and angle rms / max (rad) of a prediction."""
    d = sim - data
    dth = np.angle(np.exp(1j * (angles(sim) - angles(data))))
    return {"rms_m": float(np.sqrt(np.mean(np.sum(d * d, axis=-1)))),
            "rms_rad": float(np.sqrt(np.mean(dth ** 2))), "max_rad": float(np.abs(dth).max())}


def plot_fits(path: Path, panels: list, title: str) -> None:
    """One row per panel (label, t, data, {model: sim}): angle over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(panels), 1, figsize=(11, 3.0 * len(panels)), squeeze=False)
    for ax, (label, t, data, sims) in zip(axes[:, 0], panels, strict=True):
        ax.plot(t, angles(data), "k-", lw=1.6, label="data")
        for (name, sim), style in zip(sims.items(), ("C0--", "C3:"), strict=False):
            ax.plot(t, angles(sim), style, lw=1.0, label=name)
        ax.set_ylabel("theta - pi (rad)")
        ax.set_title(label, fontsize=9)
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("t (s) from the segment's start")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_residuals(path: Path, panels: list, noise_rad: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(panels), 1, figsize=(11, 2.6 * len(panels)), squeeze=False)
    for ax, (label, t, data, sims) in zip(axes[:, 0], panels, strict=True):
        for (name, sim), colour in zip(sims.items(), ("C0", "C3"), strict=False):
            r = np.angle(np.exp(1j * (angles(sim) - angles(data))))
            ax.plot(t, r, color=colour, lw=0.8, label=name)
        ax.axhspan(-noise_rad, noise_rad, color="0.8", label="angle noise (1 sd)")
        ax.set_ylabel("model - data (rad)")
        ax.set_title(label, fontsize=9)
        ax.legend(loc="upper left", fontsize=8)
    axes[-1, 0].set_xlabel("t (s) from the segment's start")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("out/pendulum-cal"))
    ap.add_argument("--span", type=float, default=6.0,
                    help="identification span (s) from the start of id0 (<= 9.16)")
    ap.add_argument("--val-span", type=float, default=9.16,
                    help="predicted span (s) of each validation segment (<= 9.16)")
    ap.add_argument("--step", type=float, default=0.005, help="forward model step (s)")
    ap.add_argument("--every", type=int, default=10,
                    help="frames: every N-th 1 kHz sample (importer's --every)")
    ap.add_argument("--method", default="gauss-newton")
    ap.add_argument("--multistart", type=int, default=0)
    ap.add_argument("--reimport", action="store_true", help="rerun the importer even if OUT/data "
                                                            "exists")
    ap.add_argument("--no-halving", action="store_true", help="skip the step-halving check")
    args = ap.parse_args(argv)
    if not (0 < args.span <= 9.17 and 0 < args.val_span <= 9.17 and args.step > 0
            and args.every >= 1):
        ap.error("need 0 < --span, --val-span <= 9.16, --step > 0, --every >= 1")

    from petsc4py import PETSc

    from petsoft.calibration.calibrate import run_calibration
    from petsoft.experiment import load_experiment
    from petsoft.io.recording import read_recording

    comm = PETSc.COMM_WORLD
    rank0 = comm.rank == 0

    def say(line: str) -> None:
        if rank0:
            print(line, flush=True)

    out = args.out
    data_dir = out / "data"
    t0 = time.perf_counter()
    if rank0 and (args.reimport or not (data_dir / "pendulum_val1.toml").exists()):
        import import_pendulum

        out.mkdir(parents=True, exist_ok=True)
        import_pendulum.main(["--out", str(data_dir), "--every", str(args.every),
                              "--length", str(LENGTH), "--per-segment"])
    comm.tompi4py().barrier()
    published = json.loads((data_dir / "published.json").read_text())
    eq = published["equivalent_point_mass_model"]
    mass, sigma_rad = eq["point_mass"], published["angle_noise_rad"]["savgol"]
    # the published model in this one: its g/L = g / (I + m a^2)/(m a) = 9.81 / 0.152754 with the
    # marker at L = 0.1528 means g = 9.81 L / 0.152754 (not 9.81: that is 0.03% slower)
    pub_params = {"damping.mass": eq["damping.mass"],
                  "gravity.acceleration.z": eq["gravity.acceleration.z"] * LENGTH
                  / eq["equivalent_length"]}

    # -- identification ----------------------------------------------------------------------
    id_exp = load_experiment(data_dir / "pendulum_id0.toml")
    id_rec_path = data_dir / "id0.h5"
    id_rec = read_recording(id_rec_path)
    span = min(args.span, float(id_rec.times[-1]))
    exp = with_time(id_exp, span, args.step)
    say(f"identification: id0, first {span:g} s ({int((id_rec.times <= span).sum())} frames "
        f"every {args.every} ms), forward step h = {args.step:g} s (alpha, rho = "
        f"{exp.time.alpha_radius:g}); start {dict(zip(*_start(exp), strict=True))}")
    t_cal = time.perf_counter()
    result = run_calibration(exp, id_rec_path, method=args.method, starts=args.multistart,
                             out=out / "id", comm=comm, say=say)
    t_cal = time.perf_counter() - t_cal
    cal = dict(zip(result.names, map(float, result.values), strict=True))
    std = dict(zip(result.names, map(float, result.std), strict=True))
    alpha, gz = cal["damping.mass"], cal["gravity.acceleration.z"]
    g_over_l = -gz / LENGTH
    pub_g_over_l = published["published"]["g"] / eq["equivalent_length"]
    k = alpha * mass * LENGTH ** 2
    derived = {
        "g_over_L": g_over_l, "g_over_L_std": std["gravity.acceleration.z"] / LENGTH,
        "L_for_g_9.81": G_STANDARD / g_over_l, "g_for_L_0.1528": -gz,
        "friction_k_Nms": k, "friction_k_std": std["damping.mass"] * mass * LENGTH ** 2,
        "damping_rate_1_per_s": alpha,
        "published": {"g_over_L": pub_g_over_l, "L_equivalent": eq["equivalent_length"],
                      "g": published["published"]["g"], "friction_k_Nms":
                      published["published"]["k"], "damping.mass": eq["damping.mass"]}}

    # -- predictions: identification span and validation segments ---------------------------
    panels_id, panels_val, prediction = [], [], {}
    keep = id_rec.times <= span * (1 + 1e-12)
    sims = {"calibrated": result.simulated_after,
            "published": simulate(id_exp, id_rec, keep, pub_params, args.step, comm)}
    prediction["id0"] = {m: errors(s, id_rec.positions[keep]) for m, s in sims.items()}
    panels_id.append((f"identification id0 (first {span:g} s)", id_rec.times[keep],
                      id_rec.positions[keep], sims))
    val_exps = {}
    for seg in ("val0", "val1"):
        rec = read_recording(data_dir / f"{seg}.h5")
        vexp = val_exps[seg] = load_experiment(data_dir / f"pendulum_{seg}.toml")
        vkeep = rec.times <= args.val_span * (1 + 1e-12)
        sims = {name: simulate(vexp, rec, vkeep, params, args.step, comm)
                for name, params in (("calibrated", cal), ("published", pub_params))}
        prediction[seg] = {m: errors(s, rec.positions[vkeep]) for m, s in sims.items()}
        panels_val.append((f"validation {seg} (t0 = {rec.attrs.get('time_offset', 0):g} s in the "
                           f"swing; first {rec.times[vkeep][-1]:g} s)", rec.times[vkeep],
                           rec.positions[vkeep], sims))

    # -- step halving -----------------------------------------------------------------------
    halving = {}
    if not args.no_halving:
        half = simulate(id_exp, id_rec, keep, cal, args.step / 2, comm)
        halving["id0_max_rad"] = float(np.abs(np.angle(np.exp(
            1j * (angles(half) - angles(result.simulated_after))))).max())
        rec = read_recording(data_dir / "val0.h5")
        vkeep = rec.times <= args.val_span * (1 + 1e-12)
        half = simulate(val_exps["val0"], rec, vkeep, cal, args.step / 2, comm)
        halving["val0_max_rad"] = float(np.abs(np.angle(np.exp(
            1j * (angles(half) - angles(panels_val[0][3]["calibrated"]))))).max())
        halving["step"], halving["half_step"] = args.step, args.step / 2

    summary = {
        "identification": {"segment": "id0", "span_s": span, "frames_every_ms": args.every,
                           "step_s": args.step, "integrator": exp.time.integrator,
                           "alpha_radius": exp.time.alpha_radius, "method": args.method,
                           "iterations": result.iterations, "simulations": result.evaluations,
                           "reason": result.reason, "wall_time_s": t_cal},
        "calibrated": cal, "std": std, "derived": derived,
        "rms_fit_m": result.rms_after,
        "noise": {"position_std_m": result.sigma, "angle_std_rad": sigma_rad},
        "prediction": prediction, "step_halving": halving,
        "ranks": comm.size, "wall_time_s": time.perf_counter() - t0,
        "files": {"id_fit": "id_fit.png", "val_fit": "val_fit.png",
                  "residuals": "residuals.png", "calibration": "id/"},
    }
    if rank0:
        _report(summary, say)
        (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        plot_fits(out / "id_fit.png", panels_id, "Real pendulum: identification fit (viscous "
                                                  "friction)")
        plot_fits(out / "val_fit.png", panels_val, "Real pendulum: validation prediction")
        plot_residuals(out / "residuals.png", panels_id + panels_val, sigma_rad)
        say(f"wrote {out}/ (summary.json, id_fit.png, val_fit.png, residuals.png, id/)")
    return 0


def _start(exp):
    from petsoft.experiment import get_parameter

    names = list(exp.calibrate)
    return names, [get_parameter(exp, n) for n in names]


def _report(s: dict, say) -> None:
    d, p = s["derived"], s["derived"]["published"]
    say("")
    say(f"{'quantity':<30} {'calibrated':>14} {'(1 sd)':>10} {'published':>12}")
    rows = [("g/L (1/s^2)", d["g_over_L"], d["g_over_L_std"], p["g_over_L"]),
            ("L for g = 9.81 (m)", d["L_for_g_9.81"], None, p["L_equivalent"]),
            ("g for L = 0.1528 (m/s^2)", d["g_for_L_0.1528"], None,
             p["g"] * LENGTH / p["L_equivalent"]),
            ("damping.mass (1/s)", d["damping_rate_1_per_s"], s["std"]["damping.mass"],
             p["damping.mass"]),
            ("friction k (N m s)", d["friction_k_Nms"], d["friction_k_std"], p["friction_k_Nms"])]
    for name, v, sd, pub in rows:
        say(f"{name:<30} {v:>14.6g} {'' if sd is None else f'{sd:.2g}':>10} {pub:>12.6g}")
    n = s["noise"]
    say(f"fit rms {s['rms_fit_m']:.3g} m on id0 (noise {n['position_std_m']:.3g} m, "
        f"{n['angle_std_rad']:.3g} rad)")
    say(f"{'prediction rms':<16} {'model':<11} {'m':>10} {'rad':>10} {'max rad':>9} "
        f"{'/ noise':>9}")
    for seg, models in s["prediction"].items():
        for model, e in models.items():
            say(f"{seg:<16} {model:<11} {e['rms_m']:>10.3g} {e['rms_rad']:>10.3g} "
                f"{e['max_rad']:>9.3g} {e['rms_rad'] / n['angle_std_rad']:>9.3g}")
    h = s["step_halving"]
    if h:
        say(f"step halving (h = {h['step']:g} -> {h['half_step']:g} s, calibrated model): max "
            f"angle change {h['id0_max_rad']:.3g} rad on id0, {h['val0_max_rad']:.3g} rad on "
            "val0")


if __name__ == "__main__":
    raise SystemExit(main())
