"""The velocity laws the registry declares (petsoft.terms, contributes "velocity";
petsoft.physics.velocity_law): each law's blocks, second derivative and potential against
finite differences of its own damping, on a random surface, so a law added by its declaration
alone is checked here too; and the declared builders resolve to what their callers call."""

from __future__ import annotations

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
