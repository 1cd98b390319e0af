"""The compiled Python packages petsoft takes from Debian, checked before the work that needs
them, with an error that names the package to install.

They cannot come from PyPI (``petsc4py`` there compiles PETSc for half an hour without MUMPS;
``h5py`` there brings a second HDF5 library into the process), so pip cannot install them as
dependencies, and a missing one used to surface as a raw ``ModuleNotFoundError`` (for h5py
after the solve, when the results were written).
"""

from __future__ import annotations

import importlib.util
import sys

from petsoft.errors import PetsoftError

#: The Debian package of each module (Debian 12; ``scripts/bootstrap.sh`` installs them all).
DEBIAN = {"petsc4py": "python3-petsc4py-real", "slepc4py": "python3-slepc4py-real",
          "mpi4py": "python3-mpi4py", "h5py": "python3-h5py-mpi"}
#: What each module is for, in the error message.
PURPOSE = {"petsc4py": "PETSc, every solver",
           "slepc4py": "SLEPc: natural frequencies (modes, damping, calibrate --modes) and the "
                       "explicit, ERE and IMEX integrators",
           "mpi4py": "MPI, runs on one or more ranks",
           "h5py": "HDF5: recordings, XDMF output and checkpoints"}


class MissingDependencyError(PetsoftError, ImportError):
    """A module petsoft needs cannot be imported; the message names its Debian package."""


def missing(modules) -> list[str]:
    """The names of ``modules`` this Python cannot import (found without importing them, so
    the check initialises neither MPI nor PETSc)."""
    absent = []
    for name in modules:
        try:
            found = importlib.util.find_spec(name) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            absent.append(name)
    return absent


def require(modules, needed_for: str) -> None:
    """Raise :class:`MissingDependencyError` when any of ``modules`` is missing.

    Parameters
    ----------
    modules : iterable of str
        Keys of :data:`DEBIAN`.
    needed_for : str
        What needs them, for the message (e.g. ``"petsoft modes"``).
    """
    absent = missing(modules)
    if not absent:
        return
    what = "; ".join(f"{name} ({PURPOSE[name]})" for name in absent)
    packages = " ".join(DEBIAN[name] for name in absent)
    raise MissingDependencyError(
        f"{needed_for} needs {what}, which this Python ({sys.executable}) cannot import. Install "
        f"Debian's package: apt-get install {packages} (or run `bash scripts/bootstrap.sh`, "
        "which installs them all; a virtual environment sees Debian's packages only when made "
        "from /usr/bin/python3 with --system-site-packages)")


def slepc(needed_for: str = "this computation"):
    """The ``slepc4py.SLEPc`` module, imported on first use (only modes and some integrators
    need SLEPc), or :class:`MissingDependencyError`."""
    require(("slepc4py",), needed_for)
    from slepc4py import SLEPc

    return SLEPc
