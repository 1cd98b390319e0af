"""Nonlinear Gauss-Seidel and nonlinear Jacobi for the implicit step (PETSc SNES ``ngs``).

Lecture 001: solve node i's three equations R_i(q) = 0 for its own three unknowns q_i,
holding the other nodes fixed. Here each local solve is one Newton step with the node's 3x3
diagonal block B_ii of the step Jacobian (a M + b K(q) + c K0, :mod:`petsoft.dynamics.
matrix_free`, no assembled matrix):

    q_i <- q_i - omega B_ii(q)^-1 R_i(q).

* Gauss-Seidel (default): the nodes are split into colours, no two nodes of one colour sharing
  an element or a spring. The nodes of one colour do not appear in each other's equations, so
  updating them all at once is exactly the sequential node-by-node sweep in colour order,
  vectorised (one residual and one set of diagonal blocks per colour). The colouring is
  computed on the whole (replicated) node graph, the same on every rank, so the sweep is the
  same on any number of ranks.
* Jacobi: every node from the old iterate at once (one residual, one set of blocks per sweep).
  Block Jacobi converges on a symmetric positive definite J only when omega < 2 / lambda_max
  (D^-1 J), and lambda_max <= k, the number of nodes of an element (4 for linear tetrahedra,
  2 for springs): the default omega = 0.95 min(1, 2/k) is safe for any state near a minimum.

Selected by options (``prefix`` the integrator's options prefix)::

    -<prefix>snes_type ngs                  # PETSc's NGS, with petsoft's per-node update
    -<prefix>petsoft_ngs jacobi             # gs (default) or jacobi
    -<prefix>petsoft_ngs_omega 0.5          # relaxation (default 1 for gs; see above for jacobi)

Each SNES iteration is one sweep (PETSc evaluates the residual after it for the convergence
test); petsoft raises the default ``max_it`` to :data:`MAX_SWEEPS` for ``ngs`` (an explicit
``-snes_max_it`` wins). Convergence is linear, at a rate set by the step's stiffness: fast when
the mass term a M dominates (small steps, soft bodies), slow for stiff bodies at large steps.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.dynamics.matrix_free import StepOperator
from petsoft.solvers.convergence import stop_at_round_off

OPTION = "petsoft_ngs"
OMEGA_OPTION = "petsoft_ngs_omega"
VARIANTS = ("gs", "jacobi")
#: The default ``max_it`` of an NGS solve (one sweep per iteration).
MAX_SWEEPS = 20000
#: At most this many colours (the colour sets are bit masks of an unsigned 64-bit integer).
MAX_COLOURS = 64


def greedy_colouring(n: int, src: np.ndarray, dst: np.ndarray, seed: int = 0) -> np.ndarray:
    """Colours of ``n`` nodes such that no edge (src, dst) joins two nodes of one colour.

    Jones-Plassmann with the greedy choice, vectorised: in each round every uncoloured node
    whose random priority beats all its uncoloured neighbours' takes the smallest colour none
    of its neighbours has; those nodes are independent, so a round needs no order among them.

    Parameters
    ----------
    n : int
    src, dst : ndarray of int
        Both directions of every edge (duplicates are harmless).
    seed : int
        Of the priorities: the same seed gives the same colouring on every rank.

    Returns
    -------
    ndarray (n,) of int
    """
    keep = src != dst
    # edges grouped by their first node: per-node reductions are reduceat over segments
    order = np.argsort(src[keep], kind="stable")
    src, dst = src[keep][order], dst[keep][order]
    has = np.bincount(src, minlength=n) > 0
    starts = np.searchsorted(src, np.flatnonzero(has))
    priority = np.random.default_rng(seed).permutation(n)
    colour = np.full(n, -1, dtype=np.int64)
    used = np.zeros(n, dtype=np.uint64)          # bit c: a neighbour has colour c
    one = np.uint64(1)
    while (colour < 0).any():
        open_ = colour < 0
        best = np.full(n, -1, dtype=np.int64)    # the highest open neighbour's priority
        if len(src):
            best[has] = np.maximum.reduceat(np.where(open_[dst], priority[dst], -1), starts)
        pick = np.flatnonzero(open_ & (priority > best))
        m = used[pick]
        if (m == np.iinfo(np.uint64).max).any():
            raise ValueError(f"the node graph needs more than {MAX_COLOURS} colours")
        low = ~m & (m + one)                         # the lowest zero bit of the mask
        colour[pick] = np.log2(low.astype(float)).astype(np.int64)
        chosen = np.zeros(n, dtype=bool)
        chosen[pick] = True
        if len(src):
            bits = np.where(chosen[dst], np.left_shift(one, np.maximum(colour[dst], 0)
                                                       .astype(np.uint64)), np.uint64(0))
            used[has] |= np.bitwise_or.reduceat(bits, starts)
    return colour


def node_graph(system) -> tuple[int, np.ndarray, np.ndarray]:
    """(N, src, dst): the whole node graph (file numbering; the same on every rank)."""
    if system.node_graph is None:
        raise ValueError(f"{type(system).__name__}: nonlinear Gauss-Seidel needs a continuum or "
                         "mass-spring system")
    return system.node_graph()


def owned_colours(system) -> np.ndarray:
    """(nowned,) the colour of each owned node, in the global vector's order."""
    n, src, dst = node_graph(system)
    return greedy_colouring(n, src, dst)[system.owned_nodes()]


class NodeSweeps:
    """The per-node update PETSc's SNES ``ngs`` calls (``snes.setNGS``).

    Parameters
    ----------
    integrator : petsoft.dynamics.implicit.ImplicitIntegrator
        Gives the step's residual (``_residual``) and its linearisation (``_jacobian``).
    variant : {"gs", "jacobi"}
    omega : float or None
        Relaxation; None: 1 for Gauss-Seidel, 0.95 min(1, 2/k) for Jacobi.
    """

    def __init__(self, integrator, variant: str = "gs", omega: float | None = None):
        if variant not in VARIANTS:
            raise ValueError(f"nonlinear Gauss-Seidel variant {variant!r}: expected one of "
                             f"{', '.join(VARIANTS)}")
        self.integrator = integrator
        system = integrator.system
        self.variant = variant
        if omega is None:
            omega = 1.0 if variant == "gs" else 0.95 * min(1.0, 2.0 / system.nodes_per_element)
        self.omega = float(omega)
        self.operator = StepOperator(system)
        self._R = system.create_vec()
        if variant == "gs":
            colours = owned_colours(system)
            ncolours = int(system.comm.tompi4py().allreduce(
                int(colours.max()) + 1 if len(colours) else 0, op=MPI.MAX))
            self.groups = [np.flatnonzero(colours == c) for c in range(ncolours)]
        else:
            self.groups = [None]
        self.sweeps = 0

    def _update(self, x: PETSc.Vec, b: PETSc.Vec | None, nodes: np.ndarray | None) -> None:
        """One Newton step of the nodes ``nodes`` (all when None) on their own equations."""
        R = self._R
        self.integrator._residual(x, R)
        # petsc4py hands a Vec without a handle, not None, for PETSc's NULL right-hand side
        if b is not None and b.handle:
            R.axpy(-1.0, b)
        # the blocks at x (the residual just set the velocity the drag is linearised at)
        self.integrator._jacobian(x, self.operator)
        blocks = self.operator.node_blocks()
        r = R.getArray(readonly=True).reshape(-1, 3)
        if nodes is not None:
            blocks, r = blocks[nodes], r[nodes]
        step = np.linalg.solve(blocks, r[:, :, None])[:, :, 0]
        xa = x.getArray().reshape(-1, 3)
        if nodes is None:
            xa -= self.omega * step
        else:
            xa[nodes] -= self.omega * step

    def __call__(self, snes: PETSc.SNES, x: PETSc.Vec, b: PETSc.Vec | None) -> None:
        """One sweep over all nodes (PETSc's NGS calls it once per iteration)."""
        for nodes in self.groups:
            self._update(x, b, nodes)
        self.sweeps += 1


def requested_variant(prefix: str) -> tuple[str, float | None]:
    """The variant and relaxation the options ask for (``-<prefix>petsoft_ngs``,
    ``-<prefix>petsoft_ngs_omega``)."""
    opts = PETSc.Options(prefix)
    variant = opts.getString(OPTION, "gs")
    if variant not in VARIANTS:
        raise ValueError(f"-{prefix}{OPTION} {variant}: expected one of {', '.join(VARIANTS)}")
    omega = opts.getReal(OMEGA_OPTION, 0.0) if opts.hasName(OMEGA_OPTION) else None
    if omega is not None and not 0.0 < omega < 2.0:
        raise ValueError(f"-{prefix}{OMEGA_OPTION} {omega}: expected 0 < omega < 2")
    return variant, omega


def install(integrator, snes: PETSc.SNES, prefix: str) -> NodeSweeps | None:
    """When ``snes`` is of type ``ngs``: give it petsoft's per-node update and, unless the
    options set one, a ``max_it`` of :data:`MAX_SWEEPS`. Returns the update (or None)."""
    if snes.getType() != PETSc.SNES.Type.NGS:
        return None
    variant, omega = requested_variant(prefix)
    sweeps = NodeSweeps(integrator, variant, omega)
    snes.setNGS(sweeps)
    # the round-off stop needs ||J||: the assembled matrix is never filled under NGS, the
    # blocks' operator is (a residual stalled at round-off would otherwise sweep to max_it)
    stop_at_round_off(snes, sweeps.operator, integrator.length)
    if not PETSc.Options(prefix).hasName("snes_max_it"):
        snes.setTolerances(max_it=MAX_SWEEPS)
    return sweeps
