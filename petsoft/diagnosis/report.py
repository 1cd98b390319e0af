"""The diagnosis report: report.json (formats.md section 3), report.md and its figures.

This module owns the report's contract: :func:`build_report` assembles the dict, exactly the keys
of formats.md section 3; :func:`validate_report` checks one strictly (unknown or missing keys,
wrong types, non-finite numbers, physics names outside :data:`PHYSICS`) and raises
:class:`ReportError` naming the key; :func:`write_report` writes it atomically (temporary file +
:func:`os.replace`, so a reader never sees half a report); :func:`write_report_md` says the
evidence in plain words; the ``plot_*`` functions draw the figures (matplotlib, PNG).

Two readings of formats.md that the example leaves open, decided here:

* ``fit.validation`` may be absent (or null) when there is no validation recording;
* ``mismatch.region`` is null when no marker stands out (the mismatch is everywhere or nowhere).

``rms`` everywhere is per coordinate, ``sqrt(mean(r^2))`` over all seen marker coordinates and
frames, so it is directly comparable with ``noise_std`` (a consistent fit has rms ~ noise_std).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from petsoft.errors import PetsoftError

__all__ = ["PHYSICS", "VERDICTS", "ReportError", "fit_summary", "build_report",
           "validate_report", "write_report", "read_report", "write_report_md",
           "plot_marker_residuals", "plot_residual_time", "plot_spectra"]

FORMAT = "petsoft-diagnosis"
VERSION = 1
VERDICTS = ("consistent", "missing-physics")

#: The physics vocabulary of formats.md section 3 (extend it, never rename).
PHYSICS = {
    "damping.mass": "viscous damping proportional to mass (Rayleigh alpha; air, internal losses)",
    "damping.stiffness": "viscous damping proportional to stiffness (Rayleigh beta; material "
                         "losses)",
    "gravity": "missing or wrong body force",
    "material.nonlinear": "the material law is nonlinear at the observed strains",
    "material.heterogeneous": "stiffness varies in space; mismatch.region says where",
    "material.viscoelastic": "rate-dependent stress relaxation (Kelvin-Voigt / standard linear "
                             "solid)",
    "boundary.compliance": "the support is elastic, not rigid",
    "mass.added": "extra mass attached (sensor, fixture); mismatch.region says where",
    "drag.linear": "velocity-dependent (linear) drag from the surrounding air/fluid",
    "drag.quadratic": "velocity-squared drag from the surrounding air/fluid",
    "friction.dry": "Coulomb (rate-independent) friction in joints or contacts",
    "contact.plane": "unmodelled contact with a plane (floor, wall)",
}


class ReportError(PetsoftError):
    """A diagnosis report does not follow formats.md section 3; the message names the key."""


# ---------------------------------------------------------------------------------------------
# building


def fit_summary(data: np.ndarray, sim: np.ndarray, sigma: float,
                num_parameters: int = 0) -> dict:
    """``{"rms", "chi2_per_dof"}`` of ``data - sim`` over seen coordinates (module docstring).

    Parameters
    ----------
    data, sim : ndarray (K, M, 3)
        Recorded (NaN = unseen) and simulated positions.
    sigma : float
        Noise standard deviation (m).
    num_parameters : int
        Fitted parameters, subtracted from the degrees of freedom.
    """
    r = np.asarray(data, dtype=float) - np.asarray(sim, dtype=float)
    seen = np.isfinite(r)
    n = int(seen.sum())
    if n == 0:
        raise ReportError("fit_summary: no seen marker coordinate to compare")
    if not (np.isfinite(sigma) and sigma > 0):
        raise ReportError(f"fit_summary: sigma = {sigma} must be finite and > 0")
    ss = float(np.sum(r[seen] ** 2))
    return {"rms": math.sqrt(ss / n),
            "chi2_per_dof": ss / sigma**2 / max(n - int(num_parameters), 1)}


def _num(x) -> float:
    return float(x)


def build_report(*, verdict: str, noise_std: float, base: Mapping, final: Mapping,
                 parameters: Mapping[str, float], validation: Mapping | None = None,
                 markers: Sequence[str] = (), time_windows: Sequence = (),
                 frequencies_hz: Sequence[float] = (), region: Mapping | None = None,
                 added: Sequence[Mapping] = (), rejected: Sequence[Mapping] = (),
                 numerics: Mapping | None = None) -> dict:
    """Assemble a report dict in the layout of formats.md section 3 and validate it.

    Parameters
    ----------
    verdict : {"consistent", "missing-physics"}
    noise_std : float
        Position noise standard deviation used (m).
    base, final : mapping
        ``{"rms", "chi2_per_dof"}`` of the user's model and of the final model
        (:func:`fit_summary`).
    parameters : mapping of str to float
        Final parameter values.
    validation : mapping, optional
        ``{"base_rms", "final_rms"}`` on the validation recording.
    markers, time_windows, frequencies_hz, region
        The ``mismatch`` entries (:mod:`petsoft.diagnosis.locate`, :mod:`.spectral`).
    added, rejected : sequence of mapping
        Candidate physics kept (in the order added) and rejected.

    Returns
    -------
    dict
        JSON-ready (Python floats, lists).

    Raises
    ------
    ReportError
        Whatever :func:`validate_report` rejects.
    """
    fit = {"base": {"rms": _num(base["rms"]), "chi2_per_dof": _num(base["chi2_per_dof"])},
           "final": {"rms": _num(final["rms"]), "chi2_per_dof": _num(final["chi2_per_dof"])}}
    if validation is not None:
        fit["validation"] = {"base_rms": _num(validation["base_rms"]),
                             "final_rms": _num(validation["final_rms"])}
    report = {
        "format": FORMAT, "version": VERSION, "verdict": verdict,
        "noise_std": _num(noise_std),
        "fit": fit,
        "mismatch": {
            "markers": [str(m) for m in markers],
            "time_windows": [[_num(a), _num(b)] for a, b in time_windows],
            "frequencies_hz": [_num(f) for f in frequencies_hz],
            "region": None if region is None else {
                "center": [_num(c) for c in region["center"]],
                "radius": _num(region["radius"])},
        },
        "added": [{"physics": a["physics"],
                   "parameters": {str(k): _num(v) for k, v in a["parameters"].items()},
                   "std": {str(k): _num(v) for k, v in a.get("std", {}).items()},
                   "score": _num(a["score"]), "rms_after": _num(a["rms_after"]),
                   "evidence": a["evidence"]} for a in added],
        "rejected": [{"physics": r["physics"], "score": _num(r["score"]),
                      "reason": r["reason"]} for r in rejected],
        "parameters": {str(k): _num(v) for k, v in parameters.items()},
    }
    if numerics is not None:     # what the numerics checks found (diagnosis/numerics_findings)
        report["numerics"] = dict(numerics)
    validate_report(report)
    return report


# ---------------------------------------------------------------------------------------------
# validation


def _fail(key: str, message: str):
    raise ReportError(f"report key {key!r}: {message}")


def _keys(obj, key: str, required: set, optional: frozenset = frozenset()) -> None:
    if not isinstance(obj, dict):
        _fail(key, f"must be an object, got {type(obj).__name__}")
    missing = sorted(required - set(obj))
    if missing:
        _fail(key, f"missing {', '.join(missing)} (required: {', '.join(sorted(required))})")
    unknown = sorted(set(obj) - required - optional)
    if unknown:
        allowed = ", ".join(sorted(required | optional))
        _fail(key, f"unknown {', '.join(unknown)} (allowed: {allowed})")


def _number(x, key: str, minimum: float | None = None, positive: bool = False) -> None:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        _fail(key, f"must be a number, got {x!r}")
    if not math.isfinite(x):
        _fail(key, f"must be finite, got {x!r}")
    if positive and not x > 0:
        _fail(key, f"must be > 0, got {x!r}")
    if minimum is not None and x < minimum:
        _fail(key, f"must be >= {minimum}, got {x!r}")


def _string(x, key: str) -> None:
    if not isinstance(x, str) or not x.strip():
        _fail(key, f"must be a non-empty string, got {x!r}")


def _list(x, key: str) -> None:
    if not isinstance(x, list):
        _fail(key, f"must be a list, got {type(x).__name__}")


def _physics(x, key: str) -> None:
    _string(x, key)
    if x not in PHYSICS:
        _fail(key, f"{x!r} is not in the physics vocabulary ({', '.join(PHYSICS)})")


def _param_map(x, key: str, minimum: float | None = None) -> None:
    if not isinstance(x, dict):
        _fail(key, f"must be an object of parameter name -> number, got {type(x).__name__}")
    for name, value in x.items():
        _string(name, f"{key} (a parameter name)")
        _number(value, f"{key}.{name}", minimum)


def validate_report(report: Mapping) -> None:
    """Check a report against formats.md section 3; raise :class:`ReportError` naming the key.

    Parameters
    ----------
    report : dict
        As built by :func:`build_report` or read back from JSON.
    """
    top = {"format", "version", "verdict", "noise_std", "fit", "mismatch", "added", "rejected",
           "parameters"}
    _keys(report, "(report)", top, frozenset({"numerics", "timings"}))
    for k, v in report.get("timings", {}).items():
        _number(v, f"timings.{k}")
    if "numerics" in report:
        _keys(report["numerics"], "numerics", {"findings"}, frozenset({"recommendation", "mesh"}))
        for i, f in enumerate(report["numerics"]["findings"]):
            _string(f, f"numerics.findings[{i}]")
    if report["format"] != FORMAT:
        _fail("format", f"must be {FORMAT!r}, got {report['format']!r}")
    if isinstance(report["version"], bool) or report["version"] != VERSION:
        _fail("version", f"must be {VERSION}, got {report['version']!r}")
    if report["verdict"] not in VERDICTS:
        _fail("verdict", f"must be one of {', '.join(VERDICTS)}, got {report['verdict']!r}")
    _number(report["noise_std"], "noise_std", positive=True)
    fit = report["fit"]
    _keys(fit, "fit", {"base", "final"}, frozenset({"validation"}))
    for part in ("base", "final"):
        _keys(fit[part], f"fit.{part}", {"rms", "chi2_per_dof"})
        _number(fit[part]["rms"], f"fit.{part}.rms", 0.0)
        _number(fit[part]["chi2_per_dof"], f"fit.{part}.chi2_per_dof", 0.0)
    if fit.get("validation") is not None:
        _keys(fit["validation"], "fit.validation", {"base_rms", "final_rms"})
        for k in ("base_rms", "final_rms"):
            _number(fit["validation"][k], f"fit.validation.{k}", 0.0)
    mm = report["mismatch"]
    _keys(mm, "mismatch", {"markers", "time_windows", "frequencies_hz", "region"})
    _list(mm["markers"], "mismatch.markers")
    for i, m in enumerate(mm["markers"]):
        _string(m, f"mismatch.markers[{i}]")
    if len(set(mm["markers"])) != len(mm["markers"]):
        _fail("mismatch.markers", "names a marker twice")
    _list(mm["time_windows"], "mismatch.time_windows")
    for i, w in enumerate(mm["time_windows"]):
        key = f"mismatch.time_windows[{i}]"
        if not isinstance(w, list) or len(w) != 2:
            _fail(key, f"must be a pair [t0, t1], got {w!r}")
        _number(w[0], key + "[0]")
        _number(w[1], key + "[1]")
        if w[1] < w[0]:
            _fail(key, f"t1 = {w[1]} is before t0 = {w[0]}")
    _list(mm["frequencies_hz"], "mismatch.frequencies_hz")
    for i, f in enumerate(mm["frequencies_hz"]):
        _number(f, f"mismatch.frequencies_hz[{i}]", 0.0)
    region = mm["region"]
    if region is not None:
        _keys(region, "mismatch.region", {"center", "radius"})
        c = region["center"]
        if not isinstance(c, list) or len(c) != 3:
            _fail("mismatch.region.center", f"must be [x, y, z], got {c!r}")
        for i, v in enumerate(c):
            _number(v, f"mismatch.region.center[{i}]")
        _number(region["radius"], "mismatch.region.radius", 0.0)
    _list(report["added"], "added")
    for i, a in enumerate(report["added"]):
        key = f"added[{i}]"
        _keys(a, key, {"physics", "parameters", "std", "score", "rms_after", "evidence"})
        _physics(a["physics"], key + ".physics")
        _param_map(a["parameters"], key + ".parameters")
        _param_map(a["std"], key + ".std", 0.0)
        extra = sorted(set(a["std"]) - set(a["parameters"]))
        if extra:
            _fail(key + ".std", f"has {', '.join(extra)} which {key}.parameters does not")
        _number(a["score"], key + ".score")
        _number(a["rms_after"], key + ".rms_after", 0.0)
        _string(a["evidence"], key + ".evidence")
    _list(report["rejected"], "rejected")
    for i, r in enumerate(report["rejected"]):
        key = f"rejected[{i}]"
        _keys(r, key, {"physics", "score", "reason"})
        _physics(r["physics"], key + ".physics")
        _number(r["score"], key + ".score")
        _string(r["reason"], key + ".reason")
    _param_map(report["parameters"], "parameters")


# ---------------------------------------------------------------------------------------------
# files


def write_report(path: str | Path, report: Mapping) -> Path:
    """Validate ``report`` and write it as JSON atomically (temporary file, fsync, rename)."""
    validate_report(report)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(report, indent=2, allow_nan=False) + "\n"
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def read_report(path: str | Path) -> dict:
    """Read and validate a report.json; errors name the file."""
    path = Path(path)
    try:
        report = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ReportError(f"{path}: cannot read a JSON report ({exc})") from None
    try:
        validate_report(report)
    except ReportError as exc:
        raise ReportError(f"{path}: {exc}") from None
    return report


def _fmt(x: float) -> str:
    return f"{x:.3g}"


def write_report_md(path: str | Path, report: Mapping, evidence: Mapping | None = None,
                    figures: Sequence[str] = ()) -> Path:
    """Write the report as plain-language Markdown (``report.md``).

    Parameters
    ----------
    path : path
        The ``.md`` file (written atomically).
    report : dict
        A valid report.
    evidence : mapping, optional
        Extra findings to state, any of: ``noise_test`` (a
        :class:`~petsoft.diagnosis.noise.ChiSquareResult` or its dict), ``noise_source``
        (str), ``envelope`` (:func:`~petsoft.diagnosis.spectral.decay_envelope`),
        ``modes`` (:func:`~petsoft.diagnosis.spectral.compare_modes`), ``notes`` (list of str).
    figures : sequence of str
        PNG file names (relative to the report) to embed.
    """
    validate_report(report)
    ev = dict(evidence or {})
    fit = report["fit"]
    mm = report["mismatch"]
    lines = ["# Diagnosis report", ""]
    if report["verdict"] == "consistent":
        lines.append(f"**Verdict: consistent.** After calibration the remaining residual "
                     f"(rms {_fmt(fit['final']['rms'])} m) is explained by the measurement noise "
                     f"({_fmt(report['noise_std'])} m).")
    else:
        # the verdict is about the model as given (fit.base); what was added is the final model
        lines.append(f"**Verdict: missing physics.** Even after calibration the residual of the "
                     f"model as given (rms {_fmt(fit['base']['rms'])} m, chi2/dof "
                     f"{_fmt(fit['base']['chi2_per_dof'])}) is larger or more structured than "
                     f"the measurement noise ({_fmt(report['noise_std'])} m) explains.")
        if report["added"]:
            lines.append(f"With {', '.join(a['physics'] for a in report['added'])} added, the "
                         f"residual is rms {_fmt(fit['final']['rms'])} m, chi2/dof "
                         f"{_fmt(fit['final']['chi2_per_dof'])}; the noise tests below are of "
                         "this final model.")
    lines += ["", "## Fit", "",
              "| model | rms (m) | chi2/dof |", "|---|---|---|",
              f"| as given, calibrated | {_fmt(fit['base']['rms'])} | "
              f"{_fmt(fit['base']['chi2_per_dof'])} |",
              f"| final | {_fmt(fit['final']['rms'])} | {_fmt(fit['final']['chi2_per_dof'])} |"]
    if fit.get("validation") is not None:
        v = fit["validation"]
        lines += ["", f"On the validation recording the rms went from {_fmt(v['base_rms'])} m to "
                  f"{_fmt(v['final_rms'])} m."]
    test = ev.get("noise_test")
    if test is not None:
        t = test if isinstance(test, Mapping) else test.as_dict()
        src = ev.get("noise_source", "")
        lines += ["", "## Is the residual noise?", "",
                  f"Noise level {_fmt(report['noise_std'])} m{f' ({src})' if src else ''}. "
                  f"Chi-square: {_fmt(t['chi2'])} on {t['dof']} degrees of freedom "
                  f"(chi2/dof {_fmt(t['chi2_per_dof'])}, p = {_fmt(t['p_value'])}): the level "
                  f"{'passes' if t['level_ok'] else 'fails'}. Whiteness (autocorrelation, "
                  f"portmanteau): Q = {_fmt(t['whiteness_q'])}, p = "
                  f"{_fmt(t['whiteness_p_value'])}: the residual "
                  f"{'looks white' if t['white_ok'] else 'is correlated in time, not noise'}"
                  f" (runs test on its signs: z = {_fmt(t['runs_z'])})."]
    lines += ["", "## Where and when", ""]
    if mm["markers"]:
        lines.append(f"Markers that stand out: {', '.join(mm['markers'])}.")
    else:
        lines.append("No marker stands out from the others: the mismatch, if any, is spread over "
                     "the whole body.")
    if mm["region"] is not None:
        c = mm["region"]["center"]
        lines.append(f"They lie within {_fmt(mm['region']['radius'])} m of "
                     f"({_fmt(c[0])}, {_fmt(c[1])}, {_fmt(c[2])}) in the reference configuration.")
    if mm["time_windows"]:
        wins = ", ".join(f"{_fmt(a)}-{_fmt(b)} s" for a, b in mm["time_windows"])
        lines.append(f"The residual exceeds the noise in the time windows {wins}.")
    else:
        lines.append("No time window stands out.")
    if mm["frequencies_hz"]:
        lines.append("Frequencies involved: "
                     + ", ".join(f"{_fmt(f)} Hz" for f in mm["frequencies_hz"]) + ".")
    modes = ev.get("modes")
    if modes:
        lines += ["", "## Modes: data vs simulation", "",
                  "| data (Hz) | sim (Hz) | shift | data decay (1/s) | sim decay (1/s) |",
                  "|---|---|---|---|---|"]
        lines += [f"| {_fmt(m['data_hz'])} | {_fmt(m['sim_hz'])} | "
                  f"{m['relative_frequency_shift']:+.2%} | {_fmt(m['data_decay'])} | "
                  f"{_fmt(m['sim_decay'])} |" for m in modes["matched"]]
        lines += [""] + [f"- {h}" for h in modes.get("hints", [])]
    env = ev.get("envelope")
    if env:
        lines += ["", "## Shape of the amplitude decay", "",
                  f"The oscillation amplitude decays most like the **{env['best']}** law, the "
                  f"signature of **{env['friction']}** friction (residual {env['ratio']:.2g} x "
                  f"smaller than the next law; general law dA/dt ~ -A^p with p = "
                  f"{env['exponent_p']:.2f}: 0 dry, 1 viscous, 2 quadratic)."]
        lines += ["", "| law | rms of fit |", "|---|---|"]
        lines += [f"| {k} | {_fmt(v['rms'])} |" for k, v in env["fits"].items()]
    lines += ["", "## Physics", ""]
    for a in report["added"]:
        params = ", ".join(f"{k} = {_fmt(v)}" + (f" +- {_fmt(a['std'][k])}" if k in a["std"]
                                                    else "") for k, v in a["parameters"].items())
        lines.append(f"- added **{a['physics']}** ({PHYSICS[a['physics']]}): {params}; score "
                     f"{_fmt(a['score'])}, rms after {_fmt(a['rms_after'])} m. Evidence: "
                     f"{a['evidence']}.")
    for r in report["rejected"]:
        lines.append(f"- rejected {r['physics']} (score {_fmt(r['score'])}): {r['reason']}.")
    if not report["added"] and not report["rejected"]:
        lines.append("No candidate physics was tried.")
    lines += [f"- {n}" for n in ev.get("notes", [])]
    num = report.get("numerics") or {}
    if num.get("findings") or num.get("recommendation"):
        lines += ["", "## Mesh and time step", ""] + [f"- {f}" for f in num["findings"]]
        if num.get("recommendation"):
            lines += ["", f"**Recommendation:** {num['recommendation']}"]
    if report["parameters"]:
        lines += ["", "## Final parameters", ""]
        lines += [f"- {k} = {v:.6g}" for k, v in report["parameters"].items()]
    if figures:
        lines += ["", "## Figures", ""] + [f"![{Path(f).stem}]({f})" for f in figures]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, path)
    return path


# ---------------------------------------------------------------------------------------------
# figures


def pyplot_agg():
    """matplotlib's pyplot on the Agg backend (files only, no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path) -> Path:
    """Lay out, write (110 dpi, parent directories made) and close a figure."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    pyplot_agg().close(fig)
    return path


def plot_marker_residuals(path, res, noise_std: float | None = None) -> Path:
    """Bar chart of each marker's rms residual; flagged markers in red, the robust bar dashed."""
    plt = pyplot_agg()
    fig, ax = plt.subplots(figsize=(max(5, 0.25 * len(res.names) + 2), 3.5))
    colours = np.where(res.flagged, "tab:red", "tab:blue")
    ax.bar(np.arange(len(res.names)), np.nan_to_num(res.rms), color=colours)
    ax.axhline(res.threshold_rms, ls="--", c="k", lw=1, label="median + k MAD")
    if noise_std:
        ax.axhline(np.sqrt(3) * noise_std, ls=":", c="gray", lw=1, label="noise (3D)")
    ax.set_xticks(np.arange(len(res.names)))
    ax.set_xticklabels(res.names, rotation=90, fontsize=7)
    ax.set_ylabel("rms residual (m)")
    ax.set_title("Residual per marker (red: stands out)")
    ax.legend(fontsize=8)
    return save_figure(fig, path)


def plot_residual_time(path, times, windows: Mapping) -> Path:
    """Windowed chi2/dof against time with its noise threshold and the flagged intervals."""
    plt = pyplot_agg()
    fig, ax = plt.subplots(figsize=(7, 3.5))
    t = np.asarray(times)
    ax.plot(t, windows["frame_chi2_per_dof"], lw=0.5, c="0.7", label="per frame")
    ax.plot(t, windows["window_chi2_per_dof"], c="tab:blue", label="windowed")
    ax.plot(t, windows["threshold"], "k--", lw=1, label="noise threshold")
    for a, b in windows["intervals"]:
        ax.axvspan(a, b, color="tab:red", alpha=0.2)
    ax.set_yscale("log")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("chi2 / dof")
    ax.set_title("Residual over time (red: mismatch windows)")
    ax.legend(fontsize=8)
    return save_figure(fig, path)


def plot_spectra(path, times, data, sim, data_modes=(), sim_modes=()) -> Path:
    """Amplitude spectra (sum over channels) of data and simulation, modes marked."""
    from petsoft.diagnosis.spectral import fill_gaps

    plt = pyplot_agg()
    t = np.asarray(times, dtype=float)
    dt = t[1] - t[0]
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for arr, label, c, modes in ((data, "data", "tab:blue", data_modes),
                                 (sim, "simulation", "tab:orange", sim_modes)):
        x = fill_gaps(t, arr)
        x = (x - x.mean(axis=0)) * np.hanning(len(t))[:, None]
        spec = np.sqrt(np.sum(np.abs(np.fft.rfft(x, axis=0)) ** 2, axis=1))
        f = np.fft.rfftfreq(len(t), dt)
        ax.semilogy(f[1:], spec[1:], c=c, label=label, lw=1)
        for m in modes:
            if m["frequency_hz"] > 0:
                ax.axvline(m["frequency_hz"], c=c, ls=":", lw=1)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("amplitude spectrum")
    ax.set_title("Spectra (dotted: fitted modes)")
    ax.legend(fontsize=8)
    return save_figure(fig, path)
