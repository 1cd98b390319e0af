"""The Galerkin-reduced equations of motion, stepped by the full model's schemes.

With q = q_ref + V a (V an M-orthonormal basis zero on prescribed rows, q_ref holding the
supports) the reduced equations are

    V^T M V a'' + V^T D V a' + V^T f_int(q_ref + V a) = V^T (f_g + f_t(t)),

D the system's linear damping (Rayleigh alpha M + beta K0 and linear drag: V^T D V from r
products D v_j). They are integrated by the same discrete schemes as the full model -- petsoft's
generalized-alpha (:class:`petsoft.dynamics.alpha.GeneralizedAlpha`, started from the consistent
acceleration, predictor q0 + h v0) and backward Euler -- with Newton on the r unknowns and the
reduced tangent V^T K(q) V. A basis that spans the free dofs therefore reproduces the full run to
the Newton tolerance. The elastic force and tangent come from a force provider: the full
system's assembly (:class:`FullForces`, no hyper-reduction) or a reduced mesh
(:class:`petsoft.reduced.ecsw.SampledForces`). Newton keeps the factors of its last reduced
tangent across iterations and steps while the residual falls fast (a chord, as the full model's),
so most iterations evaluate the force only.

Markers are observed through the dense (3 M x r) matrix H V, computed once: positions
X + B q_ref + H V a.

Not reduced (refused with a clear error): moving supports, the viscoelastic branch, quadratic
drag and dry friction (velocity terms that are not linear).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from petsc4py import PETSc
from scipy.linalg import lu_factor, lu_solve

from petsoft.dynamics.alpha import alpha_parameters
from petsoft.errors import ExperimentError, SolverError
from petsoft.reduced.basis import PODBasis

#: The schemes a reduced model steps.
METHODS = ("alpha", "be")
#: Newton on the reduced unknowns: converged when the update is below STOL |q1| (|q1| floored
#: by the basis coordinates' scale) or the residual fell by RTOL.
RTOL, STOL, MAX_IT = 1e-12, 1e-13, 25
#: The chord keeps its tangent while each iteration divides the residual by at least 1/this.
CHORD_RATE = 0.1


class FullForces:
    """V^T f_int(q_ref + V a) and V^T K V by the full system's assembly (no hyper-reduction).

    Parameters
    ----------
    system : DynamicSystem
    basis : PODBasis
    q_ref : PETSc.Vec
        The reference displacement (copied).
    """

    def __init__(self, system, basis: PODBasis, q_ref: PETSc.Vec):
        self.system, self.basis = system, basis
        self.q_ref = q_ref.copy()
        self._q, self._g = system.create_vec(), system.create_vec()
        self._K = system.create_matrix()
        #: full assemblies made (gradient, tangent): the online cost's measure
        self.counts = {"gradients": 0, "tangents": 0}
        self._zero_derivatives = None

    def state(self, a: np.ndarray) -> PETSc.Vec:
        self.q_ref.copy(self._q)
        return self.basis.expand(a, self._q, add=True)

    def force(self, a: np.ndarray) -> np.ndarray:
        self.counts["gradients"] += 1
        return self.basis.project(self.system.internal_gradient(self.state(a), self._g))

    def tangent(self, a: np.ndarray) -> np.ndarray:
        self.counts["tangents"] += 1
        self.system.assemble_combination(self.state(a), 0.0, 1.0, 0.0, self._K, eliminate=False)
        return self.basis.project_matrix(self._K)

    def parameters_changed(self) -> None:
        """Nothing to follow: the assembly reads the system's current parameters."""
        self._zero_derivatives = None

    def parameter_force(self, a: np.ndarray, names) -> np.ndarray:
        """(r, P): d/dp_j of V^T grad W(q_ref + V a), the potential force (elastic and nodal
        terms), by the system's residual derivatives at (q, v = 0, a = 0) minus those at
        q = 0 (what remains there is the load's derivative, which the caller holds apart)."""
        names = list(names)
        if self._zero_derivatives is None or self._zero_derivatives[0] != names:
            self._q.zeroEntries()
            self._zero_derivatives = (names, projected_derivatives(
                self.system, self.basis, names, self._q, self._q, self._q))
        self._g.zeroEntries()
        at_q = projected_derivatives(self.system, self.basis, names, self.state(a), self._g,
                                     self._g)
        return at_q - self._zero_derivatives[1]

    def destroy(self) -> None:
        for obj in (self.q_ref, self._q, self._g, self._K):
            obj.destroy()


def projected_derivatives(system, basis: PODBasis, names, q, v, a) -> np.ndarray:
    """(r, P): V^T d r/d p_j at the full state (q, v, a) (the system's residual derivatives,
    :class:`petsoft.dynamics.parameters.ParameterDerivatives`). Collective; O(mesh)."""
    vecs = system.parameter_derivatives(q, v, a).vectors(list(names))
    out = np.column_stack([basis.project(x) for x in vecs]) if vecs else \
        np.zeros((basis.size, 0))
    for x in vecs:
        x.destroy()
    return out


@dataclass
class ReducedRun:
    """A reduced run: coordinates and markers at every step.

    Attributes
    ----------
    coordinates : ndarray (N + 1, r)
        a_n, q_n = q_ref + V a_n.
    markers : ndarray (N + 1, M, 3)
        Marker positions at every step.
    newton_iterations : int
        Summed over the steps.
    """

    coordinates: np.ndarray
    markers: np.ndarray
    newton_iterations: int

    def frames(self, frame_times, h: float) -> np.ndarray:
        """(K, M, 3) markers at ``frame_times``, linear between the two neighbouring steps
        (as the forward model interpolates)."""
        return at_frames(self.markers, frame_times, h)


def at_frames(values: np.ndarray, frame_times, h: float) -> np.ndarray:
    """``values`` (N + 1, ...) given at the steps t_n = n h, at ``frame_times`` (K, ...):
    linear between the two neighbouring steps (as the forward model interpolates)."""
    t = np.asarray(frame_times, dtype=float) / h
    n = len(values) - 1
    if t.min() < -1e-9 or t.max() > n + 1e-9:
        raise ValueError(f"frame times outside the run [0, {n * h:g}] s")
    i = np.clip(np.floor(t + 1e-9).astype(int), 0, max(n - 1, 0))
    w = np.clip(t - i, 0.0, 1.0).reshape((-1,) + (1,) * (values.ndim - 1))
    j = np.minimum(i + 1, n)
    return (1.0 - w) * values[i] + w * values[j]


class ReducedModel:
    """The Galerkin-reduced dynamics of a system on a basis, with its marker observation.

    Parameters
    ----------
    system : DynamicSystem
        Its parameters may be changed (:meth:`set_parameters`); the reduced operators follow.
    basis : PODBasis
    q_ref : PETSc.Vec
        The reference displacement (the run's q_0: the supports' values).
    observer
        ``observe(q) -> (M, 3)`` = X + B q (same on every rank), e.g. a
        :class:`~petsoft.calibration.observation.MarkerObserver`.
    forces : FullForces or SampledForces, optional
        The elastic force provider (default: :class:`FullForces`).
    method : {"alpha", "be"}
    radius : float
        Generalized-alpha's spectral radius at infinity.
    """

    def __init__(self, system, basis: PODBasis, q_ref: PETSc.Vec, observer, forces=None,
                 method: str = "alpha", radius: float = 0.5):
        if method not in METHODS:
            raise ExperimentError(f"reduced model: integrator {method!r}: reduced are "
                                  f"{', '.join(METHODS)}")
        if system.moving_boundary:
            raise ExperimentError("reduced model: moving supports are not reduced (the basis "
                                  "is zero on prescribed rows); use the full model")
        branch = system.viscoelastic
        if branch is not None and branch.active:
            raise ExperimentError("reduced model: the viscoelastic branch is not reduced; use "
                                  "the full model")
        if system.velocity_terms.nonlinear:
            raise ExperimentError("reduced model: quadratic drag and dry friction are not "
                                  "reduced (only linear velocity terms); use the full model")
        self.system, self.basis, self.method = system, basis, method
        self.radius = float(radius)
        self.forces = forces if forces is not None else FullForces(system, basis, q_ref)
        self.q_ref = q_ref.copy()
        self._w1, self._w2 = system.create_vec(), system.create_vec()
        self.H = self._observation(observer)
        self.markers_ref = np.asarray(observer.observe(self.q_ref), dtype=float).reshape(-1, 3)
        self.scale = 1.0
        #: Newton on the kept factors of an earlier tangent (chord) while it converges fast
        self.chord = True
        self._factors = None
        self.parameters_changed()

    # -- operators --------------------------------------------------------------------------
    def _observation(self, observer) -> np.ndarray:
        """H V (3 M x r): B v_j = observe(c v_j) - observe(0), scaled so no digits are lost."""
        zero = self._w1
        zero.zeroEntries()
        X = np.asarray(observer.observe(zero), dtype=float).reshape(-1)
        cols = []
        for j in range(self.basis.size):
            v = self.basis.expand_column(j, self._w1)
            size = v.norm(PETSc.NormType.INFINITY)
            if size == 0.0:
                cols.append(np.zeros_like(X))
                continue
            v.scale(1.0 / size)
            cols.append((np.asarray(observer.observe(v), dtype=float).reshape(-1) - X) * size)
        return np.column_stack(cols)

    def parameters_changed(self) -> None:
        """Recompute V^T M V, V^T D V and V^T f_g (after the system's parameters changed)."""
        s, V = self.system, self.basis
        self.Mr = V.project_matrix(s.M)
        # linear damping (Rayleigh and linear drag): V^T D V from r products D v_j
        self.Dr = V.project_operator(s.damping_apply, self._w1, self._w2)
        self.gr = V.project(s.gravity)
        self._time_loads = s.time_dependent_loads
        self._tr = None if self._time_loads else V.project(s.tractions(0.0, self._w1))
        self.forces.parameters_changed()

    def set_parameters(self, values: dict) -> None:
        """Change the system's parameters (:meth:`DynamicSystem.set_parameters`) and follow."""
        self.system.set_parameters(values)
        self.parameters_changed()

    def load(self, t: float) -> np.ndarray:
        if self._time_loads:
            return self.gr + self.basis.project(self.system.tractions(t, self._w1))
        return self.gr + self._tr

    def coordinates(self, x: PETSc.Vec) -> np.ndarray:
        """(V^T M V)^-1 V^T M x: the coordinates of the M-orthogonal projection of x (a
        velocity) with the current mass (a changed density leaves V M-orthonormal no more)."""
        self.system.M.mult(x, self._w1)
        return np.linalg.solve(self.Mr, self.basis.project(self._w1))

    def markers(self, a: np.ndarray) -> np.ndarray:
        return self.markers_ref + (self.H @ a).reshape(-1, 3)

    # -- stepping ---------------------------------------------------------------------------
    def _newton(self, residual, jacobian, x: np.ndarray, what: str) -> tuple[np.ndarray, int]:
        """Newton on the reduced unknowns; with :attr:`chord`, on the factors of the last
        tangent (kept across steps) while the residual falls at least by :data:`CHORD_RATE` an
        iteration, a new tangent where it does not (the full model's chord does the same)."""
        r0 = prev = None
        for it in range(1, MAX_IT + 1):
            R = residual(x)
            norm = float(np.linalg.norm(R))
            if not np.isfinite(norm):
                # (an inverted element: the force providers return NaN on every rank)
                raise SolverError(f"reduced model: a non-finite residual at {what} (an "
                                  "element inverted?)")
            if r0 is None:
                r0 = norm
                if norm == 0.0:
                    return x, 0
            elif norm <= RTOL * r0:
                return x, it - 1
            if (self._factors is None or not self.chord
                    or (prev is not None and norm > CHORD_RATE * prev)):
                self._factors = lu_factor(jacobian(x))
            prev = norm
            dx = lu_solve(self._factors, -R)
            x = x + dx
            if np.linalg.norm(dx) <= STOL * max(np.linalg.norm(x), self.scale):
                return x, it
        raise SolverError(f"reduced model: Newton did not converge in {MAX_IT} iterations at "
                          f"{what} (residual {norm:.3g} from {r0:.3g})")

    def run(self, v0: PETSc.Vec, h: float, nsteps: int, on_step=None) -> ReducedRun:
        """Step from q = q_ref (a = 0) and velocity V^T M v0 for ``nsteps`` steps of ``h``.

        ``on_step(n, (q0, v0, a0), (q1, v1, a1))`` is called after each converged step (the
        coordinates of displacement, velocity and acceleration at its start and end; the
        accelerations None for backward Euler), e.g. by the sensitivities
        (:mod:`petsoft.reduced.sensitivity`)."""
        r = self.basis.size
        a = np.zeros(r)
        v = self.coordinates(v0)
        self._factors = None        # a run's first step takes a new tangent
        # the coordinates' own scale floors the update test (a = 0 at the start)
        self.scale = max(float(np.linalg.norm(v)) * h, 1e-300)
        coords = np.empty((nsteps + 1, r))
        coords[0] = a
        its = 0
        if self.method == "alpha":
            acc = np.linalg.solve(self.Mr, self.load(0.0) - self.forces.force(a) - self.Dr @ v)
            for n in range(nsteps):
                a1, v1, acc1, k = self._alpha_step(n * h, h, a, v, acc)
                if on_step is not None:
                    on_step(n, (a, v, acc), (a1, v1, acc1))
                a, v, acc = a1, v1, acc1
                coords[n + 1] = a
                its += k
        else:
            for n in range(nsteps):
                a1, v1, k = self._be_step(n * h, h, a, v)
                if on_step is not None:
                    on_step(n, (a, v, None), (a1, v1, None))
                a, v = a1, v1
                coords[n + 1] = a
                its += k
        markers = self.markers_ref[None] + (coords @ self.H.T).reshape(nsteps + 1, -1, 3)
        return ReducedRun(coords, markers, its)

    def _alpha_step(self, t0, h, q0, v0, a0):
        am, af, g, b = alpha_parameters(self.radius)
        Mr, Dr, forces = self.Mr, self.Dr, self.forces
        f = self.load(t0 + af * h)

        def state(q1):
            a1 = (q1 - q0 - h * v0 - h * h * (0.5 - b) * a0) / (b * h * h)
            v1 = v0 + h * ((1.0 - g) * a0 + g * a1)
            return a1, v1, q0 + af * (q1 - q0), v0 + af * (v1 - v0)

        def residual(q1):
            a1, _, qf, vf = state(q1)
            return Mr @ (a0 + am * (a1 - a0)) + forces.force(qf) + Dr @ vf - f

        def jacobian(q1):
            qf = state(q1)[2]
            c = af * g / (b * h)
            return am / (b * h * h) * Mr + af * forces.tangent(qf) + c * Dr

        q1, its = self._newton(residual, jacobian, q0 + h * v0, f"t = {t0 + h:.6g} s")
        a1, v1, _, _ = state(q1)
        return q1, v1, a1, its

    def _be_step(self, t0, h, q0, v0):
        Mr, Dr, forces = self.Mr, self.Dr, self.forces
        f = self.load(t0 + h)

        def residual(q1):
            v1 = (q1 - q0) / h
            return Mr @ (v1 - v0) / h + forces.force(q1) + Dr @ v1 - f

        def jacobian(q1):
            return Mr / h**2 + forces.tangent(q1) + Dr / h

        q1, its = self._newton(residual, jacobian, q0 + h * v0, f"t = {t0 + h:.6g} s")
        return q1, (q1 - q0) / h, its

    def destroy(self) -> None:
        for obj in (self.q_ref, self._w1, self._w2):
            obj.destroy()
        self.forces.destroy()
        self.basis.destroy()


def steps_for(frame_times, h: float) -> int:
    """The number of steps a run to the last frame takes (as the forward model counts)."""
    return max(1, math.ceil(float(np.max(frame_times)) / h - 1e-9))
