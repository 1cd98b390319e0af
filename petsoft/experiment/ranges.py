"""Valid ranges of an experiment's numeric values.

This module owns :class:`Range` (an interval, open or closed at either end, that says itself in
messages) and the named ranges the reader checks values against and the ``[calibrate]`` bounds
check reuses, with :data:`MATERIAL_RANGES` (range and unit of every continuum material
parameter).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Range:
    """The interval ``lo`` .. ``hi`` (None: unbounded), each end open or closed."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def contains(self, v: float) -> bool:
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        return not (self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi))

    def text(self, name: str) -> str:
        lo = "" if self.lo is None else f"{format_number(self.lo)} {'<' if self.lo_open else '<='} "
        hi = "" if self.hi is None else f" {'<' if self.hi_open else '<='} {format_number(self.hi)}"
        if self.lo is not None and self.hi is None:
            return f"{name} {'>' if self.lo_open else '>='} {format_number(self.lo)}"
        return f"{lo}{name}{hi}" if (lo or hi) else f"{name} any finite number"


ANY = Range()
POSITIVE = Range(lo=0.0, lo_open=True)
NONNEGATIVE = Range(lo=0.0)
POISSON = Range(lo=-1.0, hi=0.5, lo_open=True, hi_open=True)
UNIT = Range(lo=0.0, hi=1.0)
INT_POSITIVE = Range(lo=1)
INT_NONNEGATIVE = Range(lo=0)

MATERIAL_RANGES = {
    "youngs_modulus": (POSITIVE, "Pa"),
    "poisson_ratio": (POISSON, ""),
    "density": (POSITIVE, "kg/m^3"),
}


def key_range(key) -> Range:
    """The valid range a term declares for one of its keys (a :class:`petsoft.terms.Key`:
    ``minimum``, ``open``)."""
    return Range(lo=key.minimum, lo_open=key.open) if key.minimum is not None else ANY


def format_number(v: float) -> str:
    """A number as a message shows it: integers without a decimal point."""
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e15 else repr(float(v))

