"""petsoft: PETSc-backed, MPI-parallel simulation and calibration of soft deformable objects.

Read the user's files into values::

    load_experiment(path) -> Experiment        the experiment (TOML; petsoft/formats.md)
    read_recording(path) -> Recording          marker trajectories (HDF5)
    with_parameters(experiment, {name: value}) a copy with changed parameters

Compute (every function takes values and keyword options and returns a result with
``success``, ``message`` and a short repr; fits give their values by name in ``params``)::

    static(experiment)                   quasistatic equilibrium         -> StaticResult
    simulate(experiment)                 elastodynamics over [time]      -> SimulationRun
    modes(experiment, n)                 natural frequencies and shapes  -> Modes
    synth(experiment, out=...)           a synthetic recording           -> SynthResult
    calibrate(experiment, recording)     fit the [calibrate] parameters  -> CalibrationResult
    calibrate_modes(experiment, freqs)   ... to natural frequencies      -> FrequencyFit
    rest_shape(experiment)               the rest mesh of a captured one -> RestShape
    calibrate_rest_shape(experiment, r)  calibrate a captured shape      -> SplittingResult
    diagnose(experiment, recording)      find the physics a model lacks  -> DiagnoseResult

Example::

    import petsoft
    exp = petsoft.load_experiment("scripts/examples/cantilever.toml")
    fit = petsoft.calibrate(exp, petsoft.read_recording("recording.h5"))
    fit.success, fit.params["material.youngs_modulus"], fit.param_std

Errors caused by input are :class:`PetsoftError` (an :class:`ExperimentError` is also a
``ValueError``). All ranks call every function (``mpiexec -n 2 python script.py``) and get the
same result. The command line does the same: ``petsoft --help`` (or ``python -m petsoft``).

The functions are loaded on first use: ``import petsoft`` does not initialise PETSc, so a program
(or the ``petsoft`` command) can still call ``petsc4py.init(sys.argv)`` with its PETSc options
first.
"""

# One BLAS thread per process, set before PETSc (and its OpenBLAS) is loaded, and on an OpenBLAS
# that numpy or petsc4py loaded already (petsoft.blas_threads): MPI ranks and sub-communicator
# groups already use every core, and OpenBLAS's spinning threads made MUMPS factorisations 8x
# slower when another process ran on the 2-core machine (measured: one forward run 37.7 s with
# the default threads, 4.9 s with one). The user's own setting wins.
from petsoft.blas_threads import one_thread_unless_chosen

one_thread_unless_chosen()

from petsoft.errors import (  # noqa: E402
    ExperimentError,
    InvertedElementError,
    MeshError,
    PetsoftError,
    SolverError,
)
from petsoft.version import __version__ as __version__  # noqa: E402

#: The names :mod:`petsoft.api` exports, loaded lazily (PEP 562): importing the API imports
#: petsc4py, which initialises PETSc on first use.
_API = ("load_experiment", "with_parameters", "read_recording", "static", "simulate", "modes",
        "synth", "calibrate", "calibrate_modes", "rest_shape", "calibrate_rest_shape",
        "diagnose", "Experiment", "Recording", "StaticResult", "SimulationRun", "Modes",
        "SynthOptions", "SynthResult", "CalibrationResult", "DiagnoseResult")

__all__ = [*_API, "PetsoftError", "ExperimentError", "MeshError", "SolverError",
           "InvertedElementError", "__version__"]


def __getattr__(name: str):
    """The API's names, imported from :mod:`petsoft.api` on first use (PEP 562)."""
    if name in _API:
        from petsoft.dependencies import require

        require(("petsc4py", "mpi4py"), f"petsoft.{name}")
        from petsoft import api

        return getattr(api, name)
    raise AttributeError(f"module 'petsoft' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The module's names with the lazily loaded API's (for ``dir`` and ``help``)."""
    return sorted({*globals(), *__all__})
