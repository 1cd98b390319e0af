"""Building a discrete model from an experiment: mesh, regions, materials, loads, conditions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from petsc4py import PETSc

from petsoft.errors import ExperimentError, PetsoftError
from petsoft.fem.boundary import DirichletConditions
from petsoft.fem.regions import RegionResolver
from petsoft.io.recording import read_input_series
from petsoft.mesh.distributed import DistributedMesh
from petsoft.mesh.quadratic import with_order
from petsoft.mesh.refine import refine_mesh
from petsoft.mesh.serial import box_mesh, read_mesh
from petsoft.physics.elastic import ElasticTerm
from petsoft.physics.loads import gravity_forces, traction_forces
from petsoft.physics.materials import cell_materials
from petsoft.physics.potential import ModelPotential
from petsoft.physics.term import NodalTerm, ParametricTerm
from petsoft.terms import builders, plugin_tables


def on_root(comm: PETSc.Comm, fn, *args):
    """Run ``fn`` on rank 0 and share its result; a user error there is raised on every rank."""
    mpi = comm.tompi4py()
    result, error = None, None
    if mpi.rank == 0:
        try:
            result = fn(*args)
        except PetsoftError as exc:
            error = exc
    error = mpi.bcast(error, root=0)
    if error is not None:
        raise error
    return result


def load_mesh(experiment):
    """The experiment's mesh (read or generated), validated; call on rank 0."""
    spec = experiment.mesh
    if spec.box is not None:
        size = [s * spec.scale for s in spec.box.size]
        mesh = box_mesh(size, spec.box.cells)
    else:
        # a tetra10 file keeps its own (possibly curved) edge nodes; refinement then splits the
        # corners' tetrahedra and puts the children's edge nodes at their midpoints
        mesh = read_mesh(spec.file, scale=spec.scale, order=spec.order)
    return with_order(refine_mesh(mesh, spec.refine), spec.order)


@dataclass
class Model:
    """The discrete quasistatic model of an experiment on a distributed mesh.

    Attributes
    ----------
    dmesh : DistributedMesh
    resolver : RegionResolver
    elastic : ModelPotential
        The potential terms: the elastic term (``elastic.term``), elastic supports
        (``elastic.support``) and collider contact (``elastic.contact``).
    density : ndarray (ne,)
        Density of each local cell.
    external : PETSc.Vec
        Global nodal external forces (gravity + tractions) at full load.
    dirichlet : DirichletConditions
    """

    experiment: object
    dmesh: DistributedMesh
    resolver: RegionResolver
    elastic: ElasticTerm
    density: np.ndarray
    external: PETSc.Vec
    dirichlet: DirichletConditions


def package_terms(experiment, dmesh, resolver, dirichlet) -> list:
    """The nodal terms of other packages' terms the experiment uses (:data:`petsoft.terms.
    PLUGINS`; a term whose table the experiment gives), each built by its package's ``build``
    and checked by :func:`check_package_term` (all ranks call)."""
    out = []
    tables = plugin_tables()
    for plugin in {id(p): p for t, p in tables.items() if t in experiment.terms}.values():
        t = plugin.build(experiment, dmesh, resolver, dirichlet)
        if t is not None:
            out.append(check_package_term(plugin, t))
    return out


def check_package_term(plugin, t):
    """``t``, what ``plugin``'s build returned, if the system can use it; a PetsoftError
    naming the package says why not."""
    what = f"term {plugin.term.name!r} of package {plugin.package!r}"
    if not isinstance(t, NodalTerm) or not isinstance(t, ParametricTerm):
        raise PetsoftError(f"{what}: build() returned a {type(t).__name__}, which is not a "
                           "petsoft.physics.term.NodalTerm and ParametricTerm")
    if t.kind != plugin.term.name:
        raise PetsoftError(f"{what}: its nodal term's kind is {t.kind!r}; it must be the "
                           "term's name (the parameters find it by it)")
    if t.in_reference:
        # the parameter derivatives add no beta dK0/dp v (petsoft.dynamics.parameters)
        raise PetsoftError(f"{what}: in_reference = True is not supported for a package's "
                           "term yet (its Hessian would enter K0 and the stiffness damping)")
    names = plugin.parameter_names
    if set(t.parameters()) != names:
        raise PetsoftError(f"{what}: parameters() gives {sorted(t.parameters())}, its "
                           f"declaration's number keys are {sorted(names)}")
    return t


def build_model(experiment, comm: PETSc.Comm | None = None, *, project_spd: bool = False,
                mesh=None, recording=None) -> Model:
    """Distribute the experiment's mesh and assemble its model (all ranks call).

    ``recording`` is the HDF5 recording whose ``/inputs`` drive ``series`` supports.
    """
    comm = comm if comm is not None else PETSc.COMM_WORLD
    if "default" not in experiment.material:    # no [material]: the reader then has [springs]
        raise ExperimentError(f"{experiment.source}: [springs] models are not supported by this "
                              "command yet; give a [material]")
    if mesh is None:
        mesh = on_root(comm, load_mesh, experiment)
    dmesh = DistributedMesh(mesh, comm)
    resolver = RegionResolver(dmesh.mesh, experiment.regions, experiment.source)
    models, E, nu, rho = cell_materials(experiment, resolver)
    local = dmesh.cell_ids
    elastic = ElasticTerm(dmesh, models[local], E[local], nu[local], project_spd=project_spd)

    forces = gravity_forces(dmesh, rho[local], experiment.gravity.acceleration)
    conditions = []
    for i, b in enumerate(experiment.boundaries):
        key = f"boundary[{i}].where"
        if b.kind == "traction":
            faces = resolver.faces(b.where, key)
            if dmesh.comm.tompi4py().allreduce(len(faces)) == 0:
                raise ExperimentError(f"{experiment.source}: {key}: the traction selects no "
                                      "boundary face (a face belongs when all its vertices do)")
            pts = dmesh.mesh.points[faces].reshape(-1, 3)
            t = np.stack([e.evaluate_at(pts, t=0.0) for e in b.value], axis=1).reshape(-1, 3, 3)
            forces += traction_forces(dmesh, faces, t)
            continue
        displacement = b.displacement if b.kind == "prescribed" else None
        if b.kind == "prescribed" and b.series is not None:
            if recording is None:
                raise ExperimentError(
                    f"{experiment.source}: boundary[{i}].series = {b.series!r}: a measured input "
                    "needs its recording (petsoft simulate ... --recording RECORDING.h5)")

            displacement = read_input_series(recording, b.series)
        mask = resolver.vertex_mask(b.where, key)
        if not mask.any():
            raise ExperimentError(f"{experiment.source}: {key}: selects no vertex of the mesh")
        if b.kind == "fixed" and b.compliance > 0.0:
            continue   # an elastic support: penalty springs (boundary.compliance's builder)
        conditions.append((mask, b.component_indices, displacement))
    external = dmesh.create_global_vec()
    external.zeroEntries()
    dmesh.add_to_global(forces, external)
    dirichlet = DirichletConditions(dmesh, conditions)
    # the built-in nodal energy terms from their declarations (petsoft.terms), then the
    # packages' terms: the same call
    nodal = [build(experiment, dmesh, resolver, dirichlet)
             for _, build in builders("potential")]
    nodal += package_terms(experiment, dmesh, resolver, dirichlet)
    potential = ModelPotential(elastic, [t for t in nodal if t is not None])
    return Model(experiment, dmesh, resolver, potential, rho[local], external, dirichlet)
