"""The reduced model's error on the markers, in units of the recording's noise.

The measure is the one the diagnosis judges fits by: the root mean square over frames, markers
and coordinates of the difference between the reduced and the full model's marker positions,
divided by the noise's standard deviation (per coordinate), and the largest single difference
likewise. Markers the recording did not see (``seen`` False) are left out.

:func:`reduced_error` takes several checks (e.g. the training parameters and parameters moved:
E +-10 %, damping.mass from 0 to 2) and reports each and the worst; :func:`enrich_until` builds
richer reduced models until the worst is below a target fraction of the noise (0.2 by default).
The full runs are the caller's (this package does not run the full model's calibration path).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

#: The reduced model's marker error a screening may accept, as a fraction of the noise.
TARGET = 0.2


@dataclass
class ReducedError:
    """The reduced model's marker error in noise units.

    Attributes
    ----------
    rms, max : float
        The worst over the checks of the rms and of the largest difference, over the noise.
    checks : dict
        Per check label: {"rms": ..., "max": ...} (noise units).
    """

    rms: float
    max: float
    checks: dict = field(default_factory=dict)

    def below(self, target: float = TARGET) -> bool:
        return self.rms <= target

    def summary(self) -> str:
        worst = max(self.checks, key=lambda k: self.checks[k]["rms"]) if self.checks else "-"
        return (f"reduced-model error {self.rms:.3g}x the noise rms (max {self.max:.3g}x), "
                f"worst at {worst}")


def marker_error(full: np.ndarray, reduced: np.ndarray, noise: float,
                 seen: np.ndarray | None = None) -> tuple[float, float]:
    """(rms, max) of reduced - full over the noise.

    Parameters
    ----------
    full, reduced : ndarray (K, M, 3)
        Marker positions at the frames.
    noise : float
        The noise's standard deviation per coordinate (> 0).
    seen : ndarray (K, M) of bool, optional
        The markers the recording saw (default: all).
    """
    full, reduced = np.asarray(full, dtype=float), np.asarray(reduced, dtype=float)
    if full.shape != reduced.shape or full.ndim != 3 or full.shape[2] != 3:
        raise ValueError(f"marker arrays of shapes {full.shape} and {reduced.shape}: both must "
                         "be (frames, markers, 3)")
    if not noise > 0.0:
        raise ValueError(f"noise = {noise!r}: the error is measured in units of a positive noise")
    d = reduced - full
    if seen is not None:
        d = d[np.asarray(seen, dtype=bool)]
    d = d.reshape(-1)
    if d.size == 0:
        raise ValueError("no marker seen: nothing to compare")
    if not np.isfinite(d).all():
        raise ValueError("non-finite marker positions in the comparison")
    return float(np.sqrt(np.mean(d * d))) / noise, float(np.max(np.abs(d))) / noise


def reduced_error(checks: Mapping[str, tuple[np.ndarray, np.ndarray]], noise: float,
                  seen: np.ndarray | None = None) -> ReducedError:
    """The error of every check ``label -> (full, reduced)`` and the worst of them."""
    if not checks:
        raise ValueError("no checks: the reduced model's error needs at least one full run")
    out = {}
    for label, (full, reduced) in checks.items():
        rms, mx = marker_error(full, reduced, noise, seen)
        out[label] = {"rms": rms, "max": mx}
    return ReducedError(max(c["rms"] for c in out.values()),
                        max(c["max"] for c in out.values()), out)


def enrich_until(build: Callable[[int], object], check: Callable[[object], ReducedError],
                 levels: int, target: float = TARGET):
    """Build reduced models of increasing richness until one's error is below ``target``.

    ``build(level)`` for level = 0, 1, ..., levels - 1 (richer each time: more snapshots, a
    lower truncation) returns a model; ``check(model)`` its :class:`ReducedError`. Returns
    (model, error, level) of the first below the target, else of the last level (the caller
    then keeps the full model: ``error.below(target)`` is False).
    """
    if levels < 1:
        raise ValueError("enrich_until needs at least one level")
    for level in range(levels):
        model = build(level)
        err = check(model)
        if err.below(target) or level == levels - 1:
            return model, err, level
    raise AssertionError("unreachable")
