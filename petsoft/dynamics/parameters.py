"""Differentiable parameters of a :class:`~petsoft.dynamics.system.DynamicSystem`.

The residual of the semi-discrete equations is

    r(q, v, a; p) = M a + grad W(q) + D v - f_g - f_t(t),   D = alpha M + beta K0,

with prescribed rows zeroed. Every material law of petsoft is linear in its Lame parameters
(mu, lambda) (linear, StVK, corotated, log-neo-Hookean), the mass and gravity are linear in the
density, so a parameter derivative of r is the residual itself evaluated with derivative
coefficients: per cell, dmu, dlambda, drho, each multiplying one of three *unit element vectors*

* ``E_mu = grad W_e(q; mu=1, lambda=0) + beta K0_e(1, 0) v_e (+ K_e(q; 1, 0) w_e)``,
* ``E_lambda`` likewise with (mu, lambda) = (0, 1),
* ``E_rho = M_e(rho=1)(a + alpha v)_e - V_e/4 g``,

(K0_e v_e is computed as the gradient of the *linear* law at v: the Hessian at the reference of
every law equals the linear one, checked by tests/test_sensitivity.py). The optional ``w`` term
is d/dp [K(q) w], needed by the semi-implicit step's derivative.

Parameter names (see :meth:`ParameterMap.names`):

* ``material.youngs_modulus``, ``material.poisson_ratio``, ``material.density`` and the same per
  region ``material.<region>.<key>``, with the meaning of :func:`petsoft.experiment.with_parameters`
  (a region material that does not override a key follows the default);
* the Rayleigh terms' coefficients (``damping.mass``, ``damping.stiffness``: the terms that
  contribute ``"rayleigh"``, :mod:`petsoft.dynamics.rayleigh`): d r/dc = B v, B the matrix the
  term's law names (the system's ``rayleigh_unit``);
* the body force's (the gravity terms, :class:`petsoft.physics.body_force.BodyForce`):
  ``gravity.acceleration.x|y|z`` and, where gravity is stated, ``gravity.tilt_a|b``: minus the
  load of the acceleration's derivative;
* ``viscoelastic.ratio``, ``viscoelastic.relaxation_time`` (the Maxwell branch): set in place by
  :meth:`~petsoft.dynamics.system.DynamicSystem.set_parameters` but **not differentiable**
  (:class:`ParameterDerivatives` refuses them: use finite differences);
* ``drag.linear``, ``drag.quadratic``, ``friction.dry``: r is linear in each, its derivative is
  the term's damping G per unit coefficient (:mod:`petsoft.dynamics.velocity`) at v, also when
  the coefficient is 0; for a step that linearises the term at v_lin (semi-implicit) it is
  G(v_lin) + dG/dv(v_lin) (v - v_lin);
* ``material.youngs_modulus#k``, k = 0..P-1: a *stiffness field*, a multiplier (1 at the start)
  of Young's modulus on the k-th of P cell groups. The groups are **Morton chunks**: the cells of
  the whole mesh sorted along the Morton (Z-order) curve of their centroids and cut into P
  contiguous runs of nearly equal cell counts (``np.array_split``), so each group is spatially
  compact and the grouping does not depend on the number of MPI ranks. P is fixed by
  :meth:`ParameterMap.define_groups` (the forward model uses 1 + the largest k it is asked for).
* ``boundary.compliance`` (m/Pa; when the model has elastic supports, all of one compliance):
  the supports' springs K_s = diag(A / c) are part of grad W and of K0, so
  d r/dc = -(A/c^2)(q + w + beta v) on the support dofs (:mod:`petsoft.physics.support`);
* ``collider.<i>.offset`` (m; a plane collider of a model with colliders): the plane moved by the
  offset along its normal; d r/ds = -e''(phi) n on the surface nodes in contact
  (:mod:`petsoft.physics.contact`; the penalty's curvature is piecewise constant, so the ``w``
  term has no offset derivative).
* the number keys of a package's term (``<table>.<key>``, :data:`petsoft.terms.PLUGINS`): its
  nodal term (:func:`petsoft.physics.model.package_terms`) sets them and gives d/dp of its
  gradient plus its Hessian applied to ``w`` (``add_parameter_derivative(name, u, out, w)``);
  such a term is outside K0, so the stiffness damping adds nothing to its derivative.
"""

from __future__ import annotations

import re

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.dynamics.velocity import NAMES as VELOCITY_NAMES
from petsoft.errors import ExperimentError
from petsoft.experiment import get_parameter, key_part
from petsoft.experiment.ranges import format_number, key_range
from petsoft.fem.element import cell_integrals
from petsoft.fem.kernels.scatter import scatter_add_vector
from petsoft.fem.regions import RegionResolver
from petsoft.mesh.ordering import cell_morton_order
from petsoft.physics.body_force import BodyForce
from petsoft.physics.loads import gravity_forces
from petsoft.physics.materials import cell_materials
from petsoft.physics.support import COMPLIANCE, shared_compliance
from petsoft.physics.term import ParametricTerm
from petsoft.physics.viscoelastic import NAMES as BRANCH_NAMES
from petsoft.physics.viscoelastic import check as check_branch
from petsoft.terms import PLUGINS, keys_of

MATERIAL_KEYS = ("youngs_modulus", "poisson_ratio", "density")
#: Parameters set_parameters changes but the residual derivatives do not cover: the Maxwell
#: branch's internal variable z is not part of the differentiated state.
VISCOELASTIC = BRANCH_NAMES
_KIND = {"youngs_modulus": "E", "poisson_ratio": "nu", "density": "rho"}
GROUP_PATTERN = re.compile(r"^material\.youngs_modulus#(\d+)$")


def morton_groups(points: np.ndarray, tets: np.ndarray, count: int) -> np.ndarray:
    """Group index (0..count-1) of every cell of a mesh (file numbering): Morton chunks."""
    order = cell_morton_order(points, tets)
    group = np.empty(len(tets), dtype=np.int64)
    for k, chunk in enumerate(np.array_split(order, count)):
        group[chunk] = k
    return group


class ParameterMap:
    """Current parameter values of a dynamic system and which cells each material name governs.

    Parameters
    ----------
    system : DynamicSystem
    """

    def __init__(self, system):
        self.system = system
        model = system.model
        exp = model.experiment
        dm = system.dmesh
        local = dm.cell_ids
        _, E, nu, rho = cell_materials(exp, model.resolver)
        self.E_base, self.nu, self.rho = E[local].copy(), nu[local].copy(), rho[local].copy()
        self.E_mult = np.ones(len(local))
        self.group = None
        self.ngroups = 0
        self.cells: dict[str, np.ndarray] = self._material_cells(exp, model.resolver)
        self.values = {n: float(self._current(n)) for n in self.cells}
        # the Rayleigh terms' coefficients (petsoft.dynamics.rayleigh)
        self.values.update(system.rayleigh.coef)
        for name, value in system.velocity_terms.coef.items():
            self.values[name] = float(value)
        #: the body force's parameters (the gravity terms, petsoft.physics.body_force)
        self.body = BodyForce.of(exp)
        self.values.update(self.body.parameters())
        # elastic supports and collider planes (petsoft.physics.support / contact)
        support, contact = system.elastic.support, system.elastic.contact
        #: parameter -> why it is not one of this system although its term is there
        self._unshared: dict[str, str] = {}
        if support is not None:
            try:
                shared_compliance(exp)
                self.values[COMPLIANCE] = support.compliance
            except ExperimentError as exc:
                self._unshared[COMPLIANCE] = str(exc)
        if contact is not None:
            self.values.update(contact.parameters())    # the planes' offsets
        # the nodal terms' parameters (petsoft.physics.term.ParametricTerm: the supports'
        # compliance when shared, the planes' offsets, the packages' terms' numbers):
        # name -> its term, which sets it and gives its derivative
        self.nodal = {n: t for t in system.elastic.nodal_terms
                      if isinstance(t, ParametricTerm) for n in t.parameters()
                      if n in self.values or t.kind in PLUGINS}
        #: the packages' terms (petsoft.terms.PLUGINS): their ranges are their keys'
        self.package = {n: t for n, t in self.nodal.items() if t.kind in PLUGINS}
        for name, t in self.package.items():
            self.values[name] = float(t.parameters()[name])
        # the Maxwell branch: settable in place, not differentiable (see VISCOELASTIC)
        branch = system.viscoelastic
        self.values.update(branch.parameters())

    def _material_cells(self, exp, resolver) -> dict[str, np.ndarray]:
        """Which local cells each material name governs: the logic of cell_materials, with a
        region that does not override a key following the default (as with_parameters does)."""
        local = self.system.dmesh.cell_ids
        last = np.full(len(resolver.mesh.tets), -1)
        regions = [n for n in exp.material if n != "default"]
        for i, name in enumerate(regions):
            last[resolver.cell_mask(name, key=f"material.{name}")] = i
        cells: dict[str, np.ndarray] = {}
        for key in MATERIAL_KEYS:
            default = last < 0
            for i, name in enumerate(regions):
                mine = last == i
                if key not in exp.material[name].overrides:
                    default |= mine
                cells[f"material.{key_part(name)}.{key}"] = mine[local]
            cells[f"material.{key}"] = default[local]
            # a [region.<name>] without a material table: setting it appends an override
            for name in exp.regions:
                if name not in exp.material:
                    mask = resolver.cell_mask(name, key=f"region.{name}")
                    cells[f"material.{key_part(name)}.{key}"] = mask[local]
        return cells

    def move_regions(self, experiment) -> None:
        """Take ``experiment``'s regions and material values in place: the same mesh, material
        tables and laws as the system's, its regions moved or resized (a sphere search's trial,
        :mod:`petsoft.diagnosis.reduced_trials`). Every cell's E, nu and density, the cells
        each material name governs and those names' values become what a system built for
        ``experiment`` holds (stiffness-field multipliers stay). The caller rebuilds the
        matrices (``DynamicSystem.set_parameters({})``). Collective; raises on every rank when a
        cell would change its material law (the element groups are per law)."""
        mesh = self.system.model.resolver.mesh
        resolver = RegionResolver(mesh, experiment.regions, experiment.source)
        law, E, nu, rho = cell_materials(experiment, resolver)
        local = self.system.dmesh.cell_ids
        same = all(bool(np.all(law[local][g.cells] == g.model))
                   for g in self.system.elastic.groups)
        if not self.system.comm.tompi4py().allreduce(same, op=MPI.LAND):
            raise ExperimentError(f"{experiment.source}: a moved region changes some cells' "
                                  "material law, which is not done in place: build the model")
        self.E_base, self.nu, self.rho = E[local].copy(), nu[local].copy(), rho[local].copy()
        self.cells = self._material_cells(experiment, resolver)
        self.values.update({n: float(self._current(n)) for n in self.cells})

    def _current(self, name: str) -> float:
        key = name.rsplit(".", 1)[1]
        arr = {"youngs_modulus": self.E_base, "poisson_ratio": self.nu, "density": self.rho}[key]
        mask = self.cells[name]
        local = arr[mask]
        value = local[0] if len(local) else np.nan
        # the value is uniform on the cells a name governs; ranks without such cells ask others
        vals = self.system.comm.tompi4py().allgather(value)
        good = [v for v in vals if np.isfinite(v)]
        return good[0] if good else get_default(self.system, name)

    # -- groups -----------------------------------------------------------------------------------
    def define_groups(self, count: int) -> list[str]:
        """Define the P = ``count`` Morton-chunk cell groups; returns their parameter names."""
        count = int(count)
        if count < 1:
            raise ExperimentError(f"a stiffness field needs at least 1 cell group, got {count}")
        mesh = self.system.dmesh.mesh
        if count > len(mesh.tets):
            raise ExperimentError(f"a stiffness field of {count} cell groups needs at least as "
                                  f"many cells; the mesh has {len(mesh.tets)}")
        if count != self.ngroups:
            self.group = morton_groups(mesh.points, mesh.tets, count)[self.system.dmesh.cell_ids]
            self.ngroups = count
            self.E_mult = np.ones(len(self.group))
            for k in range(count):
                self.values[f"material.youngs_modulus#{k}"] = 1.0
            for k in [n for n in self.values if GROUP_PATTERN.match(n)]:
                if int(GROUP_PATTERN.match(k).group(1)) >= count:
                    del self.values[k]
        return [f"material.youngs_modulus#{k}" for k in range(count)]

    def names(self) -> list[str]:
        """The differentiable names (set_parameters also takes :data:`VISCOELASTIC`)."""
        return [n for n in self.values if n not in VISCOELASTIC]

    def check(self, names, settable: bool = False) -> None:
        """Raise (on every rank: the check is deterministic) for a name not differentiable
        (with ``settable``: not settable; the viscoelastic names are settable only)."""
        valid = self.names()
        if settable:
            valid = valid + list(VISCOELASTIC)
        else:
            refuse_viscoelastic(names)
        for n in names:
            k = minimum_model(n)
            if k is not None and n not in valid:
                if n in self._unshared:
                    raise ExperimentError(self._unshared[n])
                m = format_number(k.minimum)
                raise ExperimentError(
                    f'"{n}": this system was built with every {k.key} = {m} ({k.at_minimum}), '
                    f"another model, which cannot be changed in place: set {k.key} > {m} in the "
                    "experiment (its starting value)")
            if n not in valid:
                m = GROUP_PATTERN.match(n)
                extra = (f" (stiffness field: call define_groups with more than {m.group(1)} "
                         "groups)") if m else ""
                raise ExperimentError(
                    f'"{n}" is not a differentiable parameter of this system{extra}; valid: '
                    + ", ".join(valid[:12]) + (", ..." if len(valid) > 12 else "")
                    + (" and material.youngs_modulus#k (stiffness field)" if not self.ngroups
                       else ""))

    def validate(self, values) -> None:
        """Raise for invalid values (on every rank: the values are the same everywhere, and a
        rank-local error in the Lame conversion would deadlock the others)."""
        for name, value in values.items():
            v = float(value)
            key = name.rsplit(".", 1)[-1]
            if name in VISCOELASTIC:
                check_branch(name, v)    # the branch's own ranges
                continue
            if GROUP_PATTERN.match(name):
                ok, valid = v > 0.0, "> 0 (a multiplier of Young's modulus)"
            elif key == "poisson_ratio":
                ok, valid = -1.0 < v < 0.5, "in (-1, 0.5)"
            elif key in ("youngs_modulus", "density"):
                ok, valid = v > 0.0, "> 0"
            elif (k := minimum_model(name)) is not None:
                m = format_number(k.minimum)
                ok, valid = v > k.minimum, (f"> {m} ({k.unit}; {k.key} = {m} is {k.at_minimum}, "
                                            "another model, and cannot be set in place)")
            elif name in self.package or name in self.system.rayleigh.coef:
                rng = declared_range(name)
                ok, valid = rng.contains(v), rng.text(key)
            else:
                ok, valid = np.isfinite(v), "finite"
            if not (ok and np.isfinite(v)):
                raise ExperimentError(f'parameter "{name}" = {v!r} is invalid: it must be '
                                      f"{valid}")

    # -- gravity -------------------------------------------------------------------------------
    def gravity(self) -> np.ndarray:
        """The acceleration the system uses (:meth:`BodyForce.acceleration`, m/s^2)."""
        return self.body.acceleration()

    # -- per-cell coefficients -----------------------------------------------------------------
    def E(self) -> np.ndarray:
        return self.E_base * self.E_mult

    def governed(self, name: str, names=()) -> np.ndarray:
        """Local cells whose value of a material name's key follows that name.

        A default name (``material.<key>``) does not govern the cells of a region whose own
        name for the same key is among ``names`` (set together, the region's value wins).
        """
        mask = self.cells[name]
        parts = name.split(".")
        if len(parts) == 2:
            key = parts[1]
            for other in names:
                if other != name and other.startswith("material.") and \
                        other.endswith("." + key) and other in self.cells:
                    mask = mask & ~self.cells[other]
        return mask

    def coefficients(self, name: str, names=()):
        """(dmu, dlam, drho) per local cell (arrays or None) of a material or group name."""
        E, nu = self.E(), self.nu
        m = GROUP_PATTERN.match(name)
        if m:
            dE = np.where(self.group == int(m.group(1)), self.E_base, 0.0)
        elif name.endswith("youngs_modulus"):
            dE = np.where(self.governed(name, names), self.E_mult, 0.0)
        elif name.endswith("poisson_ratio"):
            mask = self.governed(name, names)
            dmu = np.where(mask, -E / (2.0 * (1.0 + nu) ** 2), 0.0)
            dlam = np.where(mask, E * (1.0 + 2.0 * nu**2) / ((1.0 + nu) * (1.0 - 2.0 * nu)) ** 2,
                            0.0)
            return dmu, dlam, None
        else:
            return None, None, np.where(self.governed(name, names), 1.0, 0.0)
        return dE / (2.0 * (1.0 + nu)), dE * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), None

    def update(self, values: dict) -> None:
        """Set parameter values (material ones per cell; the caller rebuilds matrices)."""
        self.check(values, settable=True)
        self.validate(values)
        # defaults before regions: a region set together with the default keeps its own value
        for name, value in sorted(values.items(), key=lambda kv: kv[0].count(".")):
            value = float(value)
            self.values[name] = value
            m = GROUP_PATTERN.match(name)
            if m:
                self.E_mult[self.group == int(m.group(1))] = value
            elif name in self.nodal:
                self.nodal[name].set_parameter(name, value)
            elif name in self.body.values:
                self.body.set_parameter(name, value)
            elif name.startswith("material."):
                key = name.rsplit(".", 1)[1]
                arr = {"youngs_modulus": self.E_base, "poisson_ratio": self.nu,
                       "density": self.rho}[key]
                arr[self.governed(name, values)] = value


def declared_range(name: str):
    """The valid range of a term's parameter ``table.key`` (its key's declaration: a package's
    term's number, a Rayleigh coefficient)."""
    table, key = name.split(".")
    return key_range(next(k for k in keys_of(table) if k.key == key))


def minimum_model(name: str):
    """The key of a term's parameter ``table.key`` whose minimum is another model
    (:attr:`petsoft.terms.Key.at_minimum`: the supports' compliance, 0 = rigid), else None: its
    value set in place must exceed the minimum, and a system built at the minimum has no such
    parameter."""
    table, _, key = name.partition(".")
    return next((k for k in keys_of(table) if k.key == key and k.at_minimum), None)


def get_default(system, name: str) -> float:
    return float(get_parameter(system.model.experiment, name))


def refuse_viscoelastic(names) -> None:
    """Raise (on every rank) for Maxwell-branch parameters: their derivatives are not
    implemented (the branch's internal variable is not part of the differentiated state)."""
    bad = [n for n in names if n in VISCOELASTIC]
    if bad:
        raise ExperimentError(
            f'"{bad[0]}" is not differentiable: the viscoelastic branch\'s internal variable is '
            "not part of the sensitivities; use finite differences (--gradient fd in petsoft "
            "calibrate, ForwardModel.fd_jacobian in Python)")


class ParameterDerivatives:
    """Element-level evaluation of d r / d p (see the module docstring) for one state."""

    def __init__(self, system, q, v, a, w=None, k0x=None, v_lin=None):
        self.system = system
        s, dm = system, system.dmesh
        pm = s.parameters
        u, vl, al = dm.to_local(q), dm.to_local(v), dm.to_local(a)  # (nv, 3)
        wl = dm.to_local(w) if w is not None else None
        n = len(dm.cells)
        # the elastic term's own parameter derivatives (+ K w, + beta K0 v)
        self.E_mu, self.E_lam = s.elastic.lame_derivatives(u, wl, vl, s.beta)
        if k0x is not None:
            # a residual term K0 x (the viscoelastic branch's c K0 (q1 - z0)): K0_e x_e is the
            # linear law's gradient at x, i.e. the reference term's derivative at u = 0
            zero = np.zeros_like(u)
            extra = s.elastic.lame_derivatives(zero, None, dm.to_local(k0x), 1.0)
            self.E_mu += extra[0]
            self.E_lam += extra[1]
        # mass (consistent) and gravity (int N_a g dV) per unit density
        unit = cell_integrals(dm)
        y = (al + s.alpha * vl)[dm.cells]                       # (n, k, 3)
        Em = np.einsum("nab,nbi->nai", unit.mass, y)
        g = pm.gravity()
        Em -= unit.load[:, :, None] * g[None, None, :]
        # a velocity law proportional to the lumped mass (the dry friction) scales with rho
        yf = s.velocity_mass_local(vl, dm.to_local(v_lin) if v_lin is not None else None)
        if yf is not None:
            Em += unit.lumped[:, :, None] * yf[dm.cells]
        self.E_rho = Em.reshape(n, -1)
        self.v = v.copy()   # the caller may destroy its state vectors
        # nodal terms: d/dp of K_s (u + w) + beta K_s v (supports), of the contact gradient
        self.u = u
        self.support_state = u + (wl if wl is not None else 0.0) + s.beta * vl
        self.w = wl
        self.v_lin = v_lin.copy() if v_lin is not None else None

    def _global_vector(self, name: str, out: PETSc.Vec) -> None:
        s = self.system
        out.zeroEntries()
        if name in s.rayleigh.coef:
            s.rayleigh_unit(s.rayleigh.matrix_of(name), self.v, out)
        elif name in s.parameters.nodal:
            # a nodal term's parameter, on its nodes: a package's term d/dp (grad W(u) + H(u) w)
            # (outside K0: no beta v); a term of the reference stiffness (the supports),
            # linear in u, d/dp K_t (u + w + beta v); any other (the planes) d/dp grad W(u)
            t = s.parameters.nodal[name]
            local = np.zeros((s.dmesh.nvertices, 3))
            if t.kind in PLUGINS:
                t.add_parameter_derivative(name, self.u, local, self.w)
            elif t.in_reference:
                t.add_parameter_derivative(name, self.support_state, local)
            else:
                t.add_parameter_derivative(name, self.u, local)
            s.dmesh.add_to_global(local, out)
        elif name in VELOCITY_NAMES:
            lin = None
            if self.v_lin is not None:
                lin = self.v_lin.getArray(readonly=True).reshape(-1, 3)
            out.getArray().reshape(-1, 3)[:] = s.velocity_terms.unit_linearised(
                name, self.v.getArray(readonly=True).reshape(-1, 3), lin)
        else:
            # the body force's (gravity.*): minus the load of the acceleration's derivative
            # (the consistent load int rho N_a dV: the lumped mass only for 4-node tetrahedra)
            s.dmesh.add_to_global(-gravity_forces(s.dmesh, s.model.density,
                                                  s.parameters.body.derivative(name)), out)

    def vectors(self, names) -> list[PETSc.Vec]:
        refuse_viscoelastic(names)
        s, dm = self.system, self.system.dmesh
        out = []
        local = np.zeros(3 * dm.nvertices)
        for name in names:
            vec = s.create_vec()
            if name.startswith("material."):
                dmu, dlam, drho = s.parameters.coefficients(name, names)
                ev = np.zeros_like(self.E_mu)
                for coef, unit in ((dmu, self.E_mu), (dlam, self.E_lam), (drho, self.E_rho)):
                    if coef is not None:
                        ev += coef[:, None] * unit
                sel = np.flatnonzero(np.any(ev != 0.0, axis=1))
                local[:] = 0.0
                scatter_add_vector(np.ascontiguousarray(dm.cells[sel]),
                                   np.ascontiguousarray(ev[sel]), local)
                vec.zeroEntries()
                dm.add_to_global(local.reshape(-1, 3), vec)
            else:
                self._global_vector(name, vec)
            s.zero_prescribed(vec)
            out.append(vec)
        return out

    def contract(self, names, mu: PETSc.Vec) -> np.ndarray:
        """[d r / d p_j . mu for j], mu with zero prescribed entries (collective)."""
        refuse_viscoelastic(names)
        s, dm = self.system, self.system.dmesh
        mul = dm.to_local(mu)[dm.cells].reshape(len(dm.cells), -1)
        per_cell = {k: np.einsum("ni,ni->n", e, mul)
                    for k, e in (("mu", self.E_mu), ("lam", self.E_lam), ("rho", self.E_rho))}
        result = np.zeros(len(names))
        globals_ = []
        pm = s.parameters
        group_sums = None
        for j, name in enumerate(names):
            m = GROUP_PATTERN.match(name)
            if m:
                # a stiffness field: one bincount over the cells serves all its P names
                if group_sums is None:
                    nu = pm.nu
                    dE = pm.E_base * (per_cell["mu"] / (2.0 * (1.0 + nu)) + per_cell["lam"]
                                      * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)))
                    group_sums = np.bincount(pm.group, weights=dE, minlength=pm.ngroups)
                result[j] = group_sums[int(m.group(1))]
            elif name.startswith("material."):
                dmu, dlam, drho = s.parameters.coefficients(name, names)
                total = 0.0
                for coef, key in ((dmu, "mu"), (dlam, "lam"), (drho, "rho")):
                    if coef is not None:
                        total += float(coef @ per_cell[key])
                result[j] = total
            else:
                globals_.append(j)
        result = np.asarray(dm.comm.tompi4py().allreduce(result))
        if globals_:
            vec = s.create_vec()
            for j in globals_:
                self._global_vector(names[j], vec)
                s.zero_prescribed(vec)
                result[j] = vec.dot(mu)
            vec.destroy()
        return result

    def cell_sensitivity(self, mu: PETSc.Vec) -> np.ndarray:
        """(local cells, 2): d r / d E_cell . mu and d r / d rho_cell . mu, one term of the
        per-cell sensitivity maps to Young's modulus and to the density."""
        s, dm = self.system, self.system.dmesh
        pm = s.parameters
        mul = dm.to_local(mu)[dm.cells].reshape(len(dm.cells), -1)
        nu = pm.nu
        dmu, dlam = 1.0 / (2.0 * (1.0 + nu)), nu / ((1 + nu) * (1 - 2 * nu))
        out = np.empty((len(mul), 2))
        out[:, 0] = (dmu * np.einsum("ni,ni->n", self.E_mu, mul)
                     + dlam * np.einsum("ni,ni->n", self.E_lam, mul))
        out[:, 1] = np.einsum("ni,ni->n", self.E_rho, mul)
        return out
