"""Rigid colliders acting on a continuum (FEM) body: penalty contact on its boundary-surface nodes.

The ``[[collider]]`` tables of a ``[material]`` experiment act on the vertices of the mesh's
exterior faces, each with the nodal penalty of :mod:`petsoft.physics.colliders` (energy
k/2 p^2 per node, p the penetration; force, Hessian): the same kernels as for mass-spring models,
summed over the surface nodes and colliders. The penalty is a potential: its energy is part of the
model's elastic (stored) energy, its gradient of the internal forces, its Hessian of the tangent
K(q) -- but not of the reference stiffness K0 (it is not a property of the undeformed body).

Stiffness per node when ``[[collider]] stiffness`` is not given (:func:`default_fem_stiffness`):

* with ``[time]``: the springs' rule k = 4 m_max / h^2, m_max the largest lumped (row-sum) mass of
  a surface node, h the step: a node's contact frequency sqrt(k/m) <= 2/h is resolved by one step,
  a node hitting at speed v penetrates at most about v sqrt(m/k) >= v h/2, and under its own weight
  (m g) a node sinks m g / k <= g h^2 / 4. With ``integrator = "explicit"`` that rule puts the
  lighter nodes beyond the stability limit h omega < 2 (measured: a dropped bar gained 4x the
  released energy), so there k = m_min / h^2 (the lightest surface node: h omega <= 1). The rule
  follows ``[time] integrator``; a ``--integrator`` given on the command line does not change k;
* without ``[time]`` (``static``, ``modes``): k = 1000 E_max L, E_max the largest Young's modulus
  and L the mean edge length of the exterior faces (E L is the order of a surface node's elastic
  stiffness, so the penetration is ~1e-3 of the body's own deformation near the contact).

The plane's ``offset`` s moves it along its normal n (surface point + s n); ``collider.<i>.offset``
is a differentiable parameter: with phi = (x - point) . n - s, d(grad E)/ds = -e''(phi) n per node
(e'' = k in contact, 0 outside). Coulomb friction on a continuum is not implemented: a collider
with ``friction`` > 0 is refused for ``[material]`` models.

A body resting on a plane with nothing else supporting it (static): its tangent is singular in z
until the contact is active, so start it in (slight) contact, e.g. ``offset`` = 1e-9 m.
"""

from __future__ import annotations

import numpy as np

from petsoft.errors import ExperimentError
from petsoft.fem.element import integrals_of
from petsoft.mesh.quadratic import face_nodes
from petsoft.mesh.topology import exterior_faces
from petsoft.physics.colliders import DEFAULT_STEP_FACTOR, Collider
from petsoft.physics.materials import cell_materials

#: Without a time step: k = this x E_max x mean exterior edge length.
DEFAULT_STATIC_FACTOR = 1000.0
#: ``integrator = "explicit"``: k = this x m_min / h^2 (every node's contact frequency <= 1/h).
EXPLICIT_STEP_FACTOR = 1.0


def surface_vertices(tets: np.ndarray, exterior_faces: np.ndarray, nvertices: int) -> np.ndarray:
    """(N,) bool: the vertices of the exterior faces (file numbering)."""
    mask = np.zeros(nvertices, dtype=bool)
    mask[np.asarray(exterior_faces, dtype=np.int64).ravel()] = True
    return mask


def default_fem_stiffness(mesh, density: np.ndarray, youngs: np.ndarray, surface: np.ndarray,
                          step: float | None, explicit: bool = False) -> float:
    """The penalty stiffness per node of a collider without ``stiffness`` (module docstring).

    ``density`` and ``youngs`` are per cell of the whole mesh (file numbering): the value is the
    same on every rank. ``explicit``: the rule for the explicit integrator (lightest node).
    """
    share = integrals_of(mesh.points[mesh.cells], mesh.order).lumped       # (E, k)
    lumped = np.bincount(mesh.cells.ravel(), weights=(density[:, None] * share).ravel(),
                         minlength=len(mesh.points))
    m_max = float(lumped[surface].max())
    if step is not None and m_max > 0.0:
        if explicit:
            return EXPLICIT_STEP_FACTOR * float(lumped[surface].min()) / step ** 2
        return DEFAULT_STEP_FACTOR * m_max / step ** 2
    p = mesh.points[exterior_faces(mesh.tets)[0]]
    edges = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2)
    return DEFAULT_STATIC_FACTOR * float(np.max(youngs)) * float(edges.mean())


class SurfaceContact:
    """Penalty contact of rigid colliders with this rank's owned surface vertices.

    A :class:`~petsoft.physics.term.NodalTerm` (not part of K0) and a
    :class:`~petsoft.physics.term.ParametricTerm` (the planes' ``collider.<i>.offset``).

    Parameters
    ----------
    dmesh : DistributedMesh
    nodes : ndarray (n,)
        Local indices of the owned surface vertices.
    colliders : list of Collider
        Their geometry as built (a plane's ``point`` already includes its offset).
    offsets : list of float
        The offset of each collider (0 for spheres).
    """

    kind = "contact"
    in_reference = False     # a state-dependent constraint, not a property of the undeformed body

    def __init__(self, dmesh, nodes: np.ndarray, colliders: list[Collider], offsets):
        self.dmesh = dmesh
        self.nodes = np.asarray(nodes, dtype=np.int64)
        self.X = dmesh.points[self.nodes]
        self.colliders = colliders
        self.offsets = [float(s) for s in offsets]
        # the offset-free point: moving the plane recomputes point = base + s n
        self.base = [None if c.kind != "plane" else c.point - s * c.normal
                     for c, s in zip(colliders, self.offsets, strict=True)]

    def set_offset(self, index: int, offset: float) -> None:
        c = self.colliders[index]
        self.offsets[index] = float(offset)
        c.point = self.base[index] + float(offset) * c.normal

    def positions(self, u_local: np.ndarray) -> np.ndarray:
        return self.X + u_local[self.nodes]

    def energy(self, u_local: np.ndarray) -> float:
        """This rank's share of the penalty energy."""
        x = self.positions(u_local)
        return float(sum(c.energy(x).sum() for c in self.colliders))

    def gradient(self, u_local: np.ndarray) -> np.ndarray:
        """(n, 3) gradient of the penalty energy (minus the contact forces) at the nodes."""
        x = self.positions(u_local)
        return sum(c.gradient(x) for c in self.colliders)

    def hessian(self, u_local: np.ndarray) -> np.ndarray:
        """(n, 3, 3) exact Hessian blocks (a sphere's curvature term included)."""
        x = self.positions(u_local)
        return sum(c.hessian(x) for c in self.colliders)

    def forces(self, u_local: np.ndarray) -> np.ndarray:
        """(n, 3) contact forces on the nodes (= -gradient)."""
        return -self.gradient(u_local)

    def penetration(self, u_local: np.ndarray) -> np.ndarray:
        """(n,) the largest penetration max(0, -phi) of each node over the colliders."""
        x = self.positions(u_local)
        depth = [np.maximum(-c.distance(x)[0], 0.0) for c in self.colliders]
        return np.max(depth, axis=0) if len(x) else np.zeros(0)

    def offset_derivative(self, index: int, u_local: np.ndarray) -> np.ndarray:
        """(n, 3) d(gradient)/d offset of collider ``index`` (a plane): -e''(phi) n."""
        c = self.colliders[index]
        x = self.positions(u_local)
        phi, n, _ = c.distance(x)
        return -c._profile(phi)[2][:, None] * n

    # -- the ParametricTerm interface ----------------------------------------------------------
    def _plane_index(self, name: str) -> int:
        parts = name.split(".")
        if (len(parts) != 3 or parts[0] != "collider" or parts[2] != "offset"
                or not parts[1].isdigit() or int(parts[1]) >= len(self.colliders)
                or self.colliders[int(parts[1])].kind != "plane"):
            raise KeyError(name)
        return int(parts[1])

    def parameters(self) -> dict[str, float]:
        return {f"collider.{i}.offset": self.offsets[i]
                for i, c in enumerate(self.colliders) if c.kind == "plane"}

    def set_parameter(self, name: str, value: float) -> None:
        self.set_offset(self._plane_index(name), value)

    def add_parameter_derivative(self, name: str, u_local: np.ndarray,
                                 out: np.ndarray) -> None:
        out[self.nodes] += self.offset_derivative(self._plane_index(name), u_local)


def build_contact(experiment, dmesh, resolver, dirichlet):
    """The contact of the experiment's colliders with the body (None without colliders):
    ``contact.plane``'s builder (petsoft.terms; the call of a nodal term's builder, whose
    ``dirichlet`` it does not need).

    Called on every rank (replicated mesh): errors are raised everywhere.
    """
    if not experiment.colliders:
        return None
    _, youngs_file, _, density_file = cell_materials(experiment, resolver)
    for i, spec in enumerate(experiment.colliders):
        if spec.friction > 0.0:
            raise ExperimentError(
                f"{experiment.source}: collider[{i}].friction = {spec.friction:g}: Coulomb "
                "friction is implemented for [springs] models only; on a [material] (FEM) body "
                "a collider is frictionless: remove friction or set it to 0")
    mesh = dmesh.mesh
    # the nodes of the exterior faces: edge nodes too for 10-node tetrahedra
    surface = surface_vertices(mesh.tets, face_nodes(mesh, dmesh.exterior[0]), len(mesh.points))
    default_k = None
    if any(spec.stiffness is None for spec in experiment.colliders):
        step = experiment.time.step if experiment.time is not None else None
        explicit = experiment.time is not None and experiment.time.integrator == "explicit"
        default_k = default_fem_stiffness(mesh, density_file, youngs_file, surface, step,
                                          explicit)
    colliders = [Collider.from_spec(spec, default_k) for spec in experiment.colliders]
    local = np.flatnonzero(surface[dmesh.vertex_ids] & dmesh.owned)
    return SurfaceContact(dmesh, local, colliders,
                          [spec.offset if spec.kind == "plane" else 0.0
                           for spec in experiment.colliders])
