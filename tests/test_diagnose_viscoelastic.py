"""diagnose fits a viscoelastic branch by forward sensitivities with generalized-alpha.

The branch's internal variable is part of alpha's (and backward Euler's) forward sensitivities
(tests/test_viscoelastic.py: Taylor tests), so a diagnosis with the alpha integrator fits a
standard linear solid by Gauss-Newton on exact columns instead of finite differences (about
four runs an iteration for E, g and tau: a branch fit on the independent L-bracket took
1145 s). Checked on the tapered cantilever (tests/_taper.py) recorded with a branch:
measured 6 iterations, g and tau within 1 std of the truth; the same fit by finite
differences (same iterations, chi2 equal to 1e-10) took 3.1-3.4 s against 1.2-1.3 s, side by
side on the loaded 2-core machine.
"""

from pathlib import Path

import pytest
from _taper import taper, taper_diagnosis
from mpi4py import MPI

from petsoft.diagnosis.context import gradient_for

NOISE = 2e-5
TRUTH = {"viscoelastic.ratio": 0.3, "viscoelastic.relaxation_time": 0.01}
BRANCH = '[viscoelastic]\nratio = {g}\nrelaxation_time = {tau}\n'
CALIBRATE = ('[calibrate]\n"material.youngs_modulus" = [1e6, 1e8]\n'
             '"viscoelastic.ratio" = [0.0, 2.0]\n'
             '"viscoelastic.relaxation_time" = [0.001, 0.3]\n')


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    d = Path(MPI.COMM_WORLD.bcast(str(tmp_path_factory.mktemp("visco_diag"))))
    return taper_diagnosis(d, taper(2.0e7, extra=BRANCH.format(g=0.3, tau=0.01)),
                           taper(1.8e7, extra=BRANCH.format(g=0.05, tau=0.02),
                                 calibrate=CALIBRATE), seed=3, noise=NOISE)


def test_the_branch_is_fitted_by_alpha_sensitivities(case):
    diag, exp = case
    assert exp.time.integrator == "alpha"
    assert gradient_for(exp, "sensitivity") == "sensitivity"
    assert gradient_for(exp, "sensitivity", "si") == "fd"       # si does not carry z
    fit = diag.calibrate(exp)
    got = dict(zip(fit.names, fit.values, strict=True))
    std = dict(zip(fit.names, fit.std, strict=True))
    for name, true in TRUTH.items():
        assert abs(got[name] - true) < max(3.0 * std[name], 0.02 * true), (name, got, std)
    assert got["material.youngs_modulus"] == pytest.approx(2.0e7, rel=0.01)
    assert fit.chi2 / diag.dof(3) < 1.3
    print(f"fit {got} +- {std}: {fit.iterations} iterations, {fit.evaluations} runs")
