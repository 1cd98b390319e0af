"""Reduced-order models (petsoft.reduced): POD basis, Galerkin steps, ECSW, error measure.

On a tiny neo-Hookean bar (box 4x1x1 cells, 24 tets, 60 dofs, 48 free), damped (Rayleigh
alpha and beta), under gravity, with an initial displacement and velocity:

1. The POD basis is M-orthonormal (V^T M V = I computed here by PETSc products) and reproduces
   its snapshots to its truncation: the snapshots' M-energy outside the basis is the sum of the
   dropped eigenvalues and at most (1 - energy) of the total.
2. A basis spanning every free dof (unit-vector snapshots, energy 1) reproduces the full
   forward model's markers (ForwardModel.simulate) to round-off, for generalized-alpha and
   backward Euler, also with every term a diagnosis adds changed in place (Rayleigh damping,
   linear drag, gravity, a region's density and stiffness); the chord (kept reduced tangent)
   converges to the Newton solution with fewer tangents.
3. ECSW: every element at weight 1 gives the full assembly's V^T f_int and V^T K V to
   round-off; the greedy NNLS selection reproduces V^T f_int on each training state to its
   tolerance (checked state by state against the full assembly), with fewer elements.
4. The error measure equals a direct comparison of two runs' markers (rms and max over the
   noise, unseen markers left out); the enrichment loop stops at the first basis below its
   target (errors falling with the energy kept).
5. On 2 ranks the reduced model (basis, ECSW mesh, run) equals the one each rank builds alone.
"""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.errors import ExperimentError
from petsoft.experiment import experiment_from_dict
from petsoft.reduced.basis import BasisError, coordinates_of, pod_basis
from petsoft.reduced.ecsw import ReducedMesh, SampledForces, ecsw_mesh, training_columns
from petsoft.reduced.error import enrich_until, marker_error, reduced_error
from petsoft.reduced.galerkin import FullForces, ReducedModel, steps_for

MARKERS = np.array([[0.3, 0.04, 0.04], [0.3, 0.0, 0.0], [0.15, 0.02, 0.04], [0.2, 0.01, 0.0]])
FRAMES = np.array([0.004, 0.0075, 0.013, 0.02])


def _bar(integrator="alpha", **extra):
    data = {
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [4, 1, 1]}},
        "material": {"model": "neohookean", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "damping": {"mass": 0.5, "stiffness": 0.002},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"displacement": ["0", "0", "0.3*x**2"], "velocity": ["0", "0.1*x", "0"]},
        "time": {"end": 0.02, "step": 2e-3, "integrator": integrator, "alpha_radius": 0.9},
    }
    data.update(extra)
    return experiment_from_dict(data)


def _forward(integrator="alpha", comm=None, **extra):
    exp = _bar(integrator, **extra)
    return exp, ForwardModel(exp, ["material.youngs_modulus"],
                             lambda s: MarkerObserver(s, MARKERS), FRAMES, comm=comm)


def _trajectory(fm):
    """The full run's displacement states q_0 .. q_N (new vectors)."""
    states, _ = fm._run(fm.p0, store=True)
    out = [q.copy() for q, _, _ in states]
    fm._free(states)
    return out


def _differences(states):
    out = []
    for q in states[1:]:
        d = q.copy()
        d.axpy(-1.0, states[0])
        out.append(d)
    return out


def _unit_vectors(system):
    template = system.create_vec()
    lo, hi = template.getOwnershipRange()
    out = []
    for i in range(template.getSize()):
        x = template.duplicate()
        x.zeroEntries()
        if lo <= i < hi:
            x.setValue(i, 1.0)
        x.assemble()
        out.append(x)
    template.destroy()
    return out


def _m_inner(system, x, y):
    mx = system.create_vec()
    system.M.mult(x, mx)
    out = y.dot(mx)
    mx.destroy()
    return out


# -- 1. the basis -------------------------------------------------------------------------------
def test_pod_basis_is_m_orthonormal_and_holds_its_energy():
    exp, fm = _forward("alpha")
    s = fm.system
    snaps = _differences(_trajectory(fm))
    energy = 0.999
    V = pod_basis(s, snaps, energy=energy)
    r = V.size
    assert 1 <= r < len(snaps)
    cols = [V.expand_column(j, s.create_vec()) for j in range(r)]
    gram = np.array([[_m_inner(s, cols[i], cols[j]) for j in range(r)] for i in range(r)])
    assert np.abs(gram - np.eye(r)).max() < 1e-12
    # the snapshots' M-energy outside span(V): sum_j |s_j - V V^T M s_j|_M^2
    outside = total = 0.0
    for x in snaps:
        y = x.copy()
        s.zero_prescribed(y)
        total += _m_inner(s, y, y)
        coef = np.array([_m_inner(s, c, y) for c in cols])
        for c, a in zip(cols, coef, strict=True):
            y.axpy(-a, c)
        outside += _m_inner(s, y, y)
    dropped = V.eigenvalues[r:].clip(min=0.0).sum()
    assert outside == pytest.approx(dropped, rel=1e-6, abs=1e-14 * total)
    assert outside <= (1.0 - energy) * total
    assert V.energy >= energy
    # one vector fewer would not hold the energy (r is the least that does)
    assert V.eigenvalues[:r - 1].sum() < energy * V.eigenvalues.clip(min=0.0).sum()
    fm.destroy()


def test_pod_basis_refuses_bad_input():
    exp, fm = _forward("alpha")
    s = fm.system
    with pytest.raises(BasisError, match="no snapshots"):
        pod_basis(s, [])
    x = s.create_vec()
    x.set(1.0)
    with pytest.raises(BasisError, match="energy"):
        pod_basis(s, [x], energy=0.0)
    x.zeroEntries()
    with pytest.raises(BasisError, match="all zero"):
        pod_basis(s, [x])
    fm.destroy()


# -- 2. a full basis reproduces the full model ------------------------------------------------
@pytest.mark.parametrize("method", ["alpha", "be"])
def test_full_basis_reproduces_the_full_run(method):
    exp, fm = _forward(method)
    full = fm.simulate(fm.p0)
    s = fm.system
    V = pod_basis(s, _unit_vectors(s), energy=1.0)
    assert V.size == 3 * 16          # every free dof of the 20-vertex bar (4 clamped)
    q0, v0 = s.initial_state()
    rm = ReducedModel(s, V, q0, fm.observer, method=method, radius=0.9)
    red = rm.run(v0, fm.h, steps_for(FRAMES, fm.h)).frames(FRAMES, fm.h)
    motion = np.abs(full - full[0]).max()
    assert motion > 1e-3
    assert np.abs(red - full).max() <= 1e-10 * motion
    # a changed parameter is followed by both
    p = fm.p0 * 1.1
    full = fm.simulate(p)
    rm.set_parameters({"material.youngs_modulus": float(p[0]), "damping.mass": 0.5})
    red = rm.run(v0, fm.h, steps_for(FRAMES, fm.h)).frames(FRAMES, fm.h)
    assert np.abs(red - full).max() <= 1e-10 * motion
    rm.destroy()
    fm.destroy()


TERMS = ["material.youngs_modulus", "damping.mass", "damping.stiffness", "drag.linear",
         "gravity.acceleration.z", "material.tip.density", "material.tip.youngs_modulus"]


@pytest.mark.parametrize("sampled", [False, True])
def test_full_basis_follows_every_term(sampled):
    """Each term a diagnosis adds (Rayleigh damping, linear drag, gravity, a region's added
    mass and stiffness) changed in place: the full-basis reduced model (full assembly, or ECSW
    with every element at weight 1) still reproduces the full run."""
    exp = _bar("alpha", drag={"linear": 0.0}, region={"tip": {"where": "x > 0.2"}},
               material={"model": "neohookean", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                         "density": 1000.0, "tip": {"density": 1000.0}})
    fm = ForwardModel(exp, TERMS, lambda s: MarkerObserver(s, MARKERS), FRAMES)
    s = fm.system
    q0, v0 = s.initial_state()
    V = pod_basis(s, _unit_vectors(s), energy=1.0)
    forces = SampledForces(s, V, q0, ReducedMesh.everything(s)) if sampled else None
    rm = ReducedModel(s, V, q0, fm.observer, forces=forces, method="alpha", radius=0.9)
    p = fm.p0.copy()
    moved = dict(zip(TERMS, p, strict=True))
    moved.update({"material.youngs_modulus": 1.2e5, "damping.mass": 2.0,
                  "damping.stiffness": 0.004, "drag.linear": 30.0,
                  "gravity.acceleration.z": -20.0, "material.tip.density": 3000.0,
                  "material.tip.youngs_modulus": 3e5})
    p = np.array([moved[n] for n in TERMS])
    base = fm.simulate(fm.p0)
    full = fm.simulate(p)
    rm.set_parameters(moved)
    red = rm.run(v0, fm.h, steps_for(FRAMES, fm.h)).frames(FRAMES, fm.h)
    change = np.abs(full - base).max()
    assert change > 1e-4          # the terms matter here
    assert np.abs(red - full).max() <= 1e-10 * np.abs(full - full[0]).max()
    rm.destroy()
    fm.destroy()


def test_chord_converges_to_the_newton_solution_with_fewer_tangents():
    exp, fm = _forward("alpha")
    s = fm.system
    states = _trajectory(fm)
    V = pod_basis(s, _differences(states), energy=0.99999)
    _, v0 = s.initial_state()
    out = {}
    for chord in (False, True):
        forces = FullForces(s, V, states[0])
        rm = ReducedModel(s, V, states[0], fm.observer, forces=forces, radius=0.9)
        rm.chord = chord
        out[chord] = (rm.run(v0, fm.h, steps_for(FRAMES, fm.h)).frames(FRAMES, fm.h),
                      forces.counts["tangents"])
        rm.destroy()
    motion = np.abs(out[False][0] - out[False][0][0]).max()
    assert np.abs(out[True][0] - out[False][0]).max() <= 1e-9 * motion
    assert out[True][1] < out[False][1]
    fm.destroy()


def test_reduced_model_refuses_what_it_does_not_reduce():
    exp, fm = _forward("alpha", drag={"quadratic": 0.3})
    s = fm.system
    snaps = _differences(_trajectory(fm))
    q0, _ = s.initial_state()
    with pytest.raises(ExperimentError, match="quadratic drag"):
        ReducedModel(s, pod_basis(s, snaps), q0, fm.observer)
    fm.destroy()


# -- 3. ECSW ------------------------------------------------------------------------------------
def test_ecsw_with_every_element_is_exact_and_selection_meets_its_tolerance():
    exp, fm = _forward("alpha")
    s = fm.system
    states = _trajectory(fm)
    V = pod_basis(s, _differences(states), energy=0.99999)
    q0 = states[0]
    full = FullForces(s, V, q0)
    every = SampledForces(s, V, q0, ReducedMesh.everything(s))
    rng = np.random.default_rng(1)
    a = 1e-3 * rng.normal(size=V.size)
    f, K = full.force(a), full.tangent(a)
    assert np.abs(every.force(a) - f).max() <= 1e-12 * np.abs(f).max()
    assert np.abs(every.tangent(a) - K).max() <= 1e-12 * np.abs(K).max()
    tol = 1e-3
    coords = np.array([coordinates_of(s, V, q, q0) for q in states[1:]])
    mesh = ecsw_mesh(s, V, q0, coords, tolerance=tol)
    ncells = s.dmesh.allreduce_sum(len(s.dmesh.cells))
    assert 0 < mesh.size < ncells
    assert mesh.error <= tol
    sampled = SampledForces(s, V, q0, mesh)
    # state by state against the full assembly (not the selection's own columns): the rms of
    # the relative errors is the selection's measure
    errs = [np.linalg.norm(sampled.force(c) - full.force(c)) / np.linalg.norm(full.force(c))
            for c in coords]
    assert np.sqrt(np.mean(np.square(errs))) == pytest.approx(mesh.error, rel=1e-6)
    assert max(errs) > 0.0
    G, _ = training_columns(s, V, q0, coords)
    assert G.shape == (len(coords) * V.size, len(s.dmesh.cells))
    # a reduced run on the sampled mesh stays near the full-assembly reduced run
    _, v0 = s.initial_state()
    runs = [ReducedModel(s, V, q0, fm.observer, forces=forces, method="alpha", radius=0.9)
            .run(v0, fm.h, steps_for(FRAMES, fm.h)).frames(FRAMES, fm.h)
            for forces in (FullForces(s, V, q0), sampled)]
    motion = np.abs(runs[0] - runs[0][0]).max()
    assert np.abs(runs[1] - runs[0]).max() <= 1e-2 * motion
    fm.destroy()


# -- 4. the error measure -----------------------------------------------------------------------
def test_error_measure_is_the_direct_comparison():
    exp, fm = _forward("alpha")
    full = fm.simulate(fm.p0)
    s = fm.system
    V = pod_basis(s, _differences(_trajectory(fm)), energy=0.99)
    q0, v0 = s.initial_state()
    red = ReducedModel(s, V, q0, fm.observer, method="alpha", radius=0.9).run(
        v0, fm.h, steps_for(FRAMES, fm.h)).frames(FRAMES, fm.h)
    noise = 1e-5
    seen = np.ones(full.shape[:2], dtype=bool)
    seen[1, 2] = False
    d = (red - full)[seen]
    rms, mx = marker_error(full, red, noise, seen)
    assert rms > 0.0
    assert rms == pytest.approx(np.sqrt(np.sum(d**2) / d.size) / noise, rel=1e-12)
    assert mx == pytest.approx(np.abs(d).max() / noise, rel=1e-12)
    both = reduced_error({"train": (full, red), "same": (full, full)}, noise, seen)
    assert both.rms == pytest.approx(rms) and both.checks["same"]["rms"] == 0.0
    assert not both.below(rms / 2) and both.below(rms * 2)
    with pytest.raises(ValueError, match="positive noise"):
        marker_error(full, red, 0.0)
    with pytest.raises(ValueError, match="shapes"):
        marker_error(full, red[:2], noise)
    fm.destroy()


def test_enrichment_stops_at_the_first_basis_below_the_target():
    """enrich_until on bases of growing energy: it returns the first whose error (measured
    here against the full run) is below the target, or the last one."""
    exp, fm = _forward("alpha")
    full = fm.simulate(fm.p0)
    s = fm.system
    states = _trajectory(fm)
    snaps = _differences(states)
    _, v0 = s.initial_state()
    energies = [0.9, 0.999, 1.0]
    built = []

    def build(level):
        V = pod_basis(s, snaps, energy=energies[level])
        built.append(V.size)
        return ReducedModel(s, V, states[0], fm.observer, radius=0.9)

    def check(model):
        run = model.run(v0, fm.h, steps_for(FRAMES, fm.h))
        return reduced_error({"train": (full, run.frames(FRAMES, fm.h))}, 1e-6)

    errors = [check(build(level)).rms for level in range(len(energies))]
    assert errors[0] > errors[1] > errors[2]
    built.clear()
    target = 0.5 * (errors[0] + errors[1])         # between the first two levels
    model, err, level = enrich_until(build, check, len(energies), target=target)
    assert level == 1 and err.rms == pytest.approx(errors[1]) and len(built) == 2
    built.clear()
    model, err, level = enrich_until(build, check, len(energies), target=0.5 * errors[2])
    assert level == 2 and not err.below(0.5 * errors[2]) and len(built) == 3
    fm.destroy()


# -- 5. 2 ranks == 1 rank -----------------------------------------------------------------------
def test_reduced_model_same_on_one_and_all_ranks():
    results = []
    for comm in (PETSc.COMM_WORLD, PETSc.COMM_SELF):
        exp, fm = _forward("alpha", comm=comm)
        s = fm.system
        states = _trajectory(fm)
        V = pod_basis(s, _differences(states), energy=0.99999)
        coords = np.array([coordinates_of(s, V, q, states[0]) for q in states[1:]])
        mesh = ecsw_mesh(s, V, states[0], coords, tolerance=1e-3)
        _, v0 = s.initial_state()
        rm = ReducedModel(s, V, states[0], fm.observer,
                          forces=SampledForces(s, V, states[0], mesh), radius=0.9)
        run = rm.run(v0, fm.h, steps_for(FRAMES, fm.h))
        results.append((V.size, mesh.size, run.frames(FRAMES, fm.h)))
        rm.destroy()
        fm.destroy()
    (r_all, m_all, f_all), (r_one, m_one, f_one) = results
    assert (r_all, m_all) == (r_one, m_one)
    motion = np.abs(f_one - f_one[0]).max()
    assert np.abs(f_all - f_one).max() <= 1e-9 * motion
