"""Semilinear Duhem model objects and their versioned JSON form.

Two kinds, after Oh & Bernstein (2007):

* `RateIndependentModel`, eqs (1)-(2)::

      dx/dt = du+/dt (A+ x + B+ u + E+) + du-/dt (A- x + B- u + E-)
      y     = C x + D u,            x(0) = x0

  with du+/dt = max(0, du/dt) and du-/dt = min(0, du/dt).

* `RateDependentModel`, eqs (18)-(19), with an affine term E and a feedthrough
  D added (both zero in the paper)::

      dx/dt = g(du/dt) (A x + B u + E)
      y     = C x + D u,            x(0) = x0

Extrapolation rule (``input_range``, JSON ``"input_range": [lo, hi]``, absent
or null = none): the model is only trusted on the input range it was fitted
on.  Outside [lo, hi] the whole model (state, feedthrough, effects) sees the
input held at the nearest edge, w = min(hi, max(lo, u)); so beyond the range
the state stops moving (du = 0 there; for the rate-dependent model g(0) = 0)
and the output stays at its value at the edge.  Whatever the branch matrices,
the output is then bounded by what the model produces inside its range.  The
fit stores the fitted input range widened by `INPUT_MARGIN` of its span on
each side (`fitter.identification.exported.input_range`).

`Signals` and `Experiment` carry what an FMU needs to describe itself (names,
units, the default experiment of the data it was fitted on).  `fit_info` is a
free-form record of how the model was identified.  `effects` (optional, JSON
``"effects": [{"effect": name, "parameters": {...}}]``, absent when empty) are
the extensions of `fitter.core.effects`.

This module needs only numpy: it is shipped inside the FMUs.
"""
from __future__ import annotations

import json
import math
import os
import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .effects import effects_from_list
from .errors import EffectError, ModelFileError
from .files import atomic_file
from .rates import RateFunction, as_rate, rate_from_dict

__all__ = ["INPUT_MARGIN", "ModelFileError", "Signal", "Signals", "Experiment", "RateIndependentModel",
           "RateDependentModel", "load_model", "save_model", "model_from_dict", "SCHEMA", "SCHEMA_VERSION"]

SCHEMA = "duhem-model"
SCHEMA_VERSION = 1

INPUT_MARGIN = 0.05
"""Share of the fitted input span added on each side of the stored `input_range` (module docstring)."""




@dataclass
class Signal:
    """Name, unit and description of the input or output."""

    name: str
    unit: str = ""
    description: str = ""


@dataclass
class Signals:
    input: Signal = field(default_factory=lambda: Signal("u", "", "hysteresis input"))
    output: Signal = field(default_factory=lambda: Signal("y", "", "hysteresis output"))


@dataclass
class Experiment:
    """Default experiment: the span and sample period of the fitted data."""

    start_time: float = 0.0
    stop_time: float = 1.0
    step_size: float = 1e-2


def _vec(name: str, value: Any, n: int) -> np.ndarray:
    a = np.array(value, dtype=float)
    if a.shape == (n, 1) or a.shape == (1, n):
        a = a.ravel()
    if a.shape != (n,):
        raise ModelFileError(f"parameter {name}: expected shape ({n},), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ModelFileError(f"parameter {name}: contains NaN or infinity")
    return a


def _mat(name: str, value: Any, n: int) -> np.ndarray:
    a = np.array(value, dtype=float)
    if a.ndim == 0 and n == 1:
        a = a.reshape(1, 1)
    if a.shape != (n, n):
        raise ModelFileError(f"parameter {name}: expected shape ({n}, {n}), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ModelFileError(f"parameter {name}: contains NaN or infinity")
    return a


def _order_of(C: Any) -> int:
    """The order n is the length of the output row C."""
    return int(np.asarray(C, dtype=float).size)


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class _ModelBase:
    """Fields shared by both kinds.

    Models are immutable once validated: `__post_init__` checks and normalises
    every field (shapes, finiteness, effects) and the arrays are made
    read-only; `replace(**changes)` returns a validated copy.
    """

    signals: Signals = field(default_factory=Signals)
    experiment: Experiment = field(default_factory=Experiment)
    fit_info: dict = field(default_factory=dict)
    input_range: tuple[float, float] | None = None

    @property
    def order(self) -> int:
        return self.C.shape[0]

    def model_input(self, u):
        """The input the model acts on: u held at the edges of `input_range` (module docstring)."""
        if self.input_range is None:
            return u
        lo, hi = self.input_range
        return np.clip(u, lo, hi) if isinstance(u, np.ndarray) else min(hi, max(lo, float(u)))

    def _check_input_range(self) -> None:
        rng = self.input_range
        if rng is None:
            return
        try:
            lo, hi = (float(v) for v in rng)
        except (TypeError, ValueError):
            raise ModelFileError(f"'input_range' must be [lo, hi] (two numbers) or null, got {rng!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ModelFileError(f"'input_range' [{lo}, {hi}] must be finite with lo < hi")
        self._set("input_range", (lo, hi))

    def replace(self, **changes) -> "_ModelBase":
        """A copy with `changes` applied, validated like a new model."""
        return dataclasses.replace(self, **changes)

    def _set(self, name: str, value) -> None:
        object.__setattr__(self, name, _frozen(value) if isinstance(value, np.ndarray) else value)

    def _check_effects(self) -> None:
        try:
            self._set("effects", effects_from_list(self.effects))
        except EffectError as exc:
            raise ModelFileError(str(exc)) from None

    def _effects_dict(self, d: dict) -> dict:
        if self.input_range is not None:
            d["input_range"] = list(self.input_range)
        if self.effects:
            d["effects"] = [e.to_dict() for e in self.effects]
        return d

    def _common_dict(self) -> dict:
        return {
            "schema": SCHEMA,
            "schema_version": SCHEMA_VERSION,
            "kind": self.kind,
            "order": self.order,
            "signals": {k: vars(getattr(self.signals, k)) for k in ("input", "output")},
            "experiment": vars(self.experiment),
            "fit_info": self.fit_info,
        }


@dataclass(frozen=True)
class RateIndependentModel(_ModelBase):
    """Rate-independent semilinear Duhem model, eqs (1)-(2).

    Vectors may be given as lists; `E_plus`, `E_minus`, `D`, `x0` default to zero.
    """

    A_plus: np.ndarray = None
    A_minus: np.ndarray = None
    B_plus: np.ndarray = None
    B_minus: np.ndarray = None
    C: np.ndarray = None
    E_plus: np.ndarray | None = None
    E_minus: np.ndarray | None = None
    D: float = 0.0
    x0: np.ndarray | None = None
    effects: list = field(default_factory=list)

    kind = "ri"
    PARAMS = ("A_plus", "A_minus", "B_plus", "B_minus", "E_plus", "E_minus", "C", "D", "x0")

    def __post_init__(self):
        if self.A_plus is None or self.A_minus is None or self.B_plus is None \
                or self.B_minus is None or self.C is None:
            raise ModelFileError("rate-independent model needs A_plus, A_minus, B_plus, B_minus, C")
        n = _order_of(self.C)
        self._set("A_plus", _mat("A_plus", self.A_plus, n))
        self._set("A_minus", _mat("A_minus", self.A_minus, n))
        self._set("B_plus", _vec("B_plus", self.B_plus, n))
        self._set("B_minus", _vec("B_minus", self.B_minus, n))
        self._set("C", _vec("C", self.C, n))
        self._set("E_plus", _vec("E_plus", np.zeros(n) if self.E_plus is None else self.E_plus, n))
        self._set("E_minus", _vec("E_minus", np.zeros(n) if self.E_minus is None else self.E_minus, n))
        self._set("x0", _vec("x0", np.zeros(n) if self.x0 is None else self.x0, n))
        self._set("D", float(self.D))
        if not np.isfinite(self.D):
            raise ModelFileError("parameter D: NaN or infinity")
        self._check_effects()
        self._check_input_range()

    def to_dict(self) -> dict:
        d = self._common_dict()
        d["parameters"] = {k: np.asarray(getattr(self, k)).tolist() for k in self.PARAMS}
        return self._effects_dict(d)


@dataclass(frozen=True)
class RateDependentModel(_ModelBase):
    """Rate-dependent semilinear Duhem model, eqs (18)-(19) (plus E and D).

    `g` is a `RateFunction` (e.g. `TabulatedRate`) or any callable v -> g(v).
    """

    A: np.ndarray = None
    B: np.ndarray = None
    C: np.ndarray = None
    g: RateFunction = None
    E: np.ndarray | None = None
    D: float = 0.0
    x0: np.ndarray | None = None
    effects: list = field(default_factory=list)

    kind = "rd"
    PARAMS = ("A", "B", "E", "C", "D", "x0")

    def __post_init__(self):
        if self.A is None or self.B is None or self.C is None or self.g is None:
            raise ModelFileError("rate-dependent model needs A, B, C and g")
        n = _order_of(self.C)
        self._set("A", _mat("A", self.A, n))
        self._set("B", _vec("B", self.B, n))
        self._set("C", _vec("C", self.C, n))
        self._set("E", _vec("E", np.zeros(n) if self.E is None else self.E, n))
        self._set("x0", _vec("x0", np.zeros(n) if self.x0 is None else self.x0, n))
        self._set("D", float(self.D))
        self._set("g", as_rate(self.g))
        self._check_effects()
        self._check_input_range()

    def to_dict(self) -> dict:
        d = self._common_dict()
        d["parameters"] = {k: np.asarray(getattr(self, k)).tolist() for k in self.PARAMS}
        d["g"] = self.g.to_dict()
        return self._effects_dict(d)


Model = RateIndependentModel | RateDependentModel


def model_from_dict(d: dict, source: str = "model") -> Model:
    """Build a model from its JSON dictionary, checking schema, version, fields, shapes."""
    if not isinstance(d, dict) or d.get("schema") != SCHEMA:
        raise ModelFileError(f"{source}: not a duhem model file (missing \"schema\": \"{SCHEMA}\")")
    version = d.get("schema_version")
    if version != SCHEMA_VERSION:
        raise ModelFileError(f"{source}: unknown schema_version {version!r} "
                             f"(this version reads {SCHEMA_VERSION})")
    kind = d.get("kind")
    cls = {"ri": RateIndependentModel, "rd": RateDependentModel}.get(kind)
    if cls is None:
        raise ModelFileError(f"{source}: unknown model kind {kind!r} (expected 'ri' or 'rd')")
    params = d.get("parameters")
    if not isinstance(params, dict):
        raise ModelFileError(f"{source}: missing field 'parameters'")
    for name in cls.PARAMS:
        if name not in params:
            raise ModelFileError(f"{source}: missing parameter '{name}'")
    kwargs = {k: params[k] for k in cls.PARAMS}
    if cls is RateDependentModel:
        if "g" not in d:
            raise ModelFileError(f"{source}: missing field 'g'")
        try:
            kwargs["g"] = rate_from_dict(d["g"])
        except ValueError as exc:
            raise ModelFileError(f"{source}: {exc}") from None
    signals = _signals_from_dict(d.get("signals", {}), source)
    experiment = _experiment_from_dict(d.get("experiment", {}), source)
    try:
        model = cls(signals=signals, experiment=experiment, fit_info=d.get("fit_info", {}),
                    effects=d.get("effects", []), input_range=d.get("input_range"), **kwargs)
    except ModelFileError as exc:
        raise ModelFileError(f"{source}: {exc}") from None
    order = d.get("order")
    if order is not None and order != model.order:
        raise ModelFileError(f"{source}: 'order' is {order} but the matrices have order {model.order}")
    return model


def _signals_from_dict(sig: Any, source: str) -> Signals:
    """The ``signals`` key: {"input"|"output": {"name": str, "unit": str, "description": str}}."""
    if not isinstance(sig, dict) or set(sig) - {"input", "output"}:
        raise ModelFileError(f"{source}: 'signals' must be an object with keys 'input' and 'output', got {sig!r}")
    out = {}
    for key, value in sig.items():
        if not isinstance(value, dict) or "name" not in value or set(value) - {"name", "unit", "description"} \
                or not all(isinstance(v, str) for v in value.values()):
            raise ModelFileError(f"{source}: 'signals.{key}' must be an object of strings 'name' (required), 'unit' "
                                 f"and 'description', got {value!r}")
        out[key] = Signal(**value)
    return Signals(**out)


def _experiment_from_dict(exp: Any, source: str) -> Experiment:
    """The ``experiment`` key: {"start_time", "stop_time", "step_size"}, finite numbers, start < stop, step > 0."""
    names = ("start_time", "stop_time", "step_size")
    if not isinstance(exp, dict) or set(exp) - set(names):
        raise ModelFileError(f"{source}: 'experiment' must be an object with keys {', '.join(names)}, got {exp!r}")
    values = {}
    for key, value in exp.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ModelFileError(f"{source}: 'experiment.{key}' must be a finite number, got {value!r}")
        values[key] = float(value)
    out = Experiment(**values)
    if not (out.start_time < out.stop_time and out.step_size > 0):
        raise ModelFileError(f"{source}: 'experiment' needs start_time < stop_time and step_size > 0, got "
                             f"{out.start_time}, {out.stop_time}, {out.step_size}")
    return out


def load_model(path: str | os.PathLike) -> Model:
    """Read a model JSON file; every problem is a `ModelFileError` naming the file."""
    try:
        with open(path, encoding="utf-8") as fh:
            d = json.load(fh)
    except FileNotFoundError:
        raise ModelFileError(f"{path}: no such file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ModelFileError(f"{path}: not a JSON model file ({exc})") from None
    return model_from_dict(d, source=str(path))


def save_model(model: Model, path: str | os.PathLike) -> None:
    """Write `model` as JSON atomically (`fitter.core.files.atomic_file`)."""
    text = json.dumps(model.to_dict(), indent=2)
    with atomic_file(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
