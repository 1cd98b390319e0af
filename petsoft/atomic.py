"""Writing a file so that a reader never sees half of it: the one home of petsoft's atomic writes.

Every file petsoft writes as a whole (report.json, report.md, report.html, summary.json, a
recording, a checkpoint, the XDMF series' files, an edited experiment file) is written under a
temporary name beside its target and renamed into place by :func:`os.replace`, which is atomic
within one directory on POSIX: a reader sees the old file or the new one, never a half. A
failure while writing (an exception) removes the temporary and leaves the old file, or none, in
place. A process killed while writing (SIGKILL, a power loss) can leave a temporary behind,
never a file under the target's name: the temporary is hidden (a leading dot) and named
``.<name>.<8 hex digits>.tmp`` (:func:`temporaries`), unique, so that two writers of one target
never write into each other's temporary.

:func:`atomic_path` is the rule; :func:`write_text` and :func:`write_bytes` are it for a file
written in one piece. An HDF5 file is written by opening the temporary::

    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        ...

This module does no MPI: the caller decides which rank writes (petsoft's writers run on rank 0
with gathered arrays, or check the rank themselves), so a serial h5py file is all it meets.
"""

from __future__ import annotations

import os
import re
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "temporaries", "write_bytes", "write_text"]

# Attempts at a fresh temporary name before giving up (8 random hex digits: a clash needs a
# directory full of left-over temporaries of one target).
_ATTEMPTS = 100


def _temporary_name(name: str) -> str:
    return f".{name}.{secrets.token_hex(4)}.tmp"


def temporaries(name_pattern: str) -> re.Pattern:
    """The names :func:`atomic_path` gives the temporaries of targets whose names match the
    regular expression ``name_pattern`` (``r"\\d+\\.h5"``), for a ``fullmatch``: what a writer
    that clears a directory of its own files may remove."""
    return re.compile(rf"\.(?:{name_pattern})\.[0-9a-f]{{8}}\.tmp")


def _create(target: Path, mode: int | None) -> Path:
    """Create an empty, new temporary beside ``target`` with the permissions the file is to
    have, and return its path."""
    for _ in range(_ATTEMPTS):
        tmp = target.with_name(_temporary_name(target.name))
        try:
            # 0o666 less the umask: what a plain open(target, "w") would give the file
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        try:
            if mode is not None:
                os.fchmod(fd, mode)
        except BaseException:
            os.close(fd)
            tmp.unlink(missing_ok=True)
            raise
        os.close(fd)
        return tmp
    raise FileExistsError(f"no free temporary name beside {target} after {_ATTEMPTS} attempts")


def _fsync(path: Path) -> None:
    """Flush ``path`` (a file or a directory) to disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(target: str | os.PathLike, *, mode: int | None = None,
                fsync: bool = False) -> Iterator[Path]:
    """A temporary path beside ``target`` to write the file into; renamed to ``target`` when
    the block ends without an exception, removed when it raises.

    Parameters
    ----------
    target : path-like
        The file to write. Its directory must exist (as for a plain ``open``).
    mode : int, optional
        The file's permission bits (e.g. ``0o644``: readable by everyone whatever the umask);
        None: those a plain ``open(target, "w")`` gives it (0o666 less the umask).
    fsync : bool, optional
        Flush the file to disk before the rename and its directory after it, so that the new
        file survives a power loss, not only a crash of the process.

    Yields
    ------
    Path
        The temporary: it exists, empty, with the permissions ``mode`` says. Write it by any
        means (``write_text``, ``open``, ``h5py.File(tmp, "w")``) and close it within the
        block.

    Raises
    ------
    OSError
        When the temporary cannot be created or renamed; nothing is left behind then either.
    """
    target = Path(target)
    tmp = _create(target, mode)
    try:
        yield tmp
        if fsync:
            _fsync(tmp)
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if fsync:
        _fsync(target.parent)


def write_bytes(target: str | os.PathLike, data: bytes, *, mode: int | None = None,
                fsync: bool = False) -> Path:
    """Write ``data`` to ``target`` atomically (:func:`atomic_path`'s ``mode``, ``fsync``);
    returns ``target`` as a Path."""
    with atomic_path(target, mode=mode, fsync=fsync) as tmp:
        tmp.write_bytes(data)
    return Path(target)


def write_text(target: str | os.PathLike, text: str, *, encoding: str = "utf-8",
               mode: int | None = None, fsync: bool = False) -> Path:
    """Write ``text`` to ``target`` atomically in ``encoding`` (:func:`atomic_path`'s
    ``mode``, ``fsync``); returns ``target`` as a Path."""
    return write_bytes(target, text.encode(encoding), mode=mode, fsync=fsync)
