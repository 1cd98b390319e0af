"""Figures of a calibration: marker trajectories and residuals before and after the fit.

Positions and residuals are drawn in millimetres (as in the diagnosis' figures). Each function
returns what it drew (``path`` and the arrays), so a test can check the data, not the pixels.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _most_moving(data: np.ndarray, count: int) -> list[tuple[int, int]]:
    """(marker, component) pairs with the largest recorded motion (NaN-aware)."""
    span = np.nanmax(data, axis=0) - np.nanmin(data, axis=0)          # (M, 3)
    span = np.where(np.isfinite(span), span, -1.0)
    order = np.argsort(span.ravel())[::-1][:count]
    return [divmod(int(i), 3) for i in order]


def plot_trajectories(path: Path, times, data, before, after, names, count: int = 4) -> dict:
    """The recorded positions (mm) of the most-moving markers with the simulation before/after.

    Returns ``path``, ``picks`` ((marker, component) pairs) and ``recorded_mm`` (K, panels).
    """
    plt = _pyplot()
    picks = _most_moving(data, min(count, data.shape[1] * 3))
    fig, axes = plt.subplots(len(picks), 1, figsize=(9, 2.2 * len(picks)), sharex=True,
                             squeeze=False)
    for ax, (m, c) in zip(axes[:, 0], picks, strict=True):
        ax.plot(times, 1e3 * data[:, m, c], ".", ms=2, color="k", label="recorded")
        if before is not None:
            ax.plot(times, 1e3 * before[:, m, c], "-", lw=1, color="tab:red", label="before")
        if after is not None:
            ax.plot(times, 1e3 * after[:, m, c], "-", lw=1, color="tab:blue",
                    label="calibrated")
        ax.set_ylabel(f"{names[m]} {'xyz'[c]} (mm)")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("t (s)")
    fig.suptitle("Marker positions: the recording (dots) and the simulation before (red) and "
                 "after (blue) calibration")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {"path": Path(path), "picks": picks,
            "recorded_mm": np.column_stack([1e3 * data[:, m, c] for m, c in picks])}


def plot_residuals(path: Path, times, data, before, after, names, sigma: float) -> dict:
    """Residual (mm) over time, and rms per marker, before and after calibration.

    Returns ``path``, ``per_marker_mm`` ({"before"|"calibrated": (M,)}) and ``noise_mm``.
    """
    plt = _pyplot()
    seen = np.isfinite(data)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6.5))
    curves = []
    per_marker_mm: dict[str, np.ndarray] = {}
    for sim, label, color in ((before, "before", "tab:red"), (after, "calibrated", "tab:blue")):
        if sim is None:
            continue
        d = np.where(seen, sim - np.where(seen, data, 0.0), 0.0)
        per_time = np.sqrt((d * d).sum(axis=(1, 2)) / np.maximum(seen.sum(axis=(1, 2)), 1))
        per_time = 1e3 * per_time
        per_marker = 1e3 * np.sqrt((d * d).sum(axis=(0, 2)) / np.maximum(seen.sum(axis=(0, 2)),
                                                                          1))
        per_marker_mm[label] = per_marker
        curves.append((per_time, label, color))
        x = np.arange(len(names))
        offset = -0.2 if label == "before" else 0.2
        ax2.bar(x + offset, per_marker, width=0.4, color=color, label=label)
    # an exact zero (the first frame of a noise-free recording) would stretch the log axis over
    # hundreds of decades: clip at a hundredth of the smallest curve's median
    positive = [np.median(c[c > 0]) for c, _, _ in curves if np.any(c > 0)]
    floor = 1e-2 * min(positive) if positive else 1e-300
    for per_time, label, color in curves:
        ax1.semilogy(times, np.maximum(per_time, floor), color=color, lw=1, label=label)
    noise_mm = None
    if sigma and sigma != 1.0:
        noise_mm = 1e3 * sigma
        ax1.axhline(noise_mm, color="0.4", ls="--", lw=1, label="noise level")
        ax2.axhline(noise_mm, color="0.4", ls="--", lw=1)
    ax1.set_xlabel("t (s)")
    ax1.set_ylabel("rms residual (mm)")
    ax1.legend(fontsize=8)
    ax2.set_xticks(np.arange(len(names)))
    ax2.set_xticklabels(names, rotation=90, fontsize=7)
    ax2.set_ylabel("rms residual per marker (mm)")
    ax2.set_yscale("log")
    ax1.set_title("Residual over time and per marker: calibrated (blue) should lie near the "
                  "noise (dashed)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {"path": Path(path), "per_marker_mm": per_marker_mm, "noise_mm": noise_mm}


def plot_frequencies(path: Path, measured, before, after, std=None) -> dict:
    """Measured natural frequencies against the model's before and after a fit: the values,
    and the relative error of each mode (the quantity the fit drives to the noise).

    Returns
    -------
    dict
        What was drawn, read back from the figure: ``path``, ``modes`` (x), ``measured``,
        ``before``, ``after`` (top panel, Hz) and ``relative`` ({"before", "calibrated"}: the
        bottom panel's (model - measured) / measured).
    """
    plt = _pyplot()
    k = np.arange(1, len(measured) + 1)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    bars = top.errorbar(k, measured, yerr=std, fmt="o", color="k", label="measured")
    (b,) = top.plot(k, before, "x", color="tab:red", label="model before")
    (a,) = top.plot(k, after, "+", ms=10, color="tab:blue", label="model calibrated")
    top.set_ylabel("frequency (Hz)")
    top.legend(fontsize=8)
    relative = {}
    for values, color, label in ((before, "tab:red", "before"), (after, "tab:blue", "calibrated")):
        (relative[label],) = bottom.plot(k, (np.asarray(values) - measured) / measured, "o-",
                                         color=color, label=label)
    if std is not None:
        bottom.fill_between(k, -np.asarray(std) / measured, np.asarray(std) / measured,
                            color="0.85", label="measurement std")
    bottom.axhline(0.0, color="k", lw=0.5)
    bottom.set_xlabel("elastic mode")
    bottom.set_ylabel("(model - measured) / measured")
    bottom.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    drawn = {"path": Path(path), "modes": np.asarray(bars.lines[0].get_xdata()),
             "measured": np.asarray(bars.lines[0].get_ydata()),
             "before": np.asarray(b.get_ydata()), "after": np.asarray(a.get_ydata()),
             "relative": {k: np.asarray(v.get_ydata()) for k, v in relative.items()}}
    plt.close(fig)
    return drawn
