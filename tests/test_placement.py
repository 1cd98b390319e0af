"""Placement: a small model's runs go to one rank each, and every rank gets their results."""

import pytest
from mpi4py import MPI
from petsc4py import PETSc

from petsoft.calibration.groups import map_on_groups
from petsoft.diagnosis.placement import Placement
from petsoft.errors import ExperimentError, InvertedElementError, PetsoftError
from petsoft.experiment import experiment_from_dict


def _bar(cells: int = 3):
    """A P1 box bar of ``cells`` x 1 x 1 hexahedra: 4 (cells + 1) nodes, 12 (cells + 1) dofs."""
    return experiment_from_dict({
        "mesh": {"box": {"size": [0.2, 0.04, 0.04], "cells": [cells, 1, 1]}},
        "material": {"model": "linear", "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
    })


def _sizes(item, sub):
    # a collective on the group: only its ranks take part
    return sub.allreduce(1), sub.Get_size()


def test_one_rank_each_gives_every_rank_a_group_even_for_one_task():
    comm = MPI.COMM_WORLD
    (res,) = map_on_groups(_sizes, ["only"], comm, one_rank_each=True)
    assert res.value == (1, 1)
    (res,) = map_on_groups(_sizes, ["only"], comm)     # without: the task has every rank
    assert res.value == (comm.size, comm.size)
    res = map_on_groups(_sizes, list(range(5)), comm, one_rank_each=True)
    assert [r.value for r in res] == [(1, 1)] * 5
    assert [r.group for r in res] == [i % comm.size for i in range(5)]


def test_dofs_are_counted_from_the_mesh_and_decide_the_placement():
    world = PETSc.COMM_WORLD
    exp = _bar(3)
    assert Placement(world).dofs(exp) == 3 * 4 * 4
    # the limit is inclusive; a single rank has nothing to place
    several = world.getSize() > 1
    assert Placement(world, one_rank_dofs=48).one_rank_each(exp) is several
    assert Placement(world, one_rank_dofs=47).one_rank_each(exp) is False
    assert Placement(world, one_rank_dofs=0).one_rank_each(exp) is False
    assert Placement(world).dofs(_bar(4)) == 3 * 5 * 4


def test_alone_runs_a_small_model_on_one_rank_and_shares_its_value():
    world = PETSc.COMM_WORLD
    exp = _bar()

    def task(sub):
        mpi = sub.tompi4py() if hasattr(sub, "tompi4py") else sub
        return mpi.allreduce(1), MPI.COMM_WORLD.rank

    members, ran_on = Placement(world).alone(task, exp)
    assert members == 1 and ran_on == 0            # the first rank alone, on every rank
    members, _ = Placement(world, one_rank_dofs=0).alone(task, exp)
    assert members == world.getSize()               # a large model: every rank


@pytest.mark.parametrize("limit", [0, 10**6])
def test_alone_raises_a_user_error_on_every_rank_as_it_was(limit):
    place = Placement(PETSc.COMM_WORLD, one_rank_dofs=limit)

    def bad_key(sub):
        raise ExperimentError("model.toml: [material] youngs_modulus must be > 0")

    with pytest.raises(ExperimentError, match="youngs_modulus must be > 0"):
        place.alone(bad_key, _bar())

    def inverted(sub):
        raise InvertedElementError(7, -0.5)

    # an error class not made from its message alone keeps its message
    with pytest.raises(PetsoftError, match="element 7 is inverted"):
        place.alone(inverted, _bar())
