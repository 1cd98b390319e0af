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

__all__ = ["collect_evidence", "write_figures"]


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
                     out: str | Path | None = None, min_share: float = 0.1) -> dict:
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
    dict
        ``noise_std``, ``noise_source``, ``noise_summary``, ``noise_test``
        (:class:`~petsoft.diagnosis.noise.ChiSquareResult`), ``verdict``, ``fit``
        ({rms, chi2_per_dof}), ``markers`` (:class:`~petsoft.diagnosis.locate.MarkerResiduals`),
        ``region``, ``windows``, ``data_modes``, ``sim_modes``, ``modes`` (comparison),
        ``residual_modes``, ``frequencies_hz``, ``envelope``, ``friction_terms``, ``notes``,
        ``field`` (path or None) and ``mismatch`` (the report's ``mismatch`` entries).
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
        if summary["gaussian"]:
            sigma, source = summary["std_mad"], "estimated from the data (robust)"
        else:
            sigma = summary["std_rms"]
            source = (f"estimated from the data (rms: the noise is heavy-tailed, kurtosis "
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
    terms = None
    if env is not None:
        terms, n5 = _safe(spectral.friction_terms, env)
        notes += [n5] if n5 else []
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
    verdict = "consistent" if test.consistent else "missing-physics"
    mismatch = {"markers": res.flagged_names, "time_windows": windows["intervals"],
                "frequencies_hz": freqs, "region": region}
    if verdict == "consistent":      # nothing to locate when the residual is noise
        mismatch = {"markers": [], "time_windows": [], "frequencies_hz": [], "region": None}
    return {"noise_std": float(sigma), "noise_source": source, "noise_summary": summary,
            "noise_test": test, "verdict": verdict, "fit": fit, "markers": res,
            "region": region, "windows": windows, "data_modes": data_modes,
            "sim_modes": sim_modes, "modes": modes, "residual_modes": residual_modes,
            "frequencies_hz": freqs, "envelope": env, "friction_terms": terms,
            "notes": notes, "field": field, "mismatch": mismatch}


def write_figures(out: str | Path, evidence: dict, times: np.ndarray, data: np.ndarray,
                  sim: np.ndarray, after: np.ndarray | None = None, added=(),
                  rejected=()) -> list[Path]:
    """The report's standard figures from :func:`collect_evidence` output; returns the PNGs."""
    out = Path(out)
    figs = [report.plot_marker_residuals(out / "residual_markers.png", evidence["markers"],
                                         evidence["noise_std"]),
            report.plot_residual_time(out / "residual_time.png", times, evidence["windows"])]
    if evidence["data_modes"] is not None and evidence["sim_modes"] is not None:
        figs.append(report.plot_spectra(out / "spectra.png", times, data, sim,
                                        evidence["data_modes"], evidence["sim_modes"]))
    if added or rejected:
        figs.append(report.plot_candidate_scores(out / "candidates.png", added, rejected))
    res = evidence["markers"]
    worst = [int(i) for i in np.argsort(-np.nan_to_num(res.rms, nan=-1.0))[:3]]
    figs.append(report.plot_trajectories(out / "trajectories.png", times, data, sim, after,
                                         res.names, worst))
    return figs
