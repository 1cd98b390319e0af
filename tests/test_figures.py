"""The diagnosis' figures (petsoft.diagnosis.figures): each checked on the data it drew."""

from __future__ import annotations

import numpy as np

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


def test_residual_on_body_colours_each_marker_by_its_residual_over_the_noise(tmp_path):
    t, ref, data, before, after = _record()
    rms = rms_per_marker(data, before)
    surface = np.random.default_rng(1).uniform([0, 0, 0], [0.3, 0.04, 0.02], (400, 3))
    drawn = plot_residual_on_body(tmp_path / "b.png", surface, ref, rms, noise=2e-5)
    assert (tmp_path / "b.png").stat().st_size > 10_000
    np.testing.assert_allclose(drawn["values"], rms / 2e-5)
    assert int(np.argmax(drawn["values"])) == 3
    assert drawn["views"] == [(0, 1), (0, 2)]          # the body's longest axes first
    assert drawn["colour_range"][1] == np.nanmax(rms / 2e-5)


def test_candidates_sorted_on_a_log_axis_with_the_added_ones_marked(tmp_path):
    scores = [{"physics": "drag.linear", "score": 3.0}, {"physics": "damping.mass", "score": 900},
              {"physics": "friction.dry", "score": 0.0},
              {"physics": "material.viscoelastic", "score": 120.0},
              {"physics": "damping.mass", "score": 40.0}]     # round 2: the largest is kept
    drawn = plot_candidates(tmp_path / "c.png", scores, added=["damping.mass"])
    assert (tmp_path / "c.png").exists()
    assert drawn["names"] == ["damping.mass", "material.viscoelastic", "drag.linear",
                              "friction.dry"]
    assert np.all(np.diff(drawn["scores"]) <= 0) and np.all(drawn["scores"] > 0)
    assert drawn["added"] == ["damping.mass"]


def test_spectra_show_where_each_signal_has_its_energy(tmp_path):
    t, ref, data, before, after = _record()
    drawn = plot_spectra_before_after(tmp_path / "s.png", t, data, before, after)
    f = drawn["frequency"]
    peaks = {k: f[1 + int(np.argmax(v[1:]))] for k, v in drawn["spectra"].items()}
    assert abs(peaks["data"] - 5.0) < 0.6 and abs(peaks["as diagnosed"] - 5.0) < 0.6
    before_spec = drawn["spectra"]["model as given"]
    f15 = np.argmin(np.abs(f - 15.0))
    assert before_spec[f15] > 10 * drawn["spectra"]["as diagnosed"][f15]


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
