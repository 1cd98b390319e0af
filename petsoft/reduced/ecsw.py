"""Energy-conserving sampling and weighting (ECSW) of the elastic forces of a reduced model.

The reduced elastic force is a sum over elements, V^T f_int(q) = sum_e V_e^T f_e(q_e). ECSW
(Farhat, Avery, Chapman, Cortial 2014) replaces it by a weighted sum over a reduced mesh E',

    f_r(a) = sum_{e in E'} w_e V_e^T f_e(q_ref,e + V_e a),   w_e >= 0,

and the tangent by sum_{e in E'} w_e V_e^T K_e V_e: each sampled element's contribution is the
exact projected virtual work of that element, so the reduced force stays the gradient of a
(weighted) energy. The weights solve a non-negative least-squares problem on training
snapshots q_s: with c_{s,e} = V_e^T f_e(q_s) (r values) and every snapshot's block scaled by
1/|sum_e c_{s,e}|, the greedy selection (:func:`select_elements`) adds the element most
correlated with the residual and refits the weights of the selected ones by
``scipy.optimize.nnls``, until |G w - G 1| <= tolerance |G 1|.

Parallel: each rank evaluates its own cells; the training columns are gathered to every rank in
the order of the file's cell numbers, the same selection is made on every rank, and each keeps
the weights of its cells: the reduced mesh is the same on any number of ranks (to round-off in
the training columns). The online force is one allreduce of r (+ r^2) numbers.

Only the elastic elements are sampled: a model with nodal potential terms (elastic supports,
contact) is refused (their forces are not element sums of this kind).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from petsoft.errors import ExperimentError, InvertedElementError
from petsoft.fem.assembly import CHUNK
from petsoft.physics.elastic import ElementGroup
from petsoft.reduced.basis import PODBasis, allreduce


@dataclass
class ReducedMesh:
    """The sampled elements of this rank and their weights, per element group.

    Attributes
    ----------
    rows : list of ndarray
        For each of the system's elastic groups, the sampled elements' rows in the group.
    weights : list of ndarray
        Their weights (> 0).
    size : int
        Sampled elements on all ranks.
    error : float
        The training fit |G w - G 1| / |G 1| (the same on every rank).
    """

    rows: list
    weights: list
    size: int
    error: float

    @classmethod
    def everything(cls, system) -> ReducedMesh:
        """Every element at weight 1 (the exact projected force)."""
        groups = _elastic(system).groups
        rows = [np.arange(len(g.cells)) for g in groups]
        size = int(allreduce(system.comm, np.array([float(sum(map(len, rows)))]))[0])
        return cls(rows, [np.ones(len(r)) for r in rows], size, 0.0)


def _elastic(system):
    potential = system.elastic
    if potential.nodal_terms:
        raise ExperimentError("ECSW: the model has nodal potential terms (elastic supports, "
                              "contact or a package's term), which are not sampled; use the "
                              "full forces")
    return potential.term


def _subset(group: ElementGroup, rows: np.ndarray) -> ElementGroup:
    """The group's elements ``rows`` as a group of their own (contiguous copies)."""
    def pick(a):
        return np.ascontiguousarray(a[rows])
    return ElementGroup(group.name, group.model, pick(group.cells), pick(group.conn),
                        pick(group.dN), pick(group.volume), pick(group.mu), pick(group.lam))


class _Sample:
    """One group's sampled elements with their basis rows V_e (n, nd, r) and reference q_e."""

    def __init__(self, group: ElementGroup, rows, weights, basis: PODBasis, u_ref: np.ndarray):
        self.source, self.rows = group, np.asarray(rows, dtype=np.int64)
        self.weights = np.asarray(weights, dtype=float)
        self.group = _subset(group, self.rows)
        r = basis.size
        k = group.conn.shape[1]
        Vl = basis.local.reshape(-1, 3, r)
        self.V = np.ascontiguousarray(Vl[self.group.conn].reshape(len(self.rows), 3 * k, r))
        self.u_ref = np.ascontiguousarray(u_ref[self.group.conn].reshape(len(self.rows), 3 * k))
        self.k = k

    def refresh(self) -> None:
        """Follow the source group's (changed) Lame parameters."""
        self.group.mu[:] = self.source.mu[self.rows]
        self.group.lam[:] = self.source.lam[self.rows]

    def evaluate_lame(self, a: np.ndarray, coefficients) -> np.ndarray:
        """(r, P): sum w V^T g(q; dmu_j, dlam_j) of this rank's sampled elements, for each
        (dmu, dlam) pair of per-local-cell arrays (or None: a zero column). Every law is
        linear in its Lame parameters, so this is the derivative of the sampled force."""
        r = self.V.shape[2]
        out = np.zeros((r, len(coefficients)))
        nd = 3 * self.k
        cells = self.group.cells
        for start in range(0, len(self.rows), CHUNK):
            stop = min(start + CHUNK, len(self.rows))
            n = stop - start
            V, w = self.V[start:stop], self.weights[start:stop]
            ue = np.ascontiguousarray((self.u_ref[start:stop] + V @ a).reshape(n, self.k, 3))
            Vw = (V * w[:, None, None]).reshape(n * nd, r)
            g = np.empty((n, nd))
            for j, (dmu, dlam) in enumerate(coefficients):
                if dmu is None:
                    continue
                c = cells[start:stop]
                self.group.evaluate(start, stop, ue, g=g, mu=np.ascontiguousarray(dmu[c]),
                                    lam=np.ascontiguousarray(dlam[c]))
                out[:, j] += Vw.T @ g.reshape(-1)
        return out

    def evaluate(self, a: np.ndarray, tangent: bool):
        """(sum w V^T g, sum w V^T H V or None) of this rank's sampled elements of the group."""
        r = self.V.shape[2]
        f = np.zeros(r)
        K = np.zeros((r, r)) if tangent else None
        nd = 3 * self.k
        for start in range(0, len(self.rows), CHUNK):
            stop = min(start + CHUNK, len(self.rows))
            n = stop - start
            V, w = self.V[start:stop], self.weights[start:stop]
            ue = (self.u_ref[start:stop] + V @ a).reshape(n, self.k, 3)
            g = np.empty((n, nd))
            H = np.empty((n, nd, nd)) if tangent else None
            self.group.evaluate(start, stop, np.ascontiguousarray(ue), g=g, H=H)
            # as single matrix products over the stacked element rows (BLAS): einsum's loops
            # took 3x as long for the tangent and 8x for the force (309 10-node elements, r 30)
            Vw = (V * w[:, None, None]).reshape(n * nd, r)
            f += Vw.T @ g.reshape(-1)
            if tangent:
                K += Vw.T @ (H @ V).reshape(n * nd, r)
        return f, K


class SampledForces:
    """The reduced elastic force and tangent on a :class:`ReducedMesh` (ECSW).

    The same interface as :class:`petsoft.reduced.galerkin.FullForces`.
    """

    def __init__(self, system, basis: PODBasis, q_ref, mesh: ReducedMesh):
        self.system, self.basis, self.mesh = system, basis, mesh
        elastic = _elastic(system)
        u_ref = system.dmesh.to_local(q_ref)
        self.samples = [_Sample(g, rows, w, basis, u_ref)
                        for g, rows, w in zip(elastic.groups, mesh.rows, mesh.weights,
                                              strict=True)]
        self.counts = {"gradients": 0, "tangents": 0}

    def _sum(self, a: np.ndarray, tangent: bool):
        r = self.basis.size
        part = np.zeros(r + (r * r if tangent else 0))
        try:
            for sample in self.samples:
                f, K = sample.evaluate(a, tangent)
                part[:r] += f
                if tangent:
                    part[r:] += K.ravel()
        except InvertedElementError:
            # NaN travels with the sum to every rank: Newton stops there on all of them
            part[:] = np.nan
        total = allreduce(self.system.comm, part)
        return total[:r], (total[r:].reshape(r, r) if tangent else None)

    def force(self, a: np.ndarray) -> np.ndarray:
        self.counts["gradients"] += 1
        return self._sum(np.asarray(a, dtype=float), False)[0]

    def tangent(self, a: np.ndarray) -> np.ndarray:
        self.counts["tangents"] += 1
        return self._sum(np.asarray(a, dtype=float), True)[1]

    def parameter_force(self, a: np.ndarray, names) -> np.ndarray:
        """(r, P): d/dp_j of the sampled elastic force at a: the sampled derivative (the same
        elements and weights, the law evaluated with the Lame parameters' derivatives).
        Parameters that are not the elastic law's (damping, density, gravity) give zero here:
        their derivatives are in the reduced model's linear operators."""
        names = list(names)
        pm = self.system.parameters
        coefficients = []
        for name in names:
            dmu, dlam = (pm.coefficients(name, names)[:2] if name.startswith("material.")
                         else (None, None))
            coefficients.append((dmu, dlam) if dmu is not None else (None, None))
        a = np.asarray(a, dtype=float)
        part = np.zeros((self.basis.size, len(names)))
        try:
            for sample in self.samples:
                part += sample.evaluate_lame(a, coefficients)
        except InvertedElementError:
            part[:] = np.nan
        return allreduce(self.system.comm, part)

    def parameters_changed(self) -> None:
        for sample in self.samples:
            sample.refresh()

    def destroy(self) -> None:
        """Nothing PETSc to free."""


def training_columns(system, basis: PODBasis, q_ref, coordinates) -> tuple[np.ndarray, list]:
    """G (S r x local elements): c_{s,e} = V_e^T f_e(q_ref + V a_s) of this rank's elements
    for the S rows a_s of ``coordinates``, and for each group its elements' file cell numbers
    (the columns' order: group by group)."""
    elastic = _elastic(system)
    dm = system.dmesh
    r = basis.size
    coordinates = np.atleast_2d(np.asarray(coordinates, dtype=float))
    Vl = basis.local.reshape(-1, 3, r)
    u_ref = dm.to_local(q_ref)
    blocks, ids = [], []
    for g in elastic.groups:
        k = g.conn.shape[1]
        ids.append(dm.cell_ids[g.cells])
        block = np.empty((len(coordinates), r, len(g.cells)))
        for s, a in enumerate(coordinates):
            u = u_ref + Vl @ a
            for start in range(0, len(g.cells), CHUNK):
                stop = min(start + CHUNK, len(g.cells))
                conn = g.conn[start:stop]
                gvec = np.empty((stop - start, 3 * k))
                g.evaluate(start, stop, np.ascontiguousarray(u[conn]), g=gvec)
                V = Vl[conn].reshape(stop - start, 3 * k, r)
                block[s, :, start:stop] = np.einsum("edr,ed->re", V, gvec)
        blocks.append(block.reshape(len(coordinates) * r, len(g.cells)))
    return np.concatenate(blocks, axis=1), ids


def select_elements(G: np.ndarray, tolerance: float, max_elements: int | None = None
                    ) -> tuple[np.ndarray, np.ndarray, float]:
    """Greedy non-negative least squares: (selected columns, their weights, relative error).

    Minimises |G w - b|, b = G 1, over w >= 0 supported on a growing set: each round adds the
    columns most correlated with the residual -- one, or an eighth of the set's size when it is
    larger, so a set of hundreds is found in tens of rounds, not hundreds -- and refits the
    set's weights by ``scipy.optimize.nnls`` (columns whose weight falls to zero leave the
    set), until |G w - b| <= tolerance |b| or no column reduces the residual.
    """
    b = G.sum(axis=1)
    nb = float(np.linalg.norm(b))
    if nb == 0.0:
        return np.zeros(0, dtype=np.int64), np.zeros(0), 0.0
    limit = G.shape[1] if max_elements is None else min(int(max_elements), G.shape[1])
    chosen = np.zeros(0, dtype=np.int64)
    w = np.zeros(0)
    res = b.copy()
    err = 1.0
    while err > tolerance and len(chosen) < limit:
        score = G.T @ res
        score[chosen] = -np.inf
        batch = min(max(1, len(chosen) // 8), limit - len(chosen))
        best = np.argsort(score)[::-1][:batch]
        best = best[score[best] > 0.0]
        if len(best) == 0:
            break
        chosen = np.concatenate([chosen, best])
        w, _ = nnls(G[:, chosen], b, maxiter=50 * len(chosen) + 100)
        keep = w > 0.0
        chosen, w = chosen[keep], w[keep]
        res = b - G[:, chosen] @ w
        err = float(np.linalg.norm(res)) / nb
    return chosen, w, err


def ecsw_mesh(system, basis: PODBasis, q_ref, coordinates, tolerance: float = 1e-3,
              max_elements: int | None = None) -> ReducedMesh:
    """The reduced mesh whose weighted forces reproduce V^T f_int(q_ref + V a_s) on the
    training coordinates a_s (rows of ``coordinates``, e.g. a full run's states projected,
    :func:`petsoft.reduced.basis.coordinates_of`) to ``tolerance``: the relative residual of
    all states' blocks, each scaled to unit norm, i.e. the rms over the states of their
    relative force errors. Collective; the same mesh on any number of ranks."""
    states = np.atleast_2d(np.asarray(coordinates, dtype=float))
    if states.size == 0:
        raise ValueError("ECSW needs at least one training state")
    if not tolerance > 0.0:
        raise ValueError(f"ECSW tolerance {tolerance!r} must be positive")
    G_local, ids = training_columns(system, basis, q_ref, states)
    r = basis.size
    mpi = system.comm.tompi4py()
    parts = mpi.allgather((G_local, np.concatenate(ids)))
    G = np.concatenate([p[0] for p in parts], axis=1)
    cell = np.concatenate([p[1] for p in parts])
    order = np.argsort(cell, kind="stable")
    G, cell = G[:, order], cell[order]
    # every state counts alike: its block scaled by the norm of its projected force
    blocks = G.reshape(len(states), r, -1)
    norms = np.linalg.norm(blocks.sum(axis=2), axis=1)
    blocks = blocks / np.where(norms > 0.0, norms, 1.0)[:, None, None]
    chosen, w, err = select_elements(blocks.reshape(len(states) * r, -1), tolerance,
                                     max_elements)
    picked = np.argsort(cell[chosen])
    picked_cells, picked_w = cell[chosen][picked], w[picked]
    rows, weights = [], []
    for group_ids in ids:
        mine = np.isin(group_ids, picked_cells)
        rows.append(np.flatnonzero(mine))
        weights.append(picked_w[np.searchsorted(picked_cells, group_ids[mine])])
    return ReducedMesh(rows, weights, len(chosen), err)
