"""Explicit integration with the lumped (row-sum) mass: symplectic Euler and velocity Verlet.

symplectic Euler (order 1):  v1 = v0 + h M^-1 f(t0, q0, v0);   q1 = q0 + h v1
velocity Verlet (order 2):   vh = v0 + h/2 a0;  q1 = q0 + h vh;  a1 = M^-1 f(t1, q1, v1*);
                             v1 = vh + h/2 a1, with v1* a prediction of v1 (damping only)

Both are stable only for h < 2 / omega_max. The limit is estimated before the first step from the
largest eigenvalue of K(q0) x = omega^2 M_lumped x (SLEPc), and a larger step is refused with a
clear error instead of blowing up.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.dependencies import slepc
from petsoft.dynamics.implicit import StepReport
from petsoft.errors import ExperimentError
from petsoft.solvers.options import SolverOptions, own_options

SCHEMES = ("euler", "verlet")


def largest_frequency(system, q: PETSc.Vec, options: SolverOptions | None = None) -> float:
    """omega_max (rad/s): sqrt of the largest eigenvalue of K(q) x = omega^2 M_lumped x
    (EPS prefix ``stability_``; ``options`` pushed under it while it solves)."""
    SLEPc = slepc("the explicit integrator (its stable step from the largest eigenvalue)")
    K = system.create_matrix()
    system.assemble_combination(q, 0.0, 1.0, 0.0, K, eliminate=False)
    mass = system.lumped.copy()
    # prescribed dofs do not move: give them a huge mass so they do not limit the step
    arr = mass.getArray()
    arr[system.prescribed_offsets(mass)] = 1e30 * max(1.0, float(np.abs(arr).max()))
    Minv = mass.copy()
    Minv.reciprocal()
    K.diagonalScale(Minv, None)                    # M^-1 K: same eigenvalues
    eps = SLEPc.EPS().create(comm=system.comm)
    eps.setOperators(K)
    eps.setProblemType(SLEPc.EPS.ProblemType.NHEP)
    eps.setWhichEigenpairs(SLEPc.EPS.Which.LARGEST_REAL)
    eps.setDimensions(1)
    eps.setTolerances(1e-6, 500)
    options = own_options("stability_", options)
    eps.setOptionsPrefix(options.prefix)
    with options.pushed():
        eps.setFromOptions()
        eps.solve()
    if eps.getConverged() < 1:
        raise RuntimeError("the stability estimate (largest eigenvalue) did not converge")
    lam = eps.getEigenvalue(0).real
    for obj in (eps, K, mass, Minv):
        obj.destroy()
    return float(np.sqrt(max(lam, 0.0)))


class ExplicitIntegrator:
    """Symplectic Euler or velocity Verlet with the lumped mass (no linear solves).

    ``options``: those of the stability estimate's eigensolver (prefix ``stability_``).
    """

    def __init__(self, system, scheme: str = "verlet", options: SolverOptions | None = None):
        if scheme not in SCHEMES:
            raise ValueError(f"explicit scheme must be one of {SCHEMES}")
        self.system, self.scheme = system, scheme
        self.options = own_options("stability_", options)
        system.lumped_kinetic = True   # the energy it conserves uses the mass it integrates with
        self.inv_mass = system.lumped.copy()
        self.inv_mass.reciprocal()
        self.f = system.create_vec()
        self.a = system.create_vec()
        self._tmp = system.create_vec()
        self._a_valid = False
        self.omega_max = None

    def check_step(self, q0: PETSc.Vec, h: float, source: str = "time.step") -> float:
        """Estimate the stability limit at q0 and refuse h above it; returns the limit."""
        self.omega_max = largest_frequency(self.system, q0, self.options)
        limit = 2.0 / self.omega_max if self.omega_max > 0 else np.inf
        terms = self.system.velocity_terms
        rate = self.system.comm.tompi4py().allreduce(
            terms.rate_bound() if terms is not None else 0.0, op=MPI.MAX)
        if rate > 0.0 and h > 2.0 / rate:
            # the regularised friction is viscous below friction.speed, at rate dry/speed: an
            # explicit step above 2/rate makes a resting node oscillate with growing amplitude
            raise ExperimentError(
                f"{source}: step {h:g} s is above the explicit stability limit {2.0 / rate:.4g} "
                f"s of the velocity-dependent forces (damping rate {rate:.4g} 1/s: the "
                "regularised dry friction's friction.dry / friction.speed, or drag.linear x the "
                "lumped area / mass of a node); use a smaller step, a larger friction.speed or "
                "an implicit integrator (be, si, alpha, midpoint)")
        if h > limit:
            raise ExperimentError(
                f"{source}: step {h:g} s is above the explicit stability limit {limit:.4g} s "
                f"(largest frequency {self.omega_max / (2 * np.pi):.4g} Hz, h < 2/omega_max); "
                f"use a step below {0.9 * limit:.3g} s or an implicit integrator (be, si, alpha, "
                "midpoint)")
        return limit

    def _acceleration(self, t: float, q: PETSc.Vec, v: PETSc.Vec | None,
                      out: PETSc.Vec) -> None:
        """out = M^-1 f(t, q, v) (v None: without the damping force)."""
        s = self.system
        s.internal_gradient(q, self.f)
        self.f.scale(-1.0)
        if v is not None:
            self.f.axpy(-1.0, s.damping_apply(v, self._tmp))
        self.f.axpy(1.0, s.gravity)
        self.f.axpy(1.0, s.tractions(t, self._tmp))
        out.pointwiseMult(self.f, self.inv_mass)
        s.zero_prescribed(out)

    def state(self) -> dict:
        """Verlet's acceleration of the last state (what its next half kick uses)."""
        return {"acceleration": self.a} if self.scheme == "verlet" and self._a_valid else {}

    def restore(self, t, q, v, state: dict) -> None:
        if "acceleration" in state:
            state["acceleration"].copy(self.a)
            self._a_valid = True

    def _damping_acceleration(self, v: PETSc.Vec) -> PETSc.Vec:
        """M^-1 D v (in a work vector)."""
        self.system.damping_apply(v, self._tmp)
        self._tmp.pointwiseMult(self._tmp, self.inv_mass)
        self.system.zero_prescribed(self._tmp)
        return self._tmp

    def step(self, t0, q0, v0, h, q1, v1) -> StepReport:
        s = self.system
        dq = q0.duplicate()
        report = StepReport()
        if self.scheme == "euler":
            self._acceleration(t0, q0, v0, self.a)
            v0.copy(v1)
            v1.axpy(h, self.a)
            q0.copy(q1)
            q1.axpy(h, v1)
            damping_v = v0
            load_t = t0
        else:
            if not self._a_valid:
                self._acceleration(t0, q0, v0, self.a)
            v0.copy(v1)
            v1.axpy(0.5 * h, self.a)                        # half-step velocity
            q0.copy(q1)
            q1.axpy(h, v1)
            s.apply_prescribed(q1, t0 + h)
            vh = v1.copy()
            # The damping force needs v1, which the kick computes: predict v1 with the damping
            # at vh, then kick with the damping at the prediction (second order with damping).
            self._acceleration(t0 + h, q1, None, self.a)
            predicted = vh.copy()
            predicted.axpy(0.5 * h, self.a)
            predicted.axpy(-0.5 * h, self._damping_acceleration(vh))
            self.a.axpy(-1.0, self._damping_acceleration(predicted))
            v1.axpy(0.5 * h, self.a)
            self._a_valid = True
            damping_v = predicted
            load_t = t0 + 0.5 * h
        s.apply_prescribed(q1, t0 + h)
        # supports: velocity of the prescribed motion over the step
        dq.waxpy(-1.0, q0, q1)
        rows = s.prescribed_offsets(v1)
        v1.getArray()[rows] = dq.getArray(readonly=True)[rows] / h
        report.dissipated = dq.dot(s.damping_apply(damping_v, self._tmp))
        report.external_work = dq.dot(s.tractions(load_t, self._tmp))
        dq.destroy()
        if self.scheme == "verlet":
            vh.destroy()
            predicted.destroy()
        return report

    def destroy(self) -> None:
        for v in (self.inv_mass, self.f, self.a, self._tmp):
            v.destroy()
