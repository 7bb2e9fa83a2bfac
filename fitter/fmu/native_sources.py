"""The C sources of a native FMU: which files it compiles and ships, and its generated ``model_data.h``.

Layout of the C (``fmu_src/native/``), after the Modelica Reference-FMUs:

* ``cosimulation.c``: the FMI framework, for FMI 2.0 and FMI 3.0: every fmi2* or fmi3* function, the state
  machine, argument checks, logging, FMU state and its serialization (shared by all models);
  ``FMI_VERSION`` selects the API;
* ``fmi2.c`` / ``fmi3.c``: two lines each, ``#define FMI_VERSION`` and ``#include "cosimulation.c"``.  An FMU
  compiles its version's one and lists it in its build description (FMI 2.0: the modelDescription's
  ``<SourceFiles>``, which cannot declare a preprocessor definition; FMI 3.0: ``sources/buildDescription.xml``),
  so an importer compiles ``sources/`` with no extra flags;
* ``duhem_model.c``: the model (exact flow, rate function, effect chain, Stepper semantics), behind the
  FMI-free hooks of ``model_interface.h``, so that both FMI versions compile the same model file;
  ``inverse_model.c`` (the compensator, which includes ``duhem_model.c``) and ``gain_model.c`` (the
  benchmark's y = k u) are the other model files;
* the standard FMI headers (``fmi2Functions.h``, ``fmi3Functions.h`` and the headers they include): those
  fmpy ships in its package (``fmpy/c-code``), not copies;
* ``model_data.h``: generated here, numbers only: kind, order, parameter start values, the value-reference
  table of `fitter.fmu.variables.model_variables` (so both backends have the same interface) with each
  parameter's allowed range, and the effect chain: the list DUHEM_EFFECTS of the effects of
  `fitter.core.effects.REGISTRY` that the C implements, whether the model has each, where its parameters
  and its state live (docs/architecture.md, "Adding an effect").  The compensator's is the plant's with
  ``COMPENSATOR_REFERENCE_START``.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import math
from pathlib import Path

import numpy as np

import fmu_src.native
from fitter.core.effects import REGISTRY, ParameterSpec
from fitter.core.rates import TabulatedRate
from fitter.fmu.toolchain import NativeBuildError
from fitter.fmu.variables import U_REF, Y_REF, model_variables, time_variable

__all__ = [
    "SOURCE_DIR",
    "MODEL_FILE",
    "COMPENSATOR_FILE",
    "GAIN_FILE",
    "NATIVE_EFFECTS",
    "c_sources",
    "fmi_headers_dir",
    "source_files",
    "source_hash",
    "check_supported",
    "model_data_header",
    "compensator_data_header",
]

SOURCE_DIR = Path(fmu_src.native.__file__).resolve().parent
MODEL_FILE = "duhem_model.c"
COMPENSATOR_FILE = "inverse_model.c"
GAIN_FILE = "gain_model.c"
_INCLUDED = ("cosimulation.c", "model_interface.h", "duhem_model.h")
_FMI_HEADERS = {
    2: ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"),
    3: ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h"),
}
NATIVE_EFFECTS = frozenset(name for name, spec in REGISTRY.items() if spec.native)
"""The effects of `fitter.core.effects.REGISTRY` that duhem_model.c implements (`EffectSpec.native`)."""


def c_sources(fmi_version: int = 2, model_file: str = MODEL_FILE) -> tuple[str, str]:
    """The C files an FMU of `fmi_version` compiles (and lists in its build description): the version's
    file, which includes the framework, and the model file."""
    return (f"fmi{fmi_version}.c", model_file)


def fmi_headers_dir() -> Path:
    """fmpy's folder of the standard FMI headers (``fmpy/c-code``), found without importing fmpy."""
    spec = importlib.util.find_spec("fmpy")
    if spec is None or spec.origin is None:
        raise NativeBuildError("the package 'fmpy' (a dependency: it ships the FMI headers) is not installed")
    return Path(spec.origin).parent / "c-code"


def source_files(fmi_version: int = 2, model_file: str = MODEL_FILE) -> dict[str, Path]:
    """Every file of the ``sources/`` of an FMU of `fmi_version` but the generated ones, name -> path: the
    C files it compiles (`c_sources`), those they include, and the FMI headers of fmpy."""
    included = _INCLUDED + ((MODEL_FILE,) if model_file == COMPENSATOR_FILE else ())  # the plant's model
    files = {name: SOURCE_DIR / name for name in c_sources(fmi_version, model_file) + included}
    return files | {name: fmi_headers_dir() / name for name in _FMI_HEADERS[fmi_version]}


def source_hash(fmi_version: int) -> str:
    """A digest of the sources of an FMU of `fmi_version` (part of its GUID)."""
    digest = hashlib.sha256()
    for path in source_files(fmi_version).values():
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


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
        entries.append(
            f"    X({name}, STAGE_{spec.stage.upper()}, {int(name in present)}, {index}, "
            f"{offset if name in present else 0})"
        )
        offset += len(spec.state) if name in present else 0
    starts = [i for name, i in real_index.items() if ".start." in name]
    if starts and (starts != list(range(starts[0], starts[0] + offset))):
        raise RuntimeError("the effects' stored start is not one block in the chain state's layout")
    return [
        f"#define DUHEM_EFFECT_STATES {offset}",
        f"#define DUHEM_EFFECT_START {starts[0] if starts else -1}",
        "#define DUHEM_EFFECTS(X)" + "".join(f" \\\n{entry}" for entry in entries),
        *(
            f"#define DUHEM_{name.upper()}_{key} {_c_constant(value)}"
            for name, spec in REGISTRY.items()
            if name in NATIVE_EFFECTS
            for key, value in spec.c_constants().items()
        ),
    ]


def _c_constant(value: int | float | tuple[float, ...]) -> str:
    """A C literal: an int as written, a float as a double, a tuple as a brace initializer of doubles."""
    return (
        "{" + ", ".join(map(_c_double, value)) + "}"
        if isinstance(value, tuple)
        else str(value)
        if isinstance(value, int)
        else _c_double(value)
    )


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
    return (
        f"{{{_c_bound(par.lower)}, {_c_bound(par.upper)}, {int(par.strict)}, "
        f"{_c_string('this parameter must be ' + par.rule())}}}"
    )


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


def check_supported(model) -> None:
    """Raise unless the C model implements `model`: a `TabulatedRate` g, and only `NATIVE_EFFECTS`."""
    if model.kind == "rd" and not isinstance(model.g, TabulatedRate):
        raise TypeError(
            "rate-dependent model: g must be a TabulatedRate for the native FMU "
            "(tabulate it with TabulatedRate.from_function)"
        )
    unknown = [e.effect for e in getattr(model, "effects", None) or [] if e.effect not in NATIVE_EFFECTS]
    if unknown:
        raise ValueError(
            f"effect {unknown[0]!r} is not supported by the native backend; export with '--backend python'"
        )


def model_data_header(model, guid: str) -> str:
    """The generated model_data.h of `model`: numbers and tables only (see duhem_model.h)."""
    check_supported(model)
    variables = model_variables(model)
    params = [v for v in variables if v.type == "Real" and v.causality == "parameter"]
    if [tuple(v.path) for v in params[: len(_base_paths(model))]] != _base_paths(model):
        raise RuntimeError("fitter.fmu.model_description parameter order differs from the C layout of duhem_model.c")
    real_index = {v.name: i for i, v in enumerate(params)}
    rows = []
    for v in variables:
        if v.value_reference == U_REF:
            rows.append((v.name, v.value_reference, "r", "VAR_INPUT", 0, "ANY_FINITE"))
        elif v.value_reference == Y_REF:
            rows.append((v.name, v.value_reference, "r", "VAR_OUTPUT", 0, "ANY_FINITE"))
        elif v.type == "Real":
            rows.append((v.name, v.value_reference, "r", "VAR_PARAMETER", real_index[v.name], _range(v.name)))
        elif v.type == "Integer":
            rows.append((v.name, v.value_reference, "i", "VAR_INTEGER", int(v.start), "ANY_FINITE"))
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
        "/* Generated by fitter.fmu.native_sources: the data of one model (no code). */",
        "#ifndef MODEL_DATA_H",
        "#define MODEL_DATA_H",
        "",
        f"#define DUHEM_GUID {_c_string(guid)}",
        "#define DUHEM_KIND " + ("DUHEM_RATE_INDEPENDENT" if model.kind == "ri" else "DUHEM_RATE_DEPENDENT"),
        f"#define DUHEM_ORDER {model.order}",
    ]
    if model.kind == "rd":
        lines.append(f"#define DUHEM_RATE_NODES {len(model.g.v)}")
    lo, hi = model.input_range if model.input_range is not None else (-math.inf, math.inf)
    lines += [
        f"#define DUHEM_INPUT_START {_c_double(u_start)}",
        f"#define DUHEM_INPUT_LO {_c_bound(lo)}",
        f"#define DUHEM_INPUT_HI {_c_bound(hi)}",
        f"#define DUHEM_N_PARAMETERS {len(params)}",
        "",
    ]
    lines += _effect_macros(model, real_index)
    lines += ["", "static const double duhem_parameters[DUHEM_N_PARAMETERS] = {"]
    lines += [f"    {_c_double(v.start)}, /* {v.name} */" for v in params]
    lines += [
        "};",
        "",
        f"#define DUHEM_N_VARIABLES {len(rows)}",
        "static const DuhemVariable duhem_variables[DUHEM_N_VARIABLES] = {",
    ]
    lines += [
        f"    {{{_c_string(name)}, {vr}, '{t}', {role}, {index}, {allowed}}},"
        for name, vr, t, role, index, allowed in rows
    ]
    lines += ["};", "", "static const char *const duhem_strings[] = {" + _c_string(strings[0]) + "};", "", "#endif", ""]
    return "\n".join(lines)


def compensator_data_header(model, guid: str, reference_start: float) -> str:
    """The generated model_data.h of the compensator of `model` (the plant): the plant's, with
    ``COMPENSATOR_REFERENCE_START``."""
    return model_data_header(model, guid).replace(
        "\n#endif\n", f"\n#define COMPENSATOR_REFERENCE_START {_c_double(reference_start)}\n\n#endif\n"
    )
