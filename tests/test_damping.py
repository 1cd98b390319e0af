"""Artificial damping (petsoft.dynamics.damping_analysis, `petsoft damping`).

1. Analytic: the BE/SI propagator's spectral radius against the lecture's closed form
   d/w = ln(1 + (tau w)^2)/(tau w); generalized alpha's rho -> 1 (tau w -> 0) and -> r
   (tau w -> inf) for r = 0, .25, .5, .75, 1; |mu| = 1 of midpoint/trapezoidal and of the explicit
   schemes below tau w = 2.
2. The fit of the one-step map recovers a known spectral radius from a trajectory.
3. Measured (petsoft's integrators on undamped oscillators) against analytic at tau w = 0.1, 1, 10.
4. FEM: the per-mode damping of BE (and alpha, midpoint) on a small linear bar.
5. The CLI end to end (serial only).

Every test but the CLI runs collectively (serially and under ``mpiexec -n 2``); ``pytest -s``
prints the measured tables.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from child_process import child_env  # tests/child_process.py
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.dynamics import damping_analysis as D
from petsoft.dynamics.alpha import alpha_parameters
from petsoft.experiment import experiment_from_dict
from petsoft.physics.model import build_model

serial_only = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns processes")
RADII = (0.0, 0.25, 0.5, 0.75, 1.0)


def _print(*args):
    if PETSc.COMM_WORLD.getRank() == 0:
        print(*args)


# -- analytic ------------------------------------------------------------------------------------
def test_be_spectral_radius_is_the_lecture_formula():
    """rho(T_BE) = 1/sqrt(1 + (tau w)^2), the eigenvalues are 1/(1 +- i tau w), and
    d/w = -2 ln(rho)/(tau w) = ln(1 + (tau w)^2)/(tau w), all to round-off."""
    x = np.logspace(-3, 3, 61)
    T = D.be_propagator(x)
    mu = np.linalg.eigvals(T)
    mu = mu[np.arange(len(x)), np.argsort(mu.imag, axis=1)[:, 1]]     # the root with Im > 0
    np.testing.assert_allclose(mu, 1.0 / (1.0 - 1j * x), rtol=1e-14)
    rho = D.analytic_rho(D.Scheme("be"), x)
    np.testing.assert_allclose(rho, 1.0 / np.sqrt(1.0 + x**2), rtol=1e-14)
    np.testing.assert_allclose(D.damping_ratio(rho, x), D.be_damping_ratio(x), rtol=1e-9,
                               atol=1e-15)
    # lecture, case 1: tau = 1/w gives d = w ln 2
    assert D.damping_ratio(D.analytic_rho(D.Scheme("si"), 1.0), 1.0)[0] == pytest.approx(
        np.log(2.0), rel=1e-15)


@pytest.mark.parametrize("radius", RADII)
def test_generalized_alpha_spectral_radius_limits(radius):
    """rho -> 1 as tau w -> 0 and rho -> r as tau w -> inf (lecture's parameters)."""
    scheme = D.Scheme("alpha", radius)
    rho = D.analytic_rho(scheme, np.array([1e-4, 1e-2, 1e4, 1e8, np.inf]))
    _print(f"r = {radius}: rho(1e-4, 1e-2, 1e4, 1e8, inf) = {rho}")
    assert rho[0] == pytest.approx(1.0, abs=1e-12)
    assert rho[1] == pytest.approx(1.0, abs=1e-8)
    assert abs(rho[3] - radius) < abs(rho[2] - radius) + 1e-5
    # at infinity the three roots coincide at -r (a defective triple root: the eigenvalue solver
    # resolves it only to ~eps^(1/3) ~ 6e-6), so check the characteristic polynomial exactly
    assert rho[4] == pytest.approx(radius, abs=1e-5)
    T = D.alpha_amplification(np.inf, radius)[0]
    c1, c2, c3 = np.trace(T), 0.5 * (np.trace(T) ** 2 - np.trace(T @ T)), np.linalg.det(T)
    np.testing.assert_allclose([c1, c2, c3], [-3 * radius, 3 * radius**2, -radius**3],
                               atol=1e-14)
    # never above 1: unconditionally stable
    x = np.logspace(-3, 6, 200)
    assert np.all(D.analytic_rho(scheme, x) <= 1.0 + 1e-12)


@pytest.mark.parametrize("radius", RADII)
def test_lecture_parameters_are_petsofts_weights_on_old_values(radius):
    """The lecture's (alpha_m, alpha_f) weight old values; petsoft's weight new ones."""
    am, af, beta, gamma = D.lecture_alpha_parameters(radius)
    pm, pf, pgamma, pbeta = alpha_parameters(radius)
    np.testing.assert_allclose([1 - am, 1 - af, beta, gamma], [pm, pf, pbeta, pgamma],
                               rtol=1e-15)


def test_midpoint_and_explicit_schemes_are_undamped_where_stable():
    x = np.logspace(-2, 2, 81)
    for name in ("midpoint", "trapezoidal"):
        np.testing.assert_allclose(D.analytic_rho(D.Scheme(name), x), 1.0, atol=1e-14)
    for name in ("verlet", "euler"):
        scheme = D.Scheme(name)
        rho = D.analytic_rho(scheme, x)
        ok = D.stable(scheme, x)
        np.testing.assert_allclose(rho[ok], 1.0, atol=1e-7)     # double root near tau w = 2
        assert np.all(rho[~ok & (x > 2.01)] > 1.0)
        assert np.array_equal(ok, x < 2.0)


def test_fit_recovers_the_spectral_radius_of_a_known_map():
    """Trajectories of known 2x2 and 3x3 maps (observing only (w q, v) of the 3x3 one)."""
    for scheme, x in ((D.Scheme("be"), 0.3), (D.Scheme("alpha", 0.5), 2.0),
                      (D.Scheme("alpha", 0.0), 0.7), (D.Scheme("midpoint"), 5.0)):
        T = D.amplification(scheme, x)[0]
        state = np.ones(len(T))
        ys = []
        for _ in range(30):
            ys.append(state[:2] * ([x, 1.0] if len(T) == 3 else 1.0))   # (q, h v) -> (w q, v)
            state = T @ state
        rho = D.fit_spectral_radius(np.array(ys)[None], rank=scheme.state_size)[0]
        assert rho == pytest.approx(D.spectral_radius(T[None])[0], rel=1e-10), scheme


# -- measured on oscillators ---------------------------------------------------------------------
@pytest.mark.parametrize("scheme", [D.Scheme("be"), D.Scheme("si"), D.Scheme("alpha", 0.5),
                                    D.Scheme("midpoint"), D.Scheme("trapezoidal"),
                                    D.Scheme("alpha", 0.0), D.Scheme("alpha", 1.0),
                                    D.Scheme("verlet")], ids=lambda s: s.key)
def test_measured_damping_matches_analytic(scheme):
    """petsoft's integrators on undamped oscillators (tau w = 0.1, 1, 10 in one system): the
    measured d/w equals the analytic one within 1% (1e-6 absolute where it is ~0); Verlet at
    tau w = 10 is unstable and the measured growth factor matches the analytic one."""
    x = np.array([0.1, 1.0, 10.0])
    row = D.scalar_analysis([scheme], x)[0]
    for r in D.scalar_table_rows([row]):
        _print(f"{r['scheme']:>12} tau*w = {r['tau_omega']:<5g} d/w analytic "
               f"{D._fmt(r['d_over_omega_analytic'], '.8g'):>12} measured "
               f"{D._fmt(r['d_over_omega_measured'], '.8g'):>12}  {r['note']}")
    ok = row.stable
    da, dm = row.d_analytic[ok], row.d_measured[ok]
    assert np.all(np.abs(dm - da) <= np.maximum(0.01 * np.abs(da), 1e-6))
    np.testing.assert_allclose(row.rho_measured[~ok], row.rho_analytic[~ok], rtol=0.01)
    if scheme.name == "be":
        np.testing.assert_allclose(dm, np.log1p(x**2) / x, rtol=1e-8)


# -- FEM modes -----------------------------------------------------------------------------------
def _bar():
    return build_model(experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [8, 2, 2]}},
        "material": {"model": "linear", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "time": {"end": 1.0, "step": 0.02},
        "output": {"directory": "unused"},
    }))


def test_fem_mode_damping_of_a_linear_bar():
    """Started from a mode shape, a linear body stays in that mode, so the measured per-mode
    damping equals the scalar analytic value at the mode's tau*w: BE within 1e-6 relative of
    ln(1 + (tau w)^2)/(tau w) (the limit is the Newton and eigensolver tolerances, 1e-10; seen
    ~1e-11), generalized alpha (r = 0.5) within 1e-4 relative or 1e-9 absolute, midpoint within
    1e-9 absolute of 0."""
    schemes = [D.Scheme("be"), D.Scheme("alpha", 0.5), D.Scheme("midpoint")]
    fem = D.fem_mode_damping(_bar(), 0.02, schemes, nmodes=3, nsteps=10)
    x = fem.tau_omega
    for r in D.fem_table_rows(fem):
        _print(f"mode {r['mode']} f = {r['frequency_hz']:.5g} Hz tau*w = {r['tau_omega']:.4g} "
               f"{r['scheme']:>11}: analytic {D._fmt(r['d_over_omega_analytic'], '.10g')} "
               f"measured {D._fmt(r['d_over_omega_measured'], '.10g')}")
    assert len(x) == 3 and np.all(np.diff(x) >= 0) and not fem.notes and not fem.failures
    assert x.min() > 0.05 and x.max() < 2.0
    d_be = D.damping_ratio(fem.rho_measured["be"], x)
    np.testing.assert_allclose(d_be, D.be_damping_ratio(x), rtol=1e-6)
    da = D.damping_ratio(fem.rho_analytic["alpha_r0.5"], x)
    dm = D.damping_ratio(fem.rho_measured["alpha_r0.5"], x)
    assert np.all(np.abs(dm - da) <= np.maximum(1e-4 * da, 1e-9))
    assert np.abs(D.damping_ratio(fem.rho_measured["midpoint"], x)).max() < 1e-9


# -- CLI -----------------------------------------------------------------------------------------


@serial_only
def test_cli_writes_plot_tables_and_summary(tmp_path):
    cmd = [sys.executable, "-m", "petsoft.cli.main", "damping", "--out", "d"]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, env=child_env(),
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "| BE | 1 | 0.693147 |" in proc.stdout and "unstable" in proc.stdout
    out = tmp_path / "d"
    assert (out / "damping.png").stat().st_size > 10_000
    summary = json.loads((out / "summary.json").read_text())
    assert summary["command"] == "damping"
    assert summary["schemes"]["be"]["d_over_omega_measured"][1] == pytest.approx(np.log(2.0),
                                                                               rel=1e-6)
    assert set(summary["schemes"]) >= {"be", "si", "midpoint", "alpha_r0", "alpha_r0.25",
                                       "alpha_r0.5", "alpha_r0.75", "alpha_r1", "verlet"}
    assert summary["max_deviation_measured_vs_analytic"] < 1e-6
    assert (out / "damping.md").read_text().count("\n| alpha r=0.5 |") == 3
    assert len((out / "damping_scalar.csv").read_text().splitlines()) == 1 + 11 * 17

    bad = subprocess.run([sys.executable, "-m", "petsoft.cli.main", "damping", "--radii", "0,2"],
                         cwd=tmp_path, capture_output=True, text=True, env=child_env(), timeout=60)
    assert bad.returncode == 2 and "radii must lie in [0, 1]" in bad.stderr
