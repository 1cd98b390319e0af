"""PETSc solver plumbing and the time-independent solvers (static equilibrium, modes)."""
