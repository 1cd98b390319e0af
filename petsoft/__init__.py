"""petsoft: PETSc-backed, MPI-parallel simulation and calibration of soft deformable objects."""

__version__ = "0.1.0"
