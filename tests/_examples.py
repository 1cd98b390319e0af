"""Import a script of ``scripts/<folder>/`` as a module (tests call its functions directly).

The scripts are run as programs, whose own directory Python puts first on ``sys.path``, so they
import their sibling modules (``_bench_common``, ``import_pendulum``...) with no path set-up of
their own; a test importing one puts that directory on ``sys.path`` the same way.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def load_script(name: str, folder: str = "examples"):
    """The module ``scripts/<folder>/<name>.py``."""
    directory = str(SCRIPTS / folder)
    if directory not in sys.path:
        sys.path.insert(0, directory)
    return importlib.import_module(name)
