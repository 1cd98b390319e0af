"""The API's conventions (scipy's, DOLFINx's): ``help(petsoft)`` lists the public functions,
every one is reachable from the package, results have ``success``, ``message``, values by name
and a short repr, the documented method names are accepted, ``ExperimentError`` is a
``ValueError``, and ``python -m petsoft`` is the command."""

from __future__ import annotations

import inspect
import pydoc
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from child_process import child_env

import petsoft
from petsoft.results import REPR_LIMIT, short_repr

ROOT = Path(__file__).resolve().parents[1]

TINY = """
[mesh]
box = { size = [0.1, 0.02, 0.02], cells = [4, 1, 1] }
[material]
model = "linear"
youngs_modulus = 1.0e6
poisson_ratio = 0.3
density = 1000.0
[gravity]
acceleration = [0.0, 0.0, -9.81]
[[boundary]]
kind = "fixed"
where = "x < 1e-9"
[time]
end = 0.004
step = 0.002
integrator = "be"
"""


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    folder = Path(comm.bcast(str(tmp_path_factory.mktemp("tiny")) if comm.rank == 0 else None))
    if comm.rank == 0:
        (folder / "tiny.toml").write_text(TINY)
    comm.barrier()
    return petsoft.load_experiment(folder / "tiny.toml")


def test_help_lists_every_public_function_and_class():
    from petsoft import api

    text = pydoc.render_doc(petsoft, renderer=pydoc.plaintext)
    functions = text.split("FUNCTIONS", 1)[1].split("DATA", 1)[0]
    for name in api.__all__:
        target = functions if inspect.isfunction(getattr(api, name)) else text
        assert re.search(rf"^    {name}\(" if target is functions else rf"\b{name}\b", target,
                         flags=re.M), f"help(petsoft) does not list {name}"
    assert "Compute (every function" in text            # the package docstring


def test_every_name_of_all_is_reachable_and_listed_by_dir():
    from petsoft import api

    assert set(api.__all__) <= set(petsoft.__all__)
    assert set(petsoft.__all__) <= set(dir(petsoft))
    for name in petsoft.__all__:
        assert getattr(petsoft, name) is not None
    assert petsoft.modes is api.modes and petsoft.rest_shape is api.rest_shape
    assert petsoft.Experiment is api.Experiment


def test_experiment_error_is_a_value_error(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(TINY.replace("youngs_modulus = 1.0e6", "youngs_modulus = -1.0"))
    with pytest.raises(ValueError, match="youngs_modulus"):
        petsoft.load_experiment(path)
    assert issubclass(petsoft.ExperimentError, ValueError)
    assert issubclass(petsoft.ExperimentError, petsoft.PetsoftError)


def test_every_documented_method_name_is_accepted_everywhere():
    from petsoft.calibration.calibrate import canonical_method
    from petsoft.calibration.methods import METHOD_ALIASES, METHODS
    from petsoft.cli.main import _parser

    doc = inspect.getdoc(petsoft.calibrate)
    listed = doc.split("method : str", 1)[1].split("gradient : str", 1)[0]
    documented = set(re.findall(r"[a-z][a-z-]*[a-z]", listed)) - {"also", "spelled", "or"}
    assert documented == set(METHODS) | set(METHOD_ALIASES)
    readme = (ROOT / "README.md").read_text() + (ROOT / "petsoft/calibration/README.md").read_text()
    for name in documented:
        assert canonical_method(name) in METHODS
        assert f"`{name}`" in readme, f"{name} is not in the README"
        for command in (["calibrate", "e.toml", "r.h5"], ["diagnose", "e.toml", "r.h5"]):
            assert _parser().parse_args([*command, "--method", name]).method == name
    assert canonical_method("gradient-descent") == "gd"
    with pytest.raises(petsoft.ExperimentError, match="gradient-descent"):
        canonical_method("steepest")


def test_static_simulate_and_modes_results_follow_the_conventions(tiny):
    sag = petsoft.static(tiny)
    assert sag.success and "Newton" in sag.message
    swing = petsoft.simulate(tiny, out=_out())
    assert swing.success and swing.end == pytest.approx(0.004) and "reached" in swing.message
    modes = petsoft.modes(tiny, 3)
    assert modes.success and modes.requested == 3
    assert modes.shapes.shape == (3, len(sag.displacement), 3)
    # the modes are free vibrations about the support: zero at the clamped nodes x = 0
    mesh_x = _node_x(tiny)
    assert np.abs(modes.shapes[:, mesh_x < 1e-9]).max() == 0.0
    assert np.all(np.diff(modes.frequencies_hz) > 0) and modes.relative_errors.max() < 1e-6
    rest = petsoft.rest_shape(tiny)
    assert rest.success and "Newton" in rest.message
    for result in (sag, swing, modes, rest):
        text = repr(result)
        assert len(text) < REPR_LIMIT and text.startswith(type(result).__name__)
        assert "success=True" in text
        assert "array(shape=" in text or result is rest
        assert f"message={result.message!r}" in text        # the message whole


def _out():
    import tempfile

    from mpi4py import MPI

    return MPI.COMM_WORLD.bcast(tempfile.mkdtemp() if MPI.COMM_WORLD.rank == 0 else None)


def _node_x(experiment):
    from petsoft.physics.model import load_mesh

    return load_mesh(experiment).points[:, 0]


def _calibration(reason="CONVERGED_STEPTOL", n=3):
    from petsoft.calibration.calibrate import CalibrationResult

    big = np.random.default_rng(0).normal(size=(200, 8, 3))
    return CalibrationResult(
        names=["material.youngs_modulus", "damping.mass", "gravity.acceleration.z"][:n],
        start=np.ones(n), values=np.array([2.0e6, 4.0, -9.81])[:n], std=np.array(
            [1e3, 0.01, 0.001])[:n], bounds=[(1, 2)] * n, rms_before=1e-3, rms_after=2e-5,
        objective_before=1.0, objective_after=0.1, iterations=7, evaluations=9, reason=reason,
        sigma=2e-5, sigma_source="recording", noise_estimate=2e-5,
        history=[{"it": k} for k in range(50)], simulated_before=big, simulated_after=big)


def test_a_calibration_gives_its_values_by_name_in_a_short_repr():
    fit = _calibration()
    assert fit.params == {"material.youngs_modulus": 2.0e6, "damping.mass": 4.0,
                          "gravity.acceleration.z": -9.81}
    assert fit.param_std["damping.mass"] == 0.01
    assert fit.success and "CONVERGED_STEPTOL after 7 iterations" in fit.message
    assert not _calibration("DIVERGED_MAXITS").success
    text = repr(fit)
    assert len(text) < REPR_LIMIT, text
    assert "'material.youngs_modulus': 2e+06" in text
    assert "simulated_before=array(shape=(200, 8, 3)" in text and "history=<list of 50>" in text


def test_a_diagnosis_says_whether_the_final_model_explains_the_data():
    from petsoft.diagnosis.context import Fit
    from petsoft.diagnosis.result import DiagnoseResult

    sim = np.zeros((300, 8, 3))
    base = Fit(experiment=None, names=["material.youngs_modulus"], values=np.array([1.8e6]),
               std=np.array([1e3]), chi2=5e4, rms=1e-3, heldout_rms=2e-3, sim=sim)
    final = Fit(experiment=None, names=["material.youngs_modulus", "damping.mass"],
                values=np.array([2.0e6, 4.01]), std=np.array([900.0, 0.012]), chi2=2400.0,
                rms=2e-5, heldout_rms=2.1e-5, sim=sim)
    kw = dict(verdict="missing-physics", report={"k": 1, "j": [1] * 100}, base=base,
              final=final, added=[{"physics": "damping.mass"}])
    found = DiagnoseResult(final_verdict="consistent", **kw)
    assert found.success and found.params == {"material.youngs_modulus": 2.0e6,
                                              "damping.mass": 4.01}
    assert found.param_std["damping.mass"] == 0.012
    assert "added damping.mass" in found.message
    assert not DiagnoseResult(final_verdict="missing-physics", **kw).success
    text = repr(found)
    assert len(text) < REPR_LIMIT and "base=<Fit>" in text and "'damping.mass': 4.01" in text


def test_a_repr_stays_short_however_many_fields():
    class Many:
        pass

    many = Many()
    items = [(f"field_{k}", np.arange(10.0 * k + 1)) for k in range(200)]
    text = short_repr(many, items)
    assert len(text) <= REPR_LIMIT and text.endswith("more)")


@pytest.mark.serial_only
def test_python_dash_m_petsoft_is_the_command():
    run = subprocess.run([sys.executable, "-m", "petsoft", "--help"], capture_output=True,
                         text=True, env=child_env(), timeout=120)
    assert run.returncode == 0 and run.stdout.startswith("usage: petsoft")
    assert "diagnose" in run.stdout
