"""The independent generators' modules (scripts/benchmarks/independent), loaded by path for the
tests that check them with gmsh or numpy alone (no DOLFINx, no petsoft)."""

import importlib.util
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1] / "scripts/benchmarks/independent"


def load(name: str):
    """The module ``HERE/<name>.py`` (its folder on sys.path, for its own imports)."""
    if str(HERE) not in sys.path:
        sys.path.insert(0, str(HERE))
    spec = importlib.util.spec_from_file_location(name, HERE / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
