"""The marker misfit: weighted least squares between simulated and recorded marker positions.

For recorded positions d_kmc (frame k, marker m, component c; NaN where the marker was not
seen) and simulated positions s_kmc(p), the residual vector holds, for every seen entry,

    r_i = (s_kmc(p) - d_kmc) / sigma

and the objective is 1/2 |r|^2 (+ a Tikhonov term 1/2 lambda |z - z_start|^2 in scaled
parameters). Entries that were not seen are left out, never compared with zero. sigma is the
recording's noise level (``/noise position_std``) when it has one, otherwise 1 m, so that
residuals are in metres and the noise is estimated from the fit.

The optimizer works on scaled parameters z (see :mod:`petsoft.calibration.scaling`); this module
is where the chain rule dp/dz meets the forward model's derivatives d s / d p.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

#: Evaluations a misfit remembers (besides the first, kept for the "before" of a fit's report)
REMEMBERED = 4


class MarkerMisfit:
    """The least-squares problem of a calibration, in scaled parameters.

    Parameters
    ----------
    forward : petsoft.calibration.forward.ForwardModel
        Simulates marker positions for physical parameters p.
    data : ndarray (K, M, 3)
        Recorded positions; NaN where not seen.
    scaling : petsoft.calibration.scaling.ParameterScaling
    sigma : float
        Position noise level (m); residuals are divided by it.
    gradient : {"adjoint", "sensitivity", "fd"}
        How gradients and Jacobians are computed: the discrete adjoint (gradient only; the
        Jacobian then comes from forward sensitivities), forward sensitivities, or central
        finite differences.
    regularization : float
        lambda of the Tikhonov term in scaled parameters (0: none).
    misfit : optional
        A residual transform of the simulated positions (``residual(sim)``, ``jvp``, ``vjp``,
        ``value_gradient``; :class:`petsoft.calibration.misfit.SpectralMisfit`) used instead of
        the position differences over sigma; None: those (l2).
    """

    def __init__(self, forward, data: np.ndarray, scaling, sigma: float = 1.0,
                 gradient: str = "adjoint", regularization: float = 0.0, misfit=None):
        self.misfit = misfit
        if gradient not in ("adjoint", "sensitivity", "fd"):
            raise ValueError(f"unknown gradient method {gradient!r}")
        self.forward, self.scaling = forward, scaling
        self.data = np.asarray(data, dtype=float)
        self.seen = np.isfinite(self.data)
        self.sigma = float(sigma)
        self.gradient_method = gradient
        self.regularization = float(regularization)
        self.z_start = np.asarray(scaling.to_scaled(scaling.start), dtype=float)
        self.n = len(scaling.names)
        self.evaluations = 0
        self.last_simulation = None
        # Evaluations by z (bitwise): a calibration asks again for what its optimizer already
        # computed -- the simulation at the start (the report's "before") and the residual and
        # Jacobian at the optimum (the uncertainty) -- a forward run and a sensitivity run a
        # fit that the forward model, a pure function of z, need not repeat.
        self._remembered: OrderedDict[bytes, dict] = OrderedDict()
        self._first: tuple[bytes, dict] | None = None
        comm = getattr(forward, "comm", None)
        # the optimizer keeps the ranks in lock-step through this (mpi4py) communicator
        self.comm = comm.tompi4py() if hasattr(comm, "tompi4py") else comm

    @property
    def num_residuals(self) -> int:
        """Seen data entries (plus one per parameter with regularisation)."""
        if self.misfit is not None:
            return len(self.misfit.F_data) + (self.n if self.regularization > 0.0 else 0)
        return int(self.seen.sum()) + (self.n if self.regularization > 0.0 else 0)

    # -- pieces -------------------------------------------------------------------------------
    def data_residual(self, sim: np.ndarray) -> np.ndarray:
        """The seen data residuals over sigma of a simulation ``sim`` (K, M, 3): r(z) without
        the regularisation rows."""
        if self.misfit is not None:
            return self.misfit.residual(sim)
        return (sim[self.seen] - self.data[self.seen]) / self.sigma

    def _regularization_residual(self, z: np.ndarray) -> np.ndarray:
        return np.sqrt(self.regularization) * (np.asarray(z) - self.z_start)

    def _memo(self, z: np.ndarray) -> dict:
        """What was computed at ``z`` (``"sim"``, ``"rJ"``); the first point's entry is kept
        for good, the others while among the last :data:`REMEMBERED` points."""
        key = np.asarray(z, dtype=float).tobytes()
        if self._first is None:
            self._first = (key, {})
        if key == self._first[0]:
            return self._first[1]
        entry = self._remembered.pop(key, {})
        self._remembered[key] = entry
        while len(self._remembered) > REMEMBERED:
            self._remembered.popitem(last=False)
        return entry

    def simulate(self, z: np.ndarray) -> np.ndarray:
        """Simulated marker positions (K, M, 3) at scaled parameters z (a copy of the run
        already made at exactly this z, if one is remembered)."""
        memo = self._memo(z)
        if "sim" not in memo:
            self.evaluations += 1
            memo["sim"] = self.forward.simulate(self.scaling.to_physical(z))
        sim = memo["sim"].copy()
        self.last_simulation = sim
        return sim

    # -- the LeastSquaresProblem protocol ---------------------------------------------------
    def residual(self, z: np.ndarray) -> np.ndarray:
        """r(z): seen data residuals over sigma (then the regularisation rows)."""
        r = self.data_residual(self.simulate(z))
        if self.regularization > 0.0:
            r = np.concatenate([r, self._regularization_residual(z)])
        return r

    def _fd_scaled(self, z: np.ndarray, sim: np.ndarray, step: float = 1e-6) -> np.ndarray:
        """dsim/dz (K, M, 3, P) by differences in the scaled variables (all of order one, so
        one step size suits a Young's modulus and a support compliance of 1e-9 m/Pa alike):
        central inside the bounds, one-sided where a bound is closer than the step (a damping
        or a viscoelastic ratio starting at 0 must not be evaluated below it)."""
        lo, hi = self.scaling.bounds()
        cols = []
        for j in range(len(z)):
            e = step * max(abs(z[j]), 1.0)
            up, down = z.copy(), z.copy()
            up[j] += e
            down[j] -= e
            if z[j] + e > hi[j]:
                cols.append((sim - self.forward.simulate(self.scaling.to_physical(down))) / e)
            elif z[j] - e < lo[j]:
                cols.append((self.forward.simulate(self.scaling.to_physical(up)) - sim) / e)
            else:
                cols.append((self.forward.simulate(self.scaling.to_physical(up))
                             - self.forward.simulate(self.scaling.to_physical(down))) / (2 * e))
        return np.stack(cols, axis=-1)

    def residual_jacobian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(r, dr/dz) by forward sensitivities (or finite differences with ``gradient="fd"``);
        copies of those already computed at exactly this z, if remembered."""
        memo = self._memo(z)
        if "rJ" not in memo:
            memo["rJ"], memo["dsim"] = self._residual_jacobian(z)
            memo["sim"] = self.last_simulation
        self.last_simulation = memo["sim"].copy()
        r, J = memo["rJ"]
        return r.copy(), J.copy()

    def _residual_jacobian(self, z: np.ndarray):
        """((r, dr/dz), dsim/dp): dsim/dp (K, M, 3, P) from forward sensitivities, None with
        finite differences (they are taken in z)."""
        p = self.scaling.to_physical(z)
        self.evaluations += 1
        if self.gradient_method == "fd":
            sim = self.forward.simulate(p)
            return self._with_residual(z, sim, self._fd_scaled(z, sim), in_z=True), None
        sim, dsim = self.forward.jacobian(p)
        return self._with_residual(z, sim, dsim), dsim

    def sensitivities(self, z: np.ndarray) -> np.ndarray | None:
        """d sim / d p (K, M, 3, P: the physical parameters in order) at exactly ``z`` when a
        forward sensitivity run there is remembered (:meth:`residual_jacobian`,
        :meth:`remember_sensitivities`), else None (no run is made)."""
        dsim = self._memo(z).get("dsim")
        return None if dsim is None else dsim.copy()

    def _with_residual(self, z, sim, dsim, in_z: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(r, dr/dz) from the simulation at z and its derivatives dsim (K, M, 3, P): with
        respect to z (``in_z``, finite differences) or to the physical p (sensitivities)."""
        J = (self.misfit.jvp(sim, dsim) if self.misfit is not None
             else dsim[self.seen] / self.sigma)                    # (m, P)
        if not in_z:
            J = J * self.scaling.dp_dz(z)[None, :]              # chain rule dp/dz (diagonal)
        self.last_simulation = sim
        r = self.data_residual(sim)
        if self.regularization > 0.0:
            r = np.concatenate([r, self._regularization_residual(z)])
            J = np.vstack([J, np.sqrt(self.regularization) * np.eye(self.n)])
        return r, J

    def remember_sensitivities(self, z: np.ndarray, sim: np.ndarray, dsim: np.ndarray) -> None:
        """Take ``sim`` and ``dsim`` (K, M, 3, P: d sim / d p, the problem's parameters in
        order) as this problem's forward sensitivity run at ``z``: computed elsewhere (a
        diagnosis' scoring run at a candidate's start), so the optimizer's first evaluation
        costs no run. Not with finite-difference gradients (their Jacobian differs)."""
        if self.gradient_method == "fd":
            return
        if sim.shape != self.data.shape or dsim.shape != self.data.shape + (self.n,):
            raise ValueError(f"remembered sensitivities of shape {dsim.shape} for data of "
                             f"shape {self.data.shape} and {self.n} parameter(s)")
        memo = self._memo(z)
        memo["rJ"] = self._with_residual(z, np.array(sim), np.array(dsim))
        memo["dsim"] = np.array(dsim)
        memo["sim"] = self.last_simulation

    def value_gradient(self, z: np.ndarray) -> tuple[float, np.ndarray]:
        """f = 1/2 |r|^2 and df/dz (adjoint by default)."""
        if self.gradient_method != "adjoint":
            r, J = self.residual_jacobian(z)
            return 0.5 * float(r @ r), J.T @ r
        p = self.scaling.to_physical(z)
        seen, data, sigma = self.seen, self.data, self.sigma

        def dphi(sim):
            self.last_simulation = sim
            if self.misfit is not None:
                return self.misfit.value_gradient(sim)
            diff = np.where(seen, sim - np.where(seen, data, 0.0), 0.0) / sigma
            return 0.5 * float(np.sum(diff * diff)), diff / sigma

        self.evaluations += 1
        value, grad_p = self.forward.gradient(p, dphi)
        grad = np.asarray(grad_p) * self.scaling.dp_dz(z)
        if self.regularization > 0.0:
            rr = self._regularization_residual(z)
            value += 0.5 * float(rr @ rr)
            grad = grad + np.sqrt(self.regularization) * rr
        return value, grad

    def value(self, z: np.ndarray) -> float:
        r = self.residual(z)
        return 0.5 * float(r @ r)

    # -- reporting ----------------------------------------------------------------------------
    def rms(self, sim: np.ndarray) -> float:
        """Root-mean-square position error over seen entries (m)."""
        d = sim[self.seen] - self.data[self.seen]
        return float(np.sqrt(np.mean(d * d))) if d.size else 0.0

    def rms_per_marker(self, sim: np.ndarray) -> np.ndarray:
        """(M,) rms position error of each marker over its seen entries (NaN: never seen)."""
        d = np.where(self.seen, sim - np.where(self.seen, self.data, 0.0), 0.0)
        count = self.seen.sum(axis=(0, 2))
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.sqrt((d * d).sum(axis=(0, 2)) / count)
