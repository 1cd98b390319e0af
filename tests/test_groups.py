"""map_on_groups: tasks on sub-communicators, results everywhere in order, errors contained."""

import pytest
from mpi4py import MPI

from petsoft.calibration.groups import map_on_groups
from petsoft.errors import PetsoftError


def _task(item, sub):
    if item == 3:
        raise PetsoftError(f"item {item} is bad")
    # a collective on the group: every rank of the group must take part
    return (item * item, sub.allreduce(1), sub.Get_size())


def test_results_are_in_order_on_every_rank_and_errors_are_contained():
    comm = MPI.COMM_WORLD
    res = map_on_groups(_task, list(range(6)), comm)
    assert [r.index for r in res] == list(range(6))
    groups = min(comm.size, 6)
    assert [r.group for r in res] == [i % groups for i in range(6)]
    assert not res[3].ok and "item 3 is bad" in res[3].error
    for r in res:
        if r.index != 3:
            square, members, size = r.value
            assert square == r.index ** 2
            # each group holds size/groups ranks: the collective ran within the group only
            assert members == size == comm.size // groups
    # identical on every rank
    assert comm.allgather([(r.index, r.value, r.error) for r in res])[0] == \
        [(r.index, r.value, r.error) for r in res]


def test_a_bug_is_raised_on_every_rank():
    def broken(item, sub):
        if item == 1:
            raise ValueError("a bug")
        return item

    with pytest.raises(RuntimeError, match="a bug"):
        map_on_groups(broken, [0, 1, 2], MPI.COMM_WORLD)


def test_setup_runs_once_per_group():
    calls = []

    def setup(sub):
        calls.append(sub.Get_size())
        return 10

    res = map_on_groups(lambda item, sub, state: item + state, [1, 2, 3], MPI.COMM_WORLD,
                        setup=setup)
    assert [r.value for r in res] == [11, 12, 13]
    assert len(calls) == 1
