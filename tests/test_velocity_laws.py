"""The velocity laws the registry declares (petsoft.terms, contributes "velocity";
petsoft.physics.velocity_law): each law's blocks, second derivative and potential against
finite differences of its own damping, on a random surface, so a law added by its declaration
alone is checked here too; and the declared builders resolve to what their callers call."""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest

from petsoft.dynamics.rayleigh import NAMES as RAYLEIGH
from petsoft.dynamics.rayleigh import RayleighLaw
from petsoft.dynamics.velocity import LAWS, NAMES, VelocityTerms
from petsoft.physics.velocity_law import VelocitySupport
from petsoft.terms import TERMS, Key, Parameter, Proposal, Term, builders


def support(rng, nnodes=7, pairs=18, speed=0.3):
    node = rng.integers(0, nnodes, pairs)
    normal = rng.standard_normal((pairs, 3))
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    mass = rng.uniform(0.5, 2.0, nnodes) * (rng.random(nnodes) < 0.8)
    return VelocitySupport.of(nnodes, (node, rng.uniform(0.1, 1.0, pairs), normal), mass, speed)


def assert_derivative(f, df, x, d):
    """|f(x + e d) - f(x) - e df| falls at order 2 as e halves, or is round-off throughout
    (f linear along d there: the linear drag, the quadratic drag's blocks away from u = 0)."""
    scale = max(np.abs(f(x)).max(), np.abs(df).max(), 1.0)
    rem = np.array([np.abs(f(x + e * d) - f(x) - e * df).max()
                    for e in 1e-2 * 0.5 ** np.arange(4)])
    if rem.max() < 1e-12 * scale:
        return
    orders = np.log2(rem[:-1] / rem[1:])
    assert np.all((orders > 1.8) & (orders < 2.2)), (orders, rem)


@pytest.mark.parametrize("name", NAMES)
def test_each_laws_derivatives_are_those_of_its_damping(name):
    rng = np.random.default_rng(3)
    sup = support(rng)
    law = LAWS[name](sup)
    v, w, x = (rng.standard_normal((sup.nnodes, 3)) for _ in range(3))
    G = law.damping(v)
    assert G.shape == (sup.nnodes, 3) and np.abs(G).max() > 0
    B = law.blocks(v)
    np.testing.assert_allclose(B, np.transpose(B, (0, 2, 1)), atol=1e-12)     # symmetric
    assert np.linalg.eigvalsh(B).min() > -1e-12                                 # PSD
    # dG/dv . w
    assert_derivative(law.damping, np.einsum("pij,pj->pi", B, w), v, w)
    # d/dv [dG/dv x] along w, symmetric in w and x
    second = law.second(v, w, x)
    assert_derivative(lambda u: np.einsum("pij,pj->pi", law.blocks(u), x), second, v, w)
    np.testing.assert_allclose(second, law.second(v, x, w), atol=1e-12)
    if law.linear:
        assert np.abs(second).max() == 0.0
    # grad psi = G
    assert_derivative(lambda u: np.array([law.potential(u)]), np.array([np.sum(G * w)]), v, w)


@pytest.mark.parametrize("name", NAMES)
def test_each_laws_declared_support_is_the_one_it_reads(name):
    """``on_surface``: the law's damping vanishes on a support without surface pairs exactly
    when it says it acts on the surface; ``mass_proportional``: twice the support's masses give
    twice its damping when it says so, the same damping otherwise. The systems read these two
    flags (a body's parameter names, the density and node-mass derivatives)."""
    rng = np.random.default_rng(11)
    sup = support(rng)
    law = LAWS[name]
    assert isinstance(law.on_surface, bool) and isinstance(law.mass_proportional, bool)
    v = rng.standard_normal((sup.nnodes, 3))
    G = law(sup).damping(v)
    bare = VelocitySupport.of(sup.nnodes, None, sup.friction_mass, sup.speed)
    assert (np.abs(law(bare).damping(v)).max() == 0.0) == law.on_surface
    heavy = law(dataclasses.replace(sup, friction_mass=2.0 * sup.friction_mass)).damping(v)
    if law.mass_proportional:
        np.testing.assert_allclose(heavy, 2.0 * G, rtol=1e-14)
    else:
        np.testing.assert_array_equal(heavy, G)


def test_the_flags_choose_the_names_and_the_mass_share():
    """A body without a surface offers the laws that do not act on it; the mass share is the
    mass-proportional laws' damping per unit mass times their coefficients, linearised as the
    coefficient derivatives are, and None when none of them acts."""
    rng = np.random.default_rng(13)
    sup = support(rng)
    pairs = (sup.node, sup.weight, sup.normal)
    assert VelocityTerms(sup.nnodes, pairs, sup.friction_mass).parameter_names == list(NAMES)
    assert VelocityTerms(sup.nnodes, None, sup.friction_mass).parameter_names == [
        n for n in NAMES if not LAWS[n].on_surface]
    coef = {n: float(c) for n, c in zip(NAMES, rng.uniform(0.5, 2.0, len(NAMES)), strict=True)}
    vt = VelocityTerms(sup.nnodes, pairs, sup.friction_mass, coef, sup.speed)
    v, v_lin = rng.standard_normal((2, sup.nnodes, 3))
    unit = (sup.friction_mass > 0).astype(float)
    for lin in (None, v_lin):
        want = np.zeros_like(v)
        for n, c in coef.items():
            # a law's share of d/dm: G at m + 1 minus G at m (G is affine in its masses)
            more = dataclasses.replace(sup, friction_mass=sup.friction_mass + unit)
            d = VelocityTerms(sup.nnodes, pairs, more.friction_mass, {n: c}, sup.speed)
            want += d.unit_linearised(n, v, lin) * c - vt.unit_linearised(n, v, lin) * c
        np.testing.assert_allclose(vt.mass_linearised(v, lin, unit), want, atol=1e-12)
    nothing = {n: (0.0 if LAWS[n].mass_proportional else 1.0) for n in NAMES}
    assert VelocityTerms(sup.nnodes, pairs, sup.friction_mass, nothing,
                         sup.speed).mass_linearised(v, None, unit) is None


def test_the_sum_is_each_law_times_its_coefficient():
    rng = np.random.default_rng(5)
    sup = support(rng)
    coef = {n: float(c) for n, c in zip(NAMES, rng.uniform(0.5, 2.0, len(NAMES)), strict=True)}
    vt = VelocityTerms(sup.nnodes, (sup.node, sup.weight, sup.normal), sup.friction_mass, coef,
                       sup.speed, node_mass=np.full(sup.nnodes, 1.5))
    v = rng.standard_normal((sup.nnodes, 3))
    want = sum(c * LAWS[n](sup).damping(v) for n, c in coef.items())
    np.testing.assert_allclose(vt.damping(v), want, rtol=1e-13)
    assert vt.rate_bound() == pytest.approx(
        max(c * LAWS[n](sup).rate(np.full(sup.nnodes, 1.5)) for n, c in coef.items()))
    with pytest.raises(ValueError, match="no velocity term"):
        VelocityTerms(3, None, np.ones(3), {"drag.cubic": 1.0})


def test_declared_builders_resolve_to_what_their_callers_call():
    """Every term that declares a builder gets one: a nodal term's is called as a package's
    build(experiment, dmesh, resolver, dirichlet); a velocity law is a class of the protocol."""
    nodal = builders("potential")
    assert {t.name for t, _ in nodal} == {"boundary.compliance", "contact.plane"}
    for _, build in nodal:
        assert list(inspect.signature(build).parameters)[:4] == [
            "experiment", "dmesh", "resolver", "dirichlet"]
    velocity = builders("velocity")
    assert [t.name for t, _ in velocity] == list(NAMES)
    for _, law in velocity:
        for method in ("damping", "blocks", "second", "potential", "rate"):
            assert callable(getattr(law, method))
        assert isinstance(law.linear, bool)
    rayleigh = builders("rayleigh")
    assert [t.name for t, _ in rayleigh] == list(RAYLEIGH)
    assert all(isinstance(law, RayleighLaw) for _, law in rayleigh)
    declared = [t for t in TERMS.values() if t.builds]
    assert len(declared) == len(nodal) + len(velocity) + len(rayleigh)


def test_a_builder_is_declared_with_what_it_contributes():
    kw = dict(name="x.y", meaning="m", keys=(Key("x", "y"),),
              proposal=Proposal(kind="value", parameters=(Parameter("x.y", "", "0", "1"),)))
    Term(**kw, contributes="velocity", builds="petsoft.physics.drag:LinearDrag")
    for bad in [dict(contributes="velocity"), dict(builds="a:b"),
                dict(contributes="mass", builds="a:b"),
                dict(contributes="velocity", builds="petsoft.physics.drag.LinearDrag")]:
        with pytest.raises(ValueError, match="given together"):
            Term(**kw, **bad)
