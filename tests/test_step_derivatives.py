"""The tangent and adjoint steps each differentiable scheme carries (dynamics.step_derivatives).

For every scheme with gradients (the registry's ``Scheme.derivatives``: be, si, alpha), on one
step of a small corotated cantilever with Rayleigh damping, quadratic drag and dry friction (so
that SI's third-derivative term T_w and the velocity terms' second derivative are on): the
adjoint step is the transpose of the tangent step, checked by the dot-product identity

    <g1, d1> = <g0, d0> - <R_p, mu>

for random tangents d0 = (dq0, dv0, da0), random adjoints g1 = (gq1, gv1, ga1) and a random
R_p, where d1 = tangent_step(d0; R_p), g0 = adjoint_step(g1) and mu the multiplier the adjoint
step hands to ``contract``. be and si also with the marker accelerations a1 = (v1 - v0)/h
carried. The forward model's Taylor tests (tests/test_sensitivity.py) check the tangent itself
against finite differences; this checks the adjoint against the tangent one step at a time,
through the public protocol alone. Runs on 1 and 2 ranks.
"""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

from petsoft.dynamics.alpha import GeneralizedAlpha, consistent_acceleration
from petsoft.dynamics.factory import build_system
from petsoft.dynamics.implicit import ImplicitIntegrator
from petsoft.dynamics.integrators import scheme, with_gradients
from petsoft.experiment import experiment_from_dict

H = 2e-3


def _experiment(method):
    return experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [4, 1, 1]}},
        "material": {"model": "corotated", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "damping": {"mass": 0.5, "stiffness": 0.002},
        "drag": {"quadratic": 2000.0},
        "friction": {"dry": 2.0, "speed": 0.01},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"displacement": ["0", "0", "0.3*x**2"], "velocity": ["0", "0.1*x", "0"]},
        "time": {"end": H, "step": H, "integrator": method},
    })


def _random(s, rng):
    x = s.create_vec()
    x.getArray()[:] = rng.standard_normal(x.getLocalSize())
    s.zero_prescribed(x)
    return x


def _dot(xs, ys) -> tuple[float, float]:
    """sum <x, y> and sum |x| . |y| (the scale the round-off is relative to)."""
    total, scale = 0.0, 0.0
    for x, y in zip(xs, ys, strict=True):
        if x is None:
            continue
        total += x.dot(y)
        xa, ya = x.copy(), y.copy()
        xa.abs()
        ya.abs()
        scale += xa.dot(ya)
        xa.destroy()
        ya.destroy()
    return total, scale


def test_every_scheme_with_gradients_has_its_derivatives():
    assert set(with_gradients()) == {"be", "si", "alpha"}
    for name in ("midpoint", "trapezoidal", "explicit", "ere", "imex"):
        assert scheme(name).derivatives is None and not scheme(name).gradients


@pytest.mark.parametrize("method,accel", [("be", False), ("be", True), ("si", False),
                                          ("si", True), ("alpha", False)])
def test_adjoint_step_is_the_transpose_of_the_tangent_step(method, accel):
    exp = _experiment(method)
    s = build_system(exp, PETSc.COMM_WORLD)
    carries = scheme(method).carries_acceleration
    integ = (GeneralizedAlpha(s, 0.5) if carries else ImplicitIntegrator(s, method))
    q0, v0 = s.initial_state()
    a0 = a1 = None
    if carries:
        a0 = s.create_vec()
        consistent_acceleration(s, 0.0, q0, v0, a0)
    q1, v1 = q0.duplicate(), v0.duplicate()
    assert integ.step(0.0, q0, v0, H, q1, v1).converged
    if carries:
        a1 = integ.a0.copy()
    steps = scheme(method).derivatives(s, integ, H, accel)
    assert steps.carries_acceleration == carries
    J = s.create_matrix()
    lin = steps.linearize(0, (q0, v0, a0), (q1, v1, a1), J)
    if method == "si":
        assert lin.T is not None and lin.w is not None     # the terms under test are on
    ksp = PETSc.KSP().create(comm=s.comm)
    s.linear_defaults(ksp)
    ksp.setOperators(J)
    ksp.setTolerances(rtol=1e-14)

    def solve(rhs, out):
        ksp.solve(rhs, out)
        assert ksp.getConvergedReason() > 0

    rng = np.random.default_rng(7 + s.comm.getRank())
    has_a = carries or accel
    d0 = [_random(s, rng), _random(s, rng), _random(s, rng) if has_a else None]
    g1 = [_random(s, rng), _random(s, rng), _random(s, rng) if has_a else None]
    Rp = _random(s, rng)
    d1 = [x.copy() if x is not None else None for x in d0]
    rhs, tmp, mu = s.create_vec(), s.create_vec(), s.create_vec()
    steps.tangent_step(lin, Rp, d1[0], d1[1], d1[2], None, solve, rhs, tmp, q1, "test")
    taken = []
    g0 = steps.adjoint_step(lin, *[x.copy() if x is not None else None for x in g1], solve,
                            lambda deriv, m: taken.append(m.copy()), mu, rhs, tmp)
    assert len(taken) == 1
    left, s1 = _dot(g1, d1)
    right, s0 = _dot(g0, d0)
    coupling, s2 = _dot([Rp], taken)
    gap = abs(left - (right - coupling))
    if s.comm.getRank() == 0:
        print(f"{method} (accelerations {accel}): |gap| / scale = {gap / (s0 + s1 + s2):.2e}")
    assert gap <= 1e-12 * (s0 + s1 + s2), (left, right, coupling)
    # and the identity is not trivially met: each side is of the order of its scale
    assert abs(left) > 1e-6 * s1 and abs(coupling) > 1e-6 * s2
    lin.free()
    for x in [q0, v0, q1, v1, a0, a1, Rp, rhs, tmp, mu, J, ksp, *d0, *d1, *g1, *g0,
              *taken]:
        if x is not None:
            x.destroy()
    integ.destroy()
    s.destroy()
