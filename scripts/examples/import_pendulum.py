"""Turn the real single-pendulum recording into petsoft recordings and a mass-spring experiment.

Run (serial; about a second)::

    .venv/bin/python scripts/examples/import_pendulum.py [--out out/pendulum] [--every 10]
        [--length 0.1528] [--per-segment]

The data (scripts/examples/data/pendulum-single/, MIT licence, Kaheman et al. 2022,
arXiv:2205.06231;
see the README there) are the angle theta(t) of a rigid arm swinging freely about a fixed pivot,
sampled at 1 kHz for 55 s, cut into 4 identification and 2 validation segments.

Conversion
----------
* Sign convention: the data measure theta so that theta = pi is hanging straight down. The
  marker is the point at distance L from the pivot (the origin) in the x-z swing plane,
  ``marker = L (sin theta, 0, cos theta)``: theta = pi gives (0, 0, -L), straight down (gravity
  is -z), and theta = pi - 1.6 (the release) puts the arm at x > 0.
* L = 0.1528 m by default: the equivalent simple-pendulum length (I + m a^2) / (m a) of the
  published physical-pendulum fit, so a point mass at the marker has the same period.
* Subsampling: every ``--every``-th sample (default 10: 100 Hz).
* Recordings: ``identification.h5`` (the 4 identification segments, 0 to 36.67 s) and
  ``validation.h5`` (the 2 validation segments; times shifted to start at 0, the offset kept in
  the root attribute ``time_offset``), or with ``--per-segment`` one file per segment
  (``id0.h5`` ... ``val1.h5``, each starting at 0, with experiments ``pendulum_id0.toml`` ...
  ``pendulum_val1.toml``). Each has one marker, ``bob``, whose
  reference position is the rest position (0, 0, -L), and ``/noise position_std``.
* Noise: the angle's noise is estimated from the high-pass residual of a Savitzky-Golay filter
  (cubic, 21 samples = 21 ms) on the 1 kHz data, corrected for the filter's own gain
  (std(residual) / sqrt(1 - h0), h0 its centre coefficient); position_std = L * sigma_theta.
  Second and third differences give the same level within 10% (printed).
* Experiments (formats.md section 1, mass-spring form): ``pendulum_id.toml`` and
  ``pendulum_val.toml``: a line mesh ``pendulum.msh`` of two nodes (pivot at the origin, bob at
  (0, 0, -L)), a stiff spring between them ([springs] pairs), the pivot fixed, a point mass at the
  bob with the published moment of inertia about the pivot, M = (I + m a^2) / L^2, gravity -z,
  viscous pivot friction as Rayleigh ``damping.mass`` (starting from 0: the undamped model that
  calibration and diagnosis should correct), initial displacement and velocity from the first
  sample of each recording (expressions scaled by z / -L so the pivot stays at rest), and
  [calibrate] bounds for damping.mass and gravity.acceleration.z.
* ``published.json``: the published fit and its equivalents in this model (damping.mass =
  k / (M L^2) makes the point mass's friction torque equal the published k theta').
* ``pendulum.png``: the angle over time (identification and validation), its decay envelope, and
  the marker path.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DATA = HERE / "data" / "pendulum-single" / "SinglePendulumDataForParameterEstimation.mat"

# The published fit (README of the data): physical pendulum with viscous pivot friction.
PUBLISHED = {"a": 0.14775, "m": 0.14758, "I": 1.0912e-4, "k": 2.2394e-4, "g": 9.810}
SPRING_STIFFNESS = 1.0e6    # N/m: axial frequency ~420 Hz >> the 1.3 Hz swing; stretch 1.4 um


def load_segments(path: Path):
    """[(kind, index, times (n,), theta (n,), omega (n,))] for the 6 segments, in time order."""
    from scipy.io import loadmat

    d = loadmat(path, squeeze_me=True)
    out = []
    for kind, ykey, tkey in (("id", "Y_id", "Time_id"), ("val", "Y_vad", "Time_vad")):
        for i, (y, t) in enumerate(zip(d[ykey], d[tkey], strict=True)):
            y = np.asarray(y, dtype=float)
            out.append((kind, i, np.asarray(t, dtype=float), y[0], y[1]))
    return out, float(d["dt"])


def marker_positions(theta: np.ndarray, length: float) -> np.ndarray:
    """(n, 3) marker positions for angles theta (pi = hanging down along -z)."""
    return length * np.column_stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)])


def marker_velocities(theta: np.ndarray, omega: np.ndarray, length: float) -> np.ndarray:
    return length * omega[:, None] * np.column_stack([np.cos(theta), np.zeros_like(theta),
                                                      -np.sin(theta)])


def angle_noise(theta: np.ndarray) -> dict:
    """Noise std of the angle (rad) from high-pass residuals of the 1 kHz signal."""
    from scipy.signal import savgol_coeffs, savgol_filter

    window = 21
    h0 = savgol_coeffs(window, 3)[window // 2]
    resid = theta - savgol_filter(theta, window, 3)
    return {"savgol": float(resid.std() / np.sqrt(1.0 - h0)),
            "second_difference": float(np.diff(theta, 2).std() / np.sqrt(6.0)),
            "third_difference": float(np.diff(theta, 3).std() / np.sqrt(20.0))}


def equivalent_model(length: float) -> dict:
    p = PUBLISHED
    inertia = p["I"] + p["m"] * p["a"] ** 2                 # about the pivot
    mass = inertia / length ** 2
    return {"length": length, "point_mass": mass, "damping.mass": p["k"] / (mass * length ** 2),
            "gravity.acceleration.z": -p["g"],
            "equivalent_length": inertia / (p["m"] * p["a"])}


def write_experiment(path: Path, mesh_name: str, length: float, mass: float, end: float,
                     step: float, theta0: float, omega0: float, recording: str) -> None:
    x0 = marker_positions(np.array([theta0]), length)[0]
    v0 = marker_velocities(np.array([theta0]), np.array([omega0]), length)[0]
    u0 = x0 - np.array([0.0, 0.0, -length])
    s = -1.0 / length              # z / -L: 1 at the bob, 0 at the pivot

    def expr(c):
        return f"{c * s:.17g}*z" if c != 0.0 else "0"

    text = f'''# Real single pendulum (scripts/examples/import_pendulum.py; data: Kaheman et al.
# 2022, MIT).
# Recording: {recording}. A point mass on a stiff spring from a fixed pivot; the undamped model
# (damping.mass = 0) is the starting point for calibration and diagnosis.

[mesh]
file = "{mesh_name}"

[springs]
stiffness = {SPRING_STIFFNESS:.6g}
damping = 0.0
pairs = [[0, 1]]
node_mass = 0.0

[[mass]]
at = [0.0, 0.0, {-length:.17g}]
value = {mass:.17g}

[damping]
mass = 0.0

[gravity]
acceleration = [0.0, 0.0, -9.81]

[[boundary]]
kind = "fixed"
where = "x*x + y*y + z*z < 1e-12"

[initial]
displacement = ["{expr(u0[0])}", "0", "{expr(u0[2])}"]
velocity = ["{expr(v0[0])}", "0", "{expr(v0[2])}"]

[time]
end = {end:.17g}
step = {step:.17g}
integrator = "alpha"
alpha_radius = 0.5

[output]
directory = "out"
probes = [[0.0, 0.0, {-length:.17g}]]

[calibrate]
"damping.mass" = [0.0, 1.0]
"gravity.acceleration.z" = [-12.0, -8.0]
'''
    path.write_text(text)


def plot(path: Path, parts: list, envelope: tuple, length: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4), gridspec_kw={"width_ratios": [3, 1]})
    for label, t, th, colour in parts:
        ax1.plot(t, th - np.pi, lw=0.6, color=colour, label=label)
    te, amp = envelope
    ax1.plot(te, amp, "k.", ms=3, label="|theta - pi| peaks")
    ax1.set_xlabel("t (s)")
    ax1.set_ylabel("theta - pi (rad)")
    ax1.legend(loc="upper right", fontsize=8)
    ax1.set_title("Real pendulum (Kaheman et al. 2022): free swing")
    for _label, _t, th, colour in parts:
        p = marker_positions(th, length)
        ax2.plot(p[:, 0], p[:, 2], lw=0.3, color=colour)
    ax2.plot([0], [0], "ko")
    ax2.set_aspect("equal")
    ax2.set_xlabel("x (m)")
    ax2.set_ylabel("z (m)")
    ax2.set_title(f"marker path (L = {length} m)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--out", type=Path, default=Path("out/pendulum"))
    ap.add_argument("--every", type=int, default=10, help="keep every N-th sample (default 10)")
    ap.add_argument("--length", type=float, default=0.1528, help="pivot-marker distance, m")
    ap.add_argument("--per-segment", action="store_true",
                    help="one recording per segment instead of identification/validation")
    args = ap.parse_args(argv)
    if args.every < 1 or not args.length > 0:
        ap.error("--every must be >= 1 and --length > 0")
    import meshio

    from petsoft.io.recording import write_recording

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    segments, dt = load_segments(args.data)
    theta_all = np.concatenate([s[3] for s in segments])
    noise = angle_noise(theta_all)
    sigma = noise["savgol"]
    L = args.length
    eq = equivalent_model(L)
    print(f"{len(segments)} segments, {len(theta_all)} samples at {1 / dt:g} Hz; angle noise "
          f"{sigma:.3g} rad (2nd/3rd differences {noise['second_difference']:.3g}/"
          f"{noise['third_difference']:.3g}) -> position_std {L * sigma:.3g} m")

    if args.per_segment:
        groups = [(f"{k}{i}", [(t, th, om)]) for k, i, t, th, om in segments]
    else:
        groups = [(name, [(t, th, om) for k, _, t, th, om in segments if k == kind])
                  for name, kind in (("identification", "id"), ("validation", "val"))]
    meshio.write(out / "pendulum.msh",
                 meshio.Mesh(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -L]]),
                             [("line", np.array([[0, 1]]))],
                             cell_data={"gmsh:physical": [np.array([1])],
                                        "gmsh:geometrical": [np.array([1])]}),
                 file_format="gmsh22", binary=False)
    written = []
    for name, parts in groups:
        # the file's times are k * 1 ms up to float fuzz (1e-14 s): round to whole nanoseconds
        t = np.round(np.concatenate([p[0] for p in parts])[::args.every], 9)
        th = np.concatenate([p[1] for p in parts])[::args.every]
        om = np.concatenate([p[2] for p in parts])[::args.every]
        offset = float(t[0])
        pos = marker_positions(th, L)[:, None, :]
        rec = write_recording(
            out / f"{name}.h5", np.array([[0.0, 0.0, -L]]), t - offset, pos, names=["bob"],
            attrs={"source": f"scripts/examples/import_pendulum.py: {args.data.name} ({name}, "
                             f"every "
                             f"{args.every} samples); Kaheman et al. 2022, MIT licence",
                   "time_offset": offset, "length": L},
            noise={"position_std": L * sigma})
        # per segment: pendulum_id0.toml ... (each with its own segment's initial state; "id"
        # for all four overwrote id0..id2 with id3's)
        short = {"identification": "id", "validation": "val"}.get(name, name)
        toml = out / f"pendulum_{short}.toml"
        write_experiment(toml, "pendulum.msh", L, eq["point_mass"], round(float(t[-1] - offset), 9),
                         round(dt * args.every, 12), float(th[0]), float(om[0]), rec.name)
        written.append((rec, toml, len(t), offset))
        print(f"wrote {rec} ({len(t)} frames, {t[-1] - offset:.3f} s from t = {offset:g} s) "
              f"and {toml.name}")
    (out / "published.json").write_text(json.dumps(
        {"source": "Kaheman et al. 2022, arXiv:2205.06231 (physical pendulum fit)",
         "published": PUBLISHED, "equivalent_point_mass_model": eq,
         "angle_noise_rad": noise, "position_std_m": L * sigma}, indent=2) + "\n")
    # decay envelope: peaks of |theta - pi| per half swing (1 kHz data)
    dev = theta_all - np.pi
    t_all = np.concatenate([s[2] for s in segments])
    peaks = np.flatnonzero((np.abs(dev[1:-1]) >= np.abs(dev[:-2]))
                           & (np.abs(dev[1:-1]) > np.abs(dev[2:]))) + 1
    peaks = peaks[np.abs(dev[peaks]) > 0.05]
    colours = {"id": "tab:blue", "val": "tab:orange"}
    names = {"id": "identification", "val": "validation"}
    parts = [(names[k] if i == 0 else None, t, th, colours[k]) for k, i, t, th, _ in segments]
    plot(out / "pendulum.png", parts, (t_all[peaks], np.abs(dev[peaks])), L)
    print(f"wrote {out / 'published.json'} and {out / 'pendulum.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
