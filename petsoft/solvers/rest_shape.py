"""Inverse statics: the rest shape X of a body captured in equilibrium at the shape x.

The mesh a user captures (a scan of a soft object sitting under gravity on its supports) is the
deformed shape x, not the stress-free rest shape. For given material parameters the rest
positions X solve

    R(X) = f_int(x; X) - f_grav(X) = 0      (free dofs),      X = x - d   (Dirichlet dofs),

with f_int_a = V(X) P(F) grad N_a(X), F = I + sum_a (x_a - X_a) (x) grad N_a(X), and the lumped
gravity f_grav_a = rho V(X) g / 4 (the density is that of the rest shape, as in the forward
model). This module owns that nonlinear solve (SNES Newton, load continuation in gravity) and its
Jacobian, derived per element (tet P1) from the forward kernels' forces f and Hessian H at the
same state: with G = sum_b dX_b (x) grad N_b,

    d grad N_a = -G^T grad N_a,    dV = V tr G,    dF = -F G,

so that

    dR_(a,i)/dX_(b,k) = f_(a,i) N_(b,k) - f_(b,i) N_(a,k) - sum_m H_(a,i),(b,m) F_(m,k)
                        - rho g_i V N_(b,k) / 4,

where N_(b,k) is component k of grad N_b. No new material code: any law of
:mod:`petsoft.fem.kernels.elastic` works. Tested by a Taylor test (tests/test_rest_shape.py).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from petsc4py import PETSc

from petsoft.errors import MeshError, PetsoftError, SolverError
from petsoft.fem.assembly import MatrixAssembler
from petsoft.fem.kernels import elastic as kernels
from petsoft.fem.kernels.scatter import scatter_add_vector
from petsoft.fem.kernels.tet import shape_gradients
from petsoft.solvers.convergence import outcome
from petsoft.solvers.options import (
    SolverOptions,
    own_options,
    scoped_defaults,
    user_has,
    with_options,
)


class RestShapeError(SolverError):
    """No rest shape was found: Newton diverged, or the load exceeds what the material carries."""


@dataclass
class RestShapeResult:
    """Rest positions of the local vertices and the solve's statistics."""

    points: np.ndarray                 # (nv, 3) local rest positions X
    load_steps: int = 0
    newton_iterations: int = 0
    retries: int = 0
    residual_norm: float = 0.0
    wall_time: float = 0.0
    history: list = field(default_factory=list)   # (load factor, [residual norms])


def element_residual_jacobian(model: str, X: np.ndarray, x: np.ndarray, mu, lam, rho,
                              g: np.ndarray, jacobian: bool = True):
    """Element residuals R_e (n, 12) and Jacobians dR_e/dX_e (n, 12, 12) of inverse statics.

    Parameters
    ----------
    model : str
        Material law (:data:`petsoft.fem.kernels.elastic.MODELS`).
    X, x : ndarray (n, 4, 3)
        Rest and captured positions of the element nodes.
    mu, lam, rho : ndarray (n,)
    g : ndarray (3,)
        Gravity acceleration.

    Raises
    ------
    PetsoftError
        A degenerate rest element (MeshError) or an inverted one (InvertedElementError).
    """
    dN, vol = shape_gradients(X)
    u = x - X
    grad, H = kernels.element_gradient_hessian(model, dN, vol, u, mu, lam, hessian=jacobian)
    n = len(X)
    fg = (rho * vol / 4.0)[:, None] * np.asarray(g, float)[None, :]          # (n, 3)
    R = grad - np.tile(fg, (1, 4))
    if not jacobian:
        return R, None
    f = grad.reshape(n, 4, 3)
    F = np.eye(3)[None] + np.einsum("nai,naj->nij", u, dN)
    J = (np.einsum("nai,nbk->naibk", f, dN) - np.einsum("nbi,nak->naibk", f, dN)
         - np.einsum("naibm,nmk->naibk", H.reshape(n, 4, 3, 4, 3), F))
    # gravity: every node a gets rho V g / 4, and dV/dX_(b,k) = V N_(b,k)
    J -= (rho * vol / 4.0)[:, None, None, None, None] * (
        np.asarray(g, float)[None, None, :, None, None] * dN[:, None, None, :, :])
    return R, J.reshape(n, 12, 12)


class RestShapeSolver:
    """Owns the SNES, Jacobian and work vectors of the inverse static problem of a model.

    Parameters
    ----------
    model : petsoft.physics.model.Model
        Built on the captured mesh (its reference points are the captured shape x). Gravity,
        the materials and fixed (zero-displacement) Dirichlet conditions are honoured; tractions,
        elastic supports, contact and non-zero prescribed displacements are refused.
    load_steps : int
        Equal increments of gravity (a failed one is retried with half the size).
    prefix : str
        Options prefix (default ``rest_shape_``): ``-rest_shape_snes_monitor``, ...
    monitor : callable(str), optional
    options : SolverOptions, optional
        The options (an experiment's ``[petsc]`` table) pushed under ``prefix`` while the SNES
        is set up and solves.
    """

    def __init__(self, model, load_steps: int = 1, prefix: str = "rest_shape_", monitor=None,
                 options: SolverOptions | None = None):
        self.model, self.monitor = model, monitor
        self.options = own_options(prefix, options)
        prefix = self.options.prefix
        self.load_steps = max(1, int(load_steps))
        exp = model.experiment
        self._refuse_unsupported(exp)
        dm = self.dmesh = model.dmesh
        self.term = model.elastic.term if hasattr(model.elastic, "term") else model.elastic
        self.g = np.asarray(exp.gravity.acceleration, float)
        self.x = np.array(dm.points, dtype=float)          # the captured shape (local)
        self.assembler = MatrixAssembler(dm, self.term.connectivities())
        self.J = self.assembler.create_matrix()
        self.J.setOption(PETSc.Mat.Option.SYMMETRIC, False)
        self.F = dm.create_global_vec()
        self.scale = 1.0
        self._failure = None          # (is a MeshError, message) of a failed evaluation
        self._norms: list[float] = []
        comm = dm.comm
        self.snes = snes = PETSc.SNES().create(comm=comm)
        snes.setOptionsPrefix(prefix)
        snes.setType(PETSc.SNES.Type.NEWTONLS)
        snes.setFunction(self._residual, self.F)
        snes.setJacobian(self._jacobian, self.J, self.J)
        snes.setTolerances(rtol=1e-12, atol=0.0, stol=0.0, max_it=40)
        snes.setMonitor(lambda s, it, norm: self._norms.append(float(norm)))
        ksp = snes.getKSP()
        pc = ksp.getPC()
        if comm.size == 1:
            ksp.setType(PETSc.KSP.Type.PREONLY)   # the Jacobian is not symmetric: a direct solve
            pc.setType(PETSc.PC.Type.LU)
        else:
            # In parallel, GMRES with block-Jacobi ILU. Both parallel direct solvers once hung
            # on 2 ranks after a diverged trial; the cause was a reference to the SNES held on
            # the failing rank only (see _collective), and with it fixed MUMPS and
            # SuperLU_dist run that failure test on 2 ranks too (-rest_shape_pc_type lu
            # -rest_shape_pc_factor_mat_solver_type mumps).
            ksp.setType(PETSc.KSP.Type.GMRES)
            ksp.setGMRESRestart(200)
            ksp.setTolerances(rtol=1e-12, atol=0.0, max_it=2000)
            pc.setType(PETSc.PC.Type.BJACOBI)
        # A full Newton step (basic): the residual norm is no merit function for this
        # non-symmetric problem, and backtracking on it crawled (40 steps of ~1 % on a cantilever
        # sagging a third of its length; basic: 6 iterations). A failed solve is retried with a
        # smaller gravity increment instead.
        with self.options.pushed():
            defaults = {} if user_has(prefix + "snes_linesearch_type") else {
                prefix + "snes_linesearch_type": "basic"}
            with scoped_defaults(**defaults):
                snes.setFromOptions()
        bc = model.dirichlet
        self._bc_values = bc.values(t=0.0)
        if np.any(self._bc_values != 0.0):
            raise PetsoftError(
                f"{exp.source}: [[boundary]] kind = \"prescribed\" with a non-zero displacement "
                "at t = 0: a rest shape needs the supports where they were captured (fixed, or "
                "prescribed zero at t = 0)")

    @staticmethod
    def _refuse_unsupported(exp) -> None:
        if exp.mesh.order != 1:
            raise PetsoftError(
                f"{exp.source}: [mesh] order = {exp.mesh.order}: the rest-shape solve is "
                "implemented for 4-node tetrahedra only (its Jacobian with respect to the "
                "reference shape is derived for the P1 element); use order = 1 (refine the mesh "
                "instead)")
        for i, b in enumerate(exp.boundaries):
            what = None
            if b.kind == "traction":
                what = "a traction"
            elif b.kind == "fixed" and getattr(b, "compliance", 0.0) > 0.0:
                what = "an elastic support (compliance > 0)"
            elif b.kind == "prescribed" and getattr(b, "series", None) is not None:
                what = "a measured input series"
            if what is not None:
                raise PetsoftError(
                    f"{exp.source}: boundary[{i}]: {what} is not supported by the rest-shape "
                    "solve (gravity, materials and fixed supports are); remove it or compute "
                    "the rest shape without it")
        if getattr(exp, "colliders", None):
            raise PetsoftError(f"{exp.source}: [[collider]] contact is not supported by the "
                               "rest-shape solve")

    # -- residual and Jacobian --------------------------------------------------------------------
    def _elements(self, X_local: np.ndarray, jacobian: bool):
        rho = self.model.density
        for grp in self.term.groups:
            conn = grp.conn
            R, J = element_residual_jacobian(grp.model, X_local[conn], self.x[conn], grp.mu,
                                             grp.lam, rho[grp.cells], self.scale * self.g,
                                             jacobian)
            yield grp, R, J

    def _collective(self, fn) -> bool:
        """Run ``fn`` on every rank; False on all ranks when some rank hit a PetsoftError, whose
        kind and message (the lowest failing rank's) every rank then keeps in ``_failure``.

        Only (is a MeshError, message) is kept, not the exception: its traceback's frames
        (the SNES callback's, holding the SNES and its vectors) existed on the failing rank
        only, so that destroying the solver there only dropped a reference while the other
        rank destroyed the SNES for real; with a parallel direct solver (MUMPS, whose
        destruction is collective) 2 ranks hung in ``destroy`` (tests/test_rest_shape.py)."""
        failure = None
        try:
            fn()
        except PetsoftError as err:
            failure = (isinstance(err, MeshError), str(err))
        failures = [f for f in self.dmesh.comm.tompi4py().allgather(failure) if f is not None]
        if failures:
            self._failure = failures[0]
        return not failures

    def residual_local(self, X_local: np.ndarray) -> np.ndarray:
        """(nv, 3) local residual contributions (before summation over ranks)."""
        out = np.zeros(3 * self.dmesh.nvertices)
        for grp, R, _ in self._elements(X_local, jacobian=False):
            scatter_add_vector(grp.conn, R.reshape(-1, 4, 3), out)
        return out.reshape(-1, 3)

    def _residual(self, snes, X, F):
        X_local = self.dmesh.to_local(X)
        holder = {}

        def work():
            holder["r"] = self.residual_local(X_local)

        F.zeroEntries()
        if not self._collective(work):
            F.set(np.inf)   # the line search shortens the step; SNES stops if it cannot
            return
        self.dmesh.add_to_global(holder["r"], F)
        self.model.dirichlet.zero_rows(F)

    def _jacobian(self, snes, X, J, P):
        X_local = self.dmesh.to_local(X)

        def work():
            self.assembler.begin()
            for grp, _, Je in self._elements(X_local, jacobian=True):
                self.assembler.add(grp.name, np.ascontiguousarray(Je), 0)

        if not self._collective(work):
            raise RestShapeError(f"rest shape: the Jacobian failed ({self._failure[1]})")
        self.assembler.finish(P)
        self.model.dirichlet.eliminate(P)

    # -- driver --------------------------------------------------------------------------------
    @with_options
    def solve(self, X0: np.ndarray | None = None) -> RestShapeResult:
        """Solve for the rest shape at full gravity; ``X0`` (local (nv, 3)) is the initial guess
        (default: the captured shape). Raises :class:`RestShapeError` with the residual history
        when no rest shape is found."""
        t0 = time.perf_counter()
        dm = self.dmesh
        X = dm.create_global_vec()
        dm.set_global_from_local(self.x if X0 is None else X0, X)
        fixed = self.x - self._bc_values
        result = RestShapeResult(points=None)
        done, increment, retries = 0.0, 1.0 / self.load_steps, 0
        self._done = 0.0
        while done < 1.0 - 1e-12:
            self.scale = min(1.0, done + increment)
            backup = X.copy()
            self.model.dirichlet.set_values(X, fixed)
            self._norms, self._failure = [], None
            # absolute tolerance: round-off level of this increment's load
            self.snes.setTolerances(atol=1e-11 * self._force_scale())
            jacobian_failed = False
            try:
                self.snes.solve(None, X)
                converged = outcome(self.snes).converged
            except RestShapeError:
                converged = False
                jacobian_failed = True
            its = self.snes.getIterationNumber()
            if not converged and self._stalled_converged(X):
                converged = True
            norms = list(self._norms)
            result.history.append((self.scale, norms))
            if not converged:
                retries += 1
                backup.copy(X)
                if retries > 6:
                    X.destroy()
                    backup.destroy()
                    raise RestShapeError(self._failure_message(result, jacobian_failed))
                increment *= 0.5
                self._say(f"rest shape: gravity factor {self.scale:.4g}: "
                          f"{self._reason_text(jacobian_failed)}; retrying with increment "
                          f"{increment:.4g}")
                continue
            backup.destroy()
            done = self._done = self.scale
            result.load_steps += 1
            result.newton_iterations += its
            self._say(f"rest shape: gravity factor {self.scale:.4g}: {its} Newton iterations, "
                      f"|R| {norms[0] if norms else 0:.3e} -> {norms[-1] if norms else 0:.3e}")
        result.retries = retries
        result.residual_norm = self._norms[-1] if self._norms else 0.0
        result.points = dm.to_local(X)
        result.wall_time = time.perf_counter() - t0
        X.destroy()
        return result

    def _stalled_converged(self, X) -> bool:
        """A Newton solve that stops at the round-off floor of the residual has converged."""
        if not self._norms or not np.isfinite(self._norms[-1]):
            return False
        scale = max(self._force_scale(), 1e-300)
        return self._norms[-1] <= 1e-9 * scale

    def _force_scale(self) -> float:
        """Norm of the nodal gravity load at the current factor (the residual's scale)."""
        if getattr(self, "_gravity_norm", None) is None:
            f = self.dmesh.create_global_vec()
            scale, self.scale = self.scale, 1.0
            captured = self.dmesh.create_global_vec()
            self.dmesh.set_global_from_local(self.x, captured)
            self._residual(None, captured, f)   # R(x) = -f_grav, as f_int(x; x) = 0
            self.scale = scale
            captured.destroy()
            self._gravity_norm = f.norm()
            f.destroy()
        return abs(self.scale) * self._gravity_norm

    def _reason_text(self, jacobian_failed: bool) -> str:
        if self._failure is not None and self._failure[0]:
            # shape_gradients' wording is about input meshes; here it is a Newton trial
            return "a trial rest shape had an inverted or degenerate element (volume <= 0)"
        if self._failure is not None:
            return self._failure[1]
        return "Jacobian failed" if jacobian_failed else f"SNES {outcome(self.snes).reason}"

    def _failure_message(self, result: RestShapeResult, jacobian_failed: bool) -> str:
        lines = []
        for factor, norms in result.history[-4:]:
            seq = ", ".join(f"{v:.3e}" for v in norms[:12])
            more = " ..." if len(norms) > 12 else ""
            lines.append(f"  gravity factor {factor:.4g}: |R| = {seq}{more}")
        reached = self._done
        return ("no rest shape found: Newton on the inverse static equations f_int(x; X) = "
                f"f_gravity(X) did not converge ({self._reason_text(jacobian_failed)}); the last "
                "attempts' residual histories:\n" + "\n".join(lines) + "\n"
                f"Either the captured shape cannot be an equilibrium of this material under "
                f"this load (the load exceeds what the material carries: the rest shape would "
                f"have to be inverted or infinitely stretched; last fully solved gravity "
                f"factor {reached:.4g}), or the Young's modulus is too small for it: check "
                "the material's youngs_modulus and density, the gravity and the supports, or "
                "try more load steps (-rest_shape_snes_max_it, --load-steps)")

    def _say(self, line: str) -> None:
        if self.monitor is not None and self.dmesh.comm.rank == 0:
            self.monitor(line)

    def destroy(self) -> None:
        self.snes.cancelMonitor()    # the monitor's closure holds self: break the cycle
        for obj in ("snes", "J", "F"):
            getattr(self, obj).destroy()
        # drop the model (its DM and vectors) now, not at some later garbage collection
        # that need not happen at the same moment on every rank
        self.model = self.dmesh = self.term = self.assembler = None
