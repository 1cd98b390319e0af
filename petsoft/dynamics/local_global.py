"""Fast mass-spring: the local/global backward-Euler step of Liu et al. 2013.

Backward Euler for a mass-spring network with lumped masses M, spring energy
E(x) = sum_s k_s/2 (|x_i - x_j| - L_s)^2, Rayleigh mass damping D = alpha M and external forces f
(gravity included) solves, for the new positions x = X + q (X the reference, q the displacement),

    R(q) = M (q - q0 - h v0) / h^2 + alpha M (q - q0) / h + grad E(X + q) - f = 0,

the residual petsoft's Newton (:mod:`petsoft.dynamics.implicit`, ``be``) solves. R is the gradient
of the incremental potential g(q) = |q - y|^2_M / (2 h^2) + alpha |q - q0|^2_M / (2 h) + E - f.q,
y = q0 + h v0. Liu et al. write each spring energy as a minimum over a vector d_s of length L_s,

    k_s/2 (|e_s| - L_s)^2 = min_{|d_s| = L_s} k_s/2 |e_s - d_s|^2,   e_s = x_i - x_j,

and minimise g over (q, d) by alternation:

* **local step**: d_s = L_s e_s / |e_s| for every spring at once (a projection, vectorised);
* **global step**: (a M + Lap) q = M y / h^2 + (alpha/h) M q0 + f - Lap X + J d, with
  a = 1/h^2 + alpha/h, Lap = sum_s k_s (e_i - e_j)(e_i - e_j)^T (the weighted graph Laplacian,
  the same for x, y and z) and J d the spring-wise sum of +-k_s d_s. The matrix is constant: it is
  assembled and factored once per step size, and each iteration costs three back-substitutions
  (one per coordinate: the system decouples into x, y and z, as Liu et al. exploit).

Each alternation does not increase g, so the iteration converges (linearly) to a stationary point
of g, i.e. to the backward-Euler step Newton finds. Since grad E = Lap x - J d(x), the residual of
the current iterate costs one product with the factored matrix, R = K q - rhs(d(q)); the
iteration stops when |R| <= max(atol, rtol |R(predictor)|) on the free dofs.

The plain iteration converges slowly when the springs are stiff against M/h^2 (a sagging cloth
at h = 0.05 s: rate 0.994 per iteration, thousands of iterations to 1e-8). By default the
fixed-point map is Anderson-accelerated (window 5, ``-<prefix>anderson``), safeguarded by the
potential (see :meth:`LocalGlobalSolver.solve`): 5-10x fewer iterations in the tests and demos.

Cost (measured, ``scripts/examples/demo_cloth_sphere.py``, 15 x 15 cloth, h = 1/400 s, 1 rank):
Newton 2.7 iterations and 28 ms per step, local/global 41 iterations and 218 ms per step to
``rtol`` 1e-8. An iteration is far cheaper than a Newton iteration (three back-substitutions
with a factorization reused across steps, no assembly), but at this tolerance the linear rate
loses to Newton's quadratic one; Liu et al. run a fixed handful of iterations instead
(``-lg_max_it 10 -lg_accept``), trading accuracy for speed.

Contact (sphere and plane colliders, optional). The quadratic penalty
k_c/2 dist(x, feasible)^2 is also a minimum over a projected point p: min_{p feasible} k_c/2
|x - p|^2. The local step projects penetrating nodes onto the collider surface (p) and the global
matrix gets k_c on the diagonal of those nodes. The matrix is then constant while the set of
nodes in contact does not change, and is refactored when it does (counted in the report). The
residual includes the penalty force k_c (p - x), so the fixed point is the backward-Euler step
with the quadratic penalty contact of the same stiffness.

Not handled (use Newton): spring dashpots and stiffness-proportional (beta) damping, whose
matrices are not the isotropic Laplacian and would change with the spring directions; smooth or
barrier contact models other than the quadratic penalty; friction.

Distribution over ranks: nodes are split into contiguous blocks of the PETSc numbering (block
size 3, like every 3-dof field of petsoft). Every rank keeps the (replicated) spring arrays; the
matrix rows of its nodes are assembled from them once; each rank projects the springs whose first
node it owns, after scattering the few off-rank positions it needs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from petsc4py import PETSc

from petsoft.dynamics.anderson import AndersonMixing
from petsoft.dynamics.implicit import ImplicitIntegrator, StepReport
from petsoft.errors import ExperimentError, PetsoftError
from petsoft.solvers.convergence import check_converged
from petsoft.solvers.options import SolverOptions, own_options, scoped_defaults, with_options

#: |R| below this many ulps of |rhs| is round-off: the step is converged (a tolerance below
#: that level would otherwise fail after max_it iterations and halve the step)
ROUNDOFF_FACTOR = 1.0e3


class LocalGlobalError(PetsoftError):
    """The input of a local/global solver is invalid (springs, masses, colliders, options)."""


@dataclass
class LocalGlobalReport:
    """What one local/global step did."""

    iterations: int = 0
    residual: float = 0.0            # |R| of the returned iterate (free dofs)
    initial_residual: float = 0.0    # |R| of the predictor
    converged: bool = False
    reason: str = ""
    factorizations: int = 0          # matrix factorizations this step (contact set changes)
    local_time: float = 0.0          # seconds in local steps (projections, scatters)
    global_time: float = 0.0         # seconds in back-substitutions
    setup_time: float = 0.0          # seconds assembling and factoring
    potential_history: list = field(default_factory=list)   # incremental potential per iterate
    anderson_rejections: int = 0    # accelerated iterates replaced by plain ones
    residual_history: list = field(default_factory=list)


@dataclass
class _Step:
    """What one local/global step (:meth:`LocalGlobalSolver.solve`) keeps on this rank's nodes:
    the fixed data of its potential, its work vectors (destroyed by the solve) and the contact
    sets (``sets``: of the matrix, grown within the step; ``active``: in contact at the last
    iterate), whether the last evaluation refactored the matrix, and the residual's round-off
    floor."""

    h: float
    mpi: object
    m: np.ndarray
    fx: np.ndarray
    q0a: np.ndarray
    y: np.ndarray
    fa: np.ndarray
    z: np.ndarray
    b0: np.ndarray
    jd: PETSc.Vec
    work: list
    zc: list
    sets: np.ndarray
    active: np.ndarray
    refactored: bool = False
    floor: float = 0.0


def _checked_network(edges, rest_lengths, stiffness, masses, fixed, node_index, damping_mass,
                     colliders):
    """(edges, rest lengths, stiffnesses, masses, (N, 3) fixed components, node_index) of a
    spring network as arrays, checked with the damping and the colliders on the replicated
    data, so that every rank raises the same :class:`LocalGlobalError` (no deadlock)."""
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    masses = np.asarray(masses, dtype=float).ravel()
    n = len(masses)
    S = len(edges)
    rest = np.asarray(rest_lengths, dtype=float).ravel()
    k = np.broadcast_to(np.asarray(stiffness, dtype=float), (S,)).copy() if S else \
        np.zeros(0)
    if rest.shape != (S,):
        raise LocalGlobalError(f"rest_lengths has {rest.size} entries for {S} springs")
    if S and (edges.min() < 0 or edges.max() >= n):
        s = int(np.flatnonzero((edges < 0).any(1) | (edges >= n).any(1))[0])
        raise LocalGlobalError(f"spring {s} joins nodes {tuple(edges[s])}: node numbers must "
                               f"be in [0, {n})")
    if S and (edges[:, 0] == edges[:, 1]).any():
        s = int(np.flatnonzero(edges[:, 0] == edges[:, 1])[0])
        raise LocalGlobalError(f"spring {s} joins node {edges[s, 0]} to itself")
    if S and not (rest > 0).all():
        s = int(np.flatnonzero(~(rest > 0))[0])
        raise LocalGlobalError(f"spring {s} has rest length {rest[s]}: it must be > 0 (the "
                               "local step projects onto the sphere of that radius)")
    if S and not (k >= 0).all():
        s = int(np.flatnonzero(~(k >= 0))[0])
        raise LocalGlobalError(f"spring {s} has stiffness {k[s]}: it must be >= 0")
    fixed = np.zeros((n, 3), bool) if fixed is None else np.asarray(fixed, bool)
    if fixed.ndim == 1:
        fixed = np.repeat(fixed[:, None], 3, axis=1)
    if fixed.shape != (n, 3):
        raise LocalGlobalError(f"fixed has shape {fixed.shape}; expected ({n},) or ({n}, 3)")
    bad = ~(masses > 0) & ~fixed.all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise LocalGlobalError(f"node {i} has mass {masses[i]}: a node that is not fixed "
                               "needs a positive mass")
    if damping_mass < 0:
        raise LocalGlobalError(f"damping_mass = {damping_mass}: it must be >= 0")
    for c in colliders:
        if not c.stiffness > 0:
            raise LocalGlobalError(f"collider {c} needs a stiffness > 0")
    node_index = np.arange(n) if node_index is None else np.asarray(node_index, np.int64)
    if sorted(node_index.tolist()) != list(range(n)):
        raise LocalGlobalError("node_index must be a permutation of 0..N-1")
    return edges, rest, k, masses, fixed, node_index


class LocalGlobalSolver:
    """The backward-Euler step of a mass-spring network by local/global iteration.

    Parameters
    ----------
    edges : array (S, 2) of int
        Spring end nodes (node numbers of the arrays below).
    rest_lengths : array (S,)
        Rest length of each spring (> 0).
    stiffness : float or array (S,)
        Spring stiffness k_s (>= 0, N/m).
    masses : array (N,)
        Lumped mass of each node (> 0 on nodes that are not fixed).
    reference : array (N, 3), optional
        Reference positions X; the unknown is the displacement q (x = X + q). Default 0: q is the
        position.
    fixed : array (N,) or (N, 3) of bool, optional
        Prescribed nodes (or prescribed components); their values are given to :meth:`solve`.
    node_index : array (N,) of int, optional
        Position of each node in the PETSc numbering of the 3N vectors (node n owns dofs
        3 node_index[n] + 0..2). Default: the identity.
    damping_mass : float
        Rayleigh alpha (1/s): D = alpha M.
    colliders : sequence of :class:`~petsoft.physics.colliders.Collider`
        Quadratic-penalty contact (see the module docstring).
    comm : PETSc.Comm, optional
        Default ``PETSC_COMM_WORLD``.
    layout : PETSc.Vec, optional
        A 3N vector (block size 3) whose ownership ranges the solver adopts; default PETSc's
        split of the N nodes.
    prefix : str
        Options prefix of the KSP (``-<prefix>ksp_type``, ``-<prefix>pc_type``...) and of the
        iteration's own options ``-<prefix>rtol``, ``-<prefix>atol``, ``-<prefix>max_it``.
    rtol, atol, max_it :
        Stopping test |R| <= max(atol, rtol |R(predictor)|), at most ``max_it`` iterations
        (defaults; the options above override them).
    anderson : int
        Anderson acceleration window (0: the plain iteration of Liu et al.); option
        ``-<prefix>anderson``.
    accept : bool
        Accept the iterate reached after ``max_it`` iterations as the step (Liu et al.'s fixed
        iteration count: fast, approximate; the report says ``ACCEPTED_AT_MAX_IT`` and the
        residual left); option ``-<prefix>accept``. Default: such a step fails.
    options : SolverOptions, optional
        The options (an experiment's ``[petsc]`` table) pushed under ``prefix`` while the
        solver reads them, sets its KSPs up and solves.

    Notes
    -----
    The default linear solver is a sparse Cholesky factorization (MUMPS when PETSc has it,
    PETSc's own on one rank otherwise; block Jacobi + ICC(0)-preconditioned CG on several ranks
    without MUMPS). ``-<prefix>ksp_type cg -<prefix>pc_type icc`` (serial) or ``-<prefix>pc_type
    gamg`` replace it; an iterative solver then solves to ``rtol`` 1e-12 each global step.
    """

    def __init__(self, edges, rest_lengths, stiffness, masses, reference=None, *, fixed=None,
                 node_index=None, damping_mass: float = 0.0, colliders=(), comm=None,
                 layout: PETSc.Vec | None = None, prefix: str = "lg_", rtol: float = 1e-8,
                 atol: float = 1e-10, max_it: int = 500, anderson: int = 5,
                 accept: bool = False, options: SolverOptions | None = None):
        self.comm = comm if comm is not None else PETSc.COMM_WORLD
        edges, rest, k, masses, fixed, node_index = _checked_network(
            edges, rest_lengths, stiffness, masses, fixed, node_index, damping_mass, colliders)
        n = self.nnodes = len(masses)
        X = np.zeros((n, 3)) if reference is None else np.asarray(reference, float).reshape(n, 3)

        # everything below in PETSc node order g = node_index[n]
        self.node_index = node_index
        self.masses = np.empty(n)
        self.masses[node_index] = masses
        self.fixed = np.empty((n, 3), bool)
        self.fixed[node_index] = fixed
        self.X = np.empty((n, 3))
        self.X[node_index] = X
        self.edges = node_index[edges]
        self.rest, self.k = rest, k
        self.alpha = float(damping_mass)
        self.colliders = tuple(colliders)
        self.options = own_options(prefix, options)
        self.prefix = prefix = self.options.prefix
        self._own_nodes(layout)
        self._own_springs()
        # the constant Laplacian, assembled from the replicated springs (owned rows only)
        i, j = self.edges[:, 0], self.edges[:, 1]
        rows = np.concatenate([i, j, i, j])
        cols = np.concatenate([i, j, j, i])
        vals = np.concatenate([k, k, -k, -k])
        self._lap = sp.coo_matrix((vals, (rows, cols)), shape=(n, n)).tocsr()
        self._lap.sum_duplicates()
        self._lapX = self._lap @ self.X   # replicated (n, 3): constant part of grad E
        self.h = None
        self._sets = None          # contact sets of the factored matrix
        self._last_active = None   # nodes in contact at the end of the last step
        self._ksps: list[PETSc.KSP] = []
        self._mats: list[PETSc.Mat] = []
        self._K = None
        self._cvecs = [self._component_vec() for _ in range(3)]
        opts = PETSc.Options(prefix)
        with self.options.pushed():
            self.rtol = opts.getReal("rtol", rtol)
            self.atol = opts.getReal("atol", atol)
            self.max_it = opts.getInt("max_it", max_it)
            self.anderson = opts.getInt("anderson", anderson)
            self.accept = opts.getBool("accept", accept)
        self.factorizations = 0

    def _own_nodes(self, layout: PETSc.Vec | None) -> None:
        """This rank's nodes ``n0:n1``: a contiguous block, ``layout``'s (3 entries per node)
        or PETSc's default split."""
        if layout is not None:
            r0, r1 = layout.getOwnershipRange()
            self.n0, self.n1 = r0 // 3, r1 // 3
        else:
            probe = PETSc.Vec().createMPI((PETSc.DECIDE, self.nnodes), comm=self.comm)
            self.n0, self.n1 = probe.getOwnershipRange()
            probe.destroy()
        if self.comm.tompi4py().allreduce(self.n1 - self.n0) != self.nnodes:
            raise LocalGlobalError("the layout vector does not have 3 entries per node")

    def _own_springs(self) -> None:
        """The springs this rank projects (those whose first node it owns), the nodes whose
        positions they need and the scatter that brings them."""
        owner_local = (self.edges[:, 0] >= self.n0) & (self.edges[:, 0] < self.n1)
        self.my_springs = np.flatnonzero(owner_local)
        ends = self.edges[self.my_springs]
        self.needed, inverse = np.unique(ends.ravel(), return_inverse=True)
        self.my_ends = inverse.reshape(-1, 2)
        # signed incidence (needed nodes x own springs): sums +-k d onto the nodes in one product
        ns = len(self.my_springs)
        self._incidence = sp.csr_matrix(
            (np.concatenate([np.ones(ns), -np.ones(ns)]),
             (self.my_ends.T.ravel(), np.concatenate([np.arange(ns), np.arange(ns)]))),
            shape=(len(self.needed), ns))
        self._seq = PETSc.Vec().createSeq(3 * len(self.needed), bsize=3, comm=PETSc.COMM_SELF)
        self._template = self.create_vec()
        self._is = PETSc.IS().createBlock(3, self.needed.astype(PETSc.IntType),
                                          comm=PETSc.COMM_SELF)
        self._scatter = PETSc.Scatter().create(self._template, self._is, self._seq, None)

    # -- vectors ----------------------------------------------------------------------------
    def create_vec(self) -> PETSc.Vec:
        """A 3N vector (block size 3) with the solver's layout."""
        v = PETSc.Vec().createMPI((3 * (self.n1 - self.n0), 3 * self.nnodes), bsize=3,
                                  comm=self.comm)
        v.zeroEntries()
        return v

    def _component_vec(self) -> PETSc.Vec:
        v = PETSc.Vec().createMPI((self.n1 - self.n0, self.nnodes), comm=self.comm)
        v.zeroEntries()
        return v

    def from_array(self, values: np.ndarray, out: PETSc.Vec | None = None) -> PETSc.Vec:
        """A 3N vector from a replicated (N, 3) array in the caller's node numbering."""
        out = out if out is not None else self.create_vec()
        g = np.empty((self.nnodes, 3))
        g[self.node_index] = np.asarray(values, float).reshape(-1, 3)
        out.getArray()[:] = g[self.n0:self.n1].ravel()
        return out

    def to_array(self, vec: PETSc.Vec) -> np.ndarray:
        """The replicated (N, 3) array (caller's node numbering) of a 3N vector (collective)."""
        parts = self.comm.tompi4py().allgather(vec.getArray(readonly=True).reshape(-1, 3).copy())
        g = np.concatenate(parts, axis=0)
        return g[self.node_index]

    # -- the matrices -----------------------------------------------------------------------
    def _owned_rows(self, A: sp.csr_matrix) -> PETSc.Mat:
        sl = A[self.n0:self.n1]
        sl.sort_indices()
        nloc = self.n1 - self.n0
        M = PETSc.Mat().createAIJ(size=((nloc, self.nnodes), (nloc, self.nnodes)),
                                  csr=(sl.indptr.astype(PETSc.IntType),
                                       sl.indices.astype(PETSc.IntType), sl.data),
                                  comm=self.comm)
        M.assemble()
        return M

    def _destroy_solvers(self) -> None:
        for obj in self._ksps + self._mats + ([self._K] if self._K is not None else []):
            obj.destroy()
        self._ksps, self._mats, self._K = [], [], None

    def _setup(self, h: float, active_weight: np.ndarray) -> float:
        """Assemble and factor a M + Lap + diag(contact) for each distinct fixed pattern."""
        t = time.perf_counter()
        self._destroy_solvers()
        a = 1.0 / h**2 + self.alpha / h
        diag = a * self.masses + active_weight
        K = (self._lap + sp.diags(diag)).tocsr()
        self._K = self._owned_rows(K)
        self._solver_of = [None] * 3
        patterns: dict[bytes, int] = {}
        for c in range(3):
            key = self.fixed[:, c].tobytes()
            if key in patterns:
                self._solver_of[c] = patterns[key]
                continue
            fx = self.fixed[:, c]
            keep = sp.diags((~fx).astype(float))
            Kc = (keep @ K @ keep + sp.diags(fx.astype(float))).tocsr()
            Kc.eliminate_zeros()
            A = self._owned_rows(Kc)
            A.setOption(PETSc.Mat.Option.SPD, True)
            ksp = PETSc.KSP().create(comm=self.comm)
            ksp.setOptionsPrefix(self.prefix)
            ksp.setOperators(A)
            pc = ksp.getPC()
            # one rank: PETSc's own Cholesky (nested-dissection ordering); MUMPS costs ~1 ms of
            # overhead per back-substitution, more than the whole solve of a small cloth
            has_mumps = PETSc.Sys.hasExternalPackage("mumps")
            if has_mumps or self.comm.size == 1:
                ksp.setType(PETSc.KSP.Type.PREONLY)
                pc.setType(PETSc.PC.Type.CHOLESKY)
                if self.comm.size > 1:
                    pc.setFactorSolverType("mumps")
                else:
                    pc.setFactorOrdering("nd")
            else:
                ksp.setType(PETSc.KSP.Type.CG)
                pc.setType(PETSc.PC.Type.BJACOBI)
            ksp.setTolerances(rtol=1e-12, atol=1e-50, max_it=10000)
            with scoped_defaults(**{self.prefix + "sub_pc_type": "icc"}):
                ksp.setFromOptions()
            ksp.setUp()
            self._ksps.append(ksp)
            self._mats.append(A)
            patterns[key] = len(self._ksps) - 1
            self._solver_of[c] = patterns[key]
        self.h = h
        self.factorizations += len(self._ksps)
        return time.perf_counter() - t

    # -- the iteration ----------------------------------------------------------------------
    def _positions_needed(self, q: PETSc.Vec) -> np.ndarray:
        self._scatter.scatter(q, self._seq, addv=PETSc.InsertMode.INSERT,
                              mode=PETSc.ScatterMode.FORWARD)
        return self.X[self.needed] + self._seq.getArray(readonly=True).reshape(-1, 3)

    def _local(self, q: PETSc.Vec, out: PETSc.Vec) -> float:
        """out = J d(q), the projected springs' pull on their nodes; returns this rank's E(q)."""
        x = self._positions_needed(q)
        s = self.my_springs
        e = x[self.my_ends[:, 0]] - x[self.my_ends[:, 1]]
        length = np.linalg.norm(e, axis=1)
        # a collapsed spring has no direction; its reference direction is as good as any
        ref = self.X[self.edges[s, 0]] - self.X[self.edges[s, 1]]
        ref_len = np.linalg.norm(ref, axis=1)
        fallback = np.where(ref_len[:, None] > 0, ref / np.where(ref_len > 0, ref_len, 1)[:, None],
                            np.array([1.0, 0.0, 0.0]))
        unit = np.where((length > 0)[:, None], e / np.where(length > 0, length, 1)[:, None],
                        fallback)
        kd = (self.k[s] * self.rest[s])[:, None] * unit
        acc = self._incidence @ kd
        out.zeroEntries()
        self._seq.getArray()[:] = acc.ravel()
        self._scatter.scatter(self._seq, out, addv=PETSc.InsertMode.ADD,
                              mode=PETSc.ScatterMode.REVERSE)
        return 0.5 * float(np.sum(self.k[s] * (length - self.rest[s]) ** 2))

    def _contact(self, q_local: np.ndarray, sets: np.ndarray):
        """Matrix weights, k_c (p - X) and contact energy on this rank's nodes, and the
        penetrating nodes (per collider).

        ``sets`` (colliders, owned nodes) says which nodes carry k_c in the matrix: a superset
        of the penetrating ones. For a node in the set that does not penetrate, p = x (its
        closest feasible point is itself), so its term adds k_c (x_now - x_iterate): a proximal
        term that vanishes at the fixed point. The set may therefore stay the same over many
        iterations (no refactorization) without changing the solution.
        """
        nloc = self.n1 - self.n0
        weight = np.zeros(nloc)
        pull = np.zeros((nloc, 3))
        energy = 0.0
        X = self.X[self.n0:self.n1]
        x = X + q_local
        active = np.zeros((len(self.colliders), nloc), bool)
        for i, c in enumerate(self.colliders):
            active[i], p = c.project(x)
            weight += c.stiffness * sets[i]
            pull += c.stiffness * sets[i][:, None] * (p - X)
            energy += 0.5 * c.stiffness * float(np.sum((x - p)[active[i]] ** 2))
        return weight, pull, energy, active

    @with_options
    def solve(self, q0: PETSc.Vec, v0: PETSc.Vec, h: float, force: PETSc.Vec, q1: PETSc.Vec,
              prescribed: PETSc.Vec | None = None, guess: PETSc.Vec | None = None
              ) -> LocalGlobalReport:
        """One backward-Euler step: q1 from (q0, v0), step h and external force ``force``.

        Parameters
        ----------
        q0, v0, force : PETSc.Vec
            Old displacement and velocity, and the external force at t0 + h (gravity included).
        h : float
            Step (s).
        q1 : PETSc.Vec
            Output: the new displacement (the velocity is (q1 - q0)/h).
        prescribed : PETSc.Vec, optional
            Values of the fixed components at t0 + h (default: their values in q0).
        guess : PETSc.Vec, optional
            Start of the iteration (default the predictor q0 + h v0).

        Returns
        -------
        LocalGlobalReport
            ``converged`` is False (with the reason) when ``max_it`` iterations did not reach
            the tolerance; q1 then holds the last iterate. A failed linear solve raises
            :class:`~petsoft.errors.SolverError` on every rank.

        Notes
        -----
        With ``anderson`` > 0 (option ``-<prefix>anderson``), the fixed-point map q -> G(q) (one
        local and one global step) is accelerated by Anderson mixing of that many previous
        iterates [Peng et al. 2018]; an accelerated iterate whose incremental potential is not
        below the previous one is replaced by the plain iterate G(q), so the potential still
        decreases monotonically (up to contact-set changes) and convergence is kept.
        """
        rep = LocalGlobalReport()
        step = self._step_data(q0, v0, float(h), force, prescribed)
        if guess is not None:
            guess.copy(q1)
        else:
            q1.getArray()[:] = step.y.ravel()
        q1.getArray().reshape(-1, 3)[step.fx] = step.z[step.fx]
        mixer = AndersonMixing(self.anderson, step.mpi)
        phi_prev = np.inf
        try:
            rhs, norm, phi = self._evaluate(step, q1, rep)
            ref = rep.initial_residual = norm
            # size of the potential's terms: the round-off scale of its differences
            phi_scale = abs(phi) + float(step.mpi.allreduce(np.sum(np.abs(step.fa * step.y))))
            for it in range(self.max_it + 1):
                # (a rise below round-off of the potential is noise: rejecting on it would make
                # the iteration count depend on the number of ranks)
                if step.refactored:
                    # a new matrix is a new fixed-point map: the history no longer applies
                    mixer.forget()
                if (mixer.window and mixer.plain is not None
                        and phi > phi_prev + 1e-12 * (abs(phi_prev) + phi_scale)):
                    # the accelerated iterate raised the potential: take the plain one
                    q1.getArray()[:] = mixer.plain
                    mixer.restart()
                    rep.anderson_rejections += 1
                    rhs, norm, phi = self._evaluate(step, q1, rep)
                rep.residual_history.append(norm)
                rep.potential_history.append(phi)
                rep.residual = norm
                rep.iterations = it
                if self._stopped(rep, it, norm, ref, step.floor):
                    break
                qa = q1.getArray(readonly=True).ravel().copy()
                g = self._global_step(step, rhs, rep).ravel()
                phi_prev = phi
                q1.getArray()[:] = mixer.mix(qa, g)
                rhs, norm, phi = self._evaluate(step, q1, rep)
            self._last_active = step.active
        finally:
            for v in [step.jd] + step.work + step.zc:
                v.destroy()
        return rep

    def _step_data(self, q0: PETSc.Vec, v0: PETSc.Vec, h: float, force: PETSc.Vec,
                   prescribed: PETSc.Vec | None) -> _Step:
        """What a step (:meth:`solve`) keeps fixed on this rank's nodes, and its work vectors."""
        m = self.masses[self.n0:self.n1, None]
        fx = self.fixed[self.n0:self.n1]
        q0a = q0.getArray(readonly=True).reshape(-1, 3).copy()
        y = q0a + h * v0.getArray(readonly=True).reshape(-1, 3)
        fa = force.getArray(readonly=True).reshape(-1, 3).copy()
        z = (prescribed if prescribed is not None else q0).getArray(readonly=True)
        z = z.reshape(-1, 3).copy()
        # constant part of the right-hand side
        b0 = m * y / h**2 + (self.alpha / h) * m * q0a + fa - self._lapX[self.n0:self.n1]
        zc = [self._component_vec() for _ in range(3)]
        for c in range(3):
            zc[c].getArray()[:] = np.where(fx[:, c], z[:, c], 0.0)
        # contact sets of the matrix: the nodes in contact at the end of the last step, grown
        # whenever another node penetrates (see _contact)
        sets = (self._last_active.copy() if self._last_active is not None
                else np.zeros((len(self.colliders), self.n1 - self.n0), bool))
        return _Step(h=h, mpi=self.comm.tompi4py(), m=m, fx=fx, q0a=q0a, y=y, fa=fa, z=z,
                     b0=b0, jd=self.create_vec(), work=[self._component_vec() for _ in range(4)],
                     zc=zc, sets=sets, active=sets.copy())

    def _evaluate(self, step: _Step, qvec: PETSc.Vec, rep: LocalGlobalReport):
        """rhs(d(q)), |R(q)| and the incremental potential at q (collective); refactors the
        matrix when the step size or the contact sets changed (``step.refactored``)."""
        t = time.perf_counter()
        mpi, h, m, fx = step.mpi, step.h, step.m, step.fx
        qa = qvec.getArray(readonly=True).reshape(-1, 3)
        e_loc = self._local(qvec, step.jd)
        refactor = self.h != h or self._K is None
        if self.colliders:
            sets = step.sets
            weight, pull, e_c, active = self._contact(qa, sets)
            if mpi.allreduce(int(np.any(active & ~sets)), op=_max_op()):
                # a node penetrates outside the matrix's contact set: grow the set
                sets[...] |= active
                weight, pull, e_c, active = self._contact(qa, sets)
            step.active = active
            refactor |= bool(mpi.allreduce(int(not np.array_equal(sets, self._sets)),
                                           op=_max_op()))
        else:
            pull, e_c, weight = 0.0, 0.0, None
        rhs = step.b0 + step.jd.getArray(readonly=True).reshape(-1, 3) + pull
        step.refactored = refactor
        if refactor:
            full_weight = (np.concatenate(mpi.allgather(weight)) if weight is not None
                           else np.zeros(self.nnodes))
            rep.setup_time += self._setup(h, full_weight)
            rep.factorizations += len(self._ksps)
            self._sets = step.sets.copy()
        res = np.empty((self.n1 - self.n0, 3))
        work = step.work
        for c in range(3):
            work[0].getArray()[:] = qa[:, c]
            self._K.mult(work[0], work[1])
            res[:, c] = work[1].getArray(readonly=True) - rhs[:, c]
        res[fx] = 0.0
        phi = (0.5 / h**2 * np.sum(m * (qa - step.y) ** 2)
               + 0.5 * self.alpha / h * np.sum(m * (qa - step.q0a) ** 2)
               - np.sum(step.fa * qa) + e_loc + e_c)
        sq, phi, rhs_sq = mpi.allreduce(np.array([float(np.sum(res * res)), float(phi),
                                                  float(np.sum(rhs[~fx] ** 2))]))
        # the residual cannot fall below the round-off of K q - rhs
        step.floor = ROUNDOFF_FACTOR * np.finfo(float).eps * float(np.sqrt(rhs_sq))
        rep.local_time += time.perf_counter() - t
        return rhs, float(np.sqrt(sq)), float(phi)

    def _global_step(self, step: _Step, rhs: np.ndarray, rep: LocalGlobalReport) -> np.ndarray:
        """G: the minimiser of the quadratic model with the projections fixed."""
        t = time.perf_counter()
        work, fx, z = step.work, step.fx, step.z
        new = np.empty((self.n1 - self.n0, 3))
        for c in range(3):
            self._K.mult(step.zc[c], work[2])
            r = rhs[:, c] - work[2].getArray(readonly=True)
            work[3].getArray()[:] = np.where(fx[:, c], z[:, c], r)
            ksp = self._ksps[self._solver_of[c]]
            ksp.solve(work[3], work[0])
            # the KSP is collective: every rank sees the same reason
            check_converged(ksp, f"local/global step (h = {step.h:g} s): the linear solve of "
                            f"coordinate {'xyz'[c]}",
                            hint=f"try -{self.prefix}ksp_type preonly "
                                 f"-{self.prefix}pc_type cholesky")
            new[:, c] = work[0].getArray(readonly=True)
        rep.global_time += time.perf_counter() - t
        return new

    def _stopped(self, rep: LocalGlobalReport, it: int, norm: float, ref: float,
                 floor: float) -> bool:
        """Whether iterate ``it`` (residual ``norm``, the predictor's ``ref``) ends the step;
        its outcome in ``rep`` (``converged``, ``reason``)."""
        if norm <= max(self.atol, self.rtol * ref):
            rep.converged, rep.reason = True, "CONVERGED_RESIDUAL"
        elif norm <= floor:
            rep.converged, rep.reason = True, "CONVERGED_ROUNDOFF"
        elif not np.isfinite(norm):
            rep.reason = "DIVERGED_NAN"
        elif it == self.max_it and self.accept:
            rep.converged, rep.reason = True, "ACCEPTED_AT_MAX_IT"
        elif it == self.max_it:
            rep.reason = (f"DIVERGED_MAX_IT ({self.max_it} iterations, |R| = "
                          f"{norm:.3e}, |R0| = {ref:.3e})")
        else:
            return False
        return True

    # -- energies (for checks and reports) -------------------------------------------------
    def spring_energy(self, q: PETSc.Vec) -> float:
        """E(X + q) = sum_s k_s/2 (|e_s| - L_s)^2 (collective)."""
        x = self._positions_needed(q)
        s = self.my_springs
        e = x[self.my_ends[:, 0]] - x[self.my_ends[:, 1]]
        value = 0.5 * np.sum(self.k[s] * (np.linalg.norm(e, axis=1) - self.rest[s]) ** 2)
        return float(self.comm.tompi4py().allreduce(value))

    def penetration(self, q: PETSc.Vec) -> float:
        """Largest depth of a node inside a collider (collective; 0 without colliders)."""
        x = self.X[self.n0:self.n1] + q.getArray(readonly=True).reshape(-1, 3)
        depth = max([float(c.penetration(x).max(initial=0.0)) for c in self.colliders],
                    default=0.0)
        return float(self.comm.tompi4py().allreduce(depth, op=_max_op()))

    def destroy(self) -> None:
        self._destroy_solvers()
        for v in self._cvecs + [self._seq, self._template]:
            v.destroy()
        self._is.destroy()
        self._scatter.destroy()


def _max_op():
    from mpi4py import MPI

    return MPI.MAX


# ---------------------------------------------------------------------------------------------
# The backward-Euler integrator of a mass-spring system by local/global iteration


def check_supported(system) -> None:
    """Raise on every rank if ``system`` has terms the local/global step does not handle.

    Raises
    ------
    petsoft.errors.ExperimentError
        Not a mass-spring system, stiffness-proportional damping, spring dashpots, friction,
        the C2 contact margin.
    """
    hint = "; use the Newton step (--solver snes) instead"
    if system.rest_lengths is None:
        raise ExperimentError("--solver local-global solves mass-spring models ([springs]) "
                              "only; a continuum ([material]) needs Newton (--solver snes)")
    if system.damping_stiffness != 0.0:
        raise ExperimentError(f"[damping] stiffness = {system.damping_stiffness}: the "
                              "local/global step handles mass damping only (its matrix must "
                              "be the isotropic spring Laplacian)" + hint)
    if np.any(np.asarray(system.damping_coefficients) != 0.0):
        raise ExperimentError("[springs] damping (dashpots) is not handled by the local/global "
                              "step (set it to 0 and use [damping] mass)" + hint)
    for k, c in enumerate(system.colliders):
        if c.margin > 0.0:
            raise ExperimentError(f"collider[{k}] has a contact margin ({c.margin}): the "
                                  "local/global step projects onto the surface, i.e. handles "
                                  "the quadratic penalty (margin 0) only" + hint)
        if c.friction > 0.0:
            raise ExperimentError(f"collider[{k}] friction = {c.friction}: friction is not "
                                  "handled by the local/global step" + hint)


class LocalGlobalIntegrator(ImplicitIntegrator):
    """Backward Euler on a mass-spring system, each step by :class:`LocalGlobalSolver`.

    The step equation, velocity update, energy terms and report are those of
    :class:`~petsoft.dynamics.implicit.ImplicitIntegrator` (``be``): only the solver differs. The
    report's ``newton_iterations`` counts local/global iterations and ``linear_iterations`` the
    back-substitutions (3 per iteration). A step that does not converge is reported as failed
    (the simulation then halves it).

    Parameters
    ----------
    system : petsoft.dynamics.mass_spring.MassSpringSystem
    prefix : str
        Options prefix of the solver (``-lg_ksp_type``, ``-lg_rtol``, ``-lg_anderson``...).
    options : SolverOptions, optional
        The options (an experiment's ``[petsc]`` table) under ``prefix``.
    """

    def __init__(self, system, prefix: str = "lg_", options: SolverOptions | None = None,
                 **solver_args):
        check_supported(system)
        options = own_options(prefix, options)
        super().__init__(system, "be", solver="snes", prefix=prefix, options=options)
        self.lg = LocalGlobalSolver(
            system.edges, system.rest_lengths, system.stiffness, system.masses,
            system.points, fixed=system.fixed, damping_mass=system.alpha,
            colliders=system.colliders, comm=system.comm, layout=self.q0,
            prefix=prefix, options=options, **solver_args)
        self._prescribed = system.create_vec()
        self.last = None

    def _new_solver(self) -> None:
        """No SNES: the local/global solver is built once (its matrix depends on h only)."""
        self.snes = self.tao = None

    def step(self, t0, q0, v0, h, q1, v1):
        s = self.system
        self.prepare(t0, q0, v0, h)
        s.apply_prescribed(self._prescribed, t0 + h)
        rep = self.last = self.lg.solve(q0, v0, h, self.f1, q1, prescribed=self._prescribed)
        report = StepReport(newton_iterations=rep.iterations,
                            linear_iterations=3 * rep.iterations,
                            converged=rep.converged, reason=rep.reason)
        if not rep.converged:
            return report
        s.apply_prescribed(q1, t0 + h)
        self._velocity(q1, v1)
        self._work_terms(q1, report)
        return report

    def destroy(self) -> None:
        self.lg.destroy()
        self._prescribed.destroy()
        super().destroy()
