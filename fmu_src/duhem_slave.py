"""pythonfmu slave of an exported semilinear Duhem model (FMI 2.0 Co-Simulation).

Runs inside the FMU, with only the FMU's ``resources/`` directory on
``sys.path`` (pythonfmu puts it there): it reads ``duhem_fmu.json`` (written by
`build_fmu`: the name of the kernel package copied from ``fitter/core``, the
model file, the variable table of `fitter.fmu.model_description.model_variables`)
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
  ``order``/``kind`` to another value, is rejected: pythonfmu turns every
  Python exception into ``fmi2Fatal`` with the exception's message.
* ``fmi2GetFMUstate`` captures parameters, phase and the Stepper state; states
  serialize as JSON (floats round-trip exactly).
* ``do_step`` must start where the FMU is (``currentCommunicationPoint`` equal
  to the end of the last step, up to rounding); roll back with
  ``fmi2SetFMUstate`` to step from elsewhere.

The compensator (``duhem export --inverse``)
-------------------------------------------
With ``"inverse": true`` in ``duhem_fmu.json`` the slave runs the kernel's
``Compensator`` (``fitter/core/inverse.py``) on the model instead: ``y_ref``
(value reference 1) is the input, ``u`` (value reference 0) the output.  The
same communication-point semantics (`_Inverse`): reading u solves the current
point from the last committed one without committing it (so y_ref may be set
again and u re-read), ``do_step`` commits it.  A NaN or infinite y_ref is
refused (an exception: fmi2Fatal in pythonfmu); the FMU state holds the
compensator's whole state, so a rollback replays the same u.

The class statement must stay literally ``class DuhemSlave(Fmi2Slave):``:
pythonfmu's binary finds the slave class with that regular expression.
"""
from __future__ import annotations

import copy
import importlib
import json
import math
import os

from pythonfmu import Fmi2Slave
from pythonfmu.enums import Fmi2Status

CONFIG_FILE = "duhem_fmu.json"
_U, _Y = 0, 1
_VALUE_KEYS = ("parameters", "g", "effects")
_INSTANTIATED, _INITIALIZATION, _STEPPING, _TERMINATED = "instantiated", "initialization", "stepping", "terminated"


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
        with open(os.path.join(self.resources, CONFIG_FILE), encoding="utf-8") as fh:
            config = json.load(fh)
        self.modelName = config["model_identifier"]
        self._kernel = importlib.import_module(config["kernel_package"])
        model = self._kernel.load_model(os.path.join(self.resources, config["model_file"]))
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
        self._stepper = self._engine(model, 0.0, self._start)

    def _engine(self, model, t0: float, value: float):
        """The Stepper (input u) or, for the compensator, the `_Inverse` (input y_ref) at t0."""
        if self._inverse:
            return _Inverse(self._kernel.Compensator, model, t0, value)
        return self._kernel.Stepper(model, t0, value)

    # -- values ----------------------------------------------------------
    def _lookup(self, path: list):
        node = self._dict
        for key in path:
            node = node[key]
        return node

    def _assign(self, vr: int, value) -> None:
        var = self._table.get(vr)
        if var is None or (var["type"] == "Real" and var["causality"] != "parameter"):
            raise ValueError(f"value reference {vr} is not a settable variable of this FMU"
                             + (" (an output)" if vr == self._out else ""))
        name, path = var["name"], var["path"]
        if var["type"] != "Real":
            if value != self._lookup(path):
                raise ValueError(f"{name} is structural ({self._lookup(path)!r}); export a new "
                                 f"FMU for a model with {name} = {value!r}")
            return
        if self._phase == _STEPPING:
            raise ValueError(f"parameter {name} has variability 'fixed': set it before "
                             "fmi2ExitInitializationMode")
        node = self._lookup(path[:-1])
        node[path[-1]] = float(value)
        self._dirty = True

    def _rebuild(self) -> None:
        """Model and Stepper from the current parameter values (start time, current u)."""
        try:
            self._model = self._kernel.model_from_dict(self._dict, source="FMU parameters")
        except ValueError as exc:
            raise ValueError(f"invalid parameter values: {exc}") from None
        u = self._stepper.u
        self._stepper = self._engine(self._model, self._t0, u)
        self._dirty = False

    def _real(self, vr: int) -> float:
        if vr == self._out:
            if self._dirty:
                self._rebuild()
            return self._stepper.output()
        if vr == self._in:
            return self._stepper.u
        var = self._table.get(vr)
        if var is None or var["type"] != "Real":
            raise ValueError(f"value reference {vr} is not a Real variable of this FMU")
        return float(self._lookup(var["path"]))

    def get_real(self, vrs):
        return [self._real(vr) for vr in vrs]

    def set_real(self, vrs, values):
        for vr, value in zip(vrs, values):
            if vr == self._in:
                self._stepper.set_input(value)
            else:
                self._assign(vr, value)

    def _typed(self, vr: int, kind: str):
        var = self._table.get(vr)
        if var is None or var["type"] != kind:
            raise ValueError(f"value reference {vr} is not an {kind} variable of this FMU")
        return self._lookup(var["path"])

    def get_integer(self, vrs):
        return [int(self._typed(vr, "Integer")) for vr in vrs]

    def get_string(self, vrs):
        return [str(self._typed(vr, "String")) for vr in vrs]

    def set_integer(self, vrs, values):
        for vr, value in zip(vrs, values):
            self._typed(vr, "Integer")
            self._assign(vr, int(value))

    def set_string(self, vrs, values):
        for vr, value in zip(vrs, values):
            self._typed(vr, "String")
            self._assign(vr, str(value))

    def get_boolean(self, vrs):
        raise ValueError("this FMU has no Boolean variables")

    def set_boolean(self, vrs, values):
        raise ValueError("this FMU has no Boolean variables")

    # -- life cycle ------------------------------------------------------
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        if not math.isfinite(start_time):
            raise ValueError(f"start time {start_time!r} is not finite")
        self._t0 = float(start_time)
        self._stepper.reset(self._t0, self._stepper.u)

    def enter_initialization_mode(self):
        self._phase = _INITIALIZATION

    def exit_initialization_mode(self):
        if self._dirty:
            self._rebuild()
        self._phase = _STEPPING

    def terminate(self):
        self._phase = _TERMINATED

    def do_step(self, current_time, step_size):
        """One step, or a refusal: an error message in the log and False (fmi2Error from pythonfmu), never an
        exception, which pythonfmu would turn into fmi2Fatal.  The state is unchanged after a refusal."""
        why = self._refusal(current_time, step_size)
        if why is None:
            try:
                self._stepper.do_step(step_size)
                return True
            except Exception as exc:    # a KernelError, or numpy overflow: refuse, keep the state
                why = str(exc)
        self.log(f"fmi2DoStep refused: {why}", Fmi2Status.error)
        return False

    def _refusal(self, current_time, step_size) -> str | None:
        """Why fmi2DoStep(current_time, step_size) is refused in this phase (None: it is not)."""
        if self._phase == _TERMINATED:
            return "called after fmi2Terminate"
        if self._phase != _STEPPING:
            return "called before fmi2ExitInitializationMode"
        if not (math.isfinite(step_size) and step_size > 0):
            return f"the step size {step_size!r} must be positive and finite"
        t = self._stepper.t
        if not math.isfinite(current_time) or abs(current_time - t) > 1e-8 * max(1.0, abs(t), abs(step_size)):
            return (f"fmi2DoStep from t = {current_time!r}, but the FMU is at t = {t!r}; "
                    "roll back with fmi2SetFMUstate to step from an earlier point")
        return None

    # -- FMU state -------------------------------------------------------
    def _get_fmu_state(self):
        return {"phase": self._phase, "t0": self._t0, "dirty": self._dirty,
                "values": {k: copy.deepcopy(self._dict[k]) for k in _VALUE_KEYS if k in self._dict},
                "stepper": (self._stepper.get_state() if self._inverse
                            else [_plain(v) for v in self._stepper.get_state()])}

    def _set_fmu_state(self, state):
        if not isinstance(state, dict) or set(state) != {"phase", "t0", "dirty", "values", "stepper"} or \
                state["phase"] not in (_INSTANTIATED, _INITIALIZATION, _STEPPING, _TERMINATED):
            raise ValueError("fmi2SetFMUstate: not a state of this FMU")
        values = copy.deepcopy(state["values"])
        changed = any(values[k] != self._dict[k] for k in values)
        self._dict.update(values)
        self._t0 = state["t0"]
        if changed:
            self._rebuild()
        self._dirty = state["dirty"]
        self._phase = state["phase"]
        self._stepper.set_state(tuple(state["stepper"]))


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
