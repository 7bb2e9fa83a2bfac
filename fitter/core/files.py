"""Output files that appear whole or not at all, and strict JSON.

Every file or directory the project writes goes through `atomic_file` or
`atomic_directory`: the content is written under a temporary name in the
target's directory (the same file system, so the final ``rename(2)`` is
atomic) and renamed into place only when the writing block succeeds; on any
failure the temporary is removed and the target is left as it was.  A reader
therefore sees the old content or the new one, never half of it.

Temporaries are named after their target and the writing process,
``.tmp-<name>.<pid>.<random>``; a process killed before it could clean up
leaves them behind, and the next write into the same directory removes those
of processes that no longer run (`sweep_leftovers`).  A temporary is never
itself given a temporary: `atomic_file` of a live temporary of this process
(an FMU build writing into the command's temporary) writes it in place, so
no name doubles ``.tmp-.tmp-``.  Working directories (FMU builds) are
`scratch_directory`: named after the process too, and swept the same way.

One writer per output: `atomic_file`, `atomic_directory` and `atomic_pair`
hold an exclusive advisory lock (``fcntl.flock``) on the sibling file
``.lock-<name>`` from before their temporary is made until the output is in
place (`output_lock`; held again by the same process it is not waited for).
A second writer of the same path waits up to `LOCK_WAIT` seconds (the
environment variable ``DUHEM_LOCK_WAIT`` overrides it), then fails with
`OutputBusyError` naming the path and the holder (its pid and command line,
which the holder writes into the lock file).  The lock file is removed when
released; one a killed writer left is taken over (its lock died with it), and removed by the next write into
its directory (`sweep_leftovers`, which removes only lock files no process holds).

Two outputs of one command that belong together (a model JSON and the FMU
built from it) are published by `atomic_pair`: the companion (FMU) is
renamed first and the record (JSON, which records the companion's SHA-256)
last, and the old companion is kept as a hard link until the record is in
place.  A run killed between the two renames leaves the old record with the
new companion and that link; `recover_pair` (run by the next write of the
pair and by every reader) puts the old companion back, so a reader finds
the old pair or the new one, never a mix.

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
import hashlib
import json
import math
import os
import re
import shutil
import stat
import sys
import tempfile
import time
import uuid
from pathlib import Path, PurePath
from typing import Any, Callable, Iterator

__all__ = [
    "atomic_file",
    "atomic_directory",
    "atomic_pair",
    "recover_pair",
    "file_digest",
    "sweep_leftovers",
    "scratch_directory",
    "write_json",
    "json_text",
    "jsonable",
    "usual_mode",
    "output_lock",
    "OutputBusyError",
    "LOCK_WAIT",
    "PUBLISH_HOOK",
]

PUBLISH_HOOK: Callable[[Path], None] | None = None
"""Called with the target just before an output is renamed into place (tests interrupt a run there)."""

LOCK_WAIT = 10.0
"""Seconds a writer waits for another writer of the same output (`output_lock`; ``DUHEM_LOCK_WAIT`` overrides)."""

_HELD: dict[str, int] = {}
"""Output locks this process holds: real path of the output -> depth (`output_lock` is re-entrant)."""
_LIVE: set[str] = set()
"""Real paths of this process's live temporaries (`atomic_file` writes one in place)."""


class OutputBusyError(RuntimeError):
    """Another process holds the lock of an output; the message names the output and that process."""


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
    name.  It is called ``.tmp-<name>.<pid>.<random><suffix>`` (default
    suffix: that of `path`, so tools that choose a format by extension see
    the right one); leftovers of killed writers of `path` are removed first
    (`sweep_leftovers`).
    On success it gets `usual_mode` and replaces `path`; on any exception it
    is removed and `path` is untouched.

    Raises
    ------
    FileNotFoundError
        The directory of `path` does not exist (before the block runs).
    """
    target = Path(path)
    if os.path.realpath(target) in _LIVE:  # a temporary of ours: already private, written in place
        yield target
        return
    check_replaceable(target)
    ending = target.suffix if suffix is None else suffix
    parent = _parent(target)
    with output_lock(target):
        sweep_leftovers(target)
        with _creating(target):
            fd, name = tempfile.mkstemp(prefix=_own_prefix(".tmp-", target), suffix=ending, dir=parent)
        os.close(fd)
        tmp = Path(name)
        _LIVE.add(os.path.realpath(tmp))
        try:
            yield tmp
            os.chmod(tmp, usual_mode())
            _publishing(target)
            os.replace(tmp, target)
        finally:
            _LIVE.discard(os.path.realpath(tmp))
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
    is untouched.  The block runs under `output_lock` of `path`.

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
    foreign = _foreign_entries(target)
    if foreign:
        raise FileExistsError(
            f"{path}: the directory holds files that are not this tool's ({', '.join(foreign[:3])}"
            f"{', ...' if len(foreign) > 3 else ''}) and would be replaced as a whole; give a new or empty "
            "directory (nothing was written)"
        )
    with output_lock(target):
        sweep_leftovers(target)
        with _creating(target):
            tmp = Path(tempfile.mkdtemp(prefix=_own_prefix(".tmp-", target), dir=parent))
        try:
            yield tmp
            (tmp / DIRECTORY_MARK).write_text("written by duhem: replaced as a whole when written again\n")
            os.chmod(tmp, usual_mode(directory=True))
            _publishing(target)
            _swap_in(tmp, target)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


DIRECTORY_MARK = ".duhem-output"
"""The file `atomic_directory` leaves in every directory it publishes: such a directory may be replaced again."""


def _foreign_entries(target: Path) -> list[str]:
    """The entries of an existing directory `target` that `atomic_directory` would lose: none when it is empty
    or one it published (`DIRECTORY_MARK`); the leftovers of its own killed writers are not counted."""
    if not target.is_dir() or (target / DIRECTORY_MARK).exists():
        return []
    return sorted(p.name for p in target.iterdir() if not p.name.startswith((".tmp-", ".lock-")))


def check_replaceable(target: Path) -> None:
    """Refuse an output path that exists and is not a regular file (a device node, a named pipe, a socket, a
    directory): replacing it by a file would destroy it.

    Raises
    ------
    IsADirectoryError, FileExistsError
    """
    if target.is_dir():
        raise IsADirectoryError(f"{target}: is a directory; give a file path for this output")
    if os.path.lexists(target) and target.exists() and not stat.S_ISREG(os.stat(target).st_mode):
        raise FileExistsError(
            f"{target}: exists and is not a regular file (a device, a pipe or a socket); this output is written "
            "as a new file, so give another path (nothing was written)"
        )


@contextlib.contextmanager
def _creating(target: Path) -> Iterator[None]:
    """Creating the temporary of `target`: an `OSError` names `target`, not the temporary (e.g. a
    read-only directory: ``out.csv: cannot write in directory d (Permission denied)``)."""
    try:
        yield
    except OSError as exc:
        raise type(exc)(exc.errno, f"cannot write in directory {target.parent} ({exc.strerror})", str(target)) from None


def _swap_in(new: Path, target: Path) -> None:
    """Rename directory `new` to `target`, replacing an existing directory `target`."""
    if not target.exists():
        os.rename(new, target)
        return
    aside = target.parent / f"{_own_prefix('.old-', target)}{uuid.uuid4().hex}"
    os.rename(target, aside)
    try:
        os.rename(new, target)
    except BaseException:
        os.rename(aside, target)
        raise
    shutil.rmtree(aside, ignore_errors=True)


def _own_prefix(kind: str, target: Path) -> str:
    """``<kind><name>.<pid>.``: the prefix of this process's temporaries for `target`."""
    return f"{kind}{target.name}.{os.getpid()}."


def _publishing(target: Path) -> None:
    if PUBLISH_HOOK is not None:
        PUBLISH_HOOK(target)


def _running(pid: int) -> bool:
    """Whether process `pid` exists (signal 0 probes without sending)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _stale(target: Path, kinds: tuple[str, ...]) -> Iterator[Path]:
    """Entries beside `target` named ``<kind><name>.<pid>.*`` (or ``...<pid>``) whose process is gone (kept
    companions of `recover_pair`, scratch directories)."""
    for entry in target.parent.iterdir() if target.parent.is_dir() else ():
        for kind in kinds:
            head = f"{kind}{target.name}."
            pid = entry.name[len(head) :].split(".", 1)[0] if entry.name.startswith(head) else ""
            if pid.isdigit() and int(pid) != os.getpid() and not _running(int(pid)):
                yield entry


def _abandoned(name: str) -> bool:
    """Whether a ``.tmp-`` or ``.old-`` entry's writer is gone: every number in its name that could be the
    writer's pid (``.<digits>`` then ``.`` or the end: a target's name may hold one too) is neither this
    process nor a running one."""
    if not name.startswith((".tmp-", ".old-")):
        return False
    pids = [int(p) for p in re.findall(r"\.(\d+)(?=\.|$)", name[5:])]
    return bool(pids) and not any(p == os.getpid() or _running(p) for p in pids)


def sweep_leftovers(path: str | os.PathLike) -> list[Path]:
    """Remove the temporaries (``.tmp-``, ``.old-``) and the lock files (``.lock-``) that killed writers left in
    the directory of `path`.

    Any target's, nested ones (``.tmp-.tmp-...``, from before a temporary was written in place)
    included; only entries of processes that no longer run are removed (a concurrent writer's
    temporaries stay), and only lock files that no process holds (`_unheld_lock`).  Returns the removed paths.
    """
    parent = Path(path).parent
    removed = []
    for entry in [e for e in parent.iterdir() if _abandoned(e.name)] if parent.is_dir() else []:
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
        removed.append(entry)
    locks = [e for e in parent.iterdir() if e.name.startswith(".lock-")] if parent.is_dir() else []
    return removed + [e for e in locks if _unheld_lock(e)]


def _unheld_lock(lock: Path) -> bool:
    """Remove `lock` when no process holds it (a writer killed before it could remove its lock file); True when
    removed.  Removed under its own lock, as `output_lock` removes it on release, so that a writer that opened it
    meanwhile finds it gone and opens a new one (`_acquire`).  A lock held by this process through another open
    file is held too (flock)."""
    import fcntl  # POSIX only, as in `_acquire`

    try:
        fd = os.open(lock, os.O_RDWR)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        if not os.path.samestat(os.fstat(fd), os.stat(lock)):
            return False
        os.unlink(lock)
        return True
    except OSError:  # BlockingIOError: held; FileNotFoundError: removed meanwhile
        return False
    finally:
        os.close(fd)


@contextlib.contextmanager
def output_lock(path: str | os.PathLike, *, wait: float | None = None) -> Iterator[None]:
    """Hold the exclusive advisory lock of the output `path` for the block (module docstring).

    `wait`: seconds to wait for another holder (default ``DUHEM_LOCK_WAIT``, else `LOCK_WAIT`).
    Re-entrant within a process.  Raises `OutputBusyError` when the lock is still held after `wait`.
    """
    target = Path(path)
    key = os.path.realpath(target)
    if key in _HELD:
        _HELD[key] += 1
        try:
            yield
        finally:
            _HELD[key] -= 1
        return
    lock = _parent(target) / f".lock-{target.name}"
    fd = _acquire(lock, target, _lock_wait() if wait is None else wait)
    _HELD[key] = 1
    try:
        yield
    finally:
        del _HELD[key]
        with contextlib.suppress(FileNotFoundError):
            os.unlink(lock)  # under the lock: a waiter on this file sees it gone and opens a new one
        os.close(fd)


def _lock_wait() -> float:
    text = os.environ.get("DUHEM_LOCK_WAIT", "")
    try:
        value = float(text) if text else LOCK_WAIT
    except ValueError:
        value = -1.0
    if not value >= 0:
        raise OutputBusyError(f"DUHEM_LOCK_WAIT={text}: not a number of seconds >= 0 (e.g. DUHEM_LOCK_WAIT=10)")
    return value


def _acquire(lock: Path, target: Path, wait: float) -> int:
    """An open descriptor of `lock`, exclusively locked, naming this process; `OutputBusyError` after `wait` s."""
    import fcntl  # POSIX only: imported here, as this module is also shipped inside the FMUs

    deadline = time.monotonic() + wait
    while True:
        with _creating(target):
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            if time.monotonic() >= deadline:
                raise OutputBusyError(
                    f"{target}: another process is writing it ({holder}); waited {wait:g} s: "
                    "run again when it has finished, or write to another path"
                ) from None
            time.sleep(min(0.05, max(deadline - time.monotonic(), 0.0)))
            continue
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(lock))
        except FileNotFoundError:
            same = False
        if same:  # not removed by the holder we waited for
            command = " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if sys.argv and sys.argv[0] else "python"
            os.ftruncate(fd, 0)
            os.write(fd, f"pid {os.getpid()}: {command[:300]}".encode("utf-8", "replace"))
            return fd
        os.close(fd)


def _holder(fd: int) -> str:
    """What the lock file open as `fd` says about its holder."""
    text = os.pread(fd, 400, 0).decode("utf-8", "replace").strip()
    return text or "a process that has not yet written its name"


@contextlib.contextmanager
def scratch_directory(tag: str) -> Iterator[Path]:
    """A private working directory ``<system temp>/<tag>.<pid>.<random>``, removed after the block.

    Those that killed processes left (same `tag`, a process that no longer
    runs) are removed first.
    """
    base = Path(tempfile.gettempdir()) / tag
    for entry in list(_stale(base, ("",))):
        shutil.rmtree(entry, ignore_errors=True)
    with tempfile.TemporaryDirectory(prefix=f"{tag}.{os.getpid()}.") as tmp:
        yield Path(tmp)


def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes, as hex."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def recover_pair(
    record: str | os.PathLike, companion: str | os.PathLike, recorded: Callable[[Path], str | None]
) -> None:
    """Finish or undo a pair publication that a killed process left half done (module docstring).

    A kept old companion (``.pair-<name>.<pid>`` of a process that no longer
    runs) goes back into place when the record still names its digest
    (``recorded(record)``: the run died between the two renames); otherwise
    it is removed.
    """
    record, companion = Path(record), Path(companion)
    for kept in list(_stale(companion, (".pair-",))):
        if record.exists() and recorded(record) == file_digest(kept):
            _put_back(kept, companion)
        else:
            kept.unlink(missing_ok=True)


def _put_back(kept: Path, companion: Path) -> None:
    """Rename `kept` to `companion`; when both are already the same file (rename(2) then does nothing) drop
    the link."""
    if companion.exists() and os.path.samefile(kept, companion):
        kept.unlink()
    else:
        os.replace(kept, companion)


@contextlib.contextmanager
def atomic_pair(
    record: str | os.PathLike, companion: str | os.PathLike, recorded: Callable[[Path], str | None]
) -> Iterator[tuple[Path, Path]]:
    """Yield temporary paths (record, companion); publish them as a pair when the block succeeds.

    Write the companion first and record its `file_digest` in the record.  On
    success the old companion is kept as a hard link, the companion renamed
    into place, then the record (the commit), then the link removed; a
    failure between the renames puts the old companion back.  `recorded`
    reads the digest a record names (for `recover_pair`, run first).  Both
    outputs are locked (`output_lock`) from before recovery until published.
    """
    record, companion = Path(record), Path(companion)
    with output_lock(record), output_lock(companion):
        recover_pair(record, companion, recorded)
        kept = companion.parent / f".pair-{companion.name}.{os.getpid()}"
        try:
            with atomic_file(record) as record_tmp, atomic_file(companion) as companion_tmp:
                yield record_tmp, companion_tmp
                if companion.exists():
                    kept.unlink(missing_ok=True)
                    os.link(companion, kept)
        except BaseException:
            if kept.exists():
                _put_back(kept, companion)
            raise
        kept.unlink(missing_ok=True)


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
