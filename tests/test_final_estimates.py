"""The final numerics check quotes Richardson's estimate for a halved step the last round adopted
(issue 40, item 3: "the step/2 test only where the time step can matter").

:func:`petsoft.diagnosis.numerics.final_estimates` decides; :func:`numerics_check` then writes an
``estimated`` entry instead of simulating, and the report's sentences say it was estimated.
"""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from _numerics_records import linearised, numerics_round
from _numerics_records import refitted as refitted_option

from petsoft.diagnosis.numerics import ESTIMATE_FINAL_BELOW, final_estimates
from petsoft.diagnosis.numerics_records import FinalChange, FinalCheck

SIGMA = 1e-4


def _rounds(label="step/2", same=0.36, refitted=0.23, share=1.0 / 3.0, params=None):
    """A last numerics round that adopted ``label``: its change at the same parameters and
    refitted (in noise units) and Richardson's share (remaining_estimate / change_rms)."""
    option = refitted_option(change_same_parameters=same * SIGMA, change_rms=refitted * SIGMA,
                       remaining_estimate=refitted * SIGMA * share,
                       parameters=params if params is not None
                       else {"material.youngs_modulus": 2.0e7})
    return [numerics_round({"P2": refitted_option()}, adopted="P2"),
            numerics_round({label: option}, adopted=label)]



def _fit(e=2.0e7):
    return SimpleNamespace(names=["material.youngs_modulus"], values=np.array([e]))


DIAG = SimpleNamespace(sigma=SIGMA)


def test_a_step_adopted_last_on_the_final_model_is_estimated():
    # the change at the same parameters times Richardson's share: 0.36 / 3
    assert final_estimates(DIAG, _rounds(), _fit()) == {"step/2": pytest.approx(0.12)}


def test_what_is_not_estimated():
    # near the noise: simulated
    big = 4.0 * ESTIMATE_FINAL_BELOW       # times 1/3: above the threshold
    assert final_estimates(DIAG, _rounds(same=big), _fit()) == {}
    # the final model is not the adopting refit (a term added or refitted since)
    assert final_estimates(DIAG, _rounds(), _fit(2.1e7)) == {}
    # the last round adopted a mesh, not a step; or nothing; or there was no round
    assert final_estimates(DIAG, _rounds(label="mesh x2"), _fit()) == {}
    assert final_estimates(DIAG, [numerics_round({})], _fit()) == {}
    assert final_estimates(DIAG, [], _fit()) == {}


def test_the_report_says_the_final_change_was_estimated():
    from petsoft.diagnosis.numerics_findings import numerics_summary

    rounds = _rounds()
    step = replace(rounds[-1].options["step/2"], how="step 0.001 s -> 0.0005 s",
                   change_over_noise=0.23, change_same_parameters_over_noise=0.23, matters=True)
    rounds[-1] = replace(rounds[-1], options={"step/2": step})
    p2 = refitted_option(how="4-node -> 10-node", change_over_noise=27.0, matters=True)
    rounds[0] = replace(rounds[0], options={"P2": p2})
    change = FinalChange(rms=None, change=0.12 * SIGMA, change_over_noise=0.12,
                         how="step 0.0005 s -> 0.00025 s", resolved=True, estimated=True)
    num = FinalCheck(base_rms_all=SIGMA, changes={"step/2": change})
    final = SimpleNamespace(experiment=SimpleNamespace(
        time=SimpleNamespace(step=0.0005), mesh=SimpleNamespace(order=2)))
    summary, adopted, _ = numerics_summary(num, rounds, final, SIGMA)
    (step,) = [s for s in summary if s.startswith("Time step")]
    assert "would change the simulation by an estimated 0.12x" in step and "not simulated" in step
    num = FinalCheck(base_rms_all=SIGMA, changes={"step/2": replace(change, estimated=False)})
    (step,) = [s for s in numerics_summary(num, rounds, final, SIGMA)[0]
               if s.startswith("Time step")]
    assert "changes the simulation by 0.12x" in step and "estimated" not in step


def test_the_summary_says_a_counted_mesh_error_is_counted():
    """A measured split mesh that moves the simulation by more than the noise at the same
    parameters but whose refit comes closer to the data, its error counted (the realistic 5k
    taper: 10.6x, 0.295x refitted, 0.39x counted), is not said to have come no closer."""
    from petsoft.diagnosis.numerics_findings import numerics_summary

    mesh = linearised(how="every tet split 1->8", change_over_noise=0.295,
                      change_same_parameters_over_noise=10.6, matters=True, gain=2019.0,
                      error_estimate=0.394 * SIGMA, measured_only=True)
    rounds = [numerics_round({"mesh x2": mesh})]
    final = SimpleNamespace(experiment=SimpleNamespace(
        time=SimpleNamespace(step=0.002), mesh=SimpleNamespace(order=1)))

    def mesh_said(rounds):
        (said,) = [s for s in numerics_summary(None, rounds, final, SIGMA)[0]
                   if s.startswith("Mesh")]
        return said

    said = mesh_said(rounds)
    assert "changes the simulation by 11x the noise, 0.29x after a refit" in said, said
    assert "estimated at 0.39x the noise, is counted" in said and "no closer" not in said
    # no error counted (the refit came no closer): said so
    mesh = replace(mesh, error_estimate=0.0, gain=-5.0, matters=False)
    said = mesh_said([numerics_round({"mesh x2": mesh})])
    assert "came no closer to the data" in said, said
    # closer to the data but neither counted nor adopted (another refinement was adopted in
    # its round): not said to have come no closer
    mesh = replace(mesh, gain=40.0, matters=True)
    p2 = refitted_option(how="4-node -> 10-node", change_over_noise=30.0, matters=True)
    rounds = [numerics_round({"mesh x2": mesh, "P2": p2}, adopted="P2")]
    said = mesh_said(rounds)
    assert "brought it closer to the data, but it was not adopted" in said, said
    assert "no closer" not in said
    # an earlier round's closer refit does not speak for the last one, which came no closer
    rounds.append(numerics_round({"mesh x2": replace(mesh, gain=-3.0, matters=False)}))
    said = mesh_said(rounds)
    assert "came no closer to the data" in said, said


def test_a_small_remaining_step_error_is_counted_instead_of_halving_again():
    from petsoft.diagnosis.numerics import estimated_instead, next_halving_estimate

    rounds = _rounds(same=0.77, refitted=0.25)
    o = rounds[-1].options["step/2"]
    # Richardson: the adopting change at the same parameters times the share, 0.77 / 3
    assert next_halving_estimate(o, SIGMA) == pytest.approx(0.77 / 3.0)
    why = estimated_instead(o, SIGMA)
    assert why is not None and "0.26x the noise" in why and "not simulated" in why
    # the threshold is the final check's: above it, the step is halved again
    above = _rounds(same=3.01 * ESTIMATE_FINAL_BELOW)[-1].options["step/2"]
    assert estimated_instead(above, SIGMA) is None
    below = _rounds(same=2.99 * ESTIMATE_FINAL_BELOW)[-1].options["step/2"]
    assert estimated_instead(below, SIGMA) is not None
