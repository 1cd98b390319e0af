"""Gravity's direction tilted at a fixed magnitude: ``[gravity] tilt_a``, ``tilt_b``.

A model that states gravity may still have it in the wrong direction (a tilted mount, a camera
frame that is not level), never of the wrong size: on the Earth's surface |g| is 9.78-9.83 m/s^2.
A fit of gravity's three components lets the size stand in for other physics (seen: the
realistic payload taper fitted |g| = 15.5 m/s^2, 12.9 of it along the bar's axis, in place of
the added mass that was there). The tilt keeps the stated size and turns the direction (a
model that states no gravity has no size to keep: diagnose still fits its three components, and
the independent plate's missing gravity came back with 10.9 m/s^2 along the bar's axis):

    g(a, b) = |g0| (n + a e1 + b e2) / sqrt(1 + a^2 + b^2),

with n = g0 / |g0| the stated direction and (e1, e2) the orthonormal pair across it of
:func:`tilt_basis` (e1 along the coordinate axis least aligned with n, made orthogonal to n;
e2 = n x e1). ``a`` and ``b`` are the tangents of the tilt towards e1 and e2 (gnomonic
coordinates: every direction of the half-space around n, smooth at a = b = 0).
"""

from __future__ import annotations

import numpy as np


def tilt_basis(stated) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """(|g0|, n, e1, e2) of the stated acceleration ``g0`` (module docstring).

    Raises
    ------
    ValueError
        When ``g0`` is zero (no direction to tilt).
    """
    g0 = np.asarray(stated, dtype=float)
    size = float(np.linalg.norm(g0))
    if size == 0.0:
        raise ValueError("a zero acceleration has no direction to tilt")
    n = g0 / size
    axis = np.zeros(3)
    axis[int(np.argmin(np.abs(n)))] = 1.0
    e1 = axis - n * float(n @ axis)
    e1 /= np.linalg.norm(e1)
    return size, n, e1, np.cross(n, e1)


def _turned(stated, a: float, b: float):
    """(|g0|, e1, e2, u = n + a e1 + b e2, s = |u|) of the stated acceleration and the tilt."""
    size, n, e1, e2 = tilt_basis(stated)
    return size, e1, e2, n + a * e1 + b * e2, np.sqrt(1.0 + a * a + b * b)


def tilted(stated, a: float, b: float) -> np.ndarray:
    """The acceleration ``stated`` tilted by (``a``, ``b``) at its own size (m/s^2)."""
    if a == 0.0 and b == 0.0:
        return np.asarray(stated, dtype=float).copy()
    size, _, _, u, s = _turned(stated, a, b)
    return size * u / s


def tilt_derivatives(stated, a: float, b: float) -> tuple[np.ndarray, np.ndarray]:
    """(d g / d a, d g / d b) of :func:`tilted` at (``a``, ``b``) (m/s^2 per unit tangent)."""
    size, e1, e2, u, s = _turned(stated, a, b)
    return (size * (e1 / s - u * a / s ** 3), size * (e2 / s - u * b / s ** 3))
