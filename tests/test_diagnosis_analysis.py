"""Mismatch analysis on arrays (petsoft.diagnosis): noise, localisation, modes, report.

Every check plants a known truth in synthetic arrays (a frequency, a decay rate, a noise level,
a mismatch at a point or in a time window, a friction law) and asks the analysis to find it.
Arrays only: no PETSc, so each rank of a 2-rank run does the same independent work.
"""

import json
import math

import numpy as np
import pytest
from scipy.spatial import Delaunay

from petsoft.diagnosis import locate, noise, report, spectral
from petsoft.errors import PetsoftError


def damped(t, f, d, phase, amp=1.0):
    return amp * np.exp(-d * t) * np.cos(2 * np.pi * f * t + phase)


def grid_markers(n=6, h=0.02):
    g = np.arange(n) * h
    x, y = np.meshgrid(g, g, indexing="ij")
    ref = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    return ref, [f"m{i:02d}" for i in range(n * n)]


# ------------------------------------------------------------------------------------ spectral

@pytest.mark.parametrize("seed", [0, 1])
def test_modes_of_damped_sinusoids_with_noise_and_dropouts(seed):
    rng = np.random.default_rng(seed)
    t = np.arange(1500) * 0.002
    modes = [(3.7, 0.8, 0.01), (11.3, 2.5, 0.004)]     # (Hz, 1/s, amplitude)
    m = 5
    x = np.zeros((len(t), m, 3))
    amps = [a * rng.uniform(0.5, 1.0, (m, 3)) for _, _, a in modes]
    amp37 = amps[0]
    for (f, d, _), a in zip(modes, amps, strict=True):
        x += damped(t[:, None, None], f, d, rng.uniform(0, 2 * np.pi, (m, 3)), a)
    x += rng.normal(0, 1e-4, x.shape)
    x[rng.random((len(t), m)) < 0.05] = np.nan
    found = [q for q in spectral.dominant_modes(t, x) if q["frequency_hz"] > 0]
    assert len(found) >= 2
    freqs = sorted(q["frequency_hz"] for q in found)
    assert np.all(np.diff(freqs) > 1e-6)                   # each conjugate pair reported once
    for f, d, _ in modes:
        best = min(found, key=lambda q: abs(q["frequency_hz"] - f))
        assert abs(best["frequency_hz"] / f - 1) < 0.005
        assert abs(best["decay_rate"] / d - 1) < 0.02
    assert found[0]["frequency_hz"] == pytest.approx(3.7, rel=0.005)   # largest first
    # The amplitude is the norm over channels of the cosine amplitudes at t = 0.
    assert found[0]["amplitude"] == pytest.approx(np.linalg.norm(amp37), rel=0.02)


def test_no_modes_in_pure_noise():
    rng = np.random.default_rng(0)
    t = np.arange(300) * 0.01
    assert spectral.dominant_modes(t, rng.normal(size=(300, 4, 3))) == []
    assert spectral.dominant_modes(t, rng.normal(size=(300, 1))) == []


def test_modes_need_uniform_times():
    t = np.sort(np.random.default_rng(0).uniform(0, 1, 100))
    with pytest.raises(spectral.SpectralError, match="uniformly sampled"):
        spectral.dominant_modes(t, np.sin(t)[:, None])


def test_compare_modes_reports_damping_and_stiffness_hints():
    t = np.arange(2000) * 0.005
    data = damped(t, 2.0, 0.5, 0.3)[:, None]
    sim = damped(t, 2.2, 0.05, 0.3)[:, None]
    cmp = spectral.compare_modes(spectral.dominant_modes(t, data),
                                 spectral.dominant_modes(t, sim))
    (m,) = cmp["matched"]
    assert m["frequency_shift_hz"] == pytest.approx(-0.2, abs=2e-3)
    assert m["decay_shift"] == pytest.approx(0.45, rel=0.02)
    text = " ".join(cmp["hints"])
    assert "missing damping" in text and "stiffness or mass" in text


@pytest.mark.parametrize("alpha,beta,expected", [(0.6, 0.0, "damping.mass"),
                                                 (0.0, 2e-4, "damping.stiffness")])
def test_rayleigh_split_of_decay_shifts(alpha, beta, expected):
    # Two-mode free vibration; the data has Rayleigh damping, the simulation none.
    rng = np.random.default_rng(6)
    t = np.arange(4000) * 0.002
    fs = np.array([3.0, 9.0])
    d = (alpha + beta * (2 * np.pi * fs) ** 2) / 2
    phases = rng.uniform(0, 2 * np.pi, (2, 4))
    data = sum(damped(t[:, None], f, dd, phases[i]) for i, (f, dd) in enumerate(zip(fs, d,
                                                                                strict=True)))
    sim = sum(damped(t[:, None], f, 0.0, phases[i]) for i, f in enumerate(fs))
    cmp = spectral.compare_modes(spectral.dominant_modes(t, data), spectral.dominant_modes(t, sim))
    split = spectral.rayleigh_from_decays(cmp["matched"])
    assert split["dominant"] == expected
    assert split["alpha"] == pytest.approx(alpha, abs=0.01)
    assert split["beta"] == pytest.approx(beta, abs=2e-6)


@pytest.mark.parametrize("law,expected", [("exp", "exponential"), ("lin", "linear"),
                                          ("inv", "inverse")])
def test_envelope_classification(law, expected):
    rng = np.random.default_rng(3)
    t = np.arange(3000) * 0.005                            # 15 s at 1.5 Hz, 22 cycles
    amp = {"exp": np.exp(-0.12 * t), "lin": 1 - 0.05 * t, "inv": 1 / (1 + 0.35 * t)}[law]
    y = np.outer(amp * np.cos(2 * np.pi * 1.5 * t), [1.0, 0.5])      # two channels, one mode
    y += 0.2 + rng.normal(0, 0.003, y.shape)               # offset must not matter
    env = spectral.decay_envelope(t, y)
    assert env["best"] == expected
    assert env["ratio"] > 3
    p = {"exp": 1.0, "lin": 0.0, "inv": 2.0}[law]
    assert abs(env["exponent_p"] - p) < 0.3


def test_envelope_recovers_the_viscous_rate():
    t = np.arange(4000) * 0.005
    env = spectral.decay_envelope(t, damped(t, 1.3, 0.07, 1.0))
    assert env["fits"]["exponential"]["rate"] == pytest.approx(0.07, rel=0.01)


# --------------------------------------------------------------------------------------- noise

def test_noise_estimate_smooth_signal_with_dropouts():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 5, 1000)
    m = 6
    clean = 0.05 * np.sin(2 * np.pi * 1.3 * t[:, None, None] + rng.uniform(0, 6, (m, 3)))
    clean += 0.02 * t[:, None, None] ** 2                  # a drift: polynomial, annihilated
    for sigma in (1e-4, 1e-3):
        x = clean + rng.normal(0, sigma, clean.shape)
        x[rng.random((len(t), m)) < 0.1] = np.nan
        est, each = noise.estimate_noise_std(x, t, per_channel=True)
        assert est == pytest.approx(sigma, rel=0.05)
        assert each.shape == (3 * m,) and np.all(np.abs(each / sigma - 1) < 0.25)


def test_noise_estimate_nonuniform_times():
    rng = np.random.default_rng(1)
    t = np.sort(rng.uniform(0, 5, 2000))
    x = 0.05 * np.sin(2 * np.pi * 1.3 * t) + rng.normal(0, 2e-4, len(t))
    assert noise.estimate_noise_std(x, t) == pytest.approx(2e-4, rel=0.05)


def test_noise_estimate_errors():
    t = np.linspace(0, 1, 5)
    with pytest.raises(noise.NoiseError, match="windows"):
        noise.estimate_noise_std(np.zeros(5), t)
    with pytest.raises(noise.NoiseError, match="first dimension"):
        noise.estimate_noise_std(np.zeros((6, 3)), t)


def test_chi_square_false_alarm_rate_is_near_alpha():
    rng = np.random.default_rng(7)
    alpha, trials = 0.05, 1500
    flags = np.array([[not r.consistent, not r.level_ok, not r.white_ok]
                      for r in (noise.chi_square_test(rng.normal(0, 2.0, (80, 3, 3)), 2.0,
                                                      alpha=alpha) for _ in range(trials))])
    rate, level, white = flags.mean(axis=0)
    sd = math.sqrt(alpha * (1 - alpha) / trials)
    assert abs(rate - alpha) < 3.5 * sd                    # Bonferroni: <= alpha, close to it
    assert abs(level - alpha / 2) < 3.5 * sd and abs(white - alpha / 2) < 3.5 * sd


def test_chi_square_detects_small_smooth_residual_that_the_level_misses():
    rng = np.random.default_rng(11)
    t = np.linspace(0, 2, 150)[:, None, None]
    level_miss = detect = 0
    for _ in range(50):
        r = rng.normal(0, 1, (150, 4, 3)) + 0.5 * np.sin(2 * np.pi * t + rng.uniform(0, 6, (4, 3)))
        res = noise.chi_square_test(r, 1.0, num_parameters=3)
        detect += not res.consistent
        level_miss += res.level_ok
    assert detect >= 48            # measured 50/50
    assert level_miss >= 3         # the level alone misses some (measured ~8/50)


def test_chi_square_input_errors():
    with pytest.raises(noise.NoiseError, match="sigma"):
        noise.chi_square_test(np.ones((5, 2, 3)), 0.0)
    with pytest.raises(noise.NoiseError, match="degrees"):
        noise.chi_square_test(np.ones((1, 1, 3)), 1.0, num_parameters=3)


# ------------------------------------------------------------------------------------- locate

def planted_point(seed=0, sigma=1e-4):
    rng = np.random.default_rng(seed)
    ref, names = grid_markers()
    t = np.linspace(0, 2, 200)
    sim = ref[None] + 0.01 * np.sin(2 * np.pi * t)[:, None, None] * np.array([0, 0, 1.0])
    point = np.array([0.062, 0.035, 0.0])
    weight = np.exp(-np.sum((ref - point) ** 2, axis=1) / (2 * 0.012**2))
    extra = 8 * sigma * weight[None, :, None] * np.sin(2 * np.pi * 3 * t)[:, None, None]
    data = sim + extra + rng.normal(0, sigma, sim.shape)
    data[rng.random((len(t), len(names))) < 0.05] = np.nan
    return ref, names, t, data, sim, point, sigma, weight


def test_planted_marker_mismatch_is_flagged_and_located(tmp_path):
    import meshio

    ref, names, t, data, sim, point, sigma, weight = planted_point()
    res = locate.marker_residuals(data, sim, names, sigma)
    flagged = [names.index(n) for n in res.flagged_names]
    dist = np.linalg.norm(ref - point, axis=1)
    assert res.flagged_names[0] == names[np.argmin(dist)]      # worst first
    assert np.all(res.flagged[weight > 0.3])                    # planted >= 2.4 sigma: found
    assert not res.flagged[weight < 0.01].any()                 # planted < 0.08 sigma: quiet
    region = locate.mismatch_region(ref, res)
    spacing = locate.marker_spacing(ref)
    assert spacing == pytest.approx(0.02)
    assert np.linalg.norm(np.array(region["center"]) - point) < spacing
    assert region["radius"] >= np.max(np.linalg.norm(ref[flagged] - region["center"], axis=1))
    # Nodal field on a tetrahedral mesh of the plate, thickened: largest near the point.
    g = np.linspace(-0.01, 0.11, 7)
    pts = np.array(np.meshgrid(g, g, [-0.01, 0.01], indexing="ij")).reshape(3, -1).T
    tets = Delaunay(pts).simplices
    path = locate.write_residual_field(tmp_path / "residual.xdmf", pts, tets, ref, res)
    mesh = meshio.read(path)
    field = mesh.point_data["residual_rms"]
    assert field.shape == (len(pts),)
    assert np.linalg.norm(pts[np.argmax(field)][:2] - point[:2]) < 2 * spacing
    assert field.min() >= np.nanmin(res.rms) - 1e-15 and field.max() <= np.nanmax(res.rms)


def test_uniform_mismatch_flags_no_single_marker():
    rng = np.random.default_rng(2)
    ref, names = grid_markers()
    sim = np.zeros((100, len(names), 3))
    data = sim + 5e-4 * np.sin(np.linspace(0, 6, 100))[:, None, None] \
        + rng.normal(0, 1e-4, sim.shape)
    res = locate.marker_residuals(data, sim, names, 1e-4)
    assert res.exceeds_noise.all() and not res.flagged.any()
    assert locate.mismatch_region(ref, res) is None


def test_planted_time_window_is_found():
    rng = np.random.default_rng(4)
    sigma = 2e-4
    t = np.linspace(0, 3, 601)
    sim = np.zeros((len(t), 8, 3))
    inside = (t >= 0.8) & (t <= 1.4)
    data = sim + rng.normal(0, sigma, sim.shape)
    data[inside] += 1.5 * sigma * np.sin(2 * np.pi * 5 * t[inside])[:, None, None]
    data[rng.random((len(t), 8)) < 0.05] = np.nan
    win = locate.mismatch_time_windows(data, sim, t, sigma, window=0.1)
    assert len(win["intervals"]) == 1
    (t0, t1), = win["intervals"]
    assert abs(t0 - 0.8) < 0.1 and abs(t1 - 1.4) < 0.1
    quiet = locate.mismatch_time_windows(sim + rng.normal(0, sigma, sim.shape), sim, t, sigma)
    assert quiet["intervals"] == []


def test_locate_input_errors():
    with pytest.raises(locate.LocateError, match=r"\(K, M, 3\)"):
        locate.marker_residuals(np.zeros((4, 2, 3)), np.zeros((4, 3, 3)), ["a", "b"])
    with pytest.raises(locate.LocateError, match="names"):
        locate.marker_residuals(np.zeros((4, 2, 3)), np.zeros((4, 2, 3)), ["a"])
    with pytest.raises(locate.LocateError, match="sigma"):
        locate.mismatch_time_windows(np.zeros((4, 2, 3)), np.zeros((4, 2, 3)), np.arange(4.0),
                                     None)


# ------------------------------------------------------------------------------------- report

def example_report():
    return report.build_report(
        verdict="missing-physics", noise_std=4e-4,
        base={"rms": 0.0061, "chi2_per_dof": 230.0}, final={"rms": 4.2e-4, "chi2_per_dof": 1.1},
        validation={"base_rms": 0.007, "final_rms": 4.9e-4},
        markers=["m07", "m12"], time_windows=[(0.8, 1.4)], frequencies_hz=[np.float64(12.5)],
        region={"center": np.array([0.3, 0.0, 0.02]), "radius": 0.012},
        added=[{"physics": "damping.mass", "parameters": {"damping.mass": 1.93},
                "std": {"damping.mass": 0.05}, "score": 812.0, "rms_after": 4.2e-4,
                "evidence": "exponential amplitude decay in all markers"}],
        rejected=[{"physics": "drag.quadratic", "score": 3.1,
                   "reason": "no significant improvement"}],
        parameters={"material.youngs_modulus": 1.02e6})


def test_report_round_trip_matches_formats_md(tmp_path):
    rep = example_report()
    path = report.write_report(tmp_path / "report.json", rep)
    back = json.loads(path.read_text())
    assert back == rep and report.read_report(path) == rep
    assert list(back) == ["format", "version", "verdict", "noise_std", "fit", "mismatch",
                          "added", "rejected", "parameters"]
    assert back["mismatch"]["region"] == {"center": [0.3, 0.0, 0.02], "radius": 0.012}
    assert not list(tmp_path.glob(".*"))                   # no temporary left behind


def _mutate(rep, path, value):
    obj = rep
    for key in path[:-1]:
        obj = obj[key]
    if value is KeyError:
        del obj[path[-1]]
    else:
        obj[path[-1]] = value


@pytest.mark.parametrize("path,value,message", [
    (("format",), "petsoft-report", "'format'"),
    (("version",), 2, "'version'"),
    (("verdict",), "maybe", "'verdict'.*consistent, missing-physics"),
    (("noise_std",), float("nan"), "'noise_std'.*finite"),
    (("noise_std",), 0.0, "'noise_std'.*> 0"),
    (("fit", "final", "rms"), KeyError, "'fit.final'.*missing rms"),
    (("fit", "base", "chi2_per_dof"), "230", "'fit.base.chi2_per_dof'.*number"),
    (("fit", "validation", "extra"), 1.0, "'fit.validation'.*unknown extra"),
    (("mismatch", "time_windows"), [[1.4, 0.8]], r"'mismatch.time_windows\[0\]'.*before"),
    (("mismatch", "time_windows"), [[0.8]], r"'mismatch.time_windows\[0\]'.*pair"),
    (("mismatch", "markers"), ["m07", "m07"], "'mismatch.markers'.*twice"),
    (("mismatch", "region", "center"), [0.0, 1.0], "'mismatch.region.center'"),
    (("mismatch", "frequencies_hz"), [-1.0], r"'mismatch.frequencies_hz\[0\]'.*>= 0"),
    (("added", 0, "physics"), "damping.magic", r"'added\[0\].physics'.*vocabulary"),
    (("added", 0, "std"), {"gravity": 0.1}, r"'added\[0\].std'.*gravity"),
    (("added", 0, "evidence"), "", r"'added\[0\].evidence'.*non-empty"),
    (("rejected", 0, "reason"), KeyError, r"'rejected\[0\]'.*missing reason"),
    (("parameters", "material.youngs_modulus"), float("inf"),
     "'parameters.material.youngs_modulus'.*finite"),
    (("surprise",), 1, r"'\(report\)'.*unknown surprise"),
])
def test_report_validation_rejects_malformed(path, value, message):
    rep = example_report()
    _mutate(rep, path, value)
    with pytest.raises(report.ReportError, match=message):
        report.validate_report(rep)
    assert issubclass(report.ReportError, PetsoftError)


def test_report_optional_validation_and_null_region_are_valid():
    rep = example_report()
    del rep["fit"]["validation"]
    rep["mismatch"]["region"] = None
    report.validate_report(rep)


def test_report_markdown_and_figures(tmp_path):
    ref, names, t, data, sim, point, sigma, _ = planted_point()
    res = locate.marker_residuals(data, sim, names, sigma)
    win = locate.mismatch_time_windows(data, sim, t, sigma)
    test = noise.chi_square_test(data - sim, sigma)
    rep = example_report()
    figs = [
        report.plot_marker_residuals(tmp_path / "markers.png", res, sigma)["path"],
        report.plot_residual_time(tmp_path / "time.png", t, win)["path"],
        report.plot_spectra(tmp_path / "spectra.png", t, data, sim,
                            spectral.dominant_modes(t, data), spectral.dominant_modes(t, sim)),
    ]
    for f in figs:
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = report.write_report_md(tmp_path / "report.md", rep, {"noise_test": test},
                                [f.name for f in figs]).read_text()
    assert "missing physics" in md and "m07, m12" in md and "damping.mass" in md
    assert "0.8-1.4 s" in md and "](markers.png)" in md and "Whiteness" in md


def test_envelope_mixed_viscous_and_dry_law():
    # dA/dt = -a A - c in closed form: the mixed fit recovers a and c.
    t = np.arange(4000) * 0.005
    a, c = 0.08, 0.01
    amp = (1 + c / a) * np.exp(-a * t) - c / a
    env = spectral.decay_envelope(t, amp * np.cos(2 * np.pi * 1.2 * t))
    both = env["viscous_plus_dry"]
    assert both["rate"] == pytest.approx(a, rel=0.03) and both["dry"] == pytest.approx(c, rel=0.05)
    assert both["dry_share_end"] > both["dry_share_start"]


def test_noise_scales_on_heavy_tailed_noise_and_constant_channels():
    rng = np.random.default_rng(8)
    t = np.linspace(0, 4, 4000)
    smooth = 0.1 * np.sin(2 * np.pi * 0.7 * t)
    # Contaminated normal: 10% of samples 3x noisier; std 1e-4, kurtosis 8.3.
    scale = np.where(rng.random((len(t), 2)) < 0.1, 3.0, 1.0) * 1e-4 / np.sqrt(1.8)
    x = np.column_stack([smooth[:, None] + scale * rng.normal(size=scale.shape),
                         np.zeros(len(t))])                        # the 3rd never varies
    assert noise.estimate_noise_std(x, t, scale="rms") == pytest.approx(1e-4, rel=0.05)
    summary = noise.noise_summary(x, t)
    assert summary["std_rms"] > summary["std_mad"] and not summary["gaussian"]
    assert summary["kurtosis"] == pytest.approx(3 * 9 / 1.8**2, rel=0.2)   # the noise's own
    gauss = noise.noise_summary(smooth[:, None] + rng.normal(0, 1e-4, (len(t), 2)), t)
    assert gauss["gaussian"] and gauss["std_mad"] == pytest.approx(1e-4, rel=0.05)
    # The constant channel is left out: otherwise a third of the pool is zeros.
    with_zero = noise.estimate_noise_std(np.column_stack([gauss_x := smooth + rng.normal(
        0, 1e-4, len(t)), np.zeros(len(t))]), t)
    assert with_zero == pytest.approx(noise.estimate_noise_std(gauss_x, t), rel=1e-12)


def test_friction_terms_separate_dry_and_quadratic():
    # -dA/dt = c0 + c2 A^2 in closed form: A = sqrt(c0/c2) tan(atan(A0 sqrt(c2/c0)) - sqrt(c0 c2) t)
    c0, c2 = 0.01, 0.03
    t = np.arange(6000) * 0.005
    r = np.sqrt(c0 / c2)
    amp = r * np.tan(np.arctan(1.5 / r) - np.sqrt(c0 * c2) * t)
    assert amp[-1] > 0.2
    env = spectral.decay_envelope(t, amp * np.cos(2 * np.pi * 1.2 * t))
    terms = spectral.friction_terms(env)
    assert terms["best"] == "dry+quadratic"
    coef = terms["subsets"]["dry+quadratic"]["coefficients"]
    assert coef["dry"] == pytest.approx(c0, rel=0.05)
    assert coef["quadratic"] == pytest.approx(c2, rel=0.05)
    viscous = spectral.friction_terms(spectral.decay_envelope(t, damped(t, 1.2, 0.05, 0.0)))
    assert viscous["best"] == "viscous"
    assert viscous["coefficients"]["viscous"] == pytest.approx(0.05, rel=0.02)


# ----------------------------------------------------------------------------------- evidence

def test_collect_evidence_planted_point_to_valid_report(tmp_path):
    from petsoft.diagnosis import evidence

    ref, names, t, data, sim, point, sigma, _ = planted_point()
    g = np.linspace(-0.01, 0.11, 5)
    pts = np.array(np.meshgrid(g, g, [-0.01, 0.01], indexing="ij")).reshape(3, -1).T
    ev = evidence.collect_evidence(data, sim, t, ref, names, points=pts,
                                   tets=Delaunay(pts).simplices, out=tmp_path)
    assert ev.noise_std == pytest.approx(sigma, rel=0.1)        # estimated: no sigma given
    assert ev.verdict == "missing-physics"
    assert ev.mismatch["markers"][0] == names[np.argmin(np.linalg.norm(ref - point, axis=1))]
    assert np.linalg.norm(np.array(ev.region["center"]) - point) < 0.02
    assert any(abs(f - 3.0) < 0.03 for f in ev.frequencies_hz)  # the planted 3 Hz
    assert ev.field.exists()
    figs = evidence.write_figures(tmp_path, ev, t, data, sim)
    assert all(f.exists() for f in figs)
    rep = report.build_report(verdict=ev.verdict, noise_std=ev.noise_std, base=ev.fit,
                              final=ev.fit, parameters={}, **ev.mismatch)
    report.write_report(tmp_path / "report.json", rep)
    md = report.write_report_md(tmp_path / "report.md", rep, ev.as_report(),
                                [f.name for f in figs])
    assert "Markers that stand out" in md.read_text()


def test_collect_evidence_on_pure_noise_is_consistent():
    from petsoft.diagnosis import evidence

    rng = np.random.default_rng(9)
    ref, names = grid_markers(4)
    t = np.linspace(0, 2, 200)
    sim = ref[None] + 0.01 * np.sin(2 * np.pi * t)[:, None, None]
    data = sim + rng.normal(0, 1e-4, sim.shape)
    ev = evidence.collect_evidence(data, sim, t, ref, names, sigma=1e-4)
    assert ev.verdict == "consistent" and ev.noise_source == "given by the recording"
    assert ev.mismatch == {"markers": [], "time_windows": [], "frequencies_hz": [],
                              "region": None}
    assert ev.fit["chi2_per_dof"] == pytest.approx(1.0, abs=0.05)


# --------------------------------------------------------------------------- the real pendulum

@pytest.mark.serial_only      # runs two scripts in subprocesses
def test_pendulum_envelope_script(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    script = root / "scripts" / "examples" / "pendulum_envelope.py"
    run = subprocess.run([sys.executable, str(script),
                          "--dir", str(tmp_path / "rec"), "--out", str(tmp_path / "env")],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    res = json.loads((tmp_path / "env" / "envelope.json").read_text())
    assert (tmp_path / "env" / "envelope.png").exists()
    # The control is the published viscous model: the analysis must call it viscous.
    control = res["published viscous model (control)"]
    assert control["envelope_angle"]["best"] == "exponential"
    coef = control["friction_terms_angle"]["coefficients"]
    assert coef["viscous"] > 5 * coef["dry"]
    # The data: the small-amplitude half decays linearly (the finding the report states).
    assert res["validation"]["envelope_angle"]["best"] == "linear"
    assert res["whole swing"]["friction_terms_angle"]["coefficients"]["dry"] > 5 * coef["dry"]
    # The evidence chain against the published (viscous) model: dry friction first, and no
    # gravity from the amplitude-driven drift of the vertical coordinate's mean.
    chain = res["evidence vs published model"]["validation"]
    names = [c["physics"] for c in chain["suggestions"]]
    assert names[0] == "friction.dry" and "gravity" not in names



def free_decay_markers(amp, t, rng, sigma=1e-5):
    """Three markers swinging in x with the given amplitude envelope, plus noise."""
    ref = np.array([[0.0, 0, 0], [0.05, 0, 0], [0.1, 0, 0]])
    x = np.zeros((len(t), 3, 3)) + ref
    x[:, :, 0] += 0.01 * np.outer(amp * np.cos(2 * np.pi * 1.5 * t), [0.5, 1.0, 1.5])
    return x + rng.normal(0, sigma, x.shape), ref


@pytest.mark.parametrize("law,first", [("dry", "friction.dry"), ("viscous", "damping.mass"),
                                       ("quadratic", "drag.quadratic")])
def test_suggest_physics_from_a_missing_friction(law, first):
    from petsoft.diagnosis import evidence

    rng = np.random.default_rng(12)
    t = np.arange(3000) * 0.005
    amp = {"dry": 1 - 0.05 * t, "viscous": np.exp(-0.12 * t),
           "quadratic": 1 / (1 + 0.35 * t)}[law]
    data, ref = free_decay_markers(amp, t, rng)
    sim, _ = free_decay_markers(np.ones_like(t), t, rng, 0.0)      # the undamped model
    ev = evidence.collect_evidence(data, sim, t, ref, ["a", "b", "c"], sigma=1e-5)
    names = [c["physics"] for c in evidence.suggest_physics(ev)]
    assert names[0] == first


def test_suggest_physics_gravity_offset_and_nothing_for_noise():
    from petsoft.diagnosis import evidence

    rng = np.random.default_rng(13)
    t = np.arange(400) * 0.005
    sim, ref = free_decay_markers(np.exp(-0.1 * t), t, rng, 0.0)
    data = sim + rng.normal(0, 1e-5, sim.shape)
    ev = evidence.collect_evidence(data, sim, t, ref, ["a", "b", "c"], sigma=1e-5)
    assert evidence.suggest_physics(ev) == []
    data[:, :, 2] -= 5e-5                                          # sags: stronger gravity
    ev = evidence.collect_evidence(data, sim, t, ref, ["a", "b", "c"], sigma=1e-5)
    top = evidence.suggest_physics(ev)[0]
    assert top["physics"] == "gravity" and "along z" in top["reason"]
