"""The native backend: an FMI 2.0 or 3.0 Co-Simulation FMU that is a plain C shared library.

`build_native_fmu` compiles the C sources of ``fmu_src/native/`` at export
time into one shared library per platform, with zig's C compiler from the
``ziglang`` package (`fitter.fmu.toolchain`; no system compiler needed):
by default Linux, Windows and macOS (x86_64 and arm64), in FMI 2.0's
``binaries/linux64``, ``win64`` and ``darwin64`` (one universal Mach-O) or
FMI 3.0's ``binaries/x86_64-linux``, ``x86_64-windows``, ``x86_64-darwin``
and ``aarch64-darwin``; ``platforms`` chooses (`toolchain.parse_platforms`).
Each library depends on the C library only (glibc 2.17's libc and libm,
Windows' universal C runtime, macOS's libSystem), so the FMU runs in hosts
without Python (fmusim, the FMI Compliance Checker, Simulink, Dymola, ...).
A system compiler is used only when asked: ``cc=`` (``duhem export --cc``)
compiles this machine's binary with it, and the sanitizer build
(``sanitize=True``, tests) is this machine's binary alone, compiled by ``cc``
or ``$CC`` or the first of cc, gcc, clang on PATH.  The FMU also carries its C
sources under ``sources/`` (a source FMU: FMI 2.0 lists them in the
modelDescription's ``<SourceFiles>``, FMI 3.0 in
``sources/buildDescription.xml``), so an importer on any other platform can
compile it.

The C sources, their layout (one framework, ``cosimulation.c``, for both FMI
versions; the model file behind ``model_interface.h``; fmpy's standard FMI
headers) and the generated ``model_data.h`` are `fitter.fmu.native_sources`.

The compensator (`build_native_compensator`, ``duhem export --inverse``):
``inverse_model.c`` in place of ``duhem_model.c``, which it includes with its
hooks renamed (the root finding of `fitter.core.inverse.Compensator` on the
plant's own C step); the same generated ``model_data.h`` (the plant's) with the
compensator's GUID and ``COMPENSATOR_REFERENCE_START``.

``resources/model.json`` carries the model itself (not read by the C; `duhem
validate` compares the FMU with its in-process simulation).

The math equals the Python kernel's (`fitter.core.stepper.Stepper` on
`fitter.core.kernel`, `fitter.core.rates`, `fitter.core.effects`): the flow of
eq (K) of the kernel is the matrix exponential of the augmented matrix
(scaling and squaring of the kernel's Taylor series, `flow.phi_blocks`); the rate
function's PCHIP slopes are computed by the same rules.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import shutil
import struct
import subprocess
import sys
import uuid
import zipfile
from pathlib import Path
from typing import Iterable
from xml.etree import ElementTree as ET

from fitter.core.files import atomic_file, scratch_directory
from fitter.fmu.model_description import FMI_VERSIONS, model_description_xml, model_description_xml3
from fitter.fmu.native_sources import (
    COMPENSATOR_FILE,
    GAIN_FILE,
    MODEL_FILE,
    SOURCE_DIR,
    c_sources,
    check_supported,
    compensator_data_header,
    model_data_header,
    source_files,
    source_hash,
)
from fitter.fmu.toolchain import (
    PLATFORMS,
    NativeBuildError,
    check_zig,
    compile_libraries,
    fat_macho,
    host_platform,
    parse_platforms,
)

__all__ = [
    "build_native_fmu",
    "build_native_compensator",
    "build_gain_fmu",
    "NativeBuildError",
    "find_c_compiler",
    "check_toolchain",
    "PLATFORMS",
    "MODEL_IDENTIFIER",
    "LOG_CATEGORIES",
]

MODEL_IDENTIFIER = "semilinear_duhem"
LOG_CATEGORIES = {
    "logStatusError": "Refused calls and failures (always reported).",
    "logStatusDiscard": "Status requests that are not available (always reported).",
    "logCalls": "Every FMI call (with debug logging on).",
}
OPTIMIZE = ("-O2", "-ffp-contract=off")
"""-ffp-contract=off: no fused multiply-adds (aarch64 compilers fuse by default), so the C flow rounds as numpy does."""
SANITIZE = ("-O1", "-g", "-fno-omit-frame-pointer", "-fsanitize=address,undefined", "-fno-sanitize-recover=undefined")
_GUID_NAMESPACE = uuid.UUID("0f8a3c52-6f7e-4d0b-8e61-0c1f3b9d2a74")
_COMPILERS = ("cc", "gcc", "clang")


def find_c_compiler(cc: str | None = None) -> str:
    """Path of the system C compiler (``cc=`` and sanitizer builds only; the others use zig): `cc`, else
    ``$CC``, else the first of cc, gcc, clang on PATH."""
    candidates = [cc] if cc else ([os.environ["CC"]] if os.environ.get("CC") else list(_COMPILERS))
    for name in candidates:
        found = shutil.which(name)
        if found:
            return found
    raise NativeBuildError(
        f"no C compiler found (looked for {', '.join(candidates)}): the compiler asked for must be "
        "installed (without --cc the native backend compiles with zig, from the package 'ziglang'), or "
        "export with '--backend python' (no compiler needed, but the simulator must then provide "
        "Python with numpy)"
    )


def check_toolchain(cc: str | None = None, sanitize: bool = False) -> None:
    """Raise `NativeBuildError` (its message names ``--backend python``) unless the native backend can
    compile: zig (package ``ziglang``), and the system compiler when `cc` or `sanitize` asks for it."""
    if cc or sanitize:
        find_c_compiler(cc)
    else:
        check_zig()


def _selection(platforms, fmi_version: int, cc: str | None, sanitize: bool) -> tuple[tuple[str, ...], bool]:
    """(the platforms zig compiles, whether this machine's binary is compiled by the system compiler);
    checks the platforms and that the compilers are there."""
    host = host_platform()
    if sanitize:
        if platforms is not None and parse_platforms(platforms) != (host,):
            raise ValueError("a sanitizer build is this machine's binary alone (platforms='host')")
        find_c_compiler(cc)
        _platform(fmi_version)
        return (), True
    chosen = parse_platforms(platforms)
    if cc:
        if host is not None and host not in chosen:
            raise ValueError(
                f"cc compiles this machine's binary ({host}), which is not among the platforms {', '.join(chosen)}"
            )
        find_c_compiler(cc)
        _platform(fmi_version)
        if chosen == (host,):
            return (), True
        check_zig()
        return tuple(name for name in chosen if name != host), True
    check_zig()
    return chosen, False


_ARCHITECTURES = {
    "x86_64": "x86_64",
    "amd64": "x86_64",
    "aarch64": "aarch64",
    "arm64": "aarch64",
    "i386": "x86",
    "i686": "x86",
}


def _platform(fmi_version: int = 2) -> tuple[str, str]:
    """Binaries folder (FMI 2.0 ``linux64``, FMI 3.0 ``x86_64-linux``) and library suffix of this machine's
    binary compiled by the system compiler."""
    if sys.platform.startswith("linux"):
        system, suffix = "linux", ".so"
    elif sys.platform == "darwin":
        system, suffix = "darwin", ".dylib"
    else:
        raise NativeBuildError(
            f"a build with the system C compiler (cc, sanitize) needs a Unix C "
            f"compiler; {sys.platform} is not supported: export without it (zig "
            "compiles every platform's binary), or with '--backend python'"
        )
    if fmi_version == 2:
        return f"{system}{'64' if struct.calcsize('P') == 8 else '32'}", suffix
    machine = platform.machine().lower()
    if machine not in _ARCHITECTURES:
        raise NativeBuildError(
            f"FMI 3.0 has no platform tuple for the architecture {machine!r}: export with --fmi-version 2"
        )
    return f"{_ARCHITECTURES[machine]}-{system}", suffix


def _guid(model, model_identifier: str, fmi_version: int) -> str:
    """Deterministic GUID (FMI 3.0: instantiationToken): same model, C sources, identifier and
    FMI version -> same GUID."""
    text = json.dumps(model.to_dict(), sort_keys=True)
    version = "" if fmi_version == 2 else f"fmi{fmi_version}:"
    return (
        "{"
        + str(uuid.uuid5(_GUID_NAMESPACE, f"native:{version}{model_identifier}:{source_hash(fmi_version)}:{text}"))
        + "}"
    )


def build_description_xml(model_identifier: str, files: tuple[str, ...]) -> str:
    """``sources/buildDescription.xml`` of an FMI 3.0 source FMU: how to compile `files`."""
    root = ET.Element("fmiBuildDescription", {"fmiVersion": "3.0"})
    config = ET.SubElement(root, "BuildConfiguration", {"modelIdentifier": model_identifier})
    file_set = ET.SubElement(config, "SourceFileSet", {"language": "C99"})
    for name in files:
        ET.SubElement(file_set, "SourceFile", {"name": name})
    ET.SubElement(config, "Library", {"name": "m"})
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _compile(cc: str, sources: Path, c_files: tuple[str, ...], target: Path, sanitize: bool) -> None:
    flags = SANITIZE if sanitize else OPTIMIZE
    command = [
        cc,
        *flags,
        "-fPIC",
        "-shared",
        "-fvisibility=hidden",
        "-I",
        str(sources),
        *[str(sources / name) for name in c_files],
        "-o",
        str(target),
        "-lm",
    ]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise NativeBuildError(f"the C compiler failed ({' '.join(command)}):\n{result.stderr.strip()}")


def _package(
    out_path: str | os.PathLike,
    xml: str,
    files: dict[str, str],
    model_file: str,
    model_identifier: str,
    cc: str | None,
    sanitize: bool,
    resources: dict[str, str] | None = None,
    fmi_version: int = 2,
    platforms=None,
) -> str:
    """Compile the sources of `model_file` (`fitter.fmu.native_sources.source_files`, plus the generated
    `files`) for `platforms` and zip the FMU atomically."""
    zig_platforms, system = _selection(platforms, fmi_version, cc, sanitize)
    c_files = c_sources(fmi_version, model_file)
    if fmi_version == 3:
        files = {**files, "buildDescription.xml": build_description_xml(model_identifier, c_files)}
    out = Path(out_path).resolve()
    with scratch_directory("duhem_native") as tmp:
        sources = Path(tmp) / "sources"
        sources.mkdir()
        for name, path in source_files(fmi_version, model_file).items():
            shutil.copyfile(path, sources / name)
        for name, text in files.items():
            (sources / name).write_text(text, encoding="utf-8")
        built = compile_libraries(
            zig_platforms, OPTIMIZE, sources, [sources / name for name in c_files], Path(tmp) / "zig", model_identifier
        )
        folders: dict[str, list[Path]] = {}
        for name, library in built.items():
            folders.setdefault(name if fmi_version == 3 else PLATFORMS[name].fmi2, []).append(library)
        if system:
            folder, suffix = _platform(fmi_version)
            (Path(tmp) / "system").mkdir()
            library = Path(tmp) / "system" / f"{model_identifier}{suffix}"
            _compile(find_c_compiler(cc), sources, c_files, library, sanitize)
            folders.setdefault(folder, []).insert(0, library)
        order = [name if fmi_version == 3 else spec.fmi2 for name, spec in PLATFORMS.items()]
        binaries = {}
        for folder, libraries in sorted(
            folders.items(), key=lambda item: order.index(item[0]) if item[0] in order else -1
        ):
            if len(libraries) > 1:  # FMI 2.0 darwin64: one universal Mach-O
                universal = Path(tmp) / folder / libraries[0].name
                universal.parent.mkdir()
                universal.write_bytes(fat_macho([library.read_bytes() for library in libraries]))
                libraries = [universal]
            binaries[f"binaries/{folder}/{libraries[0].name}"] = libraries[0]
        with atomic_file(out) as staging, zipfile.ZipFile(staging, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("modelDescription.xml", xml)
            for name, library in binaries.items():
                zf.write(library, name)
            for path in sorted(sources.iterdir()):
                zf.write(path, f"sources/{path.name}")
            for name, text in (resources or {}).items():
                zf.writestr(f"resources/{name}", text)
    return str(out)


def build_native_fmu(
    model,
    out_path: str | os.PathLike,
    *,
    sanitize: bool = False,
    cc: str | None = None,
    model_identifier: str = MODEL_IDENTIFIER,
    fmi_version: int = 2,
    platforms: str | Iterable[str] | None = None,
    **description,
) -> str:
    """Compile `model` into a native FMI 2.0 or 3.0 Co-Simulation FMU at `out_path`; return its path.

    Parameters
    ----------
    model : RateIndependentModel or RateDependentModel
        Rate-dependent models need a `TabulatedRate` g.  Effects of
        `fitter.core.effects` are supported.
    out_path : path
        The FMU to write; written under a temporary name and renamed.
    sanitize : bool
        Build this machine's binary alone with ``-fsanitize=address,undefined``
        and the system compiler (for tests; the library then needs the
        sanitizer runtimes loaded first).
    cc : str, optional
        A system C compiler for this machine's binary (the other platforms'
        are still compiled by zig); default: zig compiles every binary.
        With `sanitize`: default ``$CC``, else cc, gcc or clang on PATH.
    model_identifier : str
        Name of the shared library.
    fmi_version : {2, 3}
        FMI 2.0 (``fmi2.c``) or FMI 3.0 (``fmi3.c``), the one framework
        ``cosimulation.c`` for either; the model file, the generated model
        data and the numbers are the same.
    platforms : str or list of str, optional
        The binaries' platforms (`fitter.fmu.toolchain.parse_platforms`: a
        comma list of ``x86_64-linux``, ``x86_64-windows``, ``x86_64-darwin``,
        ``aarch64-darwin``, or ``linux``, ``windows``, ``darwin``, ``host``,
        ``all``); default all.
    **description
        ``model_name``, ``description``, ``version``, ``author`` for the
        modelDescription (`fitter.fmu.model_description.model_description_xml`).

    Raises
    ------
    NativeBuildError
        No compiler (zig's package ``ziglang``, or the system compiler asked for) was found
        (the message names ``--backend python``), or it failed.
    TypeError
        A rate-dependent model whose g is a callable, not a `TabulatedRate`.
    ValueError
        An effect that the C model does not implement (not in `NATIVE_EFFECTS`), an
        `fmi_version` other than 2 and 3, or an unknown platform.
    """
    _check_fmi_version(fmi_version)
    _selection(platforms, fmi_version, cc, sanitize)
    check_supported(model)
    guid = _guid(model, model_identifier, fmi_version)
    header = model_data_header(model, guid)
    if fmi_version == 2:
        xml = model_description_xml(
            model,
            model_identifier=model_identifier,
            guid=guid,
            backend="native",
            source_files=c_sources(2),
            log_categories=LOG_CATEGORIES,
            **description,
        )
    else:
        xml = model_description_xml3(
            model,
            model_identifier=model_identifier,
            instantiation_token=guid,
            log_categories=LOG_CATEGORIES,
            **description,
        )
    model_json = json.dumps(model.to_dict(), indent=2)
    return _package(
        out_path,
        xml,
        {"model_data.h": header},
        MODEL_FILE,
        model_identifier,
        cc,
        sanitize,
        {"model.json": model_json},
        fmi_version,
        platforms,
    )


def build_native_compensator(
    model,
    out_path: str | os.PathLike,
    *,
    sanitize: bool = False,
    cc: str | None = None,
    model_identifier: str = "duhem_compensator",
    fmi_version: int = 2,
    platforms: str | Iterable[str] | None = None,
    **description,
) -> str:
    """Compile the feedforward compensator of `model` (the plant; it needs a finite ``input_range``) into a
    native FMI 2.0 or 3.0 Co-Simulation FMU: input y_ref, output u (``inverse_model.c``); arguments as
    `build_native_fmu`.  The numbers are those of `fitter.core.inverse.Compensator` with
    ``measurement="invert"`` (the caller has dropped measurement effects it does not want inverted)."""
    from fitter.fmu.variables import reference_start

    _check_fmi_version(fmi_version)
    _selection(platforms, fmi_version, cc, sanitize)
    check_supported(model)
    lo, hi = model.input_range if model.input_range is not None else (math.nan, math.nan)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError("the compensator needs the model's finite input_range (the inputs it searches)")
    start = reference_start(model)
    text = json.dumps(model.to_dict(), sort_keys=True)
    digest = hashlib.sha256((SOURCE_DIR / COMPENSATOR_FILE).read_bytes()).hexdigest()[:16]
    guid = (
        "{"
        + str(
            uuid.uuid5(
                _GUID_NAMESPACE,
                f"native-compensator:fmi{fmi_version}:{model_identifier}:{source_hash(fmi_version)}:{digest}:{text}",
            )
        )
        + "}"
    )
    header = compensator_data_header(model, guid, start)
    if fmi_version == 2:
        xml = model_description_xml(
            model,
            model_identifier=model_identifier,
            guid=guid,
            backend="native",
            source_files=c_sources(2, COMPENSATOR_FILE),
            log_categories=LOG_CATEGORIES,
            inverse_start=start,
            **description,
        )
    else:
        xml = model_description_xml3(
            model,
            model_identifier=model_identifier,
            instantiation_token=guid,
            log_categories=LOG_CATEGORIES,
            inverse_start=start,
            **description,
        )
    return _package(
        out_path,
        xml,
        {"model_data.h": header},
        COMPENSATOR_FILE,
        model_identifier,
        cc,
        sanitize,
        {"model.json": json.dumps(model.to_dict(), indent=2)},
        fmi_version,
        platforms,
    )


def _check_fmi_version(fmi_version: int) -> None:
    if fmi_version not in FMI_VERSIONS:
        raise ValueError(f"unknown FMI version {fmi_version!r} (expected 2 or 3)")


GAIN_IDENTIFIER = "duhem_gain"
_GAIN_DESCRIPTION = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="gain" guid="{6d1c2a0e-5b8f-4c3e-9a71-0000000000a1}"
  description="y = k u on the native framework (benchmark floor)" generationTool="semilinear-duhem"
  variableNamingConvention="structured" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="duhem_gain" needsExecutionTool="false"
    canHandleVariableCommunicationStepSize="true" canGetAndSetFMUstate="true"
    canSerializeFMUstate="true">
    <SourceFiles><File name="fmi2.c"/><File name="gain_model.c"/></SourceFiles>
  </CoSimulation>
  <ModelVariables>
    <ScalarVariable name="u" valueReference="0" causality="input" variability="continuous">
      <Real start="0.0"/></ScalarVariable>
    <ScalarVariable name="y" valueReference="1" causality="output" variability="continuous"
      initial="calculated"><Real/></ScalarVariable>
    <ScalarVariable name="k" valueReference="2" causality="parameter" variability="fixed"
      initial="exact"><Real start="2.0"/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs><Unknown index="2" dependencies="1" dependenciesKind="dependent"/></Outputs>
    <InitialUnknowns><Unknown index="2" dependencies="1 3"/></InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


_GAIN_DESCRIPTION_FMI3 = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="3.0" modelName="gain"
  instantiationToken="{6d1c2a0e-5b8f-4c3e-9a71-0000000000a1}"
  description="y = k u on the native framework (benchmark floor)" generationTool="semilinear-duhem"
  variableNamingConvention="structured">
  <CoSimulation modelIdentifier="duhem_gain" canHandleVariableCommunicationStepSize="true"
    canGetAndSetFMUState="true" canSerializeFMUState="true"/>
  <UnitDefinitions><Unit name="s"><BaseUnit s="1"/></Unit></UnitDefinitions>
  <ModelVariables>
    <Float64 name="u" valueReference="0" causality="input" variability="continuous" start="0.0"/>
    <Float64 name="y" valueReference="1" causality="output" variability="continuous"
      initial="calculated"/>
    <Float64 name="k" valueReference="2" causality="parameter" variability="fixed" initial="exact"
      start="2.0"/>
    <Float64 name="time" valueReference="3" causality="independent" variability="continuous"
      unit="s"/>
  </ModelVariables>
  <ModelStructure>
    <Output valueReference="1" dependencies="0" dependenciesKind="dependent"/>
    <InitialUnknown valueReference="1" dependencies="0 2"/>
  </ModelStructure>
</fmiModelDescription>
"""


def build_gain_fmu(
    out_path: str | os.PathLike,
    *,
    cc: str | None = None,
    fmi_version: int = 2,
    platforms: str | Iterable[str] | None = "host",
) -> str:
    """The trivial y = k u FMU on the same framework, compiled the same way (for benchmarks; by default
    for this machine only).

    Its fixed three-variable modelDescription is not a model export: it only
    gives `bench/fmu_throughput.py` the per-step floor of a native FMU of
    `fmi_version` (2 or 3).
    """
    _check_fmi_version(fmi_version)
    xml = _GAIN_DESCRIPTION if fmi_version == 2 else _GAIN_DESCRIPTION_FMI3
    return _package(
        out_path, xml, {}, GAIN_FILE, GAIN_IDENTIFIER, cc, False, fmi_version=fmi_version, platforms=platforms
    )
