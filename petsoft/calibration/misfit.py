"""A phase-robust, basin-widening misfit: the Cramér (CDF-l2) distance of power spectra.

The l2 misfit of oscillating trajectories is non-convex in their phase: a Young's modulus off by
2x puts the simulated oscillation half a period out of step after a few periods, and a gradient
method stops in one of the ripples (lecture 000, "What if the problem is non-convex?"). The
notes' remedy is an optimal-transport distance, which grows with a *shift* instead of
oscillating with it. Applied to the time signals themselves it still sees the phase; applied to
their power spectra, treated as probability densities over frequency, it sees where the energy
sits, and a change of stiffness moves it: for 1D densities the optimal-transport family has
closed forms through the cumulative distributions F, and this module uses the Cramér distance

    d(sim, data)^2 = sum_k (F_sim(f_k) - F_data(f_k))^2,     F = cumsum(P) / sum(P),
    P(f_k) = sum_channels |DFT(hann * (x_c - mean x_c))|^2(f_k)       (zero-padded 2x),

which for a narrow spectral line moved by df grows monotonically with |df| (no ripple) and
ignores phase. It is a least-squares residual r = F_sim - F_data, so Gauss-Newton, L-BFGS and
the adjoint all use it unchanged: :meth:`SpectralMisfit.vjp` is the exact transpose of the
linearisation :meth:`SpectralMisfit.jvp` (Taylor-tested in tests/test_misfit.py). It
identifies frequencies, not phases or static offsets, so a calibration with it is polished by
the l2 misfit from its minimiser (``run_calibration(misfit="spectral")`` does that).
"""

from __future__ import annotations

import numpy as np

from petsoft.errors import ExperimentError

MISFITS = ("l2", "spectral")


class SpectralMisfit:
    """Residual r(sim) = w (F_sim - F_data) of the normalised cumulative power spectrum.

    Parameters
    ----------
    data : ndarray (K, ...)
        Recorded signals, time first (e.g. marker positions (K, M, 3)); every entry seen.
    weight : float
        Scale of the residual (the optimizers are invariant to it; it sets the printed value).
    pad : int
        Zero-padding factor of the DFT (finer frequency grid).
    """

    def __init__(self, data: np.ndarray, weight: float = 1.0, pad: int = 2):
        data = np.asarray(data, float)
        if not np.isfinite(data).all():
            raise ExperimentError(
                "misfit = \"spectral\" needs every marker seen in every frame of the window "
                f"({int((~np.isfinite(data)).sum())} missing samples); use misfit = \"l2\"")
        if len(data) < 4:
            raise ExperimentError("misfit = \"spectral\" needs at least 4 frames")
        self.shape = data.shape
        self.K = data.shape[0]
        self.N = pad * self.K
        self.window = np.hanning(self.K + 2)[1:-1]     # no zero end-points
        self.weight = float(weight)
        self.F_data = self.cdf(data)[0]

    # -- the transform ------------------------------------------------------------------------
    def _spectrum(self, x: np.ndarray):
        x = x.reshape(self.K, -1)
        X = np.fft.rfft(self.window[:, None] * (x - x.mean(axis=0)), n=self.N, axis=0)
        return X, np.sum(np.abs(X) ** 2, axis=1)

    def cdf(self, x: np.ndarray):
        """(F, X, P, S): the normalised cumulative spectrum and its intermediates."""
        X, P = self._spectrum(x)
        S = float(P.sum())
        if not S > 0.0:
            raise ExperimentError("misfit = \"spectral\": the signals do not move (zero power)")
        return np.cumsum(P) / S, X, P, S

    def residual(self, sim: np.ndarray) -> np.ndarray:
        return self.weight * (self.cdf(sim)[0] - self.F_data)

    def jvp(self, sim: np.ndarray, dsim: np.ndarray) -> np.ndarray:
        """dr/dsim . dsim; ``dsim`` (K, ..., P) holds one direction per trailing column."""
        _, X, P, S = self.cdf(sim)
        dsim = np.asarray(dsim, float).reshape(self.K, -1, dsim.shape[-1])
        dx = dsim - dsim.mean(axis=0)
        dX = np.fft.rfft(self.window[:, None, None] * dx, n=self.N, axis=0)
        dP = 2.0 * np.real(np.einsum("kc,kcp->kp", np.conj(X), dX))
        dp = (dP - (P / S)[:, None] * dP.sum(axis=0)[None, :]) / S
        return self.weight * np.cumsum(dp, axis=0)

    def vjp(self, sim: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(dr/dsim)^T v, shaped like ``sim``: the adjoint's input for a residual weight v."""
        _, X, P, S = self.cdf(sim)
        gF = self.weight * np.asarray(v, float)
        gp = np.cumsum(gF[::-1])[::-1]                  # transpose of cumsum
        gP = (gp - float(gp @ P) / S) / S               # transpose of the normalisation
        # d(sum_k gP_k |X_kc|^2)/dx_n = 2 w_n Re(sum_k gP_k X_kc e^{2 pi i k n / N}) over the
        # rfft bins k (each stands once in P, so no Hermitian doubling)
        full = np.zeros((self.N, X.shape[1]), complex)
        full[:X.shape[0]] = gP[:, None] * X
        g = 2.0 * self.window[:, None] * np.real(self.N * np.fft.ifft(full, axis=0)[:self.K])
        g -= g.mean(axis=0)                             # transpose of the mean removal
        return g.reshape(self.shape)

    def value_gradient(self, sim: np.ndarray):
        """(1/2 |r|^2, d/dsim) for an adjoint's ``dphi``."""
        r = self.residual(sim)
        return 0.5 * float(r @ r), self.vjp(sim, r)


def make_misfit(name: str, data: np.ndarray, source: str = "misfit"):
    """The misfit object for ``name`` (None for the plain l2 misfit)."""
    if name == "l2":
        return None
    if name == "spectral":
        return SpectralMisfit(data)
    raise ExperimentError(f"{source}: misfit = {name!r}: valid are {', '.join(MISFITS)}")
