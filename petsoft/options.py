"""The PETSc options database: experiment defaults under command-line options.

Precedence, lowest first: defaults in code (set on the objects), the experiment's ``[petsc]``
table, the command line. ``setFromOptions()`` is called last, once, on each solver object.
"""

from __future__ import annotations

from petsc4py import PETSc


def apply_experiment_options(table: dict[str, str]) -> list[str]:
    """Insert ``[petsc]`` options the command line did not set; returns the keys inserted."""
    opts = PETSc.Options()
    inserted = []
    for key, value in table.items():
        key = key.lstrip("-")
        if not opts.hasName(key):
            opts.setValue(key, value)
            inserted.append(key)
    return inserted


def clear_options(keys) -> None:
    """Remove options (tests clear what they set)."""
    opts = PETSc.Options()
    for key in keys:
        opts.delValue(key.lstrip("-"))


def set_default_option(key: str, value: str) -> None:
    """Set an option unless the user already set it (for defaults petsc4py has no setter for)."""
    opts = PETSc.Options()
    if not opts.hasName(key):
        opts.setValue(key, value)
