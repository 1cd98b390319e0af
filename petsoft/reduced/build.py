"""A reduced model built from a full run and checked against full runs: what a screening calls.

:func:`build_reduced` takes the full model's training run (its displacement states q_0..q_N),
further snapshot trajectories (velocities, sensitivity trajectories dq_n/dp: each set scaled
so that its largest M-norm equals the displacements', so that a set in other units weighs alike
in the POD), and full-model marker runs at check parameters (e.g. the training point, E +-10 %,
a damping coefficient moved). It builds POD bases keeping growing energy fractions, each with
its ECSW reduced mesh (trained on every ``ecsw_every``-th state), until the reduced model's
marker error (:mod:`petsoft.reduced.error`) is below ``target`` times the noise on every check,
and returns that model with its error -- or the richest one built, whose error then says it is
not below (the caller keeps the full model).

Sensitivity checks (optional) hold the full model's marker sensitivities at some parameters
(``ForwardModel.jacobian``) and a parameter change per column: the reduced sensitivities
(:mod:`petsoft.reduced.sensitivity`) times that change are compared with the full ones times
the same change, in the same noise units, as checks of their own (``"<label> d/d<name>"``):
a reduced model that fits and screens must get the derivatives right too, and on a long record
the derivatives need a richer basis than the runs (bench_reduced ``--sensitivities``).

The full runs are the caller's: this package never runs the calibration's forward model.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from petsc4py import PETSc

from petsoft.reduced.basis import coordinates_of, pod_basis
from petsoft.reduced.ecsw import SampledForces, ecsw_mesh
from petsoft.reduced.error import TARGET, ReducedError, enrich_until, reduced_error
from petsoft.reduced.galerkin import ReducedModel, steps_for
from petsoft.reduced.sensitivity import sensitivities

#: The energy fractions tried, in order (the bench's levels: 1 - 1e-7 met 0.2x the noise on
#: the 1.0 s realistic record, the 0.2 s one needed 1 - 1e-9).
ENERGIES = (1 - 1e-6, 1 - 1e-7, 1 - 1e-9, 1 - 1e-11)


def _m_norm(system, x: PETSc.Vec, work: PETSc.Vec) -> float:
    system.M.mult(x, work)
    return float(np.sqrt(max(x.dot(work), 0.0)))


def training_snapshots(system, states: Sequence[PETSc.Vec], extra=()) -> list[PETSc.Vec]:
    """New vectors: q_n - q_0 for the states after the first, then each set of ``extra``
    scaled together so that its largest M-norm is the displacements' largest."""
    if len(states) < 2:
        raise ValueError("a reduced model needs a training run of at least one step")
    work = system.create_vec()
    out = []
    for q in states[1:]:
        d = q.copy()
        d.axpy(-1.0, states[0])
        out.append(d)
    size = max(_m_norm(system, d, work) for d in out)
    for group in extra:
        group = list(group)
        if not group:
            continue
        top = max(_m_norm(system, x, work) for x in group)
        for x in group:
            y = x.copy()
            if top > 0.0:
                y.scale(size / top)
            out.append(y)
    work.destroy()
    return out


def build_reduced(system, observer, states: Sequence[PETSc.Vec], v0: PETSc.Vec, h: float,
                  frame_times, parameters: Mapping[str, float],
                  checks: Mapping[str, tuple[Mapping[str, float], np.ndarray]], noise: float,
                  extra=(), seen=None, method: str = "alpha", radius: float = 0.5,
                  energies: Sequence[float] = ENERGIES, target: float = TARGET,
                  ecsw: bool = True, ecsw_tolerance: float = 1e-3, ecsw_every: int = 5,
                  sensitivity_checks: Mapping[str, tuple] | None = None
                  ) -> tuple[ReducedModel, ReducedError]:
    """The first reduced model (over ``energies``) whose marker error is below ``target``.

    Parameters
    ----------
    system : DynamicSystem
        Left at ``parameters`` on return.
    observer
        ``observe(q) -> (M, 3)`` (as for :class:`ReducedModel`).
    states : sequence of PETSc.Vec
        The full training run's displacements q_0 .. q_N (at ``parameters``).
    v0 : PETSc.Vec
        The initial velocity.
    h : float
        The step.
    frame_times : (K,) array
        The checks' frame times.
    parameters : mapping
        The training parameter values (set on the system before each basis is built and at
        the end).
    checks : mapping
        label -> (parameter values, the full model's markers (K, M, 3) at ``frame_times``).
    noise : float
        The noise's standard deviation per coordinate.
    extra : sequence of sequences of PETSc.Vec
        More snapshot sets (velocities, sensitivity trajectories), each scaled as one.
    seen : (K, M) bool array, optional
    method, radius
        The reduced model's scheme (the full model's).
    energies : sequence of float
        The POD energy fractions tried, increasing.
    target : float
    ecsw : bool
        Hyper-reduce the elastic force (else the full assembly is projected).
    ecsw_tolerance : float
    ecsw_every : int
        ECSW trains on every this-many-th state (and the last).
    sensitivity_checks : mapping, optional
        label -> (parameter values, names (P,), the full model's marker sensitivities
        (K, M, 3, P) at ``frame_times``, the parameter change of each column (P,)).

    Returns
    -------
    (ReducedModel, ReducedError)
        ``error.below(target)`` False when no energy met the target (the richest model is
        returned). The caller destroys the model. Collective.
    """
    if not checks:
        raise ValueError("build_reduced needs at least one check (a full run to compare)")
    if ecsw_every < 1:
        raise ValueError(f"ecsw_every = {ecsw_every!r}: must be >= 1")
    energies = list(energies)
    sensitivity_checks = dict(sensitivity_checks or {})
    for label, (values, *_) in list(checks.items()) + list(sensitivity_checks.items()):
        missing = sorted(set(values) - set(parameters))
        if missing:
            raise ValueError(f"check {label!r} sets {', '.join(missing)}, which the training "
                             "parameters do not (the system could not be set back)")
    if not energies:
        raise ValueError("build_reduced needs at least one energy fraction")
    system.set_parameters(dict(parameters))
    snaps = training_snapshots(system, states, extra)
    q_ref = states[0]
    nsteps = steps_for(frame_times, h)
    train = list(states[1::ecsw_every])
    if states[-1] is not train[-1]:
        train.append(states[-1])
    built = []

    def build(level: int) -> ReducedModel:
        system.set_parameters(dict(parameters))
        V = pod_basis(system, snaps, energy=energies[level])
        forces = None
        if ecsw:
            coords = np.array([coordinates_of(system, V, q, q_ref) for q in train])
            forces = SampledForces(system, V, q_ref,
                                   ecsw_mesh(system, V, q_ref, coords, ecsw_tolerance))
        model = ReducedModel(system, V, q_ref, observer, forces=forces, method=method,
                             radius=radius)
        built.append(model)
        return model

    def check(model: ReducedModel) -> ReducedError:
        pairs = {}
        for label, (values, full) in checks.items():
            model.set_parameters(dict(values))
            pairs[label] = (full, model.run(v0, h, nsteps).frames(frame_times, h))
        for label, (values, names, full, steps) in sensitivity_checks.items():
            model.set_parameters(dict(values))
            _, red = sensitivities(model, v0, h, nsteps, names).frames(frame_times, h)
            for j, name in enumerate(names):
                pairs[f"{label} d/d{name}"] = (full[..., j] * steps[j], red[..., j] * steps[j])
        model.set_parameters(dict(parameters))
        return reduced_error(pairs, noise, seen)

    try:
        model, error, _ = enrich_until(build, check, len(energies), target)
    finally:
        for m in built[:-1]:
            m.destroy()
        for x in snaps:
            x.destroy()
    return model, error
