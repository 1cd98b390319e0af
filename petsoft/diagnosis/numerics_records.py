"""The numerics check's typed records: what each refinement of a round gave, the rounds, the
final model's check and what the checks found.

:func:`~petsoft.diagnosis.numerics.resolve_numerics` makes a :class:`NumericsRound` per round;
its ``options`` hold one record per refinement, of the kind its outcome was: a
:class:`RefittedOption` (the refined model calibrated), a :class:`LinearisedOption` (its refit
linearised: screened, deferred or measured by one run of a mesh too large to fit) or a
:class:`FailedOption`. :func:`~petsoft.diagnosis.numerics.numerics_check` makes a
:class:`FinalCheck` of the final model (a :class:`FinalChange` per refinement made);
:func:`~petsoft.diagnosis.numerics_findings.numerics_findings` a :class:`NumericsFindings`,
report.json's ``numerics`` (formats.md section 3); :class:`NumericsOutcome` is all of it, the
``numerics`` of diagnose's summary.json and of :attr:`DiagnoseResult.numerics
<petsoft.diagnosis.result.DiagnoseResult.numerics>`.

Each record's ``as_report()`` is the dict the checks wrote before they had records: its keys,
their order and values are that contract (a key appears only once the check set it). The
records are frozen: a round's code makes a changed copy (:func:`dataclasses.replace`) where it
once set a key. Their dicts (``options``, ``parameters``, ``not_tried``) are not changed once the
record is made.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar


@dataclass(frozen=True)
class FailedOption:
    """A refinement of a round whose refined run or refit failed.

    Attributes
    ----------
    error : str
        Why (the same on every rank: the runs are collective).
    """

    error: str
    failed: ClassVar[bool] = True

    def as_report(self) -> dict:
        """``{"error": ...}``."""
        return {"error": self.error}


@dataclass(frozen=True)
class _Outcome:
    """What a refinement of a round gave, refitted or linearised (the fields both have).

    Attributes
    ----------
    chi2, chi2_per_dof : float
        The refined model's chi2 after its refit (or linearised refit), and per degree of
        freedom of the round's fit.
    gain : float
        The current fit's chi2 minus ``chi2`` (> 0: closer to the data).
    matters : bool
        Whether the refinement matters (:func:`~petsoft.diagnosis.numerics.refinement_matters`;
        False when deferred or screened).
    change_rms, change_over_noise : float
        The rms change of the simulation the refit leaves (m), and over the noise.
    change_same_parameters, change_same_parameters_over_noise : float
        The rms change at the current parameters (m), and over the noise.
    how : str
        The refinement in the user's words (:meth:`Refinement.describe
        <petsoft.calibration.refinement.Refinement.describe>`).
    parameters : dict of str to float
        The refit's parameters.
    refit : str
        How it was refitted (a calibration, a chord, a linearised refit ...).
    error_estimate : float
        The current model's error the verdict's noise budget counts for it (Richardson;
        0 when none is counted).
    remaining_estimate : float
        The refined model's own error, estimated (Richardson).
    deferred : float or None
        The current fit's rms over the noise when the refinement, which would matter, waits
        for the misfit to shrink (:func:`~petsoft.diagnosis.numerics.deferred`).
    """

    chi2: float
    chi2_per_dof: float
    gain: float
    matters: bool
    change_rms: float
    change_over_noise: float
    change_same_parameters: float
    change_same_parameters_over_noise: float
    how: str
    parameters: dict[str, float]
    refit: str
    error_estimate: float
    remaining_estimate: float
    deferred: float | None = None
    failed: ClassVar[bool] = False

    def _changes(self) -> dict:
        """The report's keys up to ``how``, which both kinds write first."""
        return {"chi2": self.chi2, "chi2_per_dof": self.chi2_per_dof, "gain": self.gain,
                "matters": self.matters, "change_rms": self.change_rms,
                "change_over_noise": self.change_over_noise,
                "change_same_parameters": self.change_same_parameters,
                "change_same_parameters_over_noise": self.change_same_parameters_over_noise,
                "how": self.how}


@dataclass(frozen=True)
class RefittedOption(_Outcome):
    """A refinement of a round whose refined model was calibrated
    (:func:`~petsoft.diagnosis.numerics.resolve_numerics`; fields of :class:`_Outcome`).

    Attributes
    ----------
    same_parameters_from : str or None
        The refinement whose run gave ``change_same_parameters`` when it is not this one's
        (a quarter step's, Richardson's from the halved step's run).
    remaining_bound : float or None
        For the refinement a round adopted: ``remaining_estimate`` bounded by what the refined
        fit leaves above the noise; None for the others.
    """

    same_parameters_from: str | None = None
    remaining_bound: float | None = None
    screened: ClassVar[bool] = False
    measured_only: ClassVar[bool] = False

    def as_report(self) -> dict:
        """The option's keys: the changes, ``parameters``, ``refit``, the estimates, then,
        where set, ``deferred``, ``same_parameters_from`` and ``remaining_bound``."""
        out = {**self._changes(), "parameters": self.parameters, "refit": self.refit,
               "error_estimate": self.error_estimate,
               "remaining_estimate": self.remaining_estimate}
        later = {"deferred": self.deferred, "same_parameters_from": self.same_parameters_from,
                 "remaining_bound": self.remaining_bound}
        out.update((k, v) for k, v in later.items() if v is not None)
        return out


@dataclass(frozen=True)
class LinearisedOption(_Outcome):
    """A refinement whose refit was linearised (:func:`~petsoft.diagnosis.numerics.
    linearised_refit`), not calibrated (fields of :class:`_Outcome`).

    Attributes
    ----------
    screened : bool
        Not refitted for the size of its change (:func:`~petsoft.diagnosis.numerics.screened`)
        or because a refit would be deferred.
    measured_only : bool
        A mesh too large to fit, simulated once (:func:`~petsoft.diagnosis.numerics.
        measure_refinement`).
    """

    screened: bool = False
    measured_only: bool = False

    def as_report(self) -> dict:
        """The option's keys: the changes, ``refit``, ``parameters``, the estimates, then,
        where set, ``screened``, ``deferred`` and ``measured_only``."""
        out = {**self._changes(), "refit": self.refit, "parameters": self.parameters,
               "error_estimate": self.error_estimate,
               "remaining_estimate": self.remaining_estimate}
        if self.screened:
            out["screened"] = True
        if self.deferred is not None:
            out["deferred"] = self.deferred
        if self.measured_only:
            out["measured_only"] = True
        return out


#: A refinement's outcome in a round.
Option = RefittedOption | LinearisedOption | FailedOption


@dataclass(frozen=True)
class NumericsRound:
    """A round of :func:`~petsoft.diagnosis.numerics.resolve_numerics` (or the measurements of
    :func:`~petsoft.diagnosis.numerics.measure_untried`): the fit it started from and what each
    refinement gave.

    Attributes
    ----------
    chi2 : float
        The round's fit's chi2.
    dof : int
        Its degrees of freedom.
    step : float
        Its time step (s).
    options : dict of str to Option
        Refinement label -> its outcome, in the order they were judged.
    parameters : dict of str to float
        The round's fit's parameters.
    tets : int or None
        Its tetrahedra (a continuum model).
    not_tried : dict of str to str or None
        Label -> why a refinement was not tried (None: every one was).
    measured_only : bool
        A round of measurements only (made after a round that adopted a refinement).
    adopted : str or None
        The refinement the round adopted.
    remaining_counted : str or None
        Why the adopted refinement's own error is counted in the verdict's noise budget.
    after_additions : int or None
        The terms added before the round (set by :class:`~petsoft.diagnosis.numerics.
        NumericsChecks`, as ``why`` and ``final_check``).
    why : str or None
        Why the check was made.
    final_check : bool
        A check made again on the final model.
    """

    chi2: float
    dof: int
    step: float
    options: dict[str, Option]
    parameters: dict[str, float]
    tets: int | None = None
    not_tried: dict[str, str] | None = None
    measured_only: bool = False
    adopted: str | None = None
    remaining_counted: str | None = None
    after_additions: int | None = None
    why: str | None = None
    final_check: bool = False

    def as_report(self) -> dict:
        """The round's keys: ``chi2``, ``dof``, ``step``, ``options``, ``parameters`` (a
        round of measurements: ``tets`` and ``measured_only`` before ``parameters``), then,
        where set, ``tets``, ``not_tried``, ``adopted``, ``remaining_counted``,
        ``after_additions``, ``why`` and ``final_check``."""
        out = {"chi2": self.chi2, "dof": self.dof, "step": self.step,
               "options": {label: o.as_report() for label, o in self.options.items()}}
        if self.measured_only:
            out.update(tets=self.tets, measured_only=True)
        out["parameters"] = self.parameters
        later = {"tets": None if self.measured_only else self.tets,
                 "not_tried": self.not_tried, "adopted": self.adopted,
                 "remaining_counted": self.remaining_counted,
                 "after_additions": self.after_additions, "why": self.why,
                 "final_check": True if self.final_check else None}
        out.update((k, v) for k, v in later.items() if v is not None)
        return out


@dataclass(frozen=True)
class FinalChange:
    """What a refinement changes on the final model, without a refit
    (:func:`~petsoft.diagnosis.numerics.numerics_check`).

    Attributes
    ----------
    rms : float or None
        The refined model's residual rms over all frames (None: estimated, not simulated).
    change, change_over_noise : float
        The rms change of the simulation over the seen samples (m), and over the noise.
    how : str
        The refinement in the user's words.
    resolved : bool
        The change is below the noise.
    estimated : bool
        Taken from Richardson's estimate, not simulated
        (:func:`~petsoft.diagnosis.numerics.final_estimates`).
    """

    rms: float | None
    change: float
    change_over_noise: float
    how: str
    resolved: bool
    estimated: bool = False

    def as_report(self) -> dict:
        """``rms``, ``change``, ``change_over_noise``, ``how``, ``resolved``, and
        ``estimated`` (True) when it was estimated."""
        out = {"rms": self.rms, "change": self.change,
               "change_over_noise": self.change_over_noise, "how": self.how,
               "resolved": self.resolved}
        if self.estimated:
            out["estimated"] = True
        return out


@dataclass(frozen=True)
class FinalCheck:
    """:func:`~petsoft.diagnosis.numerics.numerics_check` of the final model: what each
    refinement changes on it without a refit, or why it was not made.

    Attributes
    ----------
    base_rms_all : float
        The final model's residual rms over all frames.
    changes : dict of str to FinalChange or str
        Per refinement label, in :data:`~petsoft.calibration.refinement.REFINEMENTS`' order:
        what it changes, or ``"not done: why"``.
    """

    base_rms_all: float
    changes: dict[str, FinalChange | str]

    def made(self) -> dict[str, FinalChange]:
        """The refinements made (simulated or estimated), by label."""
        return {k: v for k, v in self.changes.items() if isinstance(v, FinalChange)}

    def as_report(self) -> dict:
        """``base_rms_all``, then each label's :meth:`FinalChange.as_report` or string."""
        return {"base_rms_all": self.base_rms_all,
                **{k: v if isinstance(v, str) else v.as_report()
                   for k, v in self.changes.items()}}


@dataclass(frozen=True)
class NumericsFindings:
    """What the numerics checks found, in sentences (:func:`~petsoft.diagnosis.
    numerics_findings.numerics_findings`): report.json's ``numerics`` (formats.md section 3).

    Attributes
    ----------
    findings : list of str
        Round by round, what each refinement did, and what remains.
    recommendation : str or None
        The mesh and step to use.
    summary : list of str
        One sentence per refinement, on the final model.
    adopted : list of str
        The refinements adopted, in order.
    unchecked : dict of str to str
        Label -> why a refinement was never made (a ``skipped`` entry of the report; not in
        its ``numerics``).
    mesh : dict or None
        The tets of the user's and the final model and the recommended count (a continuum
        model).
    """

    findings: list[str]
    recommendation: str | None
    summary: list[str]
    adopted: list[str]
    unchecked: dict[str, str] = field(default_factory=dict)
    mesh: dict | None = None

    def as_report(self) -> dict:
        """report.json's ``numerics``: ``findings``, ``recommendation``, ``mesh`` (where
        there is one), ``summary``, ``adopted``."""
        out = {"findings": self.findings, "recommendation": self.recommendation}
        if self.mesh is not None:
            out["mesh"] = self.mesh
        return {**out, "summary": self.summary, "adopted": self.adopted}

    def as_summary(self) -> dict:
        """The keys summary.json's ``numerics`` adds: ``findings``, ``recommendation``,
        ``summary``, ``adopted``, ``unchecked`` and ``mesh`` (where there is one)."""
        out = {"findings": self.findings, "recommendation": self.recommendation,
               "summary": self.summary, "adopted": self.adopted, "unchecked": self.unchecked}
        if self.mesh is not None:
            out["mesh"] = self.mesh
        return out


@dataclass(frozen=True)
class NumericsOutcome:
    """Everything the numerics checks of a diagnosis made: the ``numerics`` of diagnose's
    summary.json and of :attr:`DiagnoseResult.numerics
    <petsoft.diagnosis.result.DiagnoseResult.numerics>`.

    Attributes
    ----------
    final : FinalCheck or None
        The final model's check (None: not made).
    rounds : list of NumericsRound
        Every round, in order.
    model_error : dict of str to float
        The discretisation errors the verdict's noise budget counts (m), by label.
    sigma_verdict : float
        The noise the verdict tests against (the noise and ``model_error`` in quadrature).
    findings : NumericsFindings or None
        What they found, in sentences (None: ``--no-numerics``).
    """

    final: FinalCheck | None
    rounds: list[NumericsRound]
    model_error: dict[str, float]
    sigma_verdict: float
    findings: NumericsFindings | None

    def as_report(self) -> dict:
        """The final check's keys, then, where there are any, ``refinements`` (the rounds),
        ``model_error`` and ``sigma_verdict``, then the findings' keys."""
        out = self.final.as_report() if self.final is not None else {}
        if self.rounds:
            out["refinements"] = [r.as_report() for r in self.rounds]
        if self.model_error:
            out.update(model_error=dict(self.model_error), sigma_verdict=self.sigma_verdict)
        if self.findings is not None:
            out.update(self.findings.as_summary())
        return out
