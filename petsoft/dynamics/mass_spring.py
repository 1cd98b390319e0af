"""Mass-spring models: building them from an experiment, and their dynamic system.

:class:`MassSpringSystem` has the interface of :class:`petsoft.dynamics.system.DynamicSystem`, so
every integrator (be, si, midpoint, trapezoidal, alpha, explicit, ere) runs on it unchanged:

    M q'' = -grad W(q) - D v + f_g,   W = springs + collider penalties,
    D = alpha M + beta K_ref + D_dashpots (constant, PSD)

* M is diagonal: ``[springs] node_mass`` at every node plus the ``[[mass]]`` point masses (each must
  sit on a node).
* W: springs k/2 (|x_i - x_j| - L)^2 (:mod:`petsoft.physics.springs`), exact or clamped (PSD)
  Hessian (``clamp``, the ``--spd`` idea of the FEM materials), and the penalty energies of the
  colliders (:mod:`petsoft.physics.colliders`), booked as elastic energy.
* D: Rayleigh damping (``[damping] mass`` alpha, ``stiffness`` beta with K_ref the spring
  stiffness at rest) plus the spring dashpots ``[springs] damping`` along the rest directions
  (:func:`petsoft.physics.springs.dashpot_blocks` says why constant), plus lagged Coulomb friction
  of the colliders (a velocity-dependent force applied by :meth:`damping_apply`), plus ``[drag]``
  on the triangles (both sides count once; a network without triangles refuses drag) and
  ``[friction]`` on the nodes (:mod:`petsoft.dynamics.velocity`), whose velocity Jacobian the
  integrators add through ``assemble_combination(..., velocity=...)``.

The integrators fold damping into their Jacobians as ``a M + b K(q) + c K0`` with ``c = beta x``
(the velocity coefficient of their scheme). To pass the dashpots through that interface unchanged,
this system reports ``beta = 1`` and ``K0 = beta_user K_ref + D_dashpots``, so that
``alpha M + beta K0`` is exactly its D. The user's beta is :attr:`damping_stiffness`.

Parallel layout: node i has the dofs 3i, 3i+1, 3i+2 (file numbering); PETSc splits the nodes in
contiguous ranges over the ranks. Every rank keeps the replicated node and spring arrays (like
:class:`~petsoft.mesh.distributed.DistributedMesh` keeps the serial mesh), gathers the whole state
vector (one ``VecScatter`` to all) and computes the springs touching its nodes, so forces and the
rows of the matrix it owns need no further communication. The matrix pattern is preallocated once.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.dynamics.initial import initial_from_expressions
from petsoft.dynamics.interfaces import SystemDefaults
from petsoft.dynamics.matrix_free import SpringBlocks
from petsoft.dynamics.rayleigh import RayleighDamping
from petsoft.dynamics.velocity import NAMES as VELOCITY_NAMES
from petsoft.dynamics.velocity import (
    VelocityDamping,
    VelocityTerms,
    coefficients_of,
    settings_of,
    where_of,
)
from petsoft.errors import ExperimentError
from petsoft.experiment.surface import check_surface_terms
from petsoft.fem.regions import RegionResolver
from petsoft.io.recording import read_input_series
from petsoft.mesh.springs import SpringMesh, read_spring_mesh
from petsoft.physics.body_force import BodyForce
from petsoft.physics.colliders import Collider, default_stiffness
from petsoft.physics.drag import face_pairs
from petsoft.physics.model import on_root
from petsoft.physics.springs import (
    KINDS,
    SpringNetwork,
    dashpot_blocks,
    expand_blocks,
    network_from_cells,
    network_from_pairs,
    spring_energy,
    spring_gradient,
    spring_hessian_blocks,
)

#: A ``[[mass]] at`` point closer than this (relative to the mesh's size) to a node sits on it.
NODE_TOLERANCE = 1e-9


class MassSpringWarning(UserWarning):
    """Something in a mass-spring model is suspicious but usable (a node in no spring)."""


# ---------------------------------------------------------------------------------------------
# Node layout over ranks (the "dmesh" of a mass-spring model)


class NodeLayout:
    """Nodes split in contiguous ranges over the ranks, 3 dofs each (block size 3).

    Offers what :class:`~petsoft.dynamics.simulate.Simulation` uses of a
    :class:`~petsoft.mesh.distributed.DistributedMesh`: ``mesh``, ``comm``, ``create_global_vec``,
    ``gather_global``, ``from_file_field``, ``allreduce_sum``.
    """

    def __init__(self, mesh: SpringMesh, comm: PETSc.Comm):
        self.comm, self.mesh = comm, mesh
        self.nglobal_vertices = self.nvertices = n = len(mesh.points)
        v = PETSc.Vec().createMPI((PETSc.DECIDE, 3 * n), bsize=3, comm=comm)
        lo, hi = v.getOwnershipRange()
        self.node_range = (lo // 3, hi // 3)
        self.owned = np.zeros(n, dtype=bool)
        self.owned[lo // 3:hi // 3] = True
        self.scatter, self._all = PETSc.Scatter.toAll(v)
        self._template = v

    def create_global_vec(self) -> PETSc.Vec:
        v = self._template.duplicate()
        v.zeroEntries()
        return v

    def to_all(self, vec: PETSc.Vec) -> np.ndarray:
        """The whole vector on every rank as (N, 3) (collective)."""
        self.scatter.scatter(vec, self._all, addv=PETSc.InsertMode.INSERT_VALUES,
                             mode=PETSc.Scatter.Mode.FORWARD)
        return self._all.getArray(readonly=True).reshape(-1, 3).copy()

    def gather_global(self, vec: PETSc.Vec, root: int = 0) -> np.ndarray | None:
        """(N, 3) on ``root``, None elsewhere (collective)."""
        full = self.to_all(vec)
        return full if self.comm.rank == root else None

    def from_file_field(self, fld: np.ndarray, gvec: PETSc.Vec | None = None) -> PETSc.Vec:
        gvec = gvec if gvec is not None else self.create_global_vec()
        lo, hi = self.node_range
        gvec.getArray()[:] = np.asarray(fld, dtype=float)[lo:hi].ravel()
        return gvec

    def allreduce_sum(self, value: float) -> float:
        return self.comm.tompi4py().allreduce(float(value), op=MPI.SUM)

    def destroy(self) -> None:
        for obj in (self.scatter, self._all, self._template):
            obj.destroy()


# ---------------------------------------------------------------------------------------------
# The model


class NodeConditions:
    """Fixed and prescribed node components of a mass-spring model (``[[boundary]]``).

    Provides what integrators use of :class:`~petsoft.fem.boundary.DirichletConditions`
    (``eliminate``, ``conditions``, ``count``).
    """

    def __init__(self, layout: NodeLayout, conditions):
        self.layout = layout
        n = layout.nvertices
        owner = np.full((n, 3), -1, dtype=np.int64)
        self.conditions = list(conditions)
        for k, (mask, components, _) in enumerate(self.conditions):
            for c in components:
                owner[np.asarray(mask), c] = k
        self.owner = owner
        self.mask = owner >= 0                           # (N, 3) prescribed components
        lo, hi = layout.node_range
        self.owned_dofs = np.flatnonzero(self.mask[lo:hi].ravel())   # offsets in a local array
        self.global_rows = (3 * lo + self.owned_dofs).astype(PETSc.IntType)
        self.count = int(self.mask.sum())

    def values(self, t: float = 0.0) -> np.ndarray:
        """(N, 3) prescribed displacements at t (zero elsewhere); the same on every rank."""
        out = np.zeros(self.mask.shape)
        pts = self.layout.mesh.points
        for k, (_, components, displacement) in enumerate(self.conditions):
            if displacement is None:
                continue
            for c in components:
                rows = np.flatnonzero(self.owner[:, c] == k)
                out[rows, c] = displacement[c].evaluate_at(pts[rows], t=t)
        return out

    def eliminate(self, A: PETSc.Mat, diagonal: float = 1.0) -> None:
        A.zeroRowsColumns(self.global_rows, diag=diagonal)


@dataclass
class MassSpringModel:
    """A mass-spring model built from an experiment (every rank holds all of it).

    Attributes
    ----------
    experiment : Experiment
    dmesh : NodeLayout
    resolver : RegionResolver
    network : SpringNetwork
        ``edges`` (S, 2) and ``kind`` (S,) of the springs (file node numbers).
    rest_lengths : ndarray (S,)
    stiffness : ndarray (S,)
        Per spring: ``[springs] stiffness``, ``bending`` for bending springs.
    damping : ndarray (S,)
        Dashpot coefficient per spring (``[springs] damping``; 0 for bending springs).
    point_masses : ndarray (N,)
        The ``[[mass]]`` masses summed per node.
    node_mass : float
    dirichlet : NodeConditions
    colliders : list of Collider
    """

    experiment: object
    dmesh: NodeLayout
    resolver: object
    network: SpringNetwork
    rest_lengths: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    point_masses: np.ndarray
    node_mass: float
    dirichlet: NodeConditions
    colliders: list

    @property
    def masses(self) -> np.ndarray:
        """(N,) lumped node masses (kg)."""
        return self.node_mass + self.point_masses

    @property
    def edges(self) -> np.ndarray:
        return self.network.edges


def load_spring_mesh(experiment) -> SpringMesh:
    """The experiment's mesh for a mass-spring model (call on rank 0)."""
    spec = experiment.mesh
    if spec.file is None:
        raise ExperimentError(f"{experiment.source}: mesh: a mass-spring model needs a mesh file "
                              "of nodes, lines or triangles ([mesh] file); box meshes are "
                              "tetrahedral")
    return read_spring_mesh(spec.file, scale=spec.scale)


def _listing(ids, limit: int = 5) -> str:
    ids = [int(i) for i in ids]
    text = ", ".join(map(str, ids[:limit]))
    return text + (f" and {len(ids) - limit} more" if len(ids) > limit else "")


def build_mass_spring_model(experiment, comm: PETSc.Comm | None = None, *, mesh=None,
                            recording=None) -> MassSpringModel:
    """Read, validate and lay out a ``[springs]`` experiment (all ranks call).

    Every check runs on every rank on the same replicated data, so an error is raised on all
    ranks alike (no rank is left waiting in a collective call).

    Raises
    ------
    ExperimentError
        Pairs naming missing nodes, springs of zero rest length, ``[[mass]]`` off the nodes, free
        nodes without mass, tractions, fixed nodes inside a collider, a static initial state.
    """
    comm = comm if comm is not None else PETSc.COMM_WORLD
    src = experiment.source
    if mesh is None:
        mesh = on_root(comm, load_spring_mesh, experiment)
    mesh = comm.tompi4py().bcast(mesh, root=0)
    pts = mesh.points
    spec = experiment.springs
    network = _network(spec, mesh, src)
    size = float(np.ptp(pts, axis=0).max()) or 1.0
    rest = _rest_lengths(pts, network.edges, size, spec.pairs is not None, src)
    bending_kind = network.kind == KINDS.index("bending")
    stiffness = np.where(bending_kind, spec.bending or 0.0, spec.stiffness)
    damping = np.where(bending_kind, 0.0, spec.damping)
    point_masses = _point_masses(experiment, pts, size)
    resolver = RegionResolver(mesh, experiment.regions, src)
    conditions = _node_conditions(experiment, resolver, recording)
    check_surface_terms(experiment, mesh)
    if experiment.initial.from_ == "static":
        raise ExperimentError(f"{src}: initial.from = \"static\" is not available for mass-spring "
                              "models; give initial displacement/velocity expressions")

    layout = NodeLayout(mesh, comm)
    dirichlet = NodeConditions(layout, conditions)
    masses = spec.node_mass + point_masses
    free = ~dirichlet.mask.all(axis=1)
    _check_nodes(src, masses, free, network.edges)
    default_k = default_stiffness(masses[free], experiment.time.step if experiment.time else None,
                                  spec.stiffness)
    colliders = [Collider.from_spec(c, default_k) for c in experiment.colliders]
    _check_colliders(src, colliders, pts, dirichlet.mask.any(axis=1))
    return MassSpringModel(experiment, layout, resolver, network, rest, stiffness, damping,
                           point_masses, float(spec.node_mass), dirichlet, colliders)


def _network(spec, mesh, src: str):
    """The spring network: ``springs.pairs`` (checked against the nodes), else the mesh's
    lines and triangles' edges (and bending springs); refused when empty."""
    if spec.pairs is not None:
        n = len(mesh.points)
        pairs = np.asarray(spec.pairs, dtype=np.int64)
        bad = np.flatnonzero((pairs >= n).any(axis=1))
        if len(bad):
            raise ExperimentError(f"{src}: springs.pairs[{int(bad[0])}] = "
                                  f"{pairs[bad[0]].tolist()}: the mesh has nodes 0..{n - 1}")
        network = network_from_pairs(pairs)
    else:
        network = network_from_cells(mesh.points, mesh.lines, mesh.triangles,
                                     bending=bool(spec.bending))
    if len(network.edges) == 0:
        raise ExperimentError(f"{src}: [springs]: the mesh {mesh.source} has no line or triangle "
                              "cell and no springs.pairs are given: there are no springs")
    return network


def _rest_lengths(pts: np.ndarray, edges: np.ndarray, size: float, from_pairs: bool,
                  src: str) -> np.ndarray:
    """The springs' rest lengths, refused where two nodes of a spring coincide (``size``: the
    mesh's extent, the scale of :data:`NODE_TOLERANCE`)."""
    rest = np.linalg.norm(pts[edges[:, 0]] - pts[edges[:, 1]], axis=1)
    zero = np.flatnonzero(rest <= NODE_TOLERANCE * size)
    if len(zero):
        s = int(zero[0])
        where = f"springs.pairs[{s}]" if from_pairs else f"spring {s}"
        raise ExperimentError(
            f"{src}: {where} joins nodes {edges[s].tolist()} at the same reference position "
            f"{pts[edges[s, 0]].tolist()}: a spring needs a rest length > 0 (its direction is "
            f"undefined); {len(zero)} such spring(s): merge duplicate nodes or drop the pair")
    return rest


def _point_masses(experiment, pts: np.ndarray, size: float) -> np.ndarray:
    """(N,) the ``[[mass]]`` entries on their nodes (each must sit on one)."""
    point_masses = np.zeros(len(pts))
    for k, m in enumerate(experiment.masses):
        dist = np.linalg.norm(pts - np.asarray(m.at), axis=1)
        node = int(np.argmin(dist))
        if dist[node] > NODE_TOLERANCE * size:
            raise ExperimentError(
                f"{experiment.source}: mass[{k}].at = {list(m.at)} is not a node of the mesh: "
                f"the nearest node is {node} at {pts[node].tolist()} ({dist[node]:.3g} m away); "
                "a point mass must sit on a node")
        point_masses[node] += m.value
    return point_masses


def _node_conditions(experiment, resolver, recording) -> list:
    """(mask, components, displacement) of each ``[[boundary]]`` (fixed or prescribed, a
    measured series from ``recording``); tractions refused."""
    src = experiment.source
    conditions = []
    for i, b in enumerate(experiment.boundaries):
        key = f"boundary[{i}]"
        if b.kind == "traction":
            raise ExperimentError(f"{src}: {key}: tractions act on surfaces of a continuum; a "
                                  "mass-spring model takes point masses ([[mass]]) and gravity")
        displacement = b.displacement if b.kind == "prescribed" else None
        if b.kind == "prescribed" and b.series is not None:
            if recording is None:
                raise ExperimentError(
                    f"{src}: {key}.series = {b.series!r}: a measured input needs its recording "
                    "(petsoft simulate ... --recording RECORDING.h5)")

            displacement = read_input_series(recording, b.series)
        mask = resolver.vertex_mask(b.where, f"{key}.where")
        if not mask.any():
            raise ExperimentError(f"{src}: {key}.where: selects no node of the mesh")
        conditions.append((mask, b.component_indices, displacement))
    return conditions


def _check_nodes(src: str, masses: np.ndarray, free: np.ndarray, edges: np.ndarray) -> None:
    """Refuse a free node without mass; warn of nodes in no spring."""
    massless = np.flatnonzero(free & (masses <= 0.0))
    if len(massless):
        raise ExperimentError(
            f"{src}: node(s) {_listing(massless)} are free but have no mass: give [springs] "
            "node_mass > 0, a [[mass]] at them, or fix them with a [[boundary]]")
    in_spring = np.zeros(len(masses), dtype=bool)
    in_spring[edges.ravel()] = True
    lonely = np.flatnonzero(~in_spring)
    if len(lonely):
        # (stack: this function, build_mass_spring_model, its caller)
        warnings.warn(f"{src}: node(s) {_listing(lonely)} belong to no spring (they move as free "
                      "particles)", MassSpringWarning, stacklevel=3)


def _check_colliders(src: str, colliders: list, pts: np.ndarray, held: np.ndarray) -> None:
    """Refuse a collider that contains a supported node; warn of free nodes that start
    inside one."""
    for k, c in enumerate(colliders):
        phi = c.distance(pts)[0]
        inside = np.flatnonzero(held & (phi < 0.0))
        if len(inside):
            raise ExperimentError(
                f"{src}: collider[{k}] ({c.describe()}) contains the supported node(s) "
                f"{_listing(inside)} (e.g. node {int(inside[0])} at {pts[inside[0]].tolist()}): "
                "a support inside a collider fights the contact force forever; move the collider "
                "or the support")
        inside = np.flatnonzero(~held & (phi < 0.0))
        if len(inside):
            warnings.warn(f"{src}: collider[{k}] ({c.describe()}) starts with node(s) "
                          f"{_listing(inside)} inside it: they will be pushed out",
                          MassSpringWarning, stacklevel=3)


# ---------------------------------------------------------------------------------------------
# The dynamic system


class MassSpringSystem(VelocityDamping, SystemDefaults):
    """The semi-discrete system of a :class:`MassSpringModel` (DynamicSystem's interface).

    Parameters
    ----------
    model : MassSpringModel
    damping_mass, damping_stiffness : float
        Rayleigh alpha (1/s) and beta (s); beta multiplies the spring stiffness at rest.
    clamp : bool
        Use the clamped (PSD) spring and contact Hessians in Jacobians (default: exact).

    Attributes
    ----------
    points : ndarray (N, 3)
        Reference node coordinates (file numbering; the state q is the displacement from them).
    edges, kind, rest_lengths, stiffness, damping_coefficients : ndarray
        The springs (S, 2) (node pairs), their kind (index into
        :data:`petsoft.physics.springs.KINDS`), rest lengths, stiffnesses and dashpot coefficients
        (per spring, all springs, on every rank).
    masses : ndarray (N,)
        Lumped node masses (``lumped`` is the same as a global Vec, 3 entries per node).
    fixed : ndarray (N, 3) bool
        Prescribed components (fixed or prescribed ``[[boundary]]``); values: :meth:`prescribed`.
    node_range : (int, int)
        The nodes this rank owns (dofs 3 lo .. 3 hi of every global vector).
    colliders : list of Collider
    alpha, damping_stiffness : float
        Rayleigh coefficients; ``beta`` is 1 and ``K0`` = damping_stiffness K_ref + dashpots
        (see the module docstring).
    rayleigh : RayleighDamping
        The Rayleigh terms' coefficients (:mod:`petsoft.dynamics.rayleigh`), from
        ``damping_mass`` and ``damping_stiffness`` unless given.
    """

    # a network of nodes and springs: no cells, no finite elements, no continuum material
    defined_by = "[springs]"

    def __init__(self, model: MassSpringModel, damping_mass: float = 0.0,
                 damping_stiffness: float = 0.0, clamp: bool = False, *,
                 rayleigh: RayleighDamping | None = None):
        self.model = model
        self.dmesh = lay = model.dmesh
        self.comm = lay.comm
        self.dirichlet = model.dirichlet
        self.fixed = model.dirichlet.mask
        self.clamp = bool(clamp)
        self.points = lay.mesh.points
        self.edges = model.network.edges
        self.kind = model.network.kind
        self.rest_lengths = model.rest_lengths
        self.stiffness = model.stiffness.astype(float).copy()
        self.damping_coefficients = model.damping.astype(float).copy()
        self.point_masses = model.point_masses
        self.node_mass = model.node_mass
        self.colliders = model.colliders
        self.rayleigh = (rayleigh if rayleigh is not None
                         else RayleighDamping.of_matrices(damping_mass, damping_stiffness))
        self.beta = 1.0  # D = alpha M + 1 * K0 with K0 = beta_user K_ref + dashpots (see module)
        #: the body force (its stated acceleration, no tilt: petsoft.physics.body_force)
        self.body = BodyForce(model.experiment.gravity.acceleration)
        self.acceleration = self.body.acceleration()
        self.lumped_kinetic = False
        lo, hi = self.node_range = lay.node_range
        e = self.edges
        # springs touching an owned node (their forces land in owned rows) and springs whose
        # first node is owned (each spring's energy counted once over the ranks)
        self.touch = np.flatnonzero(lay.owned[e[:, 0]] | lay.owned[e[:, 1]])
        self.count_once = lay.owned[e[self.touch, 0]]
        self._ref_dirs = ((self.points[e[:, 0]] - self.points[e[:, 1]])
                          / self.rest_lengths[:, None])
        self._build_pattern()
        self.lumped = lay.create_global_vec()
        self.gravity = lay.create_global_vec()
        self._work = lay.create_global_vec()
        self._x_last = self.points.copy()
        self._v_last = np.zeros((hi - lo, 3))
        self.M = self.create_matrix()
        self.K0 = self.create_matrix()
        self._update_mass()
        self._update_reference()
        self._velocity_setup()

    def _velocity_setup(self) -> None:
        """The velocity laws on the owned nodes (rows lo..hi); those on the surface through the
        triangles."""
        exp, lay = self.model.experiment, self.dmesh
        lo, hi = self.node_range
        n = lay.nvertices
        node_of = np.full(n, -1, dtype=np.int64)
        node_of[lo:hi] = np.arange(hi - lo)
        faces = lay.mesh.surface
        pairs = face_pairs(self.points, faces, node_of) if len(faces) else None
        # each law on the nodes its where selects
        owned = {name: mask[lo:hi] for name, mask in where_of(exp, self.model.resolver).items()}
        self.velocity_terms = VelocityTerms(hi - lo, pairs, self.masses[lo:hi].copy(),
                                            coefficients_of(exp), owned, settings_of(exp))

    # -- pattern and matrices ---------------------------------------------------------------
    def _build_pattern(self) -> None:
        lay = self.dmesh
        lo, hi = self.node_range
        nloc = hi - lo
        e = self.edges[self.touch]
        # dofs of each touching spring's two nodes: (St, 6)
        dofs = (3 * e[:, :, None] + np.arange(3)).reshape(-1, 6)
        rows = np.repeat(dofs[:, :, None], 6, axis=2)            # (St, 6, 6)
        cols = np.repeat(dofs[:, None, :], 6, axis=1)
        own = np.arange(lo, hi)
        ddofs = (3 * own[:, None] + np.arange(3))                 # (nloc, 3)
        drows = np.repeat(ddofs[:, :, None], 3, axis=2)
        dcols = np.repeat(ddofs[:, None, :], 3, axis=1)
        r = np.concatenate([rows.ravel(), drows.ravel()])
        c = np.concatenate([cols.ravel(), dcols.ravel()])
        ncol = 3 * lay.nvertices
        keep = (r >= 3 * lo) & (r < 3 * hi)
        key = r * ncol + c
        ukeys, inverse = np.unique(key[keep], return_inverse=True)
        pos = np.full(len(key), len(ukeys), dtype=np.int64)       # dropped entries: a dump slot
        pos[keep] = inverse
        self._spring_pos = pos[:rows.size]
        self._diag_pos = pos[rows.size:]
        urows = ukeys // ncol - 3 * lo
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(urows, minlength=3 * nloc))]
                                     ).astype(PETSc.IntType)
        self.indices = (ukeys % ncol).astype(PETSc.IntType)
        self.nnz = len(ukeys)

    def _values(self, spring_blocks: np.ndarray | None, diag_blocks: np.ndarray | None):
        """Pattern values from (St, 6, 6) spring matrices and (nloc, 3, 3) node blocks."""
        out = np.zeros(self.nnz + 1)
        if spring_blocks is not None:
            out += np.bincount(self._spring_pos, spring_blocks.ravel(), minlength=self.nnz + 1)
        if diag_blocks is not None:
            out += np.bincount(self._diag_pos, diag_blocks.ravel(), minlength=self.nnz + 1)
        return out[:-1]

    def create_matrix(self) -> PETSc.Mat:
        """A new matrix preallocated with the system's pattern (block size 3)."""
        n3 = 3 * self.dmesh.nvertices
        nloc = 3 * (self.node_range[1] - self.node_range[0])
        A = PETSc.Mat().createAIJ(((nloc, n3), (nloc, n3)), bsize=3, comm=self.comm)
        A.setPreallocationCSR((self.indptr, self.indices))
        A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        A.setOption(PETSc.Mat.Option.KEEP_NONZERO_PATTERN, True)
        A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        self._set(A, np.zeros(self.nnz))
        return A

    def _set(self, A: PETSc.Mat, values: np.ndarray) -> PETSc.Mat:
        A.setValuesCSR(self.indptr, self.indices, values, addv=PETSc.InsertMode.INSERT_VALUES)
        A.assemble()
        return A

    def _update_mass(self) -> None:
        lo, hi = self.node_range
        self.masses = self.node_mass + self.point_masses
        m = self.masses[lo:hi]
        self.lumped.getArray()[:] = np.repeat(m, 3)
        self.gravity.getArray()[:] = (m[:, None] * self.acceleration).ravel()
        self.mass_values = self._values(None, m[:, None, None] * np.eye(3)[None])
        self._set(self.M, self.mass_values)

    def _update_reference(self) -> None:
        """K0 = beta_user K_ref + dashpots (K_ref: the spring Hessian at rest)."""
        t = self.touch
        kref = expand_blocks(spring_hessian_blocks(self.points, self.edges[t],
                                                   self.rest_lengths[t], self.stiffness[t]))
        dash = expand_blocks(dashpot_blocks(self.points, self.edges[t],
                                            self.damping_coefficients[t]))
        self.k0_values = self._values(self.damping_stiffness * kref + dash, None)
        self._set(self.K0, self.k0_values)
        self._k0_zero = not np.any(self.k0_values)

    def _tangent_values(self, x: np.ndarray) -> np.ndarray:
        t = self.touch
        blocks = spring_hessian_blocks(x, self.edges[t], self.rest_lengths[t], self.stiffness[t],
                                       clamp=self.clamp, fallback=self._ref_dirs[t])
        diag = None
        if self.colliders:
            lo, hi = self.node_range
            diag = sum(c.hessian(x[lo:hi], clamp=self.clamp) for c in self.colliders)
        return self._values(expand_blocks(blocks), diag)

    def assemble_combination(self, q: PETSc.Vec | None, a_mass: float, b_tangent: float,
                             c_reference: float, out: PETSc.Mat,
                             eliminate: bool = True, velocity: float = 0.0,
                             reuse: bool = False) -> PETSc.Mat:
        """out = a M + b K(q) + c K0 + velocity dG/dv (drag and friction, at the velocity last
        passed to :meth:`damping_apply` or :meth:`set_velocity_state`); with ``eliminate``
        prescribed rows/columns -> identity. ``reuse`` is accepted and ignored: springs are
        nonlinear (see :meth:`petsoft.dynamics.system.DynamicSystem.assemble_combination`)."""
        values = np.zeros(self.nnz)
        if b_tangent != 0.0:
            values += b_tangent * self._tangent_values(self.positions(q))
        if a_mass != 0.0:
            values += a_mass * self.mass_values
        if c_reference != 0.0:
            values += c_reference * self.k0_values
            friction = [c for c in self.colliders if c.friction > 0.0]
            if friction:
                # c is the velocity coefficient of the scheme (beta = 1): the friction's velocity
                # Jacobian at the latest velocity joins the damping term
                lo, hi = self.node_range
                x, v = self._x_last[lo:hi], self._v_last
                values += c_reference * self._values(
                    None, sum(c.friction_damping(x, v) for c in friction))
        if velocity != 0.0 and self.velocity_terms.active:
            values += velocity * self._values(None, self.velocity_terms.blocks(self._v_last))
        self._set(out, values)
        if eliminate:
            self.dirichlet.eliminate(out)
        return out

    def combination_blocks(self, q: PETSc.Vec, a_mass: float, b_tangent: float,
                           c_reference: float, velocity: float = 0.0):
        """The matrix of :meth:`assemble_combination`, unassembled (matrix-free products).

        Returns ``(springs, nodes)``: (St, 3, 3) blocks B_s of the springs touching the owned
        nodes (``edges[touch]``; spring s adds [[B_s, -B_s], [-B_s, B_s]] on its two nodes) and
        (nloc, 3, 3) blocks of the owned nodes (mass, contact, friction, drag). No elimination
        of prescribed components. Same terms as :meth:`assemble_combination`, which is kept as
        it is so that assembled runs do not change by a bit.
        """
        t = self.touch
        lo, hi = self.node_range
        springs = np.zeros((len(t), 3, 3))
        nodes = np.zeros((hi - lo, 3, 3))
        if b_tangent != 0.0:
            x = self.positions(q)
            springs += b_tangent * spring_hessian_blocks(
                x, self.edges[t], self.rest_lengths[t], self.stiffness[t], clamp=self.clamp,
                fallback=self._ref_dirs[t])
            for c in self.colliders:
                nodes += b_tangent * c.hessian(x[lo:hi], clamp=self.clamp)
        if a_mass != 0.0:
            nodes += a_mass * self.masses[lo:hi, None, None] * np.eye(3)
        if c_reference != 0.0:
            springs += c_reference * (
                self.damping_stiffness * spring_hessian_blocks(
                    self.points, self.edges[t], self.rest_lengths[t], self.stiffness[t])
                + dashpot_blocks(self.points, self.edges[t], self.damping_coefficients[t]))
            for c in self.colliders:
                if c.friction > 0.0:
                    nodes += c_reference * c.friction_damping(self._x_last[lo:hi], self._v_last)
        if velocity != 0.0 and self.velocity_terms.active:
            nodes += velocity * self.velocity_terms.blocks(self._v_last)
        return springs, nodes

    @staticmethod
    def linear_defaults(ksp: PETSc.KSP) -> None:
        """A direct solve (LU; MUMPS on several ranks): spring networks are small, their
        stiffness contrasts large, and the exact Hessian of compressed springs is indefinite.
        ``-ksp_type``/``-pc_type`` replace it (set before ``setFromOptions``)."""
        ksp.setType(PETSc.KSP.Type.PREONLY)
        pc = ksp.getPC()
        pc.setType(PETSc.PC.Type.LU)
        if ksp.getComm().getSize() > 1:
            pc.setFactorSolverType("mumps")

    # -- state --------------------------------------------------------------------------------
    def positions(self, q: PETSc.Vec) -> np.ndarray:
        """Current positions X + q of all nodes (N, 3) on every rank (collective)."""
        x = self.points + self.dmesh.to_all(q)
        self._x_last = x
        return x

    def create_vec(self) -> PETSc.Vec:
        return self.dmesh.create_global_vec()

    def near_nullspace(self):
        return None

    def apply_prescribed(self, vec: PETSc.Vec, t: float) -> None:
        lo, hi = self.node_range
        vec.getArray()[self.dirichlet.owned_dofs] = \
            self.prescribed(t)[lo:hi].ravel()[self.dirichlet.owned_dofs]

    def zero_prescribed(self, vec: PETSc.Vec) -> None:
        vec.getArray()[self.dirichlet.owned_dofs] = 0.0

    def prescribed_offsets(self, vec: PETSc.Vec) -> np.ndarray:
        return self.dirichlet.owned_dofs

    def prescribed(self, t: float) -> np.ndarray:
        """(N, 3) prescribed displacements at t (zero where not prescribed)."""
        return self.dirichlet.values(t)

    @property
    def moving_boundary(self) -> bool:
        return any(disp is not None and any("t" in e.variables for e in disp)
                   for _, _, disp in self.dirichlet.conditions)

    time_dependent_loads = False

    # -- forces and energies ----------------------------------------------------------------
    def _spring_node_gradient(self, x: np.ndarray, stiffness: np.ndarray) -> np.ndarray:
        """(nloc, 3) gradient of the spring energy at the owned nodes."""
        t = self.touch
        e = self.edges[t]
        g = spring_gradient(x, e, self.rest_lengths[t], stiffness[t])
        n = self.dmesh.nvertices
        lo, hi = self.node_range
        out = np.empty((hi - lo, 3))
        for k in range(3):
            acc = (np.bincount(e[:, 0], g[:, k], minlength=n)
                   - np.bincount(e[:, 1], g[:, k], minlength=n))
            out[:, k] = acc[lo:hi]
        return out

    def internal_gradient(self, q: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = grad W(q): springs and collider penalties (all rows)."""
        x = self.positions(q)
        g = self._spring_node_gradient(x, self.stiffness)
        lo, hi = self.node_range
        for c in self.colliders:
            g += c.gradient(x[lo:hi])
        out.getArray()[:] = g.ravel()
        return out

    def elastic_energy(self, q: PETSc.Vec) -> float:
        """Spring plus collider penalty energy (collective)."""
        x = self.positions(q)
        t = self.touch[self.count_once]
        w = spring_energy(x, self.edges[t], self.rest_lengths[t], self.stiffness[t]).sum()
        lo, hi = self.node_range
        for c in self.colliders:
            w += c.energy(x[lo:hi]).sum()
        return self.dmesh.allreduce_sum(w)

    @property
    def alpha(self) -> float:
        """Rayleigh alpha: the coefficient of M in D (1/s)."""
        return self.rayleigh.alpha

    @property
    def damping_stiffness(self) -> float:
        """The user's Rayleigh beta: the coefficient of K_ref in K0 (s; :attr:`beta` is 1)."""
        return self.rayleigh.beta

    def rayleigh_unit(self, matrix: str, v: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = B v, B the ``matrix`` a Rayleigh term scales (:mod:`petsoft.dynamics.rayleigh`):
        the lumped masses, or K_ref (the springs' stiffness at rest, without the dashpots)."""
        arr = out.getArray().reshape(-1, 3)
        if matrix == "mass":
            lo, hi = self.node_range
            arr[:] = self.masses[lo:hi, None] * v.getArray(readonly=True).reshape(-1, 3)
        else:
            p = self.get_parameters()
            arr[:] = (p["springs.stiffness"] * self._unit_product("stiffness", v)
                      + p["springs.bending"] * self._unit_product("bending", v))
        return out

    def _linear_damping_apply(self, v: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = D v = alpha M v + K0 v."""
        out.zeroEntries()
        if self.alpha != 0.0:
            out.pointwiseMult(self.lumped, v)
            out.scale(self.alpha)
        if not self._k0_zero:
            self.K0.mult(v, self._work)
            out.axpy(1.0, self._work)
        return out

    def set_velocity_state(self, v: PETSc.Vec) -> None:
        """The velocity at which :meth:`assemble_combination` linearises the velocity terms."""
        self._v_last = v.getArray(readonly=True).reshape(-1, 3).copy()

    def damping_apply(self, v: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = D v (alpha M v + K0 v) minus the lagged friction forces of the colliders and the
        drag and friction forces."""
        self._linear_damping_apply(v, out)
        vt = self.velocity_terms
        if vt.active:
            vl = v.getArray(readonly=True).reshape(-1, 3)
            self._v_last = vl.copy()
            out.getArray().reshape(-1, 3)[:] += vt.damping(vl)
        friction = [c for c in self.colliders if c.friction > 0.0]
        if friction:
            lo, hi = self.node_range
            x = self._x_last[lo:hi]
            vl = v.getArray(readonly=True).reshape(-1, 3)
            self._v_last = vl.copy()
            f = sum(c.friction_force(x, vl) for c in friction)
            arr = out.getArray()
            arr -= f.ravel()
        return out

    def kinetic_energy(self, v: PETSc.Vec) -> float:
        self._work.pointwiseMult(v, self.lumped)
        return 0.5 * v.dot(self._work)

    def gravitational_energy(self, q: PETSc.Vec) -> float:
        return -self.gravity.dot(q)

    def tractions(self, t: float, out: PETSc.Vec) -> PETSc.Vec:
        """No surface tractions in a mass-spring model: zero."""
        out.zeroEntries()
        return out

    # -- calibration interface ----------------------------------------------------------------
    @property
    def vertex_points(self) -> np.ndarray:
        """(N, 3) reference node coordinates (every rank)."""
        return self.points

    def vertex_global_dofs(self, ids) -> np.ndarray:
        """(len(ids), 3) global dof numbers of nodes ``ids``."""
        ids = np.asarray(ids, dtype=np.int64)
        return 3 * ids[:, None] + np.arange(3)

    def parameter_names(self) -> list[str]:
        """The differentiable parameters, named as :func:`petsoft.experiment.parameter_names`."""
        names = ["springs.stiffness", "springs.damping"]
        if np.any(self.kind == KINDS.index("bending")):
            names.append("springs.bending")
        names += ["springs.node_mass", *self.rayleigh.coef, *self.body.values]
        return names + self.velocity_terms.parameter_names

    def _check_names(self, names) -> None:
        valid = self.parameter_names()
        bad = [n for n in names if n not in valid]
        if bad:
            raise ExperimentError(f"mass-spring parameters {bad} are unknown; valid: "
                                  f"{', '.join(valid)}")

    def get_parameters(self) -> dict:
        bend = self.kind == KINDS.index("bending")
        first = lambda mask, arr: float(arr[mask][0]) if mask.any() else 0.0  # noqa: E731
        return {"springs.stiffness": first(~bend, self.stiffness),
                "springs.damping": first(~bend, self.damping_coefficients),
                "springs.bending": first(bend, self.stiffness),
                "springs.node_mass": self.node_mass, **self.rayleigh.coef,
                **self.body.parameters(),
                **self.velocity_terms.coef}

    def set_parameters(self, values: dict) -> None:
        """Change named parameters in place (no rebuild: value arrays and vectors only).

        The colliders' default stiffness keeps the value it got when the model was built.
        """
        self._check_names(values)
        bend = self.kind == KINDS.index("bending")
        mass_changed = ref_changed = False
        for name, value in values.items():
            value = float(value)
            if name == "springs.stiffness":
                self.stiffness[~bend] = value
                ref_changed = True
            elif name == "springs.bending":
                self.stiffness[bend] = value
                ref_changed = True
            elif name == "springs.damping":
                self.damping_coefficients[~bend] = value
                ref_changed = True
            elif name == "springs.node_mass":
                self.node_mass = value
                mass_changed = True
            elif name in self.rayleigh.coef:
                self.rayleigh.coef[name] = value
                # K0 holds beta K_ref (the module docstring)
                ref_changed |= self.rayleigh.matrix_of(name) == "reference"
            elif name in VELOCITY_NAMES:
                # negative values are accepted here (central differences at 0); the experiment
                # file refuses them
                if not np.isfinite(value):
                    raise ExperimentError(f'parameter "{name}" = {value!r} must be finite')
                self.velocity_terms.coef[name] = value
            else:
                self.body.set_parameter(name, value)
                self.acceleration = self.body.acceleration()
                mass_changed = True
        if mass_changed:
            self._update_mass()
            if self.velocity_terms is not None:     # None while __init__ builds them
                lo, hi = self.node_range
                self.velocity_terms.node_mass = self.masses[lo:hi].copy()
        if ref_changed:
            self._update_reference()

    def residual_parameter_derivatives(self, names, q: PETSc.Vec, v: PETSc.Vec, a: PETSc.Vec,
                                       t: float = 0.0, v_lin=None) -> list[PETSc.Vec]:
        """d r / d p of r = M a + grad W(q) + D v + G(v) - f_g - f_t(t) for each name
        (prescribed rows zero). r is affine in every parameter, so these are exact (the
        colliders' lagged friction and fixed stiffness do not depend on the parameters). With
        ``v_lin`` the velocity terms are those of a step linearised at v_lin (semi-implicit):
        G(v_lin) + dG/dv(v_lin) (v - v_lin)."""
        self._check_names(names)
        lo, hi = self.node_range
        bend = self.kind == KINDS.index("bending")
        x = self.positions(q)
        vl = v.getArray(readonly=True).reshape(-1, 3)
        al = a.getArray(readonly=True).reshape(-1, 3)
        vlin = v_lin.getArray(readonly=True).reshape(-1, 3) if v_lin is not None else None
        vt = self.velocity_terms
        out = []
        for name in names:
            d = self.create_vec()
            arr = d.getArray().reshape(-1, 3)
            if name in ("springs.stiffness", "springs.bending"):
                sel = bend if name == "springs.bending" else ~bend
                arr[:] = self._spring_node_gradient(x, sel.astype(float))
                # D v contains beta_user K_ref(k) v, linear in k
                if self.damping_stiffness != 0.0:
                    arr += self.damping_stiffness * self._unit_product(
                        "bending" if name == "springs.bending" else "stiffness", v)
            elif name == "springs.damping":
                arr[:] = self._unit_product("damping", v)
            elif name == "springs.node_mass":
                arr[:] = al + self.alpha * vl - self.acceleration
                # a velocity law proportional to the node masses (the dry friction)
                share = vt.mass_linearised(vl, vlin)
                if share is not None:
                    arr += share
            elif name in VELOCITY_NAMES:
                arr[:] = vt.unit_linearised(name, vl, vlin)
            elif name in self.rayleigh.coef:
                self.rayleigh_unit(self.rayleigh.matrix_of(name), v, d)
            else:
                # the body force's: minus the masses times the acceleration's derivative
                arr[:] = 0.0
                arr -= self.masses[lo:hi, None] * self.body.derivative(name)
            self.zero_prescribed(d)
            out.append(d)
        return out

    def _unit_product(self, which: str, v: PETSc.Vec) -> np.ndarray:
        """(nloc, 3) product of v with a unit-coefficient matrix, built once: the rest stiffness
        of the non-bending ("stiffness") or bending springs, or the dashpots ("damping")."""
        mats = self.__dict__.setdefault("_unit_matrices", {})
        if which not in mats:
            bend = self.kind == KINDS.index("bending")
            t = self.touch
            if which == "damping":
                blocks = dashpot_blocks(self.points, self.edges[t], (~bend[t]).astype(float))
            else:
                blocks = spring_hessian_blocks(self.points, self.edges[t], self.rest_lengths[t],
                                               (bend if which == "bending" else ~bend)[t]
                                               .astype(float))
            mats[which] = self._set(self.create_matrix(),
                                    self._values(expand_blocks(blocks), None))
        y = self._work
        mats[which].mult(v, y)
        return y.getArray(readonly=True).reshape(-1, 3).copy()

    # -- the node-wise solvers (petsoft.dynamics.matrix_free, nonlinear_gs) ----------------------
    #: a spring couples two nodes
    nodes_per_element = 2

    def unassembled(self) -> SpringBlocks:
        """The step matrix as spring and node blocks (:meth:`combination_blocks`), unassembled."""
        return SpringBlocks(self)

    def node_graph(self) -> tuple[int, np.ndarray, np.ndarray]:
        """(N, src, dst): both directions of every spring (file numbering; every rank)."""
        e = self.edges
        return len(self.points), np.concatenate([e[:, 0], e[:, 1]]), \
            np.concatenate([e[:, 1], e[:, 0]])

    def owned_nodes(self) -> np.ndarray:
        """(nowned,) the file numbers of the owned nodes: a contiguous range."""
        return np.arange(*self.node_range)

    def locate_probes(self, probes, source: str = "probes"):
        """(connectivity, cells, weights): probes sit on nodes (:func:`locate_nodes`), "cells" of
        one node each with weight 1."""
        nodes = locate_nodes(self.points, probes, source=source)
        return np.arange(len(self.points))[:, None], nodes, np.ones((len(nodes), 1))

    @staticmethod
    def dof_count(experiment) -> int:
        """Unknowns of the network ``experiment`` describes (3 per node of its spring mesh),
        read from its mesh without building the system."""
        return 3 * len(load_spring_mesh(experiment).points)

    @staticmethod
    def body_sizes(experiment) -> dict:
        """Mass (node masses and point masses), triangle area (1 without triangles),
        bounding-box diagonal and mean spring length (the lines, else the triangles' first two
        edges; 1 without either) of the experiment's spring mesh."""
        mesh = load_spring_mesh(experiment)
        pts, tri = mesh.points, mesh.triangles
        total = float(sum(m.value for m in experiment.masses))
        total += float(experiment.springs.node_mass or 0.0) * len(pts)
        area = 1.0
        if len(tri):
            e1, e2 = pts[tri[:, 1]] - pts[tri[:, 0]], pts[tri[:, 2]] - pts[tri[:, 0]]
            area = float(0.5 * np.linalg.norm(np.cross(e1, e2), axis=1).sum())
        edges = (mesh.lines if len(mesh.lines) else
                 np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]]])
                 if len(tri) else np.zeros((0, 2), dtype=int))
        cell = (float(np.mean(np.linalg.norm(pts[edges[:, 0]] - pts[edges[:, 1]], axis=1)))
                if len(edges) else 1.0)
        return {"mass": total if total > 0 else 1.0, "area": area, "cell": cell,
                "length": float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) or 1.0}

    def initial_state(self, monitor=None):
        """(q0, v0) from the ``[initial]`` expressions at the nodes (``monitor`` is not used: the
        model builder refuses a static initial state, so nothing is solved here)."""
        return initial_from_expressions(self, self.model.experiment.initial)

    def destroy(self) -> None:
        for obj in (self.M, self.K0, self.lumped, self.gravity, self._work):
            if obj is not None:
                obj.destroy()
        for A in self.__dict__.get("_unit_matrices", {}).values():
            A.destroy()


def locate_nodes(points: np.ndarray, probes, *, source: str = "probes") -> np.ndarray:
    """The node at each probe point (mass-spring probes must sit on nodes).

    Raises
    ------
    ExperimentError
        Naming the probe that is not at a node, and the nearest node.
    """
    probes = np.asarray(probes, dtype=float).reshape(-1, 3)
    size = float(np.ptp(points, axis=0).max()) or 1.0
    out = np.empty(len(probes), dtype=np.int64)
    for i, p in enumerate(probes):  # few probes; each vectorised over the nodes
        dist = np.linalg.norm(points - p, axis=1)
        node = int(np.argmin(dist))
        if dist[node] > NODE_TOLERANCE * size:
            raise ExperimentError(f"{source}[{i}] = {p.tolist()} is not a node of the mass-spring "
                                  f"mesh: the nearest node is {node} at {points[node].tolist()} "
                                  f"({dist[node]:.3g} m away)")
        out[i] = node
    return out


def rope_mesh(nodes: int, length: float, start=(0.0, 0.0, 0.0),
              direction=(1.0, 0.0, 0.0)) -> SpringMesh:
    """A straight rope of ``nodes`` nodes (``nodes - 1`` line cells) of total ``length``."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    s = np.linspace(0.0, length, nodes)
    pts = np.asarray(start, float) + s[:, None] * d
    lines = np.stack([np.arange(nodes - 1), np.arange(1, nodes)], axis=1)
    return SpringMesh(pts, lines, np.zeros((0, 3), np.int64), source="<rope>")


def cloth_mesh(nx: int, ny: int, width: float, height: float, z: float = 0.0,
               origin=(0.0, 0.0)) -> SpringMesh:
    """A flat nx x ny node grid in the plane z = const, each quad split into two triangles."""
    xs, ys = np.meshgrid(np.linspace(0.0, width, nx) + origin[0],
                         np.linspace(0.0, height, ny) + origin[1], indexing="ij")
    pts = np.column_stack([xs.ravel(), ys.ravel(), np.full(nx * ny, float(z))])
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    return SpringMesh(pts, np.zeros((0, 2), np.int64), tris, source="<cloth>")
