"""The C toolchain of the native backend: zig's C compiler, installed from PyPI, for every platform.

`compile_library` compiles the native FMU's C into the shared library of one
platform of `PLATFORMS` with ``python -m ziglang cc -target <triple>``: the
``ziglang`` wheel (a dependency of this package) carries clang, a linker for
ELF, PE and Mach-O, and the C libraries' headers and link stubs of glibc,
mingw-w64 (UCRT) and macOS's libSystem, so one Linux (or macOS, or Windows)
machine builds the binaries of all of them without a system C compiler.

Why zig: it is the only C cross-toolchain that installs from the package
registry like any other dependency (one wheel, no system packages, no SDKs to
fetch), with a pinned clang, so every export, on every machine, compiles with
the same compiler and the same flags; and it targets an old glibc (2.17,
``x86_64-linux-gnu.2.17``: the library runs on every Linux of the last ten
years), Windows' universal C runtime and macOS 10.13 / 11.0 from the same
command.  The arm64 Mach-O it links carries the ad-hoc code signature that
Apple Silicon requires.

Platforms (`PLATFORMS`, named by their FMI 3.0 platform tuple):

=================  ============  =========================  ==========
platform           FMI 2.0       zig target                 library
=================  ============  =========================  ==========
x86_64-linux       linux64       x86_64-linux-gnu.2.17      ``.so``
x86_64-windows     win64         x86_64-windows-gnu         ``.dll``
x86_64-darwin      darwin64      x86_64-macos.10.13         ``.dylib``
aarch64-darwin     darwin64      aarch64-macos.11.0         ``.dylib``
=================  ============  =========================  ==========

FMI 2.0 has one macOS folder, ``darwin64``: it gets one universal (fat)
Mach-O with a slice per requested macOS architecture (`fat_macho`), so the FMU
loads in x86_64 and in Apple Silicon hosts.

The compiler cache: zig compiles the C runtime pieces of a target the first
time it meets it (mingw-w64's takes about 1.5 minutes on 2 cores; glibc's and
libSystem's stubs a few seconds) and keeps them, and every object, in its
global cache.  `zig_environment` keeps ``ZIG_GLOBAL_CACHE_DIR`` and
``ZIG_LOCAL_CACHE_DIR`` when set, else points both at zig's usual
``$XDG_CACHE_HOME/zig`` (``~/.cache/zig``) when that is writable, else at a
directory in the system temp directory; zig locks its cache, so concurrent
exports share it safely.  A warm export compiles each target in about 0.3 s.
zig keys the cached C runtimes on the real path of its own ``lib`` directory,
which the wheel puts inside the virtual environment: every new environment
would compile them again (75-100 s for Windows alone).  `zig_environment`
therefore points ``ZIG_LIB_DIR`` (unless set) at a copy of that directory at a
path fixed by the wheel's version, ``<cache>/lib-<version>`` (`stable_lib_dir`:
hard links where the file system allows, so it costs no space), made once,
atomically, and shared by every environment with that zig.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import shutil
import struct
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

__all__ = [
    "Platform",
    "PLATFORMS",
    "ALIASES",
    "NativeBuildError",
    "parse_platforms",
    "PLATFORMS_ENV",
    "host_platform",
    "fmi2_folders",
    "check_zig",
    "zig_command",
    "zig_environment",
    "stable_lib_dir",
    "compile_library",
    "compile_libraries",
    "fat_macho",
    "thin_macho_architecture",
]


class NativeBuildError(OSError):
    """The native FMU could not be compiled (no C compiler, or the compiler failed)."""


@dataclass(frozen=True)
class Platform:
    """One binary platform: its FMI 3.0 tuple `name`, FMI 2.0 folder `fmi2`, zig `target`, library `suffix`."""

    name: str
    fmi2: str
    target: str
    suffix: str

    @property
    def system(self) -> str:
        return self.name.split("-", 1)[1]


PLATFORMS: dict[str, Platform] = {
    p.name: p
    for p in (
        Platform("x86_64-linux", "linux64", "x86_64-linux-gnu.2.17", ".so"),
        Platform("x86_64-windows", "win64", "x86_64-windows-gnu", ".dll"),
        Platform("x86_64-darwin", "darwin64", "x86_64-macos.10.13", ".dylib"),
        Platform("aarch64-darwin", "darwin64", "aarch64-macos.11.0", ".dylib"),
    )
}
"""Every platform the native backend builds, in the order of the FMU's binaries."""

ALIASES: dict[str, tuple[str, ...]] = {
    "all": tuple(PLATFORMS),
    "linux": ("x86_64-linux",),
    "linux64": ("x86_64-linux",),
    "windows": ("x86_64-windows",),
    "win64": ("x86_64-windows",),
    "darwin": ("x86_64-darwin", "aarch64-darwin"),
    "macos": ("x86_64-darwin", "aarch64-darwin"),
    "darwin64": ("x86_64-darwin", "aarch64-darwin"),
}
"""Other names accepted by `parse_platforms`: ``all``, an OS, or an FMI 2.0 folder."""

_ARCHITECTURES = {"x86_64": "x86_64", "amd64": "x86_64", "aarch64": "aarch64", "arm64": "aarch64"}


def host_platform() -> str | None:
    """The `PLATFORMS` name of this machine, None if it is none of them."""
    import platform

    system = (
        "linux"
        if sys.platform.startswith("linux")
        else "darwin"
        if sys.platform == "darwin"
        else "windows"
        if sys.platform == "win32"
        else sys.platform
    )
    name = f"{_ARCHITECTURES.get(platform.machine().lower(), platform.machine().lower())}-{system}"
    return name if name in PLATFORMS else None


PLATFORMS_ENV = "DUHEM_PLATFORMS"
"""The environment variable naming the default platforms (as ``--platforms``; unset: all): ``host`` makes
every export compile this machine's binary alone, a third of the time (the test suite sets it)."""


def parse_platforms(platforms: str | Iterable[str] | None) -> tuple[str, ...]:
    """The platform names of `platforms` (None: ``$DUHEM_PLATFORMS`` when set, else all; a comma list or names,
    `PLATFORMS` keys or `ALIASES`, ``host`` for this machine's), without repeats, in `PLATFORMS` order.

    Raises ValueError on an unknown name or an empty selection.
    """
    if platforms is None:
        default = os.environ.get(PLATFORMS_ENV, "").strip()
        if not default:
            return tuple(PLATFORMS)
        try:
            return parse_platforms(default)
        except ValueError as error:
            raise ValueError(f"{PLATFORMS_ENV}={default!r}: {error}") from None
    names = platforms.split(",") if isinstance(platforms, str) else list(platforms)
    chosen = set()
    for raw in names:
        name = raw.strip().lower()
        if name == "host":
            if host_platform() is None:
                raise ValueError(f"this machine ({sys.platform}) is none of the platforms {', '.join(PLATFORMS)}")
            chosen.add(host_platform())
        elif name in PLATFORMS:
            chosen.add(name)
        elif name in ALIASES:
            chosen.update(ALIASES[name])
        elif name:
            raise ValueError(
                f"unknown platform {raw.strip()!r} (expected a comma list of "
                f"{', '.join([*PLATFORMS, *ALIASES, 'host'])})"
            )
    if not chosen:
        raise ValueError("no platform chosen")
    return tuple(name for name in PLATFORMS if name in chosen)


def fmi2_folders(names: Sequence[str]) -> dict[str, tuple[str, ...]]:
    """FMI 2.0 binaries folder -> the platforms whose binaries it holds (darwin64: every macOS one)."""
    folders: dict[str, tuple[str, ...]] = {}
    for name in names:
        folder = PLATFORMS[name].fmi2
        folders[folder] = folders.get(folder, ()) + (name,)
    return folders


# --------------------------------------------------------------------------- zig


def check_zig() -> None:
    """Raise `NativeBuildError` unless the ``ziglang`` package is installed."""
    if importlib.util.find_spec("ziglang") is None:
        raise NativeBuildError(
            "the native FMU backend compiles its C with zig, from the Python package 'ziglang' (a "
            "dependency of semilinear-duhem), which is not installed: 'pip install ziglang', or export "
            "with '--backend python' (the simulator must then provide Python with numpy)"
        )


def zig_command() -> list[str]:
    """The command that runs zig: ``<this Python> -m ziglang``."""
    check_zig()
    return [sys.executable, "-m", "ziglang"]


def _writable(directory: Path) -> bool:
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            pass
        return True
    except OSError:
        return False


def zig_environment() -> dict[str, str]:
    """The environment zig runs in: this one, with writable global and local cache directories."""
    env = dict(os.environ)
    cache = env.get("ZIG_GLOBAL_CACHE_DIR")
    if not cache:
        base = env.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        candidate = Path(base) / "zig"
        if not _writable(candidate):
            user = os.getuid() if hasattr(os, "getuid") else os.getlogin()
            candidate = Path(tempfile.gettempdir()) / f"semilinear-duhem-zig-{user}"
            candidate.mkdir(parents=True, exist_ok=True)
        cache = str(candidate)
    env["ZIG_GLOBAL_CACHE_DIR"] = cache
    env.setdefault("ZIG_LOCAL_CACHE_DIR", cache)
    if not env.get("ZIG_LIB_DIR"):
        lib = stable_lib_dir(Path(cache))
        if lib is not None:
            env["ZIG_LIB_DIR"] = str(lib)
    return env


def stable_lib_dir(cache: Path) -> Path | None:
    """``cache/lib-<ziglang version>``: the ``ziglang`` wheel's ``lib`` directory at a path that does not depend
    on the environment it is installed in (module docstring), made on first use; None when it cannot be made
    (zig then uses its own, and compiles the C runtimes once per environment).

    The copy is of hard links where `cache` is on the wheel's file system, else of the files (234 MB for zig
    0.17); it is built under a temporary name and renamed into place, so a reader never sees half of it and
    concurrent first uses leave one copy.
    """
    check_zig()
    source = Path(importlib.util.find_spec("ziglang").submodule_search_locations[0]) / "lib"
    target = cache / f"lib-{importlib.metadata.version('ziglang')}"
    if target.is_dir():
        return target
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}-", dir=cache))
    try:
        try:
            shutil.copytree(source, staging / "lib", copy_function=os.link)
        except OSError:
            shutil.rmtree(staging / "lib", ignore_errors=True)
            shutil.copytree(source, staging / "lib")
        os.rename(staging / "lib", target)
    except OSError:
        if not target.is_dir():
            return None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return target


def _target_flags(platform: Platform, output: Path) -> list[str]:
    if platform.system == "linux":
        return ["-fPIC"]
    if platform.system == "darwin":
        return [f"-Wl,-install_name,@rpath/{output.name}"]
    return []


def compile_library(
    platform: str,
    flags: Sequence[str],
    include: Path,
    c_files: Sequence[Path],
    output: Path,
    workdir: Path,
    libraries: Sequence[str] = ("m",),
) -> Path:
    """Compile `c_files` into the shared library `output` of `platform` (a `PLATFORMS` name) with zig.

    `flags` are the optimisation flags; the library is stripped and exports
    only what its sources mark visible.  `workdir` (created) takes what the
    linker writes beside it (the import library of a DLL).
    """
    spec = PLATFORMS[platform]
    workdir.mkdir(parents=True, exist_ok=True)
    command = [
        *zig_command(),
        "cc",
        "-target",
        spec.target,
        *flags,
        "-shared",
        "-fvisibility=hidden",
        "-s",
        *_target_flags(spec, output),
        "-I",
        str(include),
        *map(str, c_files),
        "-o",
        str(output),
        *[f"-l{name}" for name in libraries],
    ]
    result = subprocess.run(command, capture_output=True, text=True, cwd=workdir, env=zig_environment())
    if result.returncode != 0 or not output.is_file():
        raise NativeBuildError(
            f"zig cc failed for {platform} ({' '.join(command)}):\n{(result.stderr or result.stdout).strip()}"
        )
    return output


def compile_libraries(
    platforms: Sequence[str], flags: Sequence[str], include: Path, c_files: Sequence[Path], directory: Path, stem: str
) -> dict[str, Path]:
    """`compile_library` for each of `platforms`, concurrently (one compiler a core), into
    ``directory/<platform>/<stem><suffix>``; platform -> library."""

    def build(name: str) -> Path:
        folder = directory / name
        return compile_library(
            name, flags, include, c_files, folder / f"{stem}{PLATFORMS[name].suffix}", folder / "work"
        )

    workers = max(1, min(len(platforms), os.cpu_count() or 1))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return dict(zip(platforms, pool.map(build, platforms)))


# --------------------------------------------------------------------------- Mach-O

_MH_MAGIC_64 = 0xFEEDFACF
_FAT_MAGIC = 0xCAFEBABE
_CPU_NAMES = {0x01000007: "x86_64", 0x0100000C: "arm64"}
_FAT_ALIGN = 14  # 16 KiB, the arm64 page: what lipo uses for arm64 slices


def thin_macho_architecture(data: bytes) -> tuple[int, int]:
    """(cputype, cpusubtype) of a 64-bit little-endian Mach-O file's header."""
    magic, cputype, cpusubtype = struct.unpack_from("<III", data)
    if magic != _MH_MAGIC_64 or cputype not in _CPU_NAMES:
        raise NativeBuildError("not a 64-bit x86_64 or arm64 Mach-O file")
    return cputype, cpusubtype


def fat_macho(slices: Sequence[bytes]) -> bytes:
    """One universal Mach-O file of thin 64-bit `slices` (as ``lipo -create`` writes it: a big-endian fat
    header, then each slice at a 2^14-aligned offset)."""
    if len({thin_macho_architecture(s)[0] for s in slices}) != len(slices):
        raise NativeBuildError("a universal Mach-O file needs one slice per architecture")
    align = 1 << _FAT_ALIGN
    offset = -(-(8 + 20 * len(slices)) // align) * align
    header = struct.pack(">II", _FAT_MAGIC, len(slices))
    parts, position = [], offset
    for k, data in enumerate(slices):
        cputype, cpusubtype = thin_macho_architecture(data)
        header += struct.pack(">IIIII", cputype, cpusubtype, position, len(data), _FAT_ALIGN)
        parts.append(data)
        position += len(data)
        if k + 1 < len(slices):
            parts.append(b"\0" * (-position % align))
            position += -position % align
    return header + b"\0" * (offset - len(header)) + b"".join(parts)
