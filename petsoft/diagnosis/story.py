"""The story a diagnosis tells a non-specialist: the verdict box, "In short", the console's last
lines, and the check that the story never quotes one quantity two ways.

Every number a reader meets first is formatted here, once, from report.json (formats.md
section 3): :class:`Story` reads a valid report and holds the strings; report.md
(:func:`~petsoft.diagnosis.report.write_report_md`), report.html (made from report.md) and the
console (:meth:`Story.conclusion`) quote them. Parameter values are the final model's
(``parameters``, ``parameters_std``), with the unit of :func:`~petsoft.experiment.parameters.
parameter_unit`; displacements are in millimetres and in units of the noise.

:func:`quoted_conflicts` reads a finished report.md or report.html back and lists every quantity
quoted with two different values, and every sentence that calls a refinement fine while the
report says that refinement changes the simulation by more than the noise: the test of the story
(tests/test_story.py), run on the reports diagnose writes.
"""

from __future__ import annotations

import html as _html
import math
import re
from collections.abc import Mapping

import numpy as np

from petsoft.diagnosis.report import PHYSICS

__all__ = ["Story", "mismatch_cause", "pm", "quoted_conflicts", "skipped_numerics", "ties"]

#: What skipping the numerics check risks (report.json ``skipped``, the verdict box, console).
NUMERICS_RISK = ("a mismatch that a finer mesh, 10-node elements or a smaller time step would "
                 "remove may be blamed on physics instead, and added terms may absorb "
                 "discretisation error (their values are then biased)")


def skipped_numerics(why: str = "--no-numerics") -> dict:
    """report.json's ``skipped`` entry of a run without the numerics check."""
    return {"check": "numerics (mesh, element order and time step refinement)", "why": why,
            "risk": NUMERICS_RISK}


def mismatch_cause(verdict: str, added, adopted) -> str:
    """report.json ``cause`` (:data:`~petsoft.diagnosis.report.CAUSES`) from the verdict on the
    user's model, the physics added and the refinements adopted."""
    if added and adopted:
        return "both"
    if added:
        return "physics"
    if adopted:
        return "numerics"
    return "none" if verdict == "consistent" else "unexplained"


def pm(value: float, std: float | None = None) -> str:
    """``value +- std``, the value to the std's second significant digit (``4.012 +- 0.012``,
    ``2.0005e+07 +- 1.2e+04``); without a finite std, 4 significant digits."""
    if std is None or not math.isfinite(std) or std <= 0.0 or value == 0.0:
        return f"{value:.4g}"
    lead = math.floor(math.log10(std)) - 1                  # the std's second digit
    if 1e-3 <= abs(value) < 1e5:
        digits = max(-lead, 0)
        return f"{value:.{digits}f} +- {std:.{digits}f}"
    digits = min(max(math.floor(math.log10(abs(value))) - lead, 1), 10)
    return f"{value:.{digits}e} +- {std:.2g}"


def _unit(name: str) -> str:
    from petsoft.errors import ExperimentError
    from petsoft.experiment.parameters import parameter_unit

    try:
        return parameter_unit(name)
    except ExperimentError:
        return ""


def ties(report: Mapping) -> dict[str, list[str]]:
    """For each added physics, the vocabulary terms its evidence says fit and predict as well
    (the ``ambiguous:`` part of ``added[].evidence``, written by selection and reconsider)."""
    out = {}
    for a in report["added"]:
        for part in a["evidence"].split("; "):
            if part.startswith("ambiguous:"):
                names = [p for p in PHYSICS if re.search(rf"(?<![\w.]){re.escape(p)}(?![\w.])",
                                                         part) and p != a["physics"]]
                if names:
                    out[a["physics"]] = names
    return out


def _vector(v) -> str:
    return "(" + ", ".join(f"{x:.3g}" for x in v) + ")"


def gravity_said(g: Mapping) -> str:
    """An added gravity term's vector in words (report.json ``added[i].gravity``): the turn a
    fitted tilt made of the stated gravity, or the size of a fitted acceleration (a size far
    from the Earth's 9.81 m/s^2 says it stands in for something else)."""
    a = g["acceleration"]
    if "stated" in g:
        return (f"gravity turned by {g['turned_degrees']:.3g} degrees: {_vector(a)} m/s^2, "
                f"stated {_vector(g['stated'])}")
    return f"{_vector(a)} m/s^2, |g| = {float(np.linalg.norm(a)):.3g} m/s^2"


def _mm(x: float) -> str:
    return f"{1e3 * x:.3g} mm"


class Story:
    """The strings of a report's story, each made once (module docstring).

    Parameters
    ----------
    report : mapping
        A valid report.json.
    """

    def __init__(self, report: Mapping):
        self.report = report
        sigma = report["noise_std"]
        self.noise = _mm(sigma)
        self.added = [a["physics"] for a in report["added"]]
        params, std = report["parameters"], report.get("parameters_std", {})
        #: "name = value +- std unit" of every final parameter
        self.values = {n: f"{n} = {pm(v, std.get(n))}" + (f" {_unit(n)}" if _unit(n) else "")
                       for n, v in params.items()}
        self.added_values = []
        for a in report["added"]:
            said = [self.values[n] for n in a["parameters"] if n in self.values]
            if said and "gravity" in a:
                said[-1] += f" ({gravity_said(a['gravity'])})"
            self.added_values += said
        added_names = {n for a in report["added"] for n in a["parameters"]}
        self.recalibrated = [t for n, t in self.values.items() if n not in added_names]
        self.cause = report.get("cause") or mismatch_cause(
            report["verdict"], self.added, (report.get("numerics") or {}).get("adopted", []))
        num = report.get("numerics") or {}
        self.numerics = list(num.get("summary", []))
        self.recommendation = num.get("recommendation")
        self.adopted = list(num.get("adopted", []))
        self.skipped = list(report.get("skipped", []))
        self.ties = ties(report)
        fit = report["fit"]
        self.chi2 = (f"{fit['base']['chi2_per_dof']:.3g}", f"{fit['final']['chi2_per_dof']:.3g}")
        self.rms = (_mm(fit["base"]["rms"]), _mm(fit["final"]["rms"]))
        v = fit.get("validation")
        self.heldout = None
        if v is not None:
            self.heldout = (f"{_mm(v['base_rms'])} ({v['base_rms'] / sigma:.3g}x the noise)",
                            f"{_mm(v['final_rms'])} ({v['final_rms'] / sigma:.3g}x the noise)")
        self.final_consistent = report.get("final_verdict", report["verdict"]) == "consistent"

    # -- the words ----------------------------------------------------------------------------
    def _missed(self) -> str:
        """What the model as given missed, in physical words."""
        parts = [PHYSICS[p] for p in self.added]
        if self.adopted:
            from petsoft.diagnosis.numerics_findings import refinement_words

            # each kind once: the step halved twice is one thing the model missed
            kinds = dict.fromkeys(refinement_words(a)[1] for a in self.adopted)
            parts.append("its discretisation (" + ", ".join(kinds) + ")")
        return "; ".join(parts)

    def headline(self) -> str:
        """The verdict in a few words: what the mismatch was."""
        return {"none": "consistent",
                "numerics": "numerics, no missing physics",
                "physics": "missing physics",
                "both": "missing physics and numerics",
                "unexplained": "missing physics, not identified"}[self.cause]

    def verdict_box(self) -> str:
        """The verdict paragraph (report.md's first, the HTML page's box)."""
        words = [f"**Verdict: {self.headline()}.**"]
        if self.cause == "none":
            words.append(f"The model as given, calibrated, explains the recording to the "
                         f"measurement noise ({self.noise}; chi2/dof {self.chi2[0]}).")
        elif self.cause == "unexplained":
            # a search the time budget cut short found nothing, which is not "none explained it"
            # (a round's finished fit may even have passed both tests: partial_round.py)
            cut = (self.report.get("budget") or {}).get("left_out")
            words.append(f"The model as given misses the recording by more than the noise "
                         f"(chi2/dof {self.chi2[0]}; 1 is the noise), and "
                         + ("within the time budget no refinement of the numerics or term of "
                            "the vocabulary was found to explain it (what was left out is "
                            "below)." if cut else "neither a refinement of the numerics nor a "
                            "term of the vocabulary explained it."))
        else:
            words.append(f"The model as given missed {self._missed()}.")
            if self.added_values:
                words.append("Added and calibrated: " + ", ".join(self.added_values) + ".")
            elif self.cause == "numerics":
                words.append("No physics was added.")
        if self.cause != "none" and self.heldout is not None:
            words.append(f"Held-out prediction error: {self.heldout[0]} before, "
                         f"{self.heldout[1]} after.")
        if self.cause != "none":
            words.append(f"The final model {'fits to the noise' if self.final_consistent else 'still misses the data'} (chi2/dof {self.chi2[1]}).")  # noqa: E501
        for k in self.skipped:
            words.append(f"Not checked: {k['check']} ({k['why']}); the risk: {k['risk']}.")
        return " ".join(words)

    def in_short(self) -> list[str]:
        """The bullets of "In short": what a non-specialist needs, in that order."""
        out = []
        if self.cause in ("physics", "both", "numerics"):
            out.append(f"**What the model missed:** {self._missed()}.")
        for p in self.added:
            term = [self.values[n] for n in
                    next(a for a in self.report["added"] if a["physics"] == p)["parameters"]
                    if n in self.values]
            out.append(f"**Added:** {PHYSICS[p]}" + (": " + ", ".join(term) if term
                                                     else f" ({p})") + ".")
        if self.recalibrated:
            out.append("**Calibrated:** " + ", ".join(self.recalibrated) + ".")
        if self.heldout is not None:
            out.append(f"**Held-out prediction** (the part of the record the fit never saw), "
                       f"rms error: {self.heldout[0]} with the model as given, {self.heldout[1]} "
                       f"with the final model (noise {self.noise}).")
        out.append(f"**Fit** on the identification window: chi2/dof {self.chi2[0]} as given, "
                   f"{self.chi2[1]} final (1 is the noise).")
        out += [f"**Numerics:** {s}" for s in self.numerics]
        for k in self.skipped:
            out.append(f"**Not checked:** {k['check']} ({k['why']}); the risk: {k['risk']}.")
        for p, others in self.ties.items():
            out.append(f"**Ambiguous:** {', '.join(others)} fit and predict this recording as "
                       f"well as {p}; {p} was kept by the vocabulary's order, not by the data.")
        out += [f"**Next:** {n}" for n in self.next_steps()]
        return out

    def next_steps(self) -> list[str]:
        steps = []
        if self.recommendation:
            steps.append(self.recommendation)
        if any("numerics" in k["check"] for k in self.skipped):
            steps.append("Run again without --no-numerics before trusting what was added.")
        for p, others in self.ties.items():
            steps.append(f"To tell {p} from {', '.join(others)}, record longer (more of the "
                         "decay) or at a different amplitude or frequency: these terms agree "
                         "on this recording but scale differently with amplitude and frequency.")
        if self.cause != "none" and not self.final_consistent:
            steps.append("The final model still misses the data: see the appendix for the "
                         "candidates tried, and consider physics outside the vocabulary.")
        return steps

    def conclusion(self, out=None) -> list[str]:
        """The console's last lines: verdict, physics added (values, std), held-out, paths."""
        lines = [f"verdict: {self.headline()} (cause: {self.cause})"]
        if self.cause not in ("none", "unexplained"):
            lines.append(f"missed: {self._missed()}")
        if self.added_values:
            lines.append("added: " + ", ".join(self.added_values))
        lines += [f"numerics: {s}" for s in self.numerics]
        if self.heldout is not None:
            lines.append(f"held-out rms: {self.heldout[0]} -> {self.heldout[1]}")
        lines.append(f"final fit: chi2/dof {self.chi2[1]} "
                     f"({'consistent with the noise' if self.final_consistent else 'still misses'})")  # noqa: E501
        for k in self.skipped:
            lines.append(f"NOT CHECKED: {k['check']} ({k['why']}): {k['risk']}")
        for p, others in self.ties.items():
            lines.append(f"ambiguous: {', '.join(others)} fit as well as {p}")
        t = self.report.get("timings")
        if t:
            parts = [f"{k.replace('_', ' ')} {t[k]:.0f} s" for k in
                     ("base_fit", "numerics", "scoring", "fits", "final") if t.get(k, 0) >= 0.5]
            lines.append(f"time: {t['total']:.0f} s" + (f" ({', '.join(parts)})" if parts else ""))
        if out is not None:
            lines.append(f"report: {out}/report.html (also report.md, report.json, figures, "
                         "diagnosed.toml)")
        return lines


# ------------------------------------------------------------------------------------------
# the check


_PARAM = re.compile(r"(?<![\w.])((?:[a-z_]+\.)+[a-z_]+|[a-z_]+\.\"[^\"]+\"\.[a-z_]+)"
                    r" = (-?[0-9][0-9.e+-]*)(?: \+- ([0-9][0-9.e+-]*))?")
_CHANGE = re.compile(r"changes(?: the simulation)? by ([0-9][0-9.e+-]*)x the noise")
_NOUNS = {"time step": ("time step", "step is halved", "step/2"),
          "mesh": ("mesh is refined", "mesh", "tets"),
          "element order": ("element order", "order 2", "10-node")}
#: the held-out rms errors (before, after) as the verdict box and "In short" quote them
_HELDOUT = (re.compile(r"rms error: ([0-9.e+-]+ mm)[^,]*, ([0-9.e+-]+ mm)(?: \([^)]*\))? with "
                       r"the final model"),
            re.compile(r"[Hh]eld-out prediction error: ([0-9.e+-]+ mm)(?: \([^)]*\))? before, "
                       r"([0-9.e+-]+ mm)(?: \([^)]*\))? after"))


def _text(document: str) -> str:
    """Plain sentences of report.md or report.html (tags, images, markup removed)."""
    if "<html" in document[:200]:
        document = re.sub(r"<img[^>]*>", " ", document)
        document = re.sub(r"<style.*?</style>", " ", document, flags=re.S)
        document = _html.unescape(re.sub(r"<[^>]+>", "\n", document))
    document = re.sub(r"!\[[^\]]*\]\([^)]*\)", " ", document)
    return document.replace("**", "")


def _sentences(text: str) -> list[str]:
    out = []
    for line in text.splitlines():
        out += [s.strip() for s in re.split(r"(?<=[.!?])\s+(?=[A-Z*])", line) if s.strip()]
    return out


def _noun(sentence: str) -> str | None:
    """The refinement a sentence is about (its subject, when it names one at its start)."""
    low = sentence.lower()
    first = min(((low.find(k), noun) for noun, keys in _NOUNS.items() for k in keys
                 if k in low), default=(-1, None))
    return first[1] if first[0] >= 0 else None


def quoted_conflicts(document: str) -> list[str]:
    """Every inconsistency of a report.md / report.html text, as messages (empty: none).

    * a parameter quoted as ``name = value`` (or ``value +- std``) with two different values;
    * the held-out rms errors quoted two ways;
    * a refinement (time step, mesh, element order) said to be *fine* in one sentence while
      another says refining it changes the simulation by more than the noise.
    """
    text = _text(document)
    problems = []
    seen: dict[str, set] = {}
    for m in _PARAM.finditer(text):
        seen.setdefault(m.group(1), set()).add((m.group(2).rstrip(".,;"),
                                                (m.group(3) or "").rstrip(".,;")))
    for name, values in seen.items():
        shown = {v for v, _ in values}
        stds = {s for _, s in values if s}
        if len(shown) > 1 or len(stds) > 1:
            problems.append(f"{name} is quoted as " + ", ".join(
                f"{v} +- {s}" if s else v for v, s in sorted(values)))
    held = {m.groups() for pattern in _HELDOUT for m in pattern.finditer(text)}
    if len(held) > 1:
        problems.append(f"the held-out rms is quoted as {sorted(held)}")
    large: dict[str, float] = {}
    fine: dict[str, str] = {}
    for s in _sentences(text):
        noun = _noun(s)
        if noun is None:
            continue
        for m in _CHANGE.finditer(s):
            large[noun] = max(large.get(noun, 0.0), float(m.group(1).rstrip(".")))
        if re.search(r"\bis fine\b|\bit is fine\b", s):
            fine[noun] = s
    for noun, s in fine.items():
        if large.get(noun, 0.0) > 1.0:
            problems.append(f"the {noun} is said to be fine ({s!r}) while refining it changes "
                            f"the simulation by {large[noun]:g}x the noise")
    return problems
