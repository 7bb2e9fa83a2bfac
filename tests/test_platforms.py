"""Binaries for Linux, Windows and macOS from one export, compiled with zig (`fitter.fmu.toolchain`), each checked.

* Every FMU (FMI 2.0 and 3.0, model and compensator) carries a binary for each platform (FMI 2.0
  ``linux64``, ``win64``, ``darwin64``; FMI 3.0 ``x86_64-linux``, ``x86_64-windows``, ``x86_64-darwin``,
  ``aarch64-darwin``) and keeps its sources; `fmpy.validation.validate_fmu` finds nothing.
* Linux and Windows: the same small C host, ``tests/hosts/fmi_host.c``, compiled with zig for
  x86_64-linux-gnu (dlopen) and x86_64-windows-gnu (LoadLibrary), drives the FMU's library: it samples and
  steps, saves the FMU state, runs on, restores it and runs again (and from the serialized state).  The Linux
  run equals the Python kernel (1e-10), the replays equal the first run exactly, and the Windows DLL, run
  under Wine, gives the Linux numbers to 1e-12 relative.  Without Wine that test is skipped and says so.
* macOS: read with macholib: a dylib of the right architecture (FMI 2.0 ``darwin64`` is one universal file with
  an x86_64 and an arm64 slice), exporting exactly the FMI functions of the standard's header, loading
  libSystem alone and binding every undefined symbol to it; the arm64 slice carries a code signature.
* Windows: the DLL exports the same functions and imports only KERNEL32 and the universal C runtime.
* Must show: ``duhem export`` with only the virtual environment's bin on PATH (no gcc, cc or clang) writes
  all binaries and validate_fmu finds nothing.

The FMUs are built once per module.  zig's first compile for a target fills its cache
(``~/.cache/zig``, `fitter.fmu.toolchain.zig_environment`): about 1.5 minutes for Windows' C runtime on
two cores, then about 0.3 s a binary, in every later environment too (`fitter.fmu.toolchain.stable_lib_dir`).
"""

from __future__ import annotations

import ctypes
import json
import os
import re
import shutil
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from samples import sampled_input
from fitter.core import Compensator, load_model, save_model, simulate
from fitter.data.recordings import load_recording
from fitter.fmu.build import build_fmu
from fitter.fmu.native_sources import fmi_headers_dir
from fitter.fmu.toolchain import (
    PLATFORMS,
    PLATFORMS_ENV,
    host_platform,
    parse_platforms,
    zig_command,
    zig_environment,
)
from test_fmu_native import ALL_EFFECTS, rd_model, ri_model
from test_inverse import rd1, ri2

REPO = Path(__file__).resolve().parents[1]
HOST_SOURCE = REPO / "tests" / "hosts" / "fmi_host.c"
DEMO = REPO / "examples" / "demo.csv"
FMI2_FOLDERS = {"linux64", "win64", "darwin64"}
FMI3_FOLDERS = set(PLATFORMS)
WINE_MISSING = (
    "Wine is not installed, so the Windows DLLs were NOT run (install it as root with "
    "'apt-get install -y --no-install-recommends wine64'; .ci/run does)"
)


def _demo_model():
    return load_model(REPO / "examples" / "demo_truth.json")


def _demo_input():
    rec = load_recording(DEMO)
    return rec.t, rec.u


def _plant_output(model, n: int = 300):
    """A reachable reference for a compensator: the plant's output on a sine inside its input range."""
    lo, hi = model.input_range
    t = np.linspace(0.0, 6.0, n)
    u = lo + (hi - lo) * (0.5 + 0.4 * np.sin(2.1 * t) * np.cos(0.37 * t))
    return t, simulate(model, t, u).y


# name -> (model, build options, inputs, reference of the first run)
def _cases():
    demo = _demo_model()
    t, u = _demo_input()
    te, ue = sampled_input(400)
    plant2, plant3 = (
        ri2(),
        rd1(
            [
                {"effect": "creep", "parameters": {"k": 0.2, "tau": 0.6}},
                {"effect": "backlash", "parameters": {"b": 0.1}},
            ]
        ),
    )
    t2, r2 = _plant_output(plant2)
    t3, r3 = _plant_output(plant3)
    return {
        "demo_fmi2": (demo, {}, (t, u), lambda: simulate(demo, t, u).y),
        "demo_fmi3": (demo, {"fmi_version": 3}, (t, u), lambda: simulate(demo, t, u).y),
        "effects_rd_fmi2": (rd_model(ALL_EFFECTS), {}, (te, ue), lambda: simulate(rd_model(ALL_EFFECTS), te, ue).y),
        "effects_ri_fmi3": (
            ri_model(ALL_EFFECTS),
            {"fmi_version": 3},
            (te, ue),
            lambda: simulate(ri_model(ALL_EFFECTS), te, ue).y,
        ),
        "compensator_fmi2": (
            plant2,
            {"inverse": True},
            (t2, r2),
            lambda: Compensator(plant2, t0=float(t2[0])).run(t2, r2).u,
        ),
        "compensator_effects_fmi3": (
            plant3,
            {"inverse": True, "fmi_version": 3},
            (t3, r3),
            lambda: Compensator(plant3, t0=float(t3[0])).run(t3, r3).u,
        ),
    }


CASES = list(_cases())


@pytest.fixture(scope="module")
def cases():
    return _cases()


@pytest.fixture(scope="module")
def built(cases, tmp_path_factory) -> dict:
    """Every case's FMU, all platforms, unzipped: name -> (fmu path, model description, unzip directory)."""
    d = tmp_path_factory.mktemp("platforms")
    out = {}
    for name, (model, options, _, _) in cases.items():
        path = build_fmu(model, d / f"{name}.fmu", backend="native", platforms="all", **options)
        unzipdir = d / name
        with zipfile.ZipFile(path) as zf:
            zf.extractall(unzipdir)
        out[name] = (path, read_model_description(path), unzipdir)
    return out


def _library(md, unzipdir: Path, folder: str, suffix: str) -> Path:
    return unzipdir / "binaries" / folder / f"{md.coSimulation.modelIdentifier}{suffix}"


def _fmi_functions(version: int) -> set[str]:
    """The fmiXxx functions the standard's header declares (every one the framework must export)."""
    text = (fmi_headers_dir() / f"fmi{version}Functions.h").read_text()
    return set(re.findall(rf"#define\s+(fmi{version}\w+)\s+fmi{version}FullName\(", text))


# --------------------------------------------------------------------------- layout, validation


def test_platform_names(monkeypatch):
    monkeypatch.delenv(PLATFORMS_ENV)
    assert parse_platforms(None) == parse_platforms("all") == tuple(PLATFORMS)
    monkeypatch.setenv(PLATFORMS_ENV, "darwin")
    assert parse_platforms(None) == ("x86_64-darwin", "aarch64-darwin")
    assert parse_platforms("windows") == ("x86_64-windows",)
    monkeypatch.setenv(PLATFORMS_ENV, "linux,bogus")
    with pytest.raises(ValueError, match="DUHEM_PLATFORMS='linux,bogus': unknown platform 'bogus'"):
        parse_platforms(None)
    assert parse_platforms("darwin, linux") == ("x86_64-linux", "x86_64-darwin", "aarch64-darwin")
    assert parse_platforms(["win64", "x86_64-windows"]) == ("x86_64-windows",)
    assert parse_platforms("host") == (host_platform(),)
    for bad in ("bogus", "", "linux,solaris"):
        with pytest.raises(ValueError):
            parse_platforms(bad)


def test_zig_runs_on_its_lib_directory_at_a_path_shared_by_every_environment(tmp_path, monkeypatch):
    """zig keys its compiled C runtimes on its lib directory's path: `zig_environment` gives it the wheel's lib
    at ``<cache>/lib-<version>``, the same files (hard links here), made once and kept (a second call leaves it
    as it is and no staging directory behind); a ZIG_LIB_DIR the user set is kept."""
    import importlib.metadata
    import importlib.util

    monkeypatch.delenv("ZIG_LIB_DIR", raising=False)
    monkeypatch.setenv("ZIG_GLOBAL_CACHE_DIR", str(tmp_path))
    lib = Path(zig_environment()["ZIG_LIB_DIR"])
    assert lib == tmp_path / f"lib-{importlib.metadata.version('ziglang')}"
    wheel = Path(importlib.util.find_spec("ziglang").submodule_search_locations[0]) / "lib"
    for name in ("std/std.zig", "libc/include/generic-glibc/stdio.h"):
        assert (lib / name).read_bytes() == (wheel / name).read_bytes()
    assert sum(1 for _ in lib.rglob("*")) == sum(1 for _ in wheel.rglob("*"))
    stamp = (lib.stat().st_ino, lib.stat().st_mtime_ns)
    assert Path(zig_environment()["ZIG_LIB_DIR"]) == lib
    assert (lib.stat().st_ino, lib.stat().st_mtime_ns) == stamp
    assert sorted(p.name for p in tmp_path.iterdir()) == [lib.name]
    monkeypatch.setenv("ZIG_LIB_DIR", str(wheel))
    assert zig_environment()["ZIG_LIB_DIR"] == str(wheel)


@pytest.mark.parametrize("name", CASES)
def test_every_platform_has_its_binary_and_the_sources_stay(built, name):
    path, md, unzipdir = built[name]
    with zipfile.ZipFile(path) as zf:
        names = zf.namelist()
    binaries = {n.split("/")[1]: n.split("/")[2] for n in names if n.startswith("binaries/")}
    identifier = md.coSimulation.modelIdentifier
    if md.fmiVersion == "2.0":
        assert binaries == {
            "linux64": f"{identifier}.so",
            "win64": f"{identifier}.dll",
            "darwin64": f"{identifier}.dylib",
        }
        assert md.buildConfigurations[0].sourceFileSets[0].sourceFiles[0] == "fmi2.c"
    else:
        assert binaries == {p: f"{identifier}{spec.suffix}" for p, spec in PLATFORMS.items()}
        assert "sources/buildDescription.xml" in names
    sources = {n for n in names if n.startswith("sources/")}
    assert {
        f"sources/fmi{md.fmiVersion[0]}.c",
        "sources/cosimulation.c",
        "sources/duhem_model.c",
        "sources/model_data.h",
    } <= sources


@pytest.mark.parametrize("name", CASES)
def test_validate_fmu_finds_nothing(built, name):
    assert validate_fmu(built[name][0]) == []


# --------------------------------------------------------------------------- Linux and Windows, one host


@pytest.fixture(scope="module")
def hosts(tmp_path_factory) -> dict[str, Path]:
    """tests/hosts/fmi_host.c compiled with zig: platform -> executable (flags as the FMU's, so zig's cached
    C runtime is reused)."""
    d = tmp_path_factory.mktemp("hosts")
    out = {}
    for name, target, extra in (
        ("x86_64-linux", PLATFORMS["x86_64-linux"].target, ["-ldl"]),
        ("x86_64-windows", PLATFORMS["x86_64-windows"].target, []),
    ):
        exe = d / ("fmi_host.exe" if "windows" in name else "fmi_host")
        command = [
            *zig_command(),
            "cc",
            "-target",
            target,
            "-O2",
            "-s",
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-I",
            str(fmi_headers_dir()),
            str(HOST_SOURCE),
            "-o",
            str(exe),
            *extra,
        ]
        result = subprocess.run(command, capture_output=True, text=True, cwd=d, env=zig_environment())
        assert result.returncode == 0, result.stderr
        out[name] = exe
    return out


def _wine_programs() -> tuple[str, str] | None:
    wine = (
        shutil.which("wine64")
        or shutil.which("wine")
        or next((p for p in ("/usr/lib/wine/wine64", "/usr/lib/wine/wine") if os.access(p, os.X_OK)), None)
    )
    server = shutil.which("wineserver") or next(
        (p for p in ("/usr/lib/wine/wineserver64", "/usr/lib/wine/wineserver") if os.access(p, os.X_OK)), None
    )
    return (wine, server) if wine and server else None


@pytest.fixture(scope="module")
def wine(tmp_path_factory):
    """(wine, its environment) with a fresh prefix (wineboot: 10-20 s) and its wineserver, kept running for
    the module (a run then takes a few hundredths of a second) and stopped afterwards."""
    programs = _wine_programs()
    if programs is None:
        pytest.skip(WINE_MISSING)
    prefix = tmp_path_factory.mktemp("wineprefix")
    env = {
        **os.environ,
        "WINEPREFIX": str(prefix),
        "WINEDEBUG": "-all",
        "WINEARCH": "win64",
        "WINEDLLOVERRIDES": "mscoree,mshtml=",
    }  # no Mono or Gecko installer
    env.pop("DISPLAY", None)
    # The prefix first (its processes must not hold a captured pipe open), then one wineserver for every run.
    subprocess.run(
        [programs[0], "wineboot.exe", "--init"],
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        timeout=600,
        check=True,
    )
    server = subprocess.Popen(
        [programs[1], "-f", "-p"],
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        yield programs[0], env
    finally:
        subprocess.run([programs[1], "-k"], env=env, capture_output=True, timeout=60)
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()


def _host_arguments(md, library: str, inputs) -> tuple[list[str], str]:
    variables = md.modelVariables
    inp = next(v for v in variables if v.causality == "input")
    out = next(v for v in variables if v.causality == "output")
    state = 2 if md.coSimulation.canSerializeFMUstate else 1 if md.coSimulation.canGetAndSetFMUstate else 0
    t, u = inputs
    save_at = len(t) // 3
    text = "".join(f"{float(a).hex()} {float(b).hex()}\n" for a, b in zip(t, u))
    return [
        md.fmiVersion[0],
        library,
        md.guid,
        str(inp.valueReference),
        str(out.valueReference),
        str(state),
        str(save_at),
    ], text


def _runs(stdout: str) -> list[np.ndarray]:
    runs = []
    for line in stdout.split():
        if line == "run":
            runs.append([])
        else:
            runs[-1].append(float.fromhex(line))
    return [np.array(r) for r in runs]


def _run_host(command: list[str], text: str, env=None) -> list[np.ndarray]:
    result = subprocess.run(command, input=text, capture_output=True, text=True, env=env, timeout=600)
    assert result.returncode == 0, f"exit {result.returncode}: {result.stderr[-2000:]}"
    return _runs(result.stdout)


@pytest.fixture(scope="module")
def linux_runs(built, cases, hosts) -> dict[str, list[np.ndarray]]:
    out = {}
    for name, (_, md, unzipdir) in built.items():
        library = _library(md, unzipdir, "linux64" if md.fmiVersion == "2.0" else "x86_64-linux", ".so")
        arguments, text = _host_arguments(md, str(library), cases[name][2])
        out[name] = _run_host([str(hosts["x86_64-linux"]), *arguments], text)
    return out


@pytest.mark.parametrize("name", CASES)
def test_linux_binary_in_a_c_host_equals_the_kernel_and_replays_its_state(cases, built, linux_runs, name):
    if host_platform() != "x86_64-linux":
        pytest.skip("the Linux binary runs on x86_64 Linux")
    runs = linux_runs[name]
    t = cases[name][2][0]
    k = len(t) // 3
    assert built[name][1].coSimulation.canGetAndSetFMUstate and len(runs) == 4
    first = np.r_[runs[0], runs[1][1:]]
    ref = cases[name][3]()
    assert np.ptp(ref) > 0.1
    assert np.abs(first - ref).max() <= 1e-10 * max(1.0, np.abs(ref).max())
    for replay in runs[2:]:
        assert np.array_equal(replay, runs[1]) and len(replay) == len(t) - k


@pytest.mark.parametrize("name", CASES)
def test_windows_binary_under_wine_equals_linux(built, cases, hosts, linux_runs, wine, name):
    program, env = wine
    path, md, unzipdir = built[name]
    library = _library(md, unzipdir, "win64" if md.fmiVersion == "2.0" else "x86_64-windows", ".dll")
    arguments, text = _host_arguments(md, "Z:" + str(library).replace("/", "\\"), cases[name][2])
    windows = _run_host([program, str(hosts["x86_64-windows"]), *arguments], text, env)
    linux = linux_runs[name]
    assert [len(r) for r in windows] == [len(r) for r in linux] and len(linux) == 4
    for w, x in zip(windows, linux):
        assert np.all(np.abs(w - x) <= 1e-12 * np.abs(x)), np.abs(w - x).max()
    for replay in windows[2:]:
        assert np.array_equal(replay, windows[1])


def _pe(data: bytes):
    """(exported names, imported DLL names) of a PE32+ file (the export and import directories)."""
    pe = struct.unpack_from("<I", data, 0x3C)[0]
    assert data[pe : pe + 4] == b"PE\0\0"
    sections, optional_size = struct.unpack_from("<H", data, pe + 6)[0], struct.unpack_from("<H", data, pe + 20)[0]
    optional = pe + 24
    assert struct.unpack_from("<H", data, optional)[0] == 0x20B  # PE32+
    table = [struct.unpack_from("<IIII", data, optional + optional_size + 40 * i + 8) for i in range(sections)]

    def offset(rva):
        return next(raw + rva - va for size, va, raw_size, raw in table if va <= rva < va + max(size, raw_size))

    def string(rva):
        start = offset(rva)
        return data[start : data.index(b"\0", start)].decode()

    export_rva, import_rva = (struct.unpack_from("<I", data, optional + 112 + 8 * i)[0] for i in (0, 1))
    count, names_rva = (
        struct.unpack_from("<I", data, offset(export_rva) + 24)[0],
        struct.unpack_from("<I", data, offset(export_rva) + 32)[0],
    )
    exports = {string(struct.unpack_from("<I", data, offset(names_rva) + 4 * i)[0]) for i in range(count)}
    imports, at = [], offset(import_rva)
    while struct.unpack_from("<I", data, at + 12)[0]:
        imports.append(string(struct.unpack_from("<I", data, at + 12)[0]))
        at += 20
    return exports, imports


@pytest.mark.parametrize("name", CASES)
def test_windows_and_linux_binaries_export_every_fmi_function(built, name):
    path, md, unzipdir = built[name]
    version = int(md.fmiVersion[0])
    functions = _fmi_functions(version)
    exports, imports = _pe(_library(md, unzipdir, "win64" if version == 2 else "x86_64-windows", ".dll").read_bytes())
    assert exports == functions
    assert all(n.upper() == "KERNEL32.DLL" or n.lower().startswith("api-ms-win-crt-") for n in imports), imports
    if host_platform() == "x86_64-linux":
        so = ctypes.CDLL(str(_library(md, unzipdir, "linux64" if version == 2 else "x86_64-linux", ".so")))
        assert all(hasattr(so, f) for f in functions)


# --------------------------------------------------------------------------- macOS: Mach-O


LINKER_SYMBOLS = {"_mh_dylib_header", "__dso_handle"}
"""What zig's Mach-O linker exports besides the sources' visible functions: the image's own header."""


def _uleb(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[i]
        value, shift, i = value | (byte & 0x7F) << shift, shift + 7, i + 1
        if byte < 0x80:
            return value, i


def _exports(filename: str, header, commands: dict) -> list[str]:
    """The names of a Mach-O slice's export trie: what dyld finds in it (LC_DYLD_INFO_ONLY or
    LC_DYLD_EXPORTS_TRIE)."""
    from macholib import mach_o

    if mach_o.LC_DYLD_INFO_ONLY in commands:
        cmd = commands[mach_o.LC_DYLD_INFO_ONLY][0]
        start, size = cmd.export_off, cmd.export_size
    else:
        cmd = commands[mach_o.LC_DYLD_EXPORTS_TRIE][0]
        start, size = cmd.dataoff, cmd.datasize
    with open(filename, "rb") as fh:
        fh.seek(header.offset + start)
        trie = fh.read(size)
    names, nodes = [], [(0, "")]
    while nodes:
        at, prefix = nodes.pop()
        terminal, at = _uleb(trie, at)
        if terminal:
            names.append(prefix)
        at += terminal
        children, at = trie[at], at + 1
        for _ in range(children):
            end = trie.index(b"\0", at)
            child, next_at = _uleb(trie, end + 1)
            nodes.append((child, prefix + trie[at:end].decode()))
            at = next_at
    return names


@pytest.mark.parametrize("name", CASES)
def test_macos_binaries_have_their_architecture_every_fmi_function_and_only_libsystem(built, name):
    from macholib import mach_o
    from macholib.MachO import MachO
    from macholib.SymbolTable import SymbolTable

    path, md, unzipdir = built[name]
    version = int(md.fmiVersion[0])
    functions = _fmi_functions(version)
    identifier = md.coSimulation.modelIdentifier
    files = (
        {"darwin64": {"x86_64", "arm64"}}
        if version == 2
        else {"x86_64-darwin": {"x86_64"}, "aarch64-darwin": {"arm64"}}
    )
    loads = (
        mach_o.LC_LOAD_DYLIB,
        mach_o.LC_LOAD_WEAK_DYLIB,
        mach_o.LC_REEXPORT_DYLIB,
        mach_o.LC_LAZY_LOAD_DYLIB,
        mach_o.LC_LOAD_UPWARD_DYLIB,
    )
    for folder, architectures in files.items():
        macho = MachO(str(_library(md, unzipdir, folder, ".dylib")))
        assert bool(macho.fat) == (len(architectures) > 1)
        assert {mach_o.CPU_TYPE_NAMES[h.header.cputype].lower() for h in macho.headers} == architectures
        for header in macho.headers:
            arch = mach_o.CPU_TYPE_NAMES[header.header.cputype].lower()
            assert header.header.filetype == mach_o.MH_DYLIB
            commands = {lc.cmd: (cmd, data) for lc, cmd, data in header.commands}
            dylibs = [data.rstrip(b"\0").decode() for lc, cmd, data in header.commands if lc.cmd in loads]
            assert dylibs == ["/usr/lib/libSystem.B.dylib"], (arch, dylibs)
            assert commands[mach_o.LC_ID_DYLIB][1].rstrip(b"\0").decode() == f"@rpath/{identifier}.dylib"
            minos = (
                commands[mach_o.LC_BUILD_VERSION][0].minos
                if mach_o.LC_BUILD_VERSION in commands
                else commands[mach_o.LC_VERSION_MIN_MACOSX][0].version
            )
            assert minos <= (11 << 16 if arch == "arm64" else 10 << 16 | 13 << 8), hex(minos)
            assert (mach_o.LC_CODE_SIGNATURE in commands) or arch == "x86_64"  # Apple Silicon loads signed code only
            exported = {n.removeprefix("_") for n in _exports(macho.filename, header, commands)}
            assert exported - LINKER_SYMBOLS == functions, (arch, exported ^ functions)
            symbols = SymbolTable(macho, header)
            undefined = [(n.decode(), mach_o.GET_LIBRARY_ORDINAL(nl.n_desc)) for nl, n in symbols.undefsyms]
            assert undefined and all(ordinal == 1 for _, ordinal in undefined), (arch, undefined)


# --------------------------------------------------------------------------- the command line


def _path_without_compilers(tmp_path: Path) -> str:
    """A PATH with the virtual environment's bin alone (checked: no cc, gcc, clang, ld on it)."""
    path = str(Path(sys.executable).parent)
    for tool in ("cc", "gcc", "clang", "c99", "ld", "tcc"):
        assert shutil.which(tool, path=path) is None, tool
    return path


def _duhem(*arguments, env=None) -> subprocess.CompletedProcess:
    duhem = Path(sys.executable).parent / "duhem"
    return subprocess.run([str(duhem), *map(str, arguments)], capture_output=True, text=True, env=env, timeout=900)


def test_export_without_a_system_compiler_writes_every_binary(tmp_path):
    save_model(_demo_model(), tmp_path / "model.json")
    env = {k: v for k, v in os.environ.items() if k not in ("CC", "CXX", "LD", PLATFORMS_ENV)}
    env["PATH"] = _path_without_compilers(tmp_path)
    for arguments, folders in (((), FMI2_FOLDERS), (("--fmi-version", "3", "--inverse"), FMI3_FOLDERS)):
        if "--inverse" in arguments:
            save_model(_demo_model().replace(input_range=(0.0, 100.0)), tmp_path / "model.json")
        result = _duhem("export", tmp_path / "model.json", "-o", tmp_path / "m.fmu", *arguments, env=env)
        assert result.returncode == 0, result.stderr
        with zipfile.ZipFile(tmp_path / "m.fmu") as zf:
            assert {n.split("/")[1] for n in zf.namelist() if n.startswith("binaries/")} == folders
        assert validate_fmu(str(tmp_path / "m.fmu")) == []


def test_platforms_option_chooses_the_binaries(tmp_path):
    save_model(ri2(), tmp_path / "model.json")
    result = _duhem(
        "export",
        tmp_path / "model.json",
        "-o",
        tmp_path / "c.fmu",
        "--inverse",
        "--fmi-version",
        "3",
        "--platforms",
        "darwin,windows",
        "--json",
    )
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["platforms"] == ["x86_64-windows", "x86_64-darwin", "aarch64-darwin"]
    with zipfile.ZipFile(tmp_path / "c.fmu") as zf:
        assert sorted(n for n in zf.namelist() if n.startswith("binaries/")) == [
            "binaries/aarch64-darwin/duhem_compensator.dylib",
            "binaries/x86_64-darwin/duhem_compensator.dylib",
            "binaries/x86_64-windows/duhem_compensator.dll",
        ]
    result = _duhem("export", tmp_path / "model.json", "-o", tmp_path / "m.fmu", "--platforms", "linux,solaris")
    assert result.returncode == 1 and result.stderr.count("\n") == 1 and "unknown platform 'solaris'" in result.stderr
    result = _duhem(
        "export", tmp_path / "model.json", "-o", tmp_path / "m.fmu", "--backend", "python", "--platforms", "linux"
    )
    assert result.returncode == 1 and "apply to the native backend" in result.stderr
    assert not (tmp_path / "m.fmu").exists()


def test_cc_compiles_this_machines_binary_with_the_system_compiler(tmp_path):
    if host_platform() != "x86_64-linux" or shutil.which("gcc") is None:
        pytest.skip("needs gcc on x86_64 Linux")
    save_model(ri2(), tmp_path / "model.json")
    result = _duhem(
        "export", tmp_path / "model.json", "-o", tmp_path / "m.fmu", "--cc", "gcc", "--platforms", "linux,windows"
    )
    assert result.returncode == 0, result.stderr
    with zipfile.ZipFile(tmp_path / "m.fmu") as zf:
        assert sorted(n for n in zf.namelist() if n.startswith("binaries/")) == [
            "binaries/linux64/semilinear_duhem.so",
            "binaries/win64/semilinear_duhem.dll",
        ]
        assert b"GCC: (" in zf.read("binaries/linux64/semilinear_duhem.so")
        assert b"GCC: (" not in zf.read("binaries/win64/semilinear_duhem.dll")
    result = _duhem(
        "export", tmp_path / "model.json", "-o", tmp_path / "w.fmu", "--cc", "gcc", "--platforms", "windows"
    )
    assert result.returncode == 1 and "not among the platforms" in result.stderr
