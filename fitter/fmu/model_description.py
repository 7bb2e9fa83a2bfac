"""The FMI 2.0 (and, native backend, FMI 3.0) Co-Simulation modelDescription.xml of an exported model.

One function, `model_variables`, fixes the FMU interface of a model (names,
value references, start values and where each value lives in the model's JSON
dictionary); `model_description_xml` writes the complete modelDescription from
it.  Both the pythonfmu backend (`fitter.fmu.build`) and the native C backend
use them, so the two FMUs of one model have the same interface.

The interface itself (variables, value references, start values) is `fitter.fmu.variables`.

Input semantics (the `Stepper` of `fitter.core`, written into the
modelDescription's ``description``): y = C x + D u depends directly on u; the
state moves exactly along the straight input path between the inputs of
successive communication points, so a host that sets u(t_k) and reads y(t_k)
at every sample gets the in-process simulation of the sampled input.

"""

from __future__ import annotations

import datetime
from typing import Mapping, Sequence
import importlib.metadata
from xml.etree import ElementTree as ET


from fitter.core.effects import REGISTRY
from fitter.fmu.variables import FmiVariable, interface_variables, model_effects, time_variable

__all__ = [
    "package_version",
    "model_description_xml",
    "model_description_xml3",
    "semantics_text",
    "converges",
    "capabilities",
    "LOG_CATEGORIES",
    "FMI_VERSIONS",
    "compensator_text",
]

FMI_VERSIONS = (2, 3)

LOG_CATEGORIES = {
    "logStatusWarning": "Log messages with fmi2Warning status.",
    "logStatusError": "Log messages with fmi2Error status.",
    "logStatusFatal": "Log messages with fmi2Fatal status.",
    "logAll": "Log all messages.",
}

_CAPABILITIES = {
    "canHandleVariableCommunicationStepSize": "true",
    "canInterpolateInputs": "false",
    "canBeInstantiatedOnlyOncePerProcess": "false",
    "canNotUseMemoryManagementFunctions": "true",
    "canGetAndSetFMUstate": "true",
    "canSerializeFMUstate": "true",
    "providesDirectionalDerivative": "false",
}
# A pythonfmu FMU runs inside an embedded Python interpreter: an execution tool.
_NEEDS_EXECUTION_TOOL = {"python": "true", "native": "false"}
# Input derivatives (order 1, `Stepper.set_input_derivative`): the native FMU implements
# fmi2SetRealInputDerivatives; pythonfmu's wrapper does not forward that call to the slave.
_CAN_INTERPOLATE_INPUTS = {"python": "false", "native": "true"}


def converges(model) -> bool:
    """False only when the model's fit recorded a violated convergence condition
    (``fit_info["convergence"]["satisfied"]`` is false); models without that record pass."""
    conv = model.fit_info.get("convergence") if isinstance(model.fit_info, dict) else None
    return not (isinstance(conv, dict) and conv.get("satisfied") is False)


def _model_name(model) -> str:
    """ "semilinear Duhem RI model, order 2" (+ " with rate_dependence, creep" when it has effects)."""
    names = [e.effect for e in model_effects(model)]
    return f"semilinear Duhem {model.kind.upper()} model, order {model.order}" + (
        f" with {', '.join(names)}" if names else ""
    )


_COMPENSATOR_DERIVATIVES_TEXT = {
    2: (
        "Where the FMU declares canInterpolateInputs, an input derivative dy_ref/dt (fmi2SetRealInputDerivatives, "
        "order 1) moves y_ref on to y_ref + dy_ref/dt h at each step, so a host that sets y_ref(t_k) and its "
        "slope before stepping reads, after the step, the u that reaches y_ref(t_k+1)."
    ),
    3: (
        "FMI 3.0 has no input derivatives: a host that sets y_ref(t_k), steps and reads u gets the input for "
        "the reference held over the step; set y_ref(t_k+1) before reading u(t_k+1)."
    ),
}


def _compensator_name(model) -> str:
    return f"compensator (inverse of the {_model_name(model)})"


def compensator_text(model, fmi_version: int = 2) -> str:
    """The compensator's model-level description: what it computes, its input semantics, the clamp."""
    lo, hi = model.input_range if model.input_range is not None else (float("nan"), float("nan"))
    text = (
        f"Feedforward hysteresis compensator (inverse of the {_model_name(model)}; semilinear Duhem model, "
        "Oh and Bernstein, IEEE TAC 2007). Input y_ref: the output the plant is to follow; output u: the "
        "input to apply to the plant. At each communication point t_k, u(t_k) is the input that makes the "
        "plant's output equal y_ref(t_k), with the plant's input the straight line from u(t_k-1) over "
        "[t_k-1, t_k] (the plant FMU's own input semantics): the root of the plant's exact step, found by "
        "Brent's method on the forward model itself (fitter.core.inverse.Compensator), so a plant FMU of the "
        "same model fed with u(t_k) at t_k outputs y_ref(t_k). u depends directly on y_ref; reading u does not "
        "advance the compensator, a step commits the point. "
        f"u is searched in [{lo:.6g}, {hi:.6g}] (the model's input range); where no input there reaches "
        "y_ref (beyond the reachable output, past a branch's extremum), u is the input whose output is "
        "nearest y_ref: the output is clamped to the nearest reachable value, never NaN. A NaN or infinite "
        "y_ref is refused. "
    )
    text += _COMPENSATOR_DERIVATIVES_TEXT[fmi_version]
    names = [e.effect for e in model_effects(model)]
    if names:
        text += f" The plant's effect extensions (fitter.core.effects), inverted with it: {', '.join(names)}."
    if not converges(model):
        text += " WARNING: exported with --allow-unstable: the convergence condition of the fit is violated."
    return text


_DERIVATIVES_TEXT = {
    2: (
        "Where the FMU declares canInterpolateInputs, an input derivative du/dt (fmi2SetRealInputDerivatives, "
        "order 1) moves the input on to u + du h at each step, so a host that sets u(t_k) and du/dt before "
        "stepping gets y(t_k+1) on the exact flow along u(t_k) + du (t - t_k)."
    ),
    3: (
        "FMI 3.0 has no input derivatives (the standard replaces them by Intermediate Update Mode, which "
        "this FMU does not provide): a host that sets u(t_k), steps and reads y(t_k+1) gets the output "
        "of the input held over the step."
    ),
}


def semantics_text(model, fmi_version: int = 2) -> str:
    """The model-level description: what the FMU computes and its input semantics."""
    kind = {"ri": "rate-independent, eqs (1)-(2)", "rd": "rate-dependent, eqs (18)-(19)"}[model.kind]
    text = (
        f"Semilinear Duhem hysteresis model (Oh and Bernstein, IEEE TAC 2007), {kind}, "
        f"order {model.order}. Output y = C x + D u depends directly on the input u. "
        "Between communication points the input is the straight line from the input at "
        "the previous communication point to the input set for the current one, and the "
        "state moves exactly along that path (closed-form flow, no integration error, no "
        "one-sample lag): a host that sets u(t_k) and reads y(t_k) at every sample gets "
        "the in-process simulation of the sampled input. An input that is not set again "
        "holds its value, and a held input does not move the state. Setting u before the "
        "first step does not move the state: x0 is the state at the first input. " + _DERIVATIVES_TEXT[fmi_version]
    )
    if not converges(model):
        text += (
            " WARNING: exported with --allow-unstable: the convergence condition of the fit is "
            "violated, so a wrong initial state need not die out and the output may drift or grow."
        )
    rng = model.fit_info.get("fitted_range") if isinstance(model.fit_info, dict) else None
    if isinstance(rng, dict) and rng.get("input"):
        text += (
            f" Fitted on inputs in [{rng['input'][0]:.6g}, {rng['input'][1]:.6g}]"
            + (f", |du/dt| in [{rng['rate'][0]:.4g}, {rng['rate'][1]:.4g}] (5-95 %)" if rng.get("rate") else "")
            + "."
        )
    if model.input_range is not None:
        text += (
            f" Beyond [{model.input_range[0]:.6g}, {model.input_range[1]:.6g}] the model holds its input at "
            "the nearest edge, so the output stays bounded."
        )
    elif isinstance(rng, dict) and rng.get("input"):
        text += " Outside the fitted range the model extrapolates (no input_range: unbounded)."
    names = [e.effect for e in model_effects(model)]
    if names:
        text += f" Effect extensions (fitter.core.effects): {', '.join(names)}."
        if model.kind == "ri" and any(REGISTRY[n].timed for n in names):
            text += (
                " These make the output depend on time or on the input rate, so the model is not rate "
                "independent although its base is."
            )
    elif model.kind == "ri":
        text += (
            " The model is rate independent: y at a communication point does not depend "
            "on the step sizes as long as the steps contain the input's reversals."
        )
    return text


def capabilities(backend: str) -> dict[str, str]:
    """CoSimulation capability flags of a backend (``python`` or ``native``)."""
    if backend not in _NEEDS_EXECUTION_TOOL:
        raise ValueError(f"unknown FMU backend {backend!r} (expected 'python' or 'native')")
    return {
        "needsExecutionTool": _NEEDS_EXECUTION_TOOL[backend],
        **_CAPABILITIES,
        "canInterpolateInputs": _CAN_INTERPOLATE_INPUTS[backend],
    }


def _format(value: float | int | str) -> str:
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _variable_element(parent: ET.Element, v: FmiVariable) -> None:
    attrib = {
        "name": v.name,
        "valueReference": str(v.value_reference),
        "description": v.description,
        "causality": v.causality,
        "variability": v.variability,
    }
    if v.initial is not None:
        attrib["initial"] = v.initial
    node = ET.SubElement(parent, "ScalarVariable", attrib)
    type_attrib = {}
    if v.unit:
        type_attrib["unit"] = v.unit
    if v.start is not None:
        type_attrib["start"] = _format(v.start)
    ET.SubElement(node, v.type, type_attrib)


def _model_structure(
    root: ET.Element, variables: Sequence[FmiVariable], effects: bool, out: str = "y", inp: str = "u"
) -> None:
    """y depends directly on u; at initialisation y = C x0 + D u (with effects: on all knowns).  The
    compensator: `out` = u depends on `inp` = y_ref, at initialisation on y_ref, C, D, x0."""
    index = {v.name: i + 1 for i, v in enumerate(variables)}
    structure = ET.SubElement(root, "ModelStructure")
    outputs = ET.SubElement(structure, "Outputs")
    ET.SubElement(
        outputs, "Unknown", {"index": str(index[out]), "dependencies": str(index[inp]), "dependenciesKind": "dependent"}
    )
    initial = [index[inp]] + [
        i + 1
        for i, v in enumerate(variables)
        if v.path[:2] in (("parameters", "C"), ("parameters", "D"), ("parameters", "x0"))
    ]
    unknowns = ET.SubElement(structure, "InitialUnknowns")
    attrib = {"index": str(index[out])}
    if not effects:
        attrib["dependencies"] = " ".join(map(str, initial))
    ET.SubElement(unknowns, "Unknown", attrib)


def package_version() -> str:
    """The installed version of the `semilinear-duhem` distribution ("unknown" when not installed)."""
    try:
        return importlib.metadata.version("semilinear-duhem")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


# SI units a recording may name: (factor, exponents of kg, m, s, A, K) of the SI base units.
_SI_UNITS = {
    "m": (1.0, {"m": 1}),
    "mm": (1e-3, {"m": 1}),
    "um": (1e-6, {"m": 1}),
    "nm": (1e-9, {"m": 1}),
    "s": (1.0, {"s": 1}),
    "ms": (1e-3, {"s": 1}),
    "N": (1.0, {"kg": 1, "m": 1, "s": -2}),
    "kN": (1e3, {"kg": 1, "m": 1, "s": -2}),
    "Pa": (1.0, {"kg": 1, "m": -1, "s": -2}),
    "kPa": (1e3, {"kg": 1, "m": -1, "s": -2}),
    "bar": (1e5, {"kg": 1, "m": -1, "s": -2}),
    "V": (1.0, {"kg": 1, "m": 2, "s": -3, "A": -1}),
    "kV": (1e3, {"kg": 1, "m": 2, "s": -3, "A": -1}),
    "A": (1.0, {"A": 1}),
    "mA": (1e-3, {"A": 1}),
    "T": (1.0, {"kg": 1, "s": -2, "A": -1}),
    "mT": (1e-3, {"kg": 1, "s": -2, "A": -1}),
    "A/m": (1.0, {"A": 1, "m": -1}),
    "C/m2": (1.0, {"s": 1, "A": 1, "m": -2}),
    "uC/cm2": (1e-2, {"s": 1, "A": 1, "m": -2}),
    "uC/cm^2": (1e-2, {"s": 1, "A": 1, "m": -2}),
}


def _unit_element(parent: ET.Element, unit: str) -> None:
    """<Unit name=...>, with its <BaseUnit> when the unit is one of `_SI_UNITS`."""
    element = ET.SubElement(parent, "Unit", {"name": unit})
    if unit in _SI_UNITS:
        factor, exponents = _SI_UNITS[unit]
        attrib = {k: str(v) for k, v in exponents.items()}
        if factor != 1.0:
            attrib["factor"] = repr(factor)
        ET.SubElement(element, "BaseUnit", attrib)


def _rounded(value: float) -> float:
    """A step size as a person would write it: 6 significant digits (0.0024999999999999467 -> 0.0025)."""
    return float(f"{value:.6g}")


def model_description_xml(
    model,
    *,
    model_identifier: str,
    guid: str,
    backend: str,
    model_name: str | None = None,
    description: str | None = None,
    version: str | None = None,
    author: str | None = None,
    generation_tool: str | None = None,
    generation_date: datetime.datetime | None = None,
    capability_overrides: Mapping[str, str] | None = None,
    source_files: Sequence[str] = (),
    log_categories: Mapping[str, str] = LOG_CATEGORIES,
    inverse_start: float | None = None,
) -> str:
    """The complete FMI 2.0 Co-Simulation modelDescription.xml of `model`.

    Parameters
    ----------
    model_identifier : str
        Name of the binary (``binaries/<platform>/<model_identifier>.so``).
    guid : str
        The FMU's GUID, written as given.
    backend : {"python", "native"}
        Selects the capability flags (`capabilities`); `capability_overrides`
        replaces single flags.
    model_name, description, version, author : str, optional
        Defaults: a name from kind and order, `semantics_text(model)`, the
        package version, no author.  `generation_tool` defaults to
        "semilinear-duhem <version>".
    source_files : sequence of str
        C files under ``sources/`` for a source FMU (``<SourceFiles>``).
    inverse_start : float, optional
        Write the compensator of `model` (`compensator_variables`, name and description of
        `compensator_text`) with this start value of y_ref (`reference_start`).
    """
    attrib = {
        "fmiVersion": "2.0",
        **_identity(
            model,
            model_name,
            "guid",
            guid,
            description,
            generation_tool,
            generation_date,
            inverse=inverse_start is not None,
        ),
        "numberOfEventIndicators": "0",
        **_version_author(version, author),
    }
    root = ET.Element("fmiModelDescription", attrib)
    flags = {"modelIdentifier": model_identifier, **capabilities(backend), **(capability_overrides or {})}
    cosim = ET.SubElement(root, "CoSimulation", flags)
    if source_files:
        files = ET.SubElement(cosim, "SourceFiles")
        for name in source_files:
            ET.SubElement(files, "File", {"name": name})
    variables, out, inp = interface_variables(model, inverse_start)
    _units_categories_experiment(root, model, variables, log_categories)
    model_vars = ET.SubElement(root, "ModelVariables")
    for v in variables:
        _variable_element(model_vars, v)
    _model_structure(root, variables, bool(model_effects(model)), out, inp)
    return _document(root)


def _identity(
    model,
    model_name: str | None,
    token_name: str,
    token: str,
    description: str | None,
    generation_tool: str | None,
    generation_date: datetime.datetime | None,
    fmi_version: int = 2,
    inverse: bool = False,
) -> dict:
    """modelName, the GUID (FMI 3.0: instantiationToken), description, generationTool and -date,
    variableNamingConvention: the attributes both FMI versions share, in modelDescription order."""
    stamp = generation_date or datetime.datetime.now(datetime.timezone.utc)
    name = _compensator_name(model) if inverse else _model_name(model)
    text = compensator_text(model, fmi_version) if inverse else semantics_text(model, fmi_version)
    return {
        "modelName": model_name or name,
        token_name: token,
        "description": description or text,
        "generationTool": generation_tool or f"semilinear-duhem {package_version()}",
        "generationDateAndTime": stamp.strftime("%Y-%m-%dT%H:%M:%SZ"),
        "variableNamingConvention": "structured",
    }


def _version_author(version: str | None, author: str | None) -> dict:
    return {"version": version or package_version(), **({"author": author} if author else {})}


def _units_categories_experiment(
    root: ET.Element, model, variables: Sequence[FmiVariable], log_categories: Mapping[str, str]
) -> None:
    """<UnitDefinitions>, <LogCategories> and <DefaultExperiment> (the same in FMI 2.0 and 3.0)."""
    units = sorted({v.unit for v in variables if v.unit})
    if units:
        unit_defs = ET.SubElement(root, "UnitDefinitions")
        for unit in units:
            _unit_element(unit_defs, unit)
    if log_categories:
        cats = ET.SubElement(root, "LogCategories")
        for name, text in log_categories.items():
            ET.SubElement(cats, "Category", {"name": name, "description": text})
    exp = model.experiment
    ET.SubElement(
        root,
        "DefaultExperiment",
        {
            "startTime": _format(float(exp.start_time)),
            "stopTime": _format(float(exp.stop_time)),
            "stepSize": _format(_rounded(float(exp.step_size))),
        },
    )


def _document(root: ET.Element) -> str:
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


# FMI 3.0 Co-Simulation flags of the native FMU (cosimulation.c): no event mode, early
# return, intermediate update or output derivatives.
_CAPABILITIES_FMI3 = {
    "needsExecutionTool": "false",
    "canBeInstantiatedOnlyOncePerProcess": "false",
    "canGetAndSetFMUState": "true",
    "canSerializeFMUState": "true",
    "providesDirectionalDerivatives": "false",
    "providesAdjointDerivatives": "false",
    "canHandleVariableCommunicationStepSize": "true",
    "maxOutputDerivativeOrder": "0",
    "providesIntermediateUpdate": "false",
    "mightReturnEarlyFromDoStep": "false",
    "hasEventMode": "false",
}
_FMI3_TYPES = {"Real": "Float64", "Integer": "Int32", "String": "String"}


def _variable_element3(parent: ET.Element, v: FmiVariable) -> None:
    """One FMI 3.0 variable (a constant without ``initial``: exact is implied)."""
    attrib = {
        "name": v.name,
        "valueReference": str(v.value_reference),
        "description": v.description,
        "causality": v.causality,
        "variability": v.variability,
    }
    if v.initial is not None and v.variability != "constant":
        attrib["initial"] = v.initial
    if v.unit:
        attrib["unit"] = v.unit
    if v.start is not None and v.type != "String":
        attrib["start"] = _format(v.start)
    node = ET.SubElement(parent, _FMI3_TYPES[v.type], attrib)
    if v.type == "String":
        ET.SubElement(node, "Start", {"value": str(v.start)})


def _model_structure3(
    root: ET.Element, variables: Sequence[FmiVariable], effects: bool, out: str = "y", inp: str = "u"
) -> None:
    """As `_model_structure`, with value references: y depends directly on u; at initialisation
    y = C x0 + D u (with effects: on all knowns)."""
    refs = {v.name: str(v.value_reference) for v in variables}
    structure = ET.SubElement(root, "ModelStructure")
    ET.SubElement(
        structure, "Output", {"valueReference": refs[out], "dependencies": refs[inp], "dependenciesKind": "dependent"}
    )
    attrib = {"valueReference": refs[out]}
    if not effects:
        attrib["dependencies"] = " ".join(
            [refs[inp]]
            + [
                refs[v.name]
                for v in variables
                if v.path[:2] in (("parameters", "C"), ("parameters", "D"), ("parameters", "x0"))
            ]
        )
    ET.SubElement(structure, "InitialUnknown", attrib)


def model_description_xml3(
    model,
    *,
    model_identifier: str,
    instantiation_token: str,
    model_name: str | None = None,
    description: str | None = None,
    version: str | None = None,
    author: str | None = None,
    generation_tool: str | None = None,
    generation_date: datetime.datetime | None = None,
    log_categories: Mapping[str, str] = LOG_CATEGORIES,
    inverse_start: float | None = None,
) -> str:
    """The complete FMI 3.0 Co-Simulation modelDescription.xml of `model` (native backend).

    The metadata, units, DefaultExperiment and the variables with their value
    references are those of `model_description_xml`; the arguments mean the
    same (`instantiation_token` is FMI 2.0's GUID).  A source FMU lists its C
    files in ``sources/buildDescription.xml``, not here.
    """
    attrib = {
        "fmiVersion": "3.0",
        **_identity(
            model,
            model_name,
            "instantiationToken",
            instantiation_token,
            description,
            generation_tool,
            generation_date,
            fmi_version=3,
            inverse=inverse_start is not None,
        ),
        **_version_author(version, author),
    }
    root = ET.Element("fmiModelDescription", attrib)
    ET.SubElement(root, "CoSimulation", {"modelIdentifier": model_identifier, **_CAPABILITIES_FMI3})
    variables, out, inp = interface_variables(model, inverse_start)
    variables.append(time_variable(variables))
    _units_categories_experiment(root, model, variables, log_categories)
    model_vars = ET.SubElement(root, "ModelVariables")
    for v in variables:
        _variable_element3(model_vars, v)
    _model_structure3(root, variables, bool(model_effects(model)), out, inp)
    return _document(root)
