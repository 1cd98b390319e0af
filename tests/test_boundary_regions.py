"""Exact solutions that P1 reproduces: rollers/symmetry planes (partial-component Dirichlet
conditions) and per-region materials in series; physical-group regions from a mesh file."""

from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from petsoft.experiment import experiment_from_dict
from petsoft.physics.model import build_model
from petsoft.solvers.static import StaticSolver

MESHES = Path(__file__).resolve().parents[1] / "meshes"


def _solve(data, mesh=None):
    model = build_model(experiment_from_dict(data), mesh=mesh)
    solver = StaticSolver(model)
    result = solver.solve()
    u = MPI.COMM_WORLD.bcast(model.dmesh.gather_global(result.displacement))
    points = model.dmesh.mesh.points
    solver.destroy()
    return points, u


def test_symmetry_planes_give_uniaxial_stress():
    """Rollers on x=0, y=0, z=0 (one component each) and a tension traction on x=L: the exact
    homogeneous uniaxial solution u = (s/E x, -nu s/E y, -nu s/E z), which P1 reproduces."""
    E, nu, s, L = 2.0e6, 0.3, 1.0e4, 0.5
    points, u = _solve({
        "mesh": {"box": {"size": [L, 0.2, 0.1], "cells": [5, 3, 2]}},
        "material": {"model": "linear", "youngs_modulus": E, "poisson_ratio": nu,
                     "density": 1000.0},
        "boundary": [
            {"kind": "fixed", "where": "x < 1e-9", "components": ["x"]},
            {"kind": "fixed", "where": "y < 1e-9", "components": ["y"]},
            {"kind": "fixed", "where": "z < 1e-9", "components": ["z"]},
            {"kind": "traction", "where": f"x > {L} - 1e-9", "value": [s, 0, 0]},
        ],
        "output": {"directory": "unused"},
    })
    exact = np.column_stack([s / E * points[:, 0], -nu * s / E * points[:, 1],
                             -nu * s / E * points[:, 2]])
    assert np.abs(u - exact).max() <= 1e-9 * np.abs(exact).max()


def test_components_are_free_where_not_constrained():
    """A roller (z fixed only) on the bottom of a block under gravity: it sags in z but may
    spread in x and y; fixing all components instead changes the answer."""
    base = {
        "mesh": {"box": {"size": [0.2, 0.2, 0.1], "cells": [4, 4, 2]}},
        "material": {"model": "linear", "youngs_modulus": 1e5, "poisson_ratio": 0.45,
                     "density": 1000.0},
        "gravity": {"acceleration": [0, 0, -9.81]},
        "boundary": [{"kind": "fixed", "where": "z < 1e-9", "components": ["z"]},
                     {"kind": "fixed", "where": "x < 1e-9 and y < 1e-9 and z < 1e-9"},
                     {"kind": "fixed", "where": "x > 0.2 - 1e-9 and y < 1e-9 and z < 1e-9",
                      "components": ["y", "z"]}],
        "output": {"directory": "unused"},
    }
    points, u = _solve(base)
    bottom = points[:, 2] < 1e-9
    assert np.abs(u[bottom, 2]).max() == 0.0
    assert np.abs(u[bottom, :2]).max() > 1e-6  # spreads sideways (Poisson effect)
    clamped = dict(base, boundary=[{"kind": "fixed", "where": "z < 1e-9"}])
    _, u_clamped = _solve(clamped)
    assert np.abs(u_clamped[bottom]).max() == 0.0
    assert u[:, 2].min() < u_clamped[:, 2].min()  # the free-sliding base sags more


def test_region_materials_in_series():
    """Two halves of a bar with different Young's moduli under tension (nu = 0): the end
    displacement is s (L1/E1 + L2/E2) exactly; the override applies only inside its region."""
    E1, E2, s = 1.0e6, 4.0e6, 1.0e3
    points, u = _solve({
        "mesh": {"box": {"size": [1.0, 0.1, 0.1], "cells": [10, 1, 1]}},
        "material": {"model": "linear", "youngs_modulus": E1, "poisson_ratio": 0.0,
                     "density": 1000.0,
                     "stiff": {"youngs_modulus": E2}},
        "region": {"stiff": {"where": "x > 0.5"}},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"},
                     {"kind": "traction", "where": "x > 1 - 1e-9", "value": [s, 0, 0]}],
        "output": {"directory": "unused"},
    })
    x = points[:, 0]
    exact = np.where(x <= 0.5, s / E1 * x, s / E1 * 0.5 + s / E2 * (x - 0.5))
    assert np.abs(u[:, 0] - exact).max() <= 1e-9 * exact.max()


def test_mesh_physical_groups_as_regions_and_boundaries():
    """meshes/bar.msh: the 'clamp' surface group fixes the bar, the 'tip' group carries the
    traction, and [material.right] stiffens the 'right' volume group; the answer matches the
    same problem written with expressions on the same mesh file."""
    common = {"material": {"model": "linear", "youngs_modulus": 1e6, "poisson_ratio": 0.0,
                           "density": 1000.0, "right": {"youngs_modulus": 3e6}},
              "output": {"directory": "unused"}}
    by_group = dict(common, mesh={"file": str(MESHES / "bar.msh")},
                    boundary=[{"kind": "fixed", "where": "clamp"},
                              {"kind": "traction", "where": "tip", "value": [500.0, 0, 0]}])
    by_expr = dict(common, mesh={"file": str(MESHES / "bar.msh")},
                   region={"right": {"where": "x > 0.2"}},
                   boundary=[{"kind": "fixed", "where": "x < 1e-9"},
                             {"kind": "traction", "where": "x > 0.4 - 1e-9",
                              "value": [500.0, 0, 0]}])
    p1, u1 = _solve(by_group)
    p2, u2 = _solve(by_expr)
    np.testing.assert_array_equal(p1, p2)
    assert np.abs(u1 - u2).max() <= 1e-9 * np.abs(u2).max()
    tip = p1[:, 0] > 0.4 - 1e-9
    assert u1[tip, 0].mean() == pytest.approx(500.0 * (0.2 / 1e6 + 0.2 / 3e6), rel=1e-9)
