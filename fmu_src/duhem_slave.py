"""pythonfmu slave of an exported semilinear Duhem model (FMI 2.0 Co-Simulation).

Runs inside the FMU, with only the FMU's ``resources/`` directory on
``sys.path`` (pythonfmu puts it there): it reads ``duhem_fmu.json`` (written by
`build_fmu`: the name of the kernel package copied from ``fitter/core``, the
model file, the variable table of `fitter.fmu.variables.model_variables`)
and the model JSON, and steps the model with the kernel's ``Stepper``.  The
slave holds no physics of its own.

Semantics are the Stepper's (see ``fitter/core/stepper.py`` and the
modelDescription's ``description``): y = C x + D u is read at the current
communication point with the state moved along the straight input path from
the previous one; ``do_step`` commits that point.

FMI behaviour
-------------
* Parameters (variability ``fixed``) may be set after instantiation and in
  initialization mode; the model is rebuilt (and checked) from them on the next
  read of ``y`` or when initialization ends.  Setting one later, or setting
  ``order``/``kind`` to another value, is refused.
* ``fmi2GetFMUstate`` captures parameters, phase and the Stepper state; states
  serialize as JSON (floats round-trip exactly) behind a SHA-256 of the JSON
  and the identity of the model: fmi2SetFMUstate refuses a corrupted or foreign one.
* ``do_step`` must start where the FMU is (``currentCommunicationPoint`` equal
  to the end of the last step, up to rounding); roll back with
  ``fmi2SetFMUstate`` to step from elsewhere.

Defences (as the native FMU's, ``fmu_src/native``)
--------------------------------------------------
* The call sequence of FMI 2.0 Co-Simulation: a call outside the states that
  allow it (``fmi2GetReal`` before ``fmi2EnterInitializationMode``,
  ``fmi2SetReal`` after ``fmi2Terminate``, ...) is refused, "illegal call
  sequence".
* A NaN or infinite input or parameter, an effect parameter outside its range
  (``fitter.core.effects``), an unknown value reference, an output set, a
  fixed parameter set while stepping, a structural constant changed: refused
  when set, with nothing changed (a call setting several values checks all of
  them first).
* The model is checked where it is used (``fitter.core.checks``, the kernel's
  copy): at instantiation (a warning in the log) and before it runs
  (``fmi2ExitInitializationMode``, the first read of ``y``; refused), from the
  parameters themselves: every stored number finite and within 1e100 in
  magnitude (never waived), and the convergence condition, waived only for a
  model exported past it: one whose ``fit_info.convergence.satisfied`` is false
  (what ``duhem export --allow-unstable`` records), or one that records no
  verdict and already violated the condition when it was exported
  (`fitter.fmu.build.build_fmu` called on a model without that record checks
  nothing; the FMU cannot tell it from a deliberate export).  A model that
  passed when exported is refused once its parameters break the condition.
* No non-finite value is returned as a result: an output (or state) that is
  not finite after an input change is refused on read, and a step from it is
  refused with the state unchanged.
* How a refusal reaches the host.  The slave logs the reason (status error,
  category ``logStatusError``), then:

  - ``fmi2DoStep`` returns fmi2Discard (``do_step`` returns False: pythonfmu's
    one non-fatal failure status), the state unchanged;
  - every other call raises `FmiRefusal`, which pythonfmu 0.7 (its binary
    ``libpythonfmu-export``) turns into **fmi2Fatal**: its C++ wrapper has no
    way for Python to return fmi2Error.  Its exception path
    (``handle_py_exception``) also releases one reference to the slave
    instance, its log queue and the slave class while keeping the pointers,
    so the next call used to run on freed memory (a segfault on the
    ``fmi2Terminate`` or ``fmi2GetReal`` after a NaN input).  `_survive` takes
    one reference to each of the three first, so the refused call changes
    nothing and the instance stays usable: later calls, ``fmi2Reset`` and
    ``fmi2FreeInstance`` work, and the objects are freed when pythonfmu drops
    its last reference.  (FMI 2.0 lets a host make no call after fmi2Fatal;
    one that does is safe.)

  pythonfmu passes log messages to the host only with logging on
  (``loggingOn`` of ``fmi2Instantiate``).  Out of the slave's reach, in
  pythonfmu's binary: NULL arguments (a NULL value-reference array, a NULL
  FMU state) are dereferenced; ``fmi2GetRealStatus(fmi2LastSuccessfulTime)``
  returns NaN with fmi2OK before the first step; ``fmi2DeSerializeFMUstate``
  cannot fail without the same unbalanced release (for an instance the slave
  cannot identify), so corrupt bytes give a state that ``fmi2SetFMUstate``
  refuses.

The compensator (``duhem export --inverse``)
-------------------------------------------
With ``"inverse": true`` in ``duhem_fmu.json`` the slave runs the kernel's
``Compensator`` (``fitter/core/inverse.py``) on the model instead: ``y_ref``
(value reference 1) is the input, ``u`` (value reference 0) the output.  The
same communication-point semantics (`_Inverse`): reading u solves the current
point from the last committed one without committing it (so y_ref may be set
again and u re-read), ``do_step`` commits it.  A NaN or infinite y_ref is
refused (as any refused set, above); the FMU state holds the compensator's
whole state, so a rollback replays the same u.

The class statement must stay literally ``class DuhemSlave(Fmi2Slave):``:
pythonfmu's binary finds the slave class with that regular expression.
"""

from __future__ import annotations

import copy
import ctypes
import functools
import hashlib
import importlib
import json
import math
import os

import numpy as np
from pythonfmu import Fmi2Slave
from pythonfmu.enums import Fmi2Status

CONFIG_FILE = "duhem_fmu.json"
_U, _Y = 0, 1
_VALUE_KEYS = ("parameters", "g", "effects")
_INSTANTIATED, _INITIALIZATION, _STEPPING, _TERMINATED = "instantiated", "initialization", "stepping", "terminated"
_STATE_NAMES = {
    _INSTANTIATED: "Instantiated",
    _INITIALIZATION: "InitializationMode",
    _STEPPING: "StepComplete",
    _TERMINATED: "Terminated",
}
_READABLE = (_INITIALIZATION, _STEPPING, _TERMINATED)  # fmi2Get*: as the native FMU (S_GET)
_SETTABLE = (_INSTANTIATED, _INITIALIZATION, _STEPPING)  # fmi2Set*: as the native FMU (S_SET)
_STATE_KEYS = {"fmu", "phase", "t0", "dirty", "values", "stepper"}
_SERIAL_TAG = b"duhem-fmu-state-1"
_UNKNOWN = "unknown value reference for this type"


class FmiRefusal(Exception):
    """A refused FMI call; its message is already in the log (module docstring, "Defences")."""


def _incref_function():
    """``Py_IncRef`` of the interpreter the slave runs in (None where ctypes cannot reach it)."""
    try:
        incref = ctypes.pythonapi.Py_IncRef
    except (AttributeError, OSError):
        return None
    incref.argtypes, incref.restype = [ctypes.py_object], None
    return incref


_INCREF = _incref_function()


def _survive(slave) -> None:
    """Before an exception leaves an FMI call: one reference, owned by nobody, to each object pythonfmu's
    exception path releases (the instance, its log queue, the slave class), so that the release leaves
    them alive and the instance usable (module docstring, "Defences").  Only under pythonfmu's binary."""
    if slave._hosted and _INCREF is not None:
        for obj in (slave, slave.log_queue, type(slave)):
            _INCREF(obj)


def _fmi(function: str):
    """An FMI entry point whose every failure is a logged refusal: the reason in the log (status error),
    then `FmiRefusal` (fmi2Fatal from pythonfmu, survivable: `_survive`).  The method changes nothing
    before it fails (each checks first, then applies)."""

    def decorate(method):
        @functools.wraps(method)
        def call(self, *args):
            try:
                return method(self, *args)
            except Exception as exc:  # noqa: BLE001 - every failure is a refusal, never a crash
                why = str(exc) or type(exc).__name__
                message = why if why.startswith(function) else f"{function}: {why}"
                self.log(message, Fmi2Status.error)
                _survive(self)
                raise FmiRefusal(message) from None

        return call

    return decorate


def _finite_numbers(value) -> bool:
    """Whether every number in a JSON-like value (nested lists, tuples, dicts) is finite."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return True
    if isinstance(value, dict):
        return all(_finite_numbers(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return all(_finite_numbers(v) for v in value)
    if isinstance(value, (int, float)):
        return math.isfinite(value)
    return False


def _same_layout(a, b) -> bool:
    """Whether `a` has the layout of `b`: the same keys, lengths and strings, numbers where b has numbers."""
    if isinstance(b, dict):
        return isinstance(a, dict) and set(a) == set(b) and all(_same_layout(a[k], b[k]) for k in b)
    if isinstance(b, (list, tuple)):
        return isinstance(a, (list, tuple)) and len(a) == len(b) and all(map(_same_layout, a, b))
    if isinstance(b, (bool, str)) or b is None:
        return a == b
    return isinstance(a, (int, float)) and not isinstance(a, bool)


class _Inverse:
    """The kernel's Compensator with the Stepper's communication-point interface: input (``u`` here) y_ref,
    ``output()`` the compensator's u at the current point, ``do_step`` commits it (module docstring)."""

    def __init__(self, compensator, model, t0: float = 0.0, y_ref: float = 0.0):
        self._comp = compensator(model, t0=t0, measurement="invert")
        self.t, self.u, self.du = float(t0), float(y_ref), 0.0
        self._anchor = self._comp.get_state()
        self._solved = None

    def reset(self, t0: float, y_ref: float) -> None:
        self._comp.reset(t0)
        self.t, self.u, self.du = float(t0), float(y_ref), 0.0
        self._anchor = self._comp.get_state()
        self._solved = None

    def set_input(self, y_ref: float) -> None:
        if not math.isfinite(y_ref):
            raise ValueError(f"the reference y_ref = {y_ref} is not finite (NaN or infinite): refused")
        self.u = float(y_ref)
        self._solved = None

    def output(self) -> float:
        if self._solved is None:
            self._comp.set_state(self._anchor)
            u = self._comp.step(self.t, self.u)
            self._solved = (u, self._comp.get_state())
        return self._solved[0]

    def do_step(self, h: float) -> None:
        if not (math.isfinite(h) and h > 0):
            raise ValueError(f"step size {h} must be positive and finite")
        self.output()
        self._anchor = self._solved[1]
        self.t, self.u, self._solved = self.t + h, self.u + self.du * h, None

    def get_state(self) -> list:
        return [self.t, self.u, self.du, _plain_tree(self._anchor)]

    def set_state(self, state) -> None:
        t, u, du, anchor = state
        self._comp.set_state((tuple(anchor[0]),) + tuple(anchor[1:]))
        self._anchor = self._comp.get_state()
        self.t, self.u, self.du, self._solved = float(t), float(u), float(du), None


class DuhemSlave(Fmi2Slave):
    """FMI 2.0 CS slave driving ``kernel.Stepper`` (or, the compensator, ``kernel.Compensator``); see the
    module docstring."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._hosted = "logger" in kwargs  # run by pythonfmu's binary (not by its build step)
        with open(os.path.join(self.resources, CONFIG_FILE), encoding="utf-8") as fh:
            config = json.load(fh)
        self.modelName = config["model_identifier"]
        self._kernel = importlib.import_module(config["kernel_package"])
        self._checks = importlib.import_module(config["kernel_package"] + ".checks")
        self._effects = importlib.import_module(config["kernel_package"] + ".effects")
        model_path = os.path.join(self.resources, config["model_file"])
        with open(model_path, "rb") as fh:
            self._identity = hashlib.sha256(fh.read()).hexdigest()[:32]
        model = self._kernel.load_model(model_path)
        self._dict = model.to_dict()
        self._table = {v["valueReference"]: v for v in config["variables"]}
        self._names = {v["name"]: v["valueReference"] for v in config["variables"]}
        self._inverse = bool(config.get("inverse", False))
        self._in, self._out = (_Y, _U) if self._inverse else (_U, _Y)
        self._start = float(self._table[self._in].get("start") or 0.0)
        self._phase = _INSTANTIATED
        self._t0 = 0.0
        self._dirty = False
        self._model = model
        self._waived = self._convergence_waived(model)
        self._verdict = self._check(model)
        if self._verdict:
            self.log(
                f"fmi2Instantiate: the model this FMU carries fails its check: {self._verdict}; "
                "fmi2ExitInitializationMode will refuse it unless its parameters are set to values that pass",
                Fmi2Status.warning,
            )
        self._stepper = self._engine(model, 0.0, self._start)

    def _engine(self, model, t0: float, value: float):
        """The Stepper (input u) or, for the compensator, the `_Inverse` (input y_ref) at t0."""
        if self._inverse:
            return _Inverse(self._kernel.Compensator, model, t0, value)
        return self._kernel.Stepper(model, t0, value)

    # -- checks ----------------------------------------------------------
    def _convergence_waived(self, model) -> bool:
        """Whether the model was exported past its convergence condition (module docstring, "Defences")."""
        info = model.fit_info if isinstance(model.fit_info, dict) else {}
        record = info.get("convergence")
        if isinstance(record, dict) and "satisfied" in record:
            return record["satisfied"] is False
        try:
            return not self._checks.convergence(model).satisfied
        except Exception:  # noqa: BLE001 - not computable: not waived, `_check` says why
            return False

    def _check(self, model) -> str | None:
        """Why `model` may not run (None: it may): the kernel's `checks.check_model` from its parameters."""
        try:
            self._checks.check_model(model, "the FMU's model", allow_unstable=self._waived)
        except self._checks.ModelCheckError as exc:
            return str(exc)
        except Exception as exc:  # noqa: BLE001 - an uncheckable model is not run
            return f"the FMU's model could not be checked: {exc}"
        return None

    def _ready(self) -> None:
        """The model rebuilt from the parameters set, and checked; raises why it may not run."""
        if self._dirty:
            self._rebuild()
        if self._verdict:
            raise ValueError(self._verdict)

    def _require(self, function: str, phases) -> None:
        if self._phase not in phases:
            raise ValueError(f"{function}: not allowed in state {_STATE_NAMES[self._phase]} (illegal call sequence)")

    def _rebuild(self) -> None:
        """Model and Stepper from the current parameter values (start time, current u), and its verdict."""
        try:
            model = self._kernel.model_from_dict(self._dict, source="FMU parameters")
        except ValueError as exc:
            raise ValueError(f"invalid parameter values: {exc}") from None
        stepper = self._engine(model, self._t0, self._stepper.u)
        self._model, self._stepper, self._dirty = model, stepper, False
        self._verdict = self._check(model)

    def _output(self) -> float:
        """The output at the current point; raises when it (or the state) is not finite."""
        with np.errstate(all="ignore"):
            value = float(self._stepper.output())
            finite = math.isfinite(value) and (self._inverse or bool(np.all(np.isfinite(self._stepper.state()))))
        if not finite:
            raise ValueError(
                f"the state is not finite after this input change (output {value!r} at t = "
                f"{self._stepper.t!r}): the model's state overflows (a model whose state grows "
                "without bound, or too large an input change); roll back with fmi2SetFMUstate"
            )
        return value

    # -- values ----------------------------------------------------------
    def _lookup(self, path: list):
        node = self._dict
        for key in path:
            node = node[key]
        return node

    def _label(self, vr) -> str:
        var = self._table.get(vr)
        return f"{var['name'] if var else '?'} (value reference {vr})"

    def _parameter_rule(self, path: list, value: float) -> str | None:
        """Why a real parameter may not take `value` (None: it may): finite; an effect parameter in its range."""
        if not math.isfinite(value):
            return "the value is not finite (NaN or infinite)"
        if len(path) == 4 and path[0] == "effects" and path[2] == "parameters":
            spec = self._effects.REGISTRY.get(self._dict["effects"][path[1]]["effect"])
            par = next((p for p in spec.parameters if p.name == path[3]), None) if spec else None
            if par is not None and not par.allows(value):
                return f"must be {par.rule()}"
        return None

    def _real_setter(self, vr: int, value: float):
        """Check setting real `vr` to `value` in this phase; the change to apply, or raises why not."""
        var = self._table.get(vr)
        label = f"{self._label(vr)} = {value:g}"
        if vr == self._in:
            if not math.isfinite(value):
                raise ValueError(f"{label}: the input is not finite (NaN or infinite)")
            return lambda: self._stepper.set_input(value)
        if vr == self._out:
            raise ValueError(f"{label}: an output cannot be set")
        if var is None or var["type"] != "Real" or var["causality"] != "parameter":
            raise ValueError(f"{label}: {_UNKNOWN} (not a settable Real)")
        if self._phase == _STEPPING:
            raise ValueError(
                f"{label}: a fixed parameter (variability 'fixed') can only be set before fmi2ExitInitializationMode"
            )
        why = self._parameter_rule(var["path"], value)
        if why:
            raise ValueError(f"{label}: {why}")
        path = var["path"]

        def apply():
            self._lookup(path[:-1])[path[-1]] = float(value)
            self._dirty = True

        return apply

    def _constant(self, function: str, vr: int, kind: str, value=None):
        """The structural constant `vr` of type `kind`; with `value`, raises unless it is its own value."""
        var = self._table.get(vr)
        if var is None or var["type"] != kind:
            raise ValueError(f"{function}: {self._label(vr)}: {_UNKNOWN}")
        current = self._lookup(var["path"])
        if value is not None and value != current:
            raise ValueError(
                f"{function}: {self._label(vr)} = {value!r}: {var['name']} is structural "
                f"({current!r}): export a new FMU to change it"
            )
        return current

    def _real(self, vr: int) -> float:
        if vr == self._out:
            self._ready()
            return self._output()
        if vr == self._in:
            return float(self._stepper.u)
        var = self._table.get(vr)
        if var is None or var["type"] != "Real":
            raise ValueError(_UNKNOWN)
        return float(self._lookup(var["path"]))

    @_fmi("fmi2GetReal")
    def get_real(self, vrs):
        self._require("fmi2GetReal", _READABLE)
        values = []
        for vr in vrs:
            try:
                values.append(self._real(vr))
            except Exception as exc:  # noqa: BLE001 - named, then refused by _fmi
                raise ValueError(f"{self._label(vr)}: {exc}") from None
        return values

    @_fmi("fmi2SetReal")
    def set_real(self, vrs, values):
        self._require("fmi2SetReal", _SETTABLE)
        changes = [self._real_setter(vr, float(value)) for vr, value in zip(vrs, values)]
        for apply in changes:
            apply()

    @_fmi("fmi2GetInteger")
    def get_integer(self, vrs):
        self._require("fmi2GetInteger", _READABLE)
        return [int(self._constant("fmi2GetInteger", vr, "Integer")) for vr in vrs]

    @_fmi("fmi2GetString")
    def get_string(self, vrs):
        self._require("fmi2GetString", _READABLE)
        return [str(self._constant("fmi2GetString", vr, "String")) for vr in vrs]

    @_fmi("fmi2SetInteger")
    def set_integer(self, vrs, values):
        self._require("fmi2SetInteger", _SETTABLE)
        for vr, value in zip(vrs, values):
            self._constant("fmi2SetInteger", vr, "Integer", int(value))

    @_fmi("fmi2SetString")
    def set_string(self, vrs, values):
        self._require("fmi2SetString", _SETTABLE)
        for vr, value in zip(vrs, values):
            self._constant("fmi2SetString", vr, "String", value if value is None else str(value))

    @_fmi("fmi2GetBoolean")
    def get_boolean(self, vrs):
        self._require("fmi2GetBoolean", _READABLE)
        if vrs:
            raise ValueError(f"{self._label(vrs[0])}: {_UNKNOWN} (this FMU has no Boolean variables)")
        return []

    @_fmi("fmi2SetBoolean")
    def set_boolean(self, vrs, values):
        self._require("fmi2SetBoolean", _SETTABLE)
        if vrs:
            raise ValueError(f"{self._label(vrs[0])}: {_UNKNOWN} (this FMU has no Boolean variables)")

    # -- life cycle ------------------------------------------------------
    @_fmi("fmi2SetupExperiment")
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self._require("fmi2SetupExperiment", (_INSTANTIATED,))
        if not math.isfinite(start_time):
            raise ValueError(f"startTime = {start_time!r} is not finite")
        if stop_time is not None and not (math.isfinite(stop_time) and stop_time >= start_time):
            raise ValueError(f"stopTime = {stop_time!r} must be finite and >= startTime = {start_time!r}")
        self._t0 = float(start_time)
        self._stepper.reset(self._t0, self._stepper.u)

    @_fmi("fmi2EnterInitializationMode")
    def enter_initialization_mode(self):
        self._require("fmi2EnterInitializationMode", (_INSTANTIATED,))
        self._phase = _INITIALIZATION

    @_fmi("fmi2ExitInitializationMode")
    def exit_initialization_mode(self):
        self._require("fmi2ExitInitializationMode", (_INITIALIZATION,))
        self._ready()
        self._phase = _STEPPING

    @_fmi("fmi2Terminate")
    def terminate(self):
        self._require("fmi2Terminate", (_STEPPING,))
        self._phase = _TERMINATED

    def do_step(self, current_time, step_size):
        """One step, or a refusal: an error message in the log and False (fmi2Discard from pythonfmu), never an
        exception, which pythonfmu would turn into fmi2Fatal.  The state is unchanged after a refusal."""
        try:
            why = self._refusal(current_time, step_size)
            if why is None:
                saved = self._stepper.get_state()
                try:
                    self._output()  # a non-finite point is not committed
                    with np.errstate(all="ignore"):
                        self._stepper.do_step(step_size)
                    return True
                except Exception as exc:  # noqa: BLE001 - a KernelError, an overflow: refuse, keep the state
                    self._stepper.set_state(saved)
                    why = str(exc)
        except Exception as exc:  # noqa: BLE001 - whatever it is, a refused step, never a crash
            why = str(exc) or type(exc).__name__
        self.log(f"fmi2DoStep refused: {why}", Fmi2Status.discard)
        return False

    def _refusal(self, current_time, step_size) -> str | None:
        """Why fmi2DoStep(current_time, step_size) is refused in this phase (None: it is not)."""
        if self._phase == _TERMINATED:
            return "called after fmi2Terminate (not allowed in state Terminated: illegal call sequence)"
        if self._phase != _STEPPING:
            return (
                f"called before fmi2ExitInitializationMode (not allowed in state {_STATE_NAMES[self._phase]}: "
                "illegal call sequence)"
            )
        if not (math.isfinite(step_size) and step_size > 0):
            return f"the step size {step_size!r} must be positive and finite"
        t = self._stepper.t
        if not math.isfinite(current_time) or abs(current_time - t) > 1e-8 * max(1.0, abs(t), abs(step_size)):
            return (
                f"fmi2DoStep from t = {current_time!r}, but the FMU is at t = {t!r}; "
                "roll back with fmi2SetFMUstate to step from an earlier point"
            )
        if not math.isfinite(t + step_size):
            return f"the time t = {t!r} + {step_size!r} would overflow"
        if self._dirty or self._verdict:
            return self._verdict or "the parameters changed since initialization"
        return None

    # -- FMU state -------------------------------------------------------
    @_fmi("fmi2GetFMUstate")
    def _get_fmu_state(self):
        return {
            "fmu": self._identity,
            "phase": self._phase,
            "t0": self._t0,
            "dirty": self._dirty,
            "values": {k: copy.deepcopy(self._dict[k]) for k in _VALUE_KEYS if k in self._dict},
            "stepper": (self._stepper.get_state() if self._inverse else [_plain(v) for v in self._stepper.get_state()]),
        }

    @_fmi("fmi2SetFMUstate")
    def _set_fmu_state(self, state):
        if isinstance(state, dict) and set(state) == {"refused"}:
            raise ValueError(str(state["refused"]))
        self._valid_state(state)
        saved = (
            copy.deepcopy(self._dict),
            self._model,
            self._stepper,
            self._stepper.get_state(),
            self._phase,
            self._t0,
            self._dirty,
            self._verdict,
        )
        try:
            values = copy.deepcopy(state["values"])
            changed = any(values[k] != self._dict[k] for k in values)
            self._dict.update(values)
            self._t0 = float(state["t0"])
            if changed:
                self._rebuild()
            self._dirty = state["dirty"]
            self._phase = state["phase"]
            self._stepper.set_state(tuple(state["stepper"]))
        except Exception as exc:  # noqa: BLE001 - put everything back, whatever failed
            (
                self._dict,
                self._model,
                self._stepper,
                stepper_state,
                self._phase,
                self._t0,
                self._dirty,
                self._verdict,
            ) = saved
            self._stepper.set_state(stepper_state)
            raise ValueError(f"not a state of this FMU ({exc})") from None

    def _valid_state(self, state) -> None:
        """Raises unless `state` is a state of this FMU (a `_get_fmu_state` of the same model's FMU)."""
        if not isinstance(state, dict) or set(state) != _STATE_KEYS:
            raise ValueError("not a state of this FMU (fmi2GetFMUstate or fmi2DeSerializeFMUstate of it)")
        if state["fmu"] != self._identity:
            raise ValueError("a state of another FMU (another model): not a state of this FMU")
        if state["phase"] not in _STATE_NAMES or not isinstance(state["dirty"], bool):
            raise ValueError("not a state of this FMU (its phase or flags)")
        current = {k: self._dict[k] for k in _VALUE_KEYS if k in self._dict}
        if not _same_layout(state["values"], current) or not _finite_numbers(state["values"]):
            raise ValueError("not a state of this FMU (its parameter values)")
        if (
            not isinstance(state["t0"], (int, float))
            or not math.isfinite(state["t0"])
            or not isinstance(state["stepper"], (list, tuple))
            or not _finite_numbers(state["stepper"])
        ):
            raise ValueError("not a state of this FMU (a time, input or state that is not finite)")

    @staticmethod
    def _fmu_state_to_bytes(state) -> bytes:
        """The serialized state: a tag, the SHA-256 of the JSON, the JSON.  Never raises (pythonfmu calls it
        without an instance to keep alive: `_survive`)."""
        try:
            payload = json.dumps(state, sort_keys=True).encode("utf-8")
        except Exception as exc:  # noqa: BLE001
            payload = json.dumps({"refused": f"fmi2SerializeFMUstate: not serializable ({exc})"}).encode()
        return _SERIAL_TAG + b" " + hashlib.sha256(payload).hexdigest().encode("ascii") + b"\n" + payload

    @staticmethod
    def _fmu_state_from_bytes(data: bytes):
        """The state serialized by `_fmu_state_to_bytes`, or ``{"refused": why}``, which fmi2SetFMUstate
        refuses with that reason.  Never raises (see `_fmu_state_to_bytes`)."""
        why = "fmi2SetFMUstate: the state was deserialized from bytes that are not a state of this FMU"
        try:
            head, payload = bytes(data).split(b"\n", 1)
            tag, digest = head.split(b" ")
            if tag != _SERIAL_TAG:
                return {"refused": f"{why} (expected the tag {_SERIAL_TAG.decode()})"}
            if hashlib.sha256(payload).hexdigest().encode("ascii") != digest:
                return {"refused": f"{why} (checksum mismatch: corrupted)"}
            return json.loads(payload.decode("utf-8"))
        except Exception as exc:  # noqa: BLE001
            return {"refused": f"{why} ({type(exc).__name__}: {exc})"}


def _plain(value):
    """A Stepper state entry as JSON-able Python values (float, list or None)."""
    if value is None or isinstance(value, float):
        return value
    if hasattr(value, "__len__"):
        return [float(v) for v in value]
    return float(value)


def _plain_tree(value):
    """The compensator's state as JSON-able nested lists of floats, ints, bools and None."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, (tuple, list)):
        return [_plain_tree(v) for v in value]
    if hasattr(value, "tolist"):
        return value.tolist()
    return float(value)
