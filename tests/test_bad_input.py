"""The bad-input table of issue 15 (items 4 and 8): every case is refused in the house style.

Each case runs `duhem` in-process and must exit with code 1 and one stderr line
``error: <file>: <what>`` that names the file and the place (the model JSON's
key with the expected type or shape, the FMU's broken part, an XML or JSON line
and column, the CSV column), never a library's internal text, a temporary
file or click's usage text; every existing file (``out.csv`` among them) is
left as it was, byte for byte, and none is added.

The inputs are built once for the module: model JSON files with one key
broken, FMUs made by hand with `zipfile` from one real native FMU (garbage
binary, corrupt ``resources/model.json``, ...) and small recordings.
A read-only output directory and an unreadable input are simulated (the
suite may run as root): ``tempfile.mkstemp`` and ``os.access`` refuse as the
operating system would.
"""

import errno
import json
import os
import shutil
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import fmpy
import numpy as np
import pytest
from samples import ri_model, sine_input
from test_cli import assert_clean_failure, invoke, listing, write_csv

from fitter.core import save_model, simulate
from fitter.fmu.build import build_fmu

BINARY = f"binaries/{fmpy.platform}/semilinear_duhem{fmpy.sharedLibraryExtension}"
FORBIDDEN = ("Traceback", "internal error", "Usage:", ".tmp-", "duhem_fmu_check", "Errno")


def _variant(source: Path, target: Path, change: Callable[[str, bytes], bytes | None]) -> None:
    """Copy the FMU `source` to `target` with each member's bytes passed through `change` (None drops it)."""
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            data = change(item.filename, zin.read(item.filename))
            if data is not None:
                zout.writestr(item, data)


def _member(name: str, new: bytes | None) -> Callable[[str, bytes], bytes | None]:
    """A `_variant` change that replaces (or, with None, drops) the member `name`."""
    return lambda member, data: new if member == name else data


def _edited_xml(old: bytes, new: bytes) -> Callable[[str, bytes], bytes | None]:
    """A `_variant` change that replaces `old` by `new` in modelDescription.xml."""
    return lambda member, data: data.replace(old, new) if member == "modelDescription.xml" else data


def _model_json(d: Path, name: str, edit: Callable[[dict], None]) -> None:
    """``d/name``: ``d/model.json`` with `edit` applied to its dictionary."""
    data = json.loads((d / "model.json").read_text())
    edit(data)
    (d / name).write_text(json.dumps(data))


def _crashing_library(d: Path) -> bytes:
    """A shared library for this machine whose loading crashes (a constructor that writes to address 0): a binary
    damaged so that the loader faults rather than refuses it.  Compiled by zig (package ``ziglang``, the native
    backend's compiler)."""
    import subprocess
    import sys

    (d / "crash.c").write_text("__attribute__((constructor)) static void boom(void) { *(volatile int *)0 = 0; }\n")
    out = d / f"crash{fmpy.sharedLibraryExtension}"
    cmd = [sys.executable, "-m", "ziglang", "cc", "-shared", "-fPIC", "-O0", "-o", str(out), str(d / "crash.c")]
    subprocess.run(cmd, check=True, capture_output=True)
    return out.read_bytes()


def _fmus(d: Path, fmu: Path) -> None:
    """The broken FMUs, each from the real `fmu`."""
    with zipfile.ZipFile(fmu) as z:
        broken_json = json.loads(z.read("resources/model.json"))
    broken_json["parameters"]["A_plus"] = [[1.0, 2.0], [3.0]]
    (d / "garbage.fmu").write_bytes(b"PK\x03\x04 this is not a zip archive")
    _variant(fmu, d / "no_xml.fmu", _member("modelDescription.xml", None))
    _variant(fmu, d / "bad_xml.fmu", _member("modelDescription.xml", b'<?xml version="1.0"?>\n<fmiModelDescription\n<'))
    _variant(fmu, d / "fmi1.fmu", _edited_xml(b'fmiVersion="2.0"', b'fmiVersion="1.0"'))
    _variant(fmu, d / "schema.fmu", _edited_xml(b' guid="', b' gxid="'))
    _variant(fmu, d / "no_binary.fmu", _member(BINARY, None))
    _variant(fmu, d / "bad_binary.fmu", _member(BINARY, b"\x7fELF" + bytes(range(256)) * 4))
    _variant(fmu, d / "crashing_binary.fmu", _member(BINARY, _crashing_library(d)))
    _variant(fmu, d / "no_model.fmu", _member("resources/model.json", None))
    _variant(fmu, d / "corrupt_model.fmu", _member("resources/model.json", b'{"schema": "duhem-model",\n "kind": '))
    _variant(fmu, d / "schema_model.fmu", _member("resources/model.json", json.dumps(broken_json).encode()))


@pytest.fixture(scope="module")
def d(tmp_path_factory, fmu_cache) -> Path:
    """A directory of bad inputs beside good ones and an existing output ``out.csv``."""
    d = tmp_path_factory.mktemp("bad_input")
    model = ri_model(2)
    t, u = sine_input(1.0, 2, 100)
    y = simulate(model, t, u).y
    write_csv(d / "rec.csv", t, u, y)
    spike = u.copy()
    spike[50] = 1e90
    write_csv(d / "spike.csv", t, spike, y)
    write_csv(d / "flat.csv", t, u, np.full_like(y, 2.0))
    save_model(model, d / "model.json")
    _model_json(d, "signals.json", lambda m: m.update(signals="u -> y"))
    _model_json(d, "experiment.json", lambda m: m.update(experiment=[0, 10]))
    _model_json(d, "ragged.json", lambda m: m["parameters"].update(A_plus=[[1.0, 2.0], [3.0]]))
    _model_json(d, "strings.json", lambda m: m["parameters"].update(A_minus=[["1", "x"], [0, 1]]))
    _model_json(d, "object.json", lambda m: m["parameters"].update(D={"value": 1}))
    _model_json(d, "fit_info.json", lambda m: m.update(fit_info=["fitted"]))
    (d / "truncated.json").write_text((d / "model.json").read_text()[:80])
    shutil.copy(fmu_cache.build(model, "native"), d / "model.fmu")
    _fmus(d, d / "model.fmu")
    build_fmu(model, d / "fmi3.fmu", backend="native", fmi_version=3)
    (d / "folder").mkdir()
    (d / "ro").mkdir()
    (d / "out.csv").write_text("old\n")
    return d


def _read_only(d: Path, monkeypatch) -> None:
    """``d/ro`` is read-only: creating a file there fails as mkstemp(3) would."""
    real = tempfile.mkstemp

    def mkstemp(suffix=None, prefix=None, dir=None, text=False):
        if dir is not None and Path(dir) == d / "ro":
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), os.path.join(dir, f"{prefix}x{suffix}"))
        return real(suffix, prefix, dir, text)

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)


def _unreadable(d: Path, monkeypatch) -> None:
    """``d/rec.csv`` cannot be read (access(2) says so; root could read it anyway)."""
    real = os.access
    monkeypatch.setattr(
        os,
        "access",
        lambda path, mode, **kw: False if Path(path) == d / "rec.csv" and mode & os.R_OK else real(path, mode, **kw),
    )


@dataclass(frozen=True)
class Case:
    """`duhem args` (``{d}``: the inputs' directory) must fail naming ``d/file`` first, then `needles`."""

    args: tuple[str, ...]
    file: str
    needles: tuple[str, ...]
    setup: Callable[[Path, pytest.MonkeyPatch], None] | None = None


def simulate_with(model: str, *needles: str) -> Case:
    """``duhem simulate MODEL rec.csv -o out.csv`` (out.csv exists) must blame MODEL."""
    return Case(("simulate", f"{{d}}/{model}", "{d}/rec.csv", "-o", "{d}/out.csv"), model, needles)


def validate(fmu: str, *needles: str) -> Case:
    """``duhem validate FMU rec.csv --plot out.png`` must blame FMU."""
    return Case(("validate", f"{{d}}/{fmu}", "{d}/rec.csv", "--plot", "{d}/out.png"), fmu, needles)


def fit(*args: str, file: str, needles: tuple[str, ...], setup=None) -> Case:
    """``duhem fit ARGS -o out.json`` must blame `file`."""
    return Case(("fit", *args, "-o", "{d}/out.json"), file, needles, setup)


CASES = {
    # model JSON: the key, the expected type or shape, what the file has
    "signals not an object": simulate_with(
        "signals.json", "key 'signals': expected an object with keys 'input' and 'output', got the string 'u -> y'"
    ),
    "experiment not an object": simulate_with(
        "experiment.json",
        "key 'experiment': expected an object with keys start_time, stop_time, step_size, got a list of 2 numbers",
    ),
    "ragged matrix": simulate_with(
        "ragged.json", "key 'parameters.A_plus': expected a 2x2 matrix of numbers, got a ragged list"
    ),
    "string matrix": simulate_with(
        "strings.json",
        "key 'parameters.A_minus': expected a 2x2 matrix of numbers, got a list containing the string '1'",
    ),
    "object for a number": simulate_with(
        "object.json", "key 'parameters.D': expected a finite number, got an object with keys 'value'"
    ),
    "fit_info not an object": simulate_with("fit_info.json", "key 'fit_info': expected an object, got a list"),
    "truncated JSON": simulate_with("truncated.json", "not a JSON model file (invalid JSON at line 5, column"),
    # FMU: the broken part
    "not a zip archive": validate("garbage.fmu", "not an FMU (not a zip archive, or a damaged one)"),
    "no modelDescription.xml": validate("no_xml.fmu", "not an FMU (the archive has no modelDescription.xml)"),
    "malformed XML": validate("bad_xml.fmu", "modelDescription.xml is not well-formed XML: line 3, column 1"),
    "FMI 1.0": validate("fmi1.fmu", "modelDescription.xml declares fmiVersion '1.0': not an FMI 2.0 or 3.0 FMU"),
    "schema violation": validate(
        "schema.fmu", "modelDescription.xml does not follow the FMI 2.0 schema: line 2:", "'gxid'"
    ),
    "FMI 3.0 given to the FMI 2.0 host": validate("fmi3.fmu", "an FMI 3.0 FMU: this host drives FMI 2.0 FMUs"),
    "no binary for this platform": validate("no_binary.fmu", f"no binary for this platform ({BINARY} is missing"),
    "garbage binary": validate("bad_binary.fmu", f"the binary {BINARY} cannot be loaded on this machine"),
    "garbage binary, simulate": simulate_with("bad_binary.fmu", f"the binary {BINARY} cannot be loaded"),
    "binary that crashes the loader": validate(
        "crashing_binary.fmu", f"the binary {BINARY} crashed the loader (signal 11)", "export the FMU again"
    ),
    "binary that crashes the loader, simulate": simulate_with("crashing_binary.fmu", "crashed the loader"),
    "no resources/model.json": validate("no_model.fmu", "no resources/model.json: not an FMU exported by duhem"),
    "corrupt resources/model.json": validate(
        "corrupt_model.fmu", "resources/model.json: not a JSON model file (invalid JSON at line 2, column 10"
    ),
    "schema error in resources/model.json": simulate_with(
        "schema_model.fmu",
        "resources/model.json: key 'parameters.A_plus': expected a 2x2 matrix of numbers, got a ragged list",
    ),
    # files and directories
    "directory as input": fit("{d}/folder", file="folder", needles=("is a directory, not a file",)),
    "directory as FMU": validate("folder", "is a directory, not a file"),
    "file as report directory": fit(
        "{d}/rec.csv", "--report", "{d}/out.csv", file="out.csv", needles=("is a file, not a directory",)
    ),
    "unreadable input": fit(
        "{d}/rec.csv", file="rec.csv", needles=("cannot be read (permission denied)",), setup=_unreadable
    ),
    "read-only output directory": Case(
        ("simulate", "{d}/model.json", "{d}/rec.csv", "-o", "{d}/ro/out.csv"),
        "ro/out.csv",
        ("cannot write in directory", "(Permission denied)"),
        _read_only,
    ),
    # numerical dead ends, named by file
    "baseline on an input outlier": fit(
        "{d}/spike.csv",
        "--kind",
        "ri",
        "--order",
        "1",
        "--compare",
        file="spike.csv",
        needles=("cannot be fitted: its least-squares problem is singular",),
    ),
    "input lost in the pooled range": fit(
        "{d}/spike.csv",
        "{d}/rec.csv",
        file="rec.csv",
        needles=("the input does not move at the scale of all recordings",),
    ),
    "constant output": fit(
        "{d}/flat.csv", file="flat.csv", needles=("the output (column 'y') is constant over all recordings",)
    ),
}


def _contents(d: Path) -> dict[str, bytes]:
    """Every file under `d` and its bytes."""
    return {name: (d / name).read_bytes() for name in listing(d) if (d / name).is_file()}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_is_one_line_naming_the_file(d, case, monkeypatch):
    c = CASES[case]
    if c.setup:
        c.setup(d, monkeypatch)
    before, contents = listing(d), _contents(d)
    result = invoke(*[a.format(d=d) for a in c.args])
    line = assert_clean_failure(result, d, before, f"error: {d / c.file}: ", *c.needles)
    assert not any(word in line for word in FORBIDDEN), line
    assert _contents(d) == contents
