"""Parameter uncertainty of a least-squares fit from the Gauss-Newton approximation.

Near the minimum of ``1/2 |r(z)|^2`` with residual noise of standard deviation sigma, the
estimate's covariance is ``sigma^2 (J^T J)^-1`` (J = dr/dz at the fit). sigma is either given or
estimated from the fit itself, ``|r|^2 / (m - n)``. The covariance is computed in the scaled
variables z (where J^T J is well balanced) and carried to physical parameters p by the
linearized map ``C_p = D C_z D`` with ``D = diag(dp/dz)``. This module owns that computation and
its failure mode: a singular J^T J means the data cannot determine some combination of
parameters, and the error names it from the null singular vector.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from petsoft.errors import PetsoftError


class UnidentifiableError(PetsoftError):
    """The data do not determine some combination of parameters (J^T J is singular)."""


@dataclass
class Uncertainty:
    """Gauss-Newton uncertainty of a fit (physical parameters unless the name says z)."""

    names: list[str]
    p: np.ndarray
    sigma: float
    dof: int
    covariance_z: np.ndarray
    covariance: np.ndarray
    std: np.ndarray
    std_z: np.ndarray
    correlation: np.ndarray
    condition: float

    def table(self) -> str:
        """A small text table: name, value, standard deviation, relative standard deviation."""
        lines = [f"{'parameter':>12} {'value':>13} {'std':>11} {'rel':>8}"]
        for i, name in enumerate(self.names):
            rel = self.std[i] / abs(self.p[i]) if self.p[i] != 0 else np.inf
            lines.append(f"{name:>12} {self.p[i]:13.6g} {self.std[i]:11.3g} {rel:8.2%}")
        return "\n".join(lines)


def uncertainty(J, r, scaling=None, z=None, noise_std: float | None = None,
                rcond: float = 1e-8) -> Uncertainty:
    """Covariance, standard deviations and correlations of fitted parameters.

    Parameters
    ----------
    J : array_like, shape (m, n)
        Residual Jacobian dr/dz at the fit.
    r : array_like, shape (m,)
        Residuals at the fit, in the units in which ``noise_std`` is given.
    scaling : ParameterScaling, optional
        Map z -> p (without it, p = z and the names are ``z0, z1, ...``).
    z : array_like, shape (n,), optional
        The fitted scaled parameters (required with ``scaling``).
    noise_std : float, optional
        Standard deviation of one residual entry (1.0 when the residuals are already divided
        by the noise). Default: estimated as ``sqrt(|r|^2 / (m - n))``.
    rcond : float
        J is treated as rank-deficient when its smallest singular value is below ``rcond``
        times its largest (J^T J then has a condition number above ``rcond**-2``).

    Raises
    ------
    UnidentifiableError
        When J^T J is singular; the message names the undetermined parameter combination.
    PetsoftError
        When sigma must be estimated but there are no more residuals than parameters.
    """
    J = np.atleast_2d(np.asarray(J, dtype=float))
    r = np.asarray(r, dtype=float).reshape(-1)
    m, n = J.shape
    if r.size != m:
        raise PetsoftError(f"uncertainty: {r.size} residuals but the Jacobian has {m} rows")
    if scaling is not None and z is None:
        raise PetsoftError("uncertainty: give the fitted z together with the scaling")
    names = list(scaling.names) if scaling is not None else [f"z{i}" for i in range(n)]
    zz = np.zeros(n) if z is None else np.asarray(z, dtype=float).reshape(-1)
    p = scaling.to_physical(zz) if scaling is not None else zz.copy()
    if noise_std is None:
        if m <= n:
            raise PetsoftError(
                f"uncertainty: {m} residuals for {n} parameters leave no degrees of freedom to "
                "estimate the noise; give noise_std (the measurement noise)")
        sigma = float(np.sqrt(r @ r / (m - n)))
    else:
        sigma = float(noise_std)
    _, s, vt = np.linalg.svd(J, full_matrices=False)
    cond = float(s[0] / s[-1]) if s[-1] > 0 else np.inf
    if s.size < n or s[-1] <= rcond * s[0]:
        v = vt[-1]
        v = v / v[np.argmax(np.abs(v))]
        terms = [
            f"{v[i]:+.3g}*{scaling.describe(i) if scaling is not None else names[i]}"
            for i in np.flatnonzero(np.abs(v) > 1e-3)
        ]
        involved = [names[i] for i in np.flatnonzero(np.abs(v) > 1e-3)]
        raise UnidentifiableError(
            f"the data do not determine the parameter combination {' '.join(terms)} (J^T J is "
            f"singular: singular values of J from {s[0]:.3g} down to {s[-1]:.3g}); fix one of "
            f"{involved} or add data that separate them")
    # (J^T J)^-1 = V S^-2 V^T, computed from the SVD to avoid squaring the condition number.
    cov_z = sigma**2 * (vt.T / s**2) @ vt
    d = scaling.dp_dz(zz) if scaling is not None else np.ones(n)
    cov = cov_z * np.outer(d, d)
    std = np.sqrt(np.diag(cov))
    std_z = np.sqrt(np.diag(cov_z))
    corr = cov_z / np.outer(std_z, std_z)
    return Uncertainty(names, p, sigma, m - n, cov_z, cov, std, std_z, corr, cond)
