"""The public Python API: lazily exported, explicit signatures, and the README's example runs."""

from __future__ import annotations

import importlib.util
import inspect
import re
import subprocess
import sys
from pathlib import Path

import pytest
from child_process import child_env

import petsoft

ROOT = Path(__file__).resolve().parents[1]
API = ("load_experiment", "with_parameters", "read_recording", "static", "simulate", "synth",
       "calibrate", "diagnose")


@pytest.mark.parametrize("name", API)
def test_every_api_function_has_explicit_options_and_documents_each(name):
    func = getattr(petsoft, name)
    params = inspect.signature(func).parameters
    assert not any(p.kind is p.VAR_KEYWORD for p in params.values()), f"{name} hides **kwargs"
    doc = inspect.getdoc(func)
    undocumented = [p for p in params if p != "say" and not re.search(
        rf"^{p}\b|, {p}\b|\b{p},", doc, flags=re.M)]
    assert not undocumented, f"petsoft.{name}'s docstring does not describe {undocumented}"


def test_diagnose_help_shows_every_option_of_the_library_function():
    from petsoft.diagnosis.diagnose import run_diagnose

    library = set(inspect.signature(run_diagnose).parameters) - {"comm", "recording"}
    api = set(inspect.signature(petsoft.diagnose).parameters)
    assert library - {"recording"} <= api


@pytest.mark.serial_only
def test_the_readme_python_example_runs(tmp_path):
    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Python API", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, flags=re.S).group(1)
    code = code.replace('"out/', f'"{tmp_path}/')
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         env=child_env(), timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "E = 2" in run.stdout
    assert (tmp_path / "calibration" / "calibrated.toml").is_file()


def test_the_api_example_script_recovers_e_on_all_ranks(tmp_path_factory):
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    out = Path(comm.bcast(str(tmp_path_factory.mktemp("api")) if comm.rank == 0 else None))
    spec = importlib.util.spec_from_file_location(
        "api_example", ROOT / "scripts" / "examples" / "api_example.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(["--out", str(out)]) == 0
    if comm.rank == 0:
        text = (out / "calibration" / "calibrated.toml").read_text()
        e = float(re.search(r"youngs_modulus = ([0-9.e+-]+)", text).group(1))
        assert abs(e / 2.0e6 - 1) < 1e-3
