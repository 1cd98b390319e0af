"""Observing a simulated body through the markers of a recording.

Each marker is embedded in the reference geometry once: in a continuum (FEM) model by the
barycentric weights of the tetrahedron containing its reference position, in a mass-spring model
by the node it sits on. The observation is then linear in the displacement,
``x_m(t) = X_m + (B q(t))_m``, with B a sparse (3M x ndof) PETSc matrix distributed like any
other: ``observe`` gives every rank the same (M, 3) positions, ``adjoint`` maps per-marker
weights (a misfit gradient) back to a global dof vector, B^T w.

A marker that was not seen in a frame (NaN in the recording) is left out of the misfit
(:func:`frame_residual`), never treated as a zero position.
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from petsoft.errors import PetsoftError
from petsoft.mesh.quadratic import shape_values
from petsoft.mesh.topology import exterior_faces


class ObservationError(PetsoftError):
    """Markers cannot be embedded in the model (outside the mesh, off the nodes) or frames lie
    outside the simulated time span."""


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    s = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[:, None] * ab), axis=1)


def distance_to_surface(point: np.ndarray, points: np.ndarray, faces: np.ndarray) -> float:
    """Exact Euclidean distance from ``point`` to a triangulated surface (vectorised over faces).

    The minimum over faces of: the distance to the face's plane when the projection falls inside
    the triangle, else the distance to its nearest edge.
    """
    a, b, c = (points[faces[:, i]] for i in range(3))
    p = np.broadcast_to(np.asarray(point, dtype=float), a.shape)
    n = np.cross(b - a, c - a)
    n2 = np.einsum("ij,ij->i", n, n)
    ok = n2 > 0
    d_plane = np.full(len(a), np.inf)
    # projection inside the triangle: the three sub-triangle normals agree with n
    h = np.einsum("ij,ij->i", p - a, n) / np.where(ok, n2, 1.0)
    proj = p - h[:, None] * n
    inside = ok.copy()
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(v - u, proj - u), n) >= 0
    d_plane[inside] = np.abs(h[inside]) * np.sqrt(n2[inside])
    d_edges = np.minimum.reduce([_segment_distance(p, a, b), _segment_distance(p, b, c),
                                 _segment_distance(p, c, a)])
    return float(np.minimum(d_plane, d_edges).min())


def _locate_in_tets(points, tets, reference, names, source, tol=1e-9):
    """Containing cell and barycentric weights of each marker; error naming the first outside."""
    X = points[tets]
    inv = np.linalg.inv(np.transpose(X[:, 1:] - X[:, :1], (0, 2, 1)))
    cells = np.empty(len(reference), dtype=np.int64)
    weights = np.empty((len(reference), 4))
    for i, p in enumerate(reference):  # few markers; each is vectorised over all cells
        lam = np.einsum("eij,ej->ei", inv, p[None, :] - X[:, 0])
        bary = np.concatenate([1.0 - lam.sum(axis=1, keepdims=True), lam], axis=1)
        worst = bary.min(axis=1)
        best = int(np.argmax(worst))
        if worst[best] < -tol:
            faces, _ = exterior_faces(tets)
            dist = distance_to_surface(p, points, faces)
            size = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
            hint = (" (far compared with the body's size: are the recording's units the mesh's, "
                    "metres after [mesh] scale?)" if dist > 0.5 * size else "")
            raise ObservationError(
                f"{source}: marker {names[i]!r} (index {i}) at {p.tolist()} lies outside the "
                f"mesh, {dist:.4g} m from its surface{hint}; markers must be reference-"
                f"configuration points inside or on the body (mesh size {size:.4g} m)")
        cells[i], weights[i] = best, bary[best]
    return cells, weights


def locate_in_tets(points, tets, reference, names, source, tol=1e-9):
    """Containing cell (M,) and barycentric weights (M, 4) of each marker in a tet mesh.

    Raises
    ------
    ObservationError
        A marker lies outside the mesh (named, with its distance to the surface).
    """
    return _locate_in_tets(points, tets, reference, names, source, tol)


class MarkerObserver:
    """The linear observation operator of a recording's markers on a system.

    Parameters
    ----------
    system : DynamicSystem or mass-spring system
        A continuum system (``system.dmesh``: a :class:`~petsoft.mesh.distributed.DistributedMesh`)
        or a mass-spring system exposing ``vertex_points`` (N, 3) and
        ``vertex_global_dofs(ids) -> (len(ids), 3)``, and ``create_vec()``.
    reference : (M, 3) array
        Marker reference positions (same frame and units as the mesh).
    names : list of str, optional
        Marker names for messages (default ``m0, m1, ...``).
    source : str
        Where the markers come from (the recording's path), for messages.
    node_tolerance : float, optional
        Mass-spring models: how far (m) a marker may lie from its node; default 1e-6 times the
        model's size.

    All ranks construct it (collective); errors are raised on every rank.
    """

    def __init__(self, system, reference, names=None, source: str = "recording",
                 node_tolerance: float | None = None):
        self.reference = np.asarray(reference, dtype=float).reshape(-1, 3)
        M = self.num_markers = len(self.reference)
        self.names = list(names) if names is not None else [f"m{i}" for i in range(M)]
        self.source = source
        self.comm = system.comm if hasattr(system, "comm") else PETSc.COMM_WORLD
        mpi = self.comm.tompi4py()
        self._template = system.create_vec()
        # a mass-spring system also has a ``dmesh`` (its node layout, without tets): test for
        # its nodes first
        if hasattr(system, "vertex_points"):
            rows, cols, vals = self._node_entries(system, node_tolerance)
            self.kind = "nodes"
        elif hasattr(system, "dmesh"):
            rows, cols, vals = self._fem_entries(system.dmesh)
            self.kind = "fem"
        else:
            raise TypeError(f"cannot observe markers on {type(system).__name__}: it has neither "
                            "a dmesh nor vertex_points")
        # every rank knows a few entries; all ranks learn all of them (3M x <=4 entries: small)
        parts = mpi.allgather((rows, cols, vals))
        rows = np.concatenate([p[0] for p in parts]).astype(np.int64)
        cols = np.concatenate([p[1] for p in parts]).astype(np.int64)
        vals = np.concatenate([p[2] for p in parts])
        _, first = np.unique(rows * (self._template.getSize() + 1) + cols, return_index=True)
        rows, cols, vals = rows[first], cols[first], vals[first]   # a node seen by two ranks
        self.B = PETSc.Mat().create(comm=self.comm)
        self.B.setSizes(((PETSc.DECIDE, 3 * M), self._template.getSizes()))
        self.B.setType(PETSc.Mat.Type.AIJ)
        self.B.setUp()
        lo, hi = self.B.getOwnershipRange()
        mine = (rows >= lo) & (rows < hi)
        r, c, v = rows[mine], cols[mine], vals[mine]
        order = np.lexsort((c, r))
        r, c, v = r[order], c[order], v[order]
        indptr = np.zeros(hi - lo + 1, dtype=PETSc.IntType)
        np.add.at(indptr, r - lo + 1, 1)
        indptr = np.cumsum(indptr).astype(PETSc.IntType)
        self.B.setPreallocationCSR((indptr, c.astype(PETSc.IntType), v))
        self.B.assemble()
        self._y = self.B.createVecLeft()
        self._scatter, self._all = PETSc.Scatter.toAll(self._y)

    @classmethod
    def from_recording(cls, system, recording, **kw) -> MarkerObserver:
        """The observer of a :class:`~petsoft.io.recording.Recording`'s markers."""
        return cls(system, recording.reference, recording.names, source=recording.source, **kw)

    # -- embedding -----------------------------------------------------------------------------
    def _fem_entries(self, dm):
        mesh = dm.mesh
        cells, weights = _locate_in_tets(mesh.points, mesh.tets, self.reference, self.names,
                                         self.source)
        # the element's own interpolation: barycentric for 4 nodes, quadratic for 10 (a
        # curved 10-node element is located by its corners' straight tetrahedron)
        weights = shape_values(mesh.order, weights)
        self.cells, self.weights = cells, weights
        file_vertices = mesh.cells[cells]                          # (M, 4 or 10)
        local = dm.file_to_local[file_vertices]
        ok = local >= 0
        ok[ok] &= dm.owned[local[ok]]
        m, a = np.nonzero(ok)
        dofs = dm.global_dof[local[m, a]]                          # (n, 3)
        rows = (3 * m[:, None] + np.arange(3)).ravel()
        cols = dofs.ravel()
        vals = np.repeat(weights[m, a], 3)
        return rows, cols, vals

    def _node_entries(self, system, tol):
        pts = np.asarray(system.vertex_points, dtype=float)
        size = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) if len(pts) > 1 else 1.0
        tol = 1e-6 * max(size, 1e-3) if tol is None else float(tol)
        d = np.linalg.norm(self.reference[:, None, :] - pts[None], axis=2)   # (M, N)
        nearest = d.argmin(axis=1)
        dist = d[np.arange(self.num_markers), nearest]
        far = np.flatnonzero(dist > tol)
        if len(far):
            i = int(far[0])
            raise ObservationError(
                f"{self.source}: marker {self.names[i]!r} (index {i}) at "
                f"{self.reference[i].tolist()} is {dist[i]:.4g} m from the nearest node "
                f"({int(nearest[i])} at {pts[nearest[i]].tolist()}); in a mass-spring model "
                f"markers must sit on nodes (within {tol:.3g} m)")
        self.nodes = nearest
        dofs = np.asarray(system.vertex_global_dofs(nearest), dtype=np.int64).reshape(-1, 3)
        m = np.repeat(np.arange(self.num_markers), 3)
        rows = 3 * m + np.tile(np.arange(3), self.num_markers)
        cols = dofs.ravel()
        keep = cols >= 0            # a system may report -1 for vertices it does not hold
        return rows[keep], cols[keep], np.ones(int(keep.sum()))

    # -- the operator ----------------------------------------------------------------------------
    def observe(self, q: PETSc.Vec) -> np.ndarray:
        """Marker positions X + B q as an (M, 3) array, identical on every rank (collective)."""
        self.B.mult(q, self._y)
        self._scatter.scatter(self._y, self._all, addv=PETSc.InsertMode.INSERT_VALUES,
                              mode=PETSc.ScatterMode.FORWARD)
        return self.reference + self._all.getArray(readonly=True).reshape(-1, 3)

    def adjoint(self, weights: np.ndarray, out: PETSc.Vec | None = None) -> PETSc.Vec:
        """B^T w as a global dof vector, for (M, 3) weights given identically on every rank.

        NaN weights (markers not seen) must have been replaced by zeros by the caller
        (:func:`frame_residual` does); they are refused here so they cannot poison a gradient.
        """
        w = np.asarray(weights, dtype=float).reshape(-1)
        if w.size != 3 * self.num_markers:
            raise ValueError(f"weights of size {w.size} for {self.num_markers} markers")
        if not np.isfinite(w).all():
            raise ValueError("adjoint weights must be finite (zero the markers not seen)")
        lo, hi = self._y.getOwnershipRange()
        self._y.getArray()[:] = w[lo:hi]
        out = out if out is not None else self._template.duplicate()
        self.B.multTranspose(self._y, out)
        return out

    def destroy(self) -> None:
        for obj in (self.B, self._y, self._scatter, self._all, self._template):
            obj.destroy()


def frame_residual(predicted: np.ndarray, measured: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted minus measured positions of one frame, zero where a marker was not seen.

    Returns
    -------
    residual : (M, 3) array
        Zero rows for markers not seen (NaN in ``measured``): they are left out of the misfit.
    seen : (M,) bool
    """
    measured = np.asarray(measured, dtype=float)
    seen = np.isfinite(measured).all(axis=1)
    r = np.zeros_like(measured)
    r[seen] = np.asarray(predicted)[seen] - measured[seen]
    return r, seen


def time_interpolation(frame_times, step_times, *, source: str = "recording"
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of frames between simulated steps.

    Parameters
    ----------
    frame_times : (K,) array
        Times of the recorded frames.
    step_times : (S,) array, S >= 1
        Strictly increasing times of the simulated states.

    Returns
    -------
    indices : (K, 2) int array
        The two steps bracketing each frame (equal when S == 1).
    weights : (K, 2) array
        Their weights (sum 1), so frame value = w0 * state[i0] + w1 * state[i1].

    Raises
    ------
    ObservationError
        Naming the first frame outside the simulated span (beyond a round-off tolerance).
    """
    ft = np.asarray(frame_times, dtype=float)
    st = np.asarray(step_times, dtype=float)
    span = st[-1] - st[0]
    tol = 1e-9 * max(span, 1e-300) if span > 0 else 1e-12
    out = np.flatnonzero((ft < st[0] - tol) | (ft > st[-1] + tol))
    if len(out):
        k = int(out[0])
        raise ObservationError(
            f"{source}: frame {k} at t = {ft[k]:.9g} s lies outside the simulated span "
            f"[{st[0]:.9g}, {st[-1]:.9g}] s ({len(out)} frame(s) outside); simulate longer or "
            "cut the recording")
    if len(st) == 1:
        return np.zeros((len(ft), 2), dtype=np.int64), np.column_stack([np.ones(len(ft)),
                                                                         np.zeros(len(ft))])
    i = np.clip(np.searchsorted(st, ft, side="right") - 1, 0, len(st) - 2)
    s = np.clip((ft - st[i]) / (st[i + 1] - st[i]), 0.0, 1.0)
    return np.column_stack([i, i + 1]), np.column_stack([1.0 - s, s])

