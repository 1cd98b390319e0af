"""The implicit step's Jacobian without an assembled matrix: a MatShell for Newton-CG.

The step matrix of the implicit integrators, J = a M + b K(q) + c K0 + v dG/dv with the
prescribed rows and columns replaced by the identity (:mod:`petsoft.dynamics.implicit`), is kept
*unassembled*: as the element matrices of the continuum (every term's element matrices, the mass
and the reference stiffness included, combined into one array per element set) or as the 3x3
blocks of the springs and nodes of a mass-spring model. Its product with a vector gathers the
element values, multiplies and scatters back (no global sparse matrix is ever built), its
diagonal and its 3x3 diagonal blocks are sums of element blocks.

Selected by options (``prefix`` the integrator's options prefix)::

    -<prefix>petsoft_jacobian shell     # Newton with this MatShell; default KSP: CG + Jacobi

The KSP defaults to conjugate gradients preconditioned by the diagonal (``-ksp_type cg
-pc_type jacobi``, PCJacobi takes the diagonal from :meth:`StepOperator.getDiagonal`); any
``-ksp_type``/``-pc_type`` that needs only products and the diagonal replaces them (not LU,
ILU or GAMG: there is no matrix to factor or coarsen). The diagonal blocks also serve the
nonlinear Gauss-Seidel of :mod:`petsoft.dynamics.nonlinear_gs`.

The element products cost about what a sparse product costs (a P1 element matrix holds 144
values, an assembled row of a tetrahedral mesh about 3 x 45), so the gain is not flops: it is
no assembly, no matrix set-up and no factorisation, which for Newton with a few CG iterations
per step dominates.
"""

from __future__ import annotations

import atexit
import weakref

import numpy as np
from petsc4py import PETSc

from petsoft.fem.kernels.scatter import scatter_add_vector
from petsoft.physics.loads import consistent_mass_matrices

#: The option (in the integrator's prefix) that selects the MatShell Jacobian.
OPTION = "petsoft_jacobian"
CHOICES = ("assembled", "shell")


class ElementCapture:
    """Stands in for a :class:`~petsoft.fem.assembly.MatrixAssembler`: keeps the element
    matrices the physics terms add (``add(name, matrices, start)``) instead of summing them.

    Every term adds each element range of its set once per evaluation, so the buffers are
    overwritten, not zeroed and summed (they are reused from one evaluation to the next)."""

    def __init__(self, connectivity: dict[str, np.ndarray]):
        self.connectivity = connectivity
        self.sets: dict[str, np.ndarray] = {}

    def add(self, name: str, element_matrices: np.ndarray, start: int = 0) -> None:
        if name not in self.sets:
            n, nd = len(self.connectivity[name]), 3 * self.connectivity[name].shape[1]
            self.sets[name] = np.empty((n, nd, nd))
        self.sets[name][start:start + len(element_matrices)] = element_matrices


def local_diagonal_blocks(sets: dict, connectivity: dict, nv: int) -> np.ndarray:
    """(nv, 9) sums of the element matrices' (a, a) 3x3 blocks at the local vertices."""
    local = np.zeros((nv, 9))
    for name, E in sets.items():
        conn = connectivity[name]
        k = conn.shape[1]
        blocks = np.diagonal(E.reshape(len(conn), k, 3, k, 3), axis1=1, axis2=3)
        blocks = np.moveaxis(blocks, -1, 1).reshape(-1, 9)     # (ne k, 9)
        idx = conn.ravel()
        for j in range(9):
            local[:, j] += np.bincount(idx, weights=blocks[:, j], minlength=nv)
    return local


class ContinuumElements:
    """J of a :class:`~petsoft.dynamics.system.DynamicSystem` as element matrices per set.

    The tangent's element matrices are kept apart from the constant mass and K0 ones; the
    products combine them once per linearisation (on first use), the diagonal blocks (all
    nonlinear Gauss-Seidel needs, once per colour) add the constant parts' blocks, computed
    once.
    """

    def __init__(self, system):
        self.system = system
        self.dmesh = system.dmesh
        self.connectivity = system.assembler.connectivity
        self.nv = self.dmesh.nvertices
        self._version = None          # the parameters the constant parts were computed for
        self._tangent = ElementCapture(self.connectivity)
        self._coef = (0.0, 0.0, 0.0)
        self._combined = None
        self.node_blocks = np.zeros((self.nv, 3, 3))

    def _constants(self) -> None:
        """The mass and K0 element matrices (and their diagonal blocks), again after
        ``set_parameters``."""
        s = self.system
        version = s._parameter_version
        if version == self._version:
            return
        mass = ElementCapture(self.connectivity)
        mass_e = consistent_mass_matrices(self.dmesh, s.model.density)
        for group in s.elastic.groups:
            mass.add(group.name, np.ascontiguousarray(mass_e[group.cells]))
        k0 = ElementCapture(self.connectivity)
        s.elastic.add_reference_hessian(k0)
        self._mass, self._k0, self._version = mass.sets, k0.sets, version
        self._mass_diag = local_diagonal_blocks(self._mass, self.connectivity, self.nv)
        self._k0_diag = local_diagonal_blocks(self._k0, self.connectivity, self.nv)

    def update(self, q, a: float, b: float, c: float, velocity: float) -> None:
        s = self.system
        self._constants()
        self._coef = (a, b, c)
        self._combined = None
        if b != 0.0:
            s.elastic.add_hessian(self.dmesh.to_local(q), self._tangent)
        self.node_blocks[:] = 0.0
        if velocity != 0.0 and s.velocity_terms.active:
            # owned vertices come first in the local numbering, in the global vector's order
            own = self.dmesh.nowned
            self.node_blocks[:own] = velocity * s.velocity_terms.blocks(s._v_last)

    @property
    def sets(self) -> dict[str, np.ndarray]:
        """a M_e + b K_e(q) + c K0_e per element set (combined on first use)."""
        if self._combined is None:
            a, b, c = self._coef
            tangent = self._tangent.sets if b != 0.0 else {}
            combined = {}
            for name in set(tangent) | set(self._mass) | set(self._k0):
                E = b * tangent[name] if name in tangent else 0.0
                if name in self._mass:
                    E = E + a * self._mass[name]
                if name in self._k0:
                    E = E + c * self._k0[name]
                combined[name] = np.ascontiguousarray(E)
            self._combined = combined
        return self._combined

    def mult(self, x: PETSc.Vec, y: PETSc.Vec) -> None:
        u = self.dmesh.to_local(x)
        out = np.einsum("nij,nj->ni", self.node_blocks, u).ravel()
        for name, E in self.sets.items():
            conn = self.connectivity[name]
            ue = u[conn].reshape(len(conn), -1)
            scatter_add_vector(conn, np.matmul(E, ue[:, :, None])[:, :, 0], out)
        y.zeroEntries()
        self.dmesh.add_to_global(out.reshape(-1, 3), y)

    def diagonal_blocks(self, work: PETSc.Vec) -> np.ndarray:
        """(nowned, 3, 3) diagonal blocks of J without elimination (sums over the ranks)."""
        a, b, c = self._coef
        local = self.node_blocks.reshape(self.nv, 9) + a * self._mass_diag + c * self._k0_diag
        if b != 0.0:
            local += b * local_diagonal_blocks(self._tangent.sets, self.connectivity, self.nv)
        own = self.dmesh.nowned
        out = np.empty((own, 3, 3))
        for col in range(3):
            work.zeroEntries()
            self.dmesh.add_to_global(local.reshape(self.nv, 3, 3)[:, :, col], work)
            out[:, :, col] = work.getArray(readonly=True).reshape(-1, 3)
        return out

    def abs_row_sums(self, work: PETSc.Vec) -> PETSc.Vec:
        """Sum over the elements of |E| row sums: a bound on J's row sums of |J_ij|."""
        out = np.abs(self.node_blocks).sum(axis=2).ravel()
        for name, E in self.sets.items():
            scatter_add_vector(self.connectivity[name], np.abs(E).sum(axis=2), out)
        work.zeroEntries()
        self.dmesh.add_to_global(out.reshape(-1, 3), work)
        return work


class SpringBlocks:
    """J of a :class:`~petsoft.dynamics.mass_spring.MassSpringSystem` as spring and node blocks
    (:meth:`~petsoft.dynamics.mass_spring.MassSpringSystem.combination_blocks`)."""

    def __init__(self, system):
        self.system = system
        lo, hi = system.node_range
        self.lo, self.hi = lo, hi
        self.n = system.dmesh.nvertices
        self.edges = system.edges[system.touch]
        self.springs = np.zeros((len(self.edges), 3, 3))
        self.nodes = np.zeros((hi - lo, 3, 3))

    def update(self, q, a: float, b: float, c: float, velocity: float) -> None:
        self.springs, self.nodes = self.system.combination_blocks(q, a, b, c, velocity)

    def _to_nodes(self, per_spring: np.ndarray, sign: float) -> np.ndarray:
        """(nloc, m) sums at the owned nodes of per-spring rows added to the first node and
        ``sign`` times to the second."""
        e = self.edges
        cols = per_spring.shape[1]
        out = np.empty((self.hi - self.lo, cols))
        for j in range(cols):
            acc = (np.bincount(e[:, 0], per_spring[:, j], minlength=self.n)
                   + sign * np.bincount(e[:, 1], per_spring[:, j], minlength=self.n))
            out[:, j] = acc[self.lo:self.hi]
        return out

    def mult(self, x: PETSc.Vec, y: PETSc.Vec) -> None:
        xa = self.system.dmesh.to_all(x)
        e = self.edges
        f = np.einsum("sij,sj->si", self.springs, xa[e[:, 0]] - xa[e[:, 1]])
        out = self._to_nodes(f, -1.0)
        out += np.einsum("nij,nj->ni", self.nodes, xa[self.lo:self.hi])
        y.getArray()[:] = out.ravel()

    def diagonal_blocks(self, work: PETSc.Vec) -> np.ndarray:
        return self.nodes + self._to_nodes(self.springs.reshape(-1, 9), 1.0).reshape(-1, 3, 3)

    def abs_row_sums(self, work: PETSc.Vec) -> PETSc.Vec:
        # each spring's block appears twice in each of its rows: [[B, -B], [-B, B]]
        a = 2.0 * np.abs(self.springs).sum(axis=2)
        work.getArray()[:] = (self._to_nodes(a, 1.0)
                              + np.abs(self.nodes).sum(axis=2)).ravel()
        return work


def unassembled(system):
    """The unassembled representation of ``system``'s step matrix.

    Raises
    ------
    ValueError
        For a system without one (e.g. the analytic oscillator).
    """
    if system.unassembled is not None:
        return system.unassembled()
    raise ValueError(f"{type(system).__name__}: the matrix-free Jacobian and nonlinear "
                     "Gauss-Seidel need a continuum (DynamicSystem) or mass-spring system")


class StepOperator:
    """J = a M + b K(q) + c K0 + v dG/dv, prescribed rows and columns identity, unassembled.

    A petsc4py Python-matrix context (``mult``, ``getDiagonal``): :meth:`create_mat` wraps it
    in a MatShell. :meth:`update` re-linearises at a state (what assembling the Jacobian is for
    an assembled matrix).

    Parameters
    ----------
    system : DynamicSystem or MassSpringSystem
    """

    def __init__(self, system):
        self.system = system
        self.parts = unassembled(system)
        self._work = system.create_vec()
        self._x = system.create_vec()
        self._offsets = system.prescribed_offsets(self._work)

    def update(self, q: PETSc.Vec | None, a: float, b: float, c: float,
               velocity: float = 0.0) -> None:
        """Linearise at ``q`` with the coefficients of ``assemble_combination``."""
        self.parts.update(q, a, b, c, velocity)

    # -- the MatPython interface -----------------------------------------------------------------
    def mult(self, mat, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """y = J x: the free block of J on the free entries, x on the prescribed ones."""
        off = self._offsets
        x.copy(self._x)
        self._x.getArray()[off] = 0.0
        self.parts.mult(self._x, y)
        y.getArray()[off] = x.getArray(readonly=True)[off]

    def multTranspose(self, mat, x: PETSc.Vec, y: PETSc.Vec) -> None:   # noqa: N802
        self.mult(mat, x, y)       # J is symmetric

    def getDiagonal(self, mat, d: PETSc.Vec) -> None:   # noqa: N802
        blocks = self.node_blocks()
        d.getArray()[:] = np.einsum("nii->ni", blocks).ravel()

    # -- what the rest of petsoft uses ------------------------------------------------------------
    def node_blocks(self) -> np.ndarray:
        """(nowned, 3, 3) diagonal 3x3 blocks of J, prescribed components identity."""
        blocks = self.parts.diagonal_blocks(self._work)
        fixed = np.zeros(blocks.shape[0] * 3, dtype=bool)
        fixed[self._offsets] = True
        fixed = fixed.reshape(-1, 3)
        blocks[fixed[:, :, None] | fixed[:, None, :]] = 0.0
        node, comp = np.nonzero(fixed)
        blocks[node, comp, comp] = 1.0
        return blocks

    def norm(self, kind=PETSc.NormType.INFINITY) -> float:
        """An upper bound of ||J||_inf (element-wise absolute sums; for the round-off test of
        :func:`petsoft.solvers.convergence.stop_at_round_off`)."""
        sums = self.parts.abs_row_sums(self._work)
        sums.getArray()[self._offsets] = 1.0
        return sums.norm(PETSc.NormType.INFINITY)

    def create_mat(self) -> PETSc.Mat:
        """A MatShell (type python) of this operator, block size 3, symmetric."""
        v = self._work
        n, N = v.getLocalSize(), v.getSize()
        A = PETSc.Mat().createPython(((n, N), (n, N)), context=ShellContext(self),
                                     comm=self.system.comm)
        A.setBlockSize(3)
        A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        A.setUp()
        _SHELLS[id(A)] = A
        return A


#: The MatShells alive, destroyed at exit before PETSc finalises (see :class:`ShellContext`).
_SHELLS: weakref.WeakValueDictionary = weakref.WeakValueDictionary()


@atexit.register
def _destroy_shells() -> None:
    # registered after petsc4py's own exit handler, so it runs before PETSc is finalised
    for A in list(_SHELLS.values()):
        A.destroy()


class ShellContext:
    """The MatShell's context: a weak reference to its :class:`StepOperator`.

    The integrator owns the operator; the shell only borrows it. A shell left to petsc4py's
    garbage collection at exit crashed (SIGSEGV inside ``PetscFinalize``, petsc4py 3.18): the
    shells still alive at exit are destroyed before (``atexit``).
    """

    def __init__(self, operator: StepOperator):
        self._operator = weakref.ref(operator)

    @property
    def operator(self) -> StepOperator:
        op = self._operator()
        if op is None:
            raise RuntimeError("the matrix-free Jacobian's operator was freed before the MatShell")
        return op

    def update(self, *args) -> None:
        self.operator.update(*args)

    def mult(self, mat, x, y) -> None:
        self.operator.mult(mat, x, y)

    def multTranspose(self, mat, x, y) -> None:   # noqa: N802
        self.operator.mult(mat, x, y)

    def getDiagonal(self, mat, d) -> None:   # noqa: N802
        self.operator.getDiagonal(mat, d)


def requested(prefix: str) -> bool:
    """Whether the options ask for the MatShell Jacobian (``-<prefix>petsoft_jacobian shell``).

    Raises
    ------
    ValueError
        On a value other than ``assembled`` or ``shell``.
    """
    value = PETSc.Options(prefix).getString(OPTION, "assembled")
    if value not in CHOICES:
        raise ValueError(f"-{prefix}{OPTION} {value}: expected one of {', '.join(CHOICES)}")
    return value == "shell"


def fill_jacobian(system, state, a: float, b: float, c: float, P, velocity: float) -> None:
    """Linearise at ``state``: re-linearise a :class:`StepOperator` (itself or inside a
    MatShell), or assemble an ordinary matrix (``assemble_combination(..., reuse=True)``)."""
    if isinstance(P, StepOperator):
        P.update(state, a, b, c, velocity)
    elif P.getType() == PETSc.Mat.Type.PYTHON:
        P.getPythonContext().update(state, a, b, c, velocity)
    else:
        system.assemble_combination(state, a, b, c, P, velocity=velocity, reuse=True)
