"""What a diagnosis writes: report.json (formats.md section 3), report.md, report.html, the
figures, the residual field for ParaView, diagnosed.toml and summary.json."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from petsoft.diagnosis.context import Diagnosis, Fit
from petsoft.diagnosis.figures import (
    plot_candidates,
    plot_displacement,
    plot_residual_on_body,
    plot_spectra_before_after,
    rms_per_marker,
)
from petsoft.diagnosis.html import write_report_html
from petsoft.diagnosis.records import AddedTerm, Evidence
from petsoft.diagnosis.result import DiagnoseResult
from petsoft.dynamics.factory import system_class
from petsoft.experiment.writer import write_experiment_update
from petsoft.io.summary import write_summary
from petsoft.mesh.topology import boundary_facets
from petsoft.physics.model import load_mesh


def gravity_words(gravity) -> dict:
    """What an added gravity term made of the model's gravity (report.json's ``added[i].gravity``):
    the acceleration the final model uses (m/s^2) and, where a stated one was turned
    (``gravity.direction``: its tangents are what was fitted, but a reader wants the vector), the
    stated one and the angle between them (degrees)."""
    g = np.asarray(gravity.acceleration, dtype=float)
    out = {"acceleration": [float(x) for x in g]}
    if gravity.tilted:
        g0 = np.asarray(gravity.as_stated, dtype=float)
        cos = float(g @ g0) / float(np.linalg.norm(g) * np.linalg.norm(g0))
        out["stated"] = [float(x) for x in g0]
        out["turned_degrees"] = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return out


def build_diagnosis_report(diag, base: Fit, final: Fit, base_ev: Evidence, ev: Evidence,
                           added: list[AddedTerm], rejected, numerics: dict | None = None,
                           skipped: list[dict] = ()) -> dict:
    """report.json of a diagnosis (formats.md section 3). An added term's ``parameters`` and
    ``std`` are the final model's (a refinement adopted after the term was added moves them),
    so that the report quotes one value of each; ``cause`` says whether the model as given
    missed physics, numerics, both or neither."""
    from petsoft.diagnosis.context import term_values
    from petsoft.diagnosis.report import build_report, fit_summary
    from petsoft.diagnosis.story import mismatch_cause

    d = diag.data[diag.ident]
    validation = None
    if base.heldout_rms is not None and final.heldout_rms is not None:
        validation = {"base_rms": base.heldout_rms, "final_rms": final.heldout_rms}
    mismatch = base_ev.mismatch
    region = mismatch["region"]
    spatial = [a.region for a in added if a.region]
    if spatial:
        region = spatial[0]
    final_added = []
    for a in added:
        values, std = term_values(final, list(a.parameters))
        entry = {**a.as_report(), "parameters": {**a.parameters, **values},
                 "std": {**{k: v for k, v in a.std.items() if k not in values}, **std}}
        if a.physics in ("gravity", "gravity.direction"):
            entry["gravity"] = gravity_words(final.experiment.gravity)
        final_added.append(entry)
    _, std_all = term_values(final, final.names)
    adopted = (numerics or {}).get("adopted", [])
    return build_report(
        # the verdict is about the user's model: anything missing makes it missing-physics
        verdict=base_ev.verdict,
        noise_std=diag.sigma,
        base=fit_summary(d, base.sim[diag.ident], diag.sigma, len(base.names)),
        final=fit_summary(d, final.sim[diag.ident], diag.sigma, len(final.names)),
        parameters={n: float(v) for n, v in zip(final.names, final.values, strict=True)},
        validation=validation, markers=mismatch["markers"],
        time_windows=mismatch["time_windows"], frequencies_hz=mismatch["frequencies_hz"],
        region=region, added=final_added, rejected=rejected, numerics=numerics or None,
        cause=mismatch_cause(base_ev.verdict, added, adopted), skipped=skipped,
        parameters_std=std_all, final_verdict=ev.verdict)


def write_diagnosis_figures(out: Path, diag: Diagnosis, result: DiagnoseResult,
                            base_ev: Evidence | None = None) -> list[Path]:
    """displacement.png, residual_on_body.png, spectra.png and (when candidates were scored)
    candidates.png: the mismatch over the whole record, where it is, the candidates, and the
    frequencies (:mod:`petsoft.diagnosis.figures`)."""
    rec = diag.recording
    names = list(rec.names)
    before, after = result.base.sim, result.final.sim
    figs = []
    plot_displacement(out / "displacement.png", diag.times, diag.data, before, after,
                      rec.reference, diag.cut, names)
    figs.append(out / "displacement.png")
    if system_class(result.base.experiment).volume_cells:
        mesh = load_mesh(result.base.experiment)
        plot_residual_on_body(out / "residual_on_body.png", mesh.points,
                              boundary_facets(mesh.tets), rec.reference,
                              rms_per_marker(diag.data, before), diag.sigma, names)
        figs.append(out / "residual_on_body.png")
    plot_spectra_before_after(out / "spectra.png", diag.times, diag.data, before, after,
                              data_modes=(base_ev.data_modes if base_ev is not None else None)
                              or ())
    figs.append(out / "spectra.png")
    if result.scores:
        plot_candidates(out / "candidates.png", result.scores,
                        [a["physics"] for a in result.added], alpha=diag.alpha)
        figs.append(out / "candidates.png")
    return figs


def _why_adopted(r: dict) -> str:
    """Why numerics round ``r`` adopted its refinement, in the words of
    :func:`~petsoft.diagnosis.numerics.refinement_matters`' arm that held."""
    o = r["options"][r["adopted"]]
    floor = f"changing the refitted simulation by {o['change_over_noise']:.2g}x the noise"
    if o["gain"] > 0.1 * max(r["chi2"] - r["dof"], 0.0):
        return f"it lowered chi2 by more than 10 % of the excess over the noise, {floor}"
    return f"it lowered chi2 by more than 10, {floor}, more than the noise"


def write_outputs(out: Path, diag: Diagnosis, result: DiagnoseResult, base_ev: Evidence,
                  wall_time: float, spelled_out: bool = False) -> None:
    """report.json, report.md, figures, diagnosed.toml, summary.json (rank 0 writes)."""
    from petsoft.diagnosis.evidence import write_figures
    from petsoft.diagnosis.report import write_report, write_report_md

    if not diag.rank0:
        return
    out.mkdir(parents=True, exist_ok=True)
    if system_class(result.base.experiment).volume_cells and base_ev.markers is not None:
        # where on the body: the base fit's per-marker residual spread over the mesh (ParaView)
        from petsoft.diagnosis.locate import write_residual_field

        mesh = load_mesh(result.base.experiment)
        write_residual_field(out / "residual_field.xdmf", mesh.points, mesh.tets,
                             diag.recording.reference, base_ev.markers)
    write_report(out / "report.json", result.report)
    t = diag.times[diag.ident]
    figs = write_figures(out, base_ev, t, diag.data[diag.ident], result.base.sim[diag.ident],
                         modes=False)
    figs += write_diagnosis_figures(out, diag, result, base_ev)
    notes = list(result.evidence.notes) if result.evidence is not None else []
    notes.append(f"identification window t <= {diag.cut:.4g} s; held out: "
                 f"{int(diag.held.sum())} later frames")
    for s in result.scores:
        notes.append(f"round {s['round']}: score test {s['physics']}: S = {s['score']:.4g}, "
                     f"dof {s['dof']}, p = {s['p_value']:.3g}")
    for k, why in sorted(result.not_modelled.items()):
        notes.append(f"{k}: not modelled yet / not tried ({why})")
    for r in result.numerics.get("refinements", []):
        opts = "; ".join(f"{k}: chi2 {v['chi2']:.5g}" for k, v in r["options"].items()
                         if "chi2" in v)
        notes.append(f"numerics before blaming physics (after {r.get('after_additions', 0)} "
                     f"additions; checked {r['why']}): chi2 {r['chi2']:.5g} at step "
                     f"{r['step']:.4g} s; refined: "
                     f"{opts}; " + (f"adopted {r['adopted']} ({_why_adopted(r)})"
                                    if r.get("adopted")
                                    else "nothing adopted (refinement does not matter)"))
    if result.numerics.get("model_error"):
        notes.append("discretisation error estimated from the refinement check (Richardson): "
                     + ", ".join(f"{k} {v:.3g} m" for k, v in
                                 result.numerics["model_error"].items())
                     + f"; the verdict tests the residual against the noise and this error in "
                     f"quadrature ({result.numerics['sigma_verdict']:.3g} m)")
    # report.md states the evidence's findings (its report form) and this log as its notes
    ev = result.evidence.as_report() if result.evidence is not None else {}
    write_report_md(out / "report.md", result.report, {**ev, "notes": notes},
                    [f.name for f in figs])
    write_report_html(out / "report.html", out / "report.md", figs)
    write_experiment_update(diag.base_experiment, result.final.experiment,
                            out / "diagnosed.toml", spelled_out=spelled_out)
    results = {
        "recording": str(diag.path), "verdict": result.verdict,
        "final_verdict": result.final_verdict,
        "noise_std": diag.sigma, "noise_source": diag.sigma_source,
        "identification_end": diag.cut,
        "base": {"parameters": dict(zip(result.base.names, result.base.values.tolist(),
                                        strict=True)),
                 "chi2": result.base.chi2, "rms": result.base.rms,
                 "heldout_rms": result.base.heldout_rms},
        "final": {"parameters": dict(zip(result.final.names, result.final.values.tolist(),
                                         strict=True)),
                  "chi2": result.final.chi2, "rms": result.final.rms,
                  "heldout_rms": result.final.heldout_rms},
        "scores": [{k: v for k, v in s.items() if k != "gradient"} for s in result.scores],
        "not_modelled": result.not_modelled, "numerics": result.numerics,
        "files": {"report": "report.json", "markdown": "report.md", "html": "report.html",
                  "experiment": "diagnosed.toml", "figures": [f.name for f in figs],
                  "residual_field": ("residual_field.xdmf"
                                     if (out / "residual_field.xdmf").exists() else None)},
    }
    write_summary(out, "diagnose", results, {"simulations": None}, wall_time, diag.comm)
