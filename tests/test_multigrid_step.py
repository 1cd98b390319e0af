"""Newton steps preconditioned by algebraic multigrid: one GAMG set-up per step and Krylov
tolerances by Eisenstat-Walker (petsoft.solvers.linear.multigrid_once_per_step), to the same
Newton tolerance as the default direct solve; options that name either keep the solver as
they made it. On 1 and 2 ranks."""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

from petsoft.dynamics.alpha import GeneralizedAlpha
from petsoft.dynamics.implicit import ImplicitIntegrator
from petsoft.dynamics.system import DynamicSystem
from petsoft.experiment import experiment_from_dict
from petsoft.physics.model import build_model
from petsoft.solvers.options import scoped_defaults

H = 0.004


def _system():
    exp = experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [24, 3, 3]}},
        "material": {"model": "neohookean", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "time": {"end": 0.02, "step": H, "integrator": "be"},
    }, source="test_multigrid_step")
    return DynamicSystem(build_model(exp))


def _stepper(method, system, prefix):
    if method == "alpha":
        return GeneralizedAlpha(system, radius=0.9, prefix=prefix)
    return ImplicitIntegrator(system, method, prefix=prefix)


def _gamg_setups() -> PETSc.Log.Event:
    """PETSc's log event of a GAMG hierarchy's set-up (registered with the GAMG package: a PC
    of that type is made first, else the name would register a new, empty event)."""
    pc = PETSc.PC().create(comm=PETSc.COMM_SELF)
    pc.setType(PETSc.PC.Type.GAMG)
    pc.destroy()
    return PETSc.Log.Event("PCSetUp_GAMG+")


def _one_step(method, system, prefix, options):
    """One step from rest in a bend (so Newton iterates): the solution, the stepper and the
    number of GAMG hierarchies the step set up."""
    with scoped_defaults(**{prefix + k: v for k, v in options.items()}):
        stepper = _stepper(method, system, prefix)
        q0, v0 = system.create_vec(), system.create_vec()
        x = system.dmesh.points[system.dmesh.owned][:, 0]
        bend = np.zeros((len(x), 3))
        bend[:, 2] = 0.3 * x ** 2          # lifted tip: the bar springs back under gravity
        system.dmesh.set_global_from_local(np.vstack([bend, np.zeros(
            (system.dmesh.nvertices - len(x), 3))]), q0)
        system.apply_prescribed(q0, 0.0)
        v0.zeroEntries()
        q1, v1 = q0.duplicate(), v0.duplicate()
        setups = _gamg_setups()
        before = setups.getPerfInfo()["count"]
        report = stepper.step(0.0, q0, v0, H, q1, v1)
        count = setups.getPerfInfo()["count"] - before
    assert report.converged, report.reason
    return q0, q1, stepper, report, count


@pytest.mark.parametrize("method", ["be", "alpha"])
def test_multigrid_step_sets_up_once_and_converges_as_the_direct_one(method):
    PETSc.Log.begin()
    system = _system()
    q0, direct, _, _, _ = _one_step(method, system, "mgref_", {})
    _, q1, stepper, report, setups = _one_step(
        method, system, "mg_", {"ksp_type": "cg", "pc_type": "gamg"})
    snes = stepper.snes
    assert snes.getKSP().getPC().getType() == PETSc.PC.Type.GAMG
    assert snes.getUseEW()
    assert report.newton_iterations >= 3
    assert setups == 1, (setups, report.newton_iterations)
    moved = direct.copy()
    moved.axpy(-1.0, q0)
    diff = q1.copy()
    diff.axpy(-1.0, direct)
    assert diff.norm() <= 1e-8 * moved.norm(), (diff.norm(), moved.norm())


def test_options_that_name_the_lag_or_the_tolerances_keep_their_solver():
    PETSc.Log.begin()
    system = _system()
    _, _, stepper, report, setups = _one_step(
        "be", system, "mgopt_", {"ksp_type": "cg", "pc_type": "gamg", "snes_ksp_ew": "false"})
    assert not stepper.snes.getUseEW()
    assert setups == report.newton_iterations >= 2      # a hierarchy every Newton iteration
    # the semi-implicit step (one linear solve) is never inexact
    _, _, stepper, _, _ = _one_step("si", system, "mgsi_", {"ksp_type": "cg", "pc_type": "gamg"})
    assert not stepper.snes.getUseEW()
