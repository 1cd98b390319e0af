"""Elastic supports: a fixed boundary with a compliance, as penalty springs on its nodes.

A ``[[boundary]] kind = "fixed"`` with ``compliance`` c > 0 (m/Pa) is not a Dirichlet condition:
each constrained component of each of its nodes is tied to its prescribed position g = 0 by a
spring of stiffness

    k_i = A_i / c,   A_i = sum over the boundary faces inside ``where`` touching node i of A_f / 3

(the lumped area), i.e. a distributed Winkler foundation whose traction is -(u - g) / c: a
traction t on the support face displaces it by c t. Its energy is

    E(u) = 1/2 sum_i k_i |u_i - g_i|^2    (constrained components only)

with gradient k_i (u_i - g_i) and a constant, diagonal, positive semi-definite Hessian: it is added
to both the tangent K(q) and the reference stiffness K0 (so stiffness-proportional damping also
acts on it). Its derivative with respect to the compliance is d grad E / dc = -(k_i / c)(u_i - g_i).

Rules: a node inside ``where`` but on no selected boundary face gets no spring (A_i = 0); a
component that is also a Dirichlet row (another, rigid condition on the same node) stays a
Dirichlet row and carries no spring; several elastic supports on one node add their springs.
Every term lives on the owned vertices only, so sums over ranks count each node once.
"""

from __future__ import annotations

import numpy as np

from petsoft.errors import ExperimentError
from petsoft.fem.element import face_lumped_areas
from petsoft.mesh.quadratic import face_nodes

#: The experiment's name of the supports' shared compliance (see :func:`shared_compliance`).
COMPLIANCE = "boundary.compliance"


def lumped_face_areas(mesh, faces: np.ndarray) -> np.ndarray:
    """(N,) per node: the lumped areas of the faces (F, 3) touching it (A_f / 3 per vertex for
    4-node tetrahedra; :func:`petsoft.fem.element.face_lumped_areas` for 10-node ones)."""
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) == 0:
        return np.zeros(len(mesh.points))
    nodes = face_nodes(mesh, faces)
    share = face_lumped_areas(mesh.order, mesh.points, nodes)
    return np.bincount(nodes.ravel(), weights=share.ravel(), minlength=len(mesh.points))


class ElasticSupport:
    """Penalty springs of the elastic (compliant) supports on this rank's owned vertices.

    A :class:`~petsoft.physics.term.NodalTerm` (part of the reference stiffness K0) and a
    :class:`~petsoft.physics.term.ParametricTerm` (``boundary.compliance``).

    Parameters
    ----------
    dmesh : DistributedMesh
    areas : ndarray (nv, 3)
        Lumped area (m^2) on each local vertex's constrained components (0 elsewhere and on ghost
        vertices).
    compliance : float
        c > 0 (m/Pa), shared by the supports (see :func:`build_support`).
    """

    kind = "support"
    in_reference = True

    def __init__(self, dmesh, areas: np.ndarray, compliance: float):
        self.dmesh = dmesh
        self.nodes = np.flatnonzero(np.any(areas > 0.0, axis=1))     # local vertex indices
        self.areas = np.ascontiguousarray(areas[self.nodes])          # (n, 3)
        self.compliance = float(compliance)

    @property
    def stiffness(self) -> np.ndarray:
        """(n, 3) spring stiffness k = A / c of each node's components (N/m)."""
        return self.areas / self.compliance

    def set_compliance(self, compliance: float) -> None:
        self.compliance = float(compliance)

    def energy(self, u_local: np.ndarray) -> float:
        """This rank's share of 1/2 sum k |u|^2."""
        u = u_local[self.nodes]
        return 0.5 * float(np.sum(self.stiffness * u * u))

    def gradient(self, u_local: np.ndarray) -> np.ndarray:
        """(n, 3) k u at the support nodes."""
        return self.stiffness * u_local[self.nodes]

    def hessian(self, u_local: np.ndarray | None = None) -> np.ndarray:
        """(n, 3, 3) diagonal blocks diag(k) (constant: ``u_local`` is not needed)."""
        k = self.stiffness
        H = np.zeros((len(k), 3, 3))
        H[:, [0, 1, 2], [0, 1, 2]] = k
        return H

    def compliance_derivative(self, y_local: np.ndarray) -> np.ndarray:
        """(n, 3) d(K_s y)/dc = -(A / c^2) y at the support nodes (y = u, or u + w + beta v)."""
        return -(self.areas / self.compliance ** 2) * y_local[self.nodes]

    # -- the ParametricTerm interface ----------------------------------------------------------
    def parameters(self) -> dict[str, float]:
        return {COMPLIANCE: self.compliance}

    def set_parameter(self, name: str, value: float) -> None:
        if name != COMPLIANCE:
            raise KeyError(name)
        self.set_compliance(value)

    def add_parameter_derivative(self, name: str, u_local: np.ndarray,
                                 out: np.ndarray) -> None:
        """Add d(k u)/dc at ``u_local`` (linear in u: pass u + w + beta v for that state)."""
        if name != COMPLIANCE:
            raise KeyError(name)
        out[self.nodes] += self.compliance_derivative(u_local)


def build_support(experiment, dmesh, resolver, dirichlet) -> ElasticSupport | None:
    """The elastic supports of an experiment (None when every fixed boundary is rigid).

    Called on every rank with the same (replicated) mesh, so errors are raised everywhere.
    ``dirichlet`` (the model's rigid conditions) wins where it overlaps a support.
    """
    compliant = [(i, b) for i, b in enumerate(experiment.boundaries)
                 if b.kind == "fixed" and b.compliance > 0.0]
    if not compliant:
        return None
    mesh = dmesh.mesh
    areas_file = np.zeros((len(mesh.points), 3))
    for i, b in compliant:
        key = f"boundary[{i}].where"
        faces = resolver.faces(b.where, key)
        lumped = lumped_face_areas(mesh, faces)
        if not lumped.any():
            raise ExperimentError(
                f"{experiment.source}: {key}: the elastic support (compliance = {b.compliance:g} "
                "m/Pa) selects no boundary face (a face belongs when all its vertices do): its "
                "springs need a surface area; select a face set, or use compliance = 0 (rigid)")
        # with several supports of different compliance, store A c_ref / c_b (see compliance)
        scale = compliant[0][1].compliance / b.compliance
        for c in b.component_indices:
            areas_file[:, c] += scale * lumped
    areas = areas_file[dmesh.vertex_ids]
    areas[~dmesh.owned] = 0.0
    areas[dirichlet.owner >= 0] = 0.0        # a rigid condition on the same dof wins
    return ElasticSupport(dmesh, areas, compliant[0][1].compliance)


def shared_compliance(experiment) -> float | None:
    """The compliance every elastic support shares, None without one; raises if they differ
    (``boundary.compliance`` is one parameter)."""
    values = {b.compliance for b in experiment.boundaries if b.kind == "fixed"
              and b.compliance > 0.0}
    if not values:
        return None
    if len(values) > 1:
        raise ExperimentError(
            f"{experiment.source}: boundary.compliance is one parameter shared by every elastic "
            f"support, but the fixed boundaries have different compliances {sorted(values)}; "
            "give them the same compliance to calibrate or differentiate it")
    return values.pop()
