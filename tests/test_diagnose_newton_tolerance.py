"""diagnose builds its forward models at its own Newton tolerance (context.NEWTON_RTOL) as a
caller's default that the experiment's [petsc] fm_snes_rtol and the user's -fm_snes_rtol
override, and puts nothing into the options database itself."""

from petsc4py import PETSc

import petsoft.diagnosis.diagnose as diagnose
from petsoft.calibration.forward import forward_options
from petsoft.diagnosis.context import NEWTON_RTOL
from petsoft.solvers.options import clear_options


def _seen_rtol(monkeypatch, table=None, user=False):
    # the diagnosis itself replaced by a probe of the Newton tolerance its forward models'
    # solvers read (their options pushed, as while a forward model's solver is set up)
    def probe(*a, **k):
        assert PETSc.Options().hasName("fm_snes_rtol") == user
        with forward_options(table).pushed():
            return PETSc.Options().getString("fm_snes_rtol", None)

    monkeypatch.setattr(diagnose, "_run_diagnose", probe)
    return diagnose.run_diagnose(None, None)


def test_the_forward_runs_of_a_diagnosis_stop_newton_at_its_tolerance(monkeypatch):
    assert not PETSc.Options().hasName("fm_snes_rtol")
    assert float(_seen_rtol(monkeypatch)) == NEWTON_RTOL == 1e-6
    assert not PETSc.Options().hasName("fm_snes_rtol")      # removed after the run
    # outside a diagnosis the forward model's own default
    with forward_options().pushed():
        assert PETSc.Options().getReal("fm_snes_rtol") == 1e-12


def test_the_experiments_newton_tolerance_wins(monkeypatch):
    assert float(_seen_rtol(monkeypatch, {"fm_snes_rtol": "1e-8"})) == 1e-8


def test_the_users_newton_tolerance_wins(monkeypatch):
    PETSc.Options().setValue("fm_snes_rtol", "1e-9")
    try:
        assert float(_seen_rtol(monkeypatch, {"fm_snes_rtol": "1e-8"}, user=True)) == 1e-9
        assert PETSc.Options().getString("fm_snes_rtol") == "1e-9"   # the user's, kept
    finally:
        clear_options(["fm_snes_rtol"])
