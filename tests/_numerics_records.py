"""Numerics records for the unit tests of the numerics check and its findings: every field the
test does not name gets a neutral value (:mod:`petsoft.diagnosis.numerics_records`)."""

from __future__ import annotations

from petsoft.diagnosis.numerics_records import LinearisedOption, NumericsRound, RefittedOption

#: A refinement's outcome with nothing in it: no change, no gain, nothing counted.
NEUTRAL = {"chi2": 0.0, "chi2_per_dof": 0.0, "gain": 0.0, "matters": False, "change_rms": 0.0,
           "change_over_noise": 0.0, "change_same_parameters": 0.0, "how": "",
           "parameters": {}, "refit": "calibrated", "error_estimate": 0.0,
           "remaining_estimate": 0.0}


def _fields(fields: dict) -> dict:
    # a change at the same parameters not named is the refitted one (as the reports' sentences
    # once read a dict without it)
    same = fields.get("change_same_parameters_over_noise",
                      fields.get("change_over_noise", 0.0))
    return {**NEUTRAL, "change_same_parameters_over_noise": same, **fields}


def refitted(**fields) -> RefittedOption:
    """A refitted refinement's option with ``fields``, the others :data:`NEUTRAL`."""
    return RefittedOption(**_fields(fields))


def linearised(**fields) -> LinearisedOption:
    """A linearised (screened or measured) refinement's option with ``fields``."""
    return LinearisedOption(**_fields({"refit": "linearised refit", **fields}))


def numerics_round(options: dict, **fields) -> NumericsRound:
    """A round with ``options`` and ``fields``; chi2 0 on 1 dof at a 1 ms step otherwise."""
    return NumericsRound(**{"chi2": 0.0, "dof": 1, "step": 0.001, "options": options,
                            "parameters": {}, **fields})
