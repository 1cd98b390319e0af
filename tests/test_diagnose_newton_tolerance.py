"""diagnose runs its forward models at its own Newton tolerance (context.NEWTON_RTOL) as a
caller's option that the user's -fm_snes_rtol overrides, and leaves the options database as it
found it."""

from petsc4py import PETSc

import petsoft.diagnosis.diagnose as diagnose
from petsoft.diagnosis.context import NEWTON_RTOL
from petsoft.solvers.options import clear_options


def _seen_rtol(monkeypatch):
    # the diagnosis itself replaced by a probe of the options its forward models would read
    monkeypatch.setattr(diagnose, "_run_diagnose",
                        lambda *a, **k: PETSc.Options().getString("fm_snes_rtol", None))
    return diagnose.run_diagnose(None, None)


def test_the_forward_runs_of_a_diagnosis_stop_newton_at_its_tolerance(monkeypatch):
    assert not PETSc.Options().hasName("fm_snes_rtol")
    assert float(_seen_rtol(monkeypatch)) == NEWTON_RTOL == 1e-6
    assert not PETSc.Options().hasName("fm_snes_rtol")      # removed after the run


def test_the_users_newton_tolerance_wins(monkeypatch):
    PETSc.Options().setValue("fm_snes_rtol", "1e-9")
    try:
        assert float(_seen_rtol(monkeypatch)) == 1e-9
        assert PETSc.Options().getString("fm_snes_rtol") == "1e-9"   # the user's, kept
    finally:
        clear_options(["fm_snes_rtol"])
