"""Reduced-order models of a :class:`~petsoft.dynamics.system.DynamicSystem` (issue 40).

* :mod:`~petsoft.reduced.basis`: an M-orthonormal POD basis from displacement snapshots;
* :mod:`~petsoft.reduced.galerkin`: the Galerkin-projected equations stepped by the full model's
  schemes (generalized-alpha, backward Euler), markers observed through H V;
* :mod:`~petsoft.reduced.ecsw`: energy-conserving sampling and weighting of the elastic forces
  (a reduced mesh of weighted elements);
* :mod:`~petsoft.reduced.error`: the reduced model's marker error in units of the noise;
* :mod:`~petsoft.reduced.sensitivity`: forward sensitivities of a reduced run (the derivative
  of its discrete steps), observed at the markers;
* :mod:`~petsoft.reduced.build`: a reduced model built from a full run's snapshots and enriched
  until its error on full-model checks is below a fraction of the noise.

The package may use fem, physics, solvers and dynamics; never calibration or diagnosis (the
callers build snapshots and full runs and hand them in as values).

Why not pyMOR (PyPI ``pymor`` 2026.1.1, checked on this machine): it installs (a pure-Python
wheel; with numpy held at the system's 1.24) and its ``pod`` (method of snapshots with a mass
product) gives the same basis as :func:`~petsoft.reduced.basis.pod_basis` on 100 snapshots of
the P2 taper (4641 dofs: square roots of the eigenvalues to 1.4e-8 relative, the same subspace).
But it has no ECSW (its hyper-reduction is empirical interpolation, ``ei_greedy``), its PETSc
vectors come only through its FEniCSx bindings (tested for DOLFINx 0.10; Debian's is 0.5), and
its MPI vector arrays are driven from rank 0 by an event loop, where petsoft runs the same code
on every rank. The reduced model needs petsoft's own assembly and element kernels either way,
and the POD is some forty lines: written here, no dependency added.
"""
