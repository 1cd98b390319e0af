"""Modal identification from marker trajectories: natural frequencies, their standard
deviations, damping and operational mode shapes of multichannel free vibration.

Pure signal processing (numpy/scipy on arrays, no model): used by ``petsoft calibrate --modes
RECORDING.h5`` (:func:`frequencies_from_recording`) and by the diagnosis
(:mod:`petsoft.diagnosis.spectral`, which re-exports :func:`dominant_modes` and
:func:`fill_gaps`).

* :func:`dominant_modes` -- ESPRIT / matrix pencil on the stacked channels (below);
* :func:`identify_modes` -- ESPRIT for the starting poles, then the maximum-likelihood fit of
  damped sinusoids shared by all channels (variable projection), with standard deviations;
* :func:`frequencies_from_recording` -- a recording's seen modes as
  :class:`~petsoft.io.frequencies.MeasuredFrequencies` with their shapes at the markers.

Method (dominant_modes)
-----------------------
Each channel (marker, axis) minus its mean is ``x_c(k) = sum_i a_ci z_i^k + noise`` with the same
poles ``z_i = exp((-d_i + 2 pi i f_i) dt)`` in all channels. The Hankel matrices
``H_c[i, j] = x_c(i + j)`` (``L + 1`` rows) are put side by side; the leading ``r`` left
singular vectors ``U`` span the signal's column space, which is shift invariant:
``U[1:] = U[:-1] Phi`` with the eigenvalues of ``Phi`` the poles (ESPRIT). ``r`` is the number
of singular values above ``rank_factor`` times the white-noise edge ``median (1 + sqrt(gamma))``
(``gamma`` = rows / columns of the stacked Hankel matrix, Marchenko-Pastur), capped at
``2 * max_modes``: with many channels a mode present in a few of them still clears it (a
factor on the median alone would not: the noise edge is close to the median when there are
many columns). With more than ``4 * max_modes`` channels the Hankel step uses their leading
principal components only (cost), the amplitude fit all channels. Amplitudes are then the
least-squares fit of ``z_i^k`` to every channel; a conjugate pair is reported once (positive
frequency) with amplitude the norm over channels of the per-channel cosine amplitudes
``2 |a_ci|``.

The method needs uniform sampling: the times must be uniform to 1e-6 relative (else
:class:`SpectralError`). Unseen samples (NaN): channels seen in fewer than half the frames are
dropped; the others are linearly interpolated in time across their gaps (leading/trailing gaps
take the nearest seen value). Interpolation is a low-pass filter over a gap, so short dropouts
(a few frames per period) barely move the poles; long ones should be cut out by the caller.

Method (identify_modes)
-----------------------
Why not FFT peak picking: a recording of a few periods of the lowest mode resolves only modes
more than ~2/T apart with a Hann window (T the record length), and the leakage of a strong peak
biases its neighbours; the damped-sinusoid model separates close modes and has no leakage, and
its least-squares fit gives the frequencies' standard deviations directly.

1. Band and decimation, for ESPRIT only: a recording sampled far above its highest mode makes
   the pencil (at most 400 samples) span a fraction of the lowest mode's period, and its poles
   crowd near z = 1. The summed Hann periodogram of the (gap-filled, detrended) channels gives
   the highest frequency ``f_hi`` with power above both 100 x the median (noise floor) and 1e-8
   of the largest peak; the channels are subsampled to ~5 ``f_hi`` (and at most ~1200 frames).
2. ESPRIT (:func:`dominant_modes`) on the subsampled channels: the starting poles.
3. Variable projection (Golub-Pereyra) on all frames, seen samples only (no interpolation):
   every channel is ``b0 + b1 t + sum_j exp(-d_j t) (a_j cos w_j t + b_j sin w_j t)``; the
   amplitudes are solved channel by channel (linear least squares on its seen frames), and
   Levenberg-Marquardt moves the shared (d_j, w_j) with Kaufman's Jacobian ``-P_perp dB/dtheta
   A``. For white noise this is the maximum-likelihood estimate, and ``sigma^2 (J^T J)^-1``
   (``sigma^2`` = residual sum of squares / degrees of freedom) its asymptotic covariance
   (the Cramer-Rao bound; amplitudes and offsets are eliminated, so their uncertainty is
   included). Coloured noise, nonlinearity or drift the model does not have make it optimistic.
4. Seen modes: oscillating (more than one cycle in the record, below 0.45 x the sampling
   rate), damping ratio below ``max_damping_ratio`` (noise-fitting poles are strongly damped)
   and relative frequency std below ``max_relative_std``. The complex amplitude
   ``a_j - i b_j`` of each channel is the mode's operational shape at the markers (NaN for
   dropped channels); it pairs the mode with a model mode by MAC.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import detrend

from petsoft.errors import PetsoftError
from petsoft.io.frequencies import MeasuredFrequencies

__all__ = ["IdentifiedMode", "SpectralError", "dominant_modes", "fill_gaps",
           "frequencies_from_recording", "identify_modes", "uniform_step"]


class SpectralError(PetsoftError):
    """A signal cannot be analysed: non-uniform times, too short, nothing seen."""


def uniform_step(times: np.ndarray) -> float:
    """The step of uniformly sampled times (at least 8), else :class:`SpectralError`."""
    t = np.asarray(times, dtype=float)
    if t.ndim != 1 or len(t) < 8:
        raise SpectralError(f"times has shape {t.shape}; need at least 8 frames")
    dt = np.diff(t)
    h = float(np.mean(dt))
    if not (h > 0 and np.all(np.abs(dt - h) <= 1e-6 * h + 1e-12 * abs(t[-1]))):
        raise SpectralError("the spectral analysis needs uniformly sampled frames: times steps "
                            f"range from {dt.min():.6g} to {dt.max():.6g} s (resample first)")
    return h


def fill_gaps(times: np.ndarray, signals: np.ndarray, min_seen: float = 0.5) -> np.ndarray:
    """(K, C) channels with NaN gaps linearly interpolated; poorly seen channels dropped.

    Parameters
    ----------
    times : ndarray (K,)
    signals : ndarray (K, ...)
        Reshaped to (K, C).
    min_seen : float
        Channels seen in fewer than this fraction of frames are dropped.
    """
    t = np.asarray(times, dtype=float)
    x = np.asarray(signals, dtype=float).reshape(len(t), -1)
    seen = np.isfinite(x)
    keep = seen.mean(axis=0) >= min_seen
    if not keep.any():
        raise SpectralError(f"no channel is seen in at least {min_seen:.0%} of the frames")
    x, seen = x[:, keep], seen[:, keep]
    out = x.copy()
    for c in np.flatnonzero(~seen.all(axis=0)):      # loop over gappy channels only
        out[:, c] = np.interp(t, t[seen[:, c]], x[seen[:, c], c])
    return out


def dominant_modes(times: np.ndarray, signals: np.ndarray, *, max_modes: int = 6,
                   num_modes: int | None = None, pencil: int | None = None,
                   rank_factor: float = 2.0, min_seen: float = 0.5) -> list[dict]:
    """Dominant damped oscillations shared by all channels (module docstring).

    Parameters
    ----------
    times : ndarray (K,)
        Uniform frame times (s).
    signals : ndarray (K, M, 3) or (K, C)
        Positions (NaN = unseen) of all markers, or any channels.
    max_modes : int
        At most this many oscillatory modes (rank cap ``2 * max_modes``).
    num_modes : int, optional
        Force the model order to ``2 * num_modes`` (otherwise chosen from the singular values).
    pencil : int, optional
        Pencil parameter L (rows of each Hankel block); default ``min(K // 3, 400)``.
    rank_factor : float
        Singular values above ``rank_factor`` times the noise edge ``median * (1 + sqrt(gamma))``
        count as signal.
    min_seen : float
        See :func:`fill_gaps`.

    Returns
    -------
    list of dict
        ``frequency_hz``, ``decay_rate`` (1/s, > 0 decays), ``damping_ratio``, ``amplitude``
        (norm over channels) and ``shape`` (complex amplitude per kept channel), sorted by
        decreasing amplitude; empty when no singular value clears the noise edge; modes with
        frequency below half a cycle over the record are reported with ``frequency_hz`` 0
        (trend / drift).
    """
    dt = uniform_step(times)
    x = fill_gaps(times, signals, min_seen)
    x = x - x.mean(axis=0)
    k = len(x)
    L = int(pencil) if pencil else min(k // 3, 400)
    if not 2 <= L <= k - 2:
        raise SpectralError(f"pencil parameter {L} must be in [2, {k - 2}] for {k} frames")
    cols = k - L
    # Many channels: keep the leading principal components for the Hankel step (the shared
    # poles live there; cost ~ q L^2 cols instead of C L^2 cols). Amplitudes use all channels.
    q = 4 * int(max_modes if num_modes is None else max(num_modes, max_modes))
    xr = x
    if x.shape[1] > q:
        u, sv_c, _ = np.linalg.svd(x, full_matrices=False)
        xr = u[:, :q] * sv_c[:q]
    # Gram matrix of the side-by-side Hankel blocks: sum_c H_c H_c^T, (L+1) x (L+1).
    idx = np.arange(L + 1)[:, None] + np.arange(cols)[None, :]
    gram = np.zeros((L + 1, L + 1))
    for c in range(xr.shape[1]):     # <= 4 max_modes channels; one (L+1, cols) block at a time
        h = xr[idx, c]
        gram += h @ h.T
    evals, evecs = np.linalg.eigh(gram)
    evals, evecs = evals[::-1], evecs[:, ::-1]
    sv = np.sqrt(np.maximum(evals, 0.0))
    if num_modes is not None:
        r = 2 * int(num_modes)
    else:
        # White noise alone gives singular values within (1 +- sqrt(gamma)) of their median,
        # gamma = rows / columns of the stacked Hankel matrix (Marchenko-Pastur edge).
        gamma = (L + 1) / (cols * xr.shape[1])
        floor = np.median(sv) * (1.0 + np.sqrt(gamma))
        r = int(np.sum(sv > rank_factor * floor)) if floor > 0 else int(np.sum(sv > 1e-12 * sv[0]))
        r = min(r, 2 * int(max_modes))
        if r == 0:          # nothing stands above the noise: no mode to report
            return []
    r = min(r, L)
    u = evecs[:, :r]
    phi = np.linalg.lstsq(u[:-1], u[1:], rcond=None)[0]
    z = np.linalg.eigvals(phi)
    # Amplitudes: least squares of the Vandermonde basis z^k against every channel at once.
    vander = z[None, :] ** np.arange(k)[:, None]
    amps = np.linalg.lstsq(vander, x.astype(complex), rcond=None)[0]   # (r, C)
    s = np.log(z.astype(complex)) / dt       # a negative real pole is a Nyquist oscillation
    freq = s.imag / (2 * np.pi)
    duration = dt * (k - 1)
    modes = []
    used = np.zeros(len(z), dtype=bool)
    for i in np.argsort(-np.abs(freq)):            # r <= 2 max_modes poles: a short loop
        if used[i]:
            continue
        used[i] = True
        if abs(freq[i]) < 0.5 / duration:          # real pole or drift slower than half a cycle
            j, shape, f = i, amps[i].real, 0.0
        else:
            # Phi is real, so complex poles come in exact conjugate pairs: report the pair once,
            # through its positive-frequency member; 2 |a| is the cosine amplitude.
            free = np.flatnonzero(~used)
            k = free[np.argmin(np.abs(z[free] - np.conj(z[i])))] if free.size else i
            if k != i and abs(z[k] - np.conj(z[i])) <= 1e-8 * max(1.0, abs(z[i])):
                used[k] = True
            else:
                k = i
            j = i if freq[i] > 0 or k == i else k
            shape = 2 * amps[j] if freq[j] > 0 else 2 * np.conj(amps[j])
            f = abs(freq[j])
        d = float(-s[j].real)
        wn = float(abs(s[j]))
        modes.append({"frequency_hz": float(f), "decay_rate": d,
                      "damping_ratio": d / wn if wn > 0 else 0.0,
                      "amplitude": float(np.linalg.norm(shape)), "shape": shape})
    modes.sort(key=lambda m: -m["amplitude"])
    return modes


@dataclass
class IdentifiedMode:
    """One damped oscillation shared by the channels, as :func:`identify_modes` estimates it.

    Attributes
    ----------
    frequency_hz : float
        Natural (undamped) frequency |s| / (2 pi) of the pole s = -d + i omega_d: for viscous
        modal damping this is the frequency of the undamped mode a model's eigenproblem gives.
    std_hz : float
        Its standard deviation (module docstring, step 3).
    damped_frequency_hz : float
        The oscillation frequency omega_d / (2 pi).
    decay_rate : float
        d (1/s); > 0 decays.
    damping_ratio : float
        d / |s|.
    amplitude : float
        Norm over the channels of the complex amplitudes at the first frame.
    shape : ndarray (C,) complex
        Complex amplitude ``a - i b`` per channel (the operational mode shape), NaN for channels
        dropped as seen in too few frames.
    seen : bool
        Whether it passes the tests of a structural mode (module docstring, step 4).
    note : str
        Why it is not seen ("" when it is).
    """

    frequency_hz: float
    std_hz: float
    damped_frequency_hz: float
    decay_rate: float
    damping_ratio: float
    amplitude: float
    shape: np.ndarray
    seen: bool
    note: str = ""

    def summary(self) -> dict:
        """JSON-able, without the shape."""
        return {"frequency_hz": self.frequency_hz, "std_hz": self.std_hz,
                "damped_frequency_hz": self.damped_frequency_hz, "decay_rate": self.decay_rate,
                "damping_ratio": self.damping_ratio, "amplitude": self.amplitude,
                "seen": self.seen, "note": self.note}


#: Variable projection processes the channels in chunks of at most this many samples times
#: nonlinear parameters (memory of the Jacobian blocks, ~32 MB).
VARPRO_CHUNK = 4_000_000


def _band_limit(t: np.ndarray, filled: np.ndarray) -> float:
    """The highest frequency (Hz) with power above the noise floor and 1e-8 of the peak, in the
    summed Hann periodogram of the linearly detrended channels (module docstring, step 1)."""
    k = len(t)
    x = detrend(filled, axis=0) * np.hanning(k)[:, None]
    power = np.sum(np.abs(np.fft.rfft(x, axis=0)) ** 2, axis=1)
    freqs = np.fft.rfftfreq(k, t[1] - t[0])
    power[0] = 0.0
    floor = np.median(power[1:])
    strong = power > max(100.0 * floor, 1e-8 * power.max())
    return float(freqs[strong].max()) if strong.any() else float(freqs[-1])


class _DampedSinusoids:
    """Channels ``b0 + b1 tau + sum_j exp(-D_j tau) (a_j cos W_j tau + b_j sin W_j tau)`` on
    their seen samples, tau = (t - t0) / T in [0, 1], theta = (D_1, W_1, ...) = T (d, omega):
    the variable-projection residual, its Kaufman Jacobian and the amplitudes."""

    def __init__(self, tau: np.ndarray, x: np.ndarray, seen: np.ndarray):
        self.tau = tau
        self.x = np.where(seen, x, 0.0)
        self.w = seen.astype(float)
        self.all_seen = bool(seen.all())

    def _chunks(self, params: int) -> list[slice]:
        width = max(1, VARPRO_CHUNK // (len(self.tau) * max(params, 1)))
        return [slice(c, c + width) for c in range(0, self.x.shape[1], width)]

    def basis(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """B (K, 2 + 2r) and dB/dtheta per mode: (r, 2 params, K, 2 columns)."""
        tau = self.tau[:, None]
        D, W = theta[0::2][None, :], theta[1::2][None, :]
        e = np.exp(-D * tau)
        c, s = e * np.cos(W * tau), e * np.sin(W * tau)
        B = np.concatenate([np.ones_like(tau), tau, np.stack([c, s], axis=2).reshape(
            len(tau), -1)], axis=1)
        # d/dD (c, s) = -tau (c, s); d/dW (c, s) = tau (-s, c)
        dB = np.stack([np.stack([-tau * c, -tau * s], axis=2),
                       np.stack([-tau * s, tau * c], axis=2)], axis=2)   # (K, r, 2, 2)
        return B, np.transpose(dB, (1, 2, 0, 3))

    def _normal_matrices(self, B, chunk):
        """B^T diag(seen_c) B for each channel c of the chunk: (c, p, p)."""
        w = self.w[:, chunk]
        p = B.shape[1]
        if self.all_seen:
            G = np.broadcast_to(B.T @ B, (w.shape[1], p, p))
        else:
            G = (w.T @ (B[:, :, None] * B[:, None, :]).reshape(len(B), -1)).reshape(-1, p, p)
        return G

    def evaluate(self, theta: np.ndarray, jacobian: bool):
        """Residual sum of squares, amplitudes (2 + 2r, C) and, with ``jacobian``, J^T J and
        J^T r of the projected residual (Kaufman's approximation of its Jacobian)."""
        B, dB = self.basis(theta)
        n = len(theta)
        cost, A_all = 0.0, []
        JtJ, Jtr = np.zeros((n, n)), np.zeros(n)
        for chunk in self._chunks(n):      # channel blocks: bounded memory
            x, w = self.x[:, chunk], self.w[:, chunk]
            G = self._normal_matrices(B, chunk)
            A = np.linalg.solve(G, (B.T @ x).T[..., None])[..., 0].T      # (p, c)
            r = w * (x - B @ A)
            cost += float(np.sum(r * r))
            A_all.append(A)
            if not jacobian:
                continue
            J = np.empty((n, *x.shape))
            for j in range(n // 2):        # 2r <= ~30 parameters
                amps = A[2 + 2 * j:4 + 2 * j]                              # (2, c)
                for a in range(2):
                    Dk = w * (dB[j, a] @ amps)                             # (K, c)
                    proj = np.linalg.solve(G, (B.T @ Dk).T[..., None])[..., 0].T
                    J[2 * j + a] = -(Dk - w * (B @ proj))
            flat = J.reshape(n, -1)
            JtJ += flat @ flat.T
            Jtr += flat @ r.ravel()
        return cost, np.concatenate(A_all, axis=1), JtJ, Jtr


def _levenberg_marquardt(model: _DampedSinusoids, theta: np.ndarray, max_iterations: int):
    """Minimise the projected residual over theta; returns theta, cost, J^T J, amplitudes."""
    try:
        cost, A, JtJ, Jtr = model.evaluate(theta, jacobian=True)
    except np.linalg.LinAlgError:
        raise SpectralError("the damped-sinusoid fit is singular at its start (two equal "
                            "poles, or a channel with too few seen frames)") from None
    mu = 1e-3
    for _ in range(max_iterations):
        H = JtJ + mu * np.diag(np.diag(JtJ) + 1e-300)
        try:
            step = -np.linalg.solve(H, Jtr)
            trial = theta + step
            c_trial, *_ = model.evaluate(trial, jacobian=False)
        except np.linalg.LinAlgError:   # two poles merged: a singular amplitude problem
            c_trial = np.inf
        if c_trial < cost:
            # converged when the step is below round-off of theta or the cost stalls
            done = (np.max(np.abs(step) / (np.abs(theta) + 1.0)) < 1e-11
                    or c_trial > (1.0 - 1e-12) * cost)
            theta, mu = trial, mu / 3.0
            cost, A, JtJ, Jtr = model.evaluate(theta, jacobian=True)
            if done:
                break
        else:
            mu *= 4.0
            if mu > 1e12:
                break
    return theta, cost, JtJ, A


def identify_modes(times: np.ndarray, signals: np.ndarray, *, max_modes: int = 20,
                   min_seen: float = 0.5, max_damping_ratio: float = 0.25,
                   max_relative_std: float = 0.02, max_iterations: int = 50
                   ) -> list[IdentifiedMode]:
    """Natural frequencies with standard deviations, damping and operational shapes of the
    damped oscillations shared by all channels (module docstring, "Method (identify_modes)").

    Parameters
    ----------
    times : ndarray (K,)
        Uniform frame times (s).
    signals : ndarray (K, M, 3) or (K, C)
        Displacements (or positions, or accelerations: the poles are the same) of the markers;
        NaN = not seen.
    max_modes : int
        At most this many oscillations are fitted (ESPRIT's rank cap is twice this). Keep it
        above the number of modes present: a weak mode left out of the model biases a close
        one beyond its std (on a beam with 10 modes in the record, a cap of 10 merged the two
        weakest, 9.30 and 12.06 Hz, into one at 12.00 +- 0.007 Hz).
    min_seen : float
        Channels seen in fewer than this fraction of the frames are left out (shape NaN).
    max_damping_ratio, max_relative_std : float
        A fitted oscillation more damped, or with a frequency std above this fraction of its
        frequency, is reported but not ``seen``.
    max_iterations : int
        Levenberg-Marquardt iterations of the variable projection.

    Returns
    -------
    list of IdentifiedMode
        Ascending frequency; empty when nothing stands above the noise.

    Raises
    ------
    SpectralError
        Non-uniform times, fewer than 8 frames, no channel seen often enough.
    """
    t = np.asarray(times, dtype=float)
    dt = uniform_step(t)
    x = np.asarray(signals, dtype=float).reshape(len(t), -1)
    seen = np.isfinite(x)
    keep = seen.mean(axis=0) >= min_seen
    filled = fill_gaps(t, x, min_seen)                     # the same channels as ``keep``
    span = t[-1] - t[0]
    # 1.-2. ESPRIT on the channels subsampled to ~5 x the band limit: the starting poles
    q = max(1, min(int(1.0 / (5.0 * _band_limit(t, filled) * dt)), len(t) // 64))
    start = [m for m in dominant_modes(t[::q], filled[::q], max_modes=max_modes, min_seen=0.0)
             if m["frequency_hz"] > 0]
    if not start:
        return []
    theta = np.ravel([[m["decay_rate"] * span, 2 * np.pi * m["frequency_hz"] * span]
                      for m in start])
    # 3. variable projection on every seen sample at the full rate
    model = _DampedSinusoids((t - t[0]) / span, x[:, keep], seen[:, keep])
    theta, cost, JtJ, A = _levenberg_marquardt(model, theta, max_iterations)
    r = len(theta) // 2
    dof = int(seen[:, keep].sum()) - A.size - len(theta)
    sigma2 = cost / dof if dof > 0 else np.inf
    try:
        cov = sigma2 * np.linalg.inv(JtJ) / span ** 2       # of (d, omega) in SI units
    except np.linalg.LinAlgError:
        cov = np.full_like(JtJ, np.inf)
    modes = []
    for j in range(r):       # r <= max_modes: a short loop
        d, w = theta[2 * j] / span, theta[2 * j + 1] / span
        w = abs(w)
        mag = float(np.hypot(d, w))
        g = np.array([d, w]) / mag                          # d|s| / d(d, omega)
        c = cov[2 * j:2 * j + 2, 2 * j:2 * j + 2]
        std = float(np.sqrt(max(g @ c @ g, 0.0))) / (2 * np.pi) if np.all(np.isfinite(c)) \
            else np.inf
        f, fd = mag / (2 * np.pi), w / (2 * np.pi)
        shape = np.full(x.shape[1], np.nan, dtype=complex)
        shape[keep] = A[2 + 2 * j] - 1j * A[3 + 2 * j] * np.sign(theta[2 * j + 1] or 1.0)
        zeta = d / mag if mag > 0 else np.inf
        if fd * span < 1.0:
            note = f"less than one cycle in the {span:.3g} s record"
        elif fd > 0.45 / dt:
            note = "at the Nyquist frequency"
        elif zeta > max_damping_ratio:
            note = f"damping ratio {zeta:.2g} > {max_damping_ratio:g} (noise or drift)"
        elif not std <= max_relative_std * f:
            note = f"std {std:.2g} Hz > {max_relative_std:g} of the frequency"
        else:
            note = ""
        modes.append(IdentifiedMode(frequency_hz=float(f), std_hz=std,
                                    damped_frequency_hz=float(fd), decay_rate=float(d),
                                    damping_ratio=float(zeta),
                                    amplitude=float(np.linalg.norm(shape[keep])), shape=shape,
                                    seen=not note, note=note))
    modes.sort(key=lambda m: m.frequency_hz)
    return modes


def frequencies_from_recording(recording, *, max_modes: int = 20, min_seen: float = 0.5,
                               max_damping_ratio: float = 0.25,
                               max_relative_std: float = 0.02):
    """The natural frequencies seen in a recording's marker trajectories, with standard
    deviations and operational shapes at the markers (:func:`identify_modes`).

    Parameters
    ----------
    recording : petsoft.io.recording.Recording
        Positions (their displacements from the reference are used) or, without positions,
        accelerations.
    max_modes, min_seen, max_damping_ratio, max_relative_std
        See :func:`identify_modes`.

    Returns
    -------
    MeasuredFrequencies
        The seen modes, ascending, with ``markers`` (the recording's reference positions and
        names), ``shapes`` (complex, (k, M, 3)) and ``details`` (every fitted oscillation, seen
        or not, and why not).

    Raises
    ------
    SpectralError
        When no mode is seen (naming the file and what was found), or as :func:`identify_modes`.
    """
    if recording.positions is not None:
        data, kind = recording.positions - recording.reference[None], "positions"
    elif recording.accelerations is not None:
        data, kind = recording.accelerations, "accelerations"
    else:       # read_recording refuses this; a Recording made in memory may not
        raise SpectralError(f"{recording.source}: the recording has neither positions nor "
                            "accelerations: no frequency to estimate")
    try:
        modes = identify_modes(recording.times, data, max_modes=max_modes, min_seen=min_seen,
                               max_damping_ratio=max_damping_ratio,
                               max_relative_std=max_relative_std)
    except SpectralError as exc:
        raise SpectralError(f"{recording.source}: {exc}") from None
    seen = [m for m in modes if m.seen]
    if not seen:
        found = "; ".join(f"{m.frequency_hz:.4g} Hz: {m.note}" for m in modes) or "none"
        raise SpectralError(f"{recording.source}: no natural frequency could be estimated from "
                            f"the marker {kind} (oscillations found: {found}); record more "
                            "cycles, with less noise, or excite the body more")
    m = recording.num_markers
    details = {"recording": recording.source, "data": kind,
               "method": "ESPRIT start, variable-projection fit of damped sinusoids "
                         "(petsoft.calibration.spectra.identify_modes)",
               "frames": recording.num_frames,
               "duration_s": float(recording.times[-1] - recording.times[0]),
               "oscillations": [q.summary() for q in modes]}
    return MeasuredFrequencies(
        np.array([q.frequency_hz for q in seen]), np.array([q.std_hz for q in seen]),
        f"{recording.source} (modes estimated from the marker {kind})",
        markers=recording.reference, marker_names=tuple(recording.names),
        shapes=np.stack([q.shape.reshape(m, 3) for q in seen]), details=details)
