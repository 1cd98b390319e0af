"""The score (Lagrange-multiplier) test of a candidate physics term, without fitting it.

At the calibrated base fit, with r the noise-scaled residual (r_i = (s_i - d_i) / sigma) and
J = [J_b, J_c] its Jacobian with respect to the base parameters b (already fitted) and the
candidate's parameters c (at their zero value), the misfit's gradient in c is g_c = J_c^T r and
the Gauss-Newton Fisher information is I = J^T J. Projecting the nuisance parameters b out,

    S = g_c^T (I_cc - I_cb I_bb^-1 I_bc)^-1 g_c,

is asymptotically chi-square with k = dim(c) degrees of freedom when the term is absent (and the
residual is Gaussian noise of std sigma). A large S (small p-value) means the data pull on the
new term in a direction the base parameters cannot absorb. The statistic is invariant to a
rescaling of the parameters; columns are normalised before the solve for conditioning.

The sign of the score is not used: a one-sided parameter bounded at its zero value (a damping
coefficient >= 0) can show a large score that points outside its bounds; the re-calibration
then finds no improvement and the likelihood-ratio test rejects it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from petsoft.errors import PetsoftError


class ScoreError(PetsoftError):
    """The score test cannot be evaluated (shapes, or a candidate the base parameters fully
    explain)."""


@dataclass
class ScoreResult:
    """``statistic`` S, degrees of freedom ``dof``, ``p_value`` = P(chi2(dof) > S), and the raw
    gradient ``gradient`` g_c = J_c^T r (per candidate parameter)."""

    statistic: float
    dof: int
    p_value: float
    gradient: np.ndarray
    #: log10 of the p-value (finite where the p-value underflows to 0: ranks strong candidates)
    log10_p: float = 0.0
    #: a one-parameter candidate's column with the base columns projected out, of unit norm
    #: (float32): what it would change that the fitted parameters cannot; two candidates whose
    #: directions are nearly parallel explain the same misfit (None for several parameters)
    direction: np.ndarray | None = None


def score_test(r: np.ndarray, J_base: np.ndarray, J_cand: np.ndarray,
               rcond: float = 1e-10) -> ScoreResult:
    """Efficient score statistic of candidate columns ``J_cand`` given fitted ``J_base``.

    Parameters
    ----------
    r : ndarray (m,)
        Noise-scaled residual at the base fit.
    J_base : ndarray (m, nb)
        d r / d (base parameters); nb may be 0.
    J_cand : ndarray (m, k)
        d r / d (candidate parameters) at their zero value.
    rcond : float
        Relative eigenvalue threshold of the projected information below which a direction is
        treated as not identifiable (dropped, reducing the degrees of freedom).

    Returns
    -------
    ScoreResult

    Raises
    ------
    ScoreError
        Mismatched shapes, non-finite input, or a candidate with no direction left after the
        base parameters are projected out.
    """
    r = np.asarray(r, dtype=float).reshape(-1)
    Jb = np.asarray(J_base, dtype=float).reshape(len(r), -1)
    Jc = np.asarray(J_cand, dtype=float).reshape(len(r), -1)
    if not (np.isfinite(r).all() and np.isfinite(Jb).all() and np.isfinite(Jc).all()):
        raise ScoreError("score test: the residual or the Jacobian has non-finite entries")
    if Jc.shape[1] == 0:
        raise ScoreError("score test: the candidate has no parameters")
    # Projecting out the base columns by least squares equals the Schur complement
    # I_cc - I_cb I_bb^-1 I_bc = Jc^T (1 - P_b) Jc, and is better conditioned.
    if Jb.shape[1]:
        Q, _ = np.linalg.qr(Jb / np.maximum(np.linalg.norm(Jb, axis=0), 1e-300))
        Jc_perp = Jc - Q @ (Q.T @ Jc)
    else:
        Jc_perp = Jc
    g = Jc.T @ r
    # g_c = Jc^T r equals Jc_perp^T r at a base optimum (Jb^T r = 0); using the projected form
    # is exact also when the base fit stopped slightly short of the optimum.
    g_perp = Jc_perp.T @ r
    scale = np.linalg.norm(Jc, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    A = Jc_perp / scale
    info = A.T @ A
    w, V = np.linalg.eigh(info)
    keep = w > rcond * max(w.max(initial=0.0), 1e-300)
    if not keep.any() or w.max(initial=0.0) <= 1e-14:
        raise ScoreError("score test: the candidate's parameters change the simulation only in "
                         "ways the base parameters already produce (no independent direction)")
    gs = V[:, keep].T @ (g_perp / scale)
    S = float(np.sum(gs * gs / w[keep]))
    dof = int(keep.sum())
    direction = None
    if Jc_perp.shape[1] == 1:
        norm = float(np.linalg.norm(Jc_perp))
        direction = (Jc_perp[:, 0] / norm).astype(np.float32) if norm > 0 else None
    return ScoreResult(statistic=S, dof=dof, p_value=float(stats.chi2.sf(S, dof)), gradient=g,
                       log10_p=float(stats.chi2.logsf(S, dof) / np.log(10.0)),
                       direction=direction)
