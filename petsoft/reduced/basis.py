"""An M-orthonormal POD basis of displacement snapshots, by the method of snapshots.

For k snapshots s_1..s_k (global vectors, e.g. q_n - q_0 of a full run and sensitivity
trajectories dq/dp) the correlation C = S^T M S (k x k) is summed over the ranks from each
rank's owned rows, so the basis is the same on any number of ranks. With C = U diag(l) U^T
(l descending), the basis V = S U_r diag(l_r)^(-1/2) is M-orthonormal, and r is the least
number whose eigenvalues hold ``energy`` of the total: the snapshots' M-norm error after
projection, sum_j |s_j - V V^T M s_j|_M^2, is exactly the sum of the dropped eigenvalues.

Snapshots are zeroed on prescribed rows first (a reduced displacement q_ref + V a then keeps the
supports of q_ref). The basis is held as a dense (3 nv, r) array on the rank's local vertices
(owned first, in the global vector's order, then ghosts): the element-level hyper-reduction
needs the ghost rows, the projections the owned ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

#: Eigenvalues of the correlation below this fraction of the largest are round-off, never kept
#: (their directions are noise amplified by 1/sqrt(l)).
ROUND_OFF = 1e-13


class BasisError(ValueError):
    """A basis cannot be built from what was given (no snapshots, a bad energy fraction)."""


@dataclass
class PODBasis:
    """r M-orthonormal vectors, as rows of the rank's local vertices.

    Attributes
    ----------
    local : ndarray (3 nv, r)
        The vectors at the local vertices (owned rows first).
    nowned : int
        Owned dofs (3 x owned vertices): ``local[:nowned]`` are the global vector's rows.
    eigenvalues : ndarray (k,)
        All eigenvalues of the snapshot correlation, descending (the discarded ones included).
    energy : float
        The fraction of the snapshots' M-energy the kept vectors hold.
    """

    local: np.ndarray
    nowned: int
    eigenvalues: np.ndarray
    energy: float
    comm: PETSc.Comm
    _dense: PETSc.Mat | None = field(default=None, repr=False)
    _dense_array: np.ndarray | None = field(default=None, repr=False)

    @property
    def size(self) -> int:
        return self.local.shape[1]

    @property
    def owned(self) -> np.ndarray:
        return self.local[:self.nowned]

    def project(self, x: PETSc.Vec) -> np.ndarray:
        """V^T x (r,), summed over the ranks (x a force: its rows are dual to displacements)."""
        part = self.owned.T @ x.getArray(readonly=True)
        return allreduce(self.comm, part)

    def project_operator(self, apply, work: PETSc.Vec, out_vec: PETSc.Vec) -> np.ndarray:
        """V^T A V (r x r) from r products ``apply(v_j, out_vec)`` (A v_j into out_vec)."""
        r = self.size
        AV = np.empty((self.nowned, r))
        for j in range(r):
            apply(self.expand_column(j, work), out_vec)
            AV[:, j] = out_vec.getArray(readonly=True)
        return allreduce(self.comm, self.owned.T @ AV)

    def project_matrix(self, A: PETSc.Mat) -> np.ndarray:
        """V^T A V (r x r) by one sparse-times-dense product A V (one collective operation,
        where r products A v_j made r, each with its ghost exchange)."""
        if self._dense is None:
            # PETSc uses the array's memory: kept alive with the matrix
            self._dense_array = np.asfortranarray(self.owned)
            rows = A.getSizes()[1]
            self._dense = PETSc.Mat().createDense((rows, (PETSc.DECIDE, self.size)),
                                                  array=self._dense_array, comm=self.comm)
            self._dense.assemble()
        AV = A.matMult(self._dense)
        out = allreduce(self.comm, self.owned.T @ AV.getDenseArray())
        AV.destroy()
        return out

    def destroy(self) -> None:
        if self._dense is not None:
            self._dense.destroy()
            self._dense = None

    def expand(self, a: np.ndarray, out: PETSc.Vec, add: bool = False) -> PETSc.Vec:
        """out = V a (or out += V a)."""
        arr = out.getArray()
        if add:
            arr += self.owned @ a
        else:
            arr[:] = self.owned @ a
        return out

    def expand_column(self, j: int, out: PETSc.Vec) -> PETSc.Vec:
        out.getArray()[:] = self.owned[:, j]
        return out


def allreduce(comm: PETSc.Comm, part: np.ndarray) -> np.ndarray:
    """The sum over the ranks of an array (the same on every rank)."""
    part = np.ascontiguousarray(part, dtype=float)
    total = np.empty_like(part)
    comm.tompi4py().Allreduce(part, total, op=MPI.SUM)
    return total


def pod_basis(system, snapshots, energy: float = 0.99999, max_size: int | None = None
              ) -> PODBasis:
    """The M-orthonormal POD basis of ``snapshots`` holding ``energy`` of their M-energy.

    Parameters
    ----------
    system : DynamicSystem
        Its mass matrix M, prescribed rows (zeroed in the snapshots' copies) and mesh (ghost
        rows of the basis).
    snapshots : sequence of PETSc.Vec
        Global vectors (not modified).
    energy : float
        0 < energy <= 1: the kept eigenvalues' share of the total (1 keeps every direction
        above round-off, :data:`ROUND_OFF`).
    max_size : int, optional
        At most this many vectors (the energy held is then reported as it is).

    Returns
    -------
    PODBasis
        Collective; the same vectors on any number of ranks (to round-off).
    """
    snaps = list(snapshots)
    if not snaps:
        raise BasisError("no snapshots: a POD basis needs at least one")
    if not 0.0 < energy <= 1.0:
        raise BasisError(f"energy = {energy!r}: the kept fraction must be in (0, 1]")
    dm, comm = system.dmesh, system.comm
    nown = snaps[0].getLocalSize()
    S = np.empty((nown, len(snaps)))
    MS = np.empty_like(S)
    work, mx = system.create_vec(), system.create_vec()
    for j, s in enumerate(snaps):
        s.copy(work)
        system.zero_prescribed(work)
        S[:, j] = work.getArray(readonly=True)
        system.M.mult(work, mx)
        MS[:, j] = mx.getArray(readonly=True)
    C = allreduce(comm, S.T @ MS)
    C = 0.5 * (C + C.T)
    lam, U = np.linalg.eigh(C)
    order = np.argsort(lam)[::-1]
    lam, U = lam[order], U[:, order]
    if lam[0] <= 0.0:
        raise BasisError("the snapshots are all zero (on the free rows): nothing to reduce")
    usable = int(np.count_nonzero(lam > ROUND_OFF * lam[0]))
    total = float(lam[lam > 0].sum())
    held = np.cumsum(lam[:usable]) / total
    r = min(usable, int(np.searchsorted(held, energy * (1.0 - 1e-15)) + 1))
    if max_size is not None:
        r = min(r, int(max_size))
    V = S @ (U[:, :r] / np.sqrt(lam[:r]))
    # one M-Gram-Schmidt pass by Cholesky: the small kept eigenvalues leave their vectors
    # M-orthogonal only to ~eps/l; the reduced mass V^T M V is then I to round-off
    MV = np.empty_like(V)
    for j in range(r):
        work.getArray()[:] = V[:, j]
        system.M.mult(work, mx)
        MV[:, j] = mx.getArray(readonly=True)
    G = allreduce(comm, V.T @ MV)
    L = np.linalg.cholesky(0.5 * (G + G.T))
    V = np.linalg.solve(L, V.T).T
    local = np.empty((3 * dm.nvertices, r))
    for j in range(r):
        work.getArray()[:] = V[:, j]
        local[:, j] = dm.to_local(work).ravel()
    work.destroy()
    mx.destroy()
    return PODBasis(local=local, nowned=nown, eigenvalues=lam, energy=float(held[r - 1]),
                    comm=comm)


def coordinates_of(system, basis: PODBasis, x: PETSc.Vec, ref: PETSc.Vec | None = None
                   ) -> np.ndarray:
    """V^T M (x - ref): the coordinates of the M-orthogonal projection of x - ref on the basis,
    with the mass the basis was built with (V^T M V = I; after a density change use
    :meth:`petsoft.reduced.galerkin.ReducedModel.coordinates`). Collective."""
    d = x.copy()
    if ref is not None:
        d.axpy(-1.0, ref)
    md = d.duplicate()
    system.M.mult(d, md)
    out = basis.project(md)
    d.destroy()
    md.destroy()
    return out
