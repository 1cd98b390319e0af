"""The semi-discrete second-order system of an experiment: matrices, forces, energies.

``M q'' = -grad W(q) - D v + f_g + f_t(t)`` with

* M the consistent P1 mass matrix (or its row-sum lumping, for explicit integration),
* W the elastic energy (:class:`petsoft.physics.elastic.ElasticTerm`),
* D = alpha M + beta K0 Rayleigh damping, K0 the stiffness of the reference configuration (a
  constant, positive semi-definite matrix, so the damping power v^T D v is never negative and
  the energy balance is well defined also for nonlinear materials),
* f_g gravity (a potential: -f_g . q), f_t(t) surface tractions (expressions of x, y, z, t: their
  work is booked as external work),
* velocity-dependent forces ``[drag]`` (on the whole boundary surface) and ``[friction]``
  (:mod:`petsoft.dynamics.velocity`), added to D v by :meth:`DynamicSystem.damping_apply` (their
  work is dissipation) with their velocity Jacobian in :meth:`~DynamicSystem.assemble_combination`
  (``velocity``),
* Dirichlet conditions q_D = g(t) (fixed or prescribed expressions of x, y, z, t),
* optionally a Maxwell branch (standard linear solid, ``[viscoelastic]``): a force
  -g K0 (q - z) with an internal variable z, dz/dt = (q - z)/tau, that the implicit integrators
  include in their steps (:mod:`petsoft.physics.viscoelastic`, :attr:`DynamicSystem.viscoelastic`).

All matrices share one block-CSR pattern, so an integrator's Jacobian a M + b K(q) + c K0 is a
combination of value arrays handed to PETSc once.

For calibration the system's parameters (materials, damping, gravity, a stiffness field) can be
changed in place and differentiated: :meth:`DynamicSystem.parameter_names`,
:meth:`~DynamicSystem.set_parameters`, :meth:`~DynamicSystem.residual_parameter_derivatives`
(see :mod:`petsoft.dynamics.parameters`).
"""

from __future__ import annotations

import math

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.dynamics.initial import initial_from_expressions
from petsoft.dynamics.interfaces import SystemDefaults
from petsoft.dynamics.matrix_free import ContinuumElements
from petsoft.dynamics.rayleigh import RayleighDamping
from petsoft.dynamics.velocity import (
    VelocityDamping,
    VelocityTerms,
    coefficients_of,
    settings_of,
    where_of,
)
from petsoft.errors import InvertedElementError
from petsoft.experiment import get_parameter
from petsoft.fem.assembly import MatrixAssembler
from petsoft.fem.element import face_lumped_areas
from petsoft.fem.kernels.materials import lame_parameters
from petsoft.mesh.probes import embed
from petsoft.mesh.quadratic import face_nodes
from petsoft.mesh.topology import exterior_faces
from petsoft.physics.drag import face_pairs
from petsoft.physics.loads import (
    consistent_mass_matrices,
    gravity_forces,
    lumped_masses,
    traction_forces,
)
from petsoft.physics.model import load_mesh
from petsoft.physics.viscoelastic import MaxwellBranch
from petsoft.solvers.convergence import on_any_rank
from petsoft.solvers.linear import linear_defaults
from petsoft.solvers.options import SolverOptions
from petsoft.solvers.static import StaticSolver

#: The assembler's element set of single nodes: the velocity terms' 3x3 diagonal blocks.
NODE_SET = "__nodes__"
#: Attribute of a matrix filled by a reusable :meth:`DynamicSystem.assemble_combination`: its key.
_COMBINATION = "petsoft_combination"


class DynamicSystem(VelocityDamping, SystemDefaults):
    """Owns the matrices and work vectors of the dynamic problem of a :class:`Model`.

    Parameters
    ----------
    model : petsoft.physics.model.Model
        Built by :func:`petsoft.physics.model.build_model` (its ``external`` vector is not used:
        loads are
        rebuilt here split into gravity and time-dependent tractions).
    damping_mass, damping_stiffness : float
        Rayleigh alpha (1/s) and beta (s), when ``rayleigh`` is not given.
    rayleigh : RayleighDamping, optional
        The Rayleigh terms' coefficients (:mod:`petsoft.dynamics.rayleigh`; an experiment's:
        ``RayleighDamping.of(experiment)``).
    """

    defined_by = "[material]"
    volume_cells = True
    element_orders = (1, 2)
    continuum_material = True

    def __init__(self, model, damping_mass: float = 0.0, damping_stiffness: float = 0.0, *,
                 rayleigh: RayleighDamping | None = None):
        self.model = model
        self._parameter_version = 0     # set_parameters counts: a reused Jacobian's key
        self._parameters = None         # the ParameterMap, built on first use
        self.K0 = None                  # the reference stiffness as a matrix, on first use
        dm = self.dmesh = model.dmesh
        self.comm = dm.comm
        self.elastic = model.elastic
        # the material part of jacobian_is_constant (fixed for the system's life; collective)
        self._linear_material = dm.allreduce_sum(
            sum(g.model != "linear" for g in self.elastic.groups)) == 0
        self.dirichlet = model.dirichlet
        #: the Rayleigh terms (set_parameters sets their coefficients in place)
        self.rayleigh = (rayleigh if rayleigh is not None
                         else RayleighDamping.of_matrices(damping_mass, damping_stiffness))
        self.lumped_kinetic = False  # explicit integrators switch to the lumped mass
        conns = dict(self.elastic.connectivities())
        conns[NODE_SET] = np.arange(dm.nvertices, dtype=np.int64)[:, None]
        self.assembler = MatrixAssembler(dm, conns)
        # the mass shares the pattern: its element matrices go through the elastic groups' names
        self.assembler.begin()
        mass_e = consistent_mass_matrices(dm, model.density)
        for group in self.elastic.groups:
            self.assembler.add(group.name, np.ascontiguousarray(mass_e[group.cells]))
        self.mass_values = self.assembler.values.copy()
        self.assembler.begin()
        self._add_reference_hessian()
        self.k0_values = self.assembler.values.copy()
        self.M = self._matrix_from(self.mass_values)
        self.lumped = dm.create_global_vec()
        self.lumped.zeroEntries()
        dm.add_to_global(np.repeat(lumped_masses(dm, model.density)[:, None], 3, axis=1),
                         self.lumped)
        self.gravity = dm.create_global_vec()
        self.gravity.zeroEntries()
        dm.add_to_global(gravity_forces(dm, model.density,
                                        model.experiment.gravity.acceleration), self.gravity)
        self._tractions = self._traction_setup()
        self._traction_cache = None
        self._g = np.zeros(3 * dm.nvertices)
        self._work = dm.create_global_vec()
        self._viscoelastic_setup()
        self._velocity_setup()

    def _velocity_setup(self) -> None:
        """The velocity laws on the owned nodes (rows of a global vector's array)."""
        dm, exp = self.dmesh, self.model.experiment
        lo, _ = self._work.getOwnershipRange()
        self._own_local = np.flatnonzero(dm.owned)
        self._own_pos = (dm.global_dof[self._own_local, 0] - lo) // 3
        nown = len(self._own_local)
        node_of = np.full(dm.nglobal_vertices, -1, dtype=np.int64)
        node_of[dm.vertex_ids[self._own_local]] = self._own_pos
        exterior = dm.exterior[0]
        nodes = face_nodes(dm.mesh, exterior)
        pairs = face_pairs(dm.mesh.points, exterior, node_of, nodes,
                           face_lumped_areas(dm.order, dm.mesh.points, nodes))
        # each law on the nodes its where selects: the owned rows, and the local vertices
        # (the density derivative's share, integrated per cell)
        where = where_of(exp, self.model.resolver)
        owned = {}
        for name, mask in where.items():
            owned[name] = np.ones(nown, dtype=bool)
            owned[name][self._own_pos] = mask[dm.vertex_ids[self._own_local]]
        self._where_local = {name: mask[dm.vertex_ids] for name, mask in where.items()}
        self.velocity_terms = VelocityTerms(nown, pairs, self._node_masses(),
                                            coefficients_of(exp), owned, settings_of(exp))
        self._v_last = np.zeros((nown, 3))

    def velocity_mass_local(self, v_local: np.ndarray, v_lin_local=None) -> np.ndarray | None:
        """(nv, 3) the mass-proportional velocity laws' damping per unit mass at the local
        vertices (:meth:`VelocityTerms.mass_linearised`; None when none acts): their share of
        the density derivative."""
        return self.velocity_terms.mass_linearised(v_local, v_lin_local, self._where_local)

    def _node_masses(self) -> np.ndarray:
        return self.lumped.getArray(readonly=True).reshape(-1, 3)[:, 0].copy()

    # -- matrices ---------------------------------------------------------------------------
    def _add_reference_hessian(self) -> None:
        """K0 into the assembler: the elastic Hessian at q = 0 (plus the model's elastic
        supports: :meth:`petsoft.physics.potential.ModelPotential.add_reference_hessian`)."""
        self.elastic.add_reference_hessian(self.assembler)

    def _matrix_from(self, values: np.ndarray) -> PETSc.Mat:
        A = self.assembler.create_matrix()
        self.assembler.values[:] = values
        self.assembler.finish(A)
        return A

    def create_matrix(self) -> PETSc.Mat:
        """A new matrix with the system's pattern (for Jacobians)."""
        return self.assembler.create_matrix()

    @property
    def jacobian_is_constant(self) -> bool:
        """Whether :meth:`assemble_combination` depends on its coefficients only: a linear
        material, no state-dependent nodal term (contact, a package's term: those outside K0),
        no quadratic drag or dry friction (same on every rank)."""
        return (self._linear_material
                and all(t.in_reference for t in self.elastic.nodal_terms)
                and not self.velocity_terms.nonlinear)

    def assemble_combination(self, q: PETSc.Vec | None, a_mass: float, b_tangent: float,
                             c_reference: float, out: PETSc.Mat,
                             eliminate: bool = True, velocity: float = 0.0,
                             reuse: bool = False) -> PETSc.Mat:
        """out = a M + b K(q) + c K0 + velocity dG/dv (the caller folds the Rayleigh
        coefficients into a and c; ``velocity`` is dv/dq of its scheme, and dG/dv, the drag and
        friction's velocity Jacobian, is taken at the velocity last passed to
        :meth:`damping_apply` or :meth:`set_velocity_state`).

        With ``eliminate``, prescribed rows and columns become identity (symmetric).

        With ``reuse`` and a constant Jacobian (:attr:`jacobian_is_constant`), ``out`` is left
        untouched when a ``reuse`` call with the same coefficients and parameters filled it
        last: its state does not change, so a solver keeps its factorisation (PETSc refactors
        only a changed matrix). The caller must not modify ``out`` itself in between; any call
        without ``reuse`` reassembles.
        """
        key = None
        if reuse and self.jacobian_is_constant:
            key = (a_mass, b_tangent, c_reference, velocity, eliminate, self._parameter_version)
            if out.getAttr(_COMBINATION) == key:
                return out
        out.setAttr(_COMBINATION, None)
        asm = self.assembler
        asm.begin()
        if b_tangent != 0.0:
            self.elastic.add_hessian(self.dmesh.to_local(q), asm)
            if b_tangent != 1.0:
                asm.values *= b_tangent
        if a_mass != 0.0:
            asm.values += a_mass * self.mass_values
        if c_reference != 0.0:
            asm.values += c_reference * self.k0_values
        if velocity != 0.0 and self.velocity_terms.active:
            blocks = np.zeros((self.dmesh.nvertices, 3, 3))
            blocks[self._own_local] = velocity * self.velocity_terms.blocks(self._v_last)[
                self._own_pos]
            asm.add(NODE_SET, blocks)
        asm.finish(out)
        if eliminate:
            self.dirichlet.eliminate(out)
        out.setAttr(_COMBINATION, key)
        return out

    @property
    def alpha(self) -> float:
        """Rayleigh alpha: the coefficient of M in D (1/s)."""
        return self.rayleigh.alpha

    @property
    def beta(self) -> float:
        """Rayleigh beta: the coefficient of K0 in D (s)."""
        return self.rayleigh.beta

    def rayleigh_unit(self, matrix: str, v: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = B v, B the ``matrix`` a Rayleigh term scales (:mod:`petsoft.dynamics.rayleigh`):
        M or K0 (the derivative of D v with respect to the term's coefficient)."""
        (self.M if matrix == "mass" else self.K0_matrix()).mult(v, out)
        return out

    def _linear_damping_apply(self, v: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = alpha M v + beta K0 v."""
        out.zeroEntries()
        if self.alpha == 0.0 and self.beta == 0.0:
            return out
        self.M.mult(v, out)
        out.scale(self.alpha)
        if self.beta != 0.0:
            self.K0_matrix().mult(v, self._work)
            out.axpy(self.beta, self._work)
        return out

    def damping_apply(self, v: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = D v + G(v) = alpha M v + beta K0 v + (minus the drag and friction forces).

        Remembers v: the velocity Jacobian of the next :meth:`assemble_combination` is taken
        there (the Newton iterate of the step, whose residual is evaluated first).
        """
        self._linear_damping_apply(v, out)
        vt = self.velocity_terms
        if vt.active:
            vl = v.getArray(readonly=True).reshape(-1, 3)
            self._v_last = vl.copy()
            out.getArray().reshape(-1, 3)[:] += vt.damping(vl)
        return out

    def set_velocity_state(self, v: PETSc.Vec) -> None:
        """The velocity at which :meth:`assemble_combination` linearises the velocity terms."""
        self._v_last = v.getArray(readonly=True).reshape(-1, 3).copy()

    # -- the interface integrators use (an analytic system can provide the same) -----------
    def create_vec(self) -> PETSc.Vec:
        return self.dmesh.create_global_vec()

    def near_nullspace(self):
        return self.dmesh.rigid_body_modes()

    def linear_defaults(self, ksp: PETSc.KSP) -> None:
        """petsoft's default linear solver for this system's size (:func:`petsoft.solvers.linear.
        linear_defaults`: direct when small, else CG + GAMG)."""
        linear_defaults(ksp, dofs=3 * self.dmesh.nglobal_vertices, order=self.dmesh.order)

    def apply_prescribed(self, vec: PETSc.Vec, t: float) -> None:
        """Set the prescribed entries of ``vec`` to the supports' displacement at t."""
        self.dirichlet.set_values(vec, self.prescribed(t))

    def zero_prescribed(self, vec: PETSc.Vec) -> None:
        self.dirichlet.zero_rows(vec)

    def prescribed_offsets(self, vec: PETSc.Vec) -> np.ndarray:
        return self.dirichlet.owned_offsets(vec)

    # -- forces and energies ----------------------------------------------------------------
    def internal_gradient(self, q: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = grad W(q) (all rows, including prescribed ones).

        Raises InvertedElementError on every rank when an element inverted on one: after the
        collective sum, which a rank that stopped at its own element left the others waiting in
        (a 2-rank chord whose iterate inverted an element never returned)."""
        if self.comm.getSize() == 1 and out.handle != q.handle:
            # one rank: the local vertices are the global vector's, in its order, so the
            # gradient goes straight into ``out`` (no scatters and copies: a tenth of a small
            # model's residual)
            g = out.getArray()
            g[:] = 0.0
            self.elastic.add_gradient(q.getArray(readonly=True).reshape(-1, 3), g)
            return out
        u = self.dmesh.to_local(q)
        self._g[:] = 0.0
        inverted = None
        try:
            self.elastic.add_gradient(u, self._g)
        except InvertedElementError as err:
            inverted = err
        out.zeroEntries()
        self.dmesh.add_to_global(self._g.reshape(-1, 3), out)
        if on_any_rank(self.comm, inverted is not None):
            raise inverted or InvertedElementError(
                -1, math.nan, "an element inverted on another rank (its message says which)")
        return out

    def elastic_energy(self, q: PETSc.Vec) -> float:
        """W(q), the elastic energy summed over the ranks.

        Raises InvertedElementError on every rank when an element inverted on one (as
        :meth:`internal_gradient`): the flag travels with the collective sum, which a rank
        that stopped at its own element would have left the others waiting in."""
        inverted = None
        try:
            local = self.elastic.energy(self.dmesh.to_local(q))
        except InvertedElementError as err:
            inverted, local = err, 0.0
        total = np.empty(2)
        self.comm.tompi4py().Allreduce(np.array([local, float(inverted is not None)]), total,
                                       op=MPI.SUM)
        if total[1] > 0.0:
            raise inverted or InvertedElementError(
                -1, math.nan, "an element inverted on another rank (its message says which)")
        return float(total[0])

    def kinetic_energy(self, v: PETSc.Vec) -> float:
        """1/2 v^T M v with the mass the integrator uses (lumped for explicit schemes)."""
        if self.lumped_kinetic:
            self._work.pointwiseMult(v, self.lumped)
        else:
            self.M.mult(v, self._work)
        return 0.5 * v.dot(self._work)

    def gravitational_energy(self, q: PETSc.Vec) -> float:
        return -self.gravity.dot(q)

    def _traction_setup(self):
        exp = self.model.experiment
        resolver = self.model.resolver
        out = []
        for i, b in enumerate(exp.boundaries):
            if b.kind != "traction":
                continue
            faces = resolver.faces(b.where, f"boundary[{i}].where")
            pts = self.dmesh.mesh.points[faces].reshape(-1, 3)
            out.append((faces, pts, b.value,
                        any("t" in e.variables for e in b.value)))
        return out

    @property
    def time_dependent_loads(self) -> bool:
        return any(dep for *_, dep in self._tractions)

    def tractions(self, t: float, out: PETSc.Vec) -> PETSc.Vec:
        """out = f_t(t), the nodal forces of the surface tractions at time t."""
        if self._traction_cache is not None and not self.time_dependent_loads:
            return self._traction_cache.copy(out)
        local = np.zeros((self.dmesh.nvertices, 3))
        for faces, pts, value, _ in self._tractions:
            tv = np.stack([e.evaluate_at(pts, t=t) for e in value], axis=1).reshape(-1, 3, 3)
            local += traction_forces(self.dmesh, faces, tv)
        out.zeroEntries()
        self.dmesh.add_to_global(local, out)
        if not self.time_dependent_loads:
            self._traction_cache = out.copy()
        return out

    def prescribed(self, t: float) -> np.ndarray:
        """Local (nv, 3) prescribed displacements at time t (zero where not prescribed)."""
        return self.dirichlet.values(t=t)

    @property
    def moving_boundary(self) -> bool:
        """Whether some prescribed displacement depends on time."""
        return self.dirichlet.time_dependent

    # -- parameters (calibration gradients; see petsoft.dynamics.parameters) ---------------------
    @property
    def parameters(self):
        """The :class:`~petsoft.dynamics.parameters.ParameterMap` (built on first use)."""
        if self._parameters is None:
            from petsoft.dynamics.parameters import ParameterMap

            self._parameters = ParameterMap(self)
        return self._parameters

    def parameter_names(self) -> list[str]:
        """Names :meth:`set_parameters` and :meth:`residual_parameter_derivatives` accept
        (:meth:`set_parameters` also takes ``viscoelastic.ratio`` and
        ``viscoelastic.relaxation_time``, which are not differentiable)."""
        return self.parameters.names()

    def define_stiffness_groups(self, count: int) -> list[str]:
        """Define a stiffness field of ``count`` Morton-chunk cell groups; returns its names
        ``material.youngs_modulus#k`` (multipliers of E, 1 at the start)."""
        return self.parameters.define_groups(count)

    def set_parameters(self, values: dict) -> None:
        """Change named parameters in place (no mesh rebuild): per-cell Lame parameters and
        density, then M, K0, the lumped masses and gravity; Rayleigh coefficients."""
        pm = self.parameters
        pm.update(values)
        self._parameter_version += 1
        for name in self.rayleigh.coef:
            self.rayleigh.coef[name] = pm.values[name]
        self._viscoelastic_parameters(pm.values)
        for name in self.velocity_terms.coef:
            self.velocity_terms.coef[name] = pm.values[name]
        mu, lam = lame_parameters(pm.E(), pm.nu)
        for group in self.elastic.groups:
            group.mu[:] = mu[group.cells]
            group.lam[:] = lam[group.cells]
        dm, model = self.dmesh, self.model
        model.density[:] = pm.rho
        acc = pm.gravity()
        self.assembler.begin()
        mass_e = consistent_mass_matrices(dm, model.density)
        for group in self.elastic.groups:
            self.assembler.add(group.name, np.ascontiguousarray(mass_e[group.cells]))
        self.mass_values = self.assembler.values.copy()
        self.assembler.finish(self.M)
        self.assembler.begin()
        self._add_reference_hessian()
        self.k0_values = self.assembler.values.copy()
        if self.K0 is not None:
            self.assembler.finish(self.K0)
        self.lumped.zeroEntries()
        dm.add_to_global(np.repeat(lumped_masses(dm, model.density)[:, None], 3, axis=1),
                         self.lumped)
        self.gravity.zeroEntries()
        dm.add_to_global(gravity_forces(dm, model.density, acc), self.gravity)
        self.velocity_terms.node_mass = self._node_masses()
        # the static solver's load (gravity + tractions at t = 0) follows
        self.gravity.copy(model.external)
        model.external.axpy(1.0, self.tractions(0.0, self._work))

    def K0_matrix(self) -> PETSc.Mat:
        """K0 (the reference stiffness) as an assembled matrix."""
        if self.K0 is None:
            self.K0 = self._matrix_from(self.k0_values)
        return self.K0

    def parameter_derivatives(self, q, v, a, w=None, k0x=None, v_lin=None):
        """Element-level d r/d p at (q, v, a) (+ d/dp [K(q) w], + d/dp [K0 k0x]) for many names
        at once: ``.vectors(names)`` gives the vectors, ``.contract(names, mu)`` their dots
        with mu. ``v_lin``: the velocity the step linearises the velocity terms at
        (semi-implicit)."""
        from petsoft.dynamics.parameters import ParameterDerivatives

        return ParameterDerivatives(self, q, v, a, w, k0x, v_lin)

    def residual_parameter_derivatives(self, names, q, v, a, t: float = 0.0,
                                       v_lin=None) -> list:
        """d/dp of r(q, v, a; p) = M a + grad W(q) + D v + G(v) - f_g - f_t(t), prescribed rows
        zeroed (tractions do not depend on parameters, so t is unused; ``v_lin``: see
        :meth:`parameter_derivatives`)."""
        self.parameters.check(names)
        return self.parameter_derivatives(q, v, a, v_lin=v_lin).vectors(list(names))

    # -- the viscoelastic (Maxwell) branch -------------------------------------------------------
    def _viscoelastic_setup(self) -> None:
        spec = self.model.experiment.viscoelastic
        #: the :class:`~petsoft.physics.viscoelastic.MaxwellBranch` (inactive for ratio 0)
        self.viscoelastic = MaxwellBranch(self, spec.ratio, spec.relaxation_time)

    def _viscoelastic_parameters(self, values: dict) -> None:
        """Follow the branch's parameters (set_parameters)."""
        self.viscoelastic.set_parameters(values)

    def viscoelastic_energy(self, q: PETSc.Vec) -> float:
        """The branch's stored energy 1/2 g (q - z)^T K0 (q - z) (0 without a branch)."""
        return self.viscoelastic.energy(q)

    def initial_state(self, monitor=None):
        """(q0, v0) from the model's ``[initial]``: its expressions, or the static equilibrium
        under gravity and the tractions at t = 0 (``from = "static"``, solved with the
        experiment's ``[petsc]`` options without prefix, as ``petsoft static``; progress lines
        to ``monitor``)."""
        exp = self.model.experiment
        init = exp.initial
        q0 = None
        if init.from_ == "static":
            solver = StaticSolver(self.model, monitor=monitor, options=SolverOptions("", exp.petsc))
            q0 = solver.solve().displacement.copy()
            solver.destroy()
        return initial_from_expressions(self, init, q0)

    # -- the node-wise solvers (petsoft.dynamics.matrix_free, nonlinear_gs) ----------------------
    def unassembled(self) -> ContinuumElements:
        """The step matrix as element matrices per set, unassembled."""
        return ContinuumElements(self)

    def node_graph(self) -> tuple[int, np.ndarray, np.ndarray]:
        """(N, src, dst): every pair of nodes that share a cell (file numbering; the same on
        every rank)."""
        cells = np.asarray(self.dmesh.mesh.cells)
        k = cells.shape[1]
        a, b = np.nonzero(~np.eye(k, dtype=bool))
        return (self.dmesh.nglobal_vertices, cells[:, a].ravel(), cells[:, b].ravel())

    def owned_nodes(self) -> np.ndarray:
        """(nowned,) the file numbers of the owned nodes, in the global vector's order."""
        dm = self.dmesh
        return dm.vertex_ids[:dm.nowned]   # owned local vertices come first

    @property
    def nodes_per_element(self) -> int:
        """The nodes of a cell (4 or 10): the most one element couples."""
        return int(np.asarray(self.dmesh.mesh.cells).shape[1])

    def locate_probes(self, probes, source: str = "probes"):
        """(connectivity, cells, weights): the cell holding each probe point and its
        barycentric weights (:func:`petsoft.mesh.probes.embed`)."""
        mesh = self.dmesh.mesh
        cells, weights = embed(mesh, probes, source=source)
        return mesh.cells, cells, weights

    @staticmethod
    def dof_count(experiment) -> int:
        """Unknowns of the model ``experiment`` describes (3 per node of its mesh, after
        ``refine`` and ``order``), read from its mesh without building the system."""
        return 3 * len(load_mesh(experiment).points)

    @staticmethod
    def body_sizes(experiment) -> dict:
        """Mass, exterior area, bounding-box diagonal and mean cell size (the cube root of the
        mean tet volume) of the experiment's mesh, with the default material's density."""
        mesh = load_mesh(experiment)
        pts = mesh.points
        p = pts[mesh.tets]
        vol = np.abs(np.linalg.det(p[:, 1:] - p[:, :1])) / 6.0
        faces, _ = exterior_faces(mesh.tets)
        q = pts[faces]
        area = 0.5 * np.linalg.norm(np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]), axis=1).sum()
        return {"mass": float(get_parameter(experiment, "material.density") * vol.sum()),
                "area": float(area), "cell": float(np.cbrt(np.mean(vol))),
                "length": float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) or 1.0}

    def destroy(self) -> None:
        self.viscoelastic.destroy()
        for obj in (self.M, self.K0, self.lumped, self.gravity, self._work):
            if obj is not None:
                obj.destroy()
