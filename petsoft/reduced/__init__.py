"""Reduced-order models of a :class:`~petsoft.dynamics.system.DynamicSystem` (issue 40).

* :mod:`~petsoft.reduced.basis`: an M-orthonormal POD basis from displacement snapshots;
* :mod:`~petsoft.reduced.galerkin`: the Galerkin-projected equations stepped by the full model's
  schemes (generalized-alpha, backward Euler), markers observed through H V;
* :mod:`~petsoft.reduced.ecsw`: energy-conserving sampling and weighting of the elastic forces
  (a reduced mesh of weighted elements);
* :mod:`~petsoft.reduced.error`: the reduced model's marker error in units of the noise.

The package may use fem, physics, solvers and dynamics; never calibration or diagnosis (the
callers build snapshots and full runs and hand them in as values).
"""
