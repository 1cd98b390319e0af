"""Independent linear oscillators q_i'' + (alpha + beta w_i^2) q_i' + w_i^2 q_i = 0.

The same interface as :class:`~petsoft.dynamics.system.DynamicSystem` (M = I, K = diag(w^2)), so
the integrators run on it unchanged. Its exact solution makes it the independent reference for
the integrators' order of accuracy and artificial damping (``petsoft damping``).
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from petsoft.dynamics.interfaces import SystemDefaults


class OscillatorSystem(SystemDefaults):
    """N uncoupled unit-mass oscillators with angular frequencies ``omega``.

    Parameters
    ----------
    omega : array_like (N,)
        Angular frequencies (rad/s), > 0.
    damping_mass, damping_stiffness : float
        Rayleigh alpha and beta: the damping of oscillator i is alpha + beta w_i^2.
    comm : PETSc.Comm
    """

    def __init__(self, omega, damping_mass: float = 0.0, damping_stiffness: float = 0.0,
                 comm: PETSc.Comm | None = None):
        self.comm = comm if comm is not None else PETSc.COMM_WORLD
        omega = np.atleast_1d(np.asarray(omega, dtype=float))
        self.n = len(omega)
        self.alpha, self.beta = float(damping_mass), float(damping_stiffness)
        self._proto = PETSc.Vec().createMPI(self.n, comm=self.comm)
        lo, hi = self._proto.getOwnershipRange()
        self.omega2 = omega[lo:hi] ** 2
        self.M = self._diagonal(np.ones(hi - lo))
        self.lumped = self.create_vec()
        self.lumped.set(1.0)
        self.gravity = self.create_vec()
        self.gravity.zeroEntries()
        self.time_dependent_loads = False
        self.lumped_kinetic = False  # M = I: lumped and consistent coincide

    def _diagonal(self, values: np.ndarray, out: PETSc.Mat | None = None) -> PETSc.Mat:
        if out is None:
            out = PETSc.Mat().createAIJ((self.n, self.n), nnz=(1, 0), comm=self.comm)
        d = self.create_vec()
        d.getArray()[:] = values
        out.zeroEntries()
        out.setDiagonal(d)
        out.assemble()
        d.destroy()
        return out

    # -- the integrators' interface --------------------------------------------------------------
    def create_vec(self) -> PETSc.Vec:
        return self._proto.duplicate()

    def create_matrix(self) -> PETSc.Mat:
        return self._diagonal(np.zeros(len(self.omega2)))

    def near_nullspace(self):
        return None

    def linear_defaults(self, ksp: PETSc.KSP) -> None:
        """A diagonal system: one Jacobi-preconditioned iteration is exact."""
        ksp.setType(PETSc.KSP.Type.CG)
        ksp.getPC().setType(PETSc.PC.Type.JACOBI)
        ksp.setTolerances(rtol=1e-14, atol=1e-50)

    def assemble_combination(self, q, a_mass, b_tangent, c_reference, out, eliminate=True,
                             velocity=0.0, reuse=False):
        # no velocity-dependent forces: ``velocity`` is unused
        return self._diagonal(a_mass + (b_tangent + c_reference) * self.omega2, out)

    def internal_gradient(self, q: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        out.getArray()[:] = self.omega2 * q.getArray(readonly=True)
        return out

    def elastic_energy(self, q: PETSc.Vec) -> float:
        local = 0.5 * float(np.sum(self.omega2 * q.getArray(readonly=True) ** 2))
        return self.comm.tompi4py().allreduce(local)

    def kinetic_energy(self, v: PETSc.Vec) -> float:
        return 0.5 * v.dot(v)

    def gravitational_energy(self, q: PETSc.Vec) -> float:
        return 0.0

    def damping_apply(self, v: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        out.getArray()[:] = (self.alpha + self.beta * self.omega2) * v.getArray(readonly=True)
        return out

    def tractions(self, t: float, out: PETSc.Vec) -> PETSc.Vec:
        out.zeroEntries()
        return out

    def apply_prescribed(self, vec: PETSc.Vec, t: float) -> None:
        """No supports."""

    def zero_prescribed(self, vec: PETSc.Vec) -> None:
        """No supports."""

    def prescribed_offsets(self, vec: PETSc.Vec) -> np.ndarray:
        return np.zeros(0, dtype=np.int64)

    def initial_state(self, monitor=None) -> tuple[PETSc.Vec, PETSc.Vec]:
        """Every oscillator displaced by 1 and at rest (q = 1, v = 0): the start of the damping
        analysis (:func:`petsoft.dynamics.damping_analysis.measure_oscillators`)."""
        q, v = self.create_vec(), self.create_vec()
        q.set(1.0)
        v.set(0.0)
        return q, v

    # -- the exact solution -------------------------------------------------------------------
    def exact(self, t: float, q0: np.ndarray, v0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local entries of the exact q(t), v(t) from local initial values (underdamped)."""
        w2 = self.omega2
        d = self.alpha + self.beta * w2
        wd = np.sqrt(w2 - 0.25 * d**2)
        e = np.exp(-0.5 * d * t)
        c, s = np.cos(wd * t), np.sin(wd * t)
        b = (v0 + 0.5 * d * q0) / wd
        q = e * (q0 * c + b * s)
        v = e * (-0.5 * d * (q0 * c + b * s) + (-q0 * wd * s + b * wd * c))
        return q, v

    def destroy(self) -> None:
        for obj in (self._proto, self.M, self.lumped, self.gravity):
            obj.destroy()
