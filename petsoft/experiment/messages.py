"""Pieces of the experiment's error messages: how keys, values and types are shown.

Every :class:`~petsoft.errors.ExperimentError` names the key (as
:func:`~petsoft.experiment.parameters.key_part` writes it), the value as it is written in TOML
(:func:`show_value`), its type (:func:`type_name`) and, for a misspelling, the closest valid word
(:func:`suggest`).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from typing import Any

from petsoft.experiment.writer import toml_value


def type_name(v: Any) -> str:
    """The TOML type of a parsed value, with its article (``"an integer"``, ``"a table"``)."""
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, int):
        return "an integer"
    if isinstance(v, float):
        return "a float"
    if isinstance(v, str):
        return "a string"
    if isinstance(v, list):
        return "an array"
    if isinstance(v, dict):
        return "a table"
    return f"a {type(v).__name__}"


def show_value(v: Any) -> str:
    """A value as it would appear in the TOML file (shortened)."""
    try:
        text = toml_value(v)
    except (TypeError, ValueError):
        text = repr(v)
    return text if len(text) <= 80 else text[:77] + "..."


def suggest(word: str, choices: Iterable[str]) -> str:
    """The choice closest to ``word`` (a likely misspelling of it), or ``""`` for none."""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return close[0] if close else ""


