"""Physics terms. A model is a sum of terms; each gives its energy, its gradient (minus the force)
and its Hessian (minus the force Jacobian), and integrators and solvers see only that interface."""
