"""Typed, range-checked reading of one table of an experiment file.

This module owns :class:`TableReader`: the getters (number, integer, string, choice, vector,
expressions, sub-tables, arrays of tables) through which :mod:`petsoft.experiment.reader` reads
every section, each raising an :class:`~petsoft.errors.ExperimentError` that names the file, the
dotted key, the value and what would be valid.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, NoReturn

from petsoft.errors import ExperimentError
from petsoft.experiment.expressions import parse_expression
from petsoft.experiment.messages import show_value, suggest, type_name
from petsoft.experiment.parameters import key_part
from petsoft.experiment.ranges import ANY, Range

_MISSING: Any = object()


class TableReader:
    """Reads one TOML table ``name`` of file ``source``, with typed, range-checked getters."""

    def __init__(self, data: Mapping[str, Any], name: str, source: str):
        self.data = data
        self.name = name
        self.source = source

    def key(self, k: str | None = None) -> str:
        if k is None:
            return self.name
        return f"{self.name}.{key_part(k)}" if self.name else key_part(k)

    def header(self) -> str:
        if not self.name:
            return "the top level"
        return self.name if self.name.endswith("]") else f"[{self.name}]"

    def fail(self, k: str | None, message: str) -> NoReturn:
        raise ExperimentError(f"{self.source}: {self.key(k)}{message}")

    def wrong_type(self, k: str, value: Any, expected: str) -> NoReturn:
        self.fail(
            k,
            f" = {show_value(value)} has the wrong type: expected {expected}, "
            f"got {type_name(value)}",
        )

    def check_keys(self, allowed: Sequence[str], note: str = "") -> None:
        for k in self.data:
            if k not in allowed:
                close = suggest(k, allowed)
                hint = f"; did you mean {self.key(close)}?" if close else "."
                raise ExperimentError(
                    f"{self.source}: unknown key {self.key(k)}{hint} Valid keys in "
                    f"{self.header()}: {', '.join(allowed)}{note}"
                )

    def get(self, k: str, default: Any = _MISSING, what: str = "") -> Any:
        if k not in self.data:
            if default is _MISSING:
                self.fail(k, f" is missing{f' ({what})' if what else ''}")
            return default
        return self.data[k]

    def _check_number(self, k: str, v: Any, expected: str, rng: Range, unit: str) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.wrong_type(k, v, expected)
        if not math.isfinite(v):
            self.fail(k, f" = {show_value(v)} is not a finite number")
        if not rng.contains(v):
            unit_text = f" ({unit})" if unit else ""
            self.fail(
                k,
                f" = {show_value(v)} is out of range: valid is {rng.text(k)}{unit_text}",
            )
        return v

    def number(self, k: str, default: Any = _MISSING, rng: Range = ANY, unit: str = "") -> Any:
        v = self.get(k, default, what=describe_range(rng.text(k), unit))
        if v is default and k not in self.data:
            return default
        return float(self._check_number(k, v, "a number", rng, unit))

    def integer(self, k: str, default: Any = _MISSING, rng: Range = ANY) -> Any:
        v = self.get(k, default, what=f"an integer, {rng.text(k)}")
        if v is default and k not in self.data:
            return default
        if isinstance(v, bool) or not isinstance(v, int):
            self.wrong_type(k, v, f"an integer ({rng.text(k)})")
        return int(self._check_number(k, v, "an integer", rng, ""))

    def string(self, k: str, default: Any = _MISSING, what: str = "a string") -> Any:
        v = self.get(k, default, what=what)
        if v is default and k not in self.data:
            return default
        if not isinstance(v, str):
            self.wrong_type(k, v, what)
        if not v.strip():
            self.fail(k, f" is empty: expected {what}")
        return v

    def choice(self, k: str, choices: Sequence[str], default: Any = _MISSING) -> Any:
        listing = ", ".join(f'"{c}"' for c in choices)
        v = self.get(k, default, what=f"one of {listing}")
        if v is default and k not in self.data:
            return default
        if not isinstance(v, str):
            self.wrong_type(k, v, f"a string, one of {listing}")
        if v not in choices:
            close = suggest(v, choices) or suggest(v.lower(), choices)
            hint = f'; did you mean "{close}"?' if close else "."
            self.fail(k, f" = {show_value(v)} is not a valid choice{hint} Valid: {listing}")
        return v

    def vector(
        self, k: str, default: Any = _MISSING, rng: Range = ANY, unit: str = "", n: int = 3
    ) -> Any:
        expected = f"an array of {n} numbers" + (f" ({unit})" if unit else "")
        v = self.get(k, default, what=expected)
        if v is default and k not in self.data:
            return default
        return self._vector_value(k, v, expected, rng, unit, n)

    def _vector_value(self, k, v, expected, rng, unit, n) -> tuple[float, ...]:
        if not isinstance(v, list) or len(v) != n:
            if isinstance(v, list):
                self.fail(k, f" = {show_value(v)} has {len(v)} entries: expected {expected}")
            self.wrong_type(k, v, expected)
        for i, item in enumerate(v):
            self._check_number(f"{k}[{i}]", item, "a number", rng, unit)
        return tuple(float(item) for item in v)

    def expressions(
        self, k: str, variables: tuple[str, ...], default: Any = _MISSING, what: str = ""
    ) -> Any:
        expected = (
            f"an array of 3 expressions of {', '.join(variables)} (strings such as "
            f'"0.01*sin(20*t)", or numbers){f", {what}" if what else ""}'
        )
        v = self.get(k, default, what=expected)
        if v is default and k not in self.data:
            return default
        if not isinstance(v, list):
            self.wrong_type(k, v, expected)
        if len(v) != 3:
            self.fail(k, f" = {show_value(v)} has {len(v)} entries: expected {expected}")
        return tuple(
            parse_expression(
                item,
                source=f"{self.source}: {self.key(k)}[{i}]",
                variables=variables,
                expect="number",
            )
            for i, item in enumerate(v)
        )

    def table(self, k: str, header: str | None = None) -> TableReader | None:
        """The sub-table ``k`` as a reader, or None when absent."""
        if k not in self.data:
            return None
        v = self.data[k]
        if not isinstance(v, dict):
            self.wrong_type(k, v, f"a table ({header or '[' + self.key(k) + ']'})")
        return TableReader(v, self.key(k), self.source)

    def table_array(self, k: str) -> list[TableReader]:
        """The array of tables ``[[k]]`` as readers (empty when absent)."""
        if k not in self.data:
            return []
        v = self.data[k]
        if isinstance(v, dict):
            self.fail(
                k,
                f" is a single table: write [[{self.key(k)}]] (double brackets), once per entry",
            )
        if not isinstance(v, list) or not all(isinstance(item, dict) for item in v):
            self.wrong_type(k, v, f"an array of tables ([[{self.key(k)}]])")
        return [TableReader(item, f"{self.key(k)}[{i}]", self.source) for i, item in enumerate(v)]


def describe_range(range_text: str, unit: str) -> str:
    """What a number must be: its unit (if any) and valid range, for "is missing" messages."""
    return f"{unit}, {range_text}" if unit else range_text
