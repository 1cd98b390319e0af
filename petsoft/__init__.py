"""petsoft: PETSc-backed, MPI-parallel simulation and calibration of soft deformable objects."""

import os

# One BLAS thread per process, set before PETSc (and its OpenBLAS) is loaded: MPI ranks and
# sub-communicator groups already use every core, and OpenBLAS's spinning threads made MUMPS
# factorisations 8x slower when another process ran on the 2-core machine (measured: one forward
# run 37.7 s with the default threads, 4.9 s with one). The user's own setting wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from petsoft.version import __version__ as __version__  # noqa: E402
