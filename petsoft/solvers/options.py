"""The PETSc options database: each solver's options under its own prefix.

Precedence, lowest first: defaults in code, the experiment's ``[petsc]`` table, the command line.
Every object that owns a KSP, SNES, TS, TAO, EPS or MFN has an options prefix of its own
(:data:`PREFIXES`) and a :class:`SolverOptions`: it pushes the ``[petsc]`` table under its
prefix into PETSc's options database, where the command line did not set the same option, calls
``setFromOptions()``, and removes what it pushed (DOLFINx's ``LinearProblem`` pushes its
``petsc_options`` under its own prefix before ``setFromOptions()`` the same way, but over the
command line). It pushes them again around its solves, because PETSc reads some options only
when a solve sets the preconditioner up (``mat_mumps_icntl_*``, ``mg_levels_*``) or ends
(``ksp_converged_reason``). The command line reaches a solver through its prefix
(``-fm_ksp_type``). Nothing an experiment asks for stays in the database after its solver is set
up and has solved, so one experiment's choices never reach the next run of a process, and two
solvers with different prefixes never see each other's options.
Defaults petsc4py has no setter for (e.g. the SNES line search in 3.18) are pushed the same way
below the table (:meth:`SolverOptions.pushed`, :func:`scoped_defaults`).
"""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Mapping
from contextlib import contextmanager

from petsc4py import PETSc

_inserted_by_us: set[str] = set()

#: The options prefix of each solver-owning object (documented in README.md and formats.md).
#: The command's own solver (``static``'s SNES, ``simulate``'s integrator, ``modes``' EPS) has
#: none, so ``-ksp_type`` reaches it as PETSc users expect.
PREFIXES = {
    "": "the command's solver: static's Newton/TAO, simulate's integrator, modes' eigensolver",
    "lift_": "static: the lifting solve of the prescribed displacements",
    "fm_": "calibrate/diagnose: the forward model's time steps",
    "fm_grad_": "calibrate/diagnose: the sensitivity and adjoint linear solves",
    "fm_static_": "calibrate/diagnose: a static initial state",
    "fm_static_lift_": "calibrate/diagnose: its lifting solve",
    "cal_": "calibrate/diagnose: the optimizer (TAO, or petsoft's own methods' limits)",
    "rest_shape_": "rest-shape: the Newton solve of the unloaded shape",
    "ere_": "simulate with integrator ere: the MFN",
    "ere_mass_": "simulate with integrator ere: its consistent-mass solve",
    "stability_": "simulate with integrator explicit: the largest-frequency eigensolve",
    "imex_": "simulate with integrator imex: the slow modes' eigensolve",
    "lg_": "simulate --solver local-global: the global linear solve",
}

#: The keys of an experiment's ``[petsc]`` table the forward model's solvers take without a
#: prefix (``ksp_type`` reaches ``fm_ksp_type`` and ``fm_grad_ksp_type``): the experiment's
#: choice of linear solver is also the calibration's
FORWARD_KEYS = ("ksp_", "pc_", "mat_", "snes_")
GRADIENT_KEYS = ("ksp_", "pc_", "mat_")


class SolverOptions:
    """The options one solver-owning object pushes under its prefix.

    Parameters
    ----------
    prefix : str
        The object's options prefix (``""``, ``"fm_"``...).
    table : mapping of str to str, optional
        The experiment's ``[petsc]`` table (keys with or without the leading dash). A key
        written with this prefix (``fm_ksp_type`` for ``fm_``; every key for ``""``) is pushed
        as it is.
    inherit : tuple of str
        Key beginnings of the table also pushed under the prefix (``ksp_type`` ->
        ``fm_ksp_type``) where the table does not name the prefixed key itself.
    defaults : mapping of str to str, optional
        petsoft's defaults for this object (names without the prefix), below the table.
    """

    def __init__(self, prefix: str = "", table: Mapping[str, str] | None = None,
                 inherit: tuple[str, ...] = (), defaults: Mapping[str, str] | None = None):
        self.prefix = prefix
        table = {str(k).lstrip("-"): str(v) for k, v in (table or {}).items()}
        copied = ({prefix + k: v for k, v in table.items() if k.startswith(inherit)}
                  if inherit and prefix else {})
        self.values = {**copied, **{k: v for k, v in table.items() if k.startswith(prefix)}}
        self.defaults = {k: str(v) for k, v in (defaults or {}).items()}

    def under(self, prefix: str, inherit: tuple[str, ...] = ()) -> SolverOptions:
        """The options of a solver nested in this one's (``lift_`` in ``""``'s): the keys of
        this one's that begin with ``prefix``."""
        return SolverOptions(prefix, self.values, inherit)

    def __repr__(self) -> str:
        return f"SolverOptions({self.prefix!r}, {self.values!r}, defaults={self.defaults!r})"

    @contextmanager
    def pushed(self, **defaults: str):
        """The table's options (and ``defaults``, names without the prefix: petsoft's own
        values of options petsc4py has no setter for), in PETSc's options database while the
        block runs, where the command line (or an enclosing block) did not set them.

        Wrap the object's ``setFromOptions()`` and its solves in it: PETSc reads some options
        only when a solve sets the preconditioner up (MUMPS's ``mat_mumps_icntl_*``, multigrid
        levels' ``mg_levels_*``) or ends (``ksp_converged_reason``, ``ksp_view``).
        """
        opts = PETSc.Options()
        # a value of the table replaces an enclosing block's default, never a user's option
        placed = {k: (opts.getString(k) if opts.hasName(k) else None)
                  for k in self.values if not user_has(k)}
        for k in placed:
            opts.setValue(k, self.values[k])
            _inserted_by_us.discard(k)
        try:
            every = {**self.defaults, **defaults}
            with scoped_defaults(**{self.prefix + k: str(v) for k, v in every.items()}):
                yield self
        finally:
            for k, before in placed.items():
                if before is None:
                    opts.delValue(k)
                else:
                    opts.setValue(k, before)
                    _inserted_by_us.add(k)


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
    """Options present only inside the block (for one ``setFromOptions()``), unless user-set.

    A default of an enclosing block is replaced inside this one and restored after it."""
    opts = PETSc.Options()
    placed = {k: (opts.getString(k) if opts.hasName(k) else None)
              for k in defaults if not user_has(k)}
    for k in placed:
        opts.setValue(k, defaults[k])
        _inserted_by_us.add(k)
    try:
        yield
    finally:
        for k, before in placed.items():
            if before is None:
                opts.delValue(k)
                _inserted_by_us.discard(k)
            else:
                opts.setValue(k, before)


def unused_options(comm=None) -> list[str]:
    """The options in the database no solver or lookup ever used, on every rank (collective).

    PETSc's ``-options_left`` logic (``PetscOptionsLeftGet``, which petsc4py does not wrap, so
    called through the library petsc4py loaded): a misspelled option (``-ksp_tyep cg``) or one
    for a solver the run never made is otherwise silently ignored. Options petsoft set itself
    (:func:`set_default_option`) are left out; every solver removes the ``[petsc]`` options
    it pushed (:class:`SolverOptions`), so only the command line's options remain to report.
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


def own_options(prefix: str, options: SolverOptions | None) -> SolverOptions:
    """A solver-owning object's options: ``options`` (whose prefix is the object's), or none
    from an experiment under ``prefix``."""
    if options is None:
        return SolverOptions(prefix)
    if prefix and options.prefix != prefix:
        raise ValueError(f"options prefix {options.prefix!r} given for a solver of prefix "
                         f"{prefix!r}")
    return options


def with_options(method):
    """Run an object's method with its :class:`SolverOptions` (``self.options``) pushed: its
    ``setFromOptions()`` and its solves."""

    @functools.wraps(method)
    def pushing(self, *args, **kwargs):
        with self.options.pushed():
            return method(self, *args, **kwargs)
    return pushing
