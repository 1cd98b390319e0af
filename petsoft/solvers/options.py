"""The PETSc options database: experiment defaults under command-line options.

Precedence, lowest first: defaults in code, the experiment's ``[petsc]`` table (present only while
that experiment runs: :func:`experiment_options`), the command line.
Defaults petsc4py has no setter for (e.g. the SNES line search in 3.18) are put in the options
database only around one object's ``setFromOptions()`` (:func:`scoped_defaults`), so different
solvers can have different defaults and a user's option always wins.
"""

from __future__ import annotations

import ctypes
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


def unused_options(comm=None) -> list[str]:
    """The options in the database no solver or lookup ever used, on every rank (collective).

    PETSc's ``-options_left`` logic (``PetscOptionsLeftGet``, which petsc4py does not wrap, so
    called through the library petsc4py loaded): a misspelled option (``-ksp_tyep cg``) or one
    for a solver the run never made is otherwise silently ignored. Options petsoft set itself
    (:func:`set_default_option`) are left out; the experiment's ``[petsc]`` table is removed
    from the database when its run ends, so only the command line's options remain to report.
    An option counts as unused when no rank used it.

    Returns
    -------
    list of str
        ``"-name value"`` (or ``"-name"``) per unused option, in the database's order.
    """
    comm = PETSc.COMM_WORLD if comm is None else comm
    lib = ctypes.CDLL(PETSc.__file__)      # dlsym finds libpetsc's symbols through it
    int_type = ctypes.c_int64 if PETSc.IntType().itemsize == 8 else ctypes.c_int32
    count = int_type()
    names, values = ctypes.POINTER(ctypes.c_char_p)(), ctypes.POINTER(ctypes.c_char_p)()
    if lib.PetscOptionsLeftGet(None, ctypes.byref(count), ctypes.byref(names),
                               ctypes.byref(values)) != 0:
        raise RuntimeError("PetscOptionsLeftGet failed")
    try:
        left = [(names[i].decode(), None if values[i] is None else values[i].decode())
                for i in range(count.value)]
    finally:
        lib.PetscOptionsLeftRestore(None, ctypes.byref(count), ctypes.byref(names),
                                    ctypes.byref(values))
    mine = [f"-{k}" + ("" if v is None else f" {v}") for k, v in left
            if k not in _inserted_by_us]
    everywhere = set(mine)
    for other in comm.tompi4py().allgather(mine):
        everywhere &= set(other)
    return [m for m in mine if m in everywhere]
