"""Spring kernels: Taylor tests of forces and Jacobians, PSD of the clamped Hessian, networks."""

import numpy as np
import pytest

from petsoft.physics.springs import (
    KINDS,
    dashpot_blocks,
    expand_blocks,
    network_from_cells,
    spring_energy,
    spring_gradient,
    spring_hessian_blocks,
)


def _springs(rng, stretch):
    """Random springs between 6 nodes with rest lengths = stretch^-1 x current lengths."""
    x = rng.normal(size=(6, 3))
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 0], [0, 3]])
    length = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)
    rest = length / stretch
    k = rng.uniform(1.0, 10.0, size=len(edges))
    return x, edges, rest, k


def _node_gradient(x, edges, rest, k):
    g = spring_gradient(x, edges, rest, k)
    out = np.zeros_like(x)
    np.add.at(out, edges[:, 0], g)
    np.add.at(out, edges[:, 1], -g)
    return out


def _node_hessian(x, edges, rest, k, clamp=False):
    H = expand_blocks(spring_hessian_blocks(x, edges, rest, k, clamp=clamp))
    n = len(x)
    K = np.zeros((3 * n, 3 * n))
    dofs = (3 * edges[:, :, None] + np.arange(3)).reshape(-1, 6)
    for s in range(len(edges)):  # test-side reference assembly of 7 springs
        K[np.ix_(dofs[s], dofs[s])] += H[s]
    return K


def _orders(remainders, hs):
    r = np.asarray(remainders)
    return np.log(r[1:] / r[:-1]) / np.log(hs[1:] / hs[:-1])


@pytest.mark.parametrize("stretch", [0.6, 1.0, 1.7])   # compressed, at rest (by length), stretched
def test_gradient_taylor(stretch):
    rng = np.random.default_rng(1)
    x, edges, rest, k = _springs(rng, stretch)
    dx = rng.normal(size=x.shape)
    E0 = spring_energy(x, edges, rest, k).sum()
    g = _node_gradient(x, edges, rest, k)
    hs = 1e-2 * 0.5 ** np.arange(5)
    rem = [abs(spring_energy(x + h * dx, edges, rest, k).sum() - E0 - h * np.sum(g * dx))
           for h in hs]
    orders = _orders(rem, hs)
    assert np.all((orders > 1.8) & (orders < 2.2)), orders


@pytest.mark.parametrize("stretch", [0.6, 1.7])
def test_exact_hessian_taylor(stretch):
    rng = np.random.default_rng(2)
    x, edges, rest, k = _springs(rng, stretch)
    dx = rng.normal(size=x.shape)
    g0 = _node_gradient(x, edges, rest, k)
    K = _node_hessian(x, edges, rest, k)
    hs = 1e-2 * 0.5 ** np.arange(5)
    rem = [np.linalg.norm(_node_gradient(x + h * dx, edges, rest, k) - g0
                          - h * (K @ dx.ravel()).reshape(-1, 3)) for h in hs]
    orders = _orders(rem, hs)
    assert np.all((orders > 1.8) & (orders < 2.2)), orders
    assert np.allclose(K, K.T)


def test_clamped_hessian_is_psd_and_exact_when_stretched():
    """Property test over many configurations: compressed, stretched, near-degenerate, collapsed."""
    rng = np.random.default_rng(3)
    S = 4000
    xi = rng.normal(size=(S, 3))
    d = rng.normal(size=(S, 3)) * rng.choice([1e-9, 1e-3, 0.1, 1.0, 10.0], size=(S, 1))
    d[:50] = 0.0                                       # collapsed springs
    x = np.concatenate([xi, xi + d])
    edges = np.stack([np.arange(S), np.arange(S) + S], axis=1)
    rest = rng.uniform(0.01, 5.0, size=S)
    k = rng.uniform(0.1, 1e4, size=S)
    clamped = expand_blocks(spring_hessian_blocks(x, edges, rest, k, clamp=True))
    lam = np.linalg.eigvalsh(clamped)
    assert lam.min() >= -1e-9 * k.max()
    exact = expand_blocks(spring_hessian_blocks(x, edges, rest, k, clamp=False))
    lam_exact = np.linalg.eigvalsh(exact).min(axis=1)
    length = np.linalg.norm(d, axis=1)
    compressed = (length > 0) & (length < rest)
    # the exact Hessian of a compressed spring is indefinite (what the clamp is for) ...
    assert np.all(lam_exact[compressed] < 0.0)
    # ... and the clamp changes nothing for stretched springs
    stretched = length > rest
    assert np.allclose(clamped[stretched], exact[stretched])
    assert np.all(np.isfinite(clamped))


def test_collapsed_spring_has_zero_gradient_and_finite_hessian():
    x = np.zeros((2, 3))
    e = np.array([[0, 1]])
    g = spring_gradient(x, e, np.array([1.0]), np.array([5.0]))
    assert np.array_equal(g, np.zeros((1, 3)))
    H = spring_hessian_blocks(x, e, np.array([1.0]), np.array([5.0]),
                              fallback=np.array([[0.0, 1.0, 0.0]]))
    assert np.allclose(H[0], 5.0 * np.diag([0.0, 1.0, 0.0]))


def test_dashpot_is_psd_and_damps_only_along_the_rest_direction():
    pts = np.array([[0.0, 0, 0], [2.0, 0, 0]])
    D = expand_blocks(dashpot_blocks(pts, np.array([[0, 1]]), np.array([3.0])))[0]
    assert np.linalg.eigvalsh(D).min() > -1e-14
    v_axial = np.array([1.0, 0, 0, -1.0, 0, 0])
    v_transverse = np.array([0.0, 1, 0, 0, -1, 0])
    assert v_axial @ D @ v_axial == pytest.approx(3.0 * 4.0)
    assert v_transverse @ D @ v_transverse == 0.0


def _grid(nx, ny):
    xs, ys = np.meshgrid(np.arange(nx, dtype=float), np.arange(ny, dtype=float), indexing="ij")
    pts = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(nx * ny)])
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return pts, tris


def test_cloth_network_counts():
    """A 4 x 3 node grid split into right triangles: structural springs on the grid edges and
    the split diagonals, one shear spring per quad (the other diagonal) and a bending spring
    across every interior grid edge."""
    nx, ny = 4, 3
    pts, tris = _grid(nx, ny)
    net = network_from_cells(pts, np.zeros((0, 2), int), tris, bending=True)
    quads = (nx - 1) * (ny - 1)
    axis_edges = (nx - 1) * ny + nx * (ny - 1)
    assert net.count("structural") == axis_edges + quads       # grid edges + one diagonal each
    assert net.count("shear") == quads                         # the other diagonal
    interior_axis_edges = (nx - 2) * (ny - 1) + (nx - 1) * (ny - 2)
    assert net.count("bending") == interior_axis_edges
    shear = net.edges[net.kind == KINDS.index("shear")]
    lengths = np.linalg.norm(pts[shear[:, 0]] - pts[shear[:, 1]], axis=1)
    assert np.allclose(lengths, np.sqrt(2.0))
    bend = net.edges[net.kind == KINDS.index("bending")]
    blen = np.linalg.norm(pts[bend[:, 0]] - pts[bend[:, 1]], axis=1)
    assert np.allclose(blen, np.sqrt(5.0))   # across an axis edge of the split grid: a knight move
    assert network_from_cells(pts, np.zeros((0, 2), int), tris, bending=False).count(
        "bending") == 0


def test_rope_network_from_lines():
    pts = np.column_stack([np.arange(5.0), np.zeros(5), np.zeros(5)])
    lines = np.stack([np.arange(4), np.arange(1, 5)], 1)
    net = network_from_cells(pts, lines, np.zeros((0, 3), int))
    assert net.count("structural") == 4 and len(net.edges) == 4
