"""Tangent solves on a factorisation kept across steps (petsoft.solvers.lagged_factors).

1. :class:`LaggedFactors` on a matrix changed in place: a small change is solved by a few GMRES
   iterations on the old factors, to the tolerance, with no new factorisation; a solve needing
   more than ``REFACTOR_ITERATIONS`` has the next matrix factored; a solve that fails is
   repeated at once on fresh factors and is right; the lent ``preonly`` KSP applies the kept
   factors (the old matrix's inverse), not the current matrix's; on the current matrix's own
   factors a solve is that lender's one substitution; several solves a step on kept factors
   renew them once their iterations exceed a factorisation's cost (``FACTOR_IN_ITERATIONS``).
2. :meth:`ForwardModel.jacobian` of be, si and alpha on small 4- and 10-node bars (12 steps):
   the sensitivities on kept factors equal those of the every-step factorisation
   (``lags_factors = False``) to 1e-8, both equal central differences of ``simulate`` to 1e-5,
   and the kept path factored fewer times than there are steps with GMRES iterating on stale
   factors (more iterations than solves).
3. A tangent solver chosen by options (a direct or an iterative one) stays as chosen.

(The Taylor tests of tests/test_sensitivity.py run the kept path, the default; the counts of a
run's factorisations are in tests/test_borrowed_chord.py.)
"""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

import petsoft.solvers.lagged_factors as lf
from petsoft.calibration.forward import ForwardModel
from petsoft.calibration.observation import MarkerObserver
from petsoft.experiment import experiment_from_dict
from petsoft.solvers.lagged_factors import LaggedFactors
from petsoft.solvers.linear import is_direct, linear_defaults
from petsoft.solvers.options import clear_options

N = 120


def _matrix(comm, shift=0.0):
    """Tridiagonal (-1, 2 + 1e-2 + shift_i, -1) of size N on ``comm`` (shift an array or 0)."""
    A = PETSc.Mat().createAIJ([N, N], nnz=3, comm=comm)
    lo, hi = A.getOwnershipRange()
    diag = 2.0 + 1e-2 + np.broadcast_to(shift, (N,))
    for i in range(lo, hi):
        A.setValue(i, i, diag[i])
        if i > 0:
            A.setValue(i, i - 1, -1.0)
        if i < N - 1:
            A.setValue(i, i + 1, -1.0)
    A.assemble()
    return A


def _set_diagonal(A, shift) -> None:
    """Add ``shift`` (N,) to A's diagonal in place (the same nonzero pattern)."""
    lo, hi = A.getOwnershipRange()
    d = A.getDiagonal()
    d.getArray()[:] += np.asarray(shift)[lo:hi]
    A.setDiagonal(d)
    d.destroy()


def _direct(A):
    ksp = PETSc.KSP().create(comm=A.getComm())
    linear_defaults(ksp, dofs=N)     # the default direct solve (LU; redundant on 2 ranks)
    ksp.setOperators(A)
    assert is_direct(ksp)
    return ksp


def _residual(A, x, b) -> float:
    r = b.duplicate()
    A.mult(x, r)
    r.axpy(-1.0, b)
    out = r.norm() / b.norm()
    r.destroy()
    return out


def test_lagged_factors_iterate_refactor_and_lend(monkeypatch):
    comm = PETSc.COMM_WORLD
    A = _matrix(comm)
    ksp = _direct(A)
    solver = LaggedFactors(ksp)
    b, x = A.createVecs()
    b.setArray(np.sin(np.arange(*b.getOwnershipRange())) + 1.0)
    solver.operator_changed()
    assert solver.factorisations == 1
    solver.solve(b, x)
    # on the current matrix's own factors: one substitution by the preonly lender, exact
    assert solver.last_solver is solver.factors and solver.factors.getConvergedReason() > 0
    assert _residual(A, x, b) < 1e2 * lf.RTOL
    # the factors of A, kept for the lender below
    old = _direct(_matrix(comm))
    # 1. a small change: a few iterations, to the tolerance, nothing factored
    rng = np.random.default_rng(0)
    _set_diagonal(A, 1e-3 * rng.uniform(size=N))
    solver.operator_changed()
    solver.solve(b, x)
    its = ksp.getIterationNumber()
    assert solver.last_solver is ksp
    assert ksp.getConvergedReason() > 0 and 1 < its <= lf.REFACTOR_ITERATIONS, its
    assert _residual(A, x, b) < 1e2 * lf.RTOL
    assert solver.factorisations == 1
    # the lender applies A's (old) factors, not the changed matrix's inverse
    y, z = A.createVecs()
    solver.factors.solve(b, y)
    old.solve(b, z)
    z.axpy(-1.0, y)
    assert z.norm() <= 1e-12 * y.norm()
    assert _residual(A, y, b) > 1e3 * lf.RTOL
    # 2. a solve that needed more than the threshold: the next matrix is factored
    monkeypatch.setattr(lf, "REFACTOR_ITERATIONS", 1)
    _set_diagonal(A, 1e-3 * rng.uniform(size=N))
    solver.operator_changed()
    assert solver.factorisations == 1
    solver.solve(b, x)
    assert ksp.getIterationNumber() > 1
    solver.operator_changed()
    assert solver.factorisations == 2
    solver.solve(b, x)
    assert solver.last_solver is solver.factors      # on the current matrix's own factors
    assert _residual(A, x, b) < 1e2 * lf.RTOL
    monkeypatch.undo()
    # 3. a change GMRES cannot follow within MAX_IT: refactored at once, solved right
    _set_diagonal(A, 10.0 * rng.uniform(size=N) ** 4)
    solver.operator_changed()
    before = solver.iterations
    solver.solve(b, x)
    assert solver.iterations - before > lf.MAX_IT      # the failed attempt's iterations too
    assert solver.factorisations == 3
    assert ksp.getConvergedReason() > 0 and _residual(A, x, b) < 1e2 * lf.RTOL
    assert solver.stats()["solves"] == 5
    # 4. many solves a step, each within the threshold: once the iterations made on the
    # factors exceed a factorisation's cost, the next matrix is factored
    monkeypatch.setattr(lf, "FACTOR_IN_ITERATIONS", 5)
    made = solver.factorisations
    for step in range(3):
        _set_diagonal(A, 1e-3 * rng.uniform(size=N))
        solver.operator_changed()
        if step == 0:
            assert solver.factorisations == made       # the factors of the last matrix
        for _ in range(3):                              # three parameters
            solver.solve(b, x)
            assert _residual(A, x, b) < 1e2 * lf.RTOL
        if step == 0:
            assert solver.last_solver is ksp and ksp.getIterationNumber() > 1
    assert solver.factorisations > made
    monkeypatch.undo()
    assert solver.stats()["solves"] == 5 + 9
    solver.destroy()
    for obj in (ksp, old, A, b, x, y, z):
        obj.destroy()


# -- 2. forward sensitivities ---------------------------------------------------------------------
NAMES = ["material.youngs_modulus", "damping.mass"]
MARKERS = np.array([[0.3, 0.04, 0.04], [0.3, 0.0, 0.0], [0.15, 0.02, 0.04]])
STEPS, H = 12, 2e-3


def _bar(method, order):
    return experiment_from_dict({
        "mesh": {"box": {"size": [0.3, 0.04, 0.04], "cells": [4, 1, 1]}, "order": order},
        "material": {"model": "neohookean", "youngs_modulus": 1e5, "poisson_ratio": 0.3,
                     "density": 1000.0},
        "gravity": {"acceleration": [0.0, 0.0, -9.81]},
        "damping": {"mass": 0.5},
        "boundary": [{"kind": "fixed", "where": "x < 1e-9"}],
        "initial": {"displacement": ["0", "0", "0.3*x**2"], "velocity": ["0", "0.1*x", "0"]},
        "time": {"end": STEPS * H, "step": H, "integrator": method},
    })


@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("method", ["be", "si", "alpha"])
def test_sensitivities_on_kept_factors_equal_every_step_ones(method, order):
    fm = ForwardModel(_bar(method, order), NAMES, lambda s: MarkerObserver(s, MARKERS),
                      np.arange(1, STEPS + 1) * H)
    p = fm.p0.copy()
    jac = {}
    for lag in (False, True):
        fm.lags_factors = lag
        fm.stats.pop("tangent_solves", None)
        _, jac[lag] = fm.jacobian(p)
    stats = fm.stats["tangent_solves"]
    scale = np.abs(jac[False]).max(axis=(0, 1, 2))
    rel = np.abs(jac[True] - jac[False]).max(axis=(0, 1, 2)) / scale
    if PETSc.COMM_WORLD.getRank() == 0:
        print(f"{method} P{order}: kept vs every-step factors {rel}, {stats}")
    assert np.all(rel <= 1e-8), rel
    # the kept path did keep factors: fewer than one a step, GMRES iterating on stale ones
    # (how many fewer, on a longer run: tests/test_borrowed_chord.py)
    assert stats["solves"] == STEPS * len(NAMES)
    assert stats["factorisations"] < STEPS, stats
    assert stats["iterations"] > stats["solves"], stats
    # both against central differences (as tests/test_sensitivity.py checks the default path)
    fd = fm.fd_jacobian(p)
    for lag in (False, True):
        err = np.abs(jac[lag] - fd).max(axis=(0, 1, 2)) / scale
        assert np.all(err < 1e-5), (lag, err)
    fm.destroy()


@pytest.mark.parametrize("options", [{"fm_grad_ksp_type": "preonly", "fm_grad_pc_type": "lu"},
                                     {"fm_grad_pc_type": "jacobi"}], ids=["lu", "jacobi"])
def test_a_solver_chosen_by_options_is_left_as_it_is(options):
    """A tangent solver named by options (direct or iterative) is not turned into GMRES on kept
    factors: the run reports no kept-factor solves, and its sensitivities equal the default
    path's to the solvers' tolerances."""
    fm = ForwardModel(_bar("be", 1), NAMES, lambda s: MarkerObserver(s, MARKERS),
                      np.arange(1, 6) * H)
    _, default = fm.jacobian(fm.p0)
    assert "tangent_solves" in fm.stats
    fm.stats.clear()
    db = PETSc.Options()
    for key, value in options.items():
        db.setValue(key, value)
    try:
        _, chosen = fm.jacobian(fm.p0)
    finally:
        clear_options(list(options))
    assert "tangent_solves" not in fm.stats
    rel = np.abs(chosen - default).max() / np.abs(default).max()
    assert rel <= 1e-8, rel
    fm.destroy()
