"""Meshes: reading, generating and validating serial meshes (tetrahedral and spring meshes),
their topology and orderings, probe points, and the mesh distributed over MPI ranks."""
