"""petsoft: PETSc-backed, MPI-parallel simulation and calibration of soft deformable objects.

The public Python API (see :mod:`petsoft.api`)::

    load_experiment, read_recording       read the user's files into values
    with_parameters                       a copy of an experiment with changed parameters
    static, simulate, synth               solve, integrate, make a synthetic recording
    calibrate, diagnose                   fit parameters; find, model and verify missing physics
    calibrate_modes                       fit material parameters to natural frequencies
    rest_shape, calibrate_rest_shape      the rest shape of a captured equilibrium; fit with it

The API is loaded on first use: ``import petsoft`` does not initialise PETSc, so a program (or
the ``petsoft`` command) can still call ``petsc4py.init(sys.argv)`` with its PETSc options first.
"""

# One BLAS thread per process, set before PETSc (and its OpenBLAS) is loaded, and on an OpenBLAS
# that numpy or petsc4py loaded already (petsoft.blas_threads): MPI ranks and sub-communicator
# groups already use every core, and OpenBLAS's spinning threads made MUMPS factorisations 8x
# slower when another process ran on the 2-core machine (measured: one forward run 37.7 s with
# the default threads, 4.9 s with one). The user's own setting wins.
from petsoft.blas_threads import one_thread_unless_chosen

one_thread_unless_chosen()

from petsoft.version import __version__ as __version__  # noqa: E402

#: The names :mod:`petsoft.api` exports, loaded lazily (PEP 562).
_API = ("load_experiment", "with_parameters", "read_recording", "static", "simulate", "synth",
        "calibrate", "calibrate_modes", "rest_shape", "calibrate_rest_shape", "diagnose")


def __getattr__(name: str):
    if name in _API:
        from petsoft import api

        return getattr(api, name)
    raise AttributeError(f"module 'petsoft' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])
