"""Analytic least-squares problems for testing and demonstrating the optimizers.

Each problem follows :class:`petsoft.calibration.optimize.LeastSquaresProblem` in scaled
variables and is *distributed*: its data points are split across the ranks of ``comm`` and each
evaluation gathers the residual pieces, so it is collective like the real marker misfit (a rank
that skipped an evaluation would hang the others). Problems:

- :class:`ExponentialDecay` ``a exp(-k t)``: a, k > 0, log-scaled;
- :class:`Rosenbrock` residual ``(10 (z1 - z0^2), 1 - z0)``, the curved valley of the classic test;
- :class:`ShiftedOscillation` ``sin(w (t - s))`` with noisy data: non-convex in the frequency w
  and shift s (the lecture's shifted-oscillation example), many local minima;
- :class:`LinearModel` ``A p - b``: exact Gaussian statistics for covariance checks.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI

from petsoft.calibration.scaling import ParameterScaling


class _Distributed:
    """Residual entries split in contiguous blocks over the ranks and allgathered."""

    def __init__(self, m: int, comm):
        self.comm = MPI.COMM_SELF if comm is None else comm
        size, rank = self.comm.Get_size(), self.comm.Get_rank()
        bounds = np.linspace(0, m, size + 1).round().astype(int)
        self.local = slice(bounds[rank], bounds[rank + 1])
        self.m = m

    def _gather(self, local):
        if self.comm.Get_size() == 1:
            return local
        return np.concatenate(self.comm.allgather(local), axis=0)

    def residual(self, z):
        return self._gather(self._local_residual(np.asarray(z, float)))

    def residual_jacobian(self, z):
        z = np.asarray(z, float)
        return (self._gather(self._local_residual(z)),
                self._gather(self._local_jacobian(z)))

    def value_gradient(self, z):
        r, J = self.residual_jacobian(z)
        return 0.5 * float(r @ r), J.T @ r


class ExponentialDecay(_Distributed):
    """``y(t) = a exp(-k t)`` on t in [0, 3]; truth (a, k) = (2, 1.3) plus optional noise."""

    names = ("a", "k")
    truth = np.array([2.0, 1.3])

    def __init__(self, comm=None, m: int = 40, noise: float = 0.0, seed: int = 1,
                 start=(1.0, 0.4)):
        super().__init__(m, comm)
        self.t = np.linspace(0.0, 3.0, m)
        rng = np.random.default_rng(seed)
        self.y = self.model(self.truth) + noise * rng.standard_normal(m)
        self.scaling = ParameterScaling(self.names, start, [1e-2, 1e-2], [1e2, 1e2])
        self.n = 2

    def model(self, p, t=None):
        t = self.t if t is None else t
        return p[0] * np.exp(-p[1] * t)

    def _local_residual(self, z):
        p = self.scaling.to_physical(z)
        t = self.t[self.local]
        return self.model(p, t) - self.y[self.local]

    def _local_jacobian(self, z):
        p = self.scaling.to_physical(z)
        t = self.t[self.local]
        e = np.exp(-p[1] * t)
        return self.scaling.jacobian_to_scaled(z, np.column_stack([e, -p[0] * t * e]))


class Rosenbrock(_Distributed):
    """Residual ``(10 (z1 - z0^2), 1 - z0)``: f = Rosenbrock/2, minimum 0 at (1, 1)."""

    def __init__(self, comm=None):
        super().__init__(2, comm)
        self.n = 2

    def _local_residual(self, z):
        return np.array([10.0 * (z[1] - z[0] ** 2), 1.0 - z[0]])[self.local]

    def _local_jacobian(self, z):
        return np.array([[-20.0 * z[0], 10.0], [-1.0, 0.0]])[self.local]


class ShiftedOscillation(_Distributed):
    """``q(t) = sin(w (t - s))`` fitted to noisy samples on t in [0, 10].

    The truth is (w, s) = (2, 0.3) with 5 % noise (of the unit amplitude), as in the lecture's
    example; the misfit oscillates in w with period ~ 2 pi / 10 and has a local minimum in
    nearly every such interval: a gradient method started at w = 1.2 stops in one of them.
    w is log-scaled in [0.5, 4], s affine in [-1, 1].
    """

    names = ("w", "s")
    truth = np.array([2.0, 0.3])

    def __init__(self, comm=None, m: int = 200, noise: float = 0.05, seed: int = 7,
                 start=(1.2, 0.0)):
        super().__init__(m, comm)
        self.t = np.linspace(0.0, 10.0, m)
        rng = np.random.default_rng(seed)
        self.y = self.model(self.truth) + noise * rng.standard_normal(m)
        self.scaling = ParameterScaling(self.names, start, [0.5, -1.0], [4.0, 1.0])
        self.n = 2

    def model(self, p, t=None):
        t = self.t if t is None else t
        return np.sin(p[0] * (t - p[1]))

    def _local_residual(self, z):
        p = self.scaling.to_physical(z)
        return self.model(p, self.t[self.local]) - self.y[self.local]

    def _local_jacobian(self, z):
        p = self.scaling.to_physical(z)
        t = self.t[self.local]
        c = np.cos(p[0] * (t - p[1]))
        return self.scaling.jacobian_to_scaled(z, np.column_stack([c * (t - p[1]), -c * p[0]]))

    def landscape(self, w, s):
        """The objective ``1/2 |r|^2`` on a grid of physical (w, s) (vectorized, rank-local)."""
        W, S = np.meshgrid(w, s, indexing="ij")
        q = np.sin(W[..., None] * (self.t - S[..., None]))
        return 0.5 * np.sum((q - self.y) ** 2, axis=-1)


class LinearModel(_Distributed):
    """``r = A p - b`` with ``b = A p_true + noise``; affine scaling of p (covariance checks)."""

    names = ("c0", "c1", "c2")

    def __init__(self, comm=None, m: int = 30, noise: float = 0.1, seed: int = 3, b=None):
        super().__init__(m, comm)
        t = np.linspace(0.0, 1.0, m)
        self.A = np.column_stack([np.ones(m), t, np.sin(3 * t)])
        self.truth = np.array([1.0, -2.0, 0.5])
        rng = np.random.default_rng(seed)
        self.b = self.A @ self.truth + noise * rng.standard_normal(m) if b is None else b
        self.scaling = ParameterScaling(self.names, [0.0, 0.0, 0.0], widths=[1.0, 2.0, 0.5])
        self.n = 3

    def _local_residual(self, z):
        return self.A[self.local] @ self.scaling.to_physical(z) - self.b[self.local]

    def _local_jacobian(self, z):
        return self.scaling.jacobian_to_scaled(z, self.A[self.local])
