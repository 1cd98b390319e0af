"""The diagnosis' typed records: what one candidate's score test gave and what its round made
of it (:class:`ScoreEntry`), what the tests made of its fit (:class:`Judgement`), a term a
round added (:class:`AddedTerm`), and the mismatch analysis of a fit (:class:`Evidence`). The
numerics check's are in :mod:`petsoft.diagnosis.numerics_records`.

A score entry is made when a candidate is scored and then travels through its round: the
shortlist, the fits, the choice and the final ranking each set their own fields, declared here
with who sets them. Its report form (:meth:`ScoreEntry.as_report`, the ``scores`` of
``summary.json`` and of :class:`~petsoft.diagnosis.result.DiagnoseResult`) names only the fields
a reader of the report uses; the round's working fields (the fit, the score direction, why a fit
was skipped) stay out of it.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:       # (context.py makes score entries: importing it here would be a cycle)
    from petsoft.diagnosis.context import Fit
    from petsoft.diagnosis.locate import MarkerResiduals
    from petsoft.diagnosis.noise import ChiSquareResult


# eq=False: an entry is one candidate's in one round, recognised by identity (a round's lists
# of entries are searched with ``in`` and ``is``); comparing two by value would compare their
# fits' arrays
@dataclass(eq=False)
class ScoreEntry:
    """One candidate's score entry in one round of the diagnosis.

    The one record here that stays mutable: each step of the round sets its own fields on the
    same entry (below: who sets which), and the round's lists (the report's order, the ranking,
    the shortlist, the contenders, a later round's runners-up) hold that one entry, recognised
    by identity. A frozen entry would have to be replaced in each of those lists at each step.

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
@dataclass(frozen=True, eq=False)
class AddedTerm:
    """A physics term a round added: report.json's ``added`` entry while the run goes on.

    Made by :func:`~petsoft.diagnosis.selection.judge` when the candidate passes both tests;
    :func:`~petsoft.diagnosis.selection.choose` and :func:`~petsoft.diagnosis.reconsider.
    reconsider` extend its ``evidence``; :func:`~petsoft.diagnosis.geometry.refit_added_sphere`
    and ``reconsider`` replace it (a fitted sphere, a replacement term) or its values. Each
    makes a changed copy (:func:`dataclasses.replace`): the round's history
    (:class:`~petsoft.diagnosis.reconsider.Added`) holds the current one.

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


# eq=False: its arrays do not compare to one bool
@dataclass(frozen=True, eq=False)
class Evidence:
    """The mismatch analysis of a fit (:func:`~petsoft.diagnosis.evidence.collect_evidence`):
    the noise, the verdict, and where, when and at which frequencies the residual is not noise.

    Made once per fit; :func:`~petsoft.diagnosis.context.evidence_of` makes a changed copy
    (:func:`dataclasses.replace`) when the verdict counts a discretisation error.

    Attributes
    ----------
    noise_std : float
        The position noise std (m) the verdict tests against.
    noise_source : str
        Where it comes from (the recording, or estimated from the data and how).
    noise_summary : dict or None
        :func:`~petsoft.diagnosis.noise.noise_summary` of the data (None: too few frames).
    noise_test : ChiSquareResult
        The verdict's chi-square level and whiteness test.
    verdict : str
        ``"consistent"`` or ``"missing-physics"``.
    fit : dict
        ``{rms, chi2_per_dof}`` (:func:`~petsoft.diagnosis.report.fit_summary`).
    markers : MarkerResiduals
        The per-marker residuals and the markers that stand out.
    region : dict or None
        The sphere ``{"center", "radius"}`` of the mismatch on the body.
    windows : dict
        :func:`~petsoft.diagnosis.locate.mismatch_time_windows`.
    data_modes, sim_modes, residual_modes : list of dict or None
        The dominant modes of the data, the simulation and the residual (None: the spectral
        analysis could not be made, said in ``notes``).
    modes : dict or None
        Their comparison (:func:`~petsoft.diagnosis.spectral.compare_modes`).
    frequencies_hz : list of float
        The residual's frequencies (none when the verdict is consistent).
    envelope : dict or None
        The data's decay envelope (:func:`~petsoft.diagnosis.spectral.decay_envelope`).
    friction_terms, sim_friction_terms : dict or None
        The decay-rate regression of the data's envelope and of the simulation's.
    notes : list of str
        What could not be analysed, and why the verdict was made as it was.
    field : Path or None
        The nodal residual field written (XDMF).
    mismatch : dict
        The report's ``mismatch`` entries (``markers``, ``time_windows``, ``frequencies_hz``,
        ``region``; empty when the verdict is consistent).
    offset, offset_z, axis_rms : ndarray (3,)
        The mean residual per axis (m), it over its white-noise standard error, and the
        residual's rms per axis.
    offset_halves : ndarray (2, 3)
        The mean residual of each half of the record.
    duration : float
        The record's span (s).
    """

    noise_std: float
    noise_source: str
    noise_summary: dict | None
    noise_test: ChiSquareResult
    verdict: str
    fit: dict
    markers: MarkerResiduals
    region: dict | None
    windows: dict
    data_modes: list | None
    sim_modes: list | None
    modes: dict | None
    residual_modes: list | None
    frequencies_hz: list[float]
    envelope: dict | None
    friction_terms: dict | None
    sim_friction_terms: dict | None
    notes: list[str]
    field: Path | None
    mismatch: dict
    offset: np.ndarray
    offset_z: np.ndarray
    axis_rms: np.ndarray
    offset_halves: np.ndarray
    duration: float

    def as_report(self) -> dict:
        """The evidence as the dict :func:`~petsoft.diagnosis.evidence.collect_evidence` once
        returned: every field under its name, in this order (the same objects)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}
