"""The declared interfaces hold: every system is a :class:`System`, every potential term a
:class:`Term` or :class:`NodalTerm` (with the declared signatures), there is one collider, and the
integrator registry covers the experiment format's vocabulary, each entry building and stepping."""

from __future__ import annotations

import inspect

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.dynamics.integrators import SCHEMES, scheme
from petsoft.dynamics.interfaces import Stepper, System
from petsoft.dynamics.mass_spring import MassSpringSystem, build_mass_spring_model, rope_mesh
from petsoft.dynamics.oscillator import OscillatorSystem
from petsoft.dynamics.simulate import Simulation
from petsoft.dynamics.system import DynamicSystem
from petsoft.errors import ExperimentError
from petsoft.experiment import INTEGRATORS, experiment_from_dict
from petsoft.physics.colliders import Collider
from petsoft.physics.model import build_model
from petsoft.physics.term import NodalTerm, ParametricTerm, Term

BAR = {
    "mesh": {"box": {"size": [0.2, 0.04, 0.04], "cells": [4, 1, 1]}},
    "material": {"model": "neohookean", "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                 "density": 1000.0},
    "gravity": {"acceleration": [0.0, 0.0, -9.81]},
    # an elastic support (a NodalTerm) and a floor the bar does not reach (another)
    "boundary": [{"kind": "fixed", "where": "x < 1e-9", "compliance": 1e-9}],
    "collider": [{"kind": "plane", "point": [0.0, 0.0, -1.0], "normal": [0.0, 0.0, 1.0]}],
    "initial": {"velocity": ["0", "0", "x"]},
    "time": {"end": 0.002, "step": 0.001, "integrator": "be"},
    "output": {"directory": "unused"},
}


def _protocol_methods(protocol) -> dict[str, inspect.Signature]:
    return {name: inspect.signature(member) for name, member in vars(protocol).items()
            if callable(member) and not name.startswith("_")}


def _assert_implements(obj, protocol):
    assert isinstance(obj, protocol), f"{type(obj).__name__} is not a {protocol.__name__}"
    for name, declared in _protocol_methods(protocol).items():
        actual = inspect.signature(getattr(obj, name))
        want = [p for p in declared.parameters if p != "self"]
        have = list(actual.parameters)
        assert have[:len(want)] == want, (
            f"{type(obj).__name__}.{name}{actual} does not take the declared "
            f"{protocol.__name__}.{name}{declared}")
        extra = [actual.parameters[p] for p in have[len(want):]]
        assert all(p.default is not p.empty or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
                   for p in extra), f"{type(obj).__name__}.{name} needs more than declared"


@pytest.fixture(scope="module")
def fem_model():
    return build_model(experiment_from_dict(BAR))


def test_system_every_system_class_is_a_system(fem_model, tmp_path_factory):
    from petsoft.mesh.springs import write_spring_mesh

    fem = DynamicSystem(fem_model)
    _assert_implements(fem, System)
    comm = MPI.COMM_WORLD
    folder = comm.bcast(str(tmp_path_factory.mktemp("rope")) if comm.rank == 0 else None)
    mesh = rope_mesh(3, 1.0)
    if comm.rank == 0:
        write_spring_mesh(f"{folder}/rope.msh", mesh.points, mesh.lines, mesh.triangles)
    comm.Barrier()
    rope = experiment_from_dict({"mesh": {"file": f"{folder}/rope.msh"},
                                 "springs": {"stiffness": 10.0, "node_mass": 0.1},
                                 "boundary": [{"kind": "fixed", "where": "x < 0.1"}]})
    spring = MassSpringSystem(build_mass_spring_model(rope), 0.0, 0.0)
    _assert_implements(spring, System)
    oscillators = OscillatorSystem(np.array([1.0, 2.0]))
    _assert_implements(oscillators, System)
    # capabilities a system lacks are declared None, not missing
    assert oscillators.viscoelastic is None and oscillators.dirichlet is None
    assert spring.elastic is None and fem.rest_lengths is None
    for s in (fem, spring, oscillators):
        s.destroy()


def test_term_the_potential_and_its_parts_are_declared_terms(fem_model):
    potential = fem_model.elastic
    _assert_implements(potential, Term)
    _assert_implements(potential.term, Term)
    kinds = [t.kind for t in potential.nodal_terms]
    assert kinds == ["support", "contact"]
    for t in potential.nodal_terms:
        _assert_implements(t, NodalTerm)
    assert potential.support.in_reference and not potential.contact.in_reference


def test_term_reference_hessian_is_the_elastic_one_plus_the_supports(fem_model):
    """K0 = the elastic Hessian at 0 + the supports' springs: adding the support term's blocks
    to the elastic term's reference Hessian gives the potential's, entry for entry."""
    from petsoft.fem.assembly import MatrixAssembler

    potential = fem_model.elastic
    assembler = MatrixAssembler(fem_model.dmesh, potential.connectivities())
    assembler.begin()
    potential.add_reference_hessian(assembler)
    total = assembler.values.copy()
    assembler.begin()
    potential.term.add_reference_hessian(assembler)
    zero = np.zeros((fem_model.dmesh.nvertices, 3))
    assembler.add("nodal", potential.nodal_hessian(zero, reference=True))
    assert np.array_equal(total, assembler.values)
    springs = np.abs(potential.support.hessian(zero)).max(initial=0.0)   # none on some ranks
    assert MPI.COMM_WORLD.allreduce(springs, op=MPI.MAX) > 0


def test_collider_one_definition_projects_onto_its_surface():
    rng = np.random.default_rng(3)
    x = rng.uniform(-1.0, 1.0, (200, 3))
    for c in (Collider.sphere((0.1, 0.0, 0.0), 0.6, 1e3),
              Collider.plane((0, 0, 0.2), (1, 1, 2), 1e3)):
        active, p = c.project(x)
        phi = c.distance(x)[0]
        assert np.array_equal(active, phi < 0.0)
        assert np.allclose(c.distance(p[active])[0], 0.0, atol=1e-14)   # on the surface
        assert np.array_equal(p[~active], x[~active])
        assert np.allclose(c.penetration(x), np.maximum(0.0, -phi), atol=1e-15)


def test_integrator_registry_covers_the_format_and_every_entry_steps():
    assert tuple(SCHEMES) == tuple(INTEGRATORS)
    with pytest.raises(ExperimentError, match="'leapfrog' is unknown; valid: be, si, alpha"):
        scheme("leapfrog")
    data = {**BAR, "collider": []}       # contact is not for every scheme's stability limit
    for name in SCHEMES:
        # a step below the explicit stability limit (2.2e-4 s here)
        exp = experiment_from_dict({**data, "time": {"end": 2e-4, "step": 1e-4,
                                                     "integrator": name, "imex_slow_modes": 2}})
        sim = Simulation(build_model(exp), exp)
        # what Simulation (checkpoints included) calls, declared: no probing
        _assert_implements(sim.integrator, Stepper)
        assert isinstance(sim.integrator.state(), dict), name
        result = sim.run()
        assert result.steps == 2, name
        assert np.isfinite(result.energies).all(), name
        sim.destroy()


# -- parametric terms (terms branch) ------------------------------------------------------------
PRESSED = {
    "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [4, 1, 1]}},
    "material": {"model": "linear", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                 "density": 1000.0},
    "boundary": [{"kind": "fixed", "where": "x < 1e-9", "compliance": 1e-6}],
    # a plane the bottom face penetrates (a parameter) and a sphere (no parameter)
    "collider": [{"kind": "plane", "point": [0, 0, 0.002], "normal": [0, 0, 1],
                  "stiffness": 4e4},
                 {"kind": "sphere", "center": [0.31, 0.02, 0.02], "radius": 0.035,
                  "stiffness": 3e4}],
}


def test_term_parametric_terms_are_declared_and_match_differences():
    """The supports and the contact are ParametricTerms (declared signatures); each parameter's
    gradient derivative matches central differences of the term's gradient."""
    model = build_model(experiment_from_dict(PRESSED))
    potential, dm = model.elastic, model.dmesh
    assert [t.kind for t in potential.parametric_terms] == ["support", "contact"]
    assert not isinstance(potential.term, ParametricTerm)
    for t in potential.parametric_terms:
        _assert_implements(t, ParametricTerm)
    field = np.random.default_rng(0).standard_normal((len(dm.mesh.points), 3))
    u = 1e-3 * field[dm.vertex_ids]           # the same field on every rank
    params = {n: (t, v) for t in potential.parametric_terms for n, v in t.parameters().items()}
    assert sorted(params) == ["boundary.compliance", "collider.0.offset"]   # not the sphere
    for name, (t, value) in params.items():
        d = np.zeros((dm.nvertices, 3))
        t.add_parameter_derivative(name, u, d)
        step = 1e-6 * (abs(value) if value else 1e-3)
        grads = []
        for sign in (1, -1):
            t.set_parameter(name, value + sign * step)
            assert t.parameters()[name] == value + sign * step
            grads.append(t.gradient(u))
        t.set_parameter(name, value)
        fd = np.zeros_like(d)
        fd[t.nodes] = (grads[0] - grads[1]) / (2 * step)
        assert MPI.COMM_WORLD.allreduce(np.abs(d).max(initial=0.0), op=MPI.MAX) > 0.0, name
        assert np.abs(d - fd).max(initial=0.0) <= 1e-6 * max(np.abs(fd).max(initial=0.0),
                                                             1e-30), name
    with pytest.raises(KeyError):
        potential.contact.set_parameter("collider.1.offset", 0.0)      # a sphere
    with pytest.raises(KeyError):
        potential.support.add_parameter_derivative("collider.0.offset", u, d)


def test_integrator_properties_replace_the_name_comparisons():
    # the callers (implicit, imex, simulate, calibration.forward) branch on these declared
    # properties; each must single out the scheme whose code path it selects
    def having(prop, value=True):
        return {n for n, e in SCHEMES.items() if getattr(e, prop) == value}

    assert having("one_newton_step") == {"si"}
    assert having("carries_acceleration") == {"alpha"}
    assert having("branch_sensitivities") == {"be", "alpha"}
    assert having("minimization") == {"be"}
    assert having("continuum_only") == {"imex"}
    assert having("ts_backend") == {"alpha"}
    assert having("force_at", "end") >= {"be", "si"}
    assert having("force_at", "midpoint") == {"midpoint"}
    assert having("force_at", "trapezoidal") == {"trapezoidal"}
    for e in SCHEMES.values():
        assert (e.maxwell is not None) == (e.name in ("be", "si", "alpha", "midpoint",
                                                      "trapezoidal")), e.name


# -- the factory: every kind of body it builds is a System with its initial state --------------
def _box(order: int):
    """A 0.2 x 0.04 x 0.04 m bar of density 1000 fixed at x = 0, of elements of ``order``."""
    return experiment_from_dict({
        "mesh": {"box": {"size": [0.2, 0.04, 0.04], "cells": [2, 1, 1]}, "order": order},
        "material": {"model": "linear", "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"displacement": ["0.01*x + 0.001", "0", "0"], "velocity": ["0", "0", "x"]},
    }), [0.05, 0.01, 0.03], {"mass": 0.32, "area": 2 * (2 * 0.2 * 0.04 + 0.04 * 0.04),
                             "length": np.sqrt(0.2**2 + 2 * 0.04**2)}


def _rope(folder: str):
    """A 1 m rope of 3 nodes of 0.1 kg along x, node 0 fixed."""
    from petsoft.mesh.springs import write_spring_mesh

    comm = MPI.COMM_WORLD
    mesh = rope_mesh(3, 1.0)
    if comm.rank == 0:
        write_spring_mesh(f"{folder}/rope.msh", mesh.points, mesh.lines, mesh.triangles)
    comm.Barrier()
    return experiment_from_dict({
        "mesh": {"file": f"{folder}/rope.msh"},
        "springs": {"stiffness": 10.0, "node_mass": 0.1},
        "boundary": [{"kind": "fixed", "where": "x < 0.1"}],
        "initial": {"displacement": ["0.01*x + 0.001", "0", "0"], "velocity": ["0", "0", "x"]},
    }), [0.5, 0.0, 0.0], {"mass": 0.3, "area": 1.0, "length": 1.0, "cell": 0.5}


#: One example experiment per kind the factory builds (both element orders of the continuum):
#: (kind, builder of (experiment, a probe point on the body, its sizes in closed form)).
FACTORY_EXAMPLES = {"continuum P1": ("continuum", lambda folder: _box(1)),
                    "continuum P2": ("continuum", lambda folder: _box(2)),
                    "mass-spring": ("mass-spring", _rope)}

#: The systems that are not built from an experiment, and what builds them instead.
NOT_FROM_EXPERIMENTS = {
    "OscillatorSystem": "scalar oscillators of given frequencies (petsoft damping)",
    "FreeVibrationSystem": "a continuum model's undamped, unloaded body (petsoft damping's modes)",
}


def test_factory_every_kind_has_an_example_and_every_system_class_a_builder():
    """A kind added to KINDS needs an example here; a System class added to petsoft is a kind of
    the factory or says here what builds it; every one has initial_state."""
    import importlib
    import pkgutil

    import petsoft
    from petsoft.dynamics.factory import KINDS
    from petsoft.dynamics.interfaces import SystemDefaults

    assert {kind for kind, _ in FACTORY_EXAMPLES.values()} == set(KINDS), (
        "every kind of dynamics.factory.KINDS needs an example in FACTORY_EXAMPLES")
    for info in pkgutil.walk_packages(petsoft.__path__, "petsoft."):
        if not info.name.endswith("__main__"):
            importlib.import_module(info.name)

    def subclasses(cls):
        for sub in cls.__subclasses__():
            yield sub
            yield from subclasses(sub)

    classes = {c for c in subclasses(SystemDefaults) if c.__module__.startswith("petsoft.")}
    built = {k.system for k in KINDS.values()}
    apart = {c for c in classes if c.__name__ in NOT_FROM_EXPERIMENTS}
    assert classes - built - apart == set(), "System classes the factory does not build"
    assert {c.__name__ for c in apart} == set(NOT_FROM_EXPERIMENTS)
    for c in classes:
        assert callable(getattr(c, "initial_state", None)), f"{c.__name__} has no initial_state"


@pytest.mark.parametrize("example", list(FACTORY_EXAMPLES))
def test_factory_builds_each_kind_as_a_system_with_its_initial_state(example, tmp_path_factory):
    """build_system gives the kind's class, conforming to System and ExperimentSystem; its
    initial state is the [initial] expressions with the fixed nodes at 0; a probe's weights
    reproduce the probe point; the body's sizes are the closed-form ones."""
    from petsoft.dynamics.factory import KINDS, ExperimentSystem, build_system, system_class

    comm = MPI.COMM_WORLD
    kind, builder = FACTORY_EXAMPLES[example]
    folder = comm.bcast(str(tmp_path_factory.mktemp("kind")) if comm.rank == 0 else None)
    exp, probe, sizes = builder(folder)
    s = build_system(exp)
    assert type(s) is KINDS[kind].system is system_class(exp)
    _assert_implements(s, System)
    _assert_implements(s, ExperimentSystem)
    assert s.model is not None and s.model.experiment is exp
    assert isinstance(s.volume_cells, bool) and isinstance(s.continuum_material, bool)
    assert s.defined_by.startswith("[") and all(o in (1, 2) for o in s.element_orders)
    assert (exp.mesh.order in s.element_orders) == bool(s.element_orders)

    q, v = s.initial_state()
    assert q.getSize() == v.getSize() == s.create_vec().getSize()
    qf, vf = (comm.bcast(s.dmesh.gather_global(x), root=0) for x in (q, v))
    pts = s.dmesh.mesh.points
    fixed = pts[:, 0] < 1e-9      # the nodes at x = 0 (both examples fix only those)
    assert fixed.any() and not fixed.all()
    np.testing.assert_allclose(qf[~fixed, 0], 0.01 * pts[~fixed, 0] + 0.001, rtol=1e-12)
    assert np.all(qf[fixed] == 0.0) and np.all(qf[:, 1:] == 0.0)
    np.testing.assert_allclose(vf[:, 2], pts[:, 0], rtol=1e-12)
    assert np.all(vf[:, :2] == 0.0)

    conn, cells, weights = s.locate_probes([probe])
    np.testing.assert_allclose(np.einsum("k,kd->d", weights[0], pts[conn[cells[0]]]), probe,
                               atol=1e-12)
    # the unknowns counted from the mesh file alone are the built system's
    assert type(s).dof_count(exp) == q.getSize()
    got = type(s).body_sizes(exp)
    for name, value in sizes.items():
        assert got[name] == pytest.approx(value, rel=1e-12), name
    if s.volume_cells:    # the mean tet's volume: the bar's over its tets as read
        from petsoft.physics.model import load_mesh

        ntets = len(load_mesh(exp).tets)
        assert got["cell"] ** 3 * ntets == pytest.approx(0.2 * 0.04 * 0.04, rel=1e-12)
    for x in (q, v):
        x.destroy()
    s.destroy()


@pytest.mark.parametrize("example", list(FACTORY_EXAMPLES))
def test_each_kind_gives_the_node_wise_solvers_its_nodes(example, tmp_path_factory):
    """What the matrix-free Jacobian and nonlinear Gauss-Seidel ask of a body, checked against
    its assembled matrix and its initial state: ``owned_nodes`` are the rows of the global
    vector (the [initial] expression of x at each); ``unassembled`` multiplies as the assembled
    step matrix does; no two nodes of one colour of ``node_graph`` are coupled in it; an
    element couples ``nodes_per_element`` nodes."""
    from petsoft.dynamics.factory import build_system
    from petsoft.dynamics.nonlinear_gs import owned_colours

    comm = MPI.COMM_WORLD
    folder = comm.bcast(str(tmp_path_factory.mktemp("nodes")) if comm.rank == 0 else None)
    exp, _, _ = FACTORY_EXAMPLES[example][1](folder)
    s = build_system(exp)
    q, _ = s.initial_state()
    x = s.dmesh.mesh.points[s.owned_nodes()]
    qa = q.getArray(readonly=True).reshape(-1, 3)
    free = x[:, 0] >= 1e-9
    assert len(x) == len(qa) and free.any()
    np.testing.assert_allclose(qa[free, 0], 0.01 * x[free, 0] + 0.001, rtol=1e-12)

    A = s.assemble_combination(q, 2.0, 1.0, 0.5, s.create_matrix(), eliminate=False)
    parts = s.unassembled()
    parts.update(q, 2.0, 1.0, 0.5, 0.0)
    rng = np.random.default_rng(comm.rank)
    u, want, got = s.create_vec(), s.create_vec(), s.create_vec()
    u.setArray(rng.standard_normal(u.getLocalSize()))
    A.mult(u, want)
    parts.mult(u, got)
    np.testing.assert_allclose(got.getArray(), want.getArray(), rtol=1e-12,
                               atol=1e-12 * want.norm())

    colour = owned_colours(s)
    lo = u.getOwnershipRange()[0]
    own = np.arange(lo, lo + u.getLocalSize(), dtype=PETSc.IntType).reshape(-1, 3)
    for c in range(comm.allreduce(int(colour.max()) + 1, op=MPI.MAX)):
        mine = colour == c
        u.getArray().reshape(-1, 3)[~mine] = 0.0
        u.getArray().reshape(-1, 3)[mine] = rng.standard_normal((int(mine.sum()), 3))
        A.mult(u, want)
        scale = want.norm()     # collective: not inside the loop over this rank's nodes
        ua = u.getArray(readonly=True).reshape(-1, 3)
        for i in np.flatnonzero(mine):     # only the node's own block acts on it
            block = A.getValues(own[i], own[i])
            np.testing.assert_allclose(want.getArray(readonly=True).reshape(-1, 3)[i],
                                       block @ ua[i], rtol=1e-12, atol=1e-12 * scale)
    # each element of node i adds its k - 1 others to i's pairs, and k nodes' worth in all
    # (a weak check of k: divisibility, not the count of elements)
    n, src, dst = s.node_graph()
    k, count = s.nodes_per_element, np.bincount(src, minlength=n)
    assert np.all(count % (k - 1) == 0) and (count.sum() // (k - 1)) % k == 0, (k, count)
    for vec in (q, u, want, got):
        vec.destroy()
    A.destroy()
    s.destroy()


def test_factory_kind_errors_are_clear(tmp_path_factory):
    """A rest-shape mesh for a spring network, and a [springs] model given to the continuum's
    model builder, are refused with the reason."""
    from petsoft.dynamics.factory import build_system

    comm = MPI.COMM_WORLD
    folder = comm.bcast(str(tmp_path_factory.mktemp("errors")) if comm.rank == 0 else None)
    rope, _, _ = _rope(folder)
    with pytest.raises(ExperimentError, match=r"\[springs\] model is built from its own mesh"):
        build_system(rope, mesh=rope_mesh(3, 1.0))
    with pytest.raises(ExperimentError, match=r"\[springs\] models are not supported"):
        build_model(rope)
