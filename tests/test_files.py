"""Atomic output files and directories, and strict JSON (`fitter.core.files`)."""

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest


import fitter.core.files as files
from fitter.core.files import (
    atomic_directory,
    atomic_file,
    atomic_pair,
    file_digest,
    json_text,
    jsonable,
    recover_pair,
    sweep_leftovers,
    usual_mode,
    write_json,
)

UMASK = 0o027


@pytest.fixture
def umask():
    old = os.umask(UMASK)
    yield UMASK
    os.umask(old)


def names(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


def test_atomic_file_renames_on_success_with_the_usual_mode(tmp_path, umask):
    target = tmp_path / "out.csv"
    with atomic_file(target) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".tmp-") and tmp.suffix == ".csv"
        assert tmp.exists() and not target.exists()
        tmp.write_text("a,b\n")
    assert target.read_text() == "a,b\n"
    assert target.stat().st_mode & 0o777 == 0o640 == usual_mode()
    assert names(tmp_path) == ["out.csv"]


def test_atomic_file_leaves_the_old_file_on_failure(tmp_path, umask):
    target = tmp_path / "model.json"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_file(target, suffix=".part") as tmp:
            assert tmp.suffix == ".part"
            tmp.write_text("new, half written")
            raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert names(tmp_path) == ["model.json"]


def test_atomic_file_needs_an_existing_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"no/out\.csv: directory .*no does not exist"):
        with atomic_file(tmp_path / "no" / "out.csv"):
            pass
    assert names(tmp_path) == []


def test_atomic_directory_creates_and_replaces_as_a_whole(tmp_path, umask):
    target = tmp_path / "report"
    with atomic_directory(target) as tmp:
        (tmp / "index.html").write_text("one")
        (tmp / "old.png").write_text("png")
    assert names(target) == sorted([files.DIRECTORY_MARK, "index.html", "old.png"])
    assert target.stat().st_mode & 0o777 == 0o750 == usual_mode(directory=True)
    with atomic_directory(target) as tmp:
        (tmp / "index.html").write_text("two")
        assert (target / "index.html").read_text() == "one"  # the old report until the end
    assert names(target) == [files.DIRECTORY_MARK, "index.html"] and (target / "index.html").read_text() == "two"
    assert names(tmp_path) == ["report"]  # no temporary or old directory left


def test_atomic_directory_keeps_the_old_one_on_failure(tmp_path):
    target = tmp_path / "report"
    with atomic_directory(target) as tmp:
        (tmp / "index.html").write_text("old")
    with pytest.raises(ValueError, match="plot failed"):
        with atomic_directory(target) as tmp:
            (tmp / "index.html").write_text("new")
            raise ValueError("plot failed")
    assert names(target) == [files.DIRECTORY_MARK, "index.html"] and (target / "index.html").read_text() == "old"
    assert names(tmp_path) == ["report"]


def test_atomic_directory_refuses_a_directory_of_other_files(tmp_path):
    """A directory the tool did not write (a user's notes in it) is never replaced: refused before anything is
    written, its files kept; an empty one is taken."""
    target = tmp_path / "rep"
    target.mkdir()
    (target / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="notes.txt"):
        with atomic_directory(target):
            raise AssertionError("the block must not run")
    assert names(target) == ["notes.txt"] and names(tmp_path) == ["rep"]
    empty = tmp_path / "empty"
    empty.mkdir()
    with atomic_directory(empty) as tmp:
        (tmp / "index.html").write_text("new")
    assert names(empty) == [files.DIRECTORY_MARK, "index.html"]


def test_atomic_file_refuses_a_device_or_a_pipe(tmp_path):
    """An output path that is a named pipe (or a device node) is not replaced by a plain file."""
    pipe = tmp_path / "mypipe"
    os.mkfifo(pipe)
    with pytest.raises(FileExistsError, match="not a regular file"):
        with atomic_file(pipe):
            raise AssertionError("the block must not run")
    assert stat.S_ISFIFO(os.stat(pipe).st_mode) and names(tmp_path) == ["mypipe"]
    with pytest.raises(FileExistsError, match="not a regular file"), atomic_file("/dev/null"):
        pass


def test_atomic_directory_refuses_a_file_and_a_missing_parent(tmp_path):
    (tmp_path / "report").write_text("a file")
    with pytest.raises(NotADirectoryError, match="report: exists and is not a directory"):
        with atomic_directory(tmp_path / "report"):
            pass
    with pytest.raises(FileNotFoundError, match="does not exist"):
        with atomic_directory(tmp_path / "no" / "report"):
            pass
    assert names(tmp_path) == ["report"]


def test_jsonable_cleans_numpy_and_non_finite_values():
    data = {
        1: np.float64("nan"),
        "a": np.array([1.5, np.inf, -np.inf]),
        "b": (np.int64(3), np.bool_(True)),
        "c": [np.float32(0.25), {"d": Path("x") / "y"}],
        "e": "text",
        "f": None,
        "g": 2,
    }
    out = jsonable(data)
    assert out == {
        "1": None,
        "a": [1.5, None, None],
        "b": [3, True],
        "c": [0.25, {"d": "x/y"}],
        "e": "text",
        "f": None,
        "g": 2,
    }
    assert type(out["b"][0]) is int and type(out["b"][1]) is bool and type(out["c"][0]) is float
    text = json_text(data)
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == out


def test_write_json_is_atomic_and_strict(tmp_path, umask):
    write_json(tmp_path / "out.json", {"x": np.arange(3), "y": float("nan")}, indent=None)
    assert (tmp_path / "out.json").read_text() == '{"x": [0, 1, 2], "y": null}'
    assert (tmp_path / "out.json").stat().st_mode & 0o777 == 0o640
    assert names(tmp_path) == ["out.json"]


def _dead_pid() -> int:
    """The pid of a process that has finished (and been reaped)."""
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(proc.stdout)


def test_leftovers_of_killed_writers_are_removed_by_the_next_write(tmp_path):
    """Any target's leftovers in the directory, a nested build leftover (.tmp-.tmp-) too; a running writer's stay,
    also when a number in the target's name is a running pid."""
    dead, target = _dead_pid(), tmp_path / "out.csv"
    left = [
        tmp_path / f".tmp-out.csv.{dead}.abc.csv",
        tmp_path / f".old-out.csv.{dead}.ff",
        tmp_path / f".tmp-other.csv.{dead}.abc.csv",  # another target's
        tmp_path / f".tmp-.tmp-m.fmu.{dead}.a1b2c3d4.fmu.{dead}.e5f6g7h8.fmu",
    ]  # a killed FMU build's
    for path in left:
        path.write_text("half")
    left[1].unlink()
    left[1].mkdir()
    alive = tmp_path / f".tmp-out.csv.{os.getppid()}.xyz.csv"  # a running writer's temporary stays
    ambiguous = tmp_path / f".tmp-run.{os.getppid()}.csv.{dead}.abc.csv"
    alive.write_text("busy")
    ambiguous.write_text("busy?")
    with atomic_file(target) as tmp:
        tmp.write_text("new")
    assert names(tmp_path) == sorted([alive.name, ambiguous.name, "out.csv"])
    left[0].write_text("half")
    assert sweep_leftovers(tmp_path / "other.csv") == [left[0]]


def test_a_temporary_is_written_in_place_never_given_its_own(tmp_path):
    """An FMU build writing into the command's temporary: no name doubles '.tmp-.tmp-'."""
    seen = []
    with atomic_file(tmp_path / "m.fmu") as tmp:
        with atomic_file(tmp) as inner:
            inner.write_text("fmu")
            seen = names(tmp_path)
        assert inner == tmp and tmp.read_text() == "fmu"
    assert [n for n in seen if n.startswith(".tmp-")] == [tmp.name]
    assert not any(n.startswith(".tmp-.tmp-") for n in seen)
    assert names(tmp_path) == ["m.fmu"] and (tmp_path / "m.fmu").read_text() == "fmu"


def test_a_second_writer_fails_naming_the_output_and_the_first(tmp_path, holder, monkeypatch):
    target = tmp_path / "out.csv"
    target.write_text("old")
    pid = holder(target)
    monkeypatch.setenv("DUHEM_LOCK_WAIT", "0")
    with pytest.raises(files.OutputBusyError) as exc, atomic_file(target) as tmp:
        tmp.write_text("new")
    assert str(exc.value).startswith(f"{target}: another process is writing it (pid {pid}: ")
    assert "waited 0 s" in str(exc.value) and "write to another path" in str(exc.value)
    with pytest.raises(files.OutputBusyError), atomic_pair(tmp_path / "m.json", target, _digest_in):
        pass
    assert target.read_text() == "old" and names(tmp_path) == [".lock-out.csv", "out.csv"]


def test_the_lock_is_reentrant_and_leaves_no_file(tmp_path, holder, monkeypatch):
    target = tmp_path / "out"
    with files.output_lock(target), atomic_directory(target) as tmp:
        (tmp / "a").write_text("a")
        assert names(tmp_path) == [".lock-out", tmp.name]
    assert names(tmp_path) == ["out"]
    monkeypatch.setenv("DUHEM_LOCK_WAIT", "0")
    holder(target)
    with pytest.raises(files.OutputBusyError, match="another process is writing it"), atomic_directory(target):
        pass
    assert names(tmp_path) == [".lock-out", "out"] and names(target) == [files.DIRECTORY_MARK, "a"]
    monkeypatch.setenv("DUHEM_LOCK_WAIT", "soon")
    with (
        pytest.raises(files.OutputBusyError, match="DUHEM_LOCK_WAIT=soon: not a number of seconds"),
        atomic_file(tmp_path / "x"),
    ):
        pass


def _digest_in(record: Path) -> str | None:
    return json.loads(record.read_text()).get("sha256")


def _publish(record: Path, companion: Path, content: str, stop_before: Path | None = None) -> None:
    """Publish the pair (companion `content`, record naming its digest); raise just before renaming `stop_before`."""

    def hook(target):
        if target == stop_before:
            raise KeyboardInterrupt("interrupted")

    files.PUBLISH_HOOK = hook
    try:
        with atomic_pair(record, companion, _digest_in) as (rec_tmp, comp_tmp):
            comp_tmp.write_text(content)
            rec_tmp.write_text(json.dumps({"sha256": file_digest(comp_tmp)}))
    finally:
        files.PUBLISH_HOOK = None


@pytest.mark.parametrize("stop", [None, "companion", "record"])
def test_a_pair_is_published_whole_or_not_at_all(tmp_path, stop):
    record, companion = tmp_path / "m.json", tmp_path / "m.fmu"
    _publish(record, companion, "old")
    where = {"companion": companion, "record": record}.get(stop)
    if where is None:
        _publish(record, companion, "new")
    else:
        with pytest.raises(KeyboardInterrupt):
            _publish(record, companion, "new", stop_before=where)
    expect = "new" if stop is None else "old"
    assert companion.read_text() == expect and _digest_in(record) == file_digest(companion)
    assert names(tmp_path) == ["m.fmu", "m.json"]


def test_recover_pair_puts_back_the_old_companion_of_a_run_killed_between_the_renames(tmp_path):
    """The state a SIGKILL between the two renames leaves: old record, new companion, the old one kept."""
    record, companion, dead = tmp_path / "m.json", tmp_path / "m.fmu", _dead_pid()
    companion.write_text("old")
    record.write_text(json.dumps({"sha256": file_digest(companion)}))
    os.link(companion, tmp_path / f".pair-m.fmu.{dead}")
    (tmp_path / "new").write_text("new")
    os.replace(tmp_path / "new", companion)
    recover_pair(record, companion, _digest_in)
    assert companion.read_text() == "old" and names(tmp_path) == ["m.fmu", "m.json"]
    os.link(companion, tmp_path / f".pair-m.fmu.{dead}")  # killed after the commit: the link goes
    recover_pair(record, companion, _digest_in)
    assert companion.read_text() == "old" and names(tmp_path) == ["m.fmu", "m.json"]


def test_scratch_directories_of_killed_processes_are_swept(tmp_path, monkeypatch):
    monkeypatch.setattr(files.tempfile, "tempdir", str(tmp_path))
    dead = _dead_pid()
    (tmp_path / f"duhem_native.{dead}.abc").mkdir()
    (tmp_path / f"duhem_native.{os.getppid()}.abc").mkdir()  # a running build stays
    with files.scratch_directory("duhem_native") as work:
        assert work.name.startswith(f"duhem_native.{os.getpid()}.") and work.is_dir()
    assert names(tmp_path) == [f"duhem_native.{os.getppid()}.abc"]


def test_two_outputs_at_one_path_or_one_inside_the_report_are_refused(tmp_path):
    """`duhem fit rec.csv -o same.fmu --fmu same.fmu` and `-o rep/m.json --report rep` are refused before any
    fitting, each in one line naming the paths (before, the second output overwrote the first, or the fit ended
    with an internal temporary path)."""
    from fitter.cli.common import refuse_overwrite
    from fitter.cli_support import CliError

    same = str(tmp_path / "same.fmu")
    with pytest.raises(CliError, match=r"same.fmu: given for two outputs"):
        refuse_overwrite(["rec.csv"], same, same, None)
    rep = str(tmp_path / "rep")
    with pytest.raises(CliError, match=r"m.json: is inside the directory .*rep, which is written as a whole"):
        refuse_overwrite(["rec.csv"], str(tmp_path / "rep" / "m.json"), None, rep)
    refuse_overwrite(["rec.csv"], str(tmp_path / "m.json"), str(tmp_path / "m.fmu"), rep)


def test_a_killed_writers_lock_file_goes_with_the_next_write_a_live_ones_stays(tmp_path, holder):
    """kill -9 leaves the holder's ``.lock-`` file (its lock died with it); the next write into the directory
    removes it, as it removes a killed writer's temporaries, and keeps a lock a live process holds."""
    import signal

    dead, live = tmp_path / "dead.csv", tmp_path / "live.csv"
    pid = holder(dead)
    holder(live)
    os.kill(pid, signal.SIGKILL)
    os.waitpid(pid, 0)
    assert names(tmp_path) == [".lock-dead.csv", ".lock-live.csv"]
    with atomic_file(tmp_path / "other.csv") as tmp:
        tmp.write_text("x")
    assert names(tmp_path) == [".lock-live.csv", "other.csv"]
