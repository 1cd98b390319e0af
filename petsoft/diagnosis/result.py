"""The value :func:`petsoft.diagnose` returns: the fields :mod:`petsoft.diagnosis.outputs`
writes from, with the API's conventions (:mod:`petsoft.results`) on top: ``success`` (the final
model explains the recording to the noise), ``message``, the final parameters by name and a
short repr (the fields hold whole simulations and the report)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from petsoft.diagnosis.context import Fit
from petsoft.diagnosis.records import Evidence
from petsoft.results import FitResult


@dataclass(repr=False)
class DiagnoseResult(FitResult):
    """What ``petsoft diagnose`` found (identical on every rank).

    ``verdict`` is about the model as given, ``final_verdict`` about the model as diagnosed;
    ``params``/``param_std`` are the final fit's values by name (the calibrated ones and those
    of the added physics); ``added`` the physics added, with values and std.
    """

    verdict: str
    final_verdict: str
    report: dict
    base: Fit
    final: Fit
    added: list[dict] = field(default_factory=list)
    rejected: list[dict] = field(default_factory=list)
    scores: list[dict] = field(default_factory=list)
    not_modelled: dict = field(default_factory=dict)
    numerics: dict = field(default_factory=dict)
    evidence: Evidence | None = None

    @property
    def names(self) -> list[str]:
        return list(self.final.names)

    @property
    def values(self) -> np.ndarray:
        return np.asarray(self.final.values, dtype=float)

    @property
    def std(self) -> np.ndarray:
        return np.asarray(self.final.std, dtype=float)

    @property
    def success(self) -> bool:
        return self.final_verdict == "consistent"

    @property
    def message(self) -> str:
        added = ", ".join(a["physics"] for a in self.added) or "nothing"
        return (f"the model as given: {self.verdict}; added {added}; the model as diagnosed: "
                f"{self.final_verdict}")
