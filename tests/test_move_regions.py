"""ParameterMap.move_regions: a system takes another experiment's regions in place.

The cantilever of tests/test_sphere_fit.py with a sphere of denser (and stiffer) material: the
system built with the sphere at one place, its regions then moved to another place (and the
sphere's density changed), holds what a system built there holds (4- and 10-node elements) --
the mass matrix, the reference stiffness, the gravity load, each cell's E, nu and density, the
cells every material name governs and the names' values. A moved region that would change some
cells' material law is refused.
"""

import numpy as np
import pytest
import tomllib
from _cantilever import cantilever
from petsc4py import PETSc

from petsoft.diagnosis.candidates import sphere_condition
from petsoft.dynamics.factory import build_system
from petsoft.errors import ExperimentError
from petsoft.experiment import experiment_from_dict

NAME = "blob"


def _experiment(centre, density: float, E: float = 4.0e7, law: str | None = None,
                order: int = 1):
    model = f'model = "{law}"\n' if law else ""
    extra = (f"[material.{NAME}]\ndensity = {density}\nyoungs_modulus = {E}\n{model}\n"
             f'[region.{NAME}]\nwhere = "{sphere_condition(centre, 0.03)}"\n')
    text = cantilever(2.0e7, extra=extra, end=0.02).replace(
        "cells = [6, 1, 1] }", f"cells = [12, 2, 2] }}\norder = {order}")
    return experiment_from_dict(tomllib.loads(text), source="<move_regions test>")


def _matrix(A: PETSc.Mat) -> np.ndarray:
    return A.convert("dense").getDenseArray() if A.getComm().getSize() == 1 else \
        np.array(A.getValues(range(*A.getOwnershipRange()), range(A.getSize()[1])))


@pytest.mark.parametrize("order", [1, 2])
def test_moved_regions_hold_what_a_system_built_there_holds(order):
    here = _experiment((0.1, 0.02, 0.02), 5000.0, order=order)
    there = _experiment((0.22, 0.02, 0.02), 3000.0, order=order)
    moved, built = build_system(here), build_system(there)
    assert moved.nodes_per_element == (4 if order == 1 else 10)
    pm, ref = moved.parameters, built.parameters
    before = _matrix(moved.M).copy()
    pm.move_regions(there)
    moved.set_parameters({})
    assert not np.allclose(before, _matrix(built.M))
    np.testing.assert_allclose(_matrix(moved.M), _matrix(built.M), rtol=1e-13, atol=0.0)
    np.testing.assert_allclose(_matrix(moved.K0_matrix()), _matrix(built.K0_matrix()),
                               rtol=1e-13, atol=1e-9)
    np.testing.assert_allclose(moved.gravity.getArray(), built.gravity.getArray(), rtol=1e-13,
                               atol=0.0)
    for a, b in ((pm.E(), ref.E()), (pm.nu, ref.nu), (pm.rho, ref.rho)):
        np.testing.assert_array_equal(a, b)
    assert set(pm.cells) == set(ref.cells)
    for name, mask in ref.cells.items():
        np.testing.assert_array_equal(pm.cells[name], mask, err_msg=name)
        assert pm.values[name] == ref.values[name], name
    moved.destroy()
    built.destroy()


def test_a_moved_region_keeps_the_material_laws():
    here = _experiment((0.1, 0.02, 0.02), 5000.0, law="corotated")
    there = _experiment((0.22, 0.02, 0.02), 5000.0, law="corotated")
    system = build_system(here)
    with pytest.raises(ExperimentError, match="material law"):
        system.parameters.move_regions(there)
    system.destroy()
