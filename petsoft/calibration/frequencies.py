"""Calibration from measured natural frequencies ("inverse harmonics", lecture 000).

This module owns the frequency model and its fit:

* :class:`FrequencyModel`: the natural frequencies of an experiment's model (the generalized
  eigenproblem K x = omega^2 M x of :mod:`petsoft.solvers.modes`: stiffness at the reference
  state, consistent mass, Dirichlet conditions) as functions of its material parameters
  (``material[.<region>].youngs_modulus / poisson_ratio / density``, stiffness groups
  ``material.youngs_modulus#k``), with their exact derivatives. For an M-orthonormal mode x of
  eigenvalue lambda, d lambda = x^T (dK - lambda dM) x: the element Hessians per unit Lame
  parameter applied to x (:meth:`~petsoft.physics.elastic.ElasticTerm.lame_derivatives`) give
  x^T dK x cell by cell, the unit-density element masses x^T dM x, and the per-cell chain rule to
  each named parameter is the one the dynamic sensitivities use
  (:meth:`petsoft.dynamics.parameters.ParameterMap.coefficients`). f = sqrt(lambda) / (2 pi),
  so df = d lambda / (8 pi^2 f).
* pairing: the measured frequencies, ascending, are the body's lowest elastic modes in order
  (rigid-body modes of a free body are skipped). A cluster of (nearly) equal model eigenvalues
  (a square section's two bending modes) has no derivative per mode; each of its members gets the
  derivative of the cluster's mean, which exists and is what a symmetric change of E, nu or rho
  moves. Mode shapes at markers (MAC pairing) are not read yet.
* :func:`calibrate_frequencies`: Gauss-Newton (Levenberg-Marquardt) in scaled parameters on the
  residuals (f_model - f_measured) / std, standard deviations from the Gauss-Newton covariance.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from petsc4py import PETSc

from petsoft.calibration.optimize import LeastSquares, minimize
from petsoft.calibration.scaling import ParameterScaling
from petsoft.calibration.uncertainty import UnidentifiableError, uncertainty
from petsoft.dynamics.system import DynamicSystem
from petsoft.errors import ExperimentError, PetsoftError
from petsoft.fem.element import cell_integrals
from petsoft.io.progress import IterationPace
from petsoft.physics.model import build_model
from petsoft.solvers.modes import compute_modes

__all__ = ["FrequencyFit", "FrequencyModel", "calibrate_frequencies", "write_frequency_outputs"]

#: Model eigenvalues closer than this (relative) form a cluster (module docstring).
CLUSTER_RTOL = 1e-6


class FrequencyModel:
    """The lowest ``count`` elastic natural frequencies of an experiment's model as a function
    of named material parameters (collective on ``comm``).

    Parameters
    ----------
    experiment : Experiment
        A continuum model ([material]); loads and [time] are ignored.
    names : sequence of str
        Material parameters (module docstring).
    count : int
        How many elastic frequencies (the measured ones).
    comm : PETSc.Comm, optional
    """

    def __init__(self, experiment, names, count: int, comm=None):
        self.comm = comm if comm is not None else PETSc.COMM_WORLD
        self.names, self.count = list(names), int(count)
        if experiment.is_mass_spring:
            raise ExperimentError(f"{experiment.source}: calibration from frequencies needs a "
                                  "[material] model (a [springs] model has no modes solver)")
        bad = [n for n in self.names if not n.startswith("material.")
               or n.split(".")[-1].split("#")[0] not in ("youngs_modulus", "poisson_ratio",
                                                         "density")]
        if bad:
            raise ExperimentError(
                f"{experiment.source}: [calibrate] \"{bad[0]}\": natural frequencies depend on "
                "the material only (loads, damping and supports' compliance are not "
                "differentiated here); calibrate material[.<region>].youngs_modulus, "
                "poisson_ratio or density")
        self.system = DynamicSystem(build_model(experiment, self.comm), 0.0, 0.0)
        known = set(self.system.parameter_names())
        unknown = [n for n in self.names if n not in known and "#" not in n]
        if unknown:
            raise ExperimentError(f"{experiment.source}: [calibrate] \"{unknown[0]}\" is not a "
                                  f"parameter of this model; known: {', '.join(sorted(known))}")
        self.evaluations = 0

    def _modes(self):
        model = self.system.model
        res = compute_modes(model, self.count)
        if res.rigid_modes:
            rigid = res.rigid_modes
            res.destroy()
            res = compute_modes(model, self.count + rigid)
        return res

    def evaluate(self, p, jacobian: bool = True):
        """Frequencies (count,) in Hz at parameters ``p``, and df/dp (count, n) or None."""
        s = self.system
        s.set_parameters(dict(zip(self.names, map(float, p), strict=True)))
        self.evaluations += 1
        res = self._modes()
        try:
            lam = res.eigenvalues[res.rigid_modes:res.rigid_modes + self.count]
            modes = res.modes[res.rigid_modes:res.rigid_modes + self.count]
            if len(lam) < self.count:
                raise ExperimentError(f"the model has only {len(lam)} elastic modes; "
                                      f"{self.count} frequencies were measured")
            f = np.sqrt(np.maximum(lam, 0.0)) / (2.0 * np.pi)
            if not jacobian:
                return f, None
            dlam = np.array([self._eigenvalue_gradient(x, lv) for x, lv in zip(modes, lam,
                                                                                 strict=True)])
            # clusters: the derivative of their mean (module docstring)
            start = 0
            while start < len(lam):
                stop = start + 1
                while stop < len(lam) and lam[stop] - lam[start] <= CLUSTER_RTOL * lam[stop]:
                    stop += 1
                dlam[start:stop] = dlam[start:stop].mean(axis=0)
                start = stop
            return f, dlam / (8.0 * np.pi ** 2 * f[:, None])
        finally:
            res.destroy()

    def _eigenvalue_gradient(self, x: PETSc.Vec, lam: float) -> np.ndarray:
        """x^T (dK/dp_j - lam dM/dp_j) x for every parameter j (x M-orthonormal)."""
        s = self.system
        dm = s.dmesh
        xl = dm.to_local(x)
        xe = xl[dm.cells]                                            # (n, k, 3)
        n = len(dm.cells)
        d_mu, d_lam = s.elastic.lame_derivatives(np.zeros_like(xl), xl)
        q_mu = np.einsum("ni,ni->n", d_mu, xe.reshape(n, -1))
        q_lam = np.einsum("ni,ni->n", d_lam, xe.reshape(n, -1))
        q_rho = np.einsum("nab,nai,nbi->n", cell_integrals(dm).mass, xe, xe)
        out = np.zeros(len(self.names))
        for j, name in enumerate(self.names):
            dmu, dlam, drho = s.parameters.coefficients(name, self.names)
            for coef, q, sign in ((dmu, q_mu, 1.0), (dlam, q_lam, 1.0), (drho, q_rho, -lam)):
                if coef is not None:
                    out[j] += sign * float(coef @ q)
        return np.asarray(dm.comm.tompi4py().allreduce(out))


@dataclass
class FrequencyFit:
    """The result of :func:`calibrate_frequencies` (physical parameters)."""

    names: list[str]
    start: np.ndarray
    values: np.ndarray
    std: np.ndarray
    correlation: np.ndarray | None
    measured: np.ndarray
    measured_std: np.ndarray | None
    before: np.ndarray
    after: np.ndarray
    sigma: float
    sigma_source: str
    iterations: int
    evaluations: int
    reason: str
    wall_time: float
    bounds: list = field(default_factory=list)

    def summary(self) -> dict:
        """A JSON-able dict of the fit (summary.json)."""
        return {
            "kind": "frequencies",
            "parameters": {n: float(v) for n, v in zip(self.names, self.values, strict=True)},
            "std": {n: float(v) for n, v in zip(self.names, self.std, strict=True)},
            "start": {n: float(v) for n, v in zip(self.names, self.start, strict=True)},
            "bounds": {n: list(b) for n, b in zip(self.names, self.bounds, strict=True)},
            "correlation": None if self.correlation is None else self.correlation.tolist(),
            "measured_hz": self.measured.tolist(),
            "measured_std_hz": None if self.measured_std is None else self.measured_std.tolist(),
            "model_hz_before": self.before.tolist(), "model_hz_after": self.after.tolist(),
            "noise_hz": self.sigma, "noise_source": self.sigma_source,
            "iterations": self.iterations, "evaluations": self.evaluations,
            "reason": self.reason, "wall_time_s": self.wall_time,
        }


def calibrate_frequencies(experiment, measured, *, names=None, start=None, bounds=None,
                          comm=None, say=None) -> FrequencyFit:
    """Fit material parameters to measured natural frequencies (all ranks call).

    Parameters
    ----------
    experiment : Experiment
        Its ``[calibrate]`` table gives the names, bounds and (its values) the start, unless
        ``names`` (and ``start``, ``bounds``) are given.
    measured : MeasuredFrequencies
        Ascending frequencies (Hz), optionally with standard deviations.
    say : callable(str), optional
        Progress lines (rank 0).

    Returns
    -------
    FrequencyFit
    """
    from petsoft.calibration.calibrate import calibration_parameters

    comm = comm if comm is not None else PETSc.COMM_WORLD
    t0 = time.perf_counter()

    def tell(line: str) -> None:
        if say is not None and comm.rank == 0:
            say(line)

    if names is None:
        names, start0, bounds0 = calibration_parameters(experiment)
        start = start0 if start is None else start
        bounds = bounds0 if bounds is None else bounds
    names = list(names)
    start = np.asarray(start, dtype=float)
    bounds = [tuple(map(float, b)) for b in (bounds or [(-np.inf, np.inf)] * len(names))]
    f_meas = measured.frequencies
    std = measured.std
    weight = 1.0 / (std if std is not None else f_meas)   # relative error without a std
    model = FrequencyModel(experiment, names, len(f_meas), comm)
    lower = np.array([b[0] for b in bounds])
    upper = np.array([b[1] for b in bounds])
    positive = [n for n in names if not n.endswith("poisson_ratio")]
    scaling = ParameterScaling(names, start, lower, upper, positive=positive)
    tell(f"petsoft calibrate --modes: {len(f_meas)} measured frequencies "
         f"({f_meas[0]:.5g} .. {f_meas[-1]:.5g} Hz) from {measured.source}; "
         f"{len(model.system.dmesh.mesh.tets)} tets on {comm.size} rank(s); fitting "
         + ", ".join(names))

    def residual(p):
        f, _ = model.evaluate(p, jacobian=False)
        return (f - f_meas) * weight

    def jacobian(p):
        _, J = model.evaluate(p, jacobian=True)
        return J * weight[:, None]

    problem = LeastSquares(residual, len(names), jacobian, scaling=scaling,
                           comm=comm.tompi4py())
    before, _ = model.evaluate(start, jacobian=False)

    pace = IterationPace()

    def monitor(rec):
        p = np.asarray(rec.p)
        tell(f"  it {rec.iteration:3d}  f {rec.f:.6e}  " + "  ".join(
            f"{n}={v:.6g}" for n, v in zip(names, p, strict=True))
             + f"  ({pace.update(rec.iteration, rec.f)})")

    result = minimize(problem, np.zeros(len(names)), method="gauss-newton",
                      bounds=scaling.bounds(), monitor=monitor, scaling=scaling,
                      options={"gatol": 1e-12, "grtol": 1e-12})
    z = np.asarray(result.z)
    values = scaling.to_physical(z)
    after, J = model.evaluate(values, jacobian=True)
    r = (after - f_meas) * weight
    Jz = scaling.jacobian_to_scaled(z, J * weight[:, None])
    sigma_source = "the file's std" if std is not None else "estimated from the fit"
    try:
        unc = uncertainty(Jz, r, scaling=scaling, z=z,
                          noise_std=1.0 if std is not None else None)
        std_p, corr, sigma = unc.std, unc.correlation, unc.sigma
    except (UnidentifiableError, PetsoftError) as exc:   # reported, not fatal
        tell(f"no standard deviations: {exc}")
        std_p, corr, sigma = np.full(len(names), np.nan), None, float("nan")
    fit = FrequencyFit(names=names, start=start, values=values, std=std_p, correlation=corr,
                       measured=f_meas, measured_std=std, before=before, after=after,
                       sigma=float(sigma), sigma_source=sigma_source,
                       iterations=int(result.iterations), evaluations=model.evaluations,
                       reason=str(result.reason), wall_time=time.perf_counter() - t0,
                       bounds=bounds)
    tell(f"{'mode':>4} {'measured Hz':>13} {'before Hz':>13} {'after Hz':>13} {'rel.err':>9}")
    for i, (fm, fb, fa) in enumerate(zip(f_meas, before, after, strict=True)):
        tell(f"{i + 1:>4} {fm:13.6g} {fb:13.6g} {fa:13.6g} {(fa - fm) / fm:9.2e}")
    for n, v, sd in zip(names, values, std_p, strict=True):
        tell(f"{n:<34} {v:14.8g}  std {sd:.3g} ({sd / abs(v):.2%})")
    tell(f"{fit.iterations} iterations, {fit.evaluations} eigen-solves, {fit.reason}, "
         f"{fit.wall_time:.1f} s")
    return fit


def write_frequency_outputs(out, experiment, fit: FrequencyFit, spelled_out: bool = False):
    """calibrated.toml (the experiment with the fitted values), summary.json, frequencies.png;
    call on rank 0."""
    from pathlib import Path

    from petsoft.calibration.plots import plot_frequencies
    from petsoft.experiment import with_parameters
    from petsoft.experiment.writer import write_experiment_update
    from petsoft.io.summary import write_summary

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    calibrated = with_parameters(experiment, dict(zip(fit.names, fit.values, strict=True)))
    write_experiment_update(experiment, calibrated, out / "calibrated.toml",
                            spelled_out=spelled_out)
    plot_frequencies(out / "frequencies.png", fit.measured, fit.before, fit.after,
                     fit.measured_std)
    write_summary(out, "calibrate --modes", fit.summary(), {}, fit.wall_time, PETSc.COMM_SELF)
