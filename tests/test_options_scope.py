"""An experiment's [petsc] options reach its solvers, stay only while it runs, and lose to the
command line (petsoft.solvers.options.experiment_options)."""

from __future__ import annotations

from petsc4py import PETSc

from petsoft.dynamics.run_simulation import simulate_experiment
from petsoft.experiment import experiment_from_dict
from petsoft.solvers.options import experiment_options
from petsoft.solvers.run_static import solve_experiment

BAR = {
    "mesh": {"box": {"size": [0.2, 0.04, 0.04], "cells": [4, 1, 1]}},
    "material": {"model": "linear", "youngs_modulus": 1e6, "poisson_ratio": 0.3,
                 "density": 1000.0},
    "gravity": {"acceleration": [0.0, 0.0, -9.81]},
    "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
    "petsc": {"ksp_type": "gmres", "pc_type": "jacobi", "ksp_rtol": "1e-12"},
    "output": {"directory": "unused"},
}


def test_the_experiment_options_reach_the_solver_and_are_gone_after():
    opts = PETSc.Options()
    assert not opts.hasName("ksp_type")
    outcome = solve_experiment(experiment_from_dict(BAR))
    assert (outcome.ksp_type, outcome.pc_type) == ("gmres", "jacobi")
    for key in BAR["petsc"]:
        assert not opts.hasName(key), f"{key} left in the global options database"
    # the next experiment, without a [petsc] table, gets petsoft's defaults again
    plain = solve_experiment(experiment_from_dict({**BAR, "petsc": {}}))
    assert (plain.ksp_type, plain.pc_type) != ("gmres", "jacobi")


def test_the_command_line_wins_and_stays():
    opts = PETSc.Options()
    opts.setValue("ksp_type", "bcgs")           # as `petsoft static exp.toml -ksp_type bcgs`
    try:
        outcome = solve_experiment(experiment_from_dict(BAR))
        assert outcome.ksp_type == "bcgs" and outcome.pc_type == "jacobi"
        assert opts.getString("ksp_type") == "bcgs"
        assert not opts.hasName("pc_type")
    finally:
        opts.delValue("ksp_type")


def test_nested_blocks_remove_only_what_they_inserted():
    opts = PETSc.Options()
    with experiment_options({"ksp_type": "cg"}) as outer:
        with experiment_options({"ksp_type": "gmres", "pc_type": "sor"}) as inner:
            assert opts.getString("ksp_type") == "cg"          # the outer block's stays
            assert inner == ["pc_type"]
        assert opts.hasName("ksp_type") and not opts.hasName("pc_type")
        assert outer == ["ksp_type"]
    assert not opts.hasName("ksp_type")


def test_a_dynamic_run_uses_the_experiment_options_and_leaves_none_behind(tmp_path):
    """Backward Euler on a small bar with [petsc] ksp_type = cg, pc_type = jacobi: each Newton
    iteration takes several linear iterations (fewer with petsoft's default: a direct solve for
    so few unknowns in serial, a looser tolerance in parallel), and no key is in the global
    options database after the run."""
    data = {**BAR, "initial": {"displacement": ["0", "0", "0.3*x**2"]},
            "time": {"end": 0.004, "step": 2e-3, "integrator": "be"},
            "petsc": {"ksp_type": "cg", "pc_type": "jacobi", "ksp_rtol": "1e-12"}}
    krylov = simulate_experiment(experiment_from_dict(data), out=tmp_path / "cg")
    assert krylov.newton_iterations > 0
    assert krylov.linear_iterations > 2 * krylov.newton_iterations
    opts = PETSc.Options()
    for key in data["petsc"]:
        assert not opts.hasName(key), f"{key} left in the global options database"
    direct = simulate_experiment(experiment_from_dict({**data, "petsc": {}}),
                                 out=tmp_path / "default")
    assert direct.linear_iterations < krylov.linear_iterations
