"""Dirichlet conditions: which dofs are prescribed and their values.

Prescribed dofs stay in the system: their residual rows are zero and their Jacobian rows and
columns are replaced by the identity (symmetric elimination, so CG still applies), while their
values are set in the solution vector before a solve. Changing prescribed values between solves
is handled by a lifting step in the solver (see :mod:`petsoft.solvers.static`).
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from petsoft.errors import PetsoftError

ZERO = None  # marker: a fixed (zero) condition


class DirichletConditions:
    """All Dirichlet conditions of a problem on the local dofs of a distributed mesh.

    Parameters
    ----------
    dmesh : DistributedMesh
    conditions : list of (vertex_mask (N,) bool, components tuple[int], displacement or None)
        ``displacement`` is None for a fixed condition, or three Expressions of x, y, z, t.
        Later conditions win where they overlap.
    """

    def __init__(self, dmesh, conditions):
        self.dmesh = dmesh
        nv = dmesh.nvertices
        owner = np.full((nv, 3), -1, dtype=np.int64)      # index of the condition setting a dof
        self.conditions = list(conditions)
        for k, (mask, components, _) in enumerate(self.conditions):
            sel = np.asarray(mask)[dmesh.vertex_ids]
            for c in components:
                owner[sel, c] = k
        self.owner = owner
        self.local_dofs = np.flatnonzero(owner.ravel() >= 0)
        owned_dof = np.repeat(dmesh.owned, 3)[self.local_dofs]
        owned_rows = dmesh.global_dof.ravel()[self.local_dofs[owned_dof]]
        self.global_rows = owned_rows.astype(PETSc.IntType)
        self.count = dmesh.comm.tompi4py().allreduce(len(self.global_rows))
        #: whether some prescribed displacement depends on time (else :meth:`values` computes
        #: them once: a step asks twice, and each evaluation cost ~0.1 ms at 600 dofs)
        self.time_dependent = any(
            disp is not None and any("t" in e.variables for e in disp)
            for _, _, disp in self.conditions)
        self._constant_values = None
        # positions of the owned prescribed dofs in the owned local arrays
        self._owned_local = self.local_dofs[owned_dof]
        self._offsets = (None, None)

    def values(self, t: float = 0.0, scale: float = 1.0) -> np.ndarray:
        """Local (nv, 3) array: prescribed values at prescribed dofs, 0 elsewhere.

        Collective: an error evaluating a condition on some rank (a time outside a recorded
        input, an expression going non-finite) is raised on every rank, not left to deadlock
        the ranks that had nothing to evaluate.
        """
        if self._constant_values is not None:
            return scale * self._constant_values
        out = np.zeros((self.dmesh.nvertices, 3))
        error = None
        try:
            for k, (_, components, displacement) in enumerate(self.conditions):
                if displacement is None:
                    continue
                for c in components:
                    rows = np.flatnonzero(self.owner[:, c] == k)
                    # evaluated even with no local rows, so every rank checks t the same way
                    out[rows, c] = displacement[c].evaluate_at(self.dmesh.points[rows], t=t)
        except PetsoftError as exc:
            error = exc
        mpi = self.dmesh.comm.tompi4py()
        if mpi.size == 1:
            if error is not None:
                raise error
        else:
            messages = [m for m in mpi.allgather(
                None if error is None else (type(error), str(error))) if m is not None]
            if messages:
                if error is not None:
                    raise error
                kind, text = messages[0]
                raise kind(text)
        if not self.time_dependent:
            self._constant_values = out
        return scale * out

    def owned_offsets(self, vec: PETSc.Vec) -> np.ndarray:
        """Positions of the owned prescribed dofs in ``vec``'s local array."""
        start = vec.getOwnershipRange()[0]
        if self._offsets[0] != start:
            offsets = self.global_rows - start
            offsets.flags.writeable = False     # shared by every caller
            self._offsets = (start, offsets)
        return self._offsets[1]

    def zero_rows(self, vec: PETSc.Vec) -> None:
        """Set the prescribed entries of a global vector to zero (residuals, gradients)."""
        vec.getArray()[self.owned_offsets(vec)] = 0.0

    def set_values(self, vec: PETSc.Vec, local_values: np.ndarray) -> None:
        """Set the prescribed entries of a global vector from a local (nv, 3) value array."""
        arr = vec.getArray()
        arr[self.owned_offsets(vec)] = np.asarray(local_values).ravel()[self._owned_local]

    def eliminate(self, A: PETSc.Mat, diagonal: float = 1.0) -> None:
        """Symmetric elimination: prescribed rows and columns become identity rows/columns."""
        A.zeroRowsColumns(self.global_rows, diag=diagonal)
