"""An experiment's [petsc] options reach its solvers, stay only while they are set up and solve,
and lose to the command line (petsoft.solvers.options.SolverOptions)."""

from __future__ import annotations

from petsc4py import PETSc

from petsoft.dynamics.run_simulation import simulate_experiment
from petsoft.experiment import experiment_from_dict
from petsoft.solvers.options import SolverOptions
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


def test_nested_pushes_remove_only_what_they_inserted():
    opts = PETSc.Options()
    outer_options = SolverOptions("", {"ksp_type": "cg"}, defaults={"ksp_rtol": "1e-3"})
    with outer_options.pushed():
        assert opts.getString("ksp_rtol") == "1e-3"
        inner_options = SolverOptions("", {"ksp_type": "gmres", "pc_type": "sor"})
        with inner_options.pushed(ksp_rtol="1e-5"):
            assert opts.getString("ksp_type") == "cg"          # the outer block's stays
            assert opts.getString("pc_type") == "sor"
            assert opts.getString("ksp_rtol") == "1e-5"        # an inner default replaces it
        assert opts.hasName("ksp_type") and not opts.hasName("pc_type")
        assert opts.getString("ksp_rtol") == "1e-3"            # ... and gives it back
    for key in ("ksp_type", "pc_type", "ksp_rtol"):
        assert not opts.hasName(key)


def test_prefixed_keys_and_copies():
    """A key written with the prefix is pushed as it is and wins over a copied one; keys of
    other prefixes are not pushed; the root prefix takes every key."""
    table = {"ksp_type": "gmres", "fm_ksp_type": "bcgs", "pc_type": "sor", "cal_tao_max_it": "3",
             "snes_rtol": "1e-9", "ts_alpha_radius": "0.3"}
    fm = SolverOptions("fm_", table, ("ksp_", "pc_", "snes_"))
    assert fm.values == {"fm_ksp_type": "bcgs", "fm_pc_type": "sor", "fm_snes_rtol": "1e-9"}
    grad = SolverOptions("fm_grad_", table, ("ksp_", "pc_"))
    assert grad.values == {"fm_grad_ksp_type": "gmres", "fm_grad_pc_type": "sor"}
    assert SolverOptions("cal_", table).values == {"cal_tao_max_it": "3"}
    assert SolverOptions("", table).values == table
    assert SolverOptions("", table).under("cal_").values == {"cal_tao_max_it": "3"}


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


def test_every_prefix_is_documented():
    """The README's table of prefixes names every prefix petsoft's solvers use."""
    from pathlib import Path

    from petsoft.solvers.options import PREFIXES

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    table = readme[readme.index("| prefix | solver |"):]
    table = table[:table.index("\n\n")]
    missing = [p for p in PREFIXES if p and f"`{p}`" not in table]
    assert not missing, f"prefixes missing from README.md's table: {missing}"
