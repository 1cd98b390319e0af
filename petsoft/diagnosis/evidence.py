"""All array-only evidence of a mismatch in one call, in the shape the report wants.

This module owns the sequence the ``petsoft diagnose`` command runs on a (data, simulation) pair
before and after each candidate physics: noise level (given or estimated), the verdict
(chi-square level + whiteness), which markers, where on the body, when, at which frequencies,
mode shifts and the decay envelope's friction law. No solver runs here; the caller simulates.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from petsoft.diagnosis import locate, noise, report, spectral
from petsoft.diagnosis.records import Evidence
from petsoft.terms import TERMS

__all__ = ["collect_evidence", "suggest_physics", "write_figures"]


def _safe(fn, *args, **kwargs):
    """Run one spectral step; a signal it cannot analyse is a note, not a failed diagnosis."""
    try:
        return fn(*args, **kwargs), None
    except spectral.SpectralError as exc:
        return None, f"{fn.__name__}: {exc}"


def collect_evidence(data: np.ndarray, sim: np.ndarray, times: np.ndarray,
                     reference: np.ndarray, names: list[str], *, sigma: float | None = None,
                     num_parameters: int = 0, alpha: float = 0.01,
                     points: np.ndarray | None = None, tets: np.ndarray | None = None,
                     out: str | Path | None = None, min_share: float = 0.1) -> Evidence:
    """Analyse ``data - sim``: noise, verdict, markers, region, time windows, frequencies.

    Parameters
    ----------
    data, sim : ndarray (K, M, 3)
        Recorded (NaN = unseen) and simulated marker positions.
    times : ndarray (K,)
        Frame times (uniform for the spectral parts; otherwise those are skipped with a note).
    reference : ndarray (M, 3)
        Marker positions in the reference configuration.
    names : list of str
        Marker names.
    sigma : float, optional
        Position noise std (the recording's ``/noise``); estimated from ``data`` when None:
        the robust scale, or the rms scale when the noise is heavy-tailed
        (:func:`~petsoft.diagnosis.noise.noise_summary`).
    num_parameters : int
        Parameters fitted to produce ``sim``.
    alpha : float
        Significance level of the verdict and the localisation tests.
    points, tets : ndarray, optional
        The mesh; with ``out`` the nodal residual field is written to
        ``out/residual_field.xdmf``.
    out : path, optional
        Directory for the field.
    min_share : float
        Residual modes with at least this share of the largest residual mode's amplitude are
        the mismatch frequencies.

    Returns
    -------
    Evidence
        ``noise_std``, ``noise_source``, ``noise_summary``, ``noise_test``
        (:class:`~petsoft.diagnosis.noise.ChiSquareResult`), ``verdict``, ``fit``
        ({rms, chi2_per_dof}), ``markers`` (:class:`~petsoft.diagnosis.locate.MarkerResiduals`),
        ``region``, ``windows``, ``data_modes``, ``sim_modes``, ``modes`` (comparison),
        ``residual_modes``, ``frequencies_hz``, ``envelope``, ``friction_terms`` (data),
        ``sim_friction_terms`` (the simulation's, same peaks spacing), ``notes``,
        ``field`` (path or None), ``mismatch`` (the report's ``mismatch`` entries), ``offset``
        (mean residual per axis, m), ``offset_z`` (it over its white-noise standard error),
        ``axis_rms`` (residual rms per axis), ``offset_halves`` (2, 3) (the mean residual of each
        half of the record), ``duration``.
    """
    data = np.asarray(data, dtype=float)
    sim = np.asarray(sim, dtype=float)
    t = np.asarray(times, dtype=float)
    notes = []
    summary = None
    try:
        summary = noise.noise_summary(data, t)
    except noise.NoiseError as exc:
        notes.append(f"noise summary: {exc}")
    if sigma is None:
        if summary is None:
            raise noise.NoiseError("the recording has no /noise and the noise cannot be "
                                   "estimated from its positions (too few consecutive frames)")
        sigma = noise.summary_std(summary)
        source = ("estimated from the data (robust)" if summary["gaussian"] else
                  f"estimated from the data (rms: the noise is heavy-tailed, kurtosis "
                  f"{summary['kurtosis']:.3g})")
    else:
        source = "given by the recording"
    residual = data - sim
    test = noise.chi_square_test(residual, sigma, num_parameters, alpha)
    fit = report.fit_summary(data, sim, sigma, num_parameters)
    res = locate.marker_residuals(data, sim, names, sigma, alpha=alpha)
    region = locate.mismatch_region(reference, res)
    windows = locate.mismatch_time_windows(data, sim, t, sigma, alpha=alpha)
    data_modes, n1 = _safe(spectral.dominant_modes, t, data)
    sim_modes, n2 = _safe(spectral.dominant_modes, t, sim)
    residual_modes, n3 = _safe(spectral.dominant_modes, t, residual)
    env, n4 = _safe(spectral.decay_envelope, t, data)
    notes += [n for n in (n1, n2, n3, n4) if n]
    modes = spectral.compare_modes(data_modes, sim_modes) if data_modes and sim_modes else None
    terms = sim_terms = None
    if env is not None:
        terms, n5 = _safe(spectral.friction_terms, env)
        notes += [n5] if n5 else []
        sim_env, _ = _safe(spectral.decay_envelope, t, sim, frequency=env["frequency_hz"])
        if sim_env is not None:
            sim_terms, _ = _safe(spectral.friction_terms, sim_env)
    freqs = []
    if residual_modes and not test.consistent:
        osc = [m for m in residual_modes if m["frequency_hz"] > 0]
        top = max((m["amplitude"] for m in osc), default=0.0)
        freqs = sorted({round(m["frequency_hz"], 6) for m in osc
                        if m["amplitude"] >= min_share * top})
    field = None
    if points is not None and tets is not None and out is not None:
        field = locate.write_residual_field(Path(out) / "residual_field.xdmf", points, tets,
                                            reference, res)
    # Mean residual over all seen frames and markers, per axis, in units of its standard error:
    # a significant common offset is what a wrong body force leaves after calibration.
    seen = np.isfinite(residual)
    n_axis = seen.sum(axis=(0, 1))
    offset = np.where(n_axis > 0, np.nansum(residual, axis=(0, 1)) / np.maximum(n_axis, 1), 0.0)
    offset_z = offset / (sigma / np.sqrt(np.maximum(n_axis, 1)))
    halves = [np.nanmean(residual[part], axis=(0, 1)) if np.isfinite(residual[part]).any()
              else np.zeros(3) for part in (slice(0, len(t) // 2), slice(len(t) // 2, None))]
    axis_rms = np.sqrt(np.nansum(residual**2, axis=(0, 1)) / np.maximum(n_axis, 1))
    verdict = "consistent" if test.consistent else "missing-physics"
    mismatch = {"markers": res.flagged_names, "time_windows": windows["intervals"],
                "frequencies_hz": freqs, "region": region}
    if verdict == "consistent":      # nothing to locate when the residual is noise
        mismatch = {"markers": [], "time_windows": [], "frequencies_hz": [], "region": None}
    return Evidence(noise_std=float(sigma), noise_source=source, noise_summary=summary,
                    noise_test=test, verdict=verdict, fit=fit, markers=res, region=region,
                    windows=windows, data_modes=data_modes, sim_modes=sim_modes, modes=modes,
                    residual_modes=residual_modes, frequencies_hz=freqs, envelope=env,
                    friction_terms=terms, sim_friction_terms=sim_terms, notes=notes,
                    field=field, mismatch=mismatch, offset=offset, offset_z=offset_z,
                    axis_rms=axis_rms, offset_halves=np.array(halves),
                    duration=float(t[-1] - t[0]))


def suggest_physics(evidence: Evidence, *, offset_z: float = 10.0) -> list[dict]:
    """A first ordering of candidate physics from the evidence, each with its reason.

    This is a prior for the candidate search, not its result: ``petsoft diagnose`` adds each
    candidate, re-calibrates and scores the improvement. The rules read the evidence the
    way the notes of formats.md section 3 describe each physics:

    * data modes decaying faster than the simulation's: Rayleigh damping, split into mass and
      stiffness parts by :func:`~petsoft.diagnosis.spectral.rayleigh_from_decays`;
    * the decay-rate regression (:func:`~petsoft.diagnosis.spectral.friction_terms`) of the data
      minus that of the simulation, each term's excess as a share of the data's decay rate at
      its mean amplitude (> 10% counts): dry -> ``friction.dry``, quadratic ->
      ``drag.quadratic``, viscous -> ``damping.mass`` (and ``drag.linear``);
    * a frequency ratio left after calibration: lower data frequencies -> ``boundary.compliance``
      and ``mass.added``, higher -> ``material.nonlinear``; with a ``mismatch.region``,
      ``material.heterogeneous`` / ``mass.added`` there;
    * a common, steady offset of the residual (``offset_z`` standard errors, a fifth of the
      residual's rms along that axis, within 50% between the two halves of the record) ->
      ``gravity``;
    * mismatch windows covering less than half the record -> ``contact.plane``.

    Returns
    -------
    list of dict
        ``{"physics", "reason", "strength"}``, strongest first, each physics once; empty when
        the verdict is ``consistent``.
    """
    if evidence.verdict == "consistent":
        return []
    out: dict[str, dict] = {}

    def add(name: str, strength: float, evidence: str, **values) -> None:
        # the words are the term's own (petsoft.terms), filled with this evidence's numbers
        if name not in out or out[name]["strength"] < strength:
            out[name] = {"physics": name, "reason": TERMS[name].hint(evidence, **values),
                         "strength": float(strength)}

    modes = evidence.modes
    if modes and modes["matched"]:
        faster = [m for m in modes["matched"]
                  if m["decay_shift"] > 0.1 * max(abs(m["sim_decay"]), 0.01 * 2 * np.pi
                                                  * m["sim_hz"])]
        if faster:
            split = spectral.rayleigh_from_decays(faster)
            first = split["dominant"] or "damping.mass"
            second = "damping.stiffness" if first == "damping.mass" else "damping.mass"
            rel = max(m["decay_shift"] / max(m["data_decay"], 1e-12) for m in faster)
            # The modal decays are exponential fits whatever the law, so they point at damping
            # less strongly than the envelope's own law does (strengths below 3).
            add(first, 2.0 + min(rel, 1.0), "faster modes", count=len(faster),
                data=faster[0]["data_decay"], sim=faster[0]["sim_decay"])
            add(second, 1.0 + min(rel, 1.0) / 2, "partly")
        ratio = modes["frequency_ratio"]
        if np.isfinite(ratio) and abs(ratio - 1) > 0.005:
            shift = f"data frequencies {ratio:.4f} x the model's after calibration"
            if evidence.region is not None:
                add("material.heterogeneous", 2.5, "localised shift", shift=shift)
                add("mass.added", 2.4 if ratio < 1 else 1.2, "localised shift", shift=shift)
            if ratio < 1:
                add("boundary.compliance", 2.0, "lower frequencies", shift=shift)
                add("mass.added", 1.8, "lower frequencies", shift=shift)
            else:
                add("material.nonlinear", 1.8, "higher frequencies", shift=shift)
    terms = evidence.friction_terms
    if terms is not None:
        # Only what the data's decay has beyond the simulation's: each term's share of the
        # data's decay rate at its mean amplitude.
        coef = terms["coefficients"]
        sim_coef = (evidence.sim_friction_terms or {}).get("coefficients",
                                                           dict.fromkeys(coef, 0.0))
        amp = float(np.mean(evidence.envelope["amplitudes"]))
        powers = {"dry": 1.0, "viscous": amp, "quadratic": amp * amp}
        rate = sum(coef[k] * p for k, p in powers.items())
        share = {k: (coef[k] - sim_coef[k]) * p / rate if rate > 0 else 0.0
                 for k, p in powers.items()}
        law = evidence.envelope["best"]
        if share["dry"] > 0.1:
            add("friction.dry", 3.0 + share["dry"] + (law == "linear"), "constant envelope",
                share=share["dry"], law=law)
        if share["quadratic"] > 0.1:
            add("drag.quadratic", 3.0 + share["quadratic"] + (law == "inverse"),
                "quadratic envelope", share=share["quadratic"])
        if share["viscous"] > 0.1:
            add("damping.mass", 3.0 + share["viscous"] + (law == "exponential"),
                "viscous envelope", share=share["viscous"])
            add("drag.linear", 1.5 + share["viscous"] / 2, "viscous envelope")
    # A common offset: significant against white noise (offset_z) and a fifth of the
    # residual's rms along that axis (a correlated residual's mean alone is no offset).
    oz = np.asarray(evidence.offset_z, dtype=float)
    big = np.abs(np.asarray(evidence.offset)) > 0.2 * np.asarray(evidence.axis_rms)
    # ... and the same in both halves of the record: a wrong body force shifts the equilibrium
    # for good, while an amplitude error of a rotating body shifts the mean of its vertical
    # coordinate by an amount that changes as the amplitudes drift apart.
    halves = np.asarray(evidence.offset_halves)
    steady = np.abs(halves[0] - halves[1]) < 0.5 * np.abs(np.asarray(evidence.offset))
    oz = np.where(big & steady, oz, 0.0)
    if np.max(np.abs(oz)) > offset_z:
        axis = "xyz"[int(np.argmax(np.abs(oz)))]
        add("gravity", 2.0 + min(np.max(np.abs(oz)) / 100.0, 2.0), "offset", axis=axis,
            offset=evidence.offset[int(np.argmax(np.abs(oz)))])
    windows = evidence.windows.get("intervals", [])
    covered = sum(b - a for a, b in windows)
    if windows and covered < 0.5 * evidence.duration:
        add("contact.plane", 1.0, "intermittent", count=len(windows), covered=covered,
            duration=evidence.duration)
    return sorted(out.values(), key=lambda c: -c["strength"])


def write_figures(out: str | Path, evidence: Evidence, times: np.ndarray, data: np.ndarray,
                  sim: np.ndarray, modes: bool = True) -> list[Path]:
    """The evidence's figures (residual per marker, over time, the identification window's
    spectra with the fitted modes) from :func:`collect_evidence` output; returns the PNGs.
    The diagnosis adds its own (:mod:`petsoft.diagnosis.figures`) and asks for no modes.png
    (``modes=False``): its spectra.png marks the modes."""
    out = Path(out)
    figs = [report.plot_marker_residuals(out / "residual_markers.png", evidence.markers,
                                         evidence.noise_std)["path"],
            report.plot_residual_time(out / "residual_time.png", times,
                                      evidence.windows)["path"]]
    if modes and evidence.data_modes is not None and evidence.sim_modes is not None:
        figs.append(report.plot_spectra(out / "modes.png", times, data, sim,
                                        evidence.data_modes, evidence.sim_modes))
    return figs
