"""Quasistatic robustness: inverted elements during Newton are survived by smaller increments."""

import numpy as np
from mpi4py import MPI

from petsoft.experiment import experiment_from_dict
from petsoft.physics.model import build_model
from petsoft.solvers.options import clear_options, set_default_option
from petsoft.solvers.static import StaticSolver


def test_huge_load_inverts_elements_then_recovers_with_smaller_increments():
    """A one-step neo-Hookean solve that inverts elements retries smaller steps and converges to
    the same equilibrium as a run that starts with small increments."""
    exp = experiment_from_dict({
        "mesh": {"box": {"size": [0.4, 0.04, 0.04], "cells": [8, 2, 2]}},
        "material": {"model": "neohookean", "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                     "density": 1100.0},
        "boundary": [{"kind": "fixed", "where": "x < 1e-6"},
                     {"kind": "traction", "where": "x > 0.4 - 1e-6", "value": [0, 0, -3e6]}],
        "output": {"directory": "unused"},
    })
    lines = []
    results, counts = [], []
    direct = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
    for key, value in direct.items():
        set_default_option(key, value)
    for steps in (1, 32):
        model = build_model(exp)
        solver = StaticSolver(model, load_steps=steps, monitor=lines.append)
        r = solver.solve()
        u = model.dmesh.gather_global(r.displacement)
        results.append((r.retries, MPI.COMM_WORLD.bcast(u)))
        # the SNES held once, on every rank: an inverted trial's exception kept with its
        # traceback (whose frames hold the SNES callback's arguments) made its destruction
        # wait for a garbage collection, at different moments on different ranks, and MUMPS's
        # destruction is collective (the hang this test had on 2 ranks)
        counts.append(MPI.COMM_WORLD.allgather(solver.snes.getRefCount()))
        solver.destroy()
    clear_options(direct)
    assert counts == [[1] * MPI.COMM_WORLD.size] * 2, counts
    (retries_one, u_one), (_, u_many) = results
    assert retries_one > 0
    if MPI.COMM_WORLD.rank == 0:
        assert any("inverted" in line for line in lines)
        # every load step but the last says roughly how long the rest takes
        done = [line for line in lines if "Newton iterations" in line]
        assert len(done) >= 33 and "left" not in done[-1]
        assert all("s left" in line for line in done[-32:-1])
    assert np.isfinite(u_one).all()
    assert np.abs(u_one - u_many).max() <= 1e-7 * np.abs(u_many).max()
