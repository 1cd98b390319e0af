"""Where and when a simulation misses the recording: per-marker, on the body, in time.

This module owns the localisation of a residual ``data - sim`` (arrays only, no solver):

* :func:`marker_residuals` -- rms and chi2/dof of each marker, and which markers stand out;
* :func:`mismatch_region` -- the residual-weighted centre and radius of the flagged markers in
  the reference configuration (formats.md ``mismatch.region``);
* :func:`nodal_residual_field` / :func:`write_residual_field` -- the marker residuals spread
  onto the mesh nodes (Gaussian kernel) and written with :mod:`petsoft.io.xdmf` for ParaView;
* :func:`mismatch_time_windows` -- the time intervals where the windowed chi2/dof exceeds what
  noise allows.

Criteria (why these)
--------------------
A marker *stands out* when its rms residual exceeds ``median + k * 1.4826 * MAD`` of all markers'
rms (robust: a few bad markers cannot raise the bar they are compared with). When the noise
``sigma`` is known it must also *exceed the noise*: its chi2 (3 x seen frames degrees of freedom)
above the ``1 - alpha / M`` quantile (Bonferroni over the M markers). A mismatch spread over the
whole body (a missing damping) therefore flags no single marker -- which is itself evidence.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats
from scipy.spatial import cKDTree

from petsoft.errors import PetsoftError
from petsoft.io.xdmf import write_xdmf

__all__ = ["LocateError", "MarkerResiduals", "marker_residuals", "mismatch_region",
           "nodal_residual_field", "write_residual_field", "mismatch_time_windows",
           "marker_spacing"]


class LocateError(PetsoftError):
    """Arrays given to the localisation are inconsistent (shapes, names, sigma)."""


def _pair(data: np.ndarray, sim: np.ndarray) -> np.ndarray:
    data = np.asarray(data, dtype=float)
    sim = np.asarray(sim, dtype=float)
    if data.ndim != 3 or data.shape[2] != 3 or sim.shape != data.shape:
        raise LocateError(f"data {data.shape} and sim {sim.shape} must both be (K, M, 3)")
    if not np.all(np.isfinite(sim)):
        raise LocateError("sim has NaN/inf positions; only the data may have NaN (unseen)")
    return data - sim


def _sigma(sigma, what="sigma") -> float | None:
    if sigma is None:
        return None
    s = float(sigma)
    if not (np.isfinite(s) and s > 0):
        raise LocateError(f"{what} = {sigma}: the noise standard deviation must be finite and > 0")
    return s


def marker_spacing(reference: np.ndarray) -> float:
    """Median distance from each marker to its nearest neighbour (the markers' resolution)."""
    ref = np.asarray(reference, dtype=float)
    if len(ref) < 2:
        return 0.0
    d, _ = cKDTree(ref).query(ref, k=2)
    return float(np.median(d[:, 1]))


@dataclass
class MarkerResiduals:
    """Per-marker residual statistics (:func:`marker_residuals`).

    Attributes
    ----------
    names : list of str
    rms : ndarray (M,)
        sqrt(mean over seen frames of |r|^2) (m); NaN for a marker never seen.
    seen : ndarray (M,) int
        Frames in which the marker was seen.
    chi2_per_dof : ndarray (M,) or None
        sum(|r|^2) / sigma^2 / (3 seen) when sigma is known.
    stands_out, exceeds_noise, flagged : ndarray (M,) bool
        The two criteria of the module docstring and their conjunction (``exceeds_noise`` is all
        True without sigma).
    threshold_rms : float
        The robust bar ``median + k MAD`` on rms.
    """

    names: list
    rms: np.ndarray
    seen: np.ndarray
    chi2_per_dof: np.ndarray | None
    stands_out: np.ndarray
    exceeds_noise: np.ndarray
    flagged: np.ndarray
    threshold_rms: float

    @property
    def flagged_names(self) -> list:
        order = np.argsort(-np.where(self.flagged, self.rms, -np.inf))
        return [self.names[i] for i in order if self.flagged[i]]


def marker_residuals(data: np.ndarray, sim: np.ndarray, names: list[str], sigma=None, *,
                     k: float = 3.0, alpha: float = 0.01) -> MarkerResiduals:
    """Residual of each marker and which markers stand out (module docstring).

    Parameters
    ----------
    data, sim : ndarray (K, M, 3)
        Recorded (NaN = unseen) and simulated positions.
    names : list of str
        The M marker names.
    sigma : float, optional
        Position noise standard deviation (m).
    k : float, optional
        Number of robust standard deviations above the median for "stands out".
    alpha : float, optional
        Family-wise level of the chi2 "exceeds noise" test.
    """
    r = _pair(data, sim)
    m = r.shape[1]
    if len(names) != m:
        raise LocateError(f"{len(names)} names for {m} markers")
    s = _sigma(sigma)
    seen_frames = np.isfinite(r).all(axis=2)
    nseen = seen_frames.sum(axis=0)
    sq = np.where(seen_frames, np.sum(np.nan_to_num(r) ** 2, axis=2), 0.0).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.where(nseen > 0, np.sqrt(sq / np.maximum(nseen, 1)), np.nan)
    ok = np.isfinite(rms)
    med = np.median(rms[ok]) if ok.any() else np.nan
    mad = np.median(np.abs(rms[ok] - med)) if ok.any() else np.nan
    # A floor on the spread so identical residuals (MAD = 0) do not flag round-off differences.
    spread = max(1.482602218505602 * mad, 1e-3 * med if med > 0 else 0.0)
    bar = med + k * spread
    stands = ok & (rms > bar)
    if s is None:
        chi = None
        exceeds = ok.copy()
    else:
        dof = 3 * nseen
        chi = np.where(nseen > 0, sq / s**2 / np.maximum(dof, 1), np.nan)
        q = stats.chi2.isf(alpha / max(m, 1), np.maximum(dof, 1))
        exceeds = ok & (sq / s**2 > q)
    return MarkerResiduals(names=list(names), rms=rms, seen=nseen, chi2_per_dof=chi,
                           stands_out=stands, exceeds_noise=exceeds, flagged=stands & exceeds,
                           threshold_rms=float(bar))


def mismatch_region(reference: np.ndarray, res: MarkerResiduals) -> dict | None:
    """Residual-weighted centre and radius of the flagged markers (reference configuration).

    The weight of a flagged marker is its *excess* mean squared residual over the typical
    (median) marker, ``rms^2 - median(rms)^2``, so the centre sits where the mismatch is, not
    where the noise or a global error is. The radius is the largest distance from the centre to a
    flagged marker plus half the marker spacing (the resolution: a single flagged marker says the
    mismatch is within about half a spacing of it).

    Returns
    -------
    dict or None
        ``{"center": [x, y, z], "radius": r}`` (formats.md), or None when nothing is flagged.
    """
    ref = np.asarray(reference, dtype=float)
    if ref.shape != (len(res.rms), 3):
        raise LocateError(f"reference has shape {ref.shape}; expected ({len(res.rms)}, 3)")
    if not res.flagged.any():
        return None
    base = np.nanmedian(res.rms) ** 2
    w = np.where(res.flagged, np.maximum(np.nan_to_num(res.rms) ** 2 - base, 0.0), 0.0)
    if w.sum() <= 0:
        w = res.flagged.astype(float)
    center = (w[:, None] * ref).sum(axis=0) / w.sum()
    reach = np.max(np.linalg.norm(ref[res.flagged] - center, axis=1))
    radius = reach + 0.5 * marker_spacing(ref)
    return {"center": [float(c) for c in center], "radius": float(radius)}


def nodal_residual_field(points: np.ndarray, reference: np.ndarray, values: np.ndarray,
                         length: float | None = None, chunk: int = 20000) -> np.ndarray:
    """Spread per-marker values onto mesh nodes with a normalised Gaussian kernel.

    ``f(x) = sum_m w_m(x) v_m / sum_m w_m(x)``, ``w_m = exp(-|x - X_m|^2 / (2 length^2))``
    (Nadaraya-Watson); markers with NaN values are skipped. Far from every marker the field is
    the value of the nearest markers -- the distance to the nearest marker (also written by
    :func:`write_residual_field`) says how much to trust it.

    Parameters
    ----------
    points : ndarray (N, 3)
        Mesh nodes (reference configuration).
    reference, values : ndarray (M, 3), (M,)
        Marker reference positions and their values (e.g. rms residual).
    length : float, optional
        Kernel width; default the marker spacing (:func:`marker_spacing`).
    chunk : int
        Nodes per block (bounds memory to chunk x M).
    """
    pts = np.asarray(points, dtype=float)
    ref = np.asarray(reference, dtype=float)
    v = np.asarray(values, dtype=float)
    ok = np.isfinite(v)
    ref, v = ref[ok], v[ok]
    if len(v) == 0:
        raise LocateError("no marker has a finite residual to spread on the mesh")
    if length is None:
        length = marker_spacing(ref) or 1.0
    out = np.empty(len(pts))
    for a in range(0, len(pts), chunk):     # blocks of nodes, vectorised within
        d2 = ((pts[a:a + chunk, None, :] - ref[None, :, :]) ** 2).sum(axis=2)
        # Shift by the nearest marker's distance so far nodes do not underflow to 0 / 0.
        w = np.exp(-(d2 - d2.min(axis=1, keepdims=True)) / (2.0 * length**2))
        out[a:a + chunk] = (w @ v) / w.sum(axis=1)
    return out


def write_residual_field(path: str | Path, points: np.ndarray, tets: np.ndarray,
                         reference: np.ndarray, res: MarkerResiduals,
                         length: float | None = None) -> Path:
    """Write the nodal residual field (and distance to the nearest marker) as XDMF + HDF5."""
    pts = np.asarray(points, dtype=float)
    field = nodal_residual_field(pts, reference, res.rms, length)
    dist, _ = cKDTree(np.asarray(reference, dtype=float)).query(pts)
    data = {"residual_rms": field, "distance_to_marker": dist}
    if res.chi2_per_dof is not None:
        data["residual_chi2_per_dof"] = nodal_residual_field(pts, reference, res.chi2_per_dof,
                                                             length)
    write_xdmf(path, pts, tets, point_data=data)
    return Path(path)


def mismatch_time_windows(data: np.ndarray, sim: np.ndarray, times: np.ndarray, sigma, *,
                          window: float | None = None, alpha: float = 0.01) -> dict:
    """Time intervals where the windowed chi2/dof exceeds its noise quantile.

    The per-frame chi2 (all seen markers and axes) is summed over a sliding window of ``w``
    frames. Under pure noise each window's sum is chi2 with ``3 x seen`` degrees of freedom;
    a window is flagged above the ``1 - alpha / (K / w)`` quantile (Bonferroni over the number
    of disjoint windows), its centre frame is marked, and marked frames are merged into
    intervals.

    Parameters
    ----------
    data, sim : ndarray (K, M, 3)
    times : ndarray (K,)
    sigma : float
        Noise standard deviation (m); estimate it with
        :func:`petsoft.diagnosis.noise.estimate_noise_std` when the recording has none.
    window : float, optional
        Window length (s); default 1/20 of the duration, at least 5 frames.
    alpha : float

    Returns
    -------
    dict
        ``intervals`` [[t0, t1], ...], ``frame_chi2_per_dof`` (K,), ``window_chi2_per_dof`` (K,)
        (centred; NaN near the ends), ``threshold`` (K,) the chi2/dof bar per window centre,
        ``window_frames``.
    """
    r = _pair(data, sim)
    t = np.asarray(times, dtype=float)
    if t.shape != (r.shape[0],) or np.any(np.diff(t) <= 0):
        raise LocateError(f"times must be strictly increasing with shape ({r.shape[0]},)")
    s = _sigma(sigma)
    if s is None:
        raise LocateError("sigma is required to find mismatch time windows")
    k_frames = len(t)
    if window is None:
        w = max(5, k_frames // 20)
    else:
        w = int(round(window / np.median(np.diff(t))))
    w = int(min(max(w, 1), k_frames))
    seen = np.isfinite(r)
    chi_f = np.where(seen, np.nan_to_num(r) / s, 0.0) ** 2
    chi_f = chi_f.reshape(k_frames, -1).sum(axis=1)
    dof_f = seen.reshape(k_frames, -1).sum(axis=1).astype(float)
    csum = np.concatenate([[0.0], np.cumsum(chi_f)])
    dsum = np.concatenate([[0.0], np.cumsum(dof_f)])
    chi_w = csum[w:] - csum[:-w]            # window starting at frame i, i = 0 .. K - w
    dof_w = dsum[w:] - dsum[:-w]
    nwin = max(1.0, k_frames / w)
    q = np.where(dof_w > 0, stats.chi2.isf(alpha / nwin, np.maximum(dof_w, 1)), np.inf)
    bad = chi_w > q
    # Mark the centre frame of every flagged window: the intervals then estimate the extent of
    # the mismatch itself rather than growing by a window length on each side.
    off = (w - 1) // 2
    marked = np.zeros(k_frames, dtype=bool)
    marked[np.flatnonzero(bad) + off] = True
    edges = np.diff(np.concatenate([[0], marked.astype(int), [0]]))
    first, last = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    intervals = [[float(t[a]), float(t[b])] for a, b in zip(first, last, strict=True)]
    centred = np.full(k_frames, np.nan)
    thr = np.full(k_frames, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        centred[off:off + len(chi_w)] = chi_w / dof_w
        thr[off:off + len(chi_w)] = q / dof_w
        frame = chi_f / dof_f
    return {"intervals": intervals, "frame_chi2_per_dof": frame, "window_chi2_per_dof": centred,
            "threshold": thr, "window_frames": w, "marked": marked}
