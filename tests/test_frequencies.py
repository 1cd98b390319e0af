"""Calibration from measured natural frequencies (issue 17.2): ``petsoft calibrate --modes``.

1. E and nu from the first 6 frequencies of a beam computed by DOLFINx (P2, consistent mass, the
   same mesh: tests/data/p2_reference/beam_modes.npz): recovered to 1e-6 (measured ~1e-11),
   on 1 and 2 ranks.
2. With 0.5 % noise on the frequencies (and that std in the file): E and nu within 2 %, with
   standard deviations that cover the error.
3. Taylor test of the frequency gradient (exact eigenvalue derivatives) for E, nu, density and a
   region's E: the first-order remainder falls as eps^2; a cluster of close eigenvalues gets the
   derivative of its mean, which is also Taylor-tested.
4. The file: text with header, comments and std; JSON; errors that name the line.
5. The command line: outputs written; exactly one of a recording and --modes.
"""

from __future__ import annotations

import json
from pathlib import Path

import meshio
import numpy as np
import pytest
from mpi4py import MPI

import petsoft
from petsoft.calibration.frequencies import FrequencyModel, calibrate_frequencies
from petsoft.cli.main import main
from petsoft.experiment import experiment_from_dict, load_experiment
from petsoft.io.frequencies import FrequencyFileError, MeasuredFrequencies, read_frequencies

DATA = Path(__file__).parent / "data" / "p2_reference" / "beam_modes.npz"


def _shared_dir(tmp_path_factory, name):
    comm = MPI.COMM_WORLD
    return Path(comm.bcast(str(tmp_path_factory.mktemp(name)) if comm.rank == 0 else None))


@pytest.fixture(scope="module")
def beam(tmp_path_factory):
    """The DOLFINx beam's mesh as a file, its experiment (E 30 % low, nu 0.2) and frequencies."""
    d = _shared_dir(tmp_path_factory, "freq")
    ref = np.load(DATA)
    if MPI.COMM_WORLD.rank == 0:
        meshio.write(d / "beam.vtu", meshio.Mesh(ref["points"], [("tetra", ref["tets"])]))
        (d / "beam.toml").write_text("""
[mesh]
file = "beam.vtu"
order = 2

[material]
model = "linear"
youngs_modulus = 7.0e5
poisson_ratio = 0.2
density = 1000.0

[[boundary]]
kind = "fixed"
where = "x < 1e-9"

[calibrate]
"material.youngs_modulus" = [1e5, 1e7]
"material.poisson_ratio" = [0.0, 0.45]
""")
    MPI.COMM_WORLD.Barrier()
    return {"dir": d, "experiment": load_experiment(d / "beam.toml"),
            "frequencies": ref["frequencies_hz"], "E": float(ref["E"]), "nu": float(ref["nu"])}


def test_E_and_nu_from_six_dolfinx_frequencies(beam):
    f = beam["frequencies"][:6]
    fit = calibrate_frequencies(beam["experiment"], MeasuredFrequencies(f, None, "dolfinx"))
    E, nu = fit.values
    assert abs(E / beam["E"] - 1.0) < 1e-6, E
    assert abs(nu - beam["nu"]) < 1e-6, nu
    assert np.max(np.abs(fit.after / f - 1.0)) < 1e-8
    assert np.max(np.abs(fit.before / f - 1.0)) > 0.1          # the start was far off


@pytest.mark.serial_only     # ~3 s; the exact case above runs on 2 ranks too
def test_noisy_frequencies_give_E_and_nu_within_two_percent_with_their_std(beam):
    rng = np.random.default_rng(7)
    f = beam["frequencies"][:6]
    std = 0.005 * f
    noisy = np.sort(f + std * rng.standard_normal(f.size))
    fit = calibrate_frequencies(beam["experiment"], MeasuredFrequencies(noisy, std, "noisy"))
    E, nu = fit.values
    assert abs(E / beam["E"] - 1.0) < 0.02 and abs(nu - beam["nu"]) < 0.02 * beam["nu"]
    assert np.all(np.isfinite(fit.std)) and np.all(fit.std > 0)
    # the reported std covers the actual error (3 sigma)
    assert abs(E - beam["E"]) < 3 * fit.std[0] and abs(nu - beam["nu"]) < 3 * fit.std[1]
    assert fit.sigma_source == "the file's std"


def _orders(rem):
    rem = np.asarray(rem)
    return np.log2(rem[:-1] / rem[1:])


def _bar(size=(0.2, 0.01, 0.02), cells=(8, 1, 2)):
    return experiment_from_dict({
        "mesh": {"box": {"size": list(size), "cells": list(cells)}, "order": 2},
        "material": {"model": "linear", "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                     "density": 1000.0, "tip": {"youngs_modulus": 2e6}},
        "region": {"tip": {"where": "x > 0.15"}},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}]})


@pytest.mark.parametrize("name", ["material.youngs_modulus", "material.poisson_ratio",
                                  "material.density", "material.tip.youngs_modulus"])
def test_frequency_gradient_taylor(name):
    names = ["material.youngs_modulus", "material.poisson_ratio", "material.density",
             "material.tip.youngs_modulus"]
    model = FrequencyModel(_bar(), names, 5)
    p = np.array([1e6, 0.3, 1000.0, 2e6])
    f0, J = model.evaluate(p)
    d = np.zeros(4)
    d[names.index(name)] = p[names.index(name)] * (0.3 if "poisson" in name else 1.0)
    rem = []
    for k in range(4):
        eps = 0.05 * 2.0 ** -k
        f, _ = model.evaluate(p + eps * d, jacobian=False)
        rem.append(np.linalg.norm(f - f0 - eps * J @ d))
    orders = _orders(rem)
    assert np.all((orders > 1.8) & (orders < 2.2)), (name, rem, orders)


def test_a_cluster_gets_the_derivative_of_its_mean(monkeypatch):
    """A square section bends nearly alike about its two diagonals (8.6e-4 apart on this mesh,
    which has a mirror symmetry but no 4-fold one, so the pair is not exactly double). Taken as
    a cluster (the tolerance widened for the test), each member gets the derivative of the
    pair's mean, which is smooth however close the pair: Taylor order 2 on the mean."""
    import petsoft.calibration.frequencies as frequencies

    monkeypatch.setattr(frequencies, "CLUSTER_RTOL", 1e-2)
    names = ["material.youngs_modulus", "material.tip.youngs_modulus"]
    model = FrequencyModel(_bar(size=(0.2, 0.02, 0.02), cells=(8, 2, 2)), names, 2)
    p = np.array([1e6, 1.5e6])
    f0, J = model.evaluate(p)
    assert 0 < abs(f0[1] / f0[0] - 1.0) < 1e-2
    np.testing.assert_allclose(J[0] * f0[0], J[1] * f0[1])     # the same d lambda
    d = np.array([0.0, 1.5e6])
    rem = []
    for k in range(4):
        eps = 0.05 * 2.0 ** -k
        f, _ = model.evaluate(p + eps * d, jacobian=False)
        # d f_mean ~ d lambda_mean / (8 pi^2 f): the pair's frequencies are within 1e-3, so the
        # mean of df is the derivative of the mean frequency to second order in that gap
        rem.append(abs(f.mean() - f0.mean() - eps * (J @ d).mean()))
    orders = _orders(rem)
    assert np.all((orders > 1.8) & (orders < 2.2)), (rem, orders)


def test_non_material_parameters_are_refused():
    with pytest.raises(petsoft.errors.ExperimentError, match="depend on the material only"):
        FrequencyModel(_bar(), ["damping.mass"], 3)


# -- the file -------------------------------------------------------------------------------
@pytest.mark.serial_only
def test_frequency_files(tmp_path):
    p = tmp_path / "f.csv"
    p.write_text("# measured on the shaker\nfrequency_hz, std_hz\n1.5, 0.01\n3.25 ,0.02\n\n"
                 "7.0,0.05  # third\n")
    m = read_frequencies(p)
    np.testing.assert_array_equal(m.frequencies, [1.5, 3.25, 7.0])
    np.testing.assert_array_equal(m.std, [0.01, 0.02, 0.05])
    q = tmp_path / "f.json"
    q.write_text(json.dumps({"frequencies_hz": [2.0, 4.0]}))
    assert read_frequencies(q).std is None
    cases = [("1.0\n2.0\nabc\n", "line 3: 'abc' is not a number"),
             ("2.0\n1.0\n", "below frequency 1"),
             ("1.0, 0.1\n2.0\n", "on every line or on none"),
             ("1.0\n-2.0\n", "must be finite numbers > 0"),
             ("1.0, 2.0, 3.0\n", "has 3 values"),
             ("# nothing\n", "no frequency found")]
    for text, message in cases:
        p.write_text(text)
        with pytest.raises(FrequencyFileError, match=message):
            read_frequencies(p)
    q.write_text("{not json")
    with pytest.raises(FrequencyFileError, match="not valid JSON"):
        read_frequencies(q)


# -- the command line -------------------------------------------------------------------------
@pytest.mark.serial_only
def test_calibrate_modes_command(beam, tmp_path, capsys):
    f = tmp_path / "measured.txt"
    f.write_text("\n".join(repr(v) for v in beam["frequencies"][:6]))
    out = tmp_path / "out"
    assert main(["calibrate", str(beam["dir"] / "beam.toml"), "--modes", str(f),
                 "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["parameters"]["material.youngs_modulus"] == pytest.approx(1e6, rel=1e-6)
    assert (out / "frequencies.png").stat().st_size > 10_000
    back = load_experiment(out / "calibrated.toml")
    assert back.material["default"].youngs_modulus == pytest.approx(1e6, rel=1e-6)
    assert main(["calibrate", str(beam["dir"] / "beam.toml")]) != 0
    assert "exactly one of a RECORDING" in capsys.readouterr().err
