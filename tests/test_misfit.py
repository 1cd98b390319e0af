"""The spectral (Cramér) misfit: exact linearisation and transpose, phase robustness, and the
calibration with it (adjoint gradient through it, l2 polish)."""

import numpy as np
import pytest

from petsoft.calibration.misfit import SpectralMisfit
from petsoft.errors import ExperimentError


def signals(w, s=0.0, K=120):
    t = np.linspace(0.0, 10.0, K)
    base = np.sin(w * (t - s)) * np.exp(-0.05 * t)
    return np.stack([base, 0.3 * base + 0.1 * np.cos(2 * w * t)], axis=1)[:, :, None] * [
        1.0, 0.5, 0.2]


def test_taylor_and_transpose():
    rng = np.random.default_rng(0)
    m = SpectralMisfit(signals(2.0))
    sim = signals(2.3, 0.4) + 0.01 * rng.standard_normal((120, 2, 3))
    d = rng.standard_normal(sim.shape)
    r0 = m.residual(sim)
    J = m.jvp(sim, d[..., None])[:, 0]
    errs = [np.linalg.norm(m.residual(sim + h * d) - r0 - h * J) for h in (1e-3, 5e-4, 2.5e-4)]
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(rates > 1.9), (errs, rates)
    v = rng.standard_normal(r0.shape)
    assert np.isclose(v @ J, np.sum(m.vjp(sim, v) * d), rtol=1e-10)
    # the gradient of 1/2 |r|^2 against a central difference of the value
    f, g = m.value_gradient(sim)
    h = 1e-6
    fd = (0.5 * np.sum(m.residual(sim + h * d) ** 2) - 0.5 * np.sum(m.residual(sim - h * d) ** 2))
    assert np.isclose(fd / (2 * h), np.sum(g * d), rtol=1e-6)


def test_phase_blind_and_monotone_in_frequency():
    m = SpectralMisfit(signals(2.0))
    # a shift of the phase barely changes it; l2 would be of the order of the signal
    assert np.sum(m.residual(signals(2.0, 0.7)) ** 2) < 1e-2 * np.sum(
        m.residual(signals(3.0)) ** 2)
    values = [np.sum(m.residual(signals(w)) ** 2) for w in np.linspace(2.0, 4.0, 41)]
    assert np.all(np.diff(values) > 0), values      # no ripple: one basin
    l2 = [np.sum((signals(w) - signals(2.0)) ** 2) for w in np.linspace(2.0, 4.0, 41)]
    assert np.any(np.diff(l2) < 0)                  # while l2 has local minima there


def test_bad_input():
    data = signals(2.0)
    data[3, 0, 0] = np.nan
    with pytest.raises(ExperimentError, match="every marker seen"):
        SpectralMisfit(data)
    with pytest.raises(ExperimentError, match="zero power"):
        SpectralMisfit(np.ones((10, 1, 3)))


def _bench():
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "benchmarks" / "bench_basin.py"
    spec = importlib.util.spec_from_file_location("bench_basin", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("bench_basin", module)
    spec.loader.exec_module(module)
    return module


def test_adjoint_gradient_through_the_spectral_misfit():
    """d/dE of the spectral misfit by the adjoint equals a central difference (Taylor)."""
    l2, spec, scaling, E_true = _bench().body_problem(end=0.3)
    z = scaling.to_scaled(np.array([1.3 * E_true]))
    f, g = spec.value_gradient(z)
    h = 1e-5
    fd = (spec.value(z + h) - spec.value(z - h)) / (2 * h)
    assert np.isclose(g[0], fd, rtol=1e-5), (g, fd)
    # and the Gauss-Newton Jacobian (sensitivities through jvp) agrees with the adjoint
    r, J = spec.residual_jacobian(z)
    assert np.isclose(J[:, 0] @ r, g[0], rtol=1e-8)
    l2.forward.destroy()


@pytest.mark.serial_only   # 2.5 s serially, 30 s on 2 ranks (loaded machine): once is enough
def test_spectral_calibration_from_2x_off(tmp_path):
    """E started 2x too low: l2 stops in a wrong basin, spectral + l2 polish reaches the
    truth (the l2 minimiser of noise-free data)."""
    from petsoft.calibration.calibrate import run_calibration
    from petsoft.experiment import load_experiment

    text, rec = _bench().body_case(end=1.0)
    (tmp_path / "body.toml").write_text(text.replace("youngs_modulus = 1000000.0",
                                                     "youngs_modulus = 500000.0"))
    exp = load_experiment(tmp_path / "body.toml")
    wide = run_calibration(exp, rec, misfit="spectral", noise=1e-3)
    assert abs(wide.values[0] / 1e6 - 1) < 1e-5, wide.values
    plain = run_calibration(exp, rec, noise=1e-3)
    assert abs(plain.values[0] / 1e6 - 1) > 0.05, plain.values
