"""The FMU interface of an exported model: its variables, value references, start values and where each
value lives in the model's JSON dictionary (`model_variables`, `compensator_variables`), shared by every
backend and FMI version (`fitter.fmu.model_description` writes them out).

Interface
---------
* ``u`` (input, Real, continuous) and ``y`` (output, Real, continuous).  The FMI
  names stay ``u`` and ``y`` so that a connection survives re-fitting on other
  data; the recording's column name, unit and description go into the
  variable's ``description`` and its ``unit`` attribute (declared in
  ``UnitDefinitions``).
* ``order`` (Integer) and ``kind`` (String, ``ri`` or ``rd``): structural,
  ``causality="local" variability="constant"`` so that no tool offers them
  for editing; an FMU accepts only its own value for them.
* The model matrices as structured names with 1-based indices, e.g.
  ``A_plus[1,2]``, ``B_plus[1]``, ``D``, the start state ``x0[i]``, and for a
  rate-dependent model the rate table ``g_v[k]``, ``g_g[k]``.  They are
  ``causality="parameter"`` with ``variability="fixed"``: they may be set after
  instantiation and in initialization mode, and the FMU rejects them later.
  Fixed rather than tunable, because the exact flows (eigendecompositions) are
  built once from the parameters when initialization ends, and a hysteresis
  model whose matrices jump mid-simulation has no meaning for the fitted data.
* The parameters of the model's effect extensions (`fitter.core.effects`) as
  ``<effect>.<parameter>``, e.g. ``creep.tau``, also fixed; when the effects
  carry a stored start (`Effect.start`), their states at the start time as
  ``<effect>.start.<state>``, fixed, the effects' counterpart of x0.

The compensator (``duhem export --inverse``, `fitter.core.inverse.Compensator`)
has the same variables with the signals turned round (`compensator_variables`):
``u`` (value reference 0) is its output, the input to apply to the plant, and
``y_ref`` (value reference 1, the model's output name and unit) its input; the
plant's parameters stay parameters.  Both writers take ``inverse_start`` (the
start value of y_ref, `reference_start`) to write the compensator.

FMI 3.0 (`model_description_xml3`) declares the same variables with the same
value references, as ``Float64``/``Int32``/``String``, and the
independent variable ``time`` that FMI 3.0 requires follows the last
parameter (`time_variable`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from fitter.core.effects import REGISTRY
from fitter.core.rates import TabulatedRate

__all__ = [
    "FmiVariable",
    "model_variables",
    "compensator_variables",
    "time_variable",
    "start_state_values",
    "reference_start",
    "model_effects",
    "interface_variables",
    "U_REF",
    "Y_REF",
]

U_REF = 0
Y_REF = 1

_PARAM_TEXT = {
    "A_plus": "A+ (rising input), eq (1)",
    "A_minus": "A- (falling input), eq (1)",
    "B_plus": "B+ (rising input), eq (1)",
    "B_minus": "B- (falling input), eq (1)",
    "E_plus": "E+ affine term (rising input)",
    "E_minus": "E- affine term (falling input)",
    "A": "A, eq (18)",
    "B": "B, eq (18)",
    "E": "E affine term of eq (18)",
    "C": "output row C, eq (2)",
    "D": "feedthrough D of y = C x + D u",
    "x0": "start state x(0)",
}


@dataclass(frozen=True)
class FmiVariable:
    """One scalar variable of the FMU.

    ``path`` locates its value in the model's JSON dictionary
    (`model.to_dict()`): e.g. ``("parameters", "A_plus", 0, 1)`` for
    ``A_plus[1,2]`` or ``("g", "v", 3)`` for ``g_v[4]``; it is empty for ``u``
    and ``y``.
    """

    name: str
    value_reference: int
    type: str
    causality: str
    variability: str
    start: float | int | str | None
    description: str
    path: tuple = ()
    unit: str = ""
    initial: str | None = None

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "valueReference": self.value_reference,
            "type": self.type,
            "causality": self.causality,
            "path": list(self.path),
            "start": self.start,
        }


def _signal_text(role: str, signal) -> str:
    text = f"{role} (recording column '{signal.name}'"
    text += f", unit {signal.unit})" if signal.unit else ")"
    return f"{text}: {signal.description}" if signal.description else text


def _parameter(name: str, vr: int, path: tuple, value: Any, text: str) -> FmiVariable:
    return FmiVariable(
        name=name,
        value_reference=vr,
        type="Real",
        causality="parameter",
        variability="fixed",
        start=float(value),
        description=text,
        path=path,
        initial="exact",
    )


def _array_parameters(key: str, value: np.ndarray, path: tuple, vr: int, text: str) -> list:
    out = []
    for index in np.ndindex(*value.shape):
        label = f"{key}[{','.join(str(i + 1) for i in index)}]" if value.ndim else key
        out.append(_parameter(label, vr + len(out), path + index, value[index], text))
    return out


def model_effects(model) -> list:
    """The model's effects (`fitter.core.effects.Effect`), an empty list when it has none."""
    return list(getattr(model, "effects", None) or [])


def model_variables(model) -> list[FmiVariable]:
    """The FMU's variables in modelDescription order; value references 0, 1, 2, ...

    u = 0, y = 1, order = 2, kind = 3, then the real parameters in the order of
    `model.PARAMS` (row-major for matrices) and, for a rate-dependent model,
    ``g_v[k]`` and ``g_g[k]``, then the effects' parameters (in the model's
    order) and their stored start (in chain order, the layout of
    `EffectState`).  A rate-dependent model's g must be a
    `TabulatedRate` (a callable g has no parameters to export).
    """
    if model.kind == "rd" and not isinstance(model.g, TabulatedRate):
        raise TypeError(
            "rate-dependent model: g must be a TabulatedRate to be exported "
            "(tabulate it with TabulatedRate.from_function)"
        )
    sig = model.signals
    variables = [
        FmiVariable(
            "u",
            U_REF,
            "Real",
            "input",
            "continuous",
            model.first_input or 0.0,
            _signal_text("hysteresis input", sig.input),
            unit=sig.input.unit,
        ),
        FmiVariable(
            "y",
            Y_REF,
            "Real",
            "output",
            "continuous",
            None,
            _signal_text("hysteresis output y = C x + D u", sig.output),
            unit=sig.output.unit,
            initial="calculated",
        ),
        FmiVariable(
            "order",
            2,
            "Integer",
            "local",
            "constant",
            model.order,
            "model order n (length of the state x); structural, cannot be changed",
            path=("order",),
            initial="exact",
        ),
        FmiVariable(
            "kind",
            3,
            "String",
            "local",
            "constant",
            model.kind,
            "model kind: ri = rate-independent, eqs (1)-(2); rd = rate-dependent, "
            "eqs (18)-(19); structural, cannot be changed",
            path=("kind",),
            initial="exact",
        ),
    ]
    for key in model.PARAMS:
        value = np.asarray(getattr(model, key), dtype=float)
        variables += _array_parameters(key, value, ("parameters", key), len(variables), _PARAM_TEXT[key])
    if model.kind == "rd":
        variables += _array_parameters(
            "g_v", model.g.v, ("g", "v"), len(variables), "rate table: input slope du/dt of node k (g(0) = 0 implied)"
        )
        variables += _array_parameters(
            "g_g",
            model.g.g,
            ("g", "g"),
            len(variables),
            "rate table: g(du/dt) at node k; PCHIP between nodes, constant beyond the outermost nodes",
        )
    for i, effect in enumerate(model_effects(model)):
        for name, value in effect.parameters.items():
            variables.append(
                _parameter(
                    f"{effect.effect}.{name}",
                    len(variables),
                    ("effects", i, "parameters", name),
                    value,
                    f"effect '{effect.effect}': parameter {name} (fitter.core.effects)",
                )
            )
    chain = list(REGISTRY)
    for i, effect in sorted(enumerate(model_effects(model)), key=lambda item: chain.index(item[1].effect)):
        for name, value in (effect.start or {}).items():
            variables.append(
                _parameter(
                    f"{effect.effect}.start.{name}",
                    len(variables),
                    ("effects", i, "start", name),
                    value,
                    f"effect '{effect.effect}': its state {name} at the start time "
                    "(the stored start, fitter.core.effects)",
                )
            )
    return variables


def start_state_values(model) -> dict[str, float]:
    """The FMU's start-state parameters at `model`'s start: {variable name: value} of its x0 and of its effects'
    stored start (`model_variables`), for an FMU of a model that differs from `model` only there (and stores
    an effect start when `model` does)."""
    return {
        v.name: float(_at(model, v.path))
        for v in model_variables(model)
        if v.path[:2] == ("parameters", "x0") or v.path[2:3] == ("start",)
    }


def _at(model, path: tuple):
    """The value of `model` at a variable's path."""
    if path[0] == "parameters":
        return np.asarray(getattr(model, path[1]), dtype=float)[path[2:]]
    effect = model.effects[path[1]]
    return getattr(effect, path[2])[path[3]]


def reference_start(model) -> float:
    """The start value of the compensator's y_ref: the plant's output at its first sample with the compensator's
    default u0 (the model's `first_input`, else the middle of the search range), so that an unset reference
    keeps u there."""
    from fitter.core.inverse import Compensator
    from fitter.core.stepper import Stepper

    comp = Compensator(model, measurement="invert")
    return float(Stepper(comp.plant, 0.0, comp.u).output())


def compensator_variables(model, y_ref_start: float) -> list[FmiVariable]:
    """`model_variables` of the compensator of `model`: u (vr 0) an output, y_ref (vr 1) the input."""
    sig = model.signals
    variables = model_variables(model)
    variables[0] = FmiVariable(
        "u",
        U_REF,
        "Real",
        "output",
        "continuous",
        None,
        _signal_text("compensator output: the input to apply to the plant", sig.input),
        unit=sig.input.unit,
        initial="calculated",
    )
    variables[1] = FmiVariable(
        "y_ref",
        Y_REF,
        "Real",
        "input",
        "continuous",
        float(y_ref_start),
        _signal_text("reference: the output the plant is to follow", sig.output),
        unit=sig.output.unit,
    )
    return variables


def interface_variables(model, inverse_start: float | None) -> tuple[list[FmiVariable], str, str]:
    """(variables, output name, input name) of the forward FMU or (inverse_start given) of the compensator."""
    if inverse_start is None:
        return model_variables(model), "y", "u"
    return compensator_variables(model, inverse_start), "u", "y_ref"


def time_variable(variables: Sequence[FmiVariable]) -> FmiVariable:
    """The independent variable ``time`` of an FMI 3.0 FMU: value reference after `variables`."""
    return FmiVariable("time", len(variables), "Real", "independent", "continuous", None, "simulation time", unit="s")
