"""``petsoft calibrate --check-mesh``: does refining the mesh move the calibrated parameters?

A coarse P1 mesh is too stiff in bending, and a calibration absorbs that into the parameters (a
648-tet cantilever calibrated E 26 % low, issue 14) while the fit still looks fine. After the
fit, :func:`check_mesh` calibrates again on the mesh refined once (a box's cells doubled, a mesh
file split 1 -> 8: :data:`~petsoft.calibration.refinement.MESH_HALVED`), starting from the
calibrated values, and warns for every parameter the refinement moves by more than its standard
deviation, saying by how many.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from petsoft.calibration.refinement import MESH_HALVED
from petsoft.experiment import with_parameters


def check_mesh(experiment, result, refit: Callable, say: Callable[[str], None]) -> dict:
    """Re-calibrate ``experiment`` on its refined mesh and compare with ``result``.

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
    reason = MESH_HALVED.applies(experiment)
    if reason is not None:
        say(f"check-mesh: not done: {reason}")
        return {"done": False, "reason": reason}
    how = MESH_HALVED.describe(experiment)
    say(f"check-mesh: calibrating again on the refined mesh ({how}), from the calibrated values")
    start = dict(zip(result.names, map(float, result.values), strict=True))
    fine = with_parameters(MESH_HALVED.make(experiment), start)
    again = refit(fine)
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = (np.asarray(again.values) - np.asarray(result.values)) / np.asarray(result.std)
    finer = ("twice the box cells per axis" if experiment.mesh.box is not None else
             f"[mesh] refine = {experiment.mesh.refine + 1}, or a mesh file with half the "
             "element size")
    warnings = []
    for name, a, b, s, k in zip(result.names, result.values, again.values, result.std, shift,
                                strict=True):
        known = bool(np.isfinite(s) and s > 0.0)
        if known and abs(k) > 1.0:
            warnings.append(
                f"refining the mesh ({how}) moves {name} by {abs(k):.3g} standard deviations "
                f"({a:.6g} -> {b:.6g}, std {s:.3g}): the calibrated value carries the mesh's "
                f"discretisation error; calibrate on a finer mesh ({finer})")
        elif known:
            say(f"check-mesh: {name}: {a:.6g} -> {b:.6g} ({k:+.2g} std): within its standard "
                "deviation")
        else:
            say(f"check-mesh: {name}: {a:.6g} -> {b:.6g} (its standard deviation is unknown: "
                "not compared)")
    if again.rms_after < 0.8 * result.rms_after and result.rms_after > 1.2 * result.sigma:
        # the parameters may not move (a fit on the coarse mesh can settle near the right
        # values with a wrong shape) while the refined mesh fits far better: say that too
        warnings.append(f"on the refined mesh the fit is much closer to the data (rms "
                        f"{result.rms_after:.3g} m -> {again.rms_after:.3g} m; noise "
                        f"{result.sigma:.3g} m): the mesh, not the parameters, limits this fit; "
                        f"calibrate on a finer mesh ({finer})")
    for w in warnings:
        say(f"warning: {w}")
    say(f"check-mesh: rms position error {result.rms_after:.4g} m on your mesh, "
        f"{again.rms_after:.4g} m on the refined mesh")
    return {"done": True, "how": how,
            "values": dict(zip(result.names, map(float, again.values), strict=True)),
            "std": dict(zip(result.names, map(float, again.std), strict=True)),
            "shift_sigmas": dict(zip(result.names, map(float, shift), strict=True)),
            "rms": [float(result.rms_after), float(again.rms_after)], "warnings": warnings}
