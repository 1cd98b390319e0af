"""Local minimization of a least-squares misfit over scaled parameters: GD, Newton, L-BFGS, GN, NM.

This module owns the optimizers and the small-problem protocol they work on. It does not know
what a marker or a forward model is: a caller (the marker misfit) wraps its residual as a
:class:`LeastSquaresProblem` in scaled variables z (see :mod:`petsoft.calibration.scaling`).

Methods (``method=``):

``"gd"``
    Own steepest descent with Armijo backtracking (halving), projected onto the bounds: the
    trial point is ``clip(z - a g)`` and it is accepted when
    ``f(z_a) <= f(z) + c1 g.(z_a - z)``. The first trial step is ``min(alpha_max, 2 a_prev)``
    (the lecture starts every search at ``alpha_max``; doubling the last accepted step saves
    evaluations on badly scaled problems and keeps the same acceptance test). Stops on
    ``|projected g| <= gatol`` or ``<= grtol |f|``; a failed line search whose first trial
    predicted a decrease below ~1e3 machine epsilons of f is reported as
    ``CONVERGED_ROUNDOFF`` (no step can pass the test in floating point), otherwise as
    ``DIVERGED_LS_FAILURE``.
``"newton"``
    TAO ``nls`` (``bnls`` when there are bounds) with an n x n Hessian: the Gauss-Newton matrix
    ``J^T J`` when the problem provides ``residual_jacobian``, else central finite differences
    of the gradient (``result.hessian`` says which).
``"lbfgs"``
    TAO ``blmvm`` (limited-memory BFGS with bounds; without bounds it is plain L-BFGS).
``"gauss-newton"``
    Own projected Levenberg-Marquardt (Gauss-Newton steps J^T J d = -J^T r damped by
    mu diag(J^T J), Nielsen's update of mu from the ratio of actual to predicted decrease;
    a parameter the step would carry past a bound is held there and the others solved
    again; positive parameters step along straight lines in log p), with NL2SOL's structured
    secant term for large-residual fits (J^T J + S when that model predicted the last
    decrease better: superlinear where plain Gauss-Newton is linear) and a statistical stop
    (``lm_dtol``).
    Only accepted points pay for a Jacobian; a rejected trial costs one residual. TAO brgn
    (below) evaluated the forward model outside the bounds and oscillated on a 4-parameter
    elastodynamic fit, where this converged.
``"brgn"``
    TAO ``brgn`` (bounded regularized Gauss-Newton) with the ``lm`` (Levenberg-Marquardt)
    regularization by default: brgn's own default ``l2prox`` stopped at a biased point in
    petsc4py 3.18.5 (z = 0.9999 instead of 1 on r = z - 1, weight 1e-4); ``lm`` is exact there,
    on Rosenbrock and with an active bound. ``-cal_tao_brgn_regularization_type`` overrides.
``"nelder-mead"``
    TAO ``nm``. TAO's simplex has no bounds, so the objective is evaluated at the clipped point
    plus a penalty ``mu (1 + |f|) |z - clip(z)|^2`` outside; the returned z is clipped. TAO nm
    stops on the spread of f over the simplex, so its default tolerance is ``gatol**2`` (z to
    about ``gatol``) unless the caller gives ``gatol``. Its simplex can collapse at a
    non-stationary point, so it is restarted from its result with a simplex of size
    ``nm_restart_lambda`` while that still lowers f (at most ``nm_restarts`` times).

Every rank runs the same deterministic algorithm on its own copy of the (small, replicated)
vectors: TAO lives on ``COMM_SELF``, and every evaluation goes through the problem, which may be
collective on ``problem.comm``. To keep ranks in lock-step even if a collective reduction were to
round differently, every evaluation result is broadcast from rank 0 of ``problem.comm``, so all
ranks take identical decisions and make the same sequence of collective calls.

A failed evaluation (non-finite residual, objective or gradient, or a forward simulation that
raised :class:`~petsoft.errors.SolverError` / :class:`~petsoft.errors.InvertedElementError` at a
trial point -- on every rank, as petsoft's solvers do) counts as an infinite objective: line
searches, the LM damping and the simplex step back from it, and such a point is never accepted
(``result.failures`` lists them). A failure at the start is an error.

Options: defaults in code, then the caller's ``options``, then the PETSc options database under
``prefix`` (``-cal_tao_gatol 1e-10``, ``-cal_tao_max_it 50``, ``-cal_tao_nm_lambda 0.2`` ...):
``setFromOptions()`` is called last, so the command line wins. The own methods ``"gd"`` and
``"gauss-newton"`` read the same ``-<prefix>tao_gatol/grtol/max_it/max_funcs`` options, and
``"gd"`` also ``-<prefix>gd_c1`` and ``-<prefix>gd_alpha_max``.
"""

from __future__ import annotations

import sys
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from petsc4py import PETSc

from petsoft.errors import InvertedElementError, SolverError
from petsoft.solvers.convergence import outcome
from petsoft.solvers.options import SolverOptions, own_options, scoped_defaults

METHODS = ("gd", "newton", "lbfgs", "gauss-newton", "brgn", "nelder-mead")
#: Levenberg-Marquardt's default iteration limit (option ``<prefix>tao_max_it``)
LM_MAX_IT = 200
#: the reason of a minimization ended by its caller's ``stop`` (:func:`minimize`)
STOPPED = "STOPPED_BY_CALLER"



class OptimizationError(SolverError):
    """An optimization cannot run or went wrong (bad method, missing derivatives, NaN...)."""


@runtime_checkable
class LeastSquaresProblem(Protocol):
    """What the optimizers need from a calibration problem, in scaled variables z (shape (n,)).

    Attributes
    ----------
    n : int
        Number of parameters.
    comm : mpi4py.MPI.Comm, optional
        Communicator on which the evaluations are collective (absent or None: rank-local).

    Methods ``residual_jacobian`` and ``value_gradient`` are optional: without
    ``value_gradient`` the gradient is ``J^T r``; without either, wrap the problem in
    :class:`FiniteDifferenceProblem`.
    """

    n: int

    def residual(self, z: np.ndarray) -> np.ndarray:
        """Residuals r(z), shape (m,), replicated on all ranks (data units, or divided by sigma)."""

    def residual_jacobian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residuals and their Jacobian dr/dz, shapes (m,) and (m, n)."""

    def value_gradient(self, z: np.ndarray) -> tuple[float, np.ndarray]:
        """Objective ``f = 1/2 |r|^2`` (plus any regularization) and its gradient df/dz."""


class LeastSquares:
    """A :class:`LeastSquaresProblem` from plain callables of physical parameters.

    Parameters
    ----------
    residual : callable p -> r (m,)
        Residuals at physical parameters p.
    n : int
        Number of parameters.
    jacobian : callable p -> dr/dp (m, n), optional
        Residual Jacobian with respect to p (converted to z by the chain rule).
    scaling : ParameterScaling, optional
        Map z -> p; without it z = p.
    comm : mpi4py.MPI.Comm, optional
        Communicator on which the callables are collective.
    """

    def __init__(self, residual: Callable, n: int, jacobian: Callable | None = None,
                 scaling=None, comm=None):
        self._residual = residual
        self._jacobian = jacobian
        self.scaling = scaling
        self.n = int(n)
        self.comm = comm
        if jacobian is None:
            # Hide the optional methods so optimizers see what is really available.
            self.residual_jacobian = None
            self.value_gradient = None

    def _p(self, z):
        z = np.asarray(z, dtype=float)
        return z if self.scaling is None else self.scaling.to_physical(z)

    def residual(self, z):
        """Residuals at scaled parameters z."""
        return np.asarray(self._residual(self._p(z)), dtype=float).reshape(-1)

    def residual_jacobian(self, z):
        """Residuals and dr/dz at z."""
        p = self._p(z)
        r = np.asarray(self._residual(p), dtype=float).reshape(-1)
        J = np.asarray(self._jacobian(p), dtype=float).reshape(r.size, self.n)
        if self.scaling is not None:
            J = self.scaling.jacobian_to_scaled(z, J)
        return r, J

    def value_gradient(self, z):
        """``1/2 |r|^2`` and ``J^T r``."""
        r, J = self.residual_jacobian(z)
        return 0.5 * float(r @ r), J.T @ r


def fd_step(noise: float | None = None, scheme: str = "central") -> float:
    """Finite-difference step in scaled variables from the noise-amplification analysis.

    A difference quotient of a function known to relative accuracy ``eps`` has truncation error
    ``~ h^k |f^(k+1)|`` and rounding/noise error ``~ eps |f| / h`` (the lecture's O(1/h)
    amplification). In scaled variables the derivatives are of the size of f itself, so the sum
    is smallest at ``h = 2 sqrt(eps)`` (forward, k = 1) and ``h = (3 eps)^(1/3)`` (central,
    k = 2), giving errors ``~ sqrt(eps)`` and ``~ eps^(2/3)``.

    Parameters
    ----------
    noise : float, optional
        Relative noise of the evaluations (e.g. the forward solver's relative tolerance);
        default machine epsilon.
    scheme : {"central", "forward"}
    """
    eps = float(np.finfo(float).eps if noise is None else max(noise, np.finfo(float).eps))
    if scheme == "central":
        return (3.0 * eps) ** (1.0 / 3.0)
    if scheme == "forward":
        return 2.0 * np.sqrt(eps)
    raise OptimizationError(f"fd_step: unknown scheme '{scheme}'; valid: central, forward")


class FiniteDifferenceProblem:
    """Adds central-difference ``residual_jacobian``/``value_gradient`` to a residual-only problem.

    Costs 2n residual evaluations per Jacobian. The step follows :func:`fd_step`: with the
    default ``noise`` (machine epsilon) ``h ~ 9e-6``; for an iterative forward solve converged to
    a relative tolerance ``1e-8`` pass ``noise=1e-8`` (``h ~ 3e-3``): a smaller step would only
    amplify the solver noise by O(1/h). Steps may leave the bounds by h.

    Parameters
    ----------
    problem : LeastSquaresProblem
        Needs only ``residual``, ``n`` and optionally ``comm``.
    noise : float, optional
        Relative noise level of the residuals.
    step : float, optional
        Explicit step in z (overrides ``noise``).
    """

    def __init__(self, problem, noise: float | None = None, step: float | None = None):
        self.problem = problem
        self.n = problem.n
        self.comm = getattr(problem, "comm", None)
        self.step = float(step) if step is not None else fd_step(noise, "central")

    def residual(self, z):
        """Residuals of the wrapped problem."""
        return np.asarray(self.problem.residual(z), dtype=float)

    def residual_jacobian(self, z):
        """Residuals and their central-difference Jacobian."""
        z = np.asarray(z, dtype=float)
        r = self.residual(z)
        J = np.empty((r.size, self.n))
        for j in range(self.n):  # n is the (small) number of parameters, not a mesh loop
            e = np.zeros(self.n)
            e[j] = self.step
            J[:, j] = (self.residual(z + e) - self.residual(z - e)) / (2.0 * self.step)
        return r, J

    def value_gradient(self, z):
        """``1/2 |r|^2`` and ``J^T r`` with the finite-difference J."""
        r, J = self.residual_jacobian(z)
        return 0.5 * float(r @ r), J.T @ r


@dataclass
class IterationRecord:
    """One iteration as passed to a monitor and kept in the history."""

    iteration: int
    f: float
    gnorm: float
    z: np.ndarray
    p: np.ndarray
    evaluations: int
    step: float = float("nan")


@dataclass
class OptimizeResult:
    """Outcome of :func:`minimize` (identical on every rank).

    ``steps`` (method "gd" only) lists every accepted line-search step with ``z_old, z_new,
    f_old, f_new, g_old, alpha`` so the Armijo condition can be checked afterwards.
    """

    method: str
    z: np.ndarray
    p: np.ndarray
    f: float
    gnorm: float
    iterations: int
    evaluations: int
    reason: str
    converged: bool
    history: list[IterationRecord] = field(default_factory=list)
    steps: list[dict[str, Any]] = field(default_factory=list)
    hessian: str = ""
    tao_type: str = ""
    failures: list[str] = field(default_factory=list)


class _Evaluator:
    """Counted, cached, rank-synchronized evaluations of a problem (see the module docstring)."""

    def __init__(self, problem, cache_size: int = 8):
        self.problem = problem
        self.n = int(problem.n)
        comm = getattr(problem, "comm", None)
        self.comm = comm if comm is not None and comm.Get_size() > 1 else None
        self.count = 0
        self.has_jacobian = callable(getattr(problem, "residual_jacobian", None))
        self.has_gradient = callable(getattr(problem, "value_gradient", None))
        self._cache: OrderedDict[bytes, dict] = OrderedDict()
        self._size = cache_size
        # Until the start point has been evaluated, a failing forward model is an error; later
        # a physics failure at a trial point (SolverError, InvertedElementError, raised on every
        # rank by the model) becomes a non-finite value the optimizers step back from.
        self.strict = True
        self.failures: list[str] = []
        self._m: int | None = None

    def _call(self, fn, z):
        try:
            return fn(z)
        except OptimizationError:
            raise
        except (SolverError, InvertedElementError) as err:
            if self.strict:
                raise
            self.failures.append(f"z = {np.array2string(np.asarray(z))}: {err}")
            return None

    def _sync(self, value):
        return value if self.comm is None else self.comm.bcast(value, root=0)

    def _entry(self, z) -> dict:
        key = np.asarray(z, dtype=float).tobytes()
        entry = self._cache.get(key)
        if entry is None:
            entry = {}
            self._cache[key] = entry
            while len(self._cache) > self._size:
                self._cache.popitem(last=False)
        return entry

    @staticmethod
    def _finite(*values) -> bool:
        return all(bool(np.all(np.isfinite(v))) for v in values)

    def residual(self, z):
        e = self._entry(z)
        if "r" not in e:
            self.count += 1
            r = self._call(self.problem.residual, z)
            if r is None:
                e["r"] = np.full(self._m or 1, np.nan)
            else:
                e["r"] = self._sync(np.asarray(r, dtype=float).reshape(-1))
                self._m = e["r"].size
        return e["r"]

    def residual_jacobian(self, z):
        if not self.has_jacobian:
            raise OptimizationError(
                "this method needs residual Jacobians, which the problem does not provide; wrap "
                "it in petsoft.calibration.optimize.FiniteDifferenceProblem")
        e = self._entry(z)
        if "J" not in e:
            self.count += 1
            out = self._call(self.problem.residual_jacobian, z)
            if out is None:
                m = self._m or 1
                e["r"], e["J"] = np.full(m, np.nan), np.full((m, self.n), np.nan)
            else:
                r, J = self._sync((np.asarray(out[0], float).reshape(-1),
                                   np.asarray(out[1], float)))
                e["r"], e["J"] = r, J.reshape(r.size, self.n)
                self._m = r.size
        return e["r"], e["J"]

    def value_gradient(self, z):
        e = self._entry(z)
        if "g" not in e:
            if self.has_gradient:
                self.count += 1
                out = self._call(self.problem.value_gradient, z)
                if out is None:
                    f, g = np.inf, np.full(self.n, np.nan)
                else:
                    f, g = self._sync((float(out[0]), np.asarray(out[1], float).reshape(self.n)))
            elif self.has_jacobian:
                r, J = self.residual_jacobian(z)
                f, g = 0.5 * float(r @ r), J.T @ r
            else:
                raise OptimizationError(
                    "this method needs gradients, which the problem does not provide; wrap it in "
                    "petsoft.calibration.optimize.FiniteDifferenceProblem")
            if not self._finite(f, g):
                # A failed evaluation (e.g. the forward model broke at a trial point) is an
                # infinite objective: line searches and trust regions then step back, and the
                # point is never accepted. A failure at the start is an error (minimize()).
                f, g = np.inf, np.zeros(self.n)
            e["f"], e["g"] = f, g
        return e["f"], e["g"]

    def value(self, z):
        """The objective; from ``value_gradient`` when available (it may add regularization)."""
        e = self._entry(z)
        if "f" not in e:
            if self.has_gradient:
                return self.value_gradient(z)[0]
            r = self.residual(z)
            f = 0.5 * float(r @ r)
            e["f"] = f if np.isfinite(f) else np.inf
        return e["f"]

    def cached_value(self, z):
        e = self._cache.get(np.asarray(z, dtype=float).tobytes())
        if e is None:
            return None
        if "f" in e:
            return e["f"]
        if "r" in e and not self.has_gradient:
            f = 0.5 * float(e["r"] @ e["r"])
            return f if np.isfinite(f) else np.inf
        return None


def _normalize_bounds(bounds, n):
    if bounds is None:
        return np.full(n, -np.inf), np.full(n, np.inf)
    lo, hi = (np.asarray(b, dtype=float).reshape(-1) if b is not None else None for b in bounds)
    lo = np.full(n, -np.inf) if lo is None else lo
    hi = np.full(n, np.inf) if hi is None else hi
    if lo.shape != (n,) or hi.shape != (n,):
        raise OptimizationError(f"bounds need {n} lower and {n} upper values")
    if np.any(lo >= hi):
        i = int(np.flatnonzero(lo >= hi)[0])
        raise OptimizationError(f"bounds of z[{i}]: lower {lo[i]} is not below upper {hi[i]}")
    return lo, hi


def projected_gradient_norm(z, g, lo, hi) -> float:
    """The gradient norm with the components blocked by active bounds removed (TAO's projected
    gradient). Not ``|z - clip(z - g)|``: that is capped by the box's width, so with a large
    objective (a tiny noise level) ``grtol |f|`` stopped at the start however large g was."""
    z, g = np.asarray(z, dtype=float), np.asarray(g, dtype=float)
    blocked = ((z <= lo) & (g > 0)) | ((z >= hi) & (g < 0))
    return float(np.linalg.norm(np.where(blocked, 0.0, g)))


def _option(prefix: str, name: str, default, kind=float):
    opts = PETSc.Options()
    key = f"{prefix}{name}"
    if opts.hasName(key):
        return kind(opts.getReal(key) if kind is float else opts.getInt(key))
    return default


def minimize(problem, z0, method: str = "lbfgs", bounds=None, options: dict | None = None,
             monitor: Callable[[IterationRecord], None] | None = None, scaling=None,
             prefix: str = "cal_",
             stop: Callable[[IterationRecord], bool] | None = None,
             solver_options: SolverOptions | None = None) -> OptimizeResult:
    """Minimize the problem's objective over z from ``z0`` with the chosen method.

    Parameters
    ----------
    problem : LeastSquaresProblem
        Evaluations may be collective on ``problem.comm``; call on every rank of it.
    z0 : array_like, shape (n,)
        Start (clipped into the bounds).
    method : {"gd", "newton", "lbfgs", "gauss-newton", "brgn", "nelder-mead"}
    bounds : (lower, upper), optional
        Bounds on z (``-inf``/``inf`` for none), e.g. ``scaling.bounds()``.
    options : dict, optional
        Defaults overridden by the options database: ``gatol`` (1e-8), ``grtol`` (1e-8),
        ``max_it`` (:func:`iteration_limit`), ``max_funcs`` (10000; 100000 for "gd"), ``c1``
        (1e-4, Armijo), ``alpha_max`` (1.0, "gd"), ``nm_penalty`` (1e3), ``nm_restarts`` (3) and
        ``nm_restart_lambda`` (0.1, simplex size of a restart), ``fd_step`` (Hessian
        finite-difference step, default from :func:`fd_step`), ``lm_dtol`` (1e-6,
        "gauss-newton": converged when the remaining step is below sqrt(lm_dtol) of the
        parameters' standard deviation as the residual estimates it; 0 turns the test off).
    monitor : callable(IterationRecord), optional
        Called on every rank after every iteration (print on rank 0 only).
    scaling : ParameterScaling, optional
        Used only to report physical parameters ``p`` (else p = z).
    prefix : str
        PETSc options prefix of the optimizer.
    stop : callable(IterationRecord) -> bool, optional
        Called on every rank after every iteration (after ``monitor``); True ends the
        minimization there with reason ``STOPPED_BY_CALLER`` (not converged) at that iterate.
        It must decide the same on every rank (the records are identical on all of them).
    solver_options : SolverOptions, optional
        The options (an experiment's ``[petsc]`` table) pushed under ``prefix`` while the
        optimizer runs.

    Returns
    -------
    OptimizeResult
    """
    if method not in METHODS:
        raise OptimizationError(f"unknown optimization method '{method}'; valid: {METHODS}")
    ev = _Evaluator(problem)
    n = ev.n
    lo, hi = _normalize_bounds(bounds, n)
    z0 = np.asarray(z0, dtype=float).reshape(-1)
    if z0.shape != (n,):
        raise OptimizationError(f"start has {z0.size} values for {n} parameters")
    z0 = np.clip(z0, lo, hi)
    o = {"gatol": 1e-8, "grtol": 1e-8, "c1": 1e-4, "alpha_max": 1.0, "nm_penalty": 1e3,
         "nm_restarts": 3, "nm_restart_lambda": 0.1, "lm_dtol": 1e-6,
         "max_it": iteration_limit(method),
         "max_funcs": 100000 if method == "gd" else 10000, "fd_step": fd_step()}
    unknown = set(options or {}).difference(o)
    if unknown:
        raise OptimizationError(f"unknown optimizer options {sorted(unknown)}; valid: {sorted(o)}")
    o.update(options or {})

    def to_p(z):
        return np.asarray(z, float).copy() if scaling is None else scaling.to_physical(z)

    history: list[IterationRecord] = []

    def record(it, z, f, gnorm, step=float("nan")):
        rec = IterationRecord(int(it), float(f), float(gnorm), np.array(z, dtype=float),
                              to_p(z), ev.count, float(step))
        history.append(rec)
        if monitor is not None:
            monitor(rec)
        return stop is not None and bool(stop(rec))

    if method in ("gauss-newton", "brgn"):
        r0 = ev.residual_jacobian(z0)[0]  # what these methods evaluate first (cached)
        f0 = 0.5 * float(r0 @ r0)
    else:
        f0 = ev.value(z0)
    ev.strict = False
    if not np.isfinite(f0):
        raise OptimizationError(
            f"the objective is not finite at the start z = {np.array2string(z0)}"
            + (f" (p = {np.array2string(to_p(z0))})" if scaling is not None else "")
            + ": the forward model failed there; start elsewhere or tighten the bounds")
    # the optimizer's options (-cal_tao_max_it ...) pushed while it reads them and runs
    with own_options(prefix, solver_options).pushed():
        if method in ("gd", "gauss-newton"):
            res = _own_method(method, ev, z0, lo, hi, o, prefix, record, scaling, history)
        elif method == "nelder-mead":
            # TAO nm's simplex can collapse in a narrow curved valley and report convergence at a
            # non-stationary point (seen on the shifted oscillation: f = 0.386 instead of 0.192 from
            # a unit simplex). Restarting from the result with a fresh, smaller simplex resolves it;
            # restart while the objective still improves.
            res = _tao_minimize(ev, z0, lo, hi, o, prefix, method, record,
                                (options or {}).get("gatol"))
            its = res.iterations
            for _ in range(0 if res.reason == STOPPED else int(o["nm_restarts"])):
                again = _tao_minimize(ev, res.z, lo, hi, o, prefix, method, record,
                                      (options or {}).get("gatol"), o["nm_restart_lambda"])
                its += again.iterations
                if again.reason == STOPPED:
                    res = again
                    break
                improved = again.f < res.f - 1e-12 * (1.0 + abs(res.f))
                if again.f <= res.f:
                    res = again
                if not improved:
                    break
            res.iterations = its
            res.evaluations = ev.count
        else:
            res = _tao_minimize(ev, z0, lo, hi, o, prefix, method, record,
                                (options or {}).get("gatol"))
    res.history = history
    res.failures = ev.failures
    res.p = to_p(res.z)
    return res


class _StopRequested(Exception):
    """Raised by an own method's ``record`` when the caller's ``stop`` asks to end there."""


def _own_method(method, ev: _Evaluator, z0, lo, hi, o, prefix, record, scaling,
                history: list[IterationRecord]) -> OptimizeResult:
    """Gradient descent or Levenberg-Marquardt; a caller's stop ends either at the iterate it
    was asked at (the last of ``history``, which ``record`` appends to)."""

    def stoppable(it, z, f, gnorm, step=float("nan")):
        if record(it, z, f, gnorm, step):
            raise _StopRequested

    try:
        if method == "gd":
            return _gradient_descent(ev, z0, lo, hi, o, prefix, stoppable)
        is_log = (np.zeros(len(z0), dtype=bool) if scaling is None
                  else np.asarray(scaling.is_log, dtype=bool))
        # an affine parameter bounded below by zero (a term's coefficient started off) is a
        # positive quantity once it is off: its steps are relative ones (_trial_point)
        from_zero = (np.zeros(len(z0), dtype=bool) if scaling is None
                     else ~is_log & (np.asarray(scaling.lower, dtype=float) == 0.0))
        return _levenberg_marquardt(ev, z0, lo, hi, o, prefix, stoppable, is_log, from_zero)
    except _StopRequested:
        last = history[-1]
        return OptimizeResult(method, last.z, last.z, last.f, last.gnorm, last.iteration,
                              ev.count, STOPPED, False,
                              hessian="gauss-newton" if method == "gauss-newton" else "")


def iteration_limit(method: str) -> int:
    """The iteration limit ``method`` runs with by default (:func:`minimize`)."""
    return {"gd": 20000, "gauss-newton": LM_MAX_IT}.get(method, 1000)


def _stopping_reason(gnorm, f, it, count, gatol, grtol, max_it, max_funcs) -> str:
    """TAO's stopping tests for the own (non-TAO) methods; "" to go on."""
    if gnorm <= gatol:
        return "CONVERGED_GATOL"
    if gnorm <= grtol * abs(f):
        return "CONVERGED_GRTOL"
    if it >= max_it:
        return "DIVERGED_MAXITS"
    if count >= max_funcs:
        return "DIVERGED_MAXFCN"
    return ""


def _gradient_descent(ev: _Evaluator, z0, lo, hi, o, prefix, record) -> OptimizeResult:
    gatol = _option(prefix, "tao_gatol", o["gatol"])
    grtol = _option(prefix, "tao_grtol", o["grtol"])
    max_it = _option(prefix, "tao_max_it", int(o["max_it"]), int)
    max_funcs = _option(prefix, "tao_max_funcs", int(o["max_funcs"]), int)
    c1 = _option(prefix, "gd_c1", o["c1"])
    alpha_max = _option(prefix, "gd_alpha_max", o["alpha_max"])
    z = z0.copy()
    f, g = ev.value_gradient(z)
    gnorm = projected_gradient_norm(z, g, lo, hi)
    record(0, z, f, gnorm)
    steps = []
    alpha = alpha_max / 2.0
    reason, it = "DIVERGED_MAXITS", 0
    while True:
        stop = _stopping_reason(gnorm, f, it, ev.count, gatol, grtol, max_it, max_funcs)
        if stop:
            reason = stop
            break
        alpha = min(alpha_max, 2.0 * alpha)
        # Decrease predicted by the first trial; below the rounding error of f no step can pass
        # the Armijo test, and z is then a minimizer to working precision.
        predicted = alpha * float(g @ g)
        for _ in range(60):  # 60 halvings take alpha below 1e-18 alpha_max: a failed search
            zt = np.clip(z - alpha * g, lo, hi)
            slope = float(g @ (zt - z))  # < 0 unless the projected step vanishes
            ft = ev.value(zt)
            if np.isfinite(ft) and ft <= f + c1 * slope and slope < 0:
                break
            alpha *= 0.5
        else:
            roundoff = predicted <= 1e3 * np.finfo(float).eps * max(abs(f), 1e-300)
            reason = "CONVERGED_ROUNDOFF" if roundoff else "DIVERGED_LS_FAILURE"
            break
        ft, gt = ev.value_gradient(zt)
        steps.append({"z_old": z, "z_new": zt, "f_old": f, "f_new": ft, "g_old": g,
                      "alpha": alpha, "c1": c1})
        z, f, g = zt, ft, gt
        it += 1
        gnorm = projected_gradient_norm(z, g, lo, hi)
        record(it, z, f, gnorm, alpha)
    return OptimizeResult("gd", z, z, f, gnorm, it, ev.count, reason,
                          reason.startswith("CONVERGED"), steps=steps)


def _secant_update(S, step, y, ysharp):
    """Dennis-Gay-Welsch update of S, the secant model of the residual's own curvature
    sum_i r_i Hess(r_i) that Gauss-Newton leaves out (the structured quasi-Newton of NL2SOL:
    Dennis, Gay & Welsch, ACM TOMS 7, 1981). Returns S unchanged when the step carries no
    positive curvature (y.s <= 0).

    ``y`` is the change of the gradient over ``step``, ``ysharp`` = (J_new - J_old)^T r_new.
    S is first sized down by min(1, |s.y#| / s.S.s) (NL2SOL's sizing), so that a stale S
    cannot dominate the update, then changed by the least change (in the weighted norm of
    y) that satisfies the secant condition S s = y#.
    """
    ys = float(y @ step)
    if not ys > 0.0:
        return S
    sSs = float(step @ (S @ step))
    if sSs > 0.0:
        S = S * min(1.0, abs(float(step @ ysharp)) / sSs)
    v = ysharp - S @ step
    return S + (np.outer(v, y) + np.outer(y, v)) / ys - float(v @ step) / ys ** 2 * np.outer(y, y)


def _positive_definite(H) -> bool:
    try:
        np.linalg.cholesky(H)
    except np.linalg.LinAlgError:
        return False
    return True


def _relative(d: np.ndarray, z: np.ndarray, lo: np.ndarray, is_log: np.ndarray,
              from_zero: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The model step ``d`` as relative changes dp / p, and where that is defined: a
    log-scaled parameter (z = log(p / p_ref): d is dp / p) and a ``from_zero`` one (affine,
    z - lo = p / width) that is off its bound."""
    dist = z - np.where(from_zero, lo, 0.0)
    on = is_log | (from_zero & (dist > 0.0))
    rel = np.where(is_log, d, np.where(on, d / np.where(on & ~is_log, dist, 1.0), 0.0))
    return rel, on


def _pin_to_bounds(d: np.ndarray, z, lo, hi, free, M, g, is_log, from_zero):
    """The model step ``d`` (of the free parameters, ``M d = -g`` with ``M`` the damped model
    matrix) with every parameter it would carry past a bound held at that bound and the
    others solved again for it; returns (d, pinned).

    Clipping instead moves the parameters that hit a bound less than the model asked and the
    others as much: off a narrow valley that a bound ends (the viscoelastic branch's
    relaxation time at its lower bound, the ratio still growing along ratio * time ~ const)
    trials failed and the damping was raised until the step was tiny (the damping-5k case's
    fit, issue 40: 18 runs for its last 5 iterations)."""
    d = d.copy()
    pinned = np.zeros_like(free)
    bound = np.zeros_like(z)
    t_used = 1.0
    # a few passes: a pinned parameter's step is (bound - z) / t, t the path's factor of the
    # others' growth (_path), which the solve for the others changes (slightly)
    for _ in range(int(free.sum()) + 3):
        zr, _, t = _path(d, z, lo, is_log, from_zero, pinned)
        low = free & ~pinned & (zr < lo)
        high = free & ~pinned & (zr > hi)
        if not (low.any() or high.any()) and (not pinned.any()
                                              or abs(t - t_used) <= 1e-12 * t):
            break
        bound = np.where(low, lo, np.where(high, hi, bound))
        pinned |= low | high
        t_used = t
        d[pinned] = (bound[pinned] - z[pinned]) / t
        rest = free & ~pinned
        if not rest.any():
            break
        d[rest] = np.linalg.solve(M[np.ix_(rest, rest)],
                                  -(g[rest] + M[np.ix_(rest, pinned)] @ d[pinned]))
    return d, pinned


def _trial_point(d: np.ndarray, z, lo, hi, is_log, from_zero,
                 pinned) -> tuple[np.ndarray, np.ndarray]:
    """The trial point of a model step ``d``, and the step along which the model predicts it
    (the path's tangent at z).

    A log-scaled parameter, and a growing ``from_zero`` one off zero, move along a straight
    line in log p: ``p exp(t dp/p)``; the others, and those held at a bound
    (:func:`_pin_to_bounds`), ``z + t d``. (A ``from_zero`` parameter that falls does so in p:
    to zero in one step where the model says so, where exp(dp/p) would only approach it.)
    Physical parameters combine by products and powers, so the valleys of a misfit are
    straight in log p: the viscoelastic branch's ratio * relaxation time ~ const near the
    Kelvin-Voigt limit. Taken in p for the (affine) ratio and in log p for the time, that
    valley was curved, the model's step fell off it, and Levenberg-Marquardt crept along it
    by 7-10 % of each parameter an iteration (41 iterations, issue 40).

    ``t = log(1 + r) / r`` for the largest relative growth r (1 when nothing grows): the
    largest growth is then the model's own factor 1 + r, and exp(r) overshot by far when r
    is large (a support compliance started numerically rigid needs r ~ 4000: z + r went to
    the upper bound, seven trial runs were rejected, and the fit then crept up by factors of
    1.3-3 for 25 iterations; the independent suite's compliance case, 430 s of its 1630).
    One factor for the whole step keeps its direction (each growth taken as log(1 + r) on its
    own bent it off such a valley); with one parameter this is log(1 + r). t = 1 - r/2 +
    O(r^2), so the local convergence is unchanged."""
    zt, tangent, _ = _path(d, z, lo, is_log, from_zero, pinned)
    zt = np.clip(zt, lo, hi)
    return zt, np.clip(z + tangent, lo, hi) - z


def _path(d, z, lo, is_log, from_zero, pinned) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`_trial_point` before the bounds: (point, tangent step, t)."""
    rel, on = _relative(d, z, lo, is_log, from_zero)
    grow = on & ~pinned & (rel > 0.0)
    t = 1.0
    if grow.any():
        r = float(np.max(rel[grow]))
        t = float(np.log1p(r) / r)
    relative = on & ~is_log & ~pinned & (rel > 0.0)
    base = np.where(relative, lo, 0.0)     # (lo is -inf where it is not used)
    with np.errstate(over="ignore"):
        zt = np.where(relative, base + (z - base) * np.exp(t * rel), z + t * d)
    return zt, t * d, t


def _levenberg_marquardt(ev: _Evaluator, z0, lo, hi, o, prefix, record,
                         is_log: np.ndarray | None = None,
                         from_zero: np.ndarray | None = None) -> OptimizeResult:
    gatol = _option(prefix, "tao_gatol", o["gatol"])
    grtol = _option(prefix, "tao_grtol", o["grtol"])
    max_it = _option(prefix, "tao_max_it", min(int(o["max_it"]), LM_MAX_IT), int)
    max_funcs = _option(prefix, "tao_max_funcs", int(o["max_funcs"]), int)
    # relative change of z and f below which a step counts as stagnation (round-off level)
    xtol = _option(prefix, "lm_xtol", 1e-10)
    # relative decrease of f in an accepted step below which the fit has stagnated: the
    # gradient is then at the level of the solver tolerances, not of gatol
    ftol = _option(prefix, "lm_ftol", 1e-10)
    # Converged when the full model step is below sqrt(dtol) of the parameters' standard
    # deviation as the residual itself estimates it (s^2 = 2 f / (m - n), whatever the units
    # of r): the step's size in those deviations squared is g^T H^-1 g / s^2. Further digits
    # are below any statistical meaning (a large-misfit fit crept on for ~8 iterations at
    # rel. change 1e-9 of f). Exact data (s -> 0) leave this to the other tests.
    dtol = _option(prefix, "lm_dtol", o["lm_dtol"])
    is_log = np.zeros(len(z0), dtype=bool) if is_log is None else is_log
    from_zero = np.zeros(len(z0), dtype=bool) if from_zero is None else from_zero
    z = z0.copy()
    r, J = ev.residual_jacobian(z)
    f, g = 0.5 * float(r @ r), J.T @ r
    gnorm = projected_gradient_norm(z, g, lo, hi)
    record(0, z, f, gnorm)
    A = J.T @ J
    # Gauss-Newton converges only linearly when the misfit is large (the model cannot fit
    # the data: measured rate 0.52 a step, 17 iterations on a one-parameter fit at chi2/dof
    # 250): its Hessian J^T J leaves out sum_i r_i Hess(r_i). S is a secant model of that term
    # (_secant_update); each step uses the model, J^T J or J^T J + S, that predicted the last
    # accepted step's actual decrease better (NL2SOL's adaptive choice), J^T J + S only when
    # positive definite.
    S = np.zeros_like(A)
    augmented = False
    # mu is dimensionless: it multiplies diag(J^T J) (Marquardt's scaling). Scaling it by
    # max diag(J^T J) as well over-damped a tiny-noise fit (J ~ 1/sigma) by that factor: it
    # crept for ~log3(max diag) iterations before Gauss-Newton steps were taken
    mu, nu = 1e-3, 2.0
    reason, it = "DIVERGED_MAXITS", 0
    dof = max(len(r) - len(z), 1)
    last_accepted = True
    while True:
        stop = _stopping_reason(gnorm, f, it, ev.count, gatol, grtol, max_it, max_funcs)
        if stop:
            reason = stop
            break
        # active set: a parameter on a bound whose gradient pushes outwards stays there, and the
        # step is solved for the free ones (clipping a full step would leave them unadjusted)
        free = ~(((z <= lo) & (g > 0)) | ((z >= hi) & (g < 0)))
        H = A + S if augmented else A
        if augmented and not _positive_definite(H[np.ix_(free, free)]):
            H = A
        try:
            decrement = float(-g[free] @ np.linalg.solve(H[np.ix_(free, free)], -g[free]))
        except np.linalg.LinAlgError:
            decrement = np.inf
        if free.any() and 0.0 <= decrement <= dtol * 2.0 * f / dof:
            reason = "CONVERGED_DECREMENT"
            break
        # Marquardt's scaling: damp each parameter in proportion to its curvature
        damping = np.maximum(np.diag(A), 1e-12 * max(float(np.max(np.diag(A))), 1e-300))
        d = np.zeros_like(z)
        M = H + mu * np.diag(damping)
        try:
            d[free] = np.linalg.solve(M[np.ix_(free, free)], -g[free])
            d, pinned = _pin_to_bounds(d, z, lo, hi, free, M, g, is_log, from_zero)
        except np.linalg.LinAlgError:
            mu *= nu
            nu *= 2.0
            continue
        zt, tangent = _trial_point(d, z, lo, hi, is_log, from_zero, pinned)
        step = zt - z
        if np.linalg.norm(step) <= xtol * (1.0 + np.linalg.norm(z)):
            reason = "CONVERGED_STEPTOL"
            break
        # the model's decrease along the path's tangent: the path bends where the model's
        # straight step would leave a valley (_trial_point)
        predicted = -(float(g @ tangent) + 0.5 * float(tangent @ (H @ tangent)))
        # After an accepted step the next trial is likely accepted too: evaluate its Jacobian
        # with it (forward sensitivities ride along one run: 1.5 runs, where a trial run and
        # then a Jacobian run at the accepted point cost 2.5). After a rejection, the cheap
        # residual only.
        rt = ev.residual_jacobian(zt)[0] if last_accepted else ev.residual(zt)
        ft = 0.5 * float(rt @ rt)
        rho = (f - ft) / predicted if predicted > 0 else -1.0
        last_accepted = bool(np.isfinite(ft) and rho > 1e-4)
        if last_accepted:
            rel = (f - ft) / max(f, 1e-300)
            # which model predicted this step's decrease better (for the next step)
            linear = float(g @ step)
            gn = -(linear + 0.5 * float(step @ (A @ step)))
            aug = -(linear + 0.5 * float(step @ ((A + S) @ step)))
            augmented = abs(aug - (f - ft)) < abs(gn - (f - ft))
            z = zt
            J_old, g_old = J, g
            r, J = ev.residual_jacobian(z)
            f, g = 0.5 * float(r @ r), J.T @ r
            S = _secant_update(S, step, g - g_old, g - J_old.T @ r)
            A = J.T @ J
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            it += 1
            gnorm = projected_gradient_norm(z, g, lo, hi)
            record(it, z, f, gnorm, float(np.linalg.norm(step)))
            if rel <= ftol:
                reason = "CONVERGED_FTOL"
                break
        else:
            mu *= nu
            nu *= 2.0
            if mu > 1e16:
                reason = "DIVERGED_LS_FAILURE"
                break
    return OptimizeResult("gauss-newton", z, z, f, gnorm, it, ev.count, reason,
                          reason.startswith("CONVERGED"), hessian="gauss-newton")


def _dense(nrows, ncols):
    A = PETSc.Mat().createDense([nrows, ncols], comm=PETSc.COMM_SELF)
    A.setUp()
    return A


def _set_dense(A, values):
    m, n = values.shape
    A.setValues(np.arange(m, dtype=PETSc.IntType), np.arange(n, dtype=PETSc.IntType),
                np.ascontiguousarray(values).ravel())
    A.assemble()


def _tao_minimize(ev: _Evaluator, z0, lo, hi, o, prefix, method, record,
                  options_gatol=None, nm_lambda=None) -> OptimizeResult:
    n = ev.n
    bounded = bool(np.any(np.isfinite(lo)) or np.any(np.isfinite(hi)))
    tao_type = {"newton": "bnls" if bounded else "nls", "lbfgs": "blmvm",
                "brgn": "brgn", "nelder-mead": "nm"}[method]
    tao = PETSc.TAO().create(PETSc.COMM_SELF)
    objs = [tao]
    tao.setOptionsPrefix(prefix)
    tao.setType(tao_type)
    x = PETSc.Vec().createSeq(n, comm=PETSc.COMM_SELF)
    objs.append(x)
    x.setArray(z0)
    hessian_kind = ""

    def fg(tao_, X, G):
        f, g = ev.value_gradient(X.getArray(readonly=True).copy())
        G.setArray(g)
        return f

    if method in ("newton", "lbfgs"):
        tao.setObjectiveGradient(fg, None)
    if method == "newton":
        H = _dense(n, n)
        objs.append(H)
        h = float(o["fd_step"])
        if ev.has_jacobian:
            hessian_kind = "gauss-newton J^T J"

            def hess(tao_, X, H_, P_):
                _, J = ev.residual_jacobian(X.getArray(readonly=True).copy())
                _set_dense(H_, J.T @ J)
        else:
            hessian_kind = f"central finite differences of the gradient (h = {h:.2g})"

            def hess(tao_, X, H_, P_):
                z = X.getArray(readonly=True).copy()
                B = np.empty((n, n))
                for j in range(n):  # n parameters (small)
                    # central where possible, one-sided at a bound: never evaluate outside
                    zp, zm = z.copy(), z.copy()
                    zp[j] = min(z[j] + h, hi[j])
                    zm[j] = max(z[j] - h, lo[j])
                    B[:, j] = ((ev.value_gradient(zp)[1] - ev.value_gradient(zm)[1])
                               / (zp[j] - zm[j]))
                _set_dense(H_, 0.5 * (B + B.T))

        tao.setHessian(hess, H, H)
    elif method == "brgn":
        r0, _ = ev.residual_jacobian(z0)
        m = r0.size
        R = PETSc.Vec().createSeq(m, comm=PETSc.COMM_SELF)
        J = _dense(m, n)
        objs += [R, J]

        def fres(tao_, X, F):
            F.setArray(ev.residual_jacobian(X.getArray(readonly=True).copy())[0])

        def fjac(tao_, X, J_, P_):
            _set_dense(J_, ev.residual_jacobian(X.getArray(readonly=True).copy())[1])

        tao.setResidual(fres, R)
        tao.setJacobianResidual(fjac, J, J)
    elif method == "nelder-mead":
        mu = float(o["nm_penalty"])

        def fobj(tao_, X):
            z = X.getArray(readonly=True).copy()
            zc = np.clip(z, lo, hi)
            f = ev.value(zc)
            if not np.isfinite(f):
                return 1e300  # a failed evaluation: worst vertex (TAO nm rejects Inf values)
            d = z - zc
            return f + mu * (1.0 + abs(f)) * float(d @ d)

        tao.setObjective(fobj)

    if bounded and method != "nelder-mead":
        lb, ub = x.duplicate(), x.duplicate()
        objs += [lb, ub]
        lb.setArray(np.where(np.isfinite(lo), lo, PETSc.NINFINITY))
        ub.setArray(np.where(np.isfinite(hi), hi, PETSc.INFINITY))
        tao.setVariableBounds(lb, ub)

    stopped = []

    def mon(tao_):
        its, f_tao, gn_tao, _, step, _ = tao_.getSolutionStatus()
        z = np.clip(tao_.getSolution().getArray(readonly=True).copy(), lo, hi)
        f = ev.cached_value(z)
        if record(its, z, f_tao if f is None else f, gn_tao, step):
            # TAO's solvers iterate while the reason says "continue"
            stopped.append(True)
            tao_.setConvergedReason(PETSc.TAO.Reason.DIVERGED_USER)

    # brgn iterates in its subsolver (bnls on the regularized problem) and does not call the
    # outer monitor in 3.18, so monitor the subsolver; f is taken from the evaluation cache.
    (tao.getBRGNSubsolver() if method == "brgn" else tao).setMonitor(mon)
    gatol, grtol = float(o["gatol"]), float(o["grtol"])
    if method == "nelder-mead" and options_gatol is None:
        # TAO nm tests the spread of f over the simplex, not a gradient: |z - z*| ~ sqrt(spread),
        # so the gradient tolerance would stop far too early.
        gatol, grtol = gatol**2, 0.0
    tao.setTolerances(gatol=gatol, grtol=grtol, gttol=0.0)
    tao.setMaximumIterations(int(o["max_it"]))
    tao.setMaximumFunctionEvaluations(int(o["max_funcs"]))
    tao.setSolution(x)
    defaults = {}
    if nm_lambda is not None:
        defaults[f"{prefix}tao_nm_lambda"] = str(nm_lambda)
    if method == "brgn":
        # brgn's default l2prox regularizer biases the answer in 3.18: on r = z - 1 it stops
        # after one step at z = 0.9999 (= 1/(1 + weight 1e-4)); "lm" (Levenberg-Marquardt
        # damping) converges to z = 1 and took 6 instead of 17 iterations on Rosenbrock.
        defaults[f"{prefix}tao_brgn_regularization_type"] = "lm"
    with scoped_defaults(**defaults):
        tao.setFromOptions()  # last: the command line wins
    try:
        tao.solve()
        done = outcome(tao)
        reason = STOPPED if stopped else done.reason
        its = int(tao.getIterationNumber())
        tao_type = tao.getType()
        z = np.clip(x.getArray(readonly=True).copy(), lo, hi)
    finally:
        for obj in objs:
            obj.destroy()
    if ev.has_gradient or ev.has_jacobian:
        f, g = ev.value_gradient(z)
        gnorm = projected_gradient_norm(z, g, lo, hi)
    else:
        f, gnorm = ev.value(z), float("nan")
    return OptimizeResult(method, z, z, f, gnorm, its, ev.count, reason, done.converged,
                          hessian=hessian_kind, tao_type=tao_type)


def print_monitor(comm=None, names=None, stream=None) -> Callable[[IterationRecord], None]:
    """A monitor printing one progress line per iteration on rank 0 of ``comm``."""
    rank = 0 if comm is None else comm.Get_rank()

    def monitor(rec: IterationRecord):
        if rank != 0:
            return
        params = ", ".join(
            f"{names[i] if names else f'p{i}'}={v:.6g}" for i, v in enumerate(rec.p))
        print(f"  it {rec.iteration:4d}  f {rec.f:.6e}  |g| {rec.gnorm:.3e}  evals "
              f"{rec.evaluations:4d}  {params}", file=stream or sys.stderr, flush=True)

    return monitor


__all__ = [
    "METHODS", "FiniteDifferenceProblem", "IterationRecord", "LeastSquares",
    "LeastSquaresProblem", "OptimizationError", "OptimizeResult", "fd_step",
    "minimize", "print_monitor", "projected_gradient_norm",
]
