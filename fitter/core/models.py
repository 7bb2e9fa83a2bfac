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

Schema: one check, `model_from_dict` (the file's keys) and the model classes'
validation (the values: a model built in Python is checked the same way).
The keys are ``schema``, ``schema_version``, ``kind`` ("ri" | "rd"),
``order`` (optional: the length of C), ``parameters`` (exactly the kind's
`PARAMS`: n x n matrices A, n-vectors B, E, C, x0, a number D; all finite),
``g`` (rate-dependent only: ``{"type": "table", "v": [...], "g": [...]}``),
``signals``, ``experiment``, ``fit_info`` (an object), ``effects`` and
``input_range``.  A missing or unknown key, or a value of another type or
shape, is a `ModelFileError` ``<file>: key '<key>': expected <type/shape>,
got <what the file has>`` (e.g. ``key 'parameters.A_plus': expected a 2x2
matrix of numbers, got a ragged list``).

This module needs only numpy: it is shipped inside the FMUs.
"""

from __future__ import annotations

import json
import os
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .effects import effects_from_list
from .errors import EffectError, ModelFileError
from .files import atomic_file
from .rates import RateFunction, TabulatedRate, as_rate

__all__ = [
    "INPUT_MARGIN",
    "ModelFileError",
    "Signal",
    "Signals",
    "Experiment",
    "RateIndependentModel",
    "RateDependentModel",
    "load_model",
    "save_model",
    "model_from_dict",
    "model_from_json",
    "SCHEMA",
    "SCHEMA_VERSION",
]

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


def _bad_entries(value: Any) -> Iterator[Any]:
    """The entries of a (nested) list, or `value` itself, that are not numbers (JSON true/false are not)."""
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "iuf":
            yield value
    elif isinstance(value, (list, tuple)):
        for item in value:
            yield from _bad_entries(item)
    elif isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        yield value


def _describe(value: Any) -> str:
    """How a message names a JSON value that is not what its key expects: its type, shape or value."""
    if isinstance(value, (list, tuple)):
        bad = next(_bad_entries(value), _NUMBERS)
        if bad is not _NUMBERS:
            return f"a list containing {_describe(bad)}"
        try:
            return _shape_words(np.shape(np.asarray(value, dtype=float)))
        except ValueError:
            return "a ragged list"
    if value is None or isinstance(value, (bool, np.bool_)):
        return json.dumps(None if value is None else bool(value))
    if isinstance(value, (int, float, np.integer, np.floating)):
        return str(value)
    if isinstance(value, np.ndarray):
        return _shape_words(value.shape)
    if isinstance(value, str):
        return f"the string {value[:40]!r}" + ("..." if len(value) > 40 else "")
    if isinstance(value, dict):
        return f"an object with keys {', '.join(repr(k) for k in value)}" if value else "an empty object"
    return type(value).__name__


def _shape_words(shape: tuple) -> str:
    if not shape:
        return "a number"
    if len(shape) == 1:
        return "an empty list" if shape[0] == 0 else f"a list of {_count(shape[0], 'number')}"
    if len(shape) == 2:
        return f"a {shape[0]}x{shape[1]} matrix"
    return f"an array of shape {shape}"


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


_NUMBERS = object()
"""Sentinel: `_bad_entries` found no entry that is not a number."""


def _key_error(key: str, expected: str, got: str) -> ModelFileError:
    """The schema's one error form: ``key '<key>': expected <type/shape>, got <what the file has>``."""
    return ModelFileError(f"key '{key}': expected {expected}, got {got}")


def _array(key: str, value: Any, expected: str) -> np.ndarray:
    """`value` as a float array of finite numbers; anything else (a string, null, an object, a ragged
    list, NaN) is a `ModelFileError` naming `key` and `expected`.  A float array (a fit's parameters) goes
    straight to the finiteness check."""
    if not (isinstance(value, np.ndarray) and value.dtype.kind == "f"):
        if next(_bad_entries(value), _NUMBERS) is not _NUMBERS:
            raise _key_error(key, expected, _describe(value))
    try:
        a = np.array(value, dtype=float)
    except ValueError:
        raise _key_error(key, expected, "a ragged list") from None
    if not np.isfinite(a).all():
        raise _key_error(key, expected, "NaN or infinity")
    return a


def _vec(name: str, value: Any, n: int) -> np.ndarray:
    """Parameter `name`: n numbers (a 1 x n or n x 1 matrix is flattened)."""
    key, expected = f"parameters.{name}", f"a list of {_count(n, 'number')}"
    a = _array(key, value, expected)
    if a.shape == (n, 1) or a.shape == (1, n):
        a = a.ravel()
    if a.shape != (n,):
        raise _key_error(key, expected, _describe(value))
    return a


def _mat(name: str, value: Any, n: int) -> np.ndarray:
    """Parameter `name`: an n x n matrix (a number when n = 1)."""
    key, expected = f"parameters.{name}", f"a {n}x{n} matrix of numbers"
    a = _array(key, value, expected)
    if a.ndim == 0 and n == 1:
        a = a.reshape(1, 1)
    if a.shape != (n, n):
        raise _key_error(key, expected, _describe(value))
    return a


def _number(key: str, value: Any) -> float:
    """One finite number at `key`."""
    a = _array(key, value, "a finite number")
    if a.ndim != 0:
        raise _key_error(key, "a finite number", _describe(value))
    return float(a)


def _order_of(C: Any) -> int:
    """The order n is the length of the output row C."""
    expected = "a non-empty list of numbers (the output row; its length is the order)"
    a = _array("parameters.C", C, expected)
    if a.size == 0:
        raise _key_error("parameters.C", expected, _describe(C))
    return a.size


def _input_range(value: Any) -> tuple[float, float]:
    """The ``input_range`` key: [lo, hi], finite, lo < hi (null, for none, is not passed here)."""
    expected = "[lo, hi] (two finite numbers, lo < hi) or null"
    a = _array("input_range", value, expected)
    if a.shape != (2,):
        raise _key_error("input_range", expected, _describe(value))
    if not a[0] < a[1]:
        raise _key_error("input_range", expected, f"[{a[0]:g}, {a[1]:g}]")
    return float(a[0]), float(a[1])


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

    @property
    def first_input(self) -> float | None:
        """The input at which the stored x0 holds (the first sample of the recording it was fitted on,
        ``fit_info["x0"]["u0"]``), None when the fit did not record it.  A simulation starts x0 at its own
        first input; an FMU or a compensator that is not told its first input starts here."""
        x0 = self.fit_info.get("x0")
        u0 = x0.get("u0") if isinstance(x0, dict) else None
        return None if u0 is None else float(u0)

    def output(self, X: np.ndarray, w) -> np.ndarray:
        """y_k = C x_k + D w_k (eqs (2), (19)) of the states X (N, n) at the model input w (`model_input`)."""
        return X @ self.C + self.D * w

    def model_input(self, u):
        """The input the model acts on: u held at the edges of `input_range` (module docstring)."""
        if self.input_range is None:
            return u
        lo, hi = self.input_range
        return np.clip(u, lo, hi) if isinstance(u, np.ndarray) else min(hi, max(lo, float(u)))

    def _check_common(self) -> None:
        """Validate the fields both kinds share: effects, input_range, fit_info."""
        try:
            self._set("effects", effects_from_list(self.effects))
        except EffectError as exc:
            raise ModelFileError(f"key 'effects': {exc}") from None
        if self.input_range is not None:
            self._set("input_range", _input_range(self.input_range))
        if not isinstance(self.fit_info, dict):
            raise _key_error("fit_info", "an object", _describe(self.fit_info))

    def replace(self, **changes) -> "_ModelBase":
        """A copy with `changes` applied, validated like a new model."""
        return dataclasses.replace(self, **changes)

    def _set(self, name: str, value) -> None:
        object.__setattr__(self, name, _frozen(value) if isinstance(value, np.ndarray) else value)

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
        n = _order_of(self.C)
        self._set("A_plus", _mat("A_plus", self.A_plus, n))
        self._set("A_minus", _mat("A_minus", self.A_minus, n))
        self._set("B_plus", _vec("B_plus", self.B_plus, n))
        self._set("B_minus", _vec("B_minus", self.B_minus, n))
        self._set("C", _vec("C", self.C, n))
        self._set("E_plus", _vec("E_plus", np.zeros(n) if self.E_plus is None else self.E_plus, n))
        self._set("E_minus", _vec("E_minus", np.zeros(n) if self.E_minus is None else self.E_minus, n))
        self._set("x0", _vec("x0", np.zeros(n) if self.x0 is None else self.x0, n))
        self._set("D", _number("parameters.D", self.D))
        self._check_common()

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
        if self.g is None:
            raise ModelFileError("key 'g' is missing (a rate-dependent model needs its rate table)")
        n = _order_of(self.C)
        self._set("A", _mat("A", self.A, n))
        self._set("B", _vec("B", self.B, n))
        self._set("C", _vec("C", self.C, n))
        self._set("E", _vec("E", np.zeros(n) if self.E is None else self.E, n))
        self._set("x0", _vec("x0", np.zeros(n) if self.x0 is None else self.x0, n))
        self._set("D", _number("parameters.D", self.D))
        self._set("g", as_rate(self.g))
        self._check_common()

    def to_dict(self) -> dict:
        d = self._common_dict()
        d["parameters"] = {k: np.asarray(getattr(self, k)).tolist() for k in self.PARAMS}
        d["g"] = self.g.to_dict()
        return self._effects_dict(d)


Model = RateIndependentModel | RateDependentModel


_COMMON_KEYS = (
    "schema",
    "schema_version",
    "kind",
    "order",
    "signals",
    "experiment",
    "fit_info",
    "parameters",
    "effects",
    "input_range",
)
"""Top-level keys of every model file; a rate-dependent one also has "g"."""


def model_from_dict(d: dict, source: str = "model") -> Model:
    """Build a model from its JSON dictionary: the schema check of every key (module docstring).

    Every problem is a `ModelFileError` ``<source>: key '<key>': expected <type/shape>, got <...>``
    (or ``<source>: not a duhem model file`` / ``unknown schema_version``).
    """
    if not isinstance(d, dict) or d.get("schema") != SCHEMA:
        raise ModelFileError(f'{source}: not a duhem model file (missing "schema": "{SCHEMA}")')
    version = d.get("schema_version")
    if version != SCHEMA_VERSION:
        raise ModelFileError(f"{source}: unknown schema_version {version!r} (this version reads {SCHEMA_VERSION})")
    try:
        return _model_of_schema(d)
    except ModelFileError as exc:
        raise ModelFileError(f"{source}: {exc}") from None


def _model_of_schema(d: dict) -> Model:
    """`model_from_dict` after the schema and version check; errors without the source."""
    kind = d.get("kind")
    cls = {"ri": RateIndependentModel, "rd": RateDependentModel}.get(kind)
    if cls is None:
        raise _key_error("kind", "'ri' or 'rd'", _describe(kind))
    known = _COMMON_KEYS + (("g",) if cls is RateDependentModel else ())
    unknown = [k for k in d if k not in known]
    if unknown:
        raise ModelFileError(f"key '{unknown[0]}': not a key of a {kind!r} model file (known: {', '.join(known)})")
    kwargs = _parameters(d.get("parameters"), cls)
    if cls is RateDependentModel:
        kwargs["g"] = _rate_from_dict(d.get("g"))
    model = cls(
        signals=_signals_from_dict(d.get("signals", {})),
        experiment=_experiment_from_dict(d.get("experiment", {})),
        fit_info=d.get("fit_info", {}),
        effects=d.get("effects", []),
        input_range=d.get("input_range"),
        **kwargs,
    )
    order = d.get("order")
    if order is not None and order != model.order:
        raise _key_error("order", f"{model.order} (the length of parameters.C)", _describe(order))
    return model


def _parameters(params: Any, cls: type) -> dict:
    """The ``parameters`` key: an object with exactly the parameters of `cls` (values checked by `cls`)."""
    names = ", ".join(cls.PARAMS)
    if not isinstance(params, dict):
        raise _key_error("parameters", f"an object with keys {names}", _describe(params))
    for name in params:
        if name not in cls.PARAMS:
            raise ModelFileError(
                f"key 'parameters.{name}': not a parameter of a {cls.kind!r} model (its parameters: {names})"
            )
    for name in cls.PARAMS:
        if name not in params:
            raise ModelFileError(f"key 'parameters.{name}' is missing (a {cls.kind!r} model has {names})")
    return dict(params)


def _rate_from_dict(g: Any) -> TabulatedRate:
    """The ``g`` key: ``{"type": "table", "v": [...], "g": [...]}`` (`TabulatedRate.to_dict`)."""
    expected = 'an object {"type": "table", "v": [slopes], "g": [values]}'
    if g is None:
        raise ModelFileError(f"key 'g' is missing (expected {expected})")
    if not isinstance(g, dict) or g.get("type") != "table" or not {"v", "g"} <= set(g):
        raise _key_error("g", expected, _describe(g))
    v, values = (_array(f"g.{k}", g[k], "a list of numbers") for k in ("v", "g"))
    try:
        return TabulatedRate(v, values)
    except ValueError as exc:
        raise ModelFileError(f"key 'g': {exc}") from None


def _signals_from_dict(sig: Any) -> Signals:
    """The ``signals`` key: {"input"|"output": {"name": str, "unit": str, "description": str}}."""
    if not isinstance(sig, dict) or set(sig) - {"input", "output"}:
        raise _key_error("signals", "an object with keys 'input' and 'output'", _describe(sig))
    out = {}
    for key, value in sig.items():
        if not isinstance(value, dict) or "name" not in value or set(value) - {"name", "unit", "description"}:
            raise _key_error(
                f"signals.{key}", "an object with keys 'name' (required), 'unit' and 'description'", _describe(value)
            )
        for name, text in value.items():
            if not isinstance(text, str):
                raise _key_error(f"signals.{key}.{name}", "a string", _describe(text))
        out[key] = Signal(**value)
    return Signals(**out)


def _experiment_from_dict(exp: Any) -> Experiment:
    """The ``experiment`` key: {"start_time", "stop_time", "step_size"}, finite numbers, start < stop, step > 0."""
    names = ("start_time", "stop_time", "step_size")
    if not isinstance(exp, dict) or set(exp) - set(names):
        raise _key_error("experiment", f"an object with keys {', '.join(names)}", _describe(exp))
    out = Experiment(**{key: _number(f"experiment.{key}", value) for key, value in exp.items()})
    if not (out.start_time < out.stop_time and out.step_size > 0):
        raise _key_error(
            "experiment",
            "start_time < stop_time and step_size > 0",
            f"{out.start_time:g}, {out.stop_time:g}, {out.step_size:g}",
        )
    return out


def model_from_json(text: str | bytes, source: str) -> Model:
    """A model from the text of a model JSON file; every problem is a `ModelFileError` naming `source`
    (invalid JSON by its line and column)."""
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelFileError(
            f"{source}: not a JSON model file (invalid JSON at line {exc.lineno}, column "
            f"{exc.colno}: {exc.msg[0].lower()}{exc.msg[1:]})"
        ) from None
    except UnicodeDecodeError:
        raise ModelFileError(f"{source}: not a JSON model file (not UTF-8 text)") from None
    return model_from_dict(d, source=source)


def load_model(path: str | os.PathLike) -> Model:
    """Read a model JSON file; every problem is a `ModelFileError` naming the file."""
    try:
        text = Path(path).read_bytes()
    except FileNotFoundError:
        raise ModelFileError(f"{path}: no such file") from None
    return model_from_json(text, source=str(path))


def save_model(model: Model, path: str | os.PathLike) -> None:
    """Write `model` as JSON atomically (`fitter.core.files.atomic_file`)."""
    text = json.dumps(model.to_dict(), indent=2)
    with atomic_file(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
