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

Layout of the C, after the Modelica Reference-FMUs:

* ``fmi2_framework.c`` / ``fmi3_framework.c``: every fmi2* / fmi3* function,
  the state machine, argument checks, logging, FMU state (shared by all
  models); ``fmi_version`` picks one;
* ``duhem_model.c``: the model (exact flow, rate function, effect chain,
  Stepper semantics), behind the FMI-free hooks of ``model_interface.h``, so
  that both frameworks compile the same model file;
* ``model_data.h``: generated here, numbers only: kind, order, parameter start
  values, the value-reference table of
  `fitter.fmu.variables.model_variables` (so both backends have the same
  interface) with each parameter's allowed range, and the effect chain: the
  list DUHEM_EFFECTS of the effects of `fitter.core.effects.REGISTRY` that the C
  implements, whether the model has each, where its parameters and its state
  live (docs/architecture.md, "Adding an effect").

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
(scaling and squaring of the kernel's degree-18 Taylor series); the rate
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

import numpy as np

import fmu_src.native
from fitter.core.effects import REGISTRY, ParameterSpec
from fitter.core.files import atomic_file, scratch_directory
from fitter.core.rates import TabulatedRate
from fitter.fmu.model_description import FMI_VERSIONS, model_description_xml, model_description_xml3
from fitter.fmu.variables import U_REF, Y_REF, model_variables, time_variable
from fitter.fmu.toolchain import (PLATFORMS, NativeBuildError, check_zig, compile_libraries, fat_macho,
                                  host_platform, parse_platforms)

__all__ = ["build_native_fmu", "build_native_compensator", "COMPENSATOR_FILE", "build_gain_fmu", "NativeBuildError",
           "find_c_compiler", "check_toolchain", "PLATFORMS", "model_data_header", "SOURCE_DIR", "C_SOURCES", "HEADERS",
           "c_sources", "headers", "MODEL_IDENTIFIER", "LOG_CATEGORIES", "NATIVE_EFFECTS"]

SOURCE_DIR = Path(fmu_src.native.__file__).resolve().parent
MODEL_HEADERS = ("model_interface.h", "duhem_model.h")
_FRAMEWORK_HEADERS = {
    2: ("fmi2_framework.h", "serial_checksum.h", "fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"),
    3: ("fmi3_framework.h", "serial_checksum.h", "fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h"),
}


def c_sources(fmi_version: int = 2, model_file: str = "duhem_model.c") -> tuple[str, str]:
    """The C files of an FMU: the framework of `fmi_version` and the model file."""
    return (f"fmi{fmi_version}_framework.c", model_file)


def headers(fmi_version: int = 2) -> tuple[str, ...]:
    """The headers an FMU of `fmi_version` ships and compiles with."""
    return _FRAMEWORK_HEADERS[fmi_version] + MODEL_HEADERS


C_SOURCES = c_sources(2)
HEADERS = headers(2)
MODEL_IDENTIFIER = "semilinear_duhem"
LOG_CATEGORIES = {
    "logStatusError": "Refused calls and failures (always reported).",
    "logStatusDiscard": "Status requests that are not available (always reported).",
    "logCalls": "Every FMI call (with debug logging on).",
}
OPTIMIZE = ("-O2", "-ffp-contract=off")
"""-ffp-contract=off: no fused multiply-adds (aarch64 compilers fuse by default), so the C flow rounds as numpy does."""
SANITIZE = ("-O1", "-g", "-fno-omit-frame-pointer", "-fsanitize=address,undefined",
            "-fno-sanitize-recover=undefined")
NATIVE_EFFECTS = frozenset(name for name, spec in REGISTRY.items() if spec.native)
"""The effects of `fitter.core.effects.REGISTRY` that duhem_model.c implements (`EffectSpec.native`)."""
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
        "Python with numpy)")


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
            raise ValueError(f"cc compiles this machine's binary ({host}), which is not among the platforms "
                             f"{', '.join(chosen)}")
        find_c_compiler(cc)
        _platform(fmi_version)
        if chosen == (host,):
            return (), True
        check_zig()
        return tuple(name for name in chosen if name != host), True
    check_zig()
    return chosen, False


_ARCHITECTURES = {"x86_64": "x86_64", "amd64": "x86_64", "aarch64": "aarch64", "arm64": "aarch64",
                  "i386": "x86", "i686": "x86"}


def _platform(fmi_version: int = 2) -> tuple[str, str]:
    """Binaries folder (FMI 2.0 ``linux64``, FMI 3.0 ``x86_64-linux``) and library suffix of this machine's
    binary compiled by the system compiler."""
    if sys.platform.startswith("linux"):
        system, suffix = "linux", ".so"
    elif sys.platform == "darwin":
        system, suffix = "darwin", ".dylib"
    else:
        raise NativeBuildError(f"a build with the system C compiler (cc, sanitize) needs a Unix C "
                               f"compiler; {sys.platform} is not supported: export without it (zig "
                               "compiles every platform's binary), or with '--backend python'")
    if fmi_version == 2:
        return f"{system}{'64' if struct.calcsize('P') == 8 else '32'}", suffix
    machine = platform.machine().lower()
    if machine not in _ARCHITECTURES:
        raise NativeBuildError(f"FMI 3.0 has no platform tuple for the architecture {machine!r}: "
                               "export with --fmi-version 2")
    return f"{_ARCHITECTURES[machine]}-{system}", suffix


def _c_double(value: float) -> str:
    return repr(float(value))


def _c_string(text: str) -> str:
    return json.dumps(text)  # a JSON string of ASCII text is a valid C string literal


def _effect_macros(model, real_index: dict) -> list[str]:
    """DUHEM_EFFECT_STATES, DUHEM_EFFECT_START (the effects' stored start, `Effect.start`) and the
    DUHEM_EFFECTS(X) list of duhem_model.h, from `REGISTRY`, and every native effect's fixed numbers
    (`EffectSpec.c_constants`, as ``DUHEM_<EFFECT>_<KEY>``).

    Every native effect appears, in chain order, as X(name, stage, present,
    index of its first parameter, offset of its state); the C reads an
    effect's parameters as one block, so they must be consecutive.
    """
    present = {e.effect for e in getattr(model, "effects", None) or []}
    entries, offset = [], 0
    for name, spec in REGISTRY.items():
        if name not in NATIVE_EFFECTS:
            continue
        index = 0
        if name in present:
            indices = [real_index[f"{name}.{par.name}"] for par in spec.parameters]
            if indices != list(range(indices[0], indices[0] + len(indices))):
                raise RuntimeError(f"effect {name!r}: parameters are not consecutive in the C layout")
            index = indices[0]
        entries.append(f"    X({name}, STAGE_{spec.stage.upper()}, {int(name in present)}, {index}, "
                       f"{offset if name in present else 0})")
        offset += len(spec.state) if name in present else 0
    starts = [i for name, i in real_index.items() if ".start." in name]
    if starts and (starts != list(range(starts[0], starts[0] + offset))):
        raise RuntimeError("the effects' stored start is not one block in the chain state's layout")
    return [f"#define DUHEM_EFFECT_STATES {offset}",
            f"#define DUHEM_EFFECT_START {starts[0] if starts else -1}",
            "#define DUHEM_EFFECTS(X)" + "".join(f" \\\n{entry}" for entry in entries),
            *(f"#define DUHEM_{name.upper()}_{key} {_c_constant(value)}" for name, spec in REGISTRY.items()
              if name in NATIVE_EFFECTS for key, value in spec.c_constants().items())]


def _c_constant(value: int | float | tuple[float, ...]) -> str:
    """A C literal: an int as written, a float as a double, a tuple as a brace initializer of doubles."""
    return "{" + ", ".join(map(_c_double, value)) + "}" if isinstance(value, tuple) else \
        str(value) if isinstance(value, int) else _c_double(value)


def _parameter_spec(name: str) -> ParameterSpec | None:
    """The `ParameterSpec` of an effect parameter variable ``<effect>.<parameter>``, else None."""
    effect, _, param = name.partition(".")
    spec = REGISTRY.get(effect)
    return next((par for par in spec.parameters if par.name == param), None) if spec else None


def _c_bound(value: float) -> str:
    return _c_double(value) if math.isfinite(value) else ("HUGE_VAL" if value > 0 else "-HUGE_VAL")


def _range(name: str) -> str:
    """The C `Range` initializer of a Real parameter: an effect parameter's allowed range."""
    par = _parameter_spec(name)
    if par is None or (par.lower == -math.inf and par.upper == math.inf):
        return "ANY_FINITE"
    return (f"{{{_c_bound(par.lower)}, {_c_bound(par.upper)}, {int(par.strict)}, "
            f"{_c_string('this parameter must be ' + par.rule())}}}")


def _base_paths(model) -> list[tuple]:
    """Paths of the base parameters in the C layout of duhem_model.c, in order."""
    paths = []
    for key in model.PARAMS:
        value = np.asarray(getattr(model, key))
        paths += [("parameters", key) + index for index in np.ndindex(*value.shape)]
    if model.kind == "rd":
        paths += [("g", "v", k) for k in range(len(model.g.v))]
        paths += [("g", "g", k) for k in range(len(model.g.g))]
    return paths


def _check_supported(model) -> None:
    if model.kind == "rd" and not isinstance(model.g, TabulatedRate):
        raise TypeError("rate-dependent model: g must be a TabulatedRate for the native FMU "
                        "(tabulate it with TabulatedRate.from_function)")
    unknown = [e.effect for e in getattr(model, "effects", None) or []
               if e.effect not in NATIVE_EFFECTS]
    if unknown:
        raise ValueError(f"effect {unknown[0]!r} is not supported by the native backend; "
                         "export with '--backend python'")


def model_data_header(model, guid: str) -> str:
    """The generated model_data.h of `model`: numbers and tables only (see duhem_model.h)."""
    _check_supported(model)
    variables = model_variables(model)
    params = [v for v in variables if v.type == "Real" and v.causality == "parameter"]
    if [tuple(v.path) for v in params[:len(_base_paths(model))]] != _base_paths(model):
        raise RuntimeError("fitter.fmu.model_description parameter order differs from the C "
                           "layout of duhem_model.c")
    real_index = {v.name: i for i, v in enumerate(params)}
    rows = []
    for v in variables:
        if v.value_reference == U_REF:
            rows.append((v.name, v.value_reference, "r", "VAR_INPUT", 0, "ANY_FINITE"))
        elif v.value_reference == Y_REF:
            rows.append((v.name, v.value_reference, "r", "VAR_OUTPUT", 0, "ANY_FINITE"))
        elif v.type == "Real":
            rows.append((v.name, v.value_reference, "r", "VAR_PARAMETER", real_index[v.name],
                         _range(v.name)))
        elif v.type == "Integer":
            rows.append((v.name, v.value_reference, "i", "VAR_INTEGER", int(v.start),
                         "ANY_FINITE"))
        elif v.type == "String":
            rows.append((v.name, v.value_reference, "s", "VAR_STRING", 0, "ANY_FINITE"))
        else:
            raise RuntimeError(f"variable {v.name}: type {v.type} has no place in the native FMU")
    time = time_variable(variables)
    rows.append((time.name, time.value_reference, "r", "VAR_TIME", 0, "ANY_FINITE"))
    strings = [v.start for v in variables if v.type == "String"]
    if len(strings) != 1:
        raise RuntimeError("the native FMU expects exactly one String variable (kind)")
    u_start = next(v.start for v in variables if v.value_reference == U_REF)
    lines = [
        "/* Generated by fitter.fmu.native: the data of one model (no code). */",
        "#ifndef MODEL_DATA_H", "#define MODEL_DATA_H", "",
        f"#define DUHEM_GUID {_c_string(guid)}",
        "#define DUHEM_KIND " + ("DUHEM_RATE_INDEPENDENT" if model.kind == "ri"
                                 else "DUHEM_RATE_DEPENDENT"),
        f"#define DUHEM_ORDER {model.order}",
    ]
    if model.kind == "rd":
        lines.append(f"#define DUHEM_RATE_NODES {len(model.g.v)}")
    lo, hi = model.input_range if model.input_range is not None else (-math.inf, math.inf)
    lines += [f"#define DUHEM_INPUT_START {_c_double(u_start)}",
              f"#define DUHEM_INPUT_LO {_c_bound(lo)}", f"#define DUHEM_INPUT_HI {_c_bound(hi)}",
              f"#define DUHEM_N_PARAMETERS {len(params)}", ""]
    lines += _effect_macros(model, real_index)
    lines += ["", "static const double duhem_parameters[DUHEM_N_PARAMETERS] = {"]
    lines += [f"    {_c_double(v.start)}, /* {v.name} */" for v in params]
    lines += ["};", "", f"#define DUHEM_N_VARIABLES {len(rows)}",
              "static const DuhemVariable duhem_variables[DUHEM_N_VARIABLES] = {"]
    lines += [f"    {{{_c_string(name)}, {vr}, '{t}', {role}, {index}, {allowed}}},"
              for name, vr, t, role, index, allowed in rows]
    lines += ["};", "", "static const char *const duhem_strings[] = {" + _c_string(strings[0])
              + "};", "", "#endif", ""]
    return "\n".join(lines)


def _source_hash(fmi_version: int) -> str:
    digest = hashlib.sha256()
    for name in c_sources(fmi_version) + headers(fmi_version):
        digest.update((SOURCE_DIR / name).read_bytes())
    return digest.hexdigest()[:16]


def _guid(model, model_identifier: str, fmi_version: int) -> str:
    """Deterministic GUID (FMI 3.0: instantiationToken): same model, C sources, identifier and
    FMI version -> same GUID."""
    text = json.dumps(model.to_dict(), sort_keys=True)
    version = "" if fmi_version == 2 else f"fmi{fmi_version}:"
    return "{" + str(uuid.uuid5(_GUID_NAMESPACE, f"native:{version}{model_identifier}:"
                                                 f"{_source_hash(fmi_version)}:{text}")) + "}"


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


def _compile(cc: str, sources: Path, c_files: tuple[str, ...], target: Path,
             sanitize: bool) -> None:
    flags = SANITIZE if sanitize else OPTIMIZE
    command = [cc, *flags, "-fPIC", "-shared", "-fvisibility=hidden", "-I", str(sources),
               *[str(sources / name) for name in c_files], "-o", str(target), "-lm"]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise NativeBuildError(f"the C compiler failed ({' '.join(command)}):\n"
                               f"{result.stderr.strip()}")


def _package(out_path: str | os.PathLike, xml: str, files: dict[str, str], c_files: tuple[str, ...],
             model_identifier: str, cc: str | None, sanitize: bool,
             resources: dict[str, str] | None = None, fmi_version: int = 2, platforms=None) -> str:
    """Compile `c_files` (of SOURCE_DIR, plus the generated `files`) for `platforms` and zip the FMU
    atomically."""
    zig_platforms, system = _selection(platforms, fmi_version, cc, sanitize)
    if fmi_version == 3:
        files = {**files, "buildDescription.xml": build_description_xml(model_identifier, c_files)}
    out = Path(out_path).resolve()
    with scratch_directory("duhem_native") as tmp:
        sources = Path(tmp) / "sources"
        sources.mkdir()
        for name in c_files + headers(fmi_version):
            shutil.copyfile(SOURCE_DIR / name, sources / name)
        for name, text in files.items():
            (sources / name).write_text(text, encoding="utf-8")
        built = compile_libraries(zig_platforms, OPTIMIZE, sources, [sources / name for name in c_files],
                                  Path(tmp) / "zig", model_identifier)
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
        for folder, libraries in sorted(folders.items(), key=lambda item: (
                order.index(item[0]) if item[0] in order else -1)):
            if len(libraries) > 1:     # FMI 2.0 darwin64: one universal Mach-O
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


def build_native_fmu(model, out_path: str | os.PathLike, *, sanitize: bool = False,
                     cc: str | None = None, model_identifier: str = MODEL_IDENTIFIER,
                     fmi_version: int = 2, platforms: str | Iterable[str] | None = None,
                     **description) -> str:
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
        FMI 2.0 (``fmi2_framework.c``) or FMI 3.0 (``fmi3_framework.c``); the
        model file, the generated model data and the numbers are the same.
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
    _check_supported(model)
    guid = _guid(model, model_identifier, fmi_version)
    header = model_data_header(model, guid)
    if fmi_version == 2:
        xml = model_description_xml(model, model_identifier=model_identifier, guid=guid,
                                    backend="native", source_files=C_SOURCES,
                                    log_categories=LOG_CATEGORIES, **description)
    else:
        xml = model_description_xml3(model, model_identifier=model_identifier,
                                     instantiation_token=guid, log_categories=LOG_CATEGORIES,
                                     **description)
    model_json = json.dumps(model.to_dict(), indent=2)
    return _package(out_path, xml, {"model_data.h": header}, c_sources(fmi_version),
                    model_identifier, cc, sanitize, {"model.json": model_json}, fmi_version, platforms)


COMPENSATOR_FILE = "inverse_model.c"


def build_native_compensator(model, out_path: str | os.PathLike, *, sanitize: bool = False,
                             cc: str | None = None, model_identifier: str = "duhem_compensator",
                             fmi_version: int = 2, platforms: str | Iterable[str] | None = None,
                             **description) -> str:
    """Compile the feedforward compensator of `model` (the plant; it needs a finite ``input_range``) into a
    native FMI 2.0 or 3.0 Co-Simulation FMU: input y_ref, output u (``inverse_model.c``); arguments as
    `build_native_fmu`.  The numbers are those of `fitter.core.inverse.Compensator` with
    ``measurement="invert"`` (the caller has dropped measurement effects it does not want inverted)."""
    from fitter.fmu.variables import reference_start

    _check_fmi_version(fmi_version)
    _selection(platforms, fmi_version, cc, sanitize)
    _check_supported(model)
    lo, hi = model.input_range if model.input_range is not None else (math.nan, math.nan)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError("the compensator needs the model's finite input_range (the inputs it searches)")
    start = reference_start(model)
    text = json.dumps(model.to_dict(), sort_keys=True)
    digest = hashlib.sha256((SOURCE_DIR / COMPENSATOR_FILE).read_bytes()).hexdigest()[:16]
    guid = "{" + str(uuid.uuid5(_GUID_NAMESPACE, f"native-compensator:fmi{fmi_version}:{model_identifier}:"
                                                 f"{_source_hash(fmi_version)}:{digest}:{text}")) + "}"
    header = model_data_header(model, guid).replace(
        "\n#endif\n", f"\n#define COMPENSATOR_REFERENCE_START {_c_double(start)}\n\n#endif\n")
    c_files = c_sources(fmi_version, COMPENSATOR_FILE)
    if fmi_version == 2:
        xml = model_description_xml(model, model_identifier=model_identifier, guid=guid, backend="native",
                                    source_files=c_files, log_categories=LOG_CATEGORIES, inverse_start=start,
                                    **description)
    else:
        xml = model_description_xml3(model, model_identifier=model_identifier, instantiation_token=guid,
                                     log_categories=LOG_CATEGORIES, inverse_start=start, **description)
    plant_source = (SOURCE_DIR / "duhem_model.c").read_text(encoding="utf-8")
    return _package(out_path, xml, {"model_data.h": header, "duhem_model.c": plant_source}, c_files,
                    model_identifier, cc, sanitize, {"model.json": json.dumps(model.to_dict(), indent=2)},
                    fmi_version, platforms)


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
    <SourceFiles><File name="fmi2_framework.c"/><File name="gain_model.c"/></SourceFiles>
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


def build_gain_fmu(out_path: str | os.PathLike, *, cc: str | None = None, fmi_version: int = 2,
                   platforms: str | Iterable[str] | None = "host") -> str:
    """The trivial y = k u FMU on the same framework, compiled the same way (for benchmarks; by default
    for this machine only).

    Its fixed three-variable modelDescription is not a model export: it only
    gives `bench/fmu_throughput.py` the per-step floor of a native FMU of
    `fmi_version` (2 or 3).
    """
    _check_fmi_version(fmi_version)
    xml = _GAIN_DESCRIPTION if fmi_version == 2 else _GAIN_DESCRIPTION_FMI3
    return _package(out_path, xml, {}, c_sources(fmi_version, "gain_model.c"), GAIN_IDENTIFIER, cc,
                    False, fmi_version=fmi_version, platforms=platforms)
