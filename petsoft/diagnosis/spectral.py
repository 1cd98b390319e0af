"""Dominant modes of multichannel motion and the shape of its amplitude decay.

This module owns the frequency-domain evidence of a mismatch:

* :func:`dominant_modes` -- frequency (Hz), decay rate (1/s) and amplitude of the dominant
  damped oscillations shared by all channels (ESPRIT / matrix pencil on the stacked channels);
* :func:`compare_modes` -- data modes matched to simulated modes: frequency and decay-rate shifts
  (a decay shift at an unchanged frequency points at damping, a common frequency ratio at
  stiffness or mass);
* :func:`decay_envelope` -- the amplitude envelope of a free decay fitted by an exponential
  (viscous damping), a straight line (dry / Coulomb friction) and ``1 / (1 + b t)`` (quadratic
  drag), and the best by residual.


:func:`dominant_modes`, :func:`fill_gaps` and :class:`SpectralError` live in
:mod:`petsoft.calibration.spectra` (calibration from recorded frequencies uses them too; the
method is described there) and are re-exported here.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import optimize, signal

from petsoft.calibration.spectra import SpectralError, dominant_modes, fill_gaps, uniform_step

__all__ = ["SpectralError", "dominant_modes", "compare_modes", "decay_envelope",
           "friction_terms", "rayleigh_from_decays", "fill_gaps", "principal_signal"]


def compare_modes(data_modes: list[dict], sim_modes: list[dict], *, rel_tol: float = 0.25,
                  min_amplitude: float = 0.05) -> dict:
    """Match data modes to simulated modes by frequency and report the shifts.

    Oscillatory data modes with at least ``min_amplitude`` of the largest amplitude are taken in
    order of amplitude; each is matched to the nearest unmatched simulated mode within
    ``rel_tol`` relative frequency.

    Returns
    -------
    dict
        ``matched``: list of ``{data_hz, sim_hz, frequency_shift_hz (data - sim),
        relative_frequency_shift, data_decay, sim_decay, decay_shift (data - sim)}``;
        ``unmatched_data`` / ``unmatched_sim``: frequencies (Hz) with no partner;
        ``frequency_ratio``: median data/sim frequency ratio (a common ratio != 1 suggests
        stiffness or mass: f ~ sqrt(k / m)); ``hints``: plain-language readings.
    """
    def osc(modes):
        modes = [m for m in modes if m["frequency_hz"] > 0]
        top = max((m["amplitude"] for m in modes), default=0.0)
        return [m for m in modes if m["amplitude"] >= min_amplitude * top]

    dm, sm = osc(data_modes), osc(sim_modes)
    free = list(range(len(sm)))
    matched, unmatched = [], []
    for m in dm:
        if not free:
            unmatched.append(m["frequency_hz"])
            continue
        rel = [abs(sm[j]["frequency_hz"] - m["frequency_hz"]) / m["frequency_hz"] for j in free]
        best = int(np.argmin(rel))
        if rel[best] > rel_tol:
            unmatched.append(m["frequency_hz"])
            continue
        s = sm[free.pop(best)]
        matched.append({"data_hz": m["frequency_hz"], "sim_hz": s["frequency_hz"],
                        "frequency_shift_hz": m["frequency_hz"] - s["frequency_hz"],
                        "relative_frequency_shift": m["frequency_hz"] / s["frequency_hz"] - 1.0,
                        "data_decay": m["decay_rate"], "sim_decay": s["decay_rate"],
                        "decay_shift": m["decay_rate"] - s["decay_rate"]})
    ratio = float(np.median([1 + x["relative_frequency_shift"] for x in matched])) if matched \
        else float("nan")
    hints = []
    for x in matched:
        if x["decay_shift"] > 0.1 * max(abs(x["sim_decay"]), 0.01 * 2 * np.pi * x["sim_hz"]):
            hints.append(f"the {x['data_hz']:.3g} Hz mode decays faster in the data "
                         f"({x['data_decay']:.3g} vs {x['sim_decay']:.3g} 1/s): missing damping")
        elif x["decay_shift"] < -0.1 * max(abs(x["sim_decay"]), 0.01 * 2 * np.pi * x["sim_hz"]):
            hints.append(f"the {x['data_hz']:.3g} Hz mode decays slower in the data "
                         f"({x['data_decay']:.3g} vs {x['sim_decay']:.3g} 1/s): too much damping "
                         "in the model (numerical damping of the integrator?)")
    if matched and abs(ratio - 1) > 0.005:
        hints.append(f"data frequencies are {ratio:.4f} x the simulated ones: stiffness or mass "
                     f"off by a factor ~{ratio**2:.4f} (f ~ sqrt(k / m))")
    if unmatched:
        hints.append(f"data modes at {', '.join(f'{f:.3g}' for f in unmatched)} Hz have no "
                     "simulated counterpart")
    return {"matched": matched, "unmatched_data": unmatched,
            "unmatched_sim": [sm[j]["frequency_hz"] for j in free], "frequency_ratio": ratio,
            "hints": hints}


def principal_signal(times: np.ndarray, signals: np.ndarray, min_seen: float = 0.5) -> np.ndarray:
    """The motion along the first principal direction of all (gap-filled) channels, (K,)."""
    x = fill_gaps(times, signals, min_seen)
    x = x - x.mean(axis=0)
    _, _, vt = np.linalg.svd(x, full_matrices=False)
    return x @ vt[0]


def _envelope_points(t: np.ndarray, y: np.ndarray, frequency: float | None):
    """Amplitude (half peak-to-trough) at each extremum; offset and slow drift cancel."""
    dt = t[1] - t[0]
    if frequency is None or frequency <= 0:
        spec = np.abs(np.fft.rfft((y - y.mean()) * np.hanning(len(y))))
        spec[0] = 0.0
        frequency = np.fft.rfftfreq(len(y), dt)[np.argmax(spec)]
    dist = max(1, int(0.6 / (frequency * dt)))
    hi, _ = signal.find_peaks(y, distance=dist)
    lo, _ = signal.find_peaks(-y, distance=dist)
    if len(hi) < 3 or len(lo) < 3:
        raise SpectralError("fewer than 3 oscillation peaks: no decay envelope to fit")
    ext = np.sort(np.concatenate([hi, lo]))
    te = t[ext]
    inside = (te >= max(t[hi[0]], t[lo[0]])) & (te <= min(t[hi[-1]], t[lo[-1]]))
    te = te[inside]
    upper = np.interp(te, t[hi], y[hi])
    lower = np.interp(te, t[lo], y[lo])
    return te, 0.5 * (upper - lower), frequency


def _curve_fit(*args, **kwargs):
    """scipy curve_fit without its covariance warning (a constant envelope has no curvature;
    only the parameters are used here)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optimize.OptimizeWarning)
        return optimize.curve_fit(*args, **kwargs)


def decay_envelope(times: np.ndarray, signals: np.ndarray, *, frequency: float | None = None,
                   min_seen: float = 0.5) -> dict:
    """Classify the decay of a free oscillation: exponential, linear or 1/t envelope.

    The amplitude ``A(t)`` at each extremum (half the distance between the upper and lower peak
    envelopes, so an offset or slow drift cancels) of the principal signal is fitted by
    least squares in ``A`` with three two-parameter laws, each the free decay under one friction:

    * ``exponential``: ``A0 exp(-d t)`` -- viscous (linear) damping, ``dA/dt ~ -A``;
    * ``linear``: ``A0 - c t`` -- dry (Coulomb) friction, ``dA/dt ~ -const``;
    * ``inverse``: ``A0 / (1 + b t)`` -- quadratic drag, ``dA/dt ~ -A^2``.

    The best is the smallest residual (equal parameter counts, so rms residuals compare
    directly). Also fitted: the general law ``dA/dt = -c A^p`` whose exponent ``p`` (0 dry,
    1 viscous, 2 quadratic) summarises a mixture, and the three-parameter viscous + dry law
    ``dA/dt = -a A - c`` (``viscous_plus_dry``: ``rate`` a, ``dry`` c, and the dry share of the
    decay ``c / (a A + c)`` at the first and last amplitude).

    Parameters
    ----------
    times : ndarray (K,)
        Uniform times (s).
    signals : ndarray (K,), (K, C) or (K, M, 3)
        One signal, or channels reduced to their principal component.
    frequency : float, optional
        Oscillation frequency (Hz) to space the peaks; default the FFT peak.

    Returns
    -------
    dict
        ``best`` ("exponential", "linear" or "inverse"), ``friction`` (viscous / dry /
        quadratic), ``fits`` {law: {params..., rms}}, ``ratio`` (second-best rms / best rms),
        ``exponent_p``, ``viscous_plus_dry`` (None if that fit failed), ``times`` and
        ``amplitudes`` (the envelope points).
    """
    t = np.asarray(times, dtype=float)
    uniform_step(t)
    y = np.asarray(signals, dtype=float)
    y = y.reshape(len(t), -1)
    y = fill_gaps(t, y, min_seen)[:, 0] if y.shape[1] == 1 else principal_signal(t, y, min_seen)
    te, amp, freq = _envelope_points(t, y, frequency)
    if len(te) < 5:
        raise SpectralError(f"only {len(te)} envelope points; record more cycles")
    t0 = te[0]
    s = te - t0
    a0 = amp[0]
    fits = {}
    laws = {
        "exponential": (lambda s, a, d: a * np.exp(-d * s),
                        lambda: np.polyfit(s, np.log(np.maximum(amp, 1e-300)), 1)),
        "linear": (lambda s, a, c: a - c * s, lambda: np.polyfit(s, amp, 1)),
        "inverse": (lambda s, a, b: a / (1 + b * s), lambda: np.polyfit(s, 1 / amp, 1)),
    }
    for name, (law, lin) in laws.items():
        slope, icpt = lin()
        if name == "exponential":
            p0 = (np.exp(icpt), -slope)
        elif name == "linear":
            p0 = (icpt, -slope)
        else:
            p0 = (1 / icpt, slope / icpt) if icpt > 0 else (a0, 0.0)
        try:
            p, _ = _curve_fit(law, s, amp, p0=p0, maxfev=5000)
        except RuntimeError:
            p = np.asarray(p0, dtype=float)
        rms = float(np.sqrt(np.mean((law(s, *p) - amp) ** 2)))
        key = {"exponential": "rate", "linear": "slope", "inverse": "b"}[name]
        fits[name] = {"A0": float(p[0]), key: float(p[1]), "rms": rms}
    order = sorted(fits, key=lambda n: fits[n]["rms"])
    # General law: A^(1-p) = A0^(1-p) - (1 - p) c s, i.e. dA/dt = -c A^p (p = 1 as a limit).
    def general(s, a, c, p):
        if abs(1 - p) < 1e-6:
            return a * np.exp(-c * s)
        base = np.maximum(a ** (1 - p) - (1 - p) * c * s, 0.0)
        return base ** (1 / (1 - p))
    try:
        e = fits["exponential"]
        pg, _ = _curve_fit(general, s, amp, p0=(e["A0"], e["rate"], 1.01),
                                   bounds=([0, 0, -1.0], [np.inf, np.inf, 4.0]), maxfev=20000)
        exponent = float(pg[2])
    except (RuntimeError, ValueError):
        exponent = float("nan")
    # Viscous + dry together, dA/dt = -a A - c: A = (A0 + c/a) exp(-a s) - c/a. Three
    # parameters, so it is reported beside the two-parameter laws, not ranked with them.
    def mixed(s, a0, a, c):
        return (a0 + c / a) * np.exp(-a * s) - c / a
    try:
        e = fits["exponential"]
        pm, _ = _curve_fit(mixed, s, amp, p0=(e["A0"], max(e["rate"], 1e-6), 1e-9),
                                   bounds=([0, 1e-9, 0], [np.inf, np.inf, np.inf]), maxfev=20000)
        rms_m = float(np.sqrt(np.mean((mixed(s, *pm) - amp) ** 2)))
        both = {"A0": float(pm[0]), "rate": float(pm[1]), "dry": float(pm[2]), "rms": rms_m,
                "dry_share_start": float(pm[2] / (pm[1] * pm[0] + pm[2])),
                "dry_share_end": float(pm[2] / (pm[1] * amp[-1] + pm[2]))}
    except (RuntimeError, ValueError):
        both = None
    friction = {"exponential": "viscous", "linear": "dry", "inverse": "quadratic"}
    return {"best": order[0], "friction": friction[order[0]], "fits": fits,
            "viscous_plus_dry": both,
            "ratio": fits[order[1]]["rms"] / max(fits[order[0]]["rms"], 1e-300),
            "exponent_p": exponent, "frequency_hz": float(freq), "t0": float(t0),
            "times": te, "amplitudes": amp}


def friction_terms(envelope: dict, span: int = 4) -> dict:
    """Which friction laws explain the decay *rate*: ``-dA/dt = c0 + c1 A + c2 A^2``.

    The envelope's own slope, ``-(A[i+span] - A[i]) / (t[i+span] - t[i])`` at the mean
    amplitude, is regressed on ``1`` (dry / Coulomb), ``A`` (viscous) and ``A^2`` (quadratic
    drag) with non-negative coefficients (scipy ``nnls``: friction never feeds energy in), for
    every subset of the three terms. Unlike :func:`decay_envelope`'s single-law fits this
    separates a mixture, e.g. dry friction that dominates at small amplitude and drag at large.

    Parameters
    ----------
    envelope : dict
        The result of :func:`decay_envelope` (its ``times`` and ``amplitudes``).
    span : int
        Envelope points per slope (4 = two cycles: extrema alternate max / min, so an even span
        cancels a residual offset between the two).

    Returns
    -------
    dict
        ``coefficients`` {"dry": c0, "viscous": c1, "quadratic": c2} of the full fit,
        ``subsets`` {"+".join(terms): {"coefficients", "rms"}} for all 7 subsets, and ``best``:
        the subset with the fewest terms whose rms is within 1.5 x the full fit's (the slopes
        carry their own finite-difference error, so a term must cut the rms by a third to
        count).
    """
    from itertools import combinations

    te = np.asarray(envelope["times"], dtype=float)
    amp = np.asarray(envelope["amplitudes"], dtype=float)
    if len(te) < span + 3:
        raise SpectralError(f"only {len(te)} envelope points; need > {span + 2}")
    rate = -(amp[span:] - amp[:-span]) / (te[span:] - te[:-span])
    a = 0.5 * (amp[span:] + amp[:-span])
    basis = {"dry": np.ones_like(a), "viscous": a, "quadratic": a * a}
    names = list(basis)
    subsets = {}
    for n in (1, 2, 3):
        for combo in combinations(names, n):
            x = np.column_stack([basis[c] for c in combo])
            coef, _ = optimize.nnls(x, rate)
            rms = float(np.sqrt(np.mean((x @ coef - rate) ** 2)))
            subsets["+".join(combo)] = {"coefficients": dict(zip(combo, map(float, coef),
                                                                 strict=True)), "rms": rms}
    full = subsets["+".join(names)]
    best = min((k for k in subsets if subsets[k]["rms"] <= 1.5 * full["rms"]),
               key=lambda k: (k.count("+"), subsets[k]["rms"]))
    return {"coefficients": full["coefficients"], "subsets": subsets, "best": best}


def rayleigh_from_decays(matched: list[dict]) -> dict:
    """Split the extra modal decay of the data into Rayleigh mass and stiffness damping.

    With damping ``C = alpha M + beta K`` a mode of angular frequency ``w`` decays at
    ``d = (alpha + beta w^2) / 2``. The decay shifts ``data - sim`` of the matched modes
    (:func:`compare_modes`) are fitted by non-negative least squares in ``(alpha, beta)``:
    a shift that is the same for all modes points at ``damping.mass``, one growing as ``w^2``
    at ``damping.stiffness``. With a single mode the split is undetermined and both one-term
    fits are returned.

    Returns
    -------
    dict
        ``alpha`` and ``beta`` (the two-term fit; None with fewer than 2 modes), ``mass_only``
        (alpha alone) and ``stiffness_only`` (beta alone) with their rms misfit (1/s), and
        ``dominant``: "damping.mass", "damping.stiffness" or None (undetermined).
    """
    if not matched:
        raise SpectralError("no matched modes to split the damping between mass and stiffness")
    w2 = np.array([(2 * np.pi * m["data_hz"]) ** 2 for m in matched])
    shift = np.array([m["decay_shift"] for m in matched])
    ones = np.ones_like(w2)
    a_only = max(float(np.mean(2 * shift)), 0.0)
    b_only = max(float(np.sum(2 * shift * w2) / np.sum(w2 * w2)), 0.0)
    rms_a = float(np.sqrt(np.mean((a_only / 2 * ones - shift) ** 2)))
    rms_b = float(np.sqrt(np.mean((b_only / 2 * w2 - shift) ** 2)))
    out = {"mass_only": {"alpha": a_only, "rms": rms_a},
           "stiffness_only": {"beta": b_only, "rms": rms_b}, "alpha": None, "beta": None,
           "dominant": None}
    if len(matched) >= 2:
        coef, _ = optimize.nnls(np.column_stack([ones, w2]) / 2, shift)
        out["alpha"], out["beta"] = float(coef[0]), float(coef[1])
        # Compare the two contributions at the matched modes' mean squared frequency.
        mass, stiff = coef[0], coef[1] * float(np.mean(w2))
        if max(mass, stiff) > 0:
            out["dominant"] = "damping.mass" if mass >= stiff else "damping.stiffness"
    return out
