"""The conventions every result of the public API follows (scipy's ``OptimizeResult``).

``success`` says whether the computation reached its goal, ``message`` says how in one line,
``params`` (for fits) gives the values by their dotted names, and the repr is short: scalars,
names and array shapes, never an array spelled out (a calibration's repr had run to 28,000
characters of simulated trajectories), so a result printed at the prompt reads in a few lines.

A result class derives from :class:`Result` (or :class:`FitResult`) and, when it is a dataclass,
is declared ``@dataclass(repr=False)`` so that the dataclass's own repr does not replace this one.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

#: The longest repr a result gives (characters); fields past it are left out and counted.
REPR_LIMIT = 1000
#: Arrays and lists up to this many elements are shown by value, larger ones by shape/length.
SMALL_ARRAY = 6
#: Dicts of scalars (parameters by name) up to this many entries are shown by value.
SMALL_DICT = 12


def summarise(value) -> str:
    """A short text for one attribute of a result: the value of a scalar, string or small
    array; the shape of a large array; the length of a long list or dict."""
    if value is None:
        return "None"
    if isinstance(value, (bool, np.bool_)):
        return repr(bool(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.6g}"
    if isinstance(value, str):
        return repr(value if len(value) <= 240 else value[:237] + "...")
    if isinstance(value, Path):
        return repr(str(value))
    if isinstance(value, np.ndarray):
        if value.size <= SMALL_ARRAY and value.dtype.kind in "biuf":
            return np.array2string(value, precision=6, separator=", ")
        return f"array(shape={value.shape}, dtype={value.dtype})"
    if isinstance(value, dict):
        if len(value) <= SMALL_DICT and all(isinstance(k, str) for k in value) and all(
                isinstance(v, (int, float, str, bool, np.floating, np.integer))
                for v in value.values()):
            return "{" + ", ".join(f"{k!r}: {summarise(v)}" for k, v in value.items()) + "}"
        return f"<dict of {len(value)}>"
    if isinstance(value, (list, tuple)):
        if len(value) <= SMALL_ARRAY and all(isinstance(v, (int, float, str, np.floating))
                                             for v in value):
            return "[" + ", ".join(summarise(v) for v in value) + "]"
        return f"<{type(value).__name__} of {len(value)}>"
    return f"<{type(value).__name__}>"


def short_repr(obj, items: list[tuple[str, object]]) -> str:
    """``ClassName(name=value, ...)`` of ``items`` summarised, cut at :data:`REPR_LIMIT`."""
    head = f"{type(obj).__name__}("
    parts: list[str] = []
    used = len(head) + 1
    for k, (name, value) in enumerate(items):
        part = f"{name}={summarise(value)}"
        rest = len(items) - k
        more = f"... {rest} more" if rest > 1 else ""
        # keep room for the "... N more" marker should a later field not fit
        if used + len(part) + 2 + len(f"... {rest} more") > REPR_LIMIT:
            parts.append(more or f"... {rest} more")
            break
        parts.append(part)
        used += len(part) + 2
    return head + ", ".join(parts) + ")"


class Result:
    """A result of the public API: ``success``, ``message`` and a short repr.

    Subclasses define :attr:`success` and :attr:`message`; the repr lists them first, then the
    dataclass fields (or :meth:`_repr_items`).
    """

    @property
    def success(self) -> bool:
        """Whether the computation reached its goal."""
        raise NotImplementedError

    @property
    def message(self) -> str:
        """One line: how the computation ended."""
        raise NotImplementedError

    def _repr_items(self) -> list[tuple[str, object]]:
        names = [f.name for f in dataclasses.fields(self)] if dataclasses.is_dataclass(self) \
            else sorted(k for k in vars(self) if not k.startswith("_"))
        return [(n, getattr(self, n)) for n in names]

    def __repr__(self) -> str:
        first = [("success", self.success), ("message", self.message)]
        if isinstance(self, FitResult):
            first.append(("params", self.params))
        return short_repr(self, first + self._repr_items())


class FitResult(Result):
    """A result whose ``names``, ``values`` and ``std`` are calibrated parameters and their
    standard deviations: ``params`` and ``param_std`` give them by name."""

    @property
    def params(self) -> dict[str, float]:
        """The fitted values by dotted name, e.g. ``fit.params["material.youngs_modulus"]``."""
        return {n: float(v) for n, v in zip(self.names, self.values, strict=True)}

    @property
    def param_std(self) -> dict[str, float]:
        """The standard deviation of each fitted value, by dotted name (NaN when unknown)."""
        return {n: float(s) for n, s in zip(self.names, self.std, strict=True)}


class OptimizerFit(FitResult):
    """A fit an optimizer made: ``reason`` (its stopping reason, TAO's names), ``iterations``,
    ``evaluations`` (of :attr:`evaluation`, e.g. "simulations"); successful when it converged."""

    #: what one evaluation of the objective was, for :attr:`message`
    evaluation = "evaluations"

    @property
    def success(self) -> bool:
        return self.reason.startswith("CONVERGED")

    @property
    def message(self) -> str:
        return (f"{self.reason} after {self.iterations} iterations ({self.evaluations} "
                f"{self.evaluation})")
