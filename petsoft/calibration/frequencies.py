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
* pairing: without mode shapes the measured frequencies, ascending, are the body's lowest
  elastic modes in order (rigid-body modes of a free body are skipped). With mode shapes at
  markers (a JSON file's ``mode_shapes``, or the operational shapes estimated from a recording)
  more model modes are computed than were measured (``count + max(4, count)``, doubled at the
  first evaluation until they reach 1.3 x the highest measured frequency), each is
  evaluated at the markers (embedded once in the serial mesh; on several ranks each rank adds
  the nodes it owns and the sums are reduced), and the measured modes are paired with distinct
  model modes maximising the total MAC (:func:`mac_matrix`; Hungarian assignment). The pairing
  is redone at every evaluation, since modes can change order as the parameters move. A pair
  with MAC below :data:`DOUBTFUL_MAC` is reported as doubtful. A cluster of (nearly) equal model
  eigenvalues (a square section's two bending modes) has no derivative per mode; each of its
  members gets the derivative of the cluster's mean, which exists and is what a symmetric change
  of E, nu or rho moves.
* :func:`calibrate_frequencies`: Gauss-Newton (Levenberg-Marquardt) in scaled parameters on the
  residuals (f_model - f_measured) / std, standard deviations from the Gauss-Newton covariance.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from petsc4py import PETSc
from scipy.optimize import linear_sum_assignment

from petsoft.calibration.optimize import LeastSquares, minimize
from petsoft.calibration.scaling import ParameterScaling
from petsoft.calibration.spectra import frequencies_from_recording
from petsoft.calibration.uncertainty import UnidentifiableError, uncertainty
from petsoft.dynamics.factory import system_class
from petsoft.dynamics.system import DynamicSystem
from petsoft.errors import ExperimentError, PetsoftError
from petsoft.fem.element import cell_integrals
from petsoft.io.frequencies import read_frequencies
from petsoft.io.progress import IterationPace
from petsoft.io.recording import HDF5_SIGNATURE, on_rank0_for_all, read_recording
from petsoft.mesh.probes import embed
from petsoft.physics.model import build_model
from petsoft.results import OptimizerFit
from petsoft.solvers.modes import compute_modes
from petsoft.solvers.options import SolverOptions

__all__ = ["FrequencyFit", "FrequencyModel", "PairingWarning", "calibrate_frequencies",
           "mac_matrix", "read_measured_modes", "write_frequency_outputs"]

#: Model eigenvalues closer than this (relative) form a cluster (module docstring).
CLUSTER_RTOL = 1e-6
#: At most this many model modes are computed for the MAC pairing (module docstring).
MAX_MODEL_MODES = 100
#: A measured mode paired at a MAC below this is reported as a doubtful pair.
DOUBTFUL_MAC = 0.6


class PairingWarning(UserWarning):
    """A measured mode pairs with a model mode of low MAC: the pairing is doubtful."""


def mac_matrix(model: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """Modal assurance criterion of every measured shape against every model shape.

    MAC_ij = |psi_i^H phi_j|^2 / ((psi_i^H psi_i)(phi_j^T phi_j)), both sums over the components
    seen in measured mode i only (a component not seen, NaN, is left out of all three sums, so a
    partly seen shape is compared with the model's shape on the same components). 1 for shapes
    equal up to scale and sign (or a complex factor, for operational shapes), 0 for orthogonal
    ones.

    Parameters
    ----------
    model : ndarray (n, m, 3)
        Model mode shapes at the m markers (real).
    measured : ndarray (k, m, 3)
        Measured shapes, real or complex, NaN where not seen.

    Returns
    -------
    ndarray (k, n)
        In [0, 1]; 0 where either shape vanishes on the seen components.
    """
    phi = np.asarray(model, dtype=float)
    psi = np.asarray(measured)
    seen = np.isfinite(psi)
    psi = np.where(seen, psi, 0.0)
    num = np.abs(np.einsum("kmc,nmc->kn", np.conj(psi), phi)) ** 2
    den = (np.einsum("kmc,nmc->kn", seen.astype(float), phi * phi)
           * np.sum(np.abs(psi) ** 2, axis=(1, 2))[:, None])
    return np.divide(num, den, out=np.zeros_like(num), where=den > 0)


@dataclass
class Pairing:
    """Which model mode each measured mode is paired with, at one evaluation.

    Attributes
    ----------
    model_modes : ndarray (k,) int
        0-based index among the model's elastic modes (ascending) of each measured mode's pair.
    mac : ndarray (k,) or None
        The MAC of each pair (None without shapes: pairing in ascending order).
    matrix : ndarray (k, n) or None
        MAC of every measured mode against every computed model mode.
    model_hz : ndarray (n,)
        All computed elastic model frequencies.
    """

    model_modes: np.ndarray
    mac: np.ndarray | None
    matrix: np.ndarray | None
    model_hz: np.ndarray

    @property
    def doubtful(self) -> list[int]:
        """0-based measured modes whose pair has MAC < :data:`DOUBTFUL_MAC`."""
        if self.mac is None:
            return []
        return [int(i) for i in np.flatnonzero(self.mac < DOUBTFUL_MAC)]

    def summary(self) -> dict:
        """JSON-able: the method, 1-based model modes, MAC of each pair and the matrix."""
        mac = self.mac is not None
        return {"method": "mac" if mac else "ascending",
                "model_modes": [int(i) + 1 for i in self.model_modes],
                "mac": self.mac.tolist() if mac else None,
                "mac_matrix": self.matrix.tolist() if mac else None,
                "model_modes_computed": int(len(self.model_hz)),
                "model_hz_computed": self.model_hz.tolist(),
                "doubtful": [i + 1 for i in self.doubtful], "doubtful_below": DOUBTFUL_MAC}


class FrequencyModel:
    """The elastic natural frequencies of an experiment's model paired with measured modes, as a
    function of named material parameters (collective on ``comm``).

    Parameters
    ----------
    experiment : Experiment
        A continuum model ([material]); loads and [time] are ignored.
    names : sequence of str
        Material parameters (module docstring).
    count : int
        How many elastic frequencies (the measured ones).
    comm : PETSc.Comm, optional
    measured : MeasuredFrequencies, optional
        With ``shapes`` (and ``markers``): pair by MAC (module docstring); else in ascending
        order.
    model_modes : int, optional
        Elastic model modes computed for the MAC pairing (default ``count + max(4, count)``,
        more at the first evaluation until they reach 1.3 x the highest measured frequency,
        at most :data:`MAX_MODEL_MODES`).

    Raises
    ------
    ExperimentError
        A spring model, parameters that are not material ones, a marker outside the mesh.
    """

    def __init__(self, experiment, names, count: int, comm=None, *, measured=None,
                 model_modes: int | None = None):
        self.comm = comm if comm is not None else PETSc.COMM_WORLD
        self.names, self.count = list(names), int(count)
        # the eigensolver's options (no prefix, as `petsoft modes`) from the [petsc] table
        self.options = SolverOptions("", experiment.petsc)
        body = system_class(experiment)
        if not body.continuum_material:
            raise ExperimentError(f"{experiment.source}: calibration from frequencies needs a "
                                  f"[material] model (a {body.defined_by} model has no modes "
                                  "solver)")
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
        self.shapes = None if measured is None else measured.shapes
        self.pairing: Pairing | None = None
        if self.shapes is not None:
            if len(self.shapes) != self.count:
                raise ValueError(f"{len(self.shapes)} measured shapes for {self.count} modes")
            self.model_modes = int(model_modes or self.count + max(4, self.count))
            self._grow = model_modes is None
            self.f_max = float(np.max(measured.frequencies))
            if self.model_modes < self.count:
                raise ValueError(f"model_modes = {self.model_modes} < {self.count} measured")
            self._embed_markers(measured)
        else:
            self.model_modes, self._grow = self.count, False

    def _embed_markers(self, measured) -> None:
        """The local owned nodes and weights of each marker: a mode at the markers is then the
        sum over ranks of the owned nodes' weighted values (each node is owned once)."""
        dm = self.system.dmesh
        cells, weights = embed(dm.mesh, measured.markers, source=f"{measured.source}: markers",
                               names=measured.marker_names)
        local = dm.file_to_local[dm.mesh.cells[cells]]               # (m, nodes), -1 elsewhere
        mine = local >= 0
        mine[mine] = dm.owned[local[mine]]
        self._marker_nodes = np.where(mine, local, 0)
        self._marker_weights = np.where(mine, weights, 0.0)

    def at_markers(self, modes) -> np.ndarray:
        """Global mode vectors evaluated at the markers: (n, m, 3), the same on every rank."""
        dm = self.system.dmesh
        part = np.array([np.einsum("ma,mac->mc", self._marker_weights,
                                   dm.to_local(x)[self._marker_nodes]) for x in modes])
        return np.asarray(dm.comm.tompi4py().allreduce(part.reshape(len(modes), -1, 3)))

    def _modes(self):
        model = self.system.model
        res = compute_modes(model, self.model_modes, options=self.options)
        if res.rigid_modes:
            rigid = res.rigid_modes
            res.destroy()
            res = compute_modes(model, self.model_modes + rigid, options=self.options)
        return res

    def _enough_modes(self, res):
        """At the first evaluation with shapes: compute more modes until the highest lies 30 %
        above the highest measured frequency (a measured mode can be any model mode below it,
        and the start may be far off); the count found is kept for later evaluations."""
        self._grow = False
        model = self.system.model
        free = 3 * model.dmesh.nglobal_vertices - model.dirichlet.count - res.rigid_modes
        limit = min(MAX_MODEL_MODES, free // 2)     # SLEPc wants room beside the wanted pairs
        while res.frequencies_hz[-1] < 1.3 * self.f_max and self.model_modes < limit:
            self.model_modes = min(2 * self.model_modes, limit)
            res.destroy()
            res = self._modes()
        return res

    def evaluate(self, p, jacobian: bool = True):
        """Frequencies (count,) in Hz of the model modes paired with the measured ones, at
        parameters ``p``, and df/dp (count, n) or None. The pairing is kept in
        :attr:`pairing`."""
        s = self.system
        s.set_parameters(dict(zip(self.names, map(float, p), strict=True)))
        self.evaluations += 1
        res = self._modes()
        try:
            first = res.rigid_modes
            if self._grow and self.shapes is not None:
                res = self._enough_modes(res)
                first = res.rigid_modes
            lam = res.eigenvalues[first:first + self.model_modes]
            modes = res.modes[first:first + self.model_modes]
            if len(lam) < self.model_modes:
                raise ExperimentError(f"the model has only {len(lam)} elastic modes; "
                                      f"{self.model_modes} are needed for {self.count} measured "
                                      "frequencies")
            f_all = np.sqrt(np.maximum(lam, 0.0)) / (2.0 * np.pi)
            if self.shapes is None:
                pair, mac, matrix = np.arange(self.count), None, None
            else:
                matrix = mac_matrix(self.at_markers(modes), self.shapes)
                rows, pair = linear_sum_assignment(matrix, maximize=True)
                pair = pair[np.argsort(rows)]
                mac = matrix[np.arange(self.count), pair]
            self.pairing = Pairing(pair, mac, matrix, f_all)
            f = f_all[pair]
            if not jacobian:
                return f, None
            # clusters: the derivative of their mean (module docstring); only the clusters of
            # paired modes are differentiated
            cluster = np.zeros(len(lam), dtype=int)
            for i in range(1, len(lam)):
                close = lam[i] - lam[i - 1] <= CLUSTER_RTOL * lam[i]
                cluster[i] = cluster[i - 1] + (0 if close else 1)
            needed = np.flatnonzero(np.isin(cluster, cluster[pair]))
            dlam = {int(i): self._eigenvalue_gradient(modes[i], lam[i]) for i in needed}
            mean = {c: np.mean([dlam[int(i)] for i in needed[cluster[needed] == c]], axis=0)
                    for c in np.unique(cluster[pair])}
            dl = np.array([mean[cluster[i]] for i in pair])
            return f, dl / (8.0 * np.pi ** 2 * f[:, None])
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


@dataclass(repr=False)
class FrequencyFit(OptimizerFit):
    """The result of :func:`calibrate_frequencies` (physical parameters): ``success`` when the
    optimizer stopped on a convergence test, ``params``/``param_std`` by name."""

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
    #: the pairing of measured and model modes at the start and at the fitted values
    pairing_before: Pairing | None = None
    pairing: Pairing | None = None
    #: how the measured frequencies were obtained (MeasuredFrequencies.details), if known
    measured_details: dict | None = None
    #: rms of (f_model - f_measured) / std over degrees of freedom (None without std): ~1 when
    #: the model fits the frequencies to their stated std
    residual_over_std: float | None = None

    evaluation = "eigen-solves"

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
            "pairing": None if self.pairing is None else self.pairing.summary(),
            "pairing_before": (None if self.pairing_before is None
                               else self.pairing_before.summary()),
            "residual_over_std": self.residual_over_std,
            "measured": self.measured_details,
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
        Frequencies (Hz), optionally with standard deviations; with mode shapes at markers the
        modes are paired by MAC (module docstring), else in ascending order.
    say : callable(str), optional
        Progress lines (rank 0).

    Returns
    -------
    FrequencyFit

    Warns
    -----
    PairingWarning
        (rank 0) When a measured mode's pair at the fitted values has MAC < :data:`DOUBTFUL_MAC`.
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
    model = FrequencyModel(experiment, names, len(f_meas), comm, measured=measured)
    positive = [n for n in names if not n.endswith("poisson_ratio")]
    scaling = ParameterScaling(names, start, np.array([b[0] for b in bounds]),
                               np.array([b[1] for b in bounds]), positive=positive)
    _say_measured(tell, measured, model, names, comm)

    def residual(p):
        f, _ = model.evaluate(p, jacobian=False)
        return (f - f_meas) * weight

    def jacobian(p):
        _, J = model.evaluate(p, jacobian=True)
        return J * weight[:, None]

    problem = LeastSquares(residual, len(names), jacobian, scaling=scaling,
                           comm=comm.tompi4py())
    before, _ = model.evaluate(start, jacobian=False)
    pairing_before = model.pairing
    result = _gauss_newton(problem, scaling, names, experiment, tell)
    z = np.asarray(result.z)
    values = scaling.to_physical(z)
    after, J = model.evaluate(values, jacobian=True)
    pairing = model.pairing
    r = (after - f_meas) * weight
    std_p, corr, sigma = _parameter_std(scaling, z, J * weight[:, None], r, std is not None,
                                        tell)
    sigma_source = "the file's std" if std is not None else "estimated from the fit"
    fit = FrequencyFit(names=names, start=start, values=values, std=std_p, correlation=corr,
                       measured=f_meas, measured_std=std, before=before, after=after,
                       sigma=float(sigma), sigma_source=sigma_source,
                       iterations=int(result.iterations), evaluations=model.evaluations,
                       reason=str(result.reason), wall_time=time.perf_counter() - t0,
                       bounds=bounds, pairing_before=pairing_before, pairing=pairing,
                       measured_details=measured.details)
    _say_frequencies(tell, f_meas, std, before, after, pairing)
    if std is not None and len(r) > len(names):
        fit.residual_over_std = _misfit_over_std(r, len(names), tell)
    _say_pairing(tell, comm, f_meas, after, pairing, pairing_before, model.model_modes)
    for n, v, sd in zip(names, values, std_p, strict=True):
        rel = f"{sd / abs(v):.2%}" if v != 0 else "of a zero value"
        tell(f"{n:<34} {v:14.8g}  std {sd:.3g} ({rel})")
    tell(f"{fit.iterations} iterations, {fit.evaluations} eigen-solves, {fit.reason}, "
         f"{fit.wall_time:.1f} s")
    return fit


def _say_measured(tell, measured, model, names: list[str], comm) -> None:
    """The opening lines of :func:`calibrate_frequencies`: what is fitted to what (the
    recording's oscillations, the pairing by MAC)."""
    f_meas = measured.frequencies
    tell(f"petsoft calibrate --modes: {len(f_meas)} measured frequencies "
         f"({f_meas[0]:.5g} .. {f_meas[-1]:.5g} Hz) from {measured.source}; "
         f"{len(model.system.dmesh.mesh.tets)} tets on {comm.size} rank(s); fitting "
         + ", ".join(names))
    oscillations = (measured.details or {}).get("oscillations")
    if oscillations:
        tell(f"oscillations in the recording ({measured.details['frames']} frames, "
             f"{measured.details['duration_s']:.4g} s; natural frequency = |pole|):")
        for q in oscillations:
            tell(f"  {q['frequency_hz']:12.6g} Hz  std {q['std_hz']:.2g}  damping ratio "
                 f"{q['damping_ratio']:9.2e}  amplitude {q['amplitude']:.3g}  "
                 + ("seen" if q["seen"] else f"not used: {q['note']}"))
    if measured.shapes is not None:
        tell(f"pairing by MAC of the mode shapes at {len(measured.markers)} markers with the "
             f"model's {model.model_modes} lowest elastic modes")


def _gauss_newton(problem, scaling, names: list[str], experiment, tell):
    """The fit of ``problem`` from the start (scaled 0), a line per iteration."""
    pace = IterationPace()

    def monitor(rec):
        p = np.asarray(rec.p)
        tell(f"  it {rec.iteration:3d}  f {rec.f:.6e}  " + "  ".join(
            f"{n}={v:.6g}" for n, v in zip(names, p, strict=True))
             + f"  ({pace.update(rec.iteration, rec.f)})")

    return minimize(problem, np.zeros(len(names)), method="gauss-newton",
                    bounds=scaling.bounds(), monitor=monitor, scaling=scaling,
                    options={"gatol": 1e-12, "grtol": 1e-12},
                    solver_options=SolverOptions("cal_", experiment.petsc))


def _parameter_std(scaling, z: np.ndarray, J: np.ndarray, r: np.ndarray, stated: bool, tell):
    """(std, correlation, sigma) of the fitted parameters from the weighted Jacobian ``J`` and
    residual ``r`` at the scaled ``z`` (``stated``: the residual is in units of the file's std);
    NaN std when they are not identifiable (said, not fatal)."""
    Jz = scaling.jacobian_to_scaled(z, J)
    try:
        unc = uncertainty(Jz, r, scaling=scaling, z=z, noise_std=1.0 if stated else None)
        return unc.std, unc.correlation, unc.sigma
    except (UnidentifiableError, PetsoftError) as exc:   # reported, not fatal
        tell(f"no standard deviations: {exc}")
        return np.full(len(z), np.nan), None, float("nan")


def _say_frequencies(tell, f_meas, std, before, after, pairing) -> None:
    """The table of the measured frequencies beside the model's before and after the fit
    (with the paired model mode and its MAC when paired by shapes)."""
    mac = pairing.mac is not None
    tell(f"{'mode':>4} {'measured Hz':>13} {'before Hz':>13} {'after Hz':>13} {'rel.err':>9}"
         + (f" {'err/std':>8}" if std is not None else "")
         + (f" {'model mode':>10} {'MAC':>6}" if mac else ""))
    for i, (fm, fb, fa) in enumerate(zip(f_meas, before, after, strict=True)):
        tell(f"{i + 1:>4} {fm:13.6g} {fb:13.6g} {fa:13.6g} {(fa - fm) / fm:9.2e}"
             + (f" {(fa - fm) / std[i]:8.2f}" if std is not None else "")
             + (f" {pairing.model_modes[i] + 1:>10d} {pairing.mac[i]:6.3f}"
                + ("  doubtful" if i in pairing.doubtful else "") if mac else ""))


def _misfit_over_std(r: np.ndarray, n_parameters: int, tell) -> float:
    """The rms of the residual in units of the stated std; said when it is large (the
    parameters' std assume the model fits to the stated std)."""
    chi = float(np.sqrt(r @ r / (len(r) - n_parameters)))
    if chi > 3.0:
        tell(f"warning: the calibrated frequencies miss the measured ones by {chi:.3g} of "
             "their std (rms): model error (mesh, supports, a mode not paired right) or "
             "optimistic std; the parameters' std are too small by about that factor")
    return chi


def _say_pairing(tell, comm, f_meas, after, pairing, pairing_before, model_modes: int) -> None:
    """Whether the pairing changed during the fit, and each doubtful pair (also a
    :class:`PairingWarning` on rank 0)."""
    if pairing.mac is not None and not np.array_equal(pairing.model_modes,
                                                       pairing_before.model_modes):
        tell("the pairing changed during the fit: at the start the measured modes paired with "
             "model modes " + ", ".join(str(int(m) + 1) for m in pairing_before.model_modes))
    for i in pairing.doubtful:
        message = (f"measured mode {i + 1} ({f_meas[i]:.6g} Hz) pairs with model elastic mode "
                   f"{pairing.model_modes[i] + 1} ({after[i]:.6g} Hz) at MAC "
                   f"{pairing.mac[i]:.3f} < {DOUBTFUL_MAC}: the pairing is doubtful (too few or "
                   "badly placed markers, a noisy shape, or a mode the model lacks or that lies "
                   f"above the {model_modes} model modes computed)")
        tell(f"warning: {message}")
        if comm.rank == 0:
            warnings.warn(message, PairingWarning, stacklevel=3)


def read_measured_modes(path, comm=None):
    """What ``petsoft calibrate --modes FILE`` reads (all ranks call; rank 0 reads, the result
    or the error goes to every rank).

    An HDF5 file is a recording: its natural frequencies, their std and operational shapes at
    the markers are estimated from the trajectories
    (:func:`petsoft.calibration.spectra.frequencies_from_recording`). Anything else is a
    measured-frequencies file (:func:`petsoft.io.frequencies.read_frequencies`).

    Returns
    -------
    MeasuredFrequencies
    """
    def read():
        file = Path(path)
        try:
            with open(file, "rb") as f:
                hdf5 = f.read(len(HDF5_SIGNATURE)) == HDF5_SIGNATURE
        except OSError:
            hdf5 = False                   # read_frequencies names the missing file
        return (frequencies_from_recording(read_recording(file)) if hdf5
                else read_frequencies(file))

    return on_rank0_for_all(read, comm if comm is not None else PETSc.COMM_WORLD)


def write_frequency_outputs(out, experiment, fit: FrequencyFit, spelled_out: bool = False):
    """calibrated.toml (the experiment with the fitted values), summary.json, frequencies.png;
    call on rank 0."""
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
