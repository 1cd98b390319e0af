"""Shared pytest set-up: the `serial_only` marker and a non-interactive matplotlib backend.

The suite runs serially and under ``mpiexec -n 2``; every test runs on every rank, collectively.
"""

import os

os.environ.setdefault("MPLBACKEND", "Agg")


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "serial_only: runs only without MPI (spawns processes or is rank-local)")
