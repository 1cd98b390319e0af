"""The diagnosis' figures that show the mismatch: what a person looks at before reading.

* ``displacement.png``: the markers that matter most (largest residual of the model as given),
  their displacement from the reference position per component (x, y, z in their own colours,
  with a legend): data as dots, the model before and after as lines, over the whole record, the
  held-out part (where the prediction decides) shaded. Absolute positions would put x near 0.3 m
  on one axis with y, z near 0.04 m while the motion is millimetres: every curve would look flat.
* ``residual_on_body.png``: each marker's rms residual (model as given) over the noise, drawn
  where the marker sits on the body, in the two views that show the body largest.
* ``candidates.png``: the candidate terms' score-test statistics, sorted, on a log axis, the
  added ones marked.
* ``spectra.png``: amplitude spectra of the data, the model before and after.

Every function writes its PNG and returns what it drew (arrays and limits), so a test can check
the figure shows what it should without looking at pixels.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from petsoft.diagnosis.report import pyplot_agg, save_figure

__all__ = ["plot_candidates", "plot_displacement", "plot_residual_on_body",
           "plot_spectra_before_after", "rms_per_marker"]

_COMPONENT_COLOURS = ("tab:blue", "tab:orange", "tab:green")


def rms_per_marker(data: np.ndarray, sim: np.ndarray) -> np.ndarray:
    """(M,) rms over the seen samples of each marker of |sim - data| (NaN for a never-seen one)."""
    d = np.asarray(sim, float) - np.asarray(data, float)
    sq = np.where(np.isfinite(d), d * d, 0.0).sum(axis=2)            # (K, M)
    seen = np.isfinite(d).all(axis=2).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(seen > 0, np.sqrt(sq.sum(axis=0) / np.maximum(seen, 1)), np.nan)


def plot_displacement(path, times, data, before, after, reference, cut: float,
                      names: Sequence[str] | None = None, count: int = 3) -> dict:
    """Displacement per component of the ``count`` markers with the largest residual before.

    Parameters
    ----------
    times : (K,) array
        The whole record (identification window and held-out part).
    data, before, after : (K, M, 3) arrays
        Recorded positions (NaN where unseen), the model as given and as diagnosed.
    reference : (M, 3) array
        The markers' reference positions (the displacement's origin).
    cut : float
        End of the identification window; later frames are held out.

    Returns
    -------
    dict
        ``markers`` (indices drawn), ``ylim`` per panel, ``data_range`` (min, max of the drawn
        recorded displacement per panel), ``held_out`` (the shaded interval).
    """
    plt = pyplot_agg()
    t = np.asarray(times, float)
    data, before = np.asarray(data, float), np.asarray(before, float)
    after = None if after is None else np.asarray(after, float)
    ref = np.asarray(reference, float)[None]
    rms = rms_per_marker(data, before)
    markers = [int(m) for m in np.argsort(-np.nan_to_num(rms, nan=-1.0))[:count]]
    fig, axes = plt.subplots(len(markers), 1, figsize=(8, 2.4 * len(markers) + 0.6),
                             squeeze=False, sharex=True)
    drawn = {"markers": markers, "ylim": [], "data_range": [], "held_out": (cut, t[-1])}
    for ax, m in zip(axes[:, 0], markers, strict=True):
        for c, colour in enumerate(_COMPONENT_COLOURS):
            ax.plot(t, 1e3 * (data[:, m, c] - ref[0, m, c]), ".", ms=2.5, c=colour)
            ax.plot(t, 1e3 * (before[:, m, c] - ref[0, m, c]), "-", lw=0.9, c=colour, alpha=0.45)
            if after is not None:
                ax.plot(t, 1e3 * (after[:, m, c] - ref[0, m, c]), "--", lw=1.2, c=colour)
        if t[-1] > cut:
            ax.axvspan(cut, t[-1], color="0.85", zorder=0)
        label = names[m] if names is not None else f"marker {m}"
        ax.set_ylabel(f"{label}\ndisplacement (mm)", fontsize=8)
        shown = 1e3 * (data[:, m] - ref[0, m])
        drawn["data_range"].append((float(np.nanmin(shown)), float(np.nanmax(shown))))
        drawn["ylim"].append(tuple(float(v) for v in ax.get_ylim()))
    axes[-1, 0].set_xlabel("time (s)")
    # one legend: the components' colours, and what dots / lines mean
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], c=c, lw=2, label=k) for c, k in zip(_COMPONENT_COLOURS, "xyz",
                                                                    strict=True)]
    handles += [Line2D([], [], c="k", marker=".", ls="", label="data"),
                Line2D([], [], c="k", lw=0.9, alpha=0.45, label="model as given"),
                Line2D([], [], c="k", lw=1.2, ls="--", label="as diagnosed")]
    if t[-1] > cut:
        from matplotlib.patches import Patch

        handles.append(Patch(color="0.85", label="held out (prediction)"))
    axes[0, 0].legend(handles=handles, fontsize=7, ncol=4, loc="upper right")
    axes[0, 0].set_title("Markers with the largest mismatch: displacement from the reference")
    save_figure(fig, path)
    return drawn


def _two_views(points: np.ndarray) -> list[tuple[int, int]]:
    """The two coordinate planes in which the body looks largest (axes by extent)."""
    order = np.argsort(-np.ptp(points, axis=0))
    return [(int(order[0]), int(order[1])), (int(order[0]), int(order[2]))]


def plot_residual_on_body(path, surface_points, marker_positions, marker_rms, noise: float,
                          names: Sequence[str] | None = None) -> dict:
    """Each marker's rms residual over the noise, drawn where it sits, over the body's surface.

    Returns ``views`` (the coordinate pairs drawn), ``values`` (rms / noise per marker) and
    ``colour_range``.
    """
    plt = pyplot_agg()
    pts = np.asarray(surface_points, float)
    pos = np.asarray(marker_positions, float)
    values = np.asarray(marker_rms, float) / noise
    views = _two_views(pts)
    finite = values[np.isfinite(values)]
    vmax = float(max(finite.max() if finite.size else 1.0, 1.0))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, (i, j) in zip(axes, views, strict=True):
        ax.scatter(pts[:, i], pts[:, j], s=2, c="0.8", zorder=0)
        sc = ax.scatter(pos[:, i], pos[:, j], c=values, cmap="viridis", vmin=0.0, vmax=vmax,
                        s=45, edgecolors="k", linewidths=0.5, zorder=2)
        worst = int(np.nanargmax(values)) if finite.size else None
        if worst is not None:
            ax.annotate(names[worst] if names is not None else str(worst),
                        (pos[worst, i], pos[worst, j]), fontsize=7, xytext=(4, 4),
                        textcoords="offset points")
        ax.set_xlabel(f"{'xyz'[i]} (m)")
        ax.set_ylabel(f"{'xyz'[j]} (m)")
        ax.set_aspect("equal", adjustable="datalim")
    fig.colorbar(sc, ax=list(axes), label="rms residual / noise")
    fig.suptitle("Where on the body the model as given misses (grey: surface nodes)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {"views": views, "values": values, "colour_range": (0.0, vmax)}


def plot_candidates(path, scores: Sequence[Mapping], added: Sequence[str]) -> dict:
    """The candidates' score statistics (first round each was scored), sorted, log axis.

    Returns ``names`` and ``scores`` in the drawn order (largest first) and ``added``.
    """
    plt = pyplot_agg()
    best: dict[str, float] = {}
    for s in scores:
        if "score" in s and np.isfinite(s["score"]):
            key = s["physics"] + (f" ({s['region']['name']})" if isinstance(s.get("region"), dict)
                                  and s["region"].get("name") else "")
            best[key] = max(best.get(key, 0.0), float(s["score"]))
    items = sorted(best.items(), key=lambda kv: -kv[1])
    names = [k for k, _ in items]
    values = np.array([max(v, 1e-3) for _, v in items])     # a log axis: floor at 1e-3
    is_added = [any(k == a or k.startswith(a + " ") for a in added) for k in names]
    fig, ax = plt.subplots(figsize=(7, 0.32 * max(len(items), 1) + 1.4))
    if items:
        colours = ["tab:green" if a else "0.6" for a in is_added]
        y = np.arange(len(items))
        ax.barh(y, values, color=colours)
        ax.set_yticks(y)
        ax.set_yticklabels([f"{n}  (added)" if a else n for n, a in zip(names, is_added,
                                                                        strict=True)],
                           fontsize=8)
        ax.invert_yaxis()
        ax.set_xscale("log")
    ax.set_xlabel("score-test statistic (log scale; larger: the data ask more for the term)")
    ax.set_title("Candidate physics, sorted (green: added)")
    save_figure(fig, path)
    return {"names": names, "scores": values, "added": [n for n, a in zip(names, is_added,
                                                                         strict=True) if a]}


def plot_spectra_before_after(path, times, data, before, after) -> dict:
    """Amplitude spectra (summed over markers and components) of data, before and after.

    Returns ``frequency`` and the three ``spectra``.
    """
    from petsoft.diagnosis.spectral import fill_gaps

    plt = pyplot_agg()
    t = np.asarray(times, float)
    f = np.fft.rfftfreq(len(t), t[1] - t[0])
    fig, ax = plt.subplots(figsize=(7, 3.6))
    spectra = {}
    seen = np.isfinite(np.asarray(data, float))
    for arr, label, style in ((data, "data", dict(c="k", lw=1.4)),
                              (before, "model as given", dict(c="tab:red", lw=1.0)),
                              (after, "as diagnosed", dict(c="tab:blue", lw=1.0, ls="--"))):
        if arr is None:
            continue
        # the simulations seen where the data are: the same channels, the same gaps filled
        x = fill_gaps(t, np.where(seen, np.asarray(arr, float), np.nan))
        x = (x - x.mean(axis=0)) * np.hanning(len(t))[:, None]
        spec = np.sqrt(np.sum(np.abs(np.fft.rfft(x, axis=0)) ** 2, axis=1))
        spectra[label] = spec
        ax.semilogy(f[1:], spec[1:], label=label, **style)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("amplitude spectrum (m)")
    ax.set_title("Spectra of the marker motion")
    ax.legend(fontsize=8)
    save_figure(fig, path)
    return {"frequency": f, "spectra": spectra}
