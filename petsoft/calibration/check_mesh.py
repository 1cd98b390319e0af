"""``petsoft calibrate --check-mesh``: does refining the mesh move the calibrated parameters?

A coarse P1 mesh is too stiff in bending, and a calibration absorbs that into the parameters (a
648-tet cantilever calibrated E 26 % low, issue 14) while the fit still looks fine. After the
fit, :func:`check_mesh` calibrates again on the mesh refined once (a box's cells doubled, a mesh
file split 1 -> 8: :data:`~petsoft.calibration.refinement.MESH_HALVED`) and, for 4-node elements,
with 10-node ones on the same mesh (:data:`~petsoft.calibration.refinement.ORDER_RAISED`),
starting from the calibrated values, and warns for every parameter a refinement moves by more
than its standard deviation, saying by how many.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from petsoft.calibration.refinement import MESH_HALVED, ORDER_RAISED
from petsoft.experiment import with_parameters


def check_mesh(experiment, result, refit: Callable, say: Callable[[str], None]) -> dict:
    """Re-calibrate ``experiment`` on its refined mesh and compare with ``result``; for 4-node
    elements also with 10-node ones (the entry ``"order"`` of the result, same keys).

    Parameters
    ----------
    experiment : Experiment
        The calibrated model as given (its values are replaced by ``result.values``).
    result : CalibrationResult
        The fit on the user's mesh (``names``, ``values``, ``std``, ``rms_after``).
    refit : callable(Experiment) -> CalibrationResult
        Calibrates an experiment the same way as the first fit (method, gradient, noise).
    say : callable(str)
        Progress and the warnings (rank 0).

    Returns
    -------
    dict
        ``done`` (False with ``reason`` when the mesh cannot be refined), ``how`` (what the
        refinement did), ``values`` and ``std`` on the refined mesh, ``shift_sigmas``
        ((refined - original) / original std per parameter), ``rms`` (before, after) and
        ``warnings`` (sentences: one per parameter moved by more than one std, and one when
        the refined fit's rms is below 0.8 of the original's while that is above 1.2 x the
        noise).
    """
    out = _check(MESH_HALVED, experiment, result, refit, say)
    if ORDER_RAISED.applies(experiment) is None:
        out["order"] = _check(ORDER_RAISED, experiment, result, refit, say)
    return out


def _check(refinement, experiment, result, refit: Callable, say: Callable[[str], None]) -> dict:
    """One refinement's re-calibration and its comparison (:func:`check_mesh`)."""
    reason = refinement.applies(experiment)
    if reason is not None:
        say(f"check-mesh: not done: {reason}")
        return {"done": False, "reason": reason}
    how = refinement.describe(experiment)
    what = "with 10-node elements" if refinement.kind == "order" else "on the refined mesh"
    say(f"check-mesh: calibrating again {what} ({how}), from the calibrated values")
    start = dict(zip(result.names, map(float, result.values), strict=True))
    fine = with_parameters(refinement.make(experiment), start)
    again = refit(fine)
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = (np.asarray(again.values) - np.asarray(result.values)) / np.asarray(result.std)
    finer = ("twice the box cells per axis" if experiment.mesh.box is not None else
             f"[mesh] refine = {experiment.mesh.refine + 1}, or a mesh file with half the "
             "element size")
    action, advice = "refining the mesh", f"calibrate on a finer mesh ({finer})"
    if refinement.kind == "order":
        action, advice = ("raising the elements to order 2",
                          "calibrate with 10-node tetrahedra ([mesh] order = 2)")
    warnings = []
    for name, a, b, s, k in zip(result.names, result.values, again.values, result.std, shift,
                                strict=True):
        known = bool(np.isfinite(s) and s > 0.0)
        if known and abs(k) > 1.0:
            warnings.append(
                f"{action} ({how}) moves {name} by {abs(k):.3g} standard deviations "
                f"({a:.6g} -> {b:.6g}, std {s:.3g}): the calibrated value carries the mesh's "
                f"discretisation error; {advice}")
        elif known:
            say(f"check-mesh: {name}: {a:.6g} -> {b:.6g} ({k:+.2g} std): within its standard "
                "deviation")
        else:
            say(f"check-mesh: {name}: {a:.6g} -> {b:.6g} (its standard deviation is unknown: "
                "not compared)")
    if again.rms_after < 0.8 * result.rms_after and result.rms_after > 1.2 * result.sigma:
        # the parameters may not move (a fit on the coarse mesh can settle near the right
        # values with a wrong shape) while the refined mesh fits far better: say that too
        warnings.append(f"{what} the fit is much closer to the data (rms "
                        f"{result.rms_after:.3g} m -> {again.rms_after:.3g} m; noise "
                        f"{result.sigma:.3g} m): the mesh, not the parameters, limits this fit; "
                        f"{advice}")
    for w in warnings:
        say(f"warning: {w}")
    say(f"check-mesh: rms position error {result.rms_after:.4g} m on your mesh, "
        f"{again.rms_after:.4g} m {what}")
    return {"done": True, "how": how,
            "values": dict(zip(result.names, map(float, again.values), strict=True)),
            "std": dict(zip(result.names, map(float, again.std), strict=True)),
            "shift_sigmas": dict(zip(result.names, map(float, shift), strict=True)),
            "rms": [float(result.rms_after), float(again.rms_after)], "warnings": warnings}
