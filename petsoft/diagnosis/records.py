"""The diagnosis' typed records: what one candidate's score test gave and what its round made
of it (:class:`ScoreEntry`), what the tests made of its fit (:class:`Judgement`), and a term a
round added (:class:`AddedTerm`).

A score entry is made when a candidate is scored and then travels through its round: the
shortlist, the fits, the choice and the final ranking each set their own fields, declared here
with who sets them. Its report form (:meth:`ScoreEntry.as_report`, the ``scores`` of
``summary.json`` and of :class:`~petsoft.diagnosis.result.DiagnoseResult`) names only the fields
a reader of the report uses; the round's working fields (the fit, the score direction, why a fit
was skipped) stay out of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:       # (context.py makes score entries: importing it here would be a cycle)
    from petsoft.diagnosis.context import Fit


# eq=False: an entry is one candidate's in one round, recognised by identity (a round's lists
# of entries are searched with ``in`` and ``is``); comparing two by value would compare their
# fits' arrays
@dataclass(eq=False)
class ScoreEntry:
    """One candidate's score entry in one round of the diagnosis.

    Attributes
    ----------
    physics : str
        The candidate's vocabulary name (:attr:`Candidate.physics
        <petsoft.diagnosis.candidates.Candidate.physics>`); set by the scoring.
    parameters : list of str
        The parameters the candidate adds or frees (``[calibrate]`` keys); set by the scoring.
    region : dict or None
        The sphere ``{"center", "radius"}`` of a spatial candidate; set by the scoring.
    kind : str
        How it was ranked: ``"score"``, ``"score-fd"`` or ``"switch"``; set by the scoring.
    score : float
        The score-test statistic S (chi2 units; 0 when the test could not be made or the
        misfit falls only outside the parameter's bounds); set by the scoring.
    dof : int
        The test's degrees of freedom; set by the scoring.
    p_value, log10_p : float
        The statistic's p-value (chi-square, ``dof``) and its log10 (the round is ranked by it:
        p underflows to 0 for strong candidates); set by the scoring.
    gradient : list of float or None
        The misfit's gradient with respect to the tested parameters at their start (J_c^T r);
        None when the test could not be made. Set by the scoring.
    note : str or None
        Why the score is 0 (the test's error, a one-sided bound, the scoring run's failure);
        None when it is not. Set by the scoring.
    direction : ndarray or None
        The score direction (:attr:`ScoreResult.direction
        <petsoft.diagnosis.score.ScoreResult.direction>`), compared by the round's shortlist
        (:func:`~petsoft.diagnosis.selection.shortlist`) and dropped (None) after it; never
        reported.
    round : int or None
        The round it was scored in; set by :func:`~petsoft.diagnosis.diagnose.run_diagnose`.
    repeats : str or None
        The better candidate whose first-order change this one repeats, when the shortlist left
        it out for that; set by :func:`~petsoft.diagnosis.selection.shortlist`.
    replaced : bool
        Whether it stands for a term :func:`~petsoft.diagnosis.reconsider.reconsider` replaced
        (the replacement's runner-up); only ``score`` is then its round's.
    fit : Fit or None
        The candidate's calibrated model; None before the fit, or when it failed
        (``fit_error``). Set by :meth:`Diagnosis.fit_candidates
        <petsoft.diagnosis.context.Diagnosis.fit_candidates>`.
    fit_error : str
        Why the fit failed ("" when it did not, or was not made); set with ``fit``.
    unfinished : str or None
        Why the time budget left its fit unfinished (not started, or stopped at an
        iteration): it then has no ``fit``, and :mod:`petsoft.diagnosis.partial_round` judges
        the round without it. Set with ``fit``.
    skipped : str or None
        Why it was not fitted; set by :func:`~petsoft.diagnosis.selection.fit_simplest_first`.
    fitted_chi2 : float or None
        Its fit's chi2 on the identification window, for a fitted contender; set by
        :func:`~petsoft.diagnosis.selection.choose`.
    rank : int or None
        Its place in the round's final ranking (1: the added term); set by
        :func:`~petsoft.diagnosis.selection.rank_round`.
    """

    physics: str
    parameters: list[str]
    region: dict | None
    kind: str
    score: float
    dof: int
    p_value: float
    log10_p: float
    gradient: list[float] | None = None
    note: str | None = None
    direction: np.ndarray | None = None
    round: int | None = None
    repeats: str | None = None
    replaced: bool = False
    fit: Fit | None = None
    fit_error: str = ""
    unfinished: str | None = None
    skipped: str | None = None
    fitted_chi2: float | None = None
    rank: int | None = None

    @classmethod
    def unscored(cls, candidate, note: str) -> ScoreEntry:
        """The entry of ``candidate`` when it could not be scored (``note`` says why): a
        score of 0, p = 1, a degree of freedom per parameter (at least one)."""
        return cls(physics=candidate.physics, parameters=candidate.parameters,
                   region=candidate.region, kind=candidate.kind, score=0.0,
                   dof=max(len(candidate.parameters), 1), p_value=1.0, log10_p=0.0, note=note)

    @classmethod
    def replaced_term(cls, candidate, score: float) -> ScoreEntry:
        """The entry standing for ``candidate``, a term :func:`~petsoft.diagnosis.reconsider.
        reconsider` replaced, as its replacement's runner-up: ``score`` its round's score; the
        test's other numbers are not kept (NaN)."""
        return cls(physics=candidate.physics, parameters=candidate.parameters,
                   region=candidate.region, kind=candidate.kind, score=score,
                   dof=max(len(candidate.parameters), 1), p_value=float("nan"),
                   log10_p=float("nan"), replaced=True)

    @property
    def tried(self) -> bool:
        """Whether its fit was tried (``fit`` holds it, ``fit_error`` why it failed, or
        ``unfinished`` why the time budget cut it)."""
        return self.fit is not None or bool(self.fit_error) or self.unfinished is not None

    def as_report(self) -> dict:
        """The entry as ``scores`` reports it: ``physics``, ``parameters``, ``region``,
        ``kind``, ``score``, ``dof``, ``p_value``, ``log10_p``, then, each where set,
        ``gradient``, ``note``, ``round``, ``rank`` and ``fitted_chi2`` (in this order)."""
        out = {"physics": self.physics, "parameters": self.parameters, "region": self.region,
               "kind": self.kind, "score": self.score, "dof": self.dof,
               "p_value": self.p_value, "log10_p": self.log10_p}
        later = {"gradient": self.gradient, "note": self.note, "round": self.round,
                 "rank": self.rank, "fitted_chi2": self.fitted_chi2}
        out.update((k, v) for k, v in later.items() if v is not None)
        return out


# eq=False: as a ScoreEntry, one round's addition, recognised by identity
@dataclass(eq=False)
class AddedTerm:
    """A physics term a round added: report.json's ``added`` entry while the run goes on.

    Made by :func:`~petsoft.diagnosis.selection.judge` when the candidate passes both tests;
    :func:`~petsoft.diagnosis.selection.choose` and :func:`~petsoft.diagnosis.reconsider.
    reconsider` extend its ``evidence``; :func:`~petsoft.diagnosis.geometry.refit_added_sphere`
    and ``reconsider`` replace it (a fitted sphere, a replacement term) or its values.

    Attributes
    ----------
    physics : str
        The term's vocabulary name.
    parameters : dict of str to float
        Its parameters' values in the fit that added it (or, after a reconsideration, the
        final one's); the report quotes the final model's (:func:`~petsoft.diagnosis.outputs.
        build_diagnosis_report`).
    std : dict of str to float
        Their standard deviations, where finite.
    score : float
        The score-test statistic it was ranked by.
    rms_after : float
        The identification window's rms (m) of the fit that added it.
    evidence : str
        Why it was added, in words: its tests, and what it was preferred to.
    region : dict or None
        The sphere ``{"center", "radius"}`` of a spatial term.
    """

    physics: str
    parameters: dict[str, float]
    std: dict[str, float]
    score: float
    rms_after: float
    evidence: str
    region: dict | None = None

    def as_report(self) -> dict:
        """The entry as :attr:`DiagnoseResult.added <petsoft.diagnosis.result.DiagnoseResult.
        added>` gives it: ``physics``, ``parameters``, ``std``, ``score``, ``rms_after``,
        ``evidence``, ``region`` (in this order)."""
        return {"physics": self.physics, "parameters": self.parameters, "std": self.std,
                "score": self.score, "rms_after": self.rms_after, "evidence": self.evidence,
                "region": self.region}


@dataclass(frozen=True)
class Judgement:
    """What :func:`~petsoft.diagnosis.selection.judge` made of a fitted candidate: the term to
    add when its fit passes both tests (the likelihood ratio and the held-out prediction),
    else why not.

    Attributes
    ----------
    entry : AddedTerm or None
        The term, when the candidate passes (:func:`~petsoft.diagnosis.selection.choose`
        extends its evidence when it is preferred to others).
    reason : str
        Why it does not pass ("" when it does).
    """

    entry: AddedTerm | None = None
    reason: str = ""

    @property
    def added(self) -> bool:
        """Whether the candidate passes both tests."""
        return self.entry is not None
