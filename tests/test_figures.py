"""The diagnosis' figures (petsoft.diagnosis.figures): each checked on the data it drew."""

from __future__ import annotations

import numpy as np
import pytest

from petsoft.diagnosis.figures import (
    plot_candidates,
    plot_displacement,
    plot_residual_on_body,
    plot_spectra_before_after,
    rms_per_marker,
)


def _record(seed=0):
    """A bar's 5 markers near x = 0.3 m moving 4.7 mm at 5 Hz; the model as given misses
    marker 3 most (a 15 Hz error), the diagnosed one matches."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, 201)
    ref = np.column_stack([np.linspace(0.1, 0.3, 5), np.full(5, 0.04), np.full(5, 0.04)])
    motion = 4.7e-3 * np.sin(2 * np.pi * 5 * t)[:, None, None] * np.array([0.1, 0.3, 1.0])
    shape = np.linspace(0.2, 1.0, 5)[None, :, None]
    data = ref[None] + motion * shape + 2e-5 * rng.standard_normal((len(t), 5, 3))
    data[rng.random(data.shape[:2]) < 0.1] = np.nan                 # dropouts
    before = ref[None] + 0.8 * motion * shape
    before[:, 3] += 1.5e-3 * np.sin(2 * np.pi * 15 * t)[:, None]
    after = ref[None] + motion * shape
    return t, ref, data, before, after


def test_displacement_shows_the_worst_markers_motion_and_the_held_out_part(tmp_path):
    t, ref, data, before, after = _record()
    drawn = plot_displacement(tmp_path / "d.png", t, data, before, after, ref, cut=0.7,
                              names=[f"m{k}" for k in range(5)])
    assert (tmp_path / "d.png").stat().st_size > 10_000
    assert drawn["markers"][0] == 3                    # the largest residual first
    assert drawn["held_out"] == (0.7, 1.0)
    for (lo, hi), (ylo, yhi) in zip(drawn["data_range"], drawn["ylim"], strict=True):
        # millimetres of displacement, not metres of position: the axis spans the motion
        assert ylo <= lo and hi <= yhi
        assert yhi - ylo < 4 * (hi - lo) and hi - lo > 1.0


def _box_surface(size=(0.3, 0.04, 0.04), cells=(6, 1, 1)):
    """Nodes and exterior triangles of a box of tets (the mesh module's own box)."""
    from petsoft.mesh.serial import box_mesh
    from petsoft.mesh.topology import boundary_facets

    mesh = box_mesh(size, cells)
    return mesh.points, boundary_facets(mesh.tets)


def test_residual_on_body_colours_the_surface_by_the_residual_over_the_noise(tmp_path):
    t, ref, data, before, after = _record()
    rms = rms_per_marker(data, before)
    points, facets = _box_surface()
    drawn = plot_residual_on_body(tmp_path / "b.png", points, facets, ref, rms, noise=2e-5,
                                  names=[f"m{k}" for k in range(5)])
    assert (tmp_path / "b.png").exists()
    np.testing.assert_allclose(drawn["marker_values"], rms / 2e-5)
    assert drawn["worst"] == 3 and drawn["colour_range"][1] == np.nanmax(rms / 2e-5)
    # every surface triangle is coloured, by values between the markers' (a kernel average)
    fv = drawn["facet_values"]
    assert fv.shape == (len(facets),) and np.all(np.isfinite(fv))
    assert np.nanmin(rms / 2e-5) - 1e-9 <= fv.min() and fv.max() <= np.nanmax(rms / 2e-5) + 1e-9
    # the triangles nearest the worst marker are the hottest
    centres = points[facets].mean(axis=1)
    near = np.argmin(np.linalg.norm(centres - ref[3], axis=1))
    far = np.argmin(np.linalg.norm(centres - ref[0], axis=1))
    assert fv[near] > fv[far]


def test_candidates_sorted_on_a_log_axis_with_threshold_and_zero_said(tmp_path):
    from scipy import stats

    scores = [{"physics": "drag.linear", "score": 3.0, "dof": 1},
              {"physics": "damping.mass", "score": 900, "dof": 1},
              {"physics": "friction.dry", "score": 0.0, "dof": 1},
              {"physics": "gravity", "score": 120.0, "dof": 3},
              {"physics": "damping.mass", "score": 40.0, "dof": 1}]     # round 2: largest kept
    drawn = plot_candidates(tmp_path / "c.png", scores, added=["damping.mass"], alpha=0.01)
    assert (tmp_path / "c.png").exists()
    assert drawn["names"] == ["damping.mass", "gravity", "drag.linear", "friction.dry"]
    np.testing.assert_array_equal(drawn["scores"], [900.0, 120.0, 3.0, 0.0])
    assert drawn["zero"] == ["friction.dry"]             # said as 0, not a bar
    assert drawn["added"] == ["damping.mass"]
    # each term's threshold is the chi-square quantile of its dof: 6.63 (1 dof), 11.3 (3)
    assert drawn["thresholds"]["drag.linear"] == pytest.approx(stats.chi2.ppf(0.99, 1))
    assert drawn["thresholds"]["gravity"] == pytest.approx(stats.chi2.ppf(0.99, 3))
    assert drawn["scores"][2] < drawn["thresholds"]["drag.linear"]     # not significant


def test_marker_bars_are_red_only_where_a_marker_stands_out_and_in_mm(tmp_path):
    from petsoft.diagnosis import locate
    from petsoft.diagnosis.report import plot_marker_residuals

    t, ref, data, before, after = _record()
    names = [f"m{k}" for k in range(5)]
    res = locate.marker_residuals(data, before, names, 2e-5)
    drawn = plot_marker_residuals(tmp_path / "m.png", res, 2e-5)
    np.testing.assert_allclose(drawn["rms_mm"], 1e3 * np.nan_to_num(res.rms))
    assert drawn["red"] == ["m3"]                        # the marker with the 15 Hz error
    assert drawn["noise_mm"] == pytest.approx(1e3 * np.sqrt(3) * 2e-5)
    calm = locate.marker_residuals(data, after, names, 2e-5)
    assert plot_marker_residuals(tmp_path / "n.png", calm, 2e-5)["red"] == []


def test_spectra_show_where_each_signal_has_its_energy(tmp_path):
    t, ref, data, before, after = _record()
    drawn = plot_spectra_before_after(tmp_path / "s.png", t, data, before, after,
                                      data_modes=[{"frequency_hz": 5.0}, {"frequency_hz": 0.0}])
    assert drawn["modes_hz"] == [5.0]                   # the recording's modes, dotted
    f = drawn["frequency"]
    peaks = {k: f[1 + int(np.argmax(v[1:]))] for k, v in drawn["spectra"].items()}
    assert abs(peaks["data"] - 5.0) < 0.6 and abs(peaks["as diagnosed"] - 5.0) < 0.6
    before_spec = drawn["spectra"]["model as given"]
    f15 = np.argmin(np.abs(f - 15.0))
    assert before_spec[f15] > 10 * drawn["spectra"]["as diagnosed"][f15]
    # in mm: the 5 Hz motion's amplitudes 4.7 mm x (0.1, 0.3, 1) x (0.2 .. 1.0) over the 15
    # channels, root-sum-square: 4.7 sqrt(1.1 x 2.2) = 7.3 mm (the dropouts filled, the window
    # normalised)
    expected = 4.7 * np.sqrt((0.01 + 0.09 + 1.0) * np.sum(np.linspace(0.2, 1.0, 5) ** 2))
    assert drawn["spectra"]["data"][5] == pytest.approx(expected, rel=0.05)


def test_every_figure_has_a_caption_that_says_what_to_see():
    from petsoft.diagnosis.figures import CAPTIONS
    from petsoft.diagnosis.html import FIGURE_SECTIONS

    placed = {stem for stems in FIGURE_SECTIONS.values() for stem in stems}
    assert placed <= set(CAPTIONS)
    assert "Red bars" in CAPTIONS["residual_markers"] and "0" in CAPTIONS["candidates"]


def test_frequency_figure_draws_the_values_and_their_relative_errors(tmp_path):
    """petsoft calibrate --modes' figure (petsoft.calibration.plots.plot_frequencies)."""
    from petsoft.calibration.plots import plot_frequencies

    measured = np.array([1.5, 4.0, 9.5])
    before, after = 0.8 * measured, measured * (1 + np.array([1e-3, -2e-3, 0.0]))
    drawn = plot_frequencies(tmp_path / "f.png", measured, before, after, std=0.01 * measured)
    assert drawn["path"].read_bytes()[:4] == b"\x89PNG"
    np.testing.assert_array_equal(drawn["modes"], [1, 2, 3])
    np.testing.assert_allclose(drawn["measured"], measured)
    np.testing.assert_allclose(drawn["before"], before)
    np.testing.assert_allclose(drawn["after"], after)
    np.testing.assert_allclose(drawn["relative"]["before"], -0.2)
    np.testing.assert_allclose(drawn["relative"]["calibrated"], [1e-3, -2e-3, 0.0], atol=1e-15)


def test_demo_deflection_figure_draws_the_side_view_coloured_by_displacement(tmp_path):
    """The demo's figure (petsoft.cli.commands.plot_deflection): reference and deformed points
    in the x-z plane, the deformed ones coloured by |u|."""
    from petsoft.cli.commands import plot_deflection
    from petsoft.mesh.serial import box_mesh

    mesh = box_mesh([0.4, 0.04, 0.04], [4, 1, 1])
    x = mesh.points[:, 0]
    u = np.column_stack([-0.1 * x ** 2, 0.01 * x, -0.5 * x ** 2])     # a sag
    drawn = plot_deflection(mesh, u, tmp_path / "d.png")
    assert drawn["path"].read_bytes()[:4] == b"\x89PNG"
    np.testing.assert_allclose(drawn["reference"], mesh.points[:, [0, 2]])
    np.testing.assert_allclose(drawn["deformed"], (mesh.points + u)[:, [0, 2]])
    np.testing.assert_allclose(drawn["colour"], np.linalg.norm(u, axis=1))
