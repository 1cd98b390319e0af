"""Import a script of ``scripts/<folder>/`` as a module (tests call its functions directly).

The scripts are run as programs, whose own directory Python puts first on ``sys.path``, so they
import their sibling modules (``_bench_common``, ``import_pendulum``...) with no path set-up of
their own. A test loads a script by its file path instead, leaving ``sys.path`` alone; the
siblings the script imports are named in ``needs`` and loaded the same way first, registered in
``sys.modules`` under their own names so that the script's ``import import_pendulum`` finds them.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def _load(name: str, directory: Path):
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, directory / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    # registered before executing, as the import system does (dataclasses look their module up)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def load_script(name: str, folder: str = "examples", needs: tuple[str, ...] = ()):
    """The module ``scripts/<folder>/<name>.py``, loaded by file path.

    Parameters
    ----------
    name : str
        The script's file name without ``.py``.
    folder : str
        Its folder under ``scripts/`` (``examples``, ``benchmarks`` or ``tools``).
    needs : tuple of str
        Sibling modules of the same folder the script imports; loaded first.
    """
    directory = SCRIPTS / folder
    for sibling in needs:
        _load(sibling, directory)
    return _load(name, directory)
