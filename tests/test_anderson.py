"""Anderson mixing (petsoft.dynamics.anderson) on a linear fixed-point map q -> A q + b with a
slow rate (0.99): mixing reaches the fixed point in a small fraction of the plain iterations;
window 0 is the plain map; restart keeps the fallback, forget drops it. Its use with the
potential safeguard is tested with the local/global solver (tests/test_local_global.py)."""

import numpy as np
from mpi4py import MPI

from petsoft.dynamics.anderson import AndersonMixing


def _iterations(window, tol=1e-10, n=40):
    rng = np.random.default_rng(2)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A = Q @ np.diag(np.linspace(0.0, 0.99, n)) @ Q.T
    b = rng.standard_normal(n)
    fixed = np.linalg.solve(np.eye(n) - A, b)
    mixer = AndersonMixing(window, MPI.COMM_SELF)
    q = np.zeros(n)
    for it in range(1, 5000):
        q = mixer.mix(q, A @ q + b)
        if np.abs(q - fixed).max() < tol * np.abs(fixed).max():
            return it, mixer
    raise AssertionError(f"window {window}: no convergence")


def test_mixing_needs_far_fewer_iterations_than_the_plain_map():
    plain, mixer0 = _iterations(0)
    mixed, mixer = _iterations(5)
    assert plain > 1000 and mixed < plain / 5, (plain, mixed)     # 2177 and 225
    assert mixer0.plain is None          # window 0: the map's values, nothing kept


def test_restart_keeps_the_fallback_and_forget_drops_it():
    mixer = AndersonMixing(3, MPI.COMM_SELF)
    q = np.zeros(4)
    for k in range(3):
        q = mixer.mix(q, 0.5 * q + k + 1.0)
    fallback = mixer.plain.copy()
    mixer.restart()
    np.testing.assert_array_equal(mixer.plain, fallback)
    # no history: the next mix is the map's value itself
    g = 0.5 * q + 1.0
    np.testing.assert_array_equal(mixer.mix(q, g), g)
    mixer.forget()
    assert mixer.plain is None
