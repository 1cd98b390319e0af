"""Colliders: consistent penalty energy/force/Hessian (Taylor tests), PSD clamp, friction."""

import numpy as np
import pytest

from petsoft.experiment import ColliderSpec
from petsoft.physics.colliders import FRICTION_VELOCITY, Collider, default_stiffness

SPHERE = Collider("sphere", 500.0, center=np.array([0.1, -0.2, 0.3]), radius=1.0)
PLANE = Collider("plane", 800.0, point=np.array([0.0, 0.0, -0.5]),
                 normal=np.array([0.0, 0.6, 0.8]))


def _inside(c, rng, n=20):
    """Points penetrating the collider by 1..10 % of the radius (or 0.01..0.1 for the plane)."""
    depth = rng.uniform(0.01, 0.1, size=n)
    if c.kind == "sphere":
        u = rng.normal(size=(n, 3))
        u /= np.linalg.norm(u, axis=1)[:, None]
        return c.center + (c.radius - depth)[:, None] * u
    t = rng.normal(size=(n, 3))
    t -= (t @ c.normal)[:, None] * c.normal
    return c.point + t - depth[:, None] * c.normal


def _orders(rem, hs):
    rem = np.asarray(rem)
    return np.log(rem[1:] / rem[:-1]) / np.log(hs[1:] / hs[:-1])


@pytest.mark.parametrize("c", [SPHERE, PLANE], ids=["sphere", "plane"])
def test_contact_force_and_jacobian_taylor(c):
    rng = np.random.default_rng(4)
    x = _inside(c, rng)
    dx = rng.normal(size=x.shape)
    E0, g0, H = c.energy(x).sum(), c.gradient(x), c.hessian(x)
    hs = 1e-3 * 0.5 ** np.arange(5)   # small enough that no point leaves the contact
    remE = [abs(c.energy(x + h * dx).sum() - E0 - h * np.sum(g0 * dx)) for h in hs]
    remG = [np.linalg.norm(c.gradient(x + h * dx) - g0 - h * np.einsum("pij,pj->pi", H, dx))
            for h in hs]
    checks = [remE, remG]
    if c.kind == "plane":
        # the plane's penalty is exactly quadratic in contact: the gradient's Taylor remainder is
        # round-off, not O(h^2)
        scale = [h * np.linalg.norm(np.einsum("pij,pj->pi", H, dx)) for h in hs]
        assert max(r / s for r, s in zip(remG, scale, strict=True)) < 1e-8
        checks = [remE]
    for rem in checks:
        orders = _orders(rem, hs)
        assert np.all((orders > 1.8) & (orders < 2.2)), orders
    assert np.allclose(H, np.transpose(H, (0, 2, 1)))


@pytest.mark.parametrize("c", [SPHERE, PLANE], ids=["sphere", "plane"])
def test_no_force_outside(c):
    rng = np.random.default_rng(5)
    x = _inside(c, rng)
    _, n, _ = c.distance(x)
    outside = x + 0.2 * n
    assert np.all(c.energy(outside) == 0.0)
    assert np.all(c.gradient(outside) == 0.0)
    assert np.all(c.hessian(outside) == 0.0)
    # the force pushes penetrating points out along the normal
    f = -c.gradient(x)
    assert np.all(np.einsum("pi,pi->p", f, n) > 0.0)


def test_sphere_hessian_is_indefinite_and_clamped_psd():
    rng = np.random.default_rng(6)
    x = _inside(SPHERE, rng, 200)
    assert np.linalg.eigvalsh(SPHERE.hessian(x)).min() < 0.0
    assert np.linalg.eigvalsh(SPHERE.hessian(x, clamp=True)).min() >= -1e-12


def test_friction_opposes_sliding_and_is_bounded():
    rng = np.random.default_rng(7)
    c = Collider("plane", 1000.0, friction=0.4, point=np.zeros(3), normal=np.array([0, 0, 1.0]))
    x = np.column_stack([rng.normal(size=(30, 2)), -rng.uniform(0.001, 0.01, 30)])
    v = rng.normal(size=(30, 3))
    f = c.friction_force(x, v)
    fn = 1000.0 * -x[:, 2]
    assert np.all(np.einsum("pi,pi->p", f, v) <= 0.0)           # dissipative
    assert np.allclose(f[:, 2], 0.0)                              # tangential
    assert np.all(np.linalg.norm(f, axis=1) <= 0.4 * fn * (1 + 1e-12))   # Coulomb cone
    fast = c.friction_force(x, 1e3 * v)
    assert np.allclose(np.linalg.norm(fast, axis=1), 0.4 * fn, rtol=1e-6)
    slow = c.friction_force(x, 1e-3 * FRICTION_VELOCITY * v)      # viscous regime: ~ linear
    assert np.allclose(c.friction_force(x, 2e-3 * FRICTION_VELOCITY * v), 2 * slow, rtol=1e-5)
    assert np.all(c.friction_force(x * [1, 1, -1], v) == 0.0)   # out of contact: none


def test_default_stiffness_rule():
    masses = np.array([0.0, 0.5, 2.0])
    assert default_stiffness(masses, 0.01, 7.0) == pytest.approx(4 * 2.0 / 0.01 ** 2)
    assert default_stiffness(masses, None, 7.0) == 7000.0
    spec = ColliderSpec(kind="sphere", center=(0.0, 0.0, 0.0), radius=1.0)
    assert Collider.from_spec(spec, 123.0).stiffness == 123.0
    given = ColliderSpec(kind="plane", point=(0, 0, 0), normal=(0, 0, 1.0), stiffness=3.0)
    assert Collider.from_spec(given, 1e9).stiffness == 3.0


@pytest.mark.parametrize("kind", ["sphere", "plane"])
def test_c2_margin_variant_taylor_and_continuity(kind):
    """With a margin the penalty is C2: Taylor tests hold across phi = 0 and phi = delta, and the
    curvature is continuous there."""
    base = SPHERE if kind == "sphere" else PLANE
    c = Collider(**{**base.__dict__, "margin": 0.05})
    rng = np.random.default_rng(8)
    x = _inside(c, rng, 40)
    _, n, _ = c.distance(x)
    x = x + rng.uniform(-0.02, 0.08, size=(40, 1)) * n   # in the margin, inside and outside
    dx = rng.normal(size=x.shape)
    E0, g0, H = c.energy(x).sum(), c.gradient(x), c.hessian(x)
    hs = 1e-2 * 0.5 ** np.arange(6)   # large enough to cross phi = 0 and phi = delta
    remE = [abs(c.energy(x + h * dx).sum() - E0 - h * np.sum(g0 * dx)) for h in hs]
    orders = _orders(remE, hs)
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    remG = [np.linalg.norm(c.gradient(x + h * dx) - g0 - h * np.einsum("pij,pj->pi", H, dx))
            for h in hs[2:]]
    orders = _orders(remG, hs[2:])
    assert np.all(orders > 1.8), orders
    e, de, dde = c._profile(np.array([-1e-12, 1e-12, 0.05 - 1e-12, 0.05 + 1e-12]))
    assert dde[0] == pytest.approx(dde[1], rel=1e-9) and dde[2] == pytest.approx(dde[3], abs=1e-6)
    assert de[0] == pytest.approx(de[1], rel=1e-9)


def test_friction_damping_is_the_velocity_jacobian():
    rng = np.random.default_rng(9)
    c = Collider("sphere", 300.0, friction=0.7, center=np.zeros(3), radius=1.0)
    x = _inside(c, rng, 10)
    v = rng.normal(size=(10, 3)) * 0.01
    dv = rng.normal(size=(10, 3))
    D = c.friction_damping(x, v)
    hs = 1e-4 * 0.5 ** np.arange(5)
    rem = [np.linalg.norm(c.friction_force(x, v + h * dv) - c.friction_force(x, v)
                          + h * np.einsum("pij,pj->pi", D, dv)) for h in hs]
    orders = _orders(rem, hs)
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    assert np.linalg.eigvalsh(D).min() >= -1e-12
