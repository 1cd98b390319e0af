"""The PETSc options database: experiment defaults under command-line options.

Precedence, lowest first: defaults in code, the experiment's ``[petsc]`` table (present only while
that experiment runs: :func:`experiment_options`), the command line.
Defaults petsc4py has no setter for (e.g. the SNES line search in 3.18) are put in the options
database only around one object's ``setFromOptions()`` (:func:`scoped_defaults`), so different
solvers can have different defaults and a user's option always wins.
"""

from __future__ import annotations

from contextlib import contextmanager

from petsc4py import PETSc

_inserted_by_us: set[str] = set()


@contextmanager
def experiment_options(table: dict[str, str]):
    """The experiment's ``[petsc]`` options, for the solvers set up inside the block only.

    Each key the command line (or an enclosing block) did not set is inserted on entry and
    removed on exit, so one experiment's choices never leak into the next run of the process
    (the Python API runs several). Yields the keys inserted.
    """
    opts = PETSc.Options()
    placed = []
    for key, value in table.items():
        key = key.lstrip("-")
        if not opts.hasName(key):
            opts.setValue(key, value)
            placed.append(key)
    try:
        yield placed
    finally:
        for key in placed:
            opts.delValue(key)


def clear_options(keys) -> None:
    """Remove options (tests clear what they set)."""
    opts = PETSc.Options()
    for key in keys:
        opts.delValue(key.lstrip("-"))
        _inserted_by_us.discard(key.lstrip("-"))


def user_has(key: str) -> bool:
    """Whether the user (command line, ``[petsc]`` or a caller) set an option."""
    return PETSc.Options().hasName(key) and key not in _inserted_by_us


def set_default_option(key: str, value: str) -> None:
    """Set an option for the rest of the process unless the user set it."""
    if not user_has(key):
        PETSc.Options().setValue(key, value)
        _inserted_by_us.add(key)


@contextmanager
def scoped_defaults(**defaults: str):
    """Options present only inside the block (for one ``setFromOptions()``), unless user-set."""
    opts = PETSc.Options()
    placed = [k for k in defaults if not user_has(k)]
    for k in placed:
        opts.setValue(k, defaults[k])
        _inserted_by_us.add(k)
    try:
        yield
    finally:
        for k in placed:
            opts.delValue(k)
            _inserted_by_us.discard(k)
