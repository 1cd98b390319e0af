"""Quasistatic equilibrium: Newton (SNES) on the residual, or minimisation (TAO) of the energy.

Both solve  grad W(u) = f_ext  with Dirichlet conditions, for the potential
Pi(u) = W(u) - f_ext . u. Loads and prescribed displacements are applied in ``load_steps`` equal
increments; a failed increment is retried with half the size. Before each increment the change of
prescribed displacements is spread into the body by one linear solve with the current tangent
(a lifting), so that Newton never starts from a configuration with a boundary layer of crushed
elements.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.errors import InvertedElementError, SolverError, without_frames
from petsoft.fem.assembly import MatrixAssembler
from petsoft.solvers.convergence import check_converged, outcome
from petsoft.solvers.linear import linear_defaults
from petsoft.solvers.options import (
    SolverOptions,
    own_options,
    scoped_defaults,
    user_has,
    with_options,
)

STALL_RTOL = 1e-8  # a stalled solve whose gradient fell this much is converged (round-off)


@dataclass
class StaticResult:
    """Displacement and solver statistics of a quasistatic solve."""

    displacement: PETSc.Vec
    load_steps: int = 0
    newton_iterations: int = 0
    linear_iterations: int = 0
    retries: int = 0
    wall_time: float = 0.0
    history: list = field(default_factory=list)


class StaticSolver:
    """Owns the SNES or TAO, the tangent matrix and the work vectors of a quasistatic model.

    Parameters
    ----------
    model : petsoft.physics.model.Model
    method : {"snes", "tao"}
        Newton on the residual with line search, or minimisation of the potential energy.
    load_steps : int
        Number of equal load increments (>= 1).
    prefix : str
        Options prefix of the solver objects (the lifting solve's: ``<prefix>lift_``).
    options : SolverOptions, optional
        The options (an experiment's ``[petsc]`` table) pushed under ``prefix``, the lifting
        solve's among them, while the solvers are set up and solve.
    monitor : callable(str) or None
        Receives one progress line per load step (rank 0 prints it).
    """

    def __init__(self, model, method: str = "snes", load_steps: int = 1, prefix: str = "",
                 monitor=None, options: SolverOptions | None = None):
        if method not in ("snes", "tao"):
            raise ValueError(f"method must be 'snes' or 'tao', not {method!r}")
        self.model, self.method, self.load_steps = model, method, max(1, int(load_steps))
        self.monitor = monitor
        dm = model.dmesh
        self.dmesh = dm
        self.options = own_options(prefix, options)
        self.assembler = MatrixAssembler(dm, model.elastic.connectivities())
        self.J = self.assembler.create_matrix()
        self.J.setNearNullSpace(dm.rigid_body_modes())
        self.F = dm.create_global_vec()
        self.f = dm.create_global_vec()      # external forces at the current load factor
        self._g_local = np.zeros(3 * dm.nvertices)
        self.scale = 1.0
        self._bad_element = None
        self._create_solvers()

    @with_options
    def _create_solvers(self) -> None:
        """The SNES or TAO and the lifting KSP, set up with the options pushed."""
        dm, model, method, prefix = self.dmesh, self.model, self.method, self.options.prefix
        comm = dm.comm
        if method == "snes":
            self.snes = snes = PETSc.SNES().create(comm=comm)
            snes.setOptionsPrefix(prefix)
            snes.setType(PETSc.SNES.Type.NEWTONLS)
            snes.setFunction(self._residual, self.F)
            # The residual norm is a poor merit function for bending (the axial strain of a
            # linear prediction inflates it while the energy drops): cp minimises along the
            # Newton direction using the residual as the energy gradient.
            # (petsc4py 3.18 has no SNES.getLineSearch: the default goes in the options database,
            # where a user's -snes_linesearch_type still wins.)
            # Five secant iterations find the critical point along the Newton direction; one (the
            # default) took steps of 1% on the demo cantilever (112 vs 46 Newton iterations).
            # With collider contact the residual has a kink where nodes touch: cp's secant on it
            # crawls (regula falsi pinned at the far end: steps of 0.1% on a cantilever sagging
            # onto a plane, 50+ iterations and failed increments), l2 took 4-5 (measured).
            contact = model.elastic.contact is not None
            line_search = {prefix + "snes_linesearch_type": "l2" if contact else "cp",
                           prefix + "snes_linesearch_max_it": "5"}
            if user_has(prefix + "snes_linesearch_type"):
                line_search = {}
            snes.setJacobian(self._jacobian, self.J, self.J)
            snes.setTolerances(rtol=1e-10, atol=0.0, stol=0.0, max_it=50)
            self.ksp = snes.getKSP()
            linear_defaults(self.ksp, dofs=self.F.getSize(), order=dm.order)
            with scoped_defaults(**line_search):
                snes.setFromOptions()
        else:
            self.tao = tao = PETSc.TAO().create(comm=comm)
            tao.setOptionsPrefix(prefix)
            tao.setType(PETSc.TAO.Type.NLS)
            tao.setObjectiveGradient(self._objective_gradient, self.F.duplicate())
            tao.setHessian(self._hessian, self.J, self.J)
            tao.setTolerances(gatol=0.0, grtol=0.0, gttol=1e-10)
            tao.setMaximumIterations(50)
            self.ksp = tao.getKSP()
            linear_defaults(self.ksp, dofs=self.F.getSize(), order=dm.order)
            tao.setFromOptions()
        self.lift_ksp = PETSc.KSP().create(comm=comm)
        self.lift_ksp.setOptionsPrefix(prefix + "lift_")
        linear_defaults(self.lift_ksp, dofs=self.F.getSize(), order=dm.order)
        self.lift_ksp.setOperators(self.J, self.J)
        self.lift_ksp.setFromOptions()

    # -- callbacks (keep PETSc's signatures, stay thin) -----------------------------------------
    def _local_state(self, x: PETSc.Vec) -> np.ndarray:
        return self.dmesh.to_local(x)

    def _gradient(self, x: PETSc.Vec, out: PETSc.Vec, assemble: bool = False,
                  prescribed_rows: bool = False) -> bool:
        """out = grad W(x) - f, prescribed rows zero. False if an element inverted (any rank)."""
        u = self._local_state(x)
        self._g_local[:] = 0.0
        ok = True
        try:
            self.model.elastic.add_gradient(u, self._g_local,
                                            self.assembler if assemble else None)
        except InvertedElementError as err:
            self._bad_element = without_frames(err)
            ok = False
        ok = bool(self.dmesh.comm.tompi4py().allreduce(ok, op=MPI.LAND))
        out.zeroEntries()
        if not ok:
            bad = self._bad_element
            found = [e for e in self.dmesh.comm.tompi4py().allgather(
                None if bad is None else (bad.element, bad.jacobian)) if e is not None]
            self._bad_element = InvertedElementError(*found[0])
            out.set(np.inf)
            return False
        self.dmesh.add_to_global(self._g_local.reshape(-1, 3), out)
        out.axpy(-1.0, self.f)
        if not prescribed_rows:  # with them, the rows hold the support reactions
            self.model.dirichlet.zero_rows(out)
        return True

    def _residual(self, snes, x, F):
        # An inverted element leaves F = inf (petsc4py 3.18 has no setFunctionDomainError): the
        # line search then shortens the step, or SNES stops with a non-finite norm, and the load
        # increment is retried smaller.
        self._gradient(x, F)

    def _collective_hessian(self, x) -> None:
        """Element tangents into the assembler; an inversion on any rank raises on all ranks
        (raising on one rank only would leave the others in the next collective)."""
        u = self._local_state(x)
        self.assembler.begin()
        local = None
        try:
            self.model.elastic.add_hessian(u, self.assembler)
        except InvertedElementError as err:
            local = (err.element, err.jacobian)
        found = [e for e in self.dmesh.comm.tompi4py().allgather(local) if e is not None]
        if found:
            raise InvertedElementError(*found[0])

    def _assemble_tangent(self, x, P) -> None:
        self._collective_hessian(x)
        self.assembler.finish(P)
        self.model.dirichlet.eliminate(P)

    def _jacobian(self, snes, x, J, P):
        self._assemble_tangent(x, P)

    def _objective_gradient(self, tao, x, G):
        if not self._gradient(x, G):
            return np.inf
        u = self._local_state(x)
        energy = self.dmesh.allreduce_sum(self.model.elastic.energy(u))
        return energy - self.f.dot(x)

    def _hessian(self, tao, x, H, P):
        self._assemble_tangent(x, P)

    # -- driver ----------------------------------------------------------------------------------
    def _lift(self, x: PETSc.Vec, target: np.ndarray) -> int:
        """Move prescribed dofs to ``target`` and spread the change with the current tangent."""
        bc = self.model.dirichlet
        if bc.count == 0:
            return 0
        delta = x.duplicate()
        delta.zeroEntries()
        current = self.dmesh.to_local(x)
        bc.set_values(delta, target - current)
        if delta.norm(PETSc.NormType.INFINITY) == 0.0:
            return 0
        self._assemble_unconstrained(x)
        rhs = x.duplicate()
        rhs.zeroEntries()
        self.J.zeroRowsColumns(bc.global_rows, 1.0, delta, rhs)
        y = x.duplicate()
        self.lift_ksp.solve(rhs, y)
        check_converged(self.lift_ksp, "the lifting solve of the prescribed displacements")
        x.axpy(1.0, y)
        return self.lift_ksp.getIterationNumber()

    def _assemble_unconstrained(self, x) -> None:
        self._collective_hessian(x)
        self.assembler.finish(self.J)

    @with_options
    def solve(self, x: PETSc.Vec | None = None) -> StaticResult:
        """Solve for the equilibrium at full load; returns the displacement and statistics."""
        t0 = time.perf_counter()
        if x is None:
            x = self.dmesh.create_global_vec()
            x.zeroEntries()
        result = StaticResult(displacement=x)
        target_full = self.model.dirichlet.values(t=0.0)
        done, increment = 0.0, 1.0 / self.load_steps
        retries = 0
        while done < 1.0 - 1e-12:
            scale = min(1.0, done + increment)
            backup = x.copy()
            self.f.zeroEntries()
            self.f.axpy(scale, self.model.external)
            try:
                lin = self._lift(x, scale * target_full)
                its, lits, reason = self._solve_increment(x)
            except InvertedElementError as err:
                # kept without the frames it holds (petsoft.errors.without_frames)
                its, lits, reason = 0, 0, "inverted element"
                self._bad_element = without_frames(err)
                lin = 0
            if isinstance(reason, str):
                retries += 1
                backup.copy(x)
                if retries > 8:
                    detail = f" ({self._bad_element})" if self._bad_element else ""
                    raise SolverError(
                        f"quasistatic {self.method.upper()} did not converge at load factor "
                        f"{scale:.4g}: {reason}{detail}; tried {retries} smaller increments. "
                        "Try more --load-steps, a different -ksp_type/-pc_type, or check the "
                        "boundary conditions fix the rigid-body motions")
                increment *= 0.5
                self._say(f"load factor {scale:.4g}: {reason}; retrying with increment "
                          f"{increment:.4g}")
                continue
            # Iterative solves leave round-off on the prescribed dofs: re-impose them exactly.
            self.model.dirichlet.set_values(x, scale * target_full)
            done = scale
            result.load_steps += 1
            result.newton_iterations += its
            result.linear_iterations += lits + lin
            result.history.append((scale, its, lits))
            # what is left, at the pace of the load so far (later steps bend further: roughly)
            left = (time.perf_counter() - t0) / done * (1.0 - done)
            self._say(f"load factor {scale:.4g}: {its} Newton iterations, {lits} linear "
                      f"iterations, |u|max = {x.norm(PETSc.NormType.INFINITY):.6g} m"
                      + (f"; ~{left:.0f} s left" if done < 1.0 - 1e-12 else ""))
        result.retries = retries
        result.wall_time = time.perf_counter() - t0
        return result

    def _solve_increment(self, x: PETSc.Vec):
        """One load increment; returns (Newton its, linear its, positive reason or message)."""
        self._bad_element = None
        work = self.F.duplicate()
        # The force scale of the increment: loads and support reactions.
        scale = work.norm() if self._gradient(x, work, prescribed_rows=True) else np.inf
        scale = max(scale, self.f.norm())
        if self.method == "snes":
            self.snes.solve(None, x)
            done = outcome(self.snes)
            lits = self.snes.getLinearSolveIterations()
        else:
            self.tao.setSolution(x)
            self.tao.solve(x)
            done = outcome(self.tao)
            lits = self.ksp.getIterationNumber()  # TAO reports no total; this is the last solve
        its, converged = done.iterations, done.converged
        if not converged and self._bad_element is None:
            # A solver that stalls only because its relative tolerance lies below the round-off
            # floor of the gradient (an increment solved exactly by the first Newton step) has
            # converged: accept it when the gradient is below STALL_RTOL times the force scale.
            converged = self._gradient(x, work) and work.norm() <= STALL_RTOL * scale
        work.destroy()
        if not converged:
            why = f" ({self._bad_element})" if self._bad_element is not None else ""
            return its, lits, f"{done.kind} {done.reason}{why}"
        return its, lits, max(done.code, 1)

    def _say(self, line: str) -> None:
        if self.monitor is not None and self.dmesh.comm.rank == 0:
            self.monitor(line)

    def destroy(self) -> None:
        for obj in ("snes", "tao", "lift_ksp", "J", "F", "f"):
            if hasattr(self, obj):
                getattr(self, obj).destroy()
