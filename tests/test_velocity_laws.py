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
from petsoft.experiment import Experiment, experiment_from_dict
from petsoft.experiment.spec import VELOCITY_TABLES
from petsoft.physics.velocity_law import VelocitySupport
from petsoft.terms import TERMS, Key, Parameter, Proposal, Term, builders, keys_of


def support(rng, nnodes=7, pairs=18, speed=0.3):
    node = rng.integers(0, nnodes, pairs)
    normal = rng.standard_normal((pairs, 3))
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    mass = rng.uniform(0.5, 2.0, nnodes) * (rng.random(nnodes) < 0.8)
    return VelocitySupport.of(nnodes, (node, rng.uniform(0.1, 1.0, pairs), normal), mass,
                              {"speed": speed})


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
    bare = VelocitySupport.of(sup.nnodes, None, sup.mass, sup.settings)
    assert (np.abs(law(bare).damping(v)).max() == 0.0) == law.on_surface
    heavy = law(dataclasses.replace(sup, mass=2.0 * sup.mass)).damping(v)
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
    settings = {n: dict(sup.settings) for n in NAMES}
    assert VelocityTerms(sup.nnodes, pairs, sup.mass, settings=settings
                         ).parameter_names == list(NAMES)
    assert VelocityTerms(sup.nnodes, None, sup.mass, settings=settings).parameter_names == [
        n for n in NAMES if not LAWS[n].on_surface]
    coef = {n: float(c) for n, c in zip(NAMES, rng.uniform(0.5, 2.0, len(NAMES)), strict=True)}
    where = {n: sup.mass > 0 for n in NAMES}
    vt = VelocityTerms(sup.nnodes, pairs, sup.mass, coef, where, settings)
    v, v_lin = rng.standard_normal((2, sup.nnodes, 3))
    unit = (sup.mass > 0).astype(float)
    for lin in (None, v_lin):
        want = np.zeros_like(v)
        for n, c in coef.items():
            # a law's share of d/dm: G at m + 1 minus G at m (G is affine in its masses)
            d = VelocityTerms(sup.nnodes, pairs, sup.mass + unit, {n: c}, where, settings)
            want += d.unit_linearised(n, v, lin) * c - vt.unit_linearised(n, v, lin) * c
        np.testing.assert_allclose(vt.mass_linearised(v, lin), want, atol=1e-12)
    nothing = {n: (0.0 if LAWS[n].mass_proportional else 1.0) for n in NAMES}
    assert VelocityTerms(sup.nnodes, pairs, sup.mass, nothing, where,
                         settings).mass_linearised(v, None) is None


def test_the_sum_is_each_law_times_its_coefficient():
    rng = np.random.default_rng(5)
    sup = support(rng)
    coef = {n: float(c) for n, c in zip(NAMES, rng.uniform(0.5, 2.0, len(NAMES)), strict=True)}
    vt = VelocityTerms(sup.nnodes, (sup.node, sup.weight, sup.normal), sup.mass, coef,
                       settings={n: dict(sup.settings) for n in NAMES})
    v = rng.standard_normal((sup.nnodes, 3))
    want = sum(c * LAWS[n](sup).damping(v) for n, c in coef.items())
    np.testing.assert_allclose(vt.damping(v), want, rtol=1e-13)
    assert vt.rate_bound() == pytest.approx(
        max(c * LAWS[n](sup).rate(sup.mass) for n, c in coef.items()))
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


def test_each_laws_where_and_settings_are_keys_of_its_term():
    """What a law declares it is built with (``where``, ``settings``) are keys of its own term:
    the systems read those keys for it and nothing else."""
    for t, law in builders("velocity"):
        keys = {k.dotted: k for k in t.keys if k.section == "table"}
        assert isinstance(law.where, str) and isinstance(law.settings, tuple), t.name
        if law.where:
            assert keys[law.where].type == "where", t.name
        names = [name for name, _ in law.settings]
        assert len(set(names)) == len(names), t.name
        for _, key in law.settings:
            assert keys[key].type == "number", (t.name, key)


def test_a_laws_keys_live_in_its_term():
    """A built-in law's ``where`` and ``settings`` are its term's ``where_key`` and
    ``setting_keys``; the experiment's spec of each velocity-law table holds exactly the keys
    the terms declare there, with their defaults; the reader reads them all (a ``where`` too)
    and the dict form writes them back."""
    for t, law in builders("velocity"):
        assert (law.where, law.settings) == (t.where_key, t.setting_keys), t.name
    assert TERMS["friction.dry"].where_key == "friction.where"
    assert TERMS["friction.dry"].setting_keys == (("speed", "friction.speed"),)
    assert VELOCITY_TABLES == ("drag", "friction")
    base = {"mesh": {"box": {"size": [1.0, 1.0, 1.0], "cells": [1, 1, 1]}},
            "material": {"youngs_modulus": 1e5, "poisson_ratio": 0.3, "density": 1000.0}}
    given = {"number": 0.25, "where": "x > 0.5"}
    for table in VELOCITY_TABLES:
        spec = getattr(Experiment, table)
        declared = {k.key: k.default for k in keys_of(table)}
        assert {f.name: getattr(spec, f.name) for f in dataclasses.fields(spec)} == declared
        values = {k.key: given[k.type] for k in keys_of(table)}
        exp = experiment_from_dict({**base, table: values})
        d = exp.to_dict()[table]
        assert d == values, table
        assert experiment_from_dict({**base, table: d}) == exp


class _NodeDamping:
    """A velocity law of the test's own, standing in for ``drag.linear``: G_i = s m_i v_i on
    the nodes of its ``where``, s its setting ``scale`` (here the friction's keys: a new law's
    own keys would need its own experiment table)."""

    linear = True
    on_surface = False
    mass_proportional = True
    where = "friction.where"
    settings = (("scale", "friction.speed"),)

    def __init__(self, support):
        self.mass, self.scale = support.mass, support.settings["scale"]

    def damping(self, v):
        return (self.scale * self.mass)[:, None] * v


def _fem_system(where):
    from petsoft.dynamics.system import DynamicSystem
    from petsoft.experiment import experiment_from_dict
    from petsoft.physics.model import build_model
    return DynamicSystem(build_model(experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [4, 1, 1]}},
        "material": {"youngs_modulus": 1e5, "poisson_ratio": 0.3, "density": 1000.0},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        # v_y = x: each owned row says where its node is
        "initial": {"velocity": ["1", "x", "0"]},
        "drag": {"linear": 2.0}, "friction": {"dry": 1.0, "speed": 0.5, "where": where}})))


def _spring_system(tmp_path, where):
    from petsoft.dynamics.mass_spring import MassSpringSystem, build_mass_spring_model
    from petsoft.experiment import experiment_from_dict
    from petsoft.mesh.springs import write_spring_mesh
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]], float)
    path = tmp_path / "cloth.vtu"
    write_spring_mesh(path, pts, np.array([[0, 1], [1, 2], [2, 3], [3, 0], [1, 4]]),
                      np.array([[0, 1, 2], [0, 2, 3]]))
    exp = experiment_from_dict({
        "mesh": {"file": str(path)}, "springs": {"stiffness": 10.0, "node_mass": 0.3},
        "initial": {"velocity": ["1", "x", "0"]},
        "drag": {"linear": 2.0}, "friction": {"dry": 1.0, "speed": 0.5, "where": where}},
        source="<test>")
    return MassSpringSystem(build_mass_spring_model(exp), 0.0, 0.0)


@pytest.mark.parametrize("body", ["fem", "springs"])
def test_each_system_puts_a_law_where_its_declaration_says(monkeypatch, tmp_path, body):
    """A law's ``where`` and ``settings`` are read from its declaration by both systems: a law
    of the test's own declaring ``friction.where`` acts on those nodes only (with its setting),
    its masses follow the density / node mass, and the dry friction, its declared ``where``
    emptied, acts on every node though the key is set."""
    from petsoft.physics.friction import DryFriction
    monkeypatch.setitem(LAWS, "drag.linear", _NodeDamping)
    monkeypatch.setattr(DryFriction, "where", "")
    if body == "fem":
        where, heavier = "x > 0.15", {"material.density": 1500.0}
        s = _fem_system(where)
    else:
        where, heavier = "x > 0.5", {"springs.node_mass": 0.45}
        s = _spring_system(tmp_path, where)
    try:
        _, vec = s.initial_state()
        v = vec.getArray(readonly=True).reshape(-1, 3).copy()
        edge = float(where.split(">")[1])
        inside = v[:, 1] > edge
        vt = s.velocity_terms
        m = vt.node_mass.copy()
        assert 0 < inside.sum() < len(inside) or s.comm.getSize() > 1
        np.testing.assert_array_equal(vt.unit_damping("drag.linear", v),
                                      np.where(inside, 0.5 * m, 0.0)[:, None] * v)
        friction = vt.unit_damping("friction.dry", v)
        assert np.all(np.abs(friction[m > 0]).max(axis=1) > 0)
        # the masses changed: the law's masses follow, on its nodes still
        s.set_parameters(heavier)
        np.testing.assert_allclose(s.velocity_terms.node_mass, 1.5 * m, rtol=1e-14)
        np.testing.assert_allclose(s.velocity_terms.unit_damping("drag.linear", v),
                                   np.where(inside, 0.75 * m, 0.0)[:, None] * v, rtol=1e-14)
        # the mass derivative's share, per unit mass: the law's on its nodes, the friction's
        # everywhere (G / m = v / sqrt(|v|^2 + speed^2)), on the owned nodes and, for a
        # continuum's density derivative (integrated per cell), on the local vertices
        def share(u):
            return (2.0 * np.where(u[:, 1] > edge, 0.5, 0.0)[:, None] * u
                    + u / np.sqrt(np.einsum("pi,pi->p", u, u) + 0.25)[:, None])
        np.testing.assert_allclose(vt.mass_linearised(v, None), share(v), rtol=1e-13)
        if body == "fem":
            vl = s.dmesh.to_local(vec)
            np.testing.assert_allclose(s.velocity_mass_local(vl), share(vl), rtol=1e-13)
    finally:
        s.destroy()
