"""Output files that appear whole or not at all, and strict JSON.

Every file or directory the project writes goes through `atomic_file` or
`atomic_directory`: the content is written under a temporary name in the
target's directory (the same file system, so the final ``rename(2)`` is
atomic) and renamed into place only when the writing block succeeds; on any
failure the temporary is removed and the target is left as it was.  A reader
therefore sees the old content or the new one, never half of it.

Modes: `tempfile` creates files 0600 and directories 0700; the result gets
the usual mode of a new file, ``0o666 & ~umask`` (directories
``0o777 & ~umask``), as ``open(path, "w")`` or ``mkdir`` would give.

JSON: `jsonable` maps a result made of dicts, lists, tuples, numpy arrays
and numpy scalars to plain Python (arrays -> lists, numpy scalars -> int,
float or bool, paths -> str, dict keys -> str) and every non-finite float
(NaN, +-inf) to ``None``, so `json_text` always gives strict JSON (RFC 8259
has no NaN).

Standard library only: this module is shipped inside the FMUs with the rest
of `fitter.core` (numpy objects are recognised by their ``tolist`` method).
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
import uuid
from pathlib import Path, PurePath
from typing import Any, Iterator

__all__ = ["atomic_file", "atomic_directory", "write_json", "json_text", "jsonable", "usual_mode"]


def _umask() -> int:
    """The process's file-creation mask (read by setting it and setting it back)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def usual_mode(*, directory: bool = False) -> int:
    """Mode of a new file (``0o666 & ~umask``) or directory (``0o777 & ~umask``)."""
    return (0o777 if directory else 0o666) & ~_umask()


def _parent(path: str | os.PathLike) -> Path:
    """The directory that holds `path`; `FileNotFoundError` when it does not exist."""
    parent = Path(path).parent
    if not parent.resolve().is_dir():
        raise FileNotFoundError(f"{path}: directory {parent} does not exist")
    return parent


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, *, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary file path beside `path`; rename it to `path` when the block succeeds.

    The temporary file exists (empty) when the block starts; write it by
    name.  It is called ``.tmp-<random><suffix>`` (default suffix: that of
    `path`, so tools that choose a format by extension see the right one).
    On success it gets `usual_mode` and replaces `path`; on any exception it
    is removed and `path` is untouched.

    Raises
    ------
    FileNotFoundError
        The directory of `path` does not exist (before the block runs).
    """
    target = Path(path)
    ending = target.suffix if suffix is None else suffix
    fd, name = tempfile.mkstemp(prefix=".tmp-", suffix=ending, dir=_parent(target))
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, usual_mode())
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty temporary directory beside `path`; it replaces `path` when the block succeeds.

    On success the temporary directory gets ``usual_mode(directory=True)``
    and takes the name `path`.  An existing directory `path` is replaced as
    a whole (its files are not merged), as nearly atomically as POSIX
    allows: it is renamed aside, the new one renamed in, then the old one
    removed; if the second rename fails the old directory is put back.  On
    any exception in the block the temporary directory is removed and `path`
    is untouched.

    Raises
    ------
    FileNotFoundError
        The parent directory of `path` does not exist.
    NotADirectoryError
        `path` exists and is not a directory.
    """
    target = Path(path)
    parent = _parent(target)
    if target.exists() and not target.is_dir():
        raise NotADirectoryError(f"{path}: exists and is not a directory")
    tmp = Path(tempfile.mkdtemp(prefix=".tmp-", suffix=f"-{target.name}", dir=parent))
    try:
        yield tmp
        os.chmod(tmp, usual_mode(directory=True))
        _swap_in(tmp, target)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _swap_in(new: Path, target: Path) -> None:
    """Rename directory `new` to `target`, replacing an existing directory `target`."""
    if not target.exists():
        os.rename(new, target)
        return
    aside = target.parent / f".old-{uuid.uuid4().hex}-{target.name}"
    os.rename(target, aside)
    try:
        os.rename(new, target)
    except BaseException:
        os.rename(aside, target)
        raise
    shutil.rmtree(aside, ignore_errors=True)


def jsonable(obj: Any) -> Any:
    """`obj` as plain JSON-able Python; non-finite floats become None (see the module docstring).

    dict -> dict with str keys; list, tuple and numpy array -> list; numpy
    scalar -> Python scalar; `PurePath` -> str; float -> float or None when
    NaN or infinite; anything else unchanged.
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, PurePath):
        return str(obj)
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):
        return jsonable(obj.tolist())
    if isinstance(obj, float):
        return float(obj) if math.isfinite(obj) else None
    return obj


def json_text(data: Any, *, indent: int | None = 2) -> str:
    """Strict JSON text of `jsonable(data)` (no trailing newline)."""
    return json.dumps(jsonable(data), indent=indent, allow_nan=False)


def write_json(path: str | os.PathLike, data: Any, *, indent: int | None = 2) -> None:
    """Write `json_text(data)` to `path` atomically (`atomic_file`), UTF-8."""
    with atomic_file(path) as tmp:
        tmp.write_text(json_text(data, indent=indent), encoding="utf-8")
