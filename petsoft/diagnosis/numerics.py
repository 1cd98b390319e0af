"""The numerics check of a diagnosis: is the mismatch the model's discretisation, not physics?

Before physics is blamed, the step is halved and the mesh refined (:func:`resolve_numerics`);
a refinement that changes the simulation by more than the noise is adopted, and the error it
leaves is estimated (Richardson) and counted in the verdict's noise budget.
:func:`numerics_due` says when the check must run again; :class:`NumericsChecks` keeps the state
of those checks across the rounds of one run.
"""

from __future__ import annotations

import gc

import numpy as np

from petsoft.calibration.groups import map_on_groups
from petsoft.diagnosis.context import Diagnosis, Fit, evidence_of, rms, with_time

#: The numerics check refines a box mesh only while the refined mesh has at most this many
#: tetrahedra (6 per box cell).
MESH_CELLS = 4000


def numerics_check(diag: Diagnosis, fit: Fit) -> dict:
    """Residual change when the step is halved and (box meshes) the cells are doubled.

    Returns
    -------
    dict
        Per refinement: ``rms`` of the refined model's residual over all frames, ``change`` =
        rms of (refined - original simulation) over the seen samples, ``change_over_noise``.
    """
    out = {"base_rms_all": rms(fit.sim, diag.data)}
    exp = fit.experiment
    checks = [("step/2", dict(h=exp.time.step / 2), exp)]
    box = exp.mesh.box
    refined_cells = 8 * 6 * int(np.prod(box.cells)) if box is not None else 0
    if box is not None and refined_cells <= MESH_CELLS:
        checks.append(("mesh x2", {}, with_time(exp, cells_factor=2)))
    seen = np.isfinite(diag.data)
    for label, kw, e in checks:
        sim = diag.simulate(e, **kw)
        change = float(np.sqrt(np.mean((sim[seen] - fit.sim[seen]) ** 2)))
        out[label] = {"rms": rms(sim, diag.data), "change": change,
                      "change_over_noise": change / diag.sigma,
                      # below the noise, the refinement cannot move the verdict
                      "resolved": bool(change < diag.sigma)}
    if box is None:
        out["mesh x2"] = "not done: only [mesh] box meshes are refined by diagnose yet"
    elif refined_cells > MESH_CELLS:
        # the same limit as resolve_numerics: one run on 18432 tets took 7 minutes, longer than
        # the whole diagnosis on the current mesh
        out["mesh x2"] = (f"not done: the refined mesh would have {refined_cells} tets, over "
                          f"diagnose's limit of {MESH_CELLS}")
    return out


def refined(experiment, what: str):
    """The experiment with the step halved (``"step/2"``) or a box mesh's cells doubled."""
    if what == "step/2":
        return with_time(experiment, step=experiment.time.step / 2)
    return with_time(experiment, cells_factor=2)


def numerics_due(checked_excess: float | None, excess: float,
                 switch_added: str | None) -> str | None:
    """Why the numerics must be checked (again) before the next round, or None.

    First before any physics is added; again when the misfit's excess has shrunk tenfold since
    the last check (a large physical misfit hides a discretisation error that dominates once the
    physics is fixed), or when a switch was added: a model of another kind needs its own
    resolution (a penalty contact's impact, its default stiffness k = 4 m / h^2 set by the step,
    is resolved only by a finer step than the free swing's: seen, a contact case fitted E 24 %
    low at the base step).

    Parameters
    ----------
    checked_excess : float or None
        chi2 - dof the last check left (None: never checked).
    excess : float
        chi2 - dof of the current model.
    switch_added : str or None
        The switch (contact, nonlinear law) added since the last check, if any: a model of
        another kind needs its own resolution.
    """
    if checked_excess is None:
        return "first, before any physics is added"
    if switch_added:
        return f"because {switch_added}, a switch of the model's kind, was added"
    if excess <= 0.1 * checked_excess:
        return "because the misfit's excess over the noise shrank tenfold since the last check"
    return None


def resolve_numerics(diag: Diagnosis, fit: Fit, ev: dict, max_rounds: int = 3,
                     mesh_done: bool = False):
    """Rule out numerics before blaming physics (issue 6, step 5).

    The base model is re-calibrated with the step halved and (``[mesh] box`` only, once) with
    the cells doubled per axis, concurrently on groups of ranks. A refinement *matters* when its
    fit lowers chi2 by more than 10 % of the residual's excess over the noise (chi2 - dof) and by
    more than 10: part of the mismatch is then discretisation error (backward Euler's artificial
    damping looks exactly like physical damping), so the refined model replaces the base model
    and the check is repeated, at most ``max_rounds`` times (a box mesh is refined while the
    refined mesh has at most :data:`MESH_CELLS` tetrahedra; ``mesh_done`` stops it). Returns
    the (possibly refined) fit, its evidence and a list
    of what each round measured.
    """
    rounds: list[dict] = []
    for _ in range(max_rounds):
        exp = fit.experiment
        options = ["step/2"]
        box = getattr(exp.mesh, "box", None) if exp.mesh is not None else None
        if box is not None and not mesh_done and 8 * 6 * int(np.prod(box.cells)) <= MESH_CELLS:
            options.append("mesh x2")
        fits = map_on_groups(
            lambda what, sub, exp=exp: diag.calibrate(refined(exp, what), comm=sub),
            options, diag.comm)
        gc.collect()
        dof = max(int(np.isfinite(diag.data[diag.ident]).sum()) - len(fit.names), 1)
        excess = max(fit.chi2 - dof, 0.0)
        entry = {"chi2": fit.chi2, "dof": dof, "step": exp.time.step, "options": {}}
        best = None
        seen = np.isfinite(diag.data[diag.ident])
        order = {"step/2": 1 if (diag.integrator or exp.time.integrator) in ("be", "si") else 2,
                 "mesh x2": 2}
        for what, res in zip(options, fits, strict=True):
            if not res.ok:
                entry["options"][what] = {"error": res.error}
                continue
            gain = fit.chi2 - res.value.chi2
            matters = bool(gain > 0.1 * excess and gain > 10.0)
            change = float(np.sqrt(np.mean((res.value.sim[diag.ident][seen]
                                            - fit.sim[diag.ident][seen]) ** 2)))
            k = 2.0 ** order[what]
            # Richardson: the current model's error ~ change 2^p / (2^p - 1). It is counted
            # only when refining brings the simulation closer to the data (else the data do
            # not see that error) and the refinement is not adopted (an adopted model's own
            # error is unknown until the next round measures it: a coarse mesh's change is far
            # from the asymptotic regime and would overstate it)
            if gain > 0.0 and not matters:
                diag.model_error[what] = change * k / (k - 1.0)
            else:
                diag.model_error.pop(what, None)
            entry["options"][what] = {"chi2": res.value.chi2, "gain": gain, "matters": matters,
                                      "change_rms": change,
                                      "error_estimate": diag.model_error.get(what, 0.0)}
            diag.tell(f"numerics: {what}: chi2 {fit.chi2:.5g} -> {res.value.chi2:.5g} "
                      f"({'matters' if matters else 'resolved'})")
            if matters and (best is None or gain > best[1]):
                best = (what, gain, res.value)
        rounds.append(entry)
        if best is None:
            break
        entry["adopted"] = best[0]
        fit = best[2]
        ev = evidence_of(diag, fit)
        diag.tell(f"numerics: adopted {best[0]} (step {fit.experiment.time.step:.4g} s); verdict "
                  f"{ev['verdict']} (chi2/dof {ev['noise_test'].chi2_per_dof:.4g})")
        if ev["verdict"] == "consistent":
            break
    return fit, ev, rounds


class NumericsChecks:
    """The numerics checks of one diagnosis run and what they remember between rounds.

    Parameters
    ----------
    diag : Diagnosis
    enabled : bool
        ``run_diagnose(numerics=...)``: False skips every check.
    """

    def __init__(self, diag: Diagnosis, enabled: bool):
        self.diag, self.enabled = diag, enabled
        #: every refinement tried, in order (report.json ``numerics.refinements``)
        self.refinements: list[dict] = []
        #: the excess chi2 the last check left (None before the first)
        self.checked_excess: float | None = None
        #: a model switch added since the last check (it may need a finer step)
        self.switch_since_check: str | None = None

    def first(self, fit: Fit, ev: dict, added: int):
        """Rule out numerics before blaming physics, when :func:`numerics_due` says a check is
        due; returns the (possibly refined) fit and its evidence."""
        if not self.enabled or ev["verdict"] == "consistent":
            return fit, ev
        why = numerics_due(self.checked_excess, self.diag.excess(fit), self.switch_since_check)
        return self.refine(fit, ev, why, added) if why else (fit, ev)

    def refine(self, fit: Fit, ev: dict, why: str, added: int, final: bool = False):
        """:func:`resolve_numerics`, its rounds recorded, and the excess it leaves remembered so
        that the next round's :meth:`first` does not repeat it at once."""
        fit, ev, rounds = resolve_numerics(self.diag, fit, ev)
        for r in rounds:
            r["after_additions"] = added
            r["why"] = why
            if final:
                r["final_check"] = True
        self.refinements += rounds
        self.checked_excess = self.diag.excess(fit)
        self.switch_since_check = None
        return fit, ev

    def recheck_final(self, fit: Fit, ev: dict, added: int):
        """Measure an estimated discretisation error again on the final model.

        A consistent verdict may lean on a discretisation error estimated while a large
        physical misfit hid how much that error matters (``sigma_verdict``). Measured again on
        the final model, the refinement may now matter: seen, a corotated bar's step error, 2.8 x
        the noise over the record, was counted as model error and its held-out prediction stayed
        2.2 x the noise. Returns (fit, ev, whether it ran).
        """
        diag = self.diag
        if not (self.enabled and diag.model_error and ev["verdict"] == "consistent"):
            return fit, ev, False
        diag.tell("numerics: the verdict counts an estimated discretisation error ("
                  + ", ".join(f"{k} {v:.3g} m" for k, v in diag.model_error.items())
                  + "); measuring it again on the final model")
        fit, ev = self.refine(fit, ev, "again on the final model: its consistent verdict "
                              "counted an estimated discretisation error", added, final=True)
        return fit, ev, True

