"""One BLAS thread per process, also when OpenBLAS was loaded before petsoft.

``OPENBLAS_NUM_THREADS`` is read once, when OpenBLAS is loaded. A script that imports numpy or
petsc4py before petsoft (the usual order) has loaded it already with a thread per core, and
setting the variable then changes nothing: measured on the 2-core machine with other processes
running, MUMPS's numeric Cholesky of the 10-node L-bracket's step matrix (3354 dofs) took
440 ms with OpenBLAS's two spinning threads and 19 ms with one. So, unless the user chose a
number, the threads of every OpenBLAS already in the process are set to one through its own
``openblas_set_num_threads`` (Linux: the loaded libraries are listed in /proc/self/maps).
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

VARIABLE = "OPENBLAS_NUM_THREADS"


def loaded_openblas() -> list[str]:
    """Paths of the loaded shared libraries that may be OpenBLAS (empty where /proc is absent)."""
    maps = Path("/proc/self/maps")
    if not maps.exists():
        return []
    paths = {line.split()[-1] for line in maps.read_text().splitlines()
             if ".so" in line and ("blas" in line or "lapack" in line)}
    return sorted(paths)


def limit_blas_threads(user_set: bool) -> int:
    """Set every loaded OpenBLAS to one thread, unless ``user_set`` (the user's variable
    wins). Returns how many libraries were set."""
    if user_set:
        return 0
    done = 0
    for path in loaded_openblas():
        try:
            setter = ctypes.CDLL(path).openblas_set_num_threads
        except (OSError, AttributeError):   # not OpenBLAS (reference BLAS, scalapack, MKL)
            continue
        setter.argtypes, setter.restype = [ctypes.c_int], None
        setter(1)
        done += 1
    return done


def one_thread_unless_chosen() -> None:
    """The variable for OpenBLAS loaded later, and the threads of any loaded already."""
    user_set = VARIABLE in os.environ
    os.environ.setdefault(VARIABLE, "1")
    limit_blas_threads(user_set)
