"""How does the real pendulum lose its swing? Viscous, dry or quadratic friction.

Run (serial; a few seconds)::

    .venv/bin/python scripts/examples/pendulum_envelope.py [--dir out/pendulum] \
        [--out out/pendulum-envelope]

It reads the recordings ``scripts/examples/import_pendulum.py`` writes (``identification.h5`` and
``validation.h5`` in ``--dir``; it runs the import there first when they are missing) and
applies petsoft's array-only diagnosis tools (:mod:`petsoft.diagnosis`):

* the noise of the marker positions (:func:`~petsoft.diagnosis.noise.noise_summary`),
* the dominant modes of the marker motion (:func:`~petsoft.diagnosis.spectral.dominant_modes`),
* the decay envelope, fitted by the exponential / linear / 1/t laws of viscous / dry /
  quadratic friction (:func:`~petsoft.diagnosis.spectral.decay_envelope`), on the marker's
  principal motion and on the swing angle ``theta = atan2(x, -z)`` (the marker is
  ``L (sin, 0, cos)`` of the recorded angle, so at 1.6 rad the x amplitude ``L sin A`` is a
  compressed picture of the angle's),
* the decay-rate regression ``-dA/dt = c0 + c1 A + c2 A^2`` with non-negative terms
  (:func:`~petsoft.diagnosis.spectral.friction_terms`),

for each recording and for the whole 55 s swing (identification then validation, resampled on
one 100 Hz grid across the 8 ms seam). As a control, the same analysis runs on the *published
model* (rigid pendulum with viscous pivot friction only,
``(I + m a^2) theta'' + k theta' + m g a sin(theta) = 0``, theta from straight down) started
from the recording's first state: what pure viscous friction looks like at these amplitudes,
nonlinearity of the large swing included.

Finally the whole evidence chain (:func:`~petsoft.diagnosis.evidence.collect_evidence` and
:func:`~petsoft.diagnosis.evidence.suggest_physics`) runs on each recording against the
published model's marker (not calibrated here: that is ``petsoft diagnose``'s job), with the
recording's noise level.

Writes ``envelope.json`` (all numbers) and ``envelope.png`` (amplitude over time; decay rate
against amplitude, data and control) in ``--out``.

Things to try: ``--every 1`` in the import (1 kHz data) changes nothing but the run time;
compare the ``dry+quadratic`` coefficients of the identification and validation halves.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
PUBLISHED = {"a": 0.14775, "m": 0.14758, "I": 1.0912e-4, "k": 2.2394e-4, "g": 9.810}


def angle(positions: np.ndarray) -> np.ndarray:
    """Swing angle from straight down (rad) of the single marker of a pendulum recording."""
    return np.arctan2(positions[:, 0, 0], -positions[:, 0, 2])


def simulate_published(times: np.ndarray, phi0: float, omega0: float) -> np.ndarray:
    """Angle of the published viscous model at ``times`` (tight tolerances: a control)."""
    from scipy.integrate import solve_ivp

    p = PUBLISHED
    inertia = p["I"] + p["m"] * p["a"] ** 2

    def rhs(_, y):
        return [y[1], -(p["k"] * y[1] + p["m"] * p["g"] * p["a"] * np.sin(y[0])) / inertia]

    sol = solve_ivp(rhs, (times[0], times[-1]), [phi0, omega0], t_eval=times, method="DOP853",
                    rtol=1e-10, atol=1e-12)
    return sol.y[0]


def analyse(t: np.ndarray, phi: np.ndarray, markers: np.ndarray | None = None) -> dict:
    from petsoft.diagnosis import noise, spectral

    out = {}
    if markers is not None:
        out["noise"] = noise.noise_summary(markers, t)
        out["modes"] = [{k: v for k, v in m.items() if k != "shape"}
                        for m in spectral.dominant_modes(t, markers)[:4]]
        env = spectral.decay_envelope(t, markers)
        out["envelope_marker"] = {k: v for k, v in env.items() if k not in ("times", "amplitudes")}
    env = spectral.decay_envelope(t, phi)
    out["envelope_angle"] = {k: v for k, v in env.items() if k not in ("times", "amplitudes")}
    out["friction_terms_angle"] = spectral.friction_terms(env)
    out["_points"] = (env["times"], env["amplitudes"])
    return out


def describe(name: str, res: dict) -> None:
    print(f"\n== {name}")
    if "noise" in res:
        n = res["noise"]
        print(f"   noise: robust {n['std_mad']:.3g} m, rms {n['std_rms']:.3g} m, kurtosis "
              f"{n['kurtosis']:.3g} ({'Gaussian' if n['gaussian'] else 'heavy-tailed'})")
        print("   modes: " + "; ".join(f"{m['frequency_hz']:.4g} Hz decay {m['decay_rate']:.3g}/s"
                                       f" amp {m['amplitude']:.3g}" for m in res["modes"]))
    for key in ("envelope_marker", "envelope_angle"):
        if key in res:
            e = res[key]
            fits = ", ".join(f"{k} {v['rms']:.3g}" for k, v in e["fits"].items())
            print(f"   {key}: best {e['best']} ({e['friction']}), next/best rms {e['ratio']:.2f}, "
                  f"p = {e['exponent_p']:.2f}; rms: {fits}")
    ft = res["friction_terms_angle"]
    subs = ", ".join(f"{k} {v['rms']:.2g}" for k, v in ft["subsets"].items())
    coef = ft["subsets"][ft["best"]]["coefficients"]
    print(f"   -dA/dt terms (angle): best {ft['best']} "
          + " ".join(f"{k}={v:.3g}" for k, v in coef.items()) + f"; rms: {subs}")


def published_model_evidence(rec, length: float = 0.1528) -> dict:
    """Evidence and candidate physics of one recording against the published viscous model."""
    from petsoft.diagnosis import evidence

    t = rec.times
    phi = angle(rec.positions)
    # angle() = atan2(x, -z), so the marker is L (sin phi, 0, -cos phi).
    sphi = simulate_published(t, float(phi[0]), float((phi[1] - phi[0]) / (t[1] - t[0])))
    sim = np.zeros_like(rec.positions)
    sim[:, 0, 0] = length * np.sin(sphi)
    sim[:, 0, 2] = -length * np.cos(sphi)
    ev = evidence.collect_evidence(rec.positions, sim, t, rec.reference, rec.names,
                                   sigma=rec.noise["position_std"])
    return {"verdict": ev.verdict, "fit": ev.fit,
            "hints": ev.modes["hints"] if ev.modes else [],
            "suggestions": evidence.suggest_physics(ev)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dir", type=Path, default=Path("out/pendulum"))
    ap.add_argument("--out", type=Path, default=Path("out/pendulum-envelope"))
    args = ap.parse_args(argv)
    from petsoft.io.recording import read_recording

    if not (args.dir / "identification.h5").exists():
        import import_pendulum

        import_pendulum.main(["--out", str(args.dir)])
    rec = {n: read_recording(args.dir / f"{n}.h5") for n in ("identification", "validation")}
    results = {}
    for name, r in rec.items():
        results[name] = analyse(r.times, angle(r.positions), r.positions)
    # The whole swing on one uniform grid (the validation continues the identification).
    t_all = np.concatenate([rec["identification"].times,
                            rec["validation"].times + rec["validation"].attrs["time_offset"]])
    phi_all = np.concatenate([angle(r.positions) for r in rec.values()])
    step = float(np.median(np.diff(rec["identification"].times)))
    grid = np.arange(0.0, t_all[-1], step)
    phi = np.interp(grid, t_all, phi_all)
    results["whole swing"] = analyse(grid, phi)
    omega0 = (phi[2] - phi[0]) / (2 * step)
    control = simulate_published(grid, float(phi[1]), omega0)
    results["published viscous model (control)"] = analyse(grid, control)
    for name, res in results.items():
        describe(name, res)
    print("\n== evidence against the published viscous model (uncalibrated)")
    chain = {}
    for name, r in rec.items():
        chain[name] = published_model_evidence(r)
        c = chain[name]
        print(f"   {name}: {c['verdict']}, rms {c['fit']['rms']:.3g} m; candidates: "
              + ("; ".join(f"{s['physics']} ({s['reason']})" for s in c["suggestions"])
                 or "none"))

    args.out.mkdir(parents=True, exist_ok=True)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    for name, c in (("whole swing", "tab:blue"), ("published viscous model (control)", "0.4")):
        te, amp = results[name]["_points"]
        a1.semilogy(te, amp, ".", ms=3, c=c, label=name)
        rate = -(amp[4:] - amp[:-4]) / (te[4:] - te[:-4])
        am = 0.5 * (amp[4:] + amp[:-4])
        a2.plot(am, rate, ".", ms=3, c=c, label=name)
        ft = results[name]["friction_terms_angle"]
        xs = np.linspace(am.min(), am.max(), 100)
        co = ft["coefficients"]
        a2.plot(xs, co["dry"] + co["viscous"] * xs + co["quadratic"] * xs**2, "-", c=c, lw=1)
    a1.set_xlabel("time (s)")
    a1.set_ylabel("angle amplitude (rad)")
    a1.set_title("Decay envelope (log scale: exponential = straight)")
    a2.set_xlabel("amplitude A (rad)")
    a2.set_ylabel("-dA/dt (rad/s)")
    a2.set_title("Decay rate: c0 (dry) + c1 A (viscous) + c2 A^2 (drag)")
    for a in (a1, a2):
        a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out / "envelope.png", dpi=110)
    for res in results.values():
        res.pop("_points")
    results["evidence vs published model"] = chain
    (args.out / "envelope.json").write_text(json.dumps(results, indent=2, default=float) + "\n")
    print(f"\nwrote {args.out / 'envelope.json'} and {args.out / 'envelope.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
