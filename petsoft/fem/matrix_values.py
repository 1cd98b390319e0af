"""Writing a sequential AIJ matrix's values in place (PETSc's ``MatSeqAIJGetArray``).

petsc4py 3.18 has no binding for the value array of an AIJ matrix, so an assembled CSR value array
reaches PETSc through ``MatSetValues`` (a search per entry: 30 ns an entry, 0.3 ms a Jacobian of
a 351-dof bar, as much as the element kernels). When the matrix is sequential and its nonzeros are
exactly the assembler's pattern (sorted CSR, same count), its value array *is* laid out as the
assembler's, and one copy replaces the insertion. The functions are taken from the PETSc library
petsc4py already loaded (by ctypes; ``MatSeqAIJRestoreArray`` marks the matrix changed, so solvers
refactor it). Where the library cannot be found the caller keeps the generic path.
"""

from __future__ import annotations

import ctypes
from functools import lru_cache

import numpy as np
from petsc4py import PETSc

__all__ = ["copy_into_seqaij", "seqaij_available"]


@lru_cache(maxsize=1)
def _petsc_library():
    """The loaded PETSc shared library (the one petsc4py uses), or None."""
    try:
        with open("/proc/self/maps") as maps:
            paths = [line.split()[-1] for line in maps if "libpetsc" in line]
    except OSError:
        return None
    for path in paths:
        if path.startswith("/"):
            lib = ctypes.CDLL(path)
            for name in ("MatSeqAIJGetArray", "MatSeqAIJRestoreArray"):
                fn = getattr(lib, name)
                fn.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_void_p)]
                fn.restype = ctypes.c_int
            return lib
    return None


def seqaij_available() -> bool:
    """Whether in-place writes are possible in this process."""
    return PETSc.ScalarType is np.float64 and _petsc_library() is not None


def copy_into_seqaij(A: PETSc.Mat, values: np.ndarray) -> bool:
    """Copy ``values`` into the value array of the sequential AIJ matrix ``A`` in place.

    The caller guarantees that ``A``'s nonzero structure is its pattern (the same sorted CSR);
    this checks the type and the count of nonzeros and returns False (nothing written) when
    they do not match, so the caller can insert the values the generic way.
    """
    lib = _petsc_library()
    if lib is None or A.getType() != PETSc.Mat.Type.SEQAIJ:
        return False
    if int(A.getInfo()["nz_used"]) != len(values):
        return False
    ptr = ctypes.c_void_p()
    handle = ctypes.c_void_p(A.handle)
    if lib.MatSeqAIJGetArray(handle, ctypes.byref(ptr)) or not ptr.value:
        return False
    target = np.ctypeslib.as_array((ctypes.c_double * len(values)).from_address(ptr.value))
    target[:] = values
    # (the restore increases the matrix's state: a solver set up on it refactors)
    if lib.MatSeqAIJRestoreArray(handle, ctypes.byref(ptr)):
        raise PETSc.Error(1)
    return True
