"""One OpenBLAS thread per process, also when numpy and petsc4py loaded OpenBLAS first.

A user's script imports numpy (and often petsc4py) before petsoft; OpenBLAS has then read its
thread count already, and MUMPS's factorisations ran 20x slower with two spinning threads on
the loaded 2-core machine (petsoft.blas_threads). Checked in fresh interpreters, as a user runs.
"""

import json
import os
import subprocess
import sys

import pytest

SCRIPT = """
import ctypes, json, re
import numpy
from petsc4py import PETSc
maps = open('/proc/self/maps').read().split()
libs = sorted({p for p in maps if re.search(r'libopenblas.*\\.so', p)})
threads = lambda: [ctypes.CDLL(p).openblas_get_num_threads() for p in libs]
before = threads()
import petsoft
print(json.dumps({'before': before, 'after': threads()}))
"""


def _run(env_threads):
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if env_threads is not None:
        env["OPENBLAS_NUM_THREADS"] = env_threads
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    return got["before"], got["after"], len(got["after"])


@pytest.mark.serial_only   # fresh interpreters; nothing to learn from a second rank
def test_openblas_loaded_before_petsoft_gets_one_thread():
    before, after, n = _run(None)
    if n == 0:
        pytest.skip("this machine's BLAS is not OpenBLAS")
    if os.cpu_count() and os.cpu_count() > 1:
        assert max(before) > 1, before      # loaded first: a thread per core
    assert after == [1] * len(after), after


@pytest.mark.serial_only
def test_the_users_own_thread_count_wins():
    before, after, n = _run("2")
    if n == 0:
        pytest.skip("this machine's BLAS is not OpenBLAS")
    assert before == after == [2] * len(after), (before, after)
