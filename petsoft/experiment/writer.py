"""Writing experiments back as TOML (calibration writes calibrated experiments).

This module owns the TOML text: :func:`dumps_toml` serialises a dict of TOML values (the dict
form comes from :meth:`~petsoft.experiment.spec.Experiment.to_dict`), :func:`write_toml` writes
an experiment file that :func:`~petsoft.experiment.reader.load_experiment` reads back equal.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from petsoft.atomic import atomic_path, write_text
from petsoft.experiment.spec import Experiment

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _toml_string(s: str) -> str:
    out = []
    for ch in s:
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ch in "\b\t\n\f\r":
            out.append({"\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_key(k: str) -> str:
    return k if _BARE_KEY.fullmatch(k) else _toml_string(k)


def toml_value(v: Any) -> str:
    """One TOML value (scalar, array or inline table) as text."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)  # shortest round-trip repr; always a valid TOML float
    if isinstance(v, str):
        return _toml_string(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, os.PathLike):
        return _toml_string(os.fspath(v))
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _is_table_array(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def _dump_table(lines: list[str], table: Mapping[str, Any], path: list[str]) -> None:
    for k, v in table.items():
        if not isinstance(v, dict) and not _is_table_array(v):
            lines.append(f"{_toml_key(k)} = {toml_value(v)}")
    for k, v in table.items():
        name = ".".join(_toml_key(p) for p in [*path, k])
        if isinstance(v, dict):
            scalars = any(not isinstance(x, dict) and not _is_table_array(x) for x in v.values())
            if scalars or not v:  # a table holding only sub-tables needs no header of its own
                lines.extend(["", f"[{name}]"])
            _dump_table(lines, v, [*path, k])
        elif _is_table_array(v):
            for item in v:
                lines.extend(["", f"[[{name}]]"])
                _dump_table(lines, item, [*path, k])


def dumps_toml(data: Mapping[str, Any]) -> str:
    """Serialise a dict of TOML values (tables, arrays of tables, scalars, arrays) to TOML text."""
    lines: list[str] = []
    _dump_table(lines, data, [])
    return "\n".join(lines).lstrip("\n") + "\n"


def write_toml(experiment: Experiment, path: str | os.PathLike) -> None:
    """Write ``experiment`` as a TOML experiment file that :func:`load_experiment` reads back
    equal; paths inside it are written relative to the file's directory. Written atomically
    (:mod:`petsoft.atomic`): a reader never sees half a file."""
    target = Path(path)
    text = "# petsoft experiment (formats.md section 1), written by petsoft\n" + dumps_toml(
        experiment.to_dict(relative_to=target.parent.resolve())
    )
    write_text(target, text)


#: Keys whose values are paths, written relative to the file's directory.
_PATH_KEYS = (("mesh", "file"), ("output", "directory"))


def write_experiment_update(original: Experiment, updated: Experiment,
                            path: str | os.PathLike, *, spelled_out: bool = False) -> str:
    """Write ``updated`` as the user's own file with only what changed changed.

    The user's experiment file (``original.path``) is edited in place of a fresh dump: its
    comments, order and layout stay, the values that differ between ``original`` and
    ``updated`` (calibrated parameters) are replaced, and sections or keys ``updated`` adds (a
    physics term the diagnosis added) are appended, so the result diffs cleanly against the
    user's file. Paths the file gives are re-based to the new file's directory (an output
    directory left to its default stays the default: ``out`` beside the new file). The file is
    read back and checked to describe ``updated``; when it would not (or ``spelled_out``, or the
    original has no file), every value is written out as :func:`write_toml` does.

    Returns
    -------
    str
        ``"edited"`` or ``"spelled out"``: which form was written.
    """
    import tomlkit

    from petsoft.experiment.reader import load_experiment

    target = Path(path)
    source = Path(original.path) if original.path is not None else None
    if spelled_out or source is None or not source.is_file():
        write_toml(updated, target)
        return "spelled out"
    written = updated.to_dict(relative_to=target.parent.resolve())
    want = updated.to_dict()
    doc = tomlkit.parse(source.read_text(encoding="utf-8"))
    _apply_changes(doc, original.to_dict(), want, written)
    for section, key in _PATH_KEYS:
        table = doc.get(section)
        new = written.get(section, {}).get(key)
        if table is not None and key in table and new is not None and table[key] != new:
            table[key] = new
    text = tomlkit.dumps(doc)
    # An output directory the user left to its default ("out" beside the file) stays so: beside
    # the new file. Everything else must read back exactly as ``updated``.
    implicit_output = "directory" not in doc.get("output", {})
    try:
        with atomic_path(target) as tmp:
            tmp.write_text(text, encoding="utf-8")
            try:
                back = load_experiment(tmp).to_dict()
                if implicit_output:
                    back["output"].pop("directory"), want["output"].pop("directory")
                same = back == want
            except Exception:  # noqa: BLE001 -- any failure to read it back means: spell it out
                same = False
            if not same:
                raise _SpellOut  # the edited text is dropped, never renamed into place
    except _SpellOut:
        write_toml(updated, target)
        return "spelled out"
    return "edited"


class _SpellOut(Exception):
    """The edited file does not read back as the experiment: write it spelled out instead."""


def _apply_changes(doc, old: Mapping[str, Any], new: Mapping[str, Any],
                   written: Mapping[str, Any]) -> None:
    """Set in the tomlkit container ``doc`` every key whose value differs from ``old`` to
    ``new`` (``written``: the same values with paths as they are to be written); tables the
    document lacks are created with the changed keys only."""
    import tomlkit

    for key, value in new.items():
        before = old.get(key)
        if before == value:
            continue
        if isinstance(value, Mapping) and isinstance(before, Mapping):
            if key not in doc:
                doc[key] = tomlkit.table()
            _apply_changes(doc[key], before, value, written[key])
        elif (isinstance(value, list) and value and all(isinstance(v, Mapping) for v in value)):
            array = tomlkit.aot()
            for entry in written[key]:
                table = tomlkit.table()
                table.update(entry)
                array.append(table)
            doc[key] = array
        else:
            doc[key] = written[key]
    for key in list(doc.keys()):
        if key in old and key not in new:
            del doc[key]
