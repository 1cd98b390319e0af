"""Where a diagnosis runs each model: on all its ranks together, or on one rank alone.

A model that one rank solves directly gains nothing from several ranks. Up to
:data:`~petsoft.solvers.linear.REDUNDANT_DOFS` every rank of a communicator gathers the whole
matrix and factors it itself (a redundant direct solve), so a second rank only splits the
assembly and adds the messages between them: measured on the realistic cases' 10-node model
(4641 dofs, generalized-alpha, 0.3 s of record, the machine otherwise quiet), a forward run took
1.9 s on one rank and 4.5 s on two, a run with sensitivities 4.1 s and 10.2 s. Above it, several
ranks solve iteratively (CG + algebraic multigrid, deterministic across ranks where MUMPS is not,
see :func:`~petsoft.solvers.linear.linear_defaults`) while one rank still factors directly up to
:data:`~petsoft.solvers.linear.DIRECT_DOFS`, and keeps the factorisation across a time step's
Newton iterations: the realistic payload taper's 10-node model split 1 -> 8 (29,595 dofs, the
numerics check's measuring run, 15 steps of 2 ms, the machine loaded alike) took 8.9 s on one
rank (MUMPS) and 93 s on two (CG + GAMG, ~10 Krylov iterations a Newton iteration).

So a diagnosis on several ranks runs every model up to the one-rank direct limit on one rank:
work that comes in independent pieces (refinements, candidate fits, scores) on one piece per
rank, and a single run on the first rank while the others wait for its result
(:meth:`Placement.alone`). Every rank then holds the same result, as after any collective run,
and the diagnosis on two ranks takes the path it takes on one.

:class:`Placement` decides by the model's unknowns (:meth:`Placement.one_rank_each`), counted
from its mesh without building it, once per mesh.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from petsoft.calibration.groups import TaskResult, map_on_groups
from petsoft.dynamics.factory import system_class
from petsoft.errors import PetsoftError
from petsoft.solvers.linear import DIRECT_DOFS

#: A model of at most this many unknowns runs on one rank (module docstring): what one rank
#: solves directly by default.
ONE_RANK_DOFS = DIRECT_DOFS


class Placement:
    """Where a diagnosis' runs go (module docstring).

    Parameters
    ----------
    comm : PETSc.Comm
        The diagnosis' ranks.
    one_rank_dofs : int
        Models of at most this many unknowns run on one rank (0: every run on all the ranks).
    """

    def __init__(self, comm, one_rank_dofs: int = ONE_RANK_DOFS):
        self.comm = comm
        self.one_rank_dofs = int(one_rank_dofs)
        self._dofs: dict[tuple, int] = {}

    def dofs(self, experiment) -> int:
        """The unknowns of ``experiment``'s model (counted on the first rank, the same on
        every rank; call collectively)."""
        key = (system_class(experiment).__name__, repr(experiment.mesh),
               repr(getattr(experiment, "springs", None)))
        if key not in self._dofs:
            mpi = self.comm.tompi4py()
            count = system_class(experiment).dof_count(experiment) if mpi.rank == 0 else None
            self._dofs[key] = int(mpi.bcast(count, root=0))
        return self._dofs[key]

    def one_rank_each(self, *experiments) -> bool:
        """Whether the models of ``experiments`` run on one rank (several ranks, and each at
        most :attr:`one_rank_dofs` unknowns; none counted on one rank); call collectively."""
        return (self.comm.getSize() > 1 and self.one_rank_dofs > 0
                and all(self.dofs(e) <= self.one_rank_dofs for e in experiments))

    def on_groups(self, task: Callable[[Any, Any], Any], items: Sequence, *experiments
                  ) -> list[TaskResult]:
        """:func:`~petsoft.calibration.groups.map_on_groups` of ``task`` over ``items``, on one
        rank each when every model of ``experiments`` is small (:meth:`one_rank_each`)."""
        return map_on_groups(task, items, self.comm,
                             one_rank_each=self.one_rank_each(*experiments))

    def alone(self, task: Callable[[Any], Any], experiment):
        """``task(comm)``'s value: on all the ranks, or on the first rank alone when
        ``experiment``'s model is small (the others wait); every rank gets it. A
        :class:`~petsoft.errors.PetsoftError` the task raises is raised on every rank."""
        if not self.one_rank_each(experiment):
            return task(self.comm)

        def run(_, sub):
            try:
                return True, task(sub)
            except PetsoftError as err:
                # its class and message, to raise it again as it was (not the error itself:
                # its frames hold the run's PETSc objects, see errors.without_frames)
                return False, (type(err), str(err))

        res = map_on_groups(run, [None], self.comm, one_rank_each=True)[0]
        if not res.ok:     # (map_on_groups keeps a PetsoftError that escaped as a message)
            raise PetsoftError(res.error)
        ok, value = res.value
        if not ok:
            raise _rebuilt(*value)
        return value


def _rebuilt(cls: type, message: str) -> PetsoftError:
    """The error of class ``cls`` with ``message``; a :class:`PetsoftError` with it when that
    class is not made from a message alone."""
    try:
        return cls(message)
    except Exception:  # noqa: BLE001 - e.g. InvertedElementError(element, jacobian)
        return PetsoftError(message)
