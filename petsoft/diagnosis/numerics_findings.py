"""What the numerics checks of a diagnosis found, in sentences a user acts on.

:func:`numerics_findings` turns the rounds of :func:`~petsoft.diagnosis.numerics.resolve_numerics`
and the final :func:`~petsoft.diagnosis.numerics.numerics_check` into report.json's ``numerics``
(a :class:`~petsoft.diagnosis.numerics_records.NumericsFindings`: ``findings``: which
refinement matters and by how much, what was adopted and what error is left, round by round;
``summary``: one sentence and one number per refinement, on the final model; ``adopted``;
``recommendation``: the mesh and step to use; ``mesh``: the tet counts behind them). The rounds
and the final check it reads are records too (:mod:`petsoft.diagnosis.numerics_records`).
report.md says ``summary`` and ``recommendation`` in "In short", ``findings`` in its appendix.
"""

from __future__ import annotations

from petsoft.calibration.refinement import STEP_HALVED, levels_needed, mesh_cells, refinement
from petsoft.diagnosis.numerics import ADOPT_CHANGE, too_small_to_adopt
from petsoft.diagnosis.numerics_records import (
    FinalCheck,
    LinearisedOption,
    NumericsFindings,
    NumericsRound,
    RefittedOption,
)
from petsoft.dynamics.factory import system_class

#: The order and the name of each refinement in the summary (one sentence each).
_SUMMARY_ORDER = ("step/2", "mesh x2", "P2", "mesh x2 + step/2")

#: How each kind of refinement is said: (the action, the thing refined).
_WORDS = {"step": ("the time step is halved", "time step"),
          "mesh": ("the mesh is refined", "mesh"),
          "order": ("the elements are raised to order 2", "element order"),
          "mesh+step": ("the mesh is split and the step halved together", "discretisation")}


def _slot(label: str) -> str:
    """The summary's sentence a refinement ``label`` belongs to: one for the time step, whether
    it was halved or quartered (``"step/4"``, :func:`petsoft.diagnosis.numerics.step_jump`)."""
    try:
        return STEP_HALVED.label if refinement(label).kind == "step" else label
    except KeyError:
        return label


def _x(v: float) -> str:
    return f"{v:.2g}" if v < 10 else f"{v:.0f}"


def refinement_words(label: str) -> tuple[str, str]:
    """How refinement ``label`` is said: (the action, the thing refined), e.g. ("the time step
    is halved", "time step")."""
    try:
        return _WORDS[refinement(label).kind]
    except KeyError:
        return f"the model is refined ({label})", label


def _shifts(before: dict, after: dict) -> str:
    moved = [f"{n} {before[n]:.4g} -> {after[n]:.4g}" for n in after
             if n in before and before[n] != 0 and abs(after[n] / before[n] - 1) > 1e-3]
    return f", {' and '.join(moved)}" if moved else ""


def _measured_sentence(head: str, o: LinearisedOption, sigma: float, noun: str) -> str:
    """What one run of a mesh too large to fit measured (``measured_only`` options)."""
    text = (f"{head}, simulated once (over diagnose's fitting limit); after a {o.refit} "
            f"it still changes by {_x(o.change_over_noise)}x the noise")
    if o.error_estimate > 0.0:
        return (text + f": counted as a {noun} error of {_x(o.error_estimate / sigma)}x the "
                "noise in the verdict's noise budget, not blamed on physics"
                + (" (it matters: refine the mesh to resolve it)." if o.matters else "."))
    return text + f", but no closer to the data: the {noun} is not what the model misses."


def _round_sentences(r: NumericsRound, sigma: float, first: bool) -> list[str]:
    out = []
    where = ("" if first else "Checked again on the final model: " if r.final_check
             else "Then, on the adopted model: ")
    for label, o in r.options.items():
        action, noun = refinement_words(label)
        if o.failed:
            out.append(f"{where}when {action}, the refined fit failed: {o.error}.")
            continue
        x = o.change_same_parameters_over_noise
        head = f"{where}the simulation changes by {_x(x)}x the noise when {action} ({o.how})"
        head = head[0].upper() + head[1:]
        fit = f"chi2/dof {r.chi2 / r.dof:.3g} -> {o.chi2_per_dof:.3g}"
        moved = _shifts(r.parameters, o.parameters)
        # closer to the data by enough, but its refit changes the simulation by less than
        # ADOPT_CHANGE x the noise: not adopted for that alone
        small = too_small_to_adopt(o.gain, max(r.chi2 - r.dof, 0.0), o.change_rms, sigma)
        floor = (f"changes the simulation by only {_x(o.change_over_noise)}x the noise "
                 f"(a refinement is adopted from {ADOPT_CHANGE:g}x)")
        if o.measured_only:
            out.append(_measured_sentence(head, o, sigma, noun))
        elif o.screened and o.deferred:
            # not refitted: a refit would have been deferred (small beside the misfit)
            out.append(f"{head}, and a linearised refit improves the fit ({fit}), but while "
                       f"the model misses the data by {_x(o.deferred)}x the noise an error "
                       f"this small is not what it misses: counted as a {noun} error of "
                       f"{_x(o.error_estimate / sigma)}x the noise and checked "
                       "again once the misfit is smaller (not refitted).")
        elif o.screened and o.error_estimate > 0.0:
            # not refitted: its linearised refit was closer to the data by too little to matter
            improves = (f"comes closer to the data ({fit}) but {floor}" if small else
                        f"improves little ({fit})")
            out.append(f"{head}, and a linearised refit {improves}: counted as a "
                       f"{noun} error of {_x(o.error_estimate / sigma)}x the noise, not "
                       "blamed on physics (not refitted).")
        elif o.screened:
            # not refitted: its linearised refit was no closer to the data
            out.append(f"{head}" + (": less than the noise on this model" if x < 1.0 else
                                    f", but a linearised refit is no closer to the data "
                                    f"({fit}): the {noun} is not what the model misses")
                       + " (not refitted).")
        elif r.adopted == label:
            blame = (f"the mismatch is the {noun}, not physics" if x >= 3.0 else
                     f"part of the mismatch is the {noun}")
            out.append(f"{head}; refitted, {fit}{moved}: {blame}. The refined model is "
                       "adopted.")
        elif o.matters:
            out.append(f"{head}; refitted, the fit improves ({fit}), but less than when "
                       f"{refinement_words(r.adopted)[0]}.")
        elif o.deferred:
            out.append(f"{head}; refitted, the fit improves ({fit}{moved}), but while the "
                       f"model misses the data by {_x(o.deferred)}x the noise an error this "
                       f"small is not what it misses: counted as a {noun} error of "
                       f"{_x(o.error_estimate / sigma)}x the noise and checked "
                       "again once the misfit is smaller.")
        elif x < 1.0:
            out.append(f"{head}: less than the noise on this model.")
        elif o.error_estimate > 0.0:
            improves = (f"comes closer to the data ({fit}{moved}) but {floor}" if small else
                        f"improves little ({fit}{moved})")
            out.append(f"{head}, but refitted it {improves}: counted "
                       f"as a {noun} error of {_x(o.error_estimate / sigma)}x the noise, "
                       "not blamed on physics.")
        else:
            out.append(f"{head}, but refitted it is no closer to the data ({fit}): the {noun} "
                       "is not what the model misses.")
    return out


def measured_error(rounds: list[NumericsRound]) -> tuple[float, str | None]:
    """The largest error measured by one run of a mesh too large to fit, on the last round
    that measured one, and its label (``"mesh x2"``, or ``"mesh x2 + step/2"`` when only the
    split mesh at half the step came closer to the data); (0, None) if none."""
    for r in reversed(rounds):
        measured = {label: float(o.error_estimate)
                    for label, o in r.options.items() if not o.failed and o.measured_only}
        if measured:
            label = max(measured, key=measured.get)
            return measured[label], label
    return 0.0, None


def _adopted_setting(label: str, final) -> str:
    """What an adopted refinement made of the model, in the user's terms."""
    kind = refinement(label).kind
    if kind == "step":
        return f"a time step of {final.experiment.time.step:.4g} s"
    if kind == "order":
        return "10-node tetrahedra"
    return f"the refined mesh ({mesh_cells(final.experiment)} tets)"


def numerics_summary(num: FinalCheck | None, rounds: list[NumericsRound], final, sigma: float
                     ) -> tuple[list[str], list[str], dict[str, str]]:
    """(one sentence per refinement, the labels adopted, {label: why} of the refinements never
    made): what a reader needs of the numerics.

    Each sentence quotes one number, the change of the simulation in units of the noise when
    the refinement is made on the model the diagnosis ended with (its last check; the first
    rounds' changes, on other models, stay in ``findings``). A refinement is said to be fine
    only when that change is below the noise; one whose refit came closer to the data and whose
    error is counted in the verdict's noise budget (``sigma``: the noise) is said to be counted.
    ``num``: the final model's check (None: not made).
    """
    adopted = [r.adopted for r in rounds if r.adopted]
    slots = {_slot(a) for a in adopted}
    last: dict[str, tuple[dict, bool]] = {}      # label -> (its last measurement, refitted?)
    closer: dict[str, bool] = {}                 # label -> its last refit came closer
    largest: dict[str, float] = {}               # label -> its largest change on any model
    not_tried: dict[str, str] = {}
    covered: dict[str, bool] = {}
    for r in rounds:
        for raw, o in r.options.items():
            if o.failed:
                continue
            label = _slot(raw)
            refitted = not (o.screened or o.measured_only)
            # "adopting": the change is the one that made the refinement adopted, not a
            # further refinement of the adopted model
            last[label] = ({"x": o.change_same_parameters_over_noise, "how": o.how,
                            "adopting": r.adopted == raw,
                            "refitted_x": o.change_over_noise,
                            "counted": o.error_estimate / sigma}, refitted)
            # whether its last refit (a full or a linearised one) came closer to the data
            closer[label] = bool(o.matters)
            largest[label] = max(largest.get(label, 0.0), last[label][0]["x"])
        for label, why in (r.not_tried or {}).items():
            not_tried[label] = why
            # the split mesh is not made when 10-node elements, which have its nodes, are
            # tried in its place: then it is covered, not unchecked
            covered[label] = label == "mesh x2" and "P2" in r.options
    for label, v in (num.made() if num is not None else {}).items():
        last[label] = ({"x": v.change_over_noise, "how": v.how, "adopting": False,
                        "estimated": v.estimated}, last.get(label, ({}, False))[1])
    out = []
    unchecked: dict[str, str] = {}
    for label in sorted(set(last) | set(not_tried),
                        key=lambda k: _SUMMARY_ORDER.index(k) if k in _SUMMARY_ORDER else 9):
        noun = refinement_words(label)[1]
        name = noun[0].upper() + noun[1:]
        if label not in last and covered.get(label):
            out.append(f"{name}: not refined by itself ({not_tried[label]}).")
            continue
        if label not in last:
            out.append(f"{name}: not checked ({not_tried[label]}).")
            unchecked[label] = not_tried[label]
            continue
        m, refitted = last[label]
        x = f"{_x(m['x'])}x the noise"
        if label in slots and m["adopting"]:
            out.append(f"{name}: part of the mismatch: refining it ({m['how']}) changed the "
                       f"simulation by {x} and brought it closer to the data; adopted: "
                       f"{_adopted_setting(label, final)}.")
        elif label in slots:
            again = (f"; refining once more ({m['how']}) would change the simulation by an "
                     f"estimated {x} (Richardson, from the last refinement; not simulated)"
                     if m.get("estimated") else
                     f"; refining once more ({m['how']}) changes the simulation by {x}")
            again += (", so it still limits what the diagnosis can tell apart"
                      if m["x"] >= 1.0 else "")
            out.append(f"{name}: part of the mismatch; adopted: "
                       f"{_adopted_setting(label, final)}{again}.")
        elif m["x"] < 1.0 and largest.get(label, 0.0) < 1.0:
            out.append(f"{name}: refining it ({m['how']}) changes the simulation by {x}: "
                       "it is fine for this recording.")
        elif m["x"] < 1.0:
            # more than the noise on an earlier model (in ``findings``), less on the final one
            out.append(f"{name}: refining it ({m['how']}) changes the final model by {x}: "
                       f"the {noun} does not limit this diagnosis.")
        elif m.get("counted", 0.0) > 0.0:
            out.append(f"{name}: refining it ({m['how']}) changes the simulation by {x}, "
                       f"{_x(m['refitted_x'])}x after a refit that brought it closer to the "
                       f"data: the {noun}'s error, estimated at {_x(m['counted'])}x the noise, "
                       "is counted in the verdict's noise budget.")
        elif closer.get(label):
            # closer to the data, yet neither adopted nor counted (another refinement was
            # adopted in its round): it is part of what the model misses
            out.append(f"{name}: refining it ({m['how']}) changes the simulation by {x} and, "
                       f"refitted, brought it closer to the data, but it was not adopted: the "
                       f"{noun} limits what this diagnosis can tell apart.")
        elif label in closer:
            out.append(f"{name}: refining it ({m['how']}) changes the simulation by {x}, but "
                       f"refitted it came no closer to the data: the {noun} is not what the "
                       f"model misses, though the calibrated values are those of this {noun}.")
        else:
            out.append(f"{name}: refining it ({m['how']}) changes the simulation by {x} (not "
                       f"refitted): the {noun} limits what this diagnosis can tell apart.")
    return out, adopted, unchecked


def numerics_findings(diag, num: FinalCheck | None, rounds: list[NumericsRound], base,
                      final) -> NumericsFindings:
    """report.json's ``numerics``: ``findings`` (sentences), ``summary``, ``adopted``,
    ``recommendation`` (a sentence or None) and ``mesh`` (tets of the user's and the final
    model, and the recommended count).

    Parameters
    ----------
    diag : Diagnosis
    num : FinalCheck or None
        :func:`~petsoft.diagnosis.numerics.numerics_check` of the final model (None: not made).
    rounds : list of NumericsRound
        The rounds of :func:`~petsoft.diagnosis.numerics.resolve_numerics`, in order.
    base, final : Fit
        The user's calibrated model and the final one.
    """
    sigma = diag.sigma
    remaining = {r.adopted: r.options[r.adopted] for r in rounds if r.adopted}
    findings = (_rounds_findings(rounds, sigma)
                + [_remaining_sentence(label, o, rounds, diag.model_error, sigma)
                   for label, o in remaining.items()]
                + _final_model_findings(num))
    summary, adopted, unchecked = numerics_summary(num, rounds, final, sigma)
    if not system_class(base.experiment).volume_cells:
        return NumericsFindings(findings=findings, recommendation=None, summary=summary,
                                adopted=adopted, unchecked=unchecked)
    mesh = {"tets": mesh_cells(base.experiment), "tets_final": mesh_cells(final.experiment)}
    advice = _mesh_advice(num, rounds, remaining, unchecked, base, final, sigma, mesh)
    if final.experiment.mesh.order > base.experiment.mesh.order:
        advice.append("Use 10-node tetrahedra ([mesh] order = 2): on your mesh they remove "
                      "what the 4-node ones' stiffness in bending hid.")
        mesh["order_final"] = final.experiment.mesh.order
    if final.experiment.time.step < base.experiment.time.step:
        advice.append(f"Use a time step of at most {final.experiment.time.step:.4g} s (yours is "
                      f"{base.experiment.time.step:.4g} s).")
    return NumericsFindings(findings=findings, recommendation=" ".join(advice) or None,
                            summary=summary, adopted=adopted, unchecked=unchecked, mesh=mesh)


def _rounds_findings(rounds: list[NumericsRound], sigma: float) -> list[str]:
    """What each round found (:func:`_round_sentences`), and each refinement not tried, said
    once, where it was first not tried."""
    findings: list[str] = []
    said_not_tried: set[str] = set()
    for i, r in enumerate(rounds):
        findings += _round_sentences(r, sigma, first=i == 0)
        for label, why in (r.not_tried or {}).items():
            if label not in said_not_tried:
                said_not_tried.add(label)
                again = " again" if any(label in q.options for q in rounds) else ""
                findings.append(f"The {refinement_words(label)[1]} was not refined{again}: {why}.")
    return findings


def _remaining_sentence(label: str, o: RefittedOption, rounds: list[NumericsRound],
                        model_error: dict, sigma: float) -> str:
    """What remains of the adopted refinement ``label`` (its round's option ``o``): its own
    error, bounded by what the refined fit leaves, and whether the verdict counts it."""
    noun = refinement_words(label)[1]
    if o.remaining_estimate == 0.0:
        # a refinement whose own error is taken as nil (10-node elements on the same mesh:
        # their error falls as h^3), not estimated from the change it made
        at = next(i for i, q in enumerate(rounds) if q.adopted == label)
        measured = any("mesh x2" in q.options for q in rounds[at + 1:])
        return (f"What remains: the adopted {noun} is taken as resolved on this mesh "
                "(10-node elements' error falls as h^3)"
                + ("; the mesh refinement above measured it." if measured else
                   "; the mesh split 1->8 that would measure it was not made."))
    rem = o.remaining_estimate
    bound = rem if o.remaining_bound is None else o.remaining_bound
    counted = label in model_error and any(
        q.adopted == label and q.remaining_counted for q in rounds)
    share = rem / o.change_rms if o.change_rms > 0 else 0.0
    text = (f"What remains: the adopted {noun}'s own error is estimated at {_x(rem / sigma)}x "
            f"the noise (Richardson: {share:.2g} of the change refining made)")
    if bound < 0.05 * sigma:
        text += ", but the refined fit leaves nothing above the noise"
    elif bound < 0.8 * rem:
        text += (f", at most {_x(bound / sigma)}x as the refined fit leaves no more above "
                 "the noise")
    if counted:
        text += ("; it is counted in the verdict's noise budget, since the next refinement "
                 "was not made")
        if bound > sigma:
            text += (f", so a missing effect smaller than about {_x(bound / sigma)}x the "
                     f"noise cannot be told apart from the {noun}")
    return text + "."


def _final_model_findings(num: FinalCheck | None) -> list[str]:
    """What each refinement changes on the final model (``num``: its numerics check, None
    when not made), measured or estimated."""
    findings = []
    for label, v in (num.made() if num is not None else {}).items():
        action, noun = refinement_words(label)
        limits = ("" if v.resolved else f": more than the noise, so the {noun} still "
                  "limits what this diagnosis can tell apart")
        if v.estimated:
            findings.append(f"On the final model, the simulation would change by an "
                            f"estimated {_x(v.change_over_noise)}x the noise when "
                            f"{action} ({v.how}; Richardson, from the last refinement's "
                            f"change: not simulated, being far below the noise){limits}.")
        else:
            findings.append(f"On the final model, the simulation changes by "
                            f"{_x(v.change_over_noise)}x the noise when {action} "
                            f"({v.how}){limits}.")
    return findings


def _mesh_advice(num: FinalCheck | None, rounds: list[NumericsRound], remaining: dict,
                 unchecked: dict, base, final, sigma: float, mesh: dict) -> list[str]:
    """What the recommendation says of the mesh (at most one sentence, a list to extend):
    refine it to a count (set in ``mesh["recommended_tets"]``), refine it because a run
    measured its error or the final model's check found it unresolved, check it with
    ``--check-mesh``, or that it is fine."""
    user, now = mesh["tets"], mesh["tets_final"]
    measured, measured_by = measured_error(rounds)
    if "mesh x2" in remaining or now > user:
        o = remaining.get("mesh x2")
        rem = (0.0 if o is None else o.remaining_estimate if o.remaining_bound is None
               else o.remaining_bound) / sigma
        extra = levels_needed(rem)
        need = now * 8 ** extra
        levels = 0
        while user * 8 ** levels < need:
            levels += 1
        how = (f"box cells x{2 ** levels} per axis" if base.experiment.mesh.box is not None
               else f"[mesh] refine = {levels + base.experiment.mesh.refine}, or a mesh file "
                    f"with the element size divided by {2 ** levels}")
        mesh["recommended_tets"] = need
        return [f"Refine the mesh to at least {need} tets (yours has {user}: {how})"
                + (f"; the diagnosis used {now}, whose own error is estimated at "
                   f"{_x(rem)}x the noise" if extra else "") + "."]
    if measured > sigma:
        both = measured_by != "mesh x2"
        return [f"Refine the mesh ({user} tets){' and the time step' if both else ''}: "
                f"one run of the split mesh{' at half the step' if both else ''} measured "
                f"an error of {_x(measured / sigma)}x the noise on the final model."]
    made = num.made() if num is not None else {}
    unresolved = [label for label in ("mesh x2", "P2")
                  if label in made and not made[label].resolved]
    if unresolved:
        return [f"Refine the mesh ({user} tets) before using the calibrated values "
                "beyond this recording: on the final model, refining the "
                + " or the ".join(refinement_words(label)[1] for label in unresolved)
                + " changes the simulation by more than the noise."]
    if "mesh x2" in unchecked and measured == 0.0:
        return [f"Your mesh ({user} tets) could not be refined within diagnose's limit "
                f"({unchecked['mesh x2']}): check the calibrated parameters with "
                "`petsoft calibrate --check-mesh`."]
    if any("mesh x2" in r.options or "P2" in r.options for r in rounds) or "mesh x2" in made:
        raised = final.experiment.mesh.order > base.experiment.mesh.order
        text = (f"Your mesh ({user} tets) is fine for this recording"
                + (" with 10-node elements (below)" if raised else ""))
        if measured > 0.0:
            # a measured error below the noise: say it, as it is in the verdict's budget
            both = measured_by != "mesh x2"
            text += (f": one run of the split mesh{' at half the step' if both else ''} "
                     f"measured an error of {_x(measured / sigma)}x the noise on the final "
                     "model, below the noise and counted in the verdict's noise budget")
        return [text + "."]
    if (any("mesh x2" in (r.not_tried or {}) for r in rounds)
            or (num is not None and "mesh x2" in num.changes)):
        return [f"Your mesh ({user} tets) could not be checked within diagnose's limit: "
                "check the calibrated parameters with `petsoft calibrate --check-mesh`."]
    return []
