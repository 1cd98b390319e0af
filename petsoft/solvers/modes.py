"""Natural frequencies and mode shapes: the generalized eigenproblem K x = omega^2 M x (SLEPc).

K is the tangent stiffness at the undeformed reference state (for every material model it is the
linear-elastic stiffness there: loads, gravity and pre-stress are ignored) and M the consistent
P1 mass matrix. The problem is symmetric-definite (SLEPc's GHEP) and solved by Krylov-Schur with
shift-and-invert at a target shift sigma, by default a direct (MUMPS LU) factorization of
K - sigma M; the eigenvalues nearest sigma come first.

Dirichlet conditions (fixed and prescribed dofs alike, with value zero: a mode is a free
vibration about the supported state) are eliminated symmetrically: their rows and columns become
identity rows in K and zero rows in M. A constrained dof then belongs to an infinite eigenvalue
(K e_i = 1, M e_i = 0), which shift-and-invert maps to 0, the far end of the spectrum it
computes; it never shows up as a spurious low mode, and every finite eigenvector vanishes there.
B = M is then only semi-definite, which SLEPc's GHEP solver handles (its eigenvector
purification is left on).

Bodies that are not fully supported (no Dirichlet condition, or only rollers) have zero-frequency
rigid-body modes and a singular K, which a factorization at sigma = 0 cannot handle. Those modes
are known exactly: the combinations of the six rigid motions that vanish on every constrained dof.
They are computed directly (M-orthonormalised), reported first with eigenvalue 0, and deflated
from the Krylov-Schur subspace, which then only finds elastic modes; the factorization uses the
small negative shift sigma = -RIGID_SHIFT * trace(K) / trace(M), where K - sigma M is positive
definite. Other mechanisms (disconnected parts, hinges) are not detected: the factorization fails
or the eigenpairs come out inaccurate, and the error says so.

Every returned pair is checked: the relative residual ||K x - omega^2 M x|| / (omega^2 ||M x||)
must stay below max(1e-6, 100 tol), else a SolverError is raised.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from petsc4py import PETSc

from petsoft.dependencies import slepc
from petsoft.errors import PetsoftError, SolverError
from petsoft.fem.assembly import CHUNK, MatrixAssembler
from petsoft.io.progress import duration
from petsoft.physics.loads import consistent_mass_matrices
from petsoft.solvers.convergence import reason_name
from petsoft.solvers.options import SolverOptions, own_options

if TYPE_CHECKING:
    from slepc4py import SLEPc

# Shift (as a fraction of trace(K)/trace(M), an upper-end eigenvalue scale ~ c^2/h^2) used when
# rigid-body modes make K singular. It must lie well below the lowest elastic eigenvalue, or
# shift-and-invert crowds the wanted eigenvalues together and converges slowly: a cantilever's
# first bending eigenvalue is ~1e-6 of the scale on the test meshes, and bodies 100x more slender
# or meshes 10x finer still have it above ~1e-9. K - sigma M is then ill-conditioned (~1e10) in
# the rigid directions only, which are deflated and projected out of the elastic modes (their
# measured relative residuals stay ~1e-13).
RIGID_SHIFT = 1e-10
# A combination of rigid motions counts as unconstrained when less than this fraction of its
# (Euclidean) norm sits on constrained dofs: 0 up to round-off for a true zero-energy mode, while
# a single constrained vertex already holds ~1/N of a rigid motion's norm.
RIGID_TOL = 1e-12
DEFAULT_TOL = 1e-10


@dataclass
class ModesResult:
    """Natural frequencies and mode shapes, ascending.

    Attributes
    ----------
    eigenvalues : ndarray (n,)
        omega^2 in (rad/s)^2; exactly 0 for rigid-body modes.
    frequencies_hz : ndarray (n,)
        sqrt(max(omega^2, 0)) / (2 pi).
    modes : list of PETSc.Vec
        Global mode shapes, M-orthonormal (x_i^T M x_j = delta_ij), zero on constrained dofs.
    relative_errors : ndarray (n,)
        Relative residual ||K x - omega^2 M x|| / (|omega^2| ||M x||) of each pair (for rigid
        modes, omega^2 = 0, relative to the eigenvalue scale trace(K) / trace(M) instead).
    rigid_modes : int
        How many of the modes are rigid-body modes (the first ones).
    converged : int
        Eigenpairs SLEPc converged (can exceed the number requested).
    iterations : int
        Krylov-Schur restarts (outer iterations).
    shift : float
        The shift sigma of the spectral transformation.
    solver : dict
        Types of the EPS, ST, KSP, PC and factorization package used, and the tolerance.
    """

    eigenvalues: np.ndarray
    frequencies_hz: np.ndarray
    modes: list
    relative_errors: np.ndarray
    rigid_modes: int = 0
    converged: int = 0
    iterations: int = 0
    shift: float = 0.0
    solver: dict = field(default_factory=dict)

    def destroy(self) -> None:
        """Destroy the mode vectors."""
        for v in self.modes:
            v.destroy()
        self.modes = []


def assemble_operators(model) -> tuple[PETSc.Mat, PETSc.Mat, float]:
    """Stiffness and mass matrices with the Dirichlet dofs eliminated (all ranks call).

    Returns
    -------
    K, M : PETSc.Mat
        Constrained rows and columns are identity rows in K and zero in M. Both matrices come
        from the same DM, so they have the same layout. The caller destroys them.
    scale : float
        trace(K) / trace(M) before elimination: an eigenvalue scale (the upper end of the
        discrete spectrum, ~ c^2 / h^2).
    """
    dmesh = model.dmesh
    stiffness = MatrixAssembler(dmesh, model.elastic.connectivities())
    stiffness.begin()
    # At u = 0 the tangent of every material model is the linear-elastic stiffness.
    model.elastic.add_hessian(np.zeros((dmesh.nvertices, 3)), stiffness)
    K = stiffness.finish(stiffness.create_matrix())

    mass = MatrixAssembler(dmesh, {"mass": dmesh.cells})
    mass.begin()
    # chunk by chunk, so memory stays at CHUNK element matrices however large the mesh
    for start in range(0, len(dmesh.cells), CHUNK):
        stop = min(start + CHUNK, len(dmesh.cells))
        mass.add("mass", consistent_mass_matrices(dmesh, model.density, start, stop), start)
    M = mass.finish(mass.create_matrix())

    dK, dM = K.getDiagonal(), M.getDiagonal()
    scale = dK.sum() / dM.sum()
    dK.destroy()
    dM.destroy()
    model.dirichlet.eliminate(K, 1.0)
    model.dirichlet.eliminate(M, 0.0)
    return K, M, scale


def rigid_body_modes(model, M: PETSc.Mat) -> list[PETSc.Vec]:
    """The zero-energy rigid motions the Dirichlet conditions (and elastic supports) leave free,
    M-orthonormal.

    A combination R c of the six rigid motions (three translations, three rotations) is free when
    it vanishes on every constrained dof, i.e. when c is in the null space of the 6x6 Gram matrix
    of R restricted to those dofs. A fully clamped body has none, a free body six, a body on
    symmetry-plane rollers three (translations in the plane, rotation about its normal).

    Returns
    -------
    list of PETSc.Vec
        Global vectors, zero on constrained dofs, with x_i^T M x_j = delta_ij. The caller
        destroys them.
    """
    dmesh, bc = model.dmesh, model.dirichlet
    mpi = dmesh.comm.tompi4py()
    nullspace = dmesh.rigid_body_modes()
    R = [v.copy() for v in nullspace.getVecs()]
    nullspace.destroy()
    # Gram matrices: of the whole motions (H) and of their constrained parts (G).
    H = np.array([[a.dot(b) for b in R] for a in R])
    # elastic supports (petsoft.physics.support) hold the motions that stretch their springs:
    # their dofs count as constrained here (but stay free dofs of the eigenproblem)
    offsets = bc.owned_offsets(R[0])
    support = getattr(model.elastic, "support", None)
    if support is not None:
        dofs = dmesh.global_dof[support.nodes][support.areas > 0.0]
        offsets = np.concatenate([offsets, dofs - R[0].getOwnershipRange()[0]])
    B = np.stack([v.getArray(readonly=True)[offsets] for v in R], axis=1)
    # collider contact active at the reference (petsoft.physics.contact) holds the motions
    # along the normals of the penetrating nodes
    contact = getattr(model.elastic, "contact", None)
    if contact is not None:
        lo = R[0].getOwnershipRange()[0]
        dofs = dmesh.global_dof[contact.nodes] - lo                     # (n, 3)
        X = contact.positions(np.zeros((dmesh.nvertices, 3)))
        rows = []
        for c in contact.colliders:
            phi, n, _ = c.distance(X)
            inside = phi < 0.0
            rows.append(np.stack([np.einsum("pi,pi->p", v.getArray(readonly=True)[
                dofs[inside]], n[inside]) for v in R], axis=1))
        B = np.concatenate([B, *rows])
    G = mpi.allreduce(B.T @ B)
    # G c = mu H c: mu is the fraction of the motion R c on constrained dofs.
    L = np.linalg.cholesky(H)
    Linv = np.linalg.inv(L)
    mu, V = np.linalg.eigh(Linv @ G @ Linv.T)
    C = Linv.T @ V[:, mu < RIGID_TOL]
    free = []
    for c in C.T:
        z = R[0].duplicate()
        z.zeroEntries()
        z.maxpy(c, R)
        bc.zero_rows(z)      # already ~0 there; make it exact
        free.append(z)
    for v in R:
        v.destroy()
    if free:
        # M-orthonormalise: Z <- Z L^-T with Z^T M Z = L L^T.
        Mz = [M.createVecLeft() for _ in free]
        for z, w in zip(free, Mz, strict=True):
            M.mult(z, w)
        S = np.array([[a.dot(w) for w in Mz] for a in free])
        Tinv = np.linalg.inv(np.linalg.cholesky(0.5 * (S + S.T))).T
        basis = [free[0].duplicate() for _ in free]
        for j, y in enumerate(basis):
            y.zeroEntries()
            y.maxpy(Tinv[:, j], free)
        for v in free + Mz:
            v.destroy()
        free = basis
    return free


def _eps_defaults(eps: SLEPc.EPS, nev: int, target: float, prefix: str) -> None:
    """Petsoft's defaults: GHEP, Krylov-Schur, shift-and-invert with a direct solve."""
    SLEPc = slepc()
    eps.setOptionsPrefix(prefix)
    eps.setProblemType(SLEPc.EPS.ProblemType.GHEP)
    eps.setType(SLEPc.EPS.Type.KRYLOVSCHUR)
    eps.setDimensions(nev=nev)
    eps.setTolerances(tol=DEFAULT_TOL)
    eps.setTarget(target)
    eps.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
    st = eps.getST()
    st.setType(SLEPc.ST.Type.SINVERT)
    ksp = st.getKSP()
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.LU)
    if PETSc.Sys.hasExternalPackage("mumps"):
        pc.setFactorSolverType("mumps")


def _solver_info(eps: SLEPc.EPS) -> dict:
    st = eps.getST()
    ksp = st.getKSP()
    pc = ksp.getPC()
    tol, max_it = eps.getTolerances()
    info = {"eps_type": eps.getType(), "st_type": st.getType(), "ksp_type": ksp.getType(),
            "pc_type": pc.getType(), "tolerance": tol, "max_iterations": max_it}
    if pc.getType() in ("lu", "cholesky"):
        info["factor_solver_type"] = pc.getFactorSolverType()
    return info


#: Seconds between two progress lines of the eigensolver.
PROGRESS_SECONDS = 2.0


def _progress(eps: SLEPc.EPS, wanted: int, say, rank0: bool) -> None:
    """Progress lines of the Krylov-Schur iterations: converged pairs of ``wanted``, and the
    time left at the pace so far (the first line comes after the factorization of K - sigma M,
    which is most of a small problem's time)."""
    t0 = time.perf_counter()
    last = [t0]

    def cb(eps, its, nconv, eig, err):
        now = time.perf_counter()
        if not rank0 or now - last[0] < PROGRESS_SECONDS:
            return
        last[0] = now
        done = min(int(nconv), wanted)
        left = (f", ~{duration((now - t0) / done * (wanted - done))} left" if 0 < done < wanted
                else "")
        say(f"modes: Krylov-Schur iteration {its}: {done} of {wanted} eigenpairs converged "
            f"({duration(now - t0)}{left})")

    eps.setMonitor(cb)


def compute_modes(model, nmodes: int, *, target: float = 0.0, prefix: str = "",
                  monitor=None, options: SolverOptions | None = None) -> ModesResult:
    """The ``nmodes`` eigenpairs of K x = omega^2 M x nearest ``target`` (all ranks call).

    Parameters
    ----------
    model : petsoft.physics.model.Model
        Its stiffness at the reference state, consistent mass and Dirichlet conditions are used;
        loads are ignored.
    nmodes : int
        Number of modes wanted (>= 1, at most the number of unconstrained dofs).
    target : float, optional
        Shift sigma in (rad/s)^2; the default 0 gives the lowest modes. An ``-eps_target`` option
        (with ``prefix``) overrides it.
    prefix : str, optional
        Options prefix of the EPS (its ST, KSP and PC use ``prefix + "st_"``). Defaults set here
        (Krylov-Schur, shift-and-invert, preonly + LU with MUMPS, tol 1e-10) are overridden by
        the options database: ``-eps_type``, ``-eps_tol``, ``-eps_ncv``, ``-st_pc_type`` ...
    monitor : callable(str), optional
        Progress lines (rank 0): the factorization, then at most one line per
        :data:`PROGRESS_SECONDS` with the converged count and the time left at that pace.
    options : SolverOptions, optional
        The options (an experiment's ``[petsc]`` table) pushed under ``prefix`` while the EPS
        is set up and solves.

    Returns
    -------
    ModesResult
        Ascending by eigenvalue; the caller destroys it. When the conditions leave rigid-body
        motions free and the target is <= 0, those come first with eigenvalue exactly 0 (see the
        module docstring), and the rest are elastic modes; with a positive target only elastic
        modes (the nearest to it) are returned.

    Raises
    ------
    PetsoftError
        When ``nmodes`` is not between 1 and the number of unconstrained dofs.
    SolverError
        When fewer than the requested eigenpairs converge, or the factorization fails.
    """
    options = own_options(prefix, options)
    with options.pushed():
        return _compute_modes(model, nmodes, target, options.prefix, monitor)


def _compute_modes(model, nmodes: int, target: float, prefix: str, monitor) -> ModesResult:
    """compute_modes with its options pushed."""
    dmesh, bc = model.dmesh, model.dirichlet
    nfree = 3 * dmesh.nglobal_vertices - bc.count
    if not 1 <= int(nmodes) <= nfree:
        raise PetsoftError(f"modes: the number of modes must be between 1 and the number of "
                           f"unconstrained dofs ({nfree}), not {nmodes}")
    nmodes = int(nmodes)
    # imported here, not with the module: only the commands that compute modes need SLEPc
    SLEPc = slepc("natural frequencies (SLEPc's eigensolver)")
    K, M, scale = assemble_operators(model)
    rigid = rigid_body_modes(model, M)
    created = list(rigid)        # destroyed on error; handed to the result otherwise
    eps = SLEPc.EPS().create(comm=dmesh.comm)
    try:
        eps.setOperators(K, M)
        _eps_defaults(eps, nmodes, target, prefix)
        eps.setFromOptions()
        sigma = eps.getTarget()
        nrigid = 0
        if rigid:
            # Look for elastic modes in the M-complement of the exact rigid ones, which are
            # reported first when the target is at or below 0; a singular K cannot be factored
            # at sigma = 0, so move the shift just below 0.
            eps.setDeflationSpace(rigid)
            if sigma <= 0.0:
                nrigid = min(len(rigid), nmodes)
            if sigma == 0.0:
                sigma = -RIGID_SHIFT * scale
                eps.setTarget(sigma)
        nelastic = nmodes - nrigid
        values, vectors = [0.0] * nrigid, rigid[:nrigid]
        nconv = iterations = 0
        if nelastic > 0:
            eps.setDimensions(nev=nelastic)
            if monitor is not None:
                _progress(eps, nelastic, monitor, dmesh.comm.getRank() == 0)
            try:
                eps.solve()
            except PETSc.Error as exc:
                # 71: zero pivot, 76: MUMPS failed, 91: the (preonly) solve did not converge.
                hint = (f"; K - sigma M (sigma = {sigma:.6g}) is singular: the structure has a "
                        "mechanism the supports do not remove (disconnected parts?) or the target "
                        "sits on an eigenvalue; try a small negative -eps_target"
                        if exc.ierr in (71, 76, 91) else "")
                raise SolverError(f"modes: the eigensolver failed (PETSc error {exc.ierr}: "
                                  f"{str(exc).strip().splitlines()[-1].strip()}){hint}") from None
            nconv, iterations = eps.getConverged(), eps.getIterationNumber()
            if nconv < nelastic:
                raise SolverError(
                    f"modes: only {nconv} of {nelastic} eigenpairs converged in {iterations} "
                    f"iterations (reason {reason_name(eps)}, tolerance "
                    f"{eps.getTolerances()[0]:g}); raise -eps_max_it or -eps_ncv, or relax "
                    "-eps_tol")
            for i in range(nelastic):
                x = K.createVecRight()
                created.append(x)
                values.append(eps.getEigenpair(i, x).real)
                vectors.append(x)
        # The pairs nearest a positive target do not come in ascending order; rigid modes
        # (exactly 0) stay first.
        order = np.argsort(values, kind="stable")
        values = np.asarray(values, float)[order]
        vectors = [vectors[i] for i in order]
        _m_normalise(vectors[nrigid:], M, bc, rigid)
        errors = _relative_residuals(vectors, values, K, M, scale)
        solver = _solver_info(eps)
        accurate = max(1e-6, 100.0 * solver["tolerance"])
        if errors.max(initial=0.0) > accurate:
            raise SolverError(
                f"modes: the eigenpairs are inaccurate (relative residual "
                f"{errors.max():.2e} > {accurate:.0e}): K - sigma M (sigma = {sigma:.6g}) is "
                "nearly singular: the structure has a mechanism the supports do not remove "
                "(disconnected parts?), or -eps_target sits on an eigenvalue (try a small "
                "negative -eps_target)")
    except BaseException:
        for v in created:
            v.destroy()
        raise
    finally:
        eps.destroy()
        K.destroy()
        M.destroy()
    for v in rigid[nrigid:]:
        v.destroy()
    return ModesResult(values, np.sqrt(np.maximum(values, 0.0)) / (2.0 * np.pi), vectors,
                       errors, rigid_modes=nrigid, converged=nconv, iterations=iterations,
                       shift=float(sigma), solver=solver)


def _m_normalise(vectors, M: PETSc.Mat, bc, rigid=()) -> None:
    """Scale each vector to x^T M x = 1, exactly zero on constrained dofs, M-orthogonal to the
    rigid modes (purification re-applies the shifted inverse, which amplifies round-off in the
    rigid directions by 1 / |sigma|: remove it)."""
    if not vectors:
        return
    w = M.createVecLeft()
    for x in vectors:
        bc.zero_rows(x)      # the infinite-eigenvalue components, ~0 after purification
        for r in rigid:
            M.mult(r, w)
            x.axpy(-x.dot(w), r)
        M.mult(x, w)
        x.scale(1.0 / np.sqrt(x.dot(w)))
    w.destroy()


def _relative_residuals(vectors, values, K: PETSc.Mat, M: PETSc.Mat, scale: float) -> np.ndarray:
    """||K x - lambda M x|| / (|lambda| ||M x||) per pair; the eigenvalue scale replaces |lambda|
    below it (rigid modes, lambda = 0)."""
    out = np.zeros(len(vectors))
    if not vectors:
        return out
    kx, mx = K.createVecLeft(), M.createVecLeft()
    for i, (x, lam) in enumerate(zip(vectors, values, strict=True)):
        K.mult(x, kx)
        M.mult(x, mx)
        norm_mx = mx.norm()
        kx.axpy(-lam, mx)
        out[i] = kx.norm() / ((abs(lam) if lam != 0.0 else scale) * norm_mx)
    kx.destroy()
    mx.destroy()
    return out
