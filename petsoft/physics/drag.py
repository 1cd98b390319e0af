"""Aerodynamic drag on a surface: linear and quadratic in the normal velocity (pure numpy kernels).

A surface triangle f of reference area A_f and unit normal n_f lumps its traction onto its three
nodes (A_f / 3 each). With u = v_i . n_f the normal velocity of node i,

* linear drag (``[drag] linear`` c_l, Pa s/m):        f_i = -sum_f (A_f/3) c_l u n_f,
* quadratic drag (``[drag] quadratic`` c_q, kg/m^3):  f_i = -sum_f (A_f/3) c_q |u| u n_f

(c_q = rho_air C_d / 2). Both are odd in n_f, so the normal's orientation does not matter, and a
node's force depends on its own velocity only: every Jacobian is block diagonal (3 x 3 per node).
The normals are those of the reference configuration (small rotations; the force stays a
gradient of a dissipation potential, so its velocity Jacobian is symmetric).

The kernels work on *pairs* (node, face): ``node`` (P,) the row of the node in the caller's node
array, ``weight`` (P,) = A_f/3 and ``normal`` (P, 3); forces and blocks are summed per node with
``np.bincount``. All of them are for a unit coefficient (the caller multiplies by c_l or c_q):
the residual is linear in each coefficient. Signs: "damping" quantities are minus the force
(G = -f, G' = -df/dv is positive semi-definite), as :meth:`DynamicSystem.damping_apply` adds them.
"""

from __future__ import annotations

import numpy as np

from petsoft.mesh.topology import triangle_areas_normals
from petsoft.terms import term


def face_pairs(points: np.ndarray, faces: np.ndarray, node_of: np.ndarray,
               nodes: np.ndarray | None = None, node_weights: np.ndarray | None = None):
    """(node, weight, normal) pairs of surface triangles, for the nodes a caller holds.

    Parameters
    ----------
    points : ndarray (N, 3)
        Reference coordinates (file numbering).
    faces : ndarray (F, 3)
        Triangles (file numbering); each counts once (both sides of a cloth together).
    node_of : ndarray (N,) int
        The caller's row of each file node, -1 for nodes it does not hold (pairs dropped).
    nodes, node_weights : ndarray (F, kf), optional
        The faces' nodes and their lumped areas when they are not the corners with A_f / 3
        (6-node faces of 10-node tetrahedra: :func:`petsoft.fem.element.face_lumped_areas`).

    Returns
    -------
    node : ndarray (P,) int64
    weight : ndarray (P,)
        The node's lumped area of the face (A_f / 3 for 3-node faces).
    normal : ndarray (P, 3)
        Unit reference normals.
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    area, normal = triangle_areas_normals(points, faces)
    if nodes is None:
        nodes, node_weights = faces, np.repeat((area / 3.0)[:, None], 3, axis=1)
    kf = nodes.shape[1]
    node = np.asarray(node_of)[nodes].ravel()
    weight = np.asarray(node_weights, float).ravel()
    normal = np.repeat(normal, kf, axis=0)
    keep = node >= 0
    return node[keep].astype(np.int64), weight[keep], normal[keep]


def _sum_vectors(node, values, nnodes):
    """(nnodes, 3) per-node sums of (P, 3) pair values."""
    return np.stack([np.bincount(node, values[:, k], minlength=nnodes) for k in range(3)], axis=1)


def _sum_blocks(node, values, nnodes):
    """(nnodes, 3, 3) per-node sums of (P, 3, 3) pair blocks."""
    flat = values.reshape(len(node), 9)
    return np.stack([np.bincount(node, flat[:, k], minlength=nnodes) for k in range(9)],
                    axis=1).reshape(nnodes, 3, 3)


def linear_blocks(node, weight, normal, nnodes: int) -> np.ndarray:
    """(nnodes, 3, 3) S_i = sum_f (A_f/3) n_f n_f^T: the linear drag's damping per unit c_l
    (constant, symmetric PSD); its force is -c_l S_i v_i."""
    nn = normal[:, :, None] * normal[:, None, :]
    return _sum_blocks(node, weight[:, None, None] * nn, nnodes)


def quadratic_damping(v: np.ndarray, node, weight, normal) -> np.ndarray:
    """(nnodes, 3) G = -f of the quadratic drag per unit c_q: sum_f (A_f/3) |u| u n_f."""
    u = np.einsum("pi,pi->p", v[node], normal)
    return _sum_vectors(node, (weight * np.abs(u) * u)[:, None] * normal, len(v))


def quadratic_damping_blocks(v: np.ndarray, node, weight, normal) -> np.ndarray:
    """(nnodes, 3, 3) dG/dv per unit c_q: sum_f 2 (A_f/3) |u| n_f n_f^T (PSD)."""
    u = np.einsum("pi,pi->p", v[node], normal)
    nn = normal[:, :, None] * normal[:, None, :]
    return _sum_blocks(node, (2.0 * weight * np.abs(u))[:, None, None] * nn, len(v))


def quadratic_damping_second(v: np.ndarray, w: np.ndarray, x: np.ndarray, node, weight,
                             normal) -> np.ndarray:
    """(nnodes, 3) d/dv [dG/dv x] along w per unit c_q: sum_f 2 (A_f/3) sign(u) (n.w)(n.x) n
    (symmetric in w and x)."""
    u = np.einsum("pi,pi->p", v[node], normal)
    nw = np.einsum("pi,pi->p", w[node], normal)
    nx = np.einsum("pi,pi->p", x[node], normal)
    return _sum_vectors(node, (2.0 * weight * np.sign(u) * nw * nx)[:, None] * normal, len(v))


def quadratic_potential(v: np.ndarray, node, weight, normal) -> float:
    """sum_f (A_f/3) |u|^3 / 3 per unit c_q: the dissipation potential whose gradient is G."""
    u = np.einsum("pi,pi->p", v[node], normal)
    return float(np.sum(weight * np.abs(u) ** 3) / 3.0)


class LinearDrag:
    """``drag.linear``'s law (:mod:`petsoft.physics.velocity_law`): G_i = S_i v_i per unit
    c_l, S_i = :func:`linear_blocks` (constant)."""

    linear = True
    on_surface = term("drag.linear").surface
    mass_proportional = False
    where = term("drag.linear").where_key
    settings = term("drag.linear").setting_keys

    def __init__(self, support):
        self.S = linear_blocks(support.node, support.weight, support.normal, support.nnodes)

    def damping(self, v: np.ndarray) -> np.ndarray:
        return np.einsum("pij,pj->pi", self.S, v)

    def blocks(self, v: np.ndarray) -> np.ndarray:
        return self.S

    def second(self, v: np.ndarray, w: np.ndarray, x: np.ndarray) -> np.ndarray:
        return np.zeros_like(v)

    def potential(self, v: np.ndarray) -> float:
        return 0.5 * float(np.einsum("pi,pij,pj->", v, self.S, v))

    def rate(self, node_mass: np.ndarray | None) -> float:
        """max_i trace S_i / m_i over the nodes with mass (the lumped area over the mass)."""
        if node_mass is None or not len(node_mass):
            return 0.0
        free = node_mass > 0.0
        if not np.any(free):
            return 0.0
        return float(np.max(np.einsum("pii->p", self.S)[free] / node_mass[free]))


class QuadraticDrag:
    """``drag.quadratic``'s law (:mod:`petsoft.physics.velocity_law`): per unit c_q,
    G_i = sum_f (A_f/3) |u| u n_f. Its rate 2 c_q (A_i/m_i) |v.n| grows with the speed and is
    not bounded (``rate`` 0)."""

    linear = False
    on_surface = term("drag.quadratic").surface
    mass_proportional = False
    where = term("drag.quadratic").where_key
    settings = term("drag.quadratic").setting_keys

    def __init__(self, support):
        self.pairs = (support.node, support.weight, support.normal)

    def damping(self, v: np.ndarray) -> np.ndarray:
        return quadratic_damping(v, *self.pairs)

    def blocks(self, v: np.ndarray) -> np.ndarray:
        return quadratic_damping_blocks(v, *self.pairs)

    def second(self, v: np.ndarray, w: np.ndarray, x: np.ndarray) -> np.ndarray:
        return quadratic_damping_second(v, w, x, *self.pairs)

    def potential(self, v: np.ndarray) -> float:
        return quadratic_potential(v, *self.pairs)

    def rate(self, node_mass: np.ndarray | None) -> float:
        return 0.0
