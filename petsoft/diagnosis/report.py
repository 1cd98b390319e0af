"""The diagnosis report: report.json (formats.md section 3), report.md and its figures.

This module owns the report's contract: :func:`build_report` assembles the dict, exactly the keys
of formats.md section 3; :func:`validate_report` checks one strictly (unknown or missing keys,
wrong types, non-finite numbers, physics names outside :data:`PHYSICS`) and raises
:class:`ReportError` naming the key; :func:`write_report` writes it atomically
(:mod:`petsoft.atomic`: a reader never sees half a report); :func:`write_report_md` says the
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
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from petsoft.atomic import write_text
from petsoft.errors import PetsoftError
from petsoft.terms import TERMS

__all__ = ["CAUSES", "PHYSICS", "VERDICTS", "ReportError", "fit_summary", "build_report",
           "validate_report", "write_report", "read_report", "write_report_md",
           "plot_marker_residuals", "plot_residual_time", "plot_spectra"]

FORMAT = "petsoft-diagnosis"
VERSION = 1
VERDICTS = ("consistent", "missing-physics")
#: What the model as given missed (report.json ``cause``, optional): ``none`` (nothing: the
#: verdict is consistent), ``numerics`` (a refinement of mesh, element order or step was adopted
#: and no physics added), ``physics`` (physics added, no refinement adopted), ``both``, or
#: ``unexplained`` (a mismatch that neither a refinement nor a vocabulary term explained).
CAUSES = ("none", "numerics", "physics", "both", "unexplained")

#: The physics vocabulary of formats.md section 3 (extend it, never rename): name -> meaning,
#: read from the term registry (:mod:`petsoft.terms`), in its order.
PHYSICS = {name: t.meaning for name, t in TERMS.items()}


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
                 numerics: Mapping | None = None, cause: str | None = None,
                 skipped: Sequence[Mapping] = (),
                 parameters_std: Mapping[str, float] | None = None,
                 final_verdict: str | None = None) -> dict:
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
    numerics : mapping, optional
        What the refinement checks found (:mod:`petsoft.diagnosis.numerics_findings`).
    cause : str, optional
        One of :data:`CAUSES`.
    skipped : sequence of mapping
        Checks not made: ``{"check", "why", "risk"}`` each.
    parameters_std : mapping of str to float, optional
        Standard deviations of the final parameters (where finite).
    final_verdict : {"consistent", "missing-physics"}, optional
        The verdict on the final model (``verdict`` is the one on the model as given).

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
                   "evidence": a["evidence"],
                   **({"gravity": _gravity_entry(a["gravity"])} if "gravity" in a else {})}
                  for a in added],
        "rejected": [{"physics": r["physics"], "score": _num(r["score"]),
                      "reason": r["reason"]} for r in rejected],
        "parameters": {str(k): _num(v) for k, v in parameters.items()},
    }
    if numerics is not None:     # what the numerics checks found (diagnosis/numerics_findings)
        report["numerics"] = dict(numerics)
    if parameters_std is not None:
        report["parameters_std"] = {str(k): _num(v) for k, v in parameters_std.items()}
    if cause is not None:
        report["cause"] = cause
    if final_verdict is not None:
        report["final_verdict"] = final_verdict
    if skipped:
        report["skipped"] = [{"check": str(k["check"]), "why": str(k["why"]),
                              "risk": str(k["risk"])} for k in skipped]
    validate_report(report)
    return report


def _gravity_entry(g: Mapping) -> dict:
    """An added gravity term's ``gravity`` entry (outputs.gravity_words), numbers made plain."""
    out = {"acceleration": [_num(x) for x in g["acceleration"]]}
    if "stated" in g:
        out["stated"] = [_num(x) for x in g["stated"]]
        out["turned_degrees"] = _num(g["turned_degrees"])
    return out


# ---------------------------------------------------------------------------------------------
# validation


def _check_gravity(g, key: str) -> None:
    _keys(g, key, {"acceleration"}, frozenset({"stated", "turned_degrees"}))
    for part in ("acceleration", "stated"):
        if part not in g:
            continue
        v = g[part]
        if not isinstance(v, list) or len(v) != 3:
            _fail(f"{key}.{part}", f"must be [x, y, z] in m/s^2, got {v!r}")
        for i, x in enumerate(v):
            _number(x, f"{key}.{part}[{i}]")
    if ("stated" in g) != ("turned_degrees" in g):
        _fail(key, "stated and turned_degrees come together (a turned gravity) or not at all")
    if "turned_degrees" in g:
        _number(g["turned_degrees"], f"{key}.turned_degrees", 0.0)
        if g["turned_degrees"] > 180.0:
            _fail(f"{key}.turned_degrees", f"is an angle in [0, 180], got {g['turned_degrees']}")


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
    _keys(report, "(report)", top,
          frozenset({"numerics", "cause", "skipped", "parameters_std", "final_verdict",
                     "timings", "budget"}))
    for k, v in report.get("timings", {}).items():
        _number(v, f"timings.{k}")
    if "budget" in report:
        _check_budget(report["budget"])
    if "numerics" in report:
        _check_numerics(report["numerics"])
    if "final_verdict" in report and report["final_verdict"] not in VERDICTS:
        _fail("final_verdict", f"must be one of {', '.join(VERDICTS)}, got "
                               f"{report['final_verdict']!r}")
    if "cause" in report and report["cause"] not in CAUSES:
        _fail("cause", f"must be one of {', '.join(CAUSES)}, got {report['cause']!r}")
    if "skipped" in report:
        _check_skipped(report["skipped"])
    if report["format"] != FORMAT:
        _fail("format", f"must be {FORMAT!r}, got {report['format']!r}")
    if isinstance(report["version"], bool) or report["version"] != VERSION:
        _fail("version", f"must be {VERSION}, got {report['version']!r}")
    if report["verdict"] not in VERDICTS:
        _fail("verdict", f"must be one of {', '.join(VERDICTS)}, got {report['verdict']!r}")
    _number(report["noise_std"], "noise_std", positive=True)
    _check_fit(report["fit"])
    _check_mismatch(report["mismatch"])
    _list(report["added"], "added")
    for i, a in enumerate(report["added"]):
        _check_added(a, f"added[{i}]")
    _list(report["rejected"], "rejected")
    for i, r in enumerate(report["rejected"]):
        key = f"rejected[{i}]"
        _keys(r, key, {"physics", "score", "reason"})
        _physics(r["physics"], key + ".physics")
        _number(r["score"], key + ".score")
        _string(r["reason"], key + ".reason")
    _param_map(report["parameters"], "parameters")
    if "parameters_std" in report:
        _param_map(report["parameters_std"], "parameters_std", 0.0)
        extra = sorted(set(report["parameters_std"]) - set(report["parameters"]))
        if extra:
            _fail("parameters_std", f"has {', '.join(extra)} which parameters does not")


def _check_budget(b) -> None:
    """report.json's ``budget``: its seconds, whether it was spent, when, and what was left
    out."""
    _keys(b, "budget", {"seconds", "spent", "spent_at", "left_out"})
    if b["seconds"] is not None:
        _number(b["seconds"], "budget.seconds", positive=True)
    if not isinstance(b["spent"], bool):
        _fail("budget.spent", f"must be true or false, got {b['spent']!r}")
    if b["spent_at"] is not None:
        _number(b["spent_at"], "budget.spent_at")
    _list(b["left_out"], "budget.left_out")
    for i, k in enumerate(b["left_out"]):
        _string(k, f"budget.left_out[{i}]")


def _check_numerics(n) -> None:
    """report.json's ``numerics``: its findings, summary and adopted refinements (strings)."""
    _keys(n, "numerics", {"findings"},
          frozenset({"recommendation", "mesh", "summary", "adopted"}))
    for part in ("findings", "summary", "adopted"):
        _list(n.get(part, []), f"numerics.{part}")
        for i, f in enumerate(n.get(part, [])):
            _string(f, f"numerics.{part}[{i}]")


def _check_skipped(skipped) -> None:
    """report.json's ``skipped``: the checks not made, each with why and the risk."""
    _list(skipped, "skipped")
    for i, k in enumerate(skipped):
        _keys(k, f"skipped[{i}]", {"check", "why", "risk"})
        for part in ("check", "why", "risk"):
            _string(k[part], f"skipped[{i}].{part}")


def _check_fit(fit) -> None:
    """report.json's ``fit``: rms and chi2/dof of the base and the final model, and the
    held-out validation when there is one."""
    _keys(fit, "fit", {"base", "final"}, frozenset({"validation"}))
    for part in ("base", "final"):
        _keys(fit[part], f"fit.{part}", {"rms", "chi2_per_dof"})
        _number(fit[part]["rms"], f"fit.{part}.rms", 0.0)
        _number(fit[part]["chi2_per_dof"], f"fit.{part}.chi2_per_dof", 0.0)
    if fit.get("validation") is not None:
        _keys(fit["validation"], "fit.validation", {"base_rms", "final_rms"})
        for k in ("base_rms", "final_rms"):
            _number(fit["validation"][k], f"fit.validation.{k}", 0.0)


def _check_mismatch(mm) -> None:
    """report.json's ``mismatch``: the markers (each once), the time windows, the frequencies
    and the region."""
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


def _check_added(a, key: str) -> None:
    """One entry of report.json's ``added`` (``key``: its place, ``added[i]``)."""
    _keys(a, key, {"physics", "parameters", "std", "score", "rms_after", "evidence"},
          frozenset({"gravity"}))
    _physics(a["physics"], key + ".physics")
    _param_map(a["parameters"], key + ".parameters")
    _param_map(a["std"], key + ".std", 0.0)
    extra = sorted(set(a["std"]) - set(a["parameters"]))
    if extra:
        _fail(key + ".std", f"has {', '.join(extra)} which {key}.parameters does not")
    _number(a["score"], key + ".score")
    _number(a["rms_after"], key + ".rms_after", 0.0)
    _string(a["evidence"], key + ".evidence")
    if "gravity" in a:
        _check_gravity(a["gravity"], key + ".gravity")


# ---------------------------------------------------------------------------------------------
# files


def write_report(path: str | Path, report: Mapping) -> Path:
    """Validate ``report`` and write it as JSON atomically (temporary file, fsync, rename)."""
    validate_report(report)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(report, indent=2, allow_nan=False) + "\n"
    # readable by everyone whatever the umask: a report is for sharing
    return write_text(path, text, mode=0o644, fsync=True)


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

    The page opens with the verdict and "In short" (:class:`~petsoft.diagnosis.story.Story`:
    what the model missed, what was added with its values, the held-out prediction, what the
    numerics check found, ties, what to do next); then where and when, the physics, the mesh
    and time step; the details (noise tests, modes, decay shape, score tests, the numerics round
    by round, raw chi2) in a collapsed appendix (``<details>``).

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
        ``modes`` (:func:`~petsoft.diagnosis.spectral.compare_modes`), ``notes`` (list of str,
        for the appendix).
    figures : sequence of str
        PNG file names (relative to the report) to embed.
    """
    from petsoft.diagnosis.figures import CAPTIONS
    from petsoft.diagnosis.story import Story

    validate_report(report)
    ev = dict(evidence or {})
    story = Story(report)
    lines = ["# Diagnosis report", "", story.verdict_box(), "", "## In short", ""]
    lines += [f"- {b}" for b in story.in_short()]
    lines += ["", "## Where and when", ""] + _md_where_and_when(report["mismatch"])
    lines += ["", "## Physics", ""] + _md_physics(report)
    # the numerics' summary and recommendation are "In short"'s (one place); the rounds are in
    # the appendix
    if figures:
        lines += ["", "## Figures", ""] + [
            f"![{CAPTIONS.get(Path(f).stem, Path(f).stem)}]({f})" for f in figures]
    # the details: collapsed (GitHub's Markdown and report.html both fold <details>)
    lines += ["", "<details><summary>Appendix: the evidence in detail (raw fit numbers, noise "
              "tests, modes, score tests, the numerics round by round)</summary>", ""]
    lines += _md_fit(story)
    lines += _md_noise_test(ev.get("noise_test"), ev.get("noise_source", ""), story.noise)
    lines += _md_modes(ev.get("modes"))
    lines += _md_envelope(ev.get("envelope"))
    lines += ["", "### Candidates, as each was judged", ""] + _md_candidates(report)
    notes = ev.get("notes", [])
    if notes:
        lines += ["", "### Log", ""] + [f"- {n}" for n in notes]
    num = report.get("numerics") or {}
    if num.get("findings"):
        lines += ["", "### The numerics round by round (each on the model of its round)", ""]
        lines += [f"- {f}" for f in num["findings"]]
    lines += ["", "</details>"]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_text(path, "\n".join(lines) + "\n")


def _md_where_and_when(mm: Mapping) -> list[str]:
    """report.md's "Where and when": the markers, the region, the time windows and the
    frequencies of the mismatch (``report["mismatch"]``)."""
    lines = []
    if mm["markers"]:
        lines.append(f"Markers that stand out: {', '.join(mm['markers'])}.")
    else:
        lines.append("No marker stands out from the others: the mismatch, if any, is spread over "
                     "the whole body.")
    if mm["region"] is not None:
        c = mm["region"]["center"]
        lines.append(f"They lie within {1e3 * mm['region']['radius']:.3g} mm of "
                     f"({1e3 * c[0]:.4g}, {1e3 * c[1]:.4g}, {1e3 * c[2]:.4g}) mm in the "
                     "reference configuration.")
    if mm["time_windows"]:
        wins = ", ".join(f"{_fmt(a)}-{_fmt(b)} s" for a, b in mm["time_windows"])
        lines.append(f"With the model as given, the residual exceeds the noise in the time "
                     f"windows {wins}.")
    else:
        lines.append("No time window stands out.")
    if mm["frequencies_hz"]:
        lines.append("Frequencies involved: "
                     + ", ".join(f"{_fmt(f)} Hz" for f in mm["frequencies_hz"]) + ".")
    lines.append("The residual over the whole body is in residual_field.xdmf (open it in "
                 "ParaView) when the model has a mesh.")
    return lines


#: report.md's groups of the candidates not kept: the start of a rejection's reason -> the
#: group's words (the other reasons: "Fitted and not kept").
_REJECTED_GROUPS = (
    ("not tried", "Not fitted (a round fits only its best-scoring candidates)"),
    ("score not significant", "No sign of it in the data (score test not significant)"),
    ("fitted too", "Fitted too, but an added term predicted better"),
)


def _md_physics(report: Mapping) -> list[str]:
    """report.md's "Physics": what was added, and the other candidates grouped by why they
    were not kept."""
    lines = []
    if report["added"]:
        lines.append("Added: " + ", ".join(a["physics"] for a in report["added"])
                     + " (values above). The other candidates:")
        lines.append("")
    groups: dict[str, list[str]] = {}
    for r in report["rejected"]:
        group = next((words for start, words in _REJECTED_GROUPS
                      if r["reason"].startswith(start)),
                     "Fitted and not kept (see the appendix)")
        groups.setdefault(group, []).append(r["physics"])
    lines += [f"- {k}: {', '.join(v)}." for k, v in groups.items()]
    if not report["added"] and not report["rejected"]:
        lines.append("No candidate physics was tried.")
    return lines


def _md_fit(story) -> list[str]:
    """The appendix's fit table: the numbers "In short" quotes, from the same strings
    (story.py)."""
    return ["### Fit", "",
            "| model | rms, identification window | chi2/dof | rms, held out |",
            "|---|---|---|---|",
            f"| as given, calibrated | {story.rms[0]} | {story.chi2[0]} | "
            f"{story.heldout[0] if story.heldout else '-'} |",
            f"| final | {story.rms[1]} | {story.chi2[1]} | "
            f"{story.heldout[1] if story.heldout else '-'} |"]


def _md_noise_test(test, source: str, noise: str) -> list[str]:
    """The appendix's noise test of the final model's residual (``test``: a
    :class:`~petsoft.diagnosis.noise.ChiSquareResult` or its dict; None: nothing)."""
    if test is None:
        return []
    t = test if isinstance(test, Mapping) else test.as_dict()
    return ["", "### Is the residual of the final model noise?", "",
            f"Noise level {noise}{f' ({source})' if source else ''}. "
            f"Chi-square: {t['chi2']:.4g} on {t['dof']} degrees of freedom "
            f"(p = {t['p_value']:.3g}): the level "
            f"{'passes' if t['level_ok'] else 'fails'}. Whiteness (autocorrelation, "
            f"portmanteau): Q = {t['whiteness_q']:.3g}, p = "
            f"{t['whiteness_p_value']:.3g}: the residual "
            f"{'looks white' if t['white_ok'] else 'is correlated in time, not noise'}"
            f" (runs test on its signs: z = {t['runs_z']:.3g})."]


def _md_modes(modes) -> list[str]:
    """The appendix's table of the matched modes, data vs simulation, and their hints."""
    if not modes:
        return []
    lines = ["", "### Modes: data vs simulation", "",
             "| data (Hz) | sim (Hz) | shift | data decay (1/s) | sim decay (1/s) |",
             "|---|---|---|---|---|"]
    lines += [f"| {_fmt(m['data_hz'])} | {_fmt(m['sim_hz'])} | "
              f"{m['relative_frequency_shift']:+.2%} | {_fmt(m['data_decay'])} | "
              f"{_fmt(m['sim_decay'])} |" for m in modes["matched"]]
    return lines + [""] + [f"- {h}" for h in modes.get("hints", [])]


def _md_envelope(env) -> list[str]:
    """The appendix's shape of the recording's amplitude decay, and each law's fit."""
    if not env:
        return []
    lines = ["", "### Shape of the amplitude decay (the recording)", ""]
    if env["ratio"] < 2.0:
        # a law whose fit is barely better than the next one's names no friction
        lines.append(f"The decay's shape does not tell the friction laws apart: the best "
                     f"law's fit ({env['best']}) is only {env['ratio']:.2g}x closer than "
                     "the next one's.")
    else:
        lines.append(f"The oscillation amplitude decays most like the **{env['best']}** "
                     f"law, the signature of **{env['friction']}** friction (its fit is "
                     f"{env['ratio']:.2g}x closer than the next law's; general law dA/dt ~ "
                     f"-A^p with p = {env['exponent_p']:.2f}: 0 dry, 1 viscous, 2 "
                     "quadratic).")
    lines += ["", "| law | rms of fit (m) |", "|---|---|"]
    return lines + [f"| {k} | {_fmt(v['rms'])} |" for k, v in env["fits"].items()]


def _md_candidates(report: Mapping) -> list[str]:
    """The appendix's candidates, as each was judged: the added ones, then the others, the
    rounds' shortlist sentences said once at the end."""
    lines = []
    for a in report["added"]:
        lines.append(f"- added {a['physics']} (score {a['score']:.4g}; rms after it was added "
                     f"{a['rms_after']:.4g} m): {a['evidence']}.")
    shortlist = []
    for r in report["rejected"]:
        reason = r["reason"]
        if reason.startswith("not tried:") and " (" in reason:
            # the round's shortlist sentence is about other terms: said once, below
            reason, why = reason.split(" (", 1)
            why = why[:-1] if why.endswith(")") else why
            if why not in shortlist:
                shortlist.append(why)
        lines.append(f"- {r['physics']} (score {r['score']:.4g}): {reason}.")
    return lines + [f"- {w[0].upper()}{w[1:]}." for w in shortlist]


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


def plot_marker_residuals(path, res, noise_std: float | None = None) -> dict:
    """Bar chart of each marker's rms residual (mm): the markers that stand out in red (the
    title says so only when there are some), the robust bar dashed, the noise dotted.

    Returns ``path``, ``rms_mm`` (the bars), ``red`` (names drawn red), ``threshold_mm`` and
    ``noise_mm`` (the lines; None without a noise).
    """
    plt = pyplot_agg()
    fig, ax = plt.subplots(figsize=(max(5, 0.25 * len(res.names) + 2), 3.5))
    flagged = np.asarray(res.flagged, bool)
    colours = np.where(flagged, "tab:red", "tab:blue")
    rms_mm = 1e3 * np.nan_to_num(np.asarray(res.rms, float))
    ax.bar(np.arange(len(res.names)), rms_mm, color=colours)
    threshold = 1e3 * float(res.threshold_rms)
    ax.axhline(threshold, ls="--", c="k", lw=1, label="stands out above (median + k MAD)")
    noise_mm = None
    if noise_std:
        noise_mm = 1e3 * np.sqrt(3) * noise_std
        ax.axhline(noise_mm, ls=":", c="gray", lw=1, label="noise (3 components)")
    ax.set_xticks(np.arange(len(res.names)))
    ax.set_xticklabels(res.names, rotation=90, fontsize=7)
    ax.set_ylabel("rms residual (mm)")
    red = [n for n, f in zip(res.names, flagged, strict=True) if f]
    ax.set_title("Residual per marker" + (" (red: stands out)" if red
                                          else " (no marker stands out)"))
    ax.legend(fontsize=8)
    save_figure(fig, path)
    return {"path": Path(path), "rms_mm": rms_mm, "red": red, "threshold_mm": threshold,
            "noise_mm": noise_mm}


def plot_residual_time(path, times, windows: Mapping) -> dict:
    """Windowed chi2/dof against time with its noise threshold and the flagged intervals (red
    bands). Returns ``path``, ``window_chi2_per_dof`` and ``intervals`` (the bands drawn)."""
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
    ax.set_ylabel("chi2 / dof (1 = the noise)")
    ax.set_title("Residual over time" + (" (red: mismatch windows)" if len(windows["intervals"])
                                         else " (no window exceeds the noise)"))
    ax.legend(fontsize=8)
    save_figure(fig, path)
    return {"path": Path(path), "window_chi2_per_dof": np.asarray(windows["window_chi2_per_dof"]),
            "intervals": [tuple(w) for w in windows["intervals"]]}


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
