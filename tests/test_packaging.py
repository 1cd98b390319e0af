"""Packaging: the declared dependencies cover every third-party import, one version string,
``petsoft --version``, the licence; ``import petsoft`` leaves PETSc uninitialised."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

from child_process import child_env

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
#: From Debian's packages, deliberately not pip dependencies (pyproject.toml says why).
FROM_DEBIAN = {"petsc4py", "slepc4py", "mpi4py", "h5py"}
#: Import name -> distribution name, where they differ.
DISTRIBUTION = {"tomli": "tomli", "mpl_toolkits": "matplotlib"}   # mplot3d ships with matplotlib


def _third_party_imports() -> set[str]:
    stdlib = set(sys.stdlib_module_names)
    names = set()
    for path in (ROOT / "petsoft").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return {n for n in names if n not in stdlib and n not in ("petsoft", "__future__")}


def test_every_imported_package_is_declared_or_from_debian():
    declared = {re.split(r"[<>=;! \[]", d, maxsplit=1)[0].lower()
                for d in PYPROJECT["project"]["dependencies"]}
    imported = _third_party_imports()
    missing = {n for n in imported - FROM_DEBIAN if DISTRIBUTION.get(n, n).lower() not in declared}
    assert not missing, f"imported by petsoft but not in pyproject's dependencies: {missing}"
    assert {"numpy", "scipy", "meshio", "matplotlib"} <= declared


def test_numpy_is_bounded_below_2():
    numpy = [d for d in PYPROJECT["project"]["dependencies"] if d.startswith("numpy")]
    assert numpy and "<2" in numpy[0].replace(" ", "")


def test_one_version_string():
    from petsoft.version import __version__

    assert PYPROJECT["project"]["version"] == __version__


def test_the_licence_is_the_one_pyproject_names():
    assert PYPROJECT["project"]["license"] == {"file": "LICENSE"}
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")


def test_petsoft_version_prints_petsc_version():
    from petsoft.version import __version__

    run = subprocess.run([sys.executable, "-m", "petsoft.cli.main", "--version"],
                         capture_output=True, text=True, env=child_env(), timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith(f"petsoft {__version__} (PETSc 3.")


def test_importing_petsoft_does_not_initialise_petsc():
    # the CLI must call petsc4py.init(argv) before PETSc loads, so the package root and its
    # lazily exported API may not import petsc4py.PETSc
    code = ("import sys, petsoft, petsoft.cli.main; names = dir(petsoft); "
            "print('petsc4py.PETSc' in sys.modules, 'diagnose' in names)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=child_env(), timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["False", "True"]


def test_tests_load_scripts_by_file_path_without_editing_sys_path():
    from _examples import load_script

    before = list(sys.path)
    problems = load_script("optimization_problems")
    assert sys.path == before
    assert Path(problems.__file__).parent == ROOT / "scripts" / "examples"
