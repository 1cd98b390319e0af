"""Spring networks: vectorised energy, force and Hessian kernels, and networks built from meshes.

A spring s joins nodes i and j with stiffness k and rest length L (lecture 001, "spring
Jacobians"). With d = x_i - x_j, l = |d|, n = d / l:

* energy        W_s = k/2 (l - L)^2
* gradient      dW/dx_i = k (l - L) n = -dW/dx_j          (minus the spring force on i)
* Hessian block H = k [ (1 - L/l) (I - n n^T) + n n^T ],    6x6 = [[H, -H], [-H, H]]

The transverse coefficient 1 - L/l is negative for a compressed spring (l < L), which makes the
Hessian indefinite. The *clamped* Hessian replaces it by max(0, 1 - L/l) ("set to zero if
negative, for definiteness"): every block is then k times a PSD matrix and the 6x6 spring matrix
is PSD because [[1, -1], [-1, 1]] is. With it the backward-Euler matrix M/h^2 + K is SPD for any
configuration (conjugate gradients, Cholesky), at the price of Newton being only a quasi-Newton
method for compressed springs. A degenerate spring (l = 0) has no direction: its gradient is taken
as zero (a subgradient) and its Hessian uses a fallback direction (the reference one).

Damping (dashpots) is handled by :func:`dashpot_blocks`: see its docstring for the form chosen.

Networks: :func:`network_from_cells` makes structural springs from the edges of line and triangle
cells, shear springs across the long diagonal edge of adjacent right triangles (the other diagonal
of a quad split into two triangles) and bending springs between the opposite vertices of the other
adjacent triangle pairs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Kinds of springs of a network (their index is the value of :attr:`SpringNetwork.kind`).
KINDS = ("structural", "shear", "bending", "pair")
#: A shared edge at least this many times longer than every other edge of both triangles is a
#: quad's diagonal (1.414 for the right isosceles triangles of a split grid, 1 for equilateral).
DIAGONAL_RATIO = 1.2


def spring_geometry(x: np.ndarray, edges: np.ndarray, fallback: np.ndarray | None = None):
    """Current vectors, lengths and unit directions of the springs.

    Parameters
    ----------
    x : ndarray (N, 3)
        Node positions.
    edges : ndarray (S, 2) int
    fallback : ndarray (S, 3), optional
        Unit directions used where a spring has zero length (default e_x).

    Returns
    -------
    d : (S, 3), length : (S,), n : (S, 3), degenerate : (S,) bool
    """
    d = x[edges[:, 0]] - x[edges[:, 1]]
    length = np.sqrt(np.einsum("si,si->s", d, d))
    degenerate = length <= 0.0
    safe = np.where(degenerate, 1.0, length)
    n = d / safe[:, None]
    if degenerate.any():
        fb = np.tile([1.0, 0.0, 0.0], (len(edges), 1)) if fallback is None else fallback
        n[degenerate] = fb[degenerate]
    return d, length, n, degenerate


def spring_energy(x: np.ndarray, edges: np.ndarray, rest: np.ndarray,
                  stiffness: np.ndarray) -> np.ndarray:
    """(S,) energies k/2 (l - L)^2 of the springs at positions x (N, 3)."""
    d = x[edges[:, 0]] - x[edges[:, 1]]
    length = np.sqrt(np.einsum("si,si->s", d, d))
    return 0.5 * stiffness * (length - rest) ** 2


def spring_gradient(x: np.ndarray, edges: np.ndarray, rest: np.ndarray,
                    stiffness: np.ndarray) -> np.ndarray:
    """(S, 3) dW_s/dx_i (the gradient at node i; node j gets the opposite)."""
    _, length, n, degenerate = spring_geometry(x, edges)
    g = (stiffness * (length - rest))[:, None] * n
    g[degenerate] = 0.0  # subgradient of a spring collapsed to a point
    return g


def spring_hessian_blocks(x: np.ndarray, edges: np.ndarray, rest: np.ndarray,
                          stiffness: np.ndarray, clamp: bool = False,
                          fallback: np.ndarray | None = None) -> np.ndarray:
    """(S, 3, 3) blocks H with the 6x6 spring Hessian [[H, -H], [-H, H]].

    ``clamp`` replaces the transverse coefficient 1 - L/l by max(0, 1 - L/l) (PSD, lecture 001).
    A zero-length spring gets the clamped block k n n^T with the fallback direction (its exact
    Hessian does not exist).
    """
    _, length, n, degenerate = spring_geometry(x, edges, fallback)
    safe = np.where(degenerate, 1.0, length)
    transverse = 1.0 - rest / safe
    if clamp:
        transverse = np.maximum(transverse, 0.0)
    transverse = np.where(degenerate, 0.0, transverse)
    nn = n[:, :, None] * n[:, None, :]
    eye = np.eye(3)[None]
    return stiffness[:, None, None] * (transverse[:, None, None] * (eye - nn) + nn)


def expand_blocks(blocks: np.ndarray) -> np.ndarray:
    """(S, 6, 6) spring matrices [[H, -H], [-H, H]] from (S, 3, 3) blocks."""
    out = np.empty((len(blocks), 6, 6))
    out[:, :3, :3] = blocks
    out[:, 3:, 3:] = blocks
    out[:, :3, 3:] = -blocks
    out[:, 3:, :3] = -blocks
    return out


def dashpot_blocks(points: np.ndarray, edges: np.ndarray, damping: np.ndarray) -> np.ndarray:
    """(S, 3, 3) blocks d n0 n0^T of the constant spring-dashpot damping matrix.

    Lecture 001 damps the relative velocity along the *current* direction n,
    f = -d ((v_i - v_j) . n) n, which makes D depend on q. The integrators of petsoft take a
    constant, PSD damping matrix D (their energy ledger books v^T D v as dissipation and their
    Jacobians fold D in once per step), so the dashpots here act along the *reference* direction
    n0: D_s = d [[n0 n0^T, -n0 n0^T], [-n0 n0^T, n0 n0^T]]. This is exact for small rotations
    (ropes under tension, cloth near its rest shape), is always dissipative, and keeps the
    integrators unchanged; for large rotations it damps the relative velocity along the rest
    direction rather than the current one.
    """
    n0 = points[edges[:, 0]] - points[edges[:, 1]]
    n0 = n0 / np.linalg.norm(n0, axis=1)[:, None]
    return damping[:, None, None] * (n0[:, :, None] * n0[:, None, :])


@dataclass
class SpringNetwork:
    """The springs of a mass-spring model (file node numbering).

    Attributes
    ----------
    edges : ndarray (S, 2) int64
        Node pairs.
    kind : ndarray (S,) int8
        Index into :data:`KINDS`.
    """

    edges: np.ndarray
    kind: np.ndarray

    def count(self, name: str) -> int:
        return int(np.count_nonzero(self.kind == KINDS.index(name)))


def _unique_edges(pairs: np.ndarray) -> np.ndarray:
    e = np.sort(pairs, axis=1)
    return np.unique(e, axis=0) if len(e) else e.reshape(0, 2)


def network_from_cells(points: np.ndarray, lines: np.ndarray, triangles: np.ndarray,
                       bending: bool = True) -> SpringNetwork:
    """Structural, shear and (with ``bending``) bending springs of line and triangle cells.

    Parameters
    ----------
    points : ndarray (N, 3)
    lines : ndarray (L, 2) int
    triangles : ndarray (T, 3) int
    bending : bool
        Whether to add the bending springs (a model with ``[springs] bending``).
    """
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    lines = np.asarray(lines, dtype=np.int64).reshape(-1, 2)
    tri_edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    structural = _unique_edges(np.concatenate([lines, tri_edges]))
    edges = [structural]
    kinds = [np.full(len(structural), KINDS.index("structural"), np.int8)]
    if len(tri):
        # every (triangle, local edge) with its opposite vertex; interior edges appear twice
        local = np.array([[0, 1, 2], [1, 2, 0], [2, 0, 1]])
        ends = np.sort(np.stack([tri[:, local[k, :2]] for k in range(3)], axis=1), axis=2)
        opposite = np.stack([tri[:, local[k, 2]] for k in range(3)], axis=1)
        flat_ends = ends.reshape(-1, 2)
        lengths = np.linalg.norm(points[flat_ends[:, 0]] - points[flat_ends[:, 1]], axis=1)
        lengths = lengths.reshape(-1, 3)
        # ratio of each edge to the longest other edge of its triangle
        other = np.stack([np.maximum(lengths[:, (k + 1) % 3], lengths[:, (k + 2) % 3])
                          for k in range(3)], axis=1)
        ratio = (lengths / other).ravel()
        order = np.lexsort((flat_ends[:, 1], flat_ends[:, 0]))
        fe = flat_ends[order]
        same = np.all(fe[1:] == fe[:-1], axis=1)
        first = np.flatnonzero(same)
        a, b = order[first], order[first + 1]
        opp = opposite.ravel()
        across = np.stack([opp[a], opp[b]], axis=1)
        diagonal = (ratio[a] >= DIAGONAL_RATIO) & (ratio[b] >= DIAGONAL_RATIO)
        shear = _unique_edges(across[diagonal])
        edges.append(shear)
        kinds.append(np.full(len(shear), KINDS.index("shear"), np.int8))
        if bending:
            bend = _unique_edges(across[~diagonal])
            edges.append(bend)
            kinds.append(np.full(len(bend), KINDS.index("bending"), np.int8))
    return SpringNetwork(np.concatenate(edges).astype(np.int64), np.concatenate(kinds))


def network_from_pairs(pairs) -> SpringNetwork:
    """A network of explicit node pairs (``[springs] pairs``), kept in the given order."""
    e = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    return SpringNetwork(e, np.full(len(e), KINDS.index("pair"), np.int8))
