"""Atomic output files and directories, and strict JSON (`fitter.core.files`)."""
import json
import os
from pathlib import Path

import numpy as np
import pytest

from fitter.core.files import atomic_directory, atomic_file, json_text, jsonable, usual_mode, write_json

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
    assert names(target) == ["index.html", "old.png"]
    assert target.stat().st_mode & 0o777 == 0o750 == usual_mode(directory=True)
    with atomic_directory(target) as tmp:
        (tmp / "index.html").write_text("two")
        assert (target / "index.html").read_text() == "one"      # the old report until the end
    assert names(target) == ["index.html"] and (target / "index.html").read_text() == "two"
    assert names(tmp_path) == ["report"]                           # no temporary or old directory left


def test_atomic_directory_keeps_the_old_one_on_failure(tmp_path):
    target = tmp_path / "report"
    target.mkdir()
    (target / "index.html").write_text("old")
    with pytest.raises(ValueError, match="plot failed"):
        with atomic_directory(target) as tmp:
            (tmp / "index.html").write_text("new")
            raise ValueError("plot failed")
    assert names(target) == ["index.html"] and (target / "index.html").read_text() == "old"
    assert names(tmp_path) == ["report"]


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
    data = {1: np.float64("nan"), "a": np.array([1.5, np.inf, -np.inf]), "b": (np.int64(3), np.bool_(True)),
            "c": [np.float32(0.25), {"d": Path("x") / "y"}], "e": "text", "f": None, "g": 2}
    out = jsonable(data)
    assert out == {"1": None, "a": [1.5, None, None], "b": [3, True], "c": [0.25, {"d": "x/y"}], "e": "text",
                   "f": None, "g": 2}
    assert type(out["b"][0]) is int and type(out["b"][1]) is bool and type(out["c"][0]) is float
    text = json_text(data)
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == out


def test_write_json_is_atomic_and_strict(tmp_path, umask):
    write_json(tmp_path / "out.json", {"x": np.arange(3), "y": float("nan")}, indent=None)
    assert (tmp_path / "out.json").read_text() == '{"x": [0, 1, 2], "y": null}'
    assert (tmp_path / "out.json").stat().st_mode & 0o777 == 0o640
    assert names(tmp_path) == ["out.json"]
