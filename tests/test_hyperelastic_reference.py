"""StVK and neo-Hookean at large deformation, P1 and P2, against DOLFINx 0.5 (issue 36, item 1).

The reference data ``tests/data/hyperelastic_bar.npz`` were made by
``scripts/references/hyperelastic_bar.py`` (system python, DOLFINx/UFL, no petsoft; its docstring
describes the problem): a bar 1 x 0.2 x 0.2 m clamped at x = 0 whose end x = 1 is twisted by
60 degrees and pulled by 20 % (prescribed), E = 1e6, nu = 0.3; the laws written in UFL from their
textbook definitions, P = d psi / d F by ``ufl.diff``. These tests need only the stored file.

petsoft solves the same problem on DOLFINx's mesh (P2: petsoft's own edge nodes, matched by
coordinate) with Newton (8 load steps) and its displacement at the free nodes (neither end
face) is compared with DOLFINx's, relative to their largest:

* P1: every quadrature rule is exact (F is constant per tet): agreement to solver tolerance;
* P2 at the same rule: DOLFINx at quadrature degree 2 is basix's 4-point rule, the same points
  and weights as petsoft's default (Keast's 4 points; the script checks this);
* P2 at degree 6: petsoft with its rule swapped for ``tet_rule(6)`` (exact for StVK's degree-4
  integrand, as is basix's degree-6 rule) against DOLFINx's degree-6 solution; and petsoft's
  DEFAULT rule against it, whose difference is the quadrature error of the 4-point rule
  (asserted to be the same as DOLFINx's own degree-2 vs degree-6 difference).

Measured (``-s`` prints them; relative max difference at the free nodes; 1 rank, 21:30 UTC run):

====  ======  =========================================  ==========  ===========
law   order   reference                                  StVK        neo-Hookean
====  ======  =========================================  ==========  ===========
any   P1      DOLFINx (every rule exact)                 7.1e-14     2.4e-16
      P2      DOLFINx degree 2 (= petsoft's 4 points)    1.2e-14     3.4e-15
      P2      DOLFINx degree 6, petsoft tet_rule(6)      1.5e-14     2.4e-09
      P2      DOLFINx degree 6, petsoft default rule     3.6e-04     2.9e-04
====  ======  =========================================  ==========  ===========

The last row is the quadrature error of the default 4-point rule on this problem (DOLFINx's own
degree 2 vs 6: 3.6e-04 and 2.9e-04). StVK and neo-Hookean solutions differ by 2.5e-2, so the
comparison tells the laws apart. Co-rotated has no DOLFINx case: it is checked against a closed
form here (a bar in uniaxial tension rigidly rotated by 60 degrees, P1 and P2: 1.3e-16 and
3.9e-16 of max |u|; neo-Hookean under the same loads 4.2e-2 away) and pointwise in
tests/test_material_formulas.py.
"""

from __future__ import annotations

import gc
from pathlib import Path

import numpy as np
import pytest
from _static_cases import solve
from petsc4py import PETSc
from scipy.spatial import cKDTree

from petsoft.experiment import experiment_from_dict
from petsoft.fem.element import quadratic_geometry, tet_rule
from petsoft.mesh.quadratic import raise_order
from petsoft.mesh.serial import Mesh, validate
from petsoft.physics.model import build_model

DATA = Path(__file__).parent / "data" / "hyperelastic_bar.npz"
#: petsoft's default linear solver, tight. (With MUMPS, -pc_factor_mat_solver_type mumps, the
#: co-rotated case below hung now and then on 2 ranks: rank 0 inside StaticSolver.destroy while
#: rank 1 had left it; not understood, reported.)
SOLVER = {"snes_rtol": "1e-13", "snes_atol": "1e-9", "ksp_rtol": "1e-12"}
LOAD_STEPS = 8


def _print(*args):
    if PETSc.COMM_WORLD.getRank() == 0:
        print(*args)


def _root(value):
    return PETSc.COMM_WORLD.tompi4py().bcast(value, root=0)


@pytest.fixture(scope="module")
def data():
    with np.load(DATA) as d:
        return {k: d[k] for k in d.files}


def _end_expressions(d) -> list[str]:
    """The end face's displacement (rigid twist about the axis y = z = B/2 plus axial stretch)
    as petsoft expressions of x, y, z."""
    th, s, L, B = (float(d[k]) for k in ("theta", "stretch", "L", "B"))
    c, sn, h = repr(np.cos(th)), repr(np.sin(th)), repr(B / 2)
    return [repr(s * L),
            f"{c}*(y - {h}) - {sn}*(z - {h}) - (y - {h})",
            f"{sn}*(y - {h}) + {c}*(z - {h}) - (z - {h})"]


def _model(d, law: str, order: int):
    mesh = validate(Mesh(points=np.asarray(d["points"], float),
                         tets=np.asarray(d["tets"], np.int64),
                         cell_tags=np.zeros(len(d["tets"]), np.int64),
                         source="dolfinx hyperelastic bar"))
    if order == 2:
        mesh = raise_order(mesh)
    L = float(d["L"])
    exp = experiment_from_dict({
        "mesh": {"box": {"size": [L, float(d["B"]), float(d["B"])], "cells": [1, 1, 1]},
                 "order": order},
        "material": {"model": law, "youngs_modulus": float(d["E"]),
                     "poisson_ratio": float(d["nu"]), "density": 1000.0},
        "gravity": {"acceleration": [0.0, 0.0, 0.0]},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"},
                     {"kind": "prescribed", "where": f"x > {L} - 1e-9",
                      "displacement": _end_expressions(d)}],
        "output": {"directory": "/tmp/petsoft-hyperelastic-reference"},
    })
    return mesh, build_model(exp, mesh=mesh)


def _use_rule(model, degree: int) -> None:
    """Integrate the P2 elastic term by ``tet_rule(degree)`` instead of the default rule."""
    dm = model.dmesh
    for group in model.elastic.groups:
        dN, w = quadratic_geometry(dm.points[dm.cells[group.cells]], *tet_rule(degree))
        group.dN, group.volume = np.ascontiguousarray(dN), np.ascontiguousarray(w)


def _free():
    """Free the dropped models' PETSc objects now, at the same point on every rank: left to
    Python's cyclic collector they were freed on one rank only and the 2-rank run hung."""
    gc.collect()
    PETSc.COMM_WORLD.tompi4py().Barrier()


def _petsoft(d, law, order, degree=None):
    mesh, model = _model(d, law, order)
    if degree is not None:
        _use_rule(model, degree)
    u, result = solve(model, load_steps=LOAD_STEPS, options=SOLVER)
    summary = {"newton_iterations": result.newton_iterations, "load_steps": result.load_steps}
    del model, result
    _free()
    return mesh.points, u, summary


def _reference(points, d, key_x, key_u):
    X, U = np.asarray(d[key_x]), np.asarray(d[key_u])
    dist, idx = cKDTree(X).query(points)
    assert dist.max() < 1e-12
    assert len(np.unique(idx)) == len(points) == len(X)
    return U[idx]


def _free_difference(points, u, ref, L):
    """max |u - ref| / max |ref| over the nodes of neither end face (the prescribed ones agree
    by construction)."""
    free = (points[:, 0] > 1e-9) & (points[:, 0] < L - 1e-9)
    return float(np.abs(u[free] - ref[free]).max() / np.abs(ref[free]).max())


@pytest.mark.parametrize("law", ["stvk", "neohookean"])
def test_p1_matches_dolfinx(data, law):
    """P1 (any rule is exact): petsoft == DOLFINx at the free nodes to 1e-8; the two laws'
    solutions differ by > 1 % (so the comparison can tell them apart)."""
    points, u, result = _petsoft(data, law, 1)
    ref = _reference(points, data, f"{law}_p1_x", f"{law}_p1_u")
    diff = _root(_free_difference(points, u, ref, float(data["L"])))
    other = "neohookean" if law == "stvk" else "stvk"
    gap = _free_difference(points, ref, _reference(points, data, f"{other}_p1_x",
                                                   f"{other}_p1_u"), float(data["L"]))
    _print(f"\n{law} P1 vs DOLFINx: {diff:.2e} (the other law's DOLFINx solution differs by "
           f"{gap:.2e}); {result['newton_iterations']} Newton iterations")
    assert result["load_steps"] == LOAD_STEPS
    assert gap > 1e-2
    assert diff < 1e-8


@pytest.mark.parametrize("law", ["stvk", "neohookean"])
def test_p2_matches_dolfinx_same_rule_and_quadrature_error(data, law):
    """P2: petsoft's default rule (4 points) == DOLFINx at degree 2 (the same rule) to 1e-8;
    petsoft at ``tet_rule(6)`` == DOLFINx at degree 6 to 1e-6 (StVK: both exact; neo-Hookean:
    both within ~1e-7 of exact); petsoft's default against DOLFINx's degree 6 differs by the
    quadrature error, equal to DOLFINx's own degree-2 vs degree-6 difference within 1 %."""
    L = float(data["L"])
    points, u2, _ = _petsoft(data, law, 2)
    ref2 = _reference(points, data, f"{law}_p2_x", f"{law}_p2_q2_u")
    ref6 = _reference(points, data, f"{law}_p2_x", f"{law}_p2_q6_u")
    same_rule = _root(_free_difference(points, u2, ref2, L))
    quad_err_petsoft = _root(_free_difference(points, u2, ref6, L))
    quad_err_dolfinx = _free_difference(points, ref2, ref6, L)
    _, u6, _ = _petsoft(data, law, 2, degree=6)
    high_rule = _root(_free_difference(points, u6, ref6, L))
    _print(f"\n{law} P2 vs DOLFINx: same 4-point rule {same_rule:.2e}; degree 6 vs degree 6 "
           f"{high_rule:.2e}; petsoft default vs DOLFINx degree 6 {quad_err_petsoft:.2e} "
           f"(DOLFINx degree 2 vs 6: {quad_err_dolfinx:.2e})")
    assert same_rule < 1e-8
    assert high_rule < 1e-6
    assert quad_err_petsoft == pytest.approx(quad_err_dolfinx, rel=0.01)
    assert quad_err_dolfinx > 100 * max(same_rule, high_rule)  # the rules are told apart


def _rotation(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


@pytest.mark.parametrize("order", [1, 2])
def test_corotated_rotated_bar_in_uniaxial_tension(order):
    """Co-rotated, closed form: a bar [0, 1] x [0, 0.2]^2 (E = 1e6, nu = 0.3) stretched by a dead
    traction T = 2.5e5 Pa along its axis and rigidly rotated by Q (60 degrees about (1, 2, 2)).
    Uniaxial stress of this law: P = Q diag(E (a - 1), 0, 0) with a - 1 = T / E exactly and the
    lateral stretch b = 1 - nu (a - 1) (derived in test_material_formulas.py). The face x = 0 is
    held where the closed form puts it, u = (Q diag(a, b, b) - I) X, the face x = 1 carries the
    traction Q (T, 0, 0); the exact solution u = (Q diag(a, b, b) - I) X is affine, so P1 and P2
    reproduce it at every node (to 1e-9 of max |u|) if and only if the law's stress is right.
    The neo-Hookean law under the same loads lands elsewhere (> 1 % away)."""
    E, nu, T = 1e6, 0.3, 2.5e5
    a = 1 + T / E
    b = 1 - nu * (a - 1)
    Q = _rotation((1.0, 2.0, 2.0), np.pi / 3)
    G = Q @ np.diag([a, b, b]) - np.eye(3)
    clamp = [" + ".join(f"({G[i, j]!r})*{c}" for j, c in enumerate("xyz")) for i in range(3)]
    traction = [float(c) for c in Q @ np.array([T, 0.0, 0.0])]
    result = {}
    for law in ("corotated", "neohookean"):
        exp = experiment_from_dict({
            "mesh": {"box": {"size": [1.0, 0.2, 0.2], "cells": [4, 1, 1]}, "order": order},
            "material": {"model": law, "youngs_modulus": E, "poisson_ratio": nu,
                         "density": 1000.0},
            "gravity": {"acceleration": [0.0, 0.0, 0.0]},
            "boundary": [{"kind": "prescribed", "where": "x < 1e-9", "displacement": clamp},
                         {"kind": "traction", "where": "x > 1 - 1e-9", "value": traction}],
            "output": {"directory": "/tmp/petsoft-hyperelastic-reference"},
        })
        model = build_model(exp)
        u, res = solve(model, load_steps=4, options=SOLVER)
        X = model.dmesh.mesh.points
        del model, res
        _free()
        exact = X @ G.T
        result[law] = _root(float(np.abs(u - exact).max() / np.abs(exact).max()))
    _print(f"\nco-rotated P{order}, rotated bar in uniaxial tension: max |u - u_exact| / max |u| "
           f"= {result['corotated']:.2e} (neo-Hookean: {result['neohookean']:.2e})")
    assert result["corotated"] < 1e-9
    assert result["neohookean"] > 1e-2
