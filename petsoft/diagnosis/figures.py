"""The diagnosis' figures that show the mismatch: what a person looks at before reading.

* ``displacement.png``: the markers that matter most (largest residual of the model as given),
  their displacement from the reference position per component (x, y, z in their own colours,
  with a legend): data as dots, the model before and after as lines, over the whole record, the
  held-out part (where the prediction decides) shaded. Absolute positions would put x near 0.3 m
  on one axis with y, z near 0.04 m while the motion is millimetres: every curve would look flat.
* ``residual_on_body.png``: the body's surface in 3-D (mm), each triangle coloured by the
  residual of the model as given over the noise, spread from the markers
  (:func:`~petsoft.diagnosis.locate.nodal_residual_field`, the field residual_field.xdmf holds),
  the markers drawn on it.
* ``candidates.png``: the candidate terms' score-test statistics, sorted, on a log axis, the
  added ones marked, each term's significance threshold drawn, a zero score said as such.
* ``spectra.png``: amplitude spectra (mm) of the data, the model before and after, the fitted
  modes of the data marked (the only spectra figure).

Displacements and lengths are in millimetres in every figure. :data:`CAPTIONS` says under each
figure what to see in it.

Every function writes its PNG and returns what it drew (arrays and limits), so a test can check
the figure shows what it should without looking at pixels.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from petsoft.diagnosis.report import pyplot_agg, save_figure

__all__ = ["CAPTIONS", "plot_candidates", "plot_displacement", "plot_residual_on_body",
           "plot_spectra_before_after", "rms_per_marker"]

_COMPONENT_COLOURS = ("tab:blue", "tab:orange", "tab:green")

#: What to see in each figure (its caption in report.md and report.html), by file stem.
CAPTIONS = {
    "displacement": "The markers the model as given misses most: recorded displacement (dots), "
                    "the model as given (thin lines) and as diagnosed (dashed), in mm. Where "
                    "the dashed lines follow the dots in the grey held-out part, the diagnosed "
                    "model predicts what it was not fitted to.",
    "residual_on_body": "Where on the body the model as given misses: the surface coloured by "
                        "its residual over the noise (1 = the noise), spread from the markers "
                        "(dots). A hot patch points to a local cause (added mass, a soft "
                        "region); an even colour to a global one (damping, stiffness).",
    "residual_markers": "Residual of the model as given per marker (mm). Red bars, if any, stand "
                        "out from the others (above the dashed line); the dotted line is the "
                        "noise.",
    "residual_time": "When the model as given misses: the residual's chi2/dof over time "
                     "(1 = the noise); red bands exceed the noise threshold (dashed).",
    "spectra": "Amplitude spectra of the marker motion (mm): the recording (black), the model "
               "as given (red) and as diagnosed (blue dashed); dotted lines at the recording's "
               "fitted modes. A peak the model as given misses or shifts is what the diagnosis "
               "had to explain.",
    "candidates": "How strongly the recording asks for each candidate term (score-test "
                  "statistic, log scale; green: added). A bar right of its tick (the 1 % "
                  "significance threshold) is significant; a zero score is marked 0.",
}


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


def plot_residual_on_body(path, points, facets, marker_positions, marker_rms, noise: float,
                          names: Sequence[str] | None = None) -> dict:
    """The body's surface in 3-D coloured by the residual over the noise (module docstring).

    Parameters
    ----------
    points : (N, 3) array
        Mesh nodes (reference configuration, m).
    facets : (F, 3) int array
        The exterior triangles (:func:`~petsoft.mesh.topology.boundary_facets`).
    marker_positions : (M, 3) array
        The markers' reference positions (m).
    marker_rms : (M,) array
        Each marker's rms residual (m; NaN: never seen).
    noise : float
        The noise std (m).

    Returns
    -------
    dict
        ``facet_values`` (F,): each triangle's residual / noise (the mean of its nodes' field),
        ``marker_values`` (M,): rms / noise per marker, ``colour_range``, ``worst`` (the marker
        named on the figure).
    """
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from petsoft.diagnosis.locate import nodal_residual_field

    plt = pyplot_agg()
    pts = 1e3 * np.asarray(points, float)                       # mm
    tri = np.asarray(facets, int)
    pos = 1e3 * np.asarray(marker_positions, float)
    values = np.asarray(marker_rms, float) / noise
    node = nodal_residual_field(np.asarray(points, float), np.asarray(marker_positions, float),
                                values)
    facet_values = node[tri].mean(axis=1)
    finite = values[np.isfinite(values)]
    vmax = float(max(finite.max() if finite.size else 1.0, 1.0))
    cmap = plt.get_cmap("viridis")
    norm = plt.Normalize(0.0, vmax)
    fig = plt.figure(figsize=(9, 5.4))
    ax = fig.add_subplot(projection="3d")
    poly = Poly3DCollection(pts[tri], facecolors=cmap(norm(facet_values)), edgecolors="0.3",
                            linewidths=0.2)
    ax.add_collection3d(poly)
    ax.scatter(*pos.T, c=cmap(norm(np.nan_to_num(values))), s=40, edgecolors="k",
               depthshade=False)
    worst = int(np.nanargmax(values)) if finite.size else None
    if worst is not None:
        ax.text(*pos[worst], f"  {names[worst] if names is not None else worst}", fontsize=8)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    # a slender bar drawn to scale is a line: thin sides are drawn at least a quarter as long
    ax.set_box_aspect(np.maximum(hi - lo, 0.25 * (hi - lo).max()))
    ax.view_init(elev=22, azim=-60)
    from matplotlib.ticker import MaxNLocator

    for axis in (ax.yaxis, ax.zaxis):              # the short sides: few ticks, readable
        axis.set_major_locator(MaxNLocator(3))
    for setter, axis in zip((ax.set_xlabel, ax.set_ylabel, ax.set_zlabel), "xyz", strict=True):
        setter(f"{axis} (mm)")
    sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, ax=ax, shrink=0.6, label="residual / noise (model as given)")
    ax.set_title("Where on the body the model as given misses")
    save_figure(fig, path)
    return {"facet_values": facet_values, "marker_values": values,
            "colour_range": (0.0, vmax), "worst": worst}


def plot_candidates(path, scores: Sequence[Mapping], added: Sequence[str],
                    alpha: float = 0.01) -> dict:
    """The candidates' score statistics (the largest of the rounds each was scored in), sorted,
    on a log axis, with each one's significance threshold (chi-square with its dof at
    ``alpha``) and a zero score written as 0 instead of a bar.

    Returns ``names`` and ``scores`` in the drawn order (largest first; zeros are 0.0),
    ``thresholds`` (per name), ``zero`` (names whose score is 0, drawn as text) and ``added``.
    """
    from scipy import stats

    plt = pyplot_agg()
    best: dict[str, float] = {}
    dof: dict[str, int] = {}
    for s in scores:
        if "score" in s and np.isfinite(s["score"]):
            key = s["physics"] + (f" ({s['region']['name']})" if isinstance(s.get("region"), dict)
                                  and s["region"].get("name") else "")
            best[key] = max(best.get(key, 0.0), float(s["score"]))
            dof[key] = int(s.get("dof", 1))
    items = sorted(best.items(), key=lambda kv: -kv[1])
    names = [k for k, _ in items]
    values = np.array([v for _, v in items])
    thresholds = np.array([stats.chi2.ppf(1.0 - alpha, dof[k]) for k in names])
    zero = [k for k, v in items if v <= 0.0]
    is_added = [any(k == a or k.startswith(a + " ") for a in added) for k in names]
    fig, ax = plt.subplots(figsize=(7.5, 0.34 * max(len(items), 1) + 1.6))
    if items:
        positive = values[values > 0]
        left = 0.3 * min(positive.min() if positive.size else 1.0, thresholds.min())
        colours = ["tab:green" if a else "0.6" for a in is_added]
        y = np.arange(len(items))
        # a bar from the axis' left edge; a zero score has no bar on a log axis: text says 0
        widths = np.where(values > 0, values - left, 0.0)
        ax.barh(y, widths, left=left, color=colours)
        ax.scatter(thresholds, y, marker="|", s=200, c="tab:red", zorder=3,
                   label=f"significance threshold (p = {alpha:g})")
        for yi, v in zip(y, values, strict=True):
            if v <= 0.0:
                ax.text(left * 1.15, yi, "0 (no sign of it)", va="center", fontsize=8)
        ax.set_yticks(y)
        ax.set_yticklabels([f"{n}  (added)" if a else n for n, a in zip(names, is_added,
                                                                        strict=True)],
                           fontsize=8)
        ax.invert_yaxis()
        ax.set_xscale("log")
        ax.set_xlim(left, max(values.max(), thresholds.max()) * 3)
        ax.legend(fontsize=8, loc="lower right")
    ax.set_xlabel("score-test statistic (log scale; larger: the data ask more for the term)")
    ax.set_title("Candidate physics, sorted (green: added)")
    save_figure(fig, path)
    return {"names": names, "scores": values, "thresholds": dict(zip(names, thresholds,
                                                                      strict=True)),
            "zero": zero,
            "added": [n for n, a in zip(names, is_added, strict=True) if a]}


def plot_spectra_before_after(path, times, data, before, after, data_modes=()) -> dict:
    """Amplitude spectra (mm, summed over markers and components) of data, before and after,
    the data's fitted modes (:func:`~petsoft.diagnosis.spectral.dominant_modes`) dotted.

    Returns ``frequency``, the three ``spectra`` (mm) and ``modes_hz`` (the dotted lines).
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
        window = np.hanning(len(t))
        x = (x - x.mean(axis=0)) * window[:, None]
        # 2 / sum(window): a sinusoid of amplitude A mm on a bin reads A (root-sum-square over
        # the channels)
        spec = 2e3 / window.sum() * np.sqrt(np.sum(np.abs(np.fft.rfft(x, axis=0)) ** 2, axis=1))
        spectra[label] = spec
        ax.semilogy(f[1:], spec[1:], label=label, **style)
    modes_hz = [float(m["frequency_hz"]) for m in data_modes or () if m["frequency_hz"] > 0]
    for hz in modes_hz:
        ax.axvline(hz, c="k", ls=":", lw=0.8)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("amplitude (mm, all markers)")
    ax.set_title("Spectra of the marker motion (dotted: the recording's fitted modes)")
    ax.legend(fontsize=8)
    save_figure(fig, path)
    return {"frequency": f, "spectra": spectra, "modes_hz": modes_hz}
