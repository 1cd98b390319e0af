"""Parameter scaling: the map between physical parameters p and the optimizer's variables z.

Material parameters differ by orders of magnitude (a Young's modulus of 1e5 Pa beside a damping
ratio of 0.02), so gradients with respect to p are badly balanced and a steepest-descent step, a
finite-difference step or a simplex size cannot suit all of them. Optimizers here therefore work
in scaled variables z of order one:

- a positive parameter (lower bound > 0, or a name declared positive) is scaled logarithmically,
  ``z = log(p / p_ref)`` with ``p_ref`` its start value: a unit step in z is a factor e in p,
  whatever the magnitude, and z is unbounded even though p stays positive;
- any other parameter is scaled affinely, ``z = (p - p0) / width``, with ``p0`` its start value and
  ``width`` half the bound interval when both bounds are finite (else ``|p0|``, else 1).

This module owns only the map (values, bounds, derivative dp/dz); it knows nothing of PETSc.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from petsoft.errors import PetsoftError


class ScalingError(PetsoftError):
    """Parameter names, start values or bounds that cannot be scaled (the message says which)."""


class ParameterScaling:
    """Scaled variables z for physical parameters p (log for positive ones, affine otherwise).

    Parameters
    ----------
    names : sequence of str
        Parameter names (used in messages and reports).
    start : array_like, shape (n,)
        Start values p0 in physical units; the reference point z = 0.
    lower, upper : array_like, shape (n,), optional
        Physical bounds (``-inf``/``inf`` or None for none). ``lower > 0`` makes a parameter
        log-scaled.
    positive : iterable of str, optional
        Names of parameters known to be positive (log-scaled even without a positive bound).
    widths : array_like, shape (n,), optional
        Affine widths (physical units) overriding the default for the affine parameters.

    Raises
    ------
    ScalingError
        Mismatched lengths, a start value outside its bounds, ``lower >= upper``, a non-positive
        start or bound of a log-scaled parameter, or a non-positive width.
    """

    def __init__(
        self,
        names: Sequence[str],
        start,
        lower=None,
        upper=None,
        positive: Iterable[str] = (),
        widths=None,
    ):
        self.names = [str(s) for s in names]
        n = len(self.names)
        self.n = n
        p0 = np.asarray(start, dtype=float).reshape(-1)
        lo = np.full(n, -np.inf) if lower is None else np.asarray(lower, dtype=float).reshape(-1)
        hi = np.full(n, np.inf) if upper is None else np.asarray(upper, dtype=float).reshape(-1)
        for label, arr in (("start", p0), ("lower", lo), ("upper", hi)):
            if arr.shape != (n,):
                raise ScalingError(
                    f"parameter scaling: {label} has {arr.size} values for {n} parameters "
                    f"{self.names}; give one value per parameter")
        lo = np.where(np.isnan(lo), -np.inf, lo)
        hi = np.where(np.isnan(hi), np.inf, hi)
        positive = set(positive)
        unknown = positive.difference(self.names)
        if unknown:
            raise ScalingError(
                f"parameter scaling: positive names {sorted(unknown)} are not parameters; valid: "
                f"{self.names}")
        for i, name in enumerate(self.names):
            if not np.isfinite(p0[i]):
                raise ScalingError(f"parameter '{name}': start value {p0[i]} is not finite")
            if not lo[i] < hi[i]:
                raise ScalingError(
                    f"parameter '{name}': lower bound {lo[i]} must be below upper bound {hi[i]}")
            if not lo[i] <= p0[i] <= hi[i]:
                raise ScalingError(
                    f"parameter '{name}': start value {p0[i]} is outside its bounds "
                    f"[{lo[i]}, {hi[i]}]")
        self.is_log = (lo > 0) | np.array([s in positive for s in self.names], dtype=bool)
        bad = self.is_log & ((p0 <= 0) | (hi <= 0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ScalingError(
                f"parameter '{self.names[i]}' is declared positive (log-scaled) but its start "
                f"value {p0[i]} or upper bound {hi[i]} is not > 0")
        self.start = p0.copy()
        self.lower = lo
        self.upper = hi
        both = np.isfinite(lo) & np.isfinite(hi)
        default_width = np.where(both, 0.5 * (hi - lo), np.where(p0 != 0, np.abs(p0), 1.0))
        if widths is not None:
            w = np.asarray(widths, dtype=float).reshape(-1)
            if w.shape != (n,):
                raise ScalingError(
                    f"parameter scaling: widths has {w.size} values for {n} parameters")
            default_width = np.where(np.isnan(w), default_width, w)
        if (default_width <= 0).any():
            i = int(np.flatnonzero(default_width <= 0)[0])
            raise ScalingError(
                f"parameter '{self.names[i]}': affine width {default_width[i]} must be > 0")
        # For log parameters the "width" is unused; keep 1 so the arrays stay finite.
        self.width = np.where(self.is_log, 1.0, default_width)
        self.reference = p0.copy()

    # --- the map -------------------------------------------------------------------------------
    def to_scaled(self, p) -> np.ndarray:
        """Scaled variables z of physical parameters p (shape (n,) or (k, n))."""
        p = np.asarray(p, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            zl = np.log(p / self.reference)
        za = (p - self.reference) / self.width
        return np.where(self.is_log, zl, za)

    def to_physical(self, z) -> np.ndarray:
        """Physical parameters p of scaled variables z (shape (n,) or (k, n))."""
        z = np.asarray(z, dtype=float)
        with np.errstate(over="ignore"):
            pl = self.reference * np.exp(np.where(self.is_log, z, 0.0))
        pa = self.reference + self.width * z
        # z at its bound maps back to the physical bound, not to a rounding of it one ulp
        # outside (exp(log(lo / ref)) * ref): the calibrated value must pass the bounds check
        # of the experiment it is written into
        return np.clip(np.where(self.is_log, pl, pa), self.lower, self.upper)

    def dp_dz(self, z) -> np.ndarray:
        """The diagonal of the Jacobian dp/dz at z, shape (n,) (the map is componentwise)."""
        return np.where(self.is_log, self.to_physical(z), self.width)

    def gradient_to_scaled(self, z, grad_p) -> np.ndarray:
        """Chain rule: df/dz = df/dp * dp/dz (grad_p shape (n,))."""
        return np.asarray(grad_p, dtype=float) * self.dp_dz(z)

    def jacobian_to_scaled(self, z, jac_p) -> np.ndarray:
        """Chain rule for a residual Jacobian: dr/dz = dr/dp diag(dp/dz) (jac_p shape (m, n))."""
        return np.asarray(jac_p, dtype=float) * self.dp_dz(z)[None, :]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds in z (``-inf``/``inf`` where the physical bound is absent or zero for logs)."""
        # A positive-by-name parameter without a positive lower bound has z unbounded below.
        zl = self.to_scaled(np.where(self.is_log & (self.lower <= 0), 0.0, self.lower))
        zu = self.to_scaled(self.upper)
        return zl, zu

    def describe(self, i: int) -> str:
        """How parameter i enters z, e.g. ``log(E/1e+05)`` or ``(nu - 0.3)/0.2``."""
        name = self.names[i]
        if self.is_log[i]:
            return f"log({name}/{self.reference[i]:.4g})"
        return f"({name} - {self.reference[i]:.4g})/{self.width[i]:.4g}"

    def __repr__(self) -> str:
        return "ParameterScaling(" + ", ".join(self.describe(i) for i in range(self.n)) + ")"
