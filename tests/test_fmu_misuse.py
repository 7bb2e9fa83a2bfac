"""One misuse table, run against both FMU backends: the python (pythonfmu) FMU must be as defensive as the native one.

Each case of `CASES` is a sequence of FMI 2.0 calls that a careless or hostile host makes: NaN and infinite
inputs and parameters, calls out of sequence and after an error, bad steps, huge states and inputs, models
that overflow, corrupt FMU states.  A case runs in a subprocess (this file run as a script, ``python
tests/test_fmu_misuse.py run CASE BACKEND FMU UNZIPDIR``: `_run_case`), so that a crash fails its test instead
of killing pytest.  After its calls the driver always reads y, terminates and frees the instance: the later
calls after an error.  The test then asserts

* the subprocess exits 0 (no segfault, no abort), having run every call;
* every call's status: a refused call logs why (the case's fragment in the log lines of that call);
* no non-finite value is ever returned with fmi2OK (fmi2GetReal, fmi2GetRealStatus);
* where the case ends with a run from the start, its outputs equal the kernel's `simulate`: the refused calls
  changed nothing.

Statuses.  The native FMU refuses with fmi2Error.  The python FMU runs in pythonfmu 0.7's binary, whose C++
wrapper gives a Python slave no way to return fmi2Error: a refused fmi2DoStep is fmi2Discard (``do_step``
returns False), every other refusal fmi2Fatal (the slave raises; `fmu_src/duhem_slave.py` keeps the instance
alive through pythonfmu's exception path, so later calls are safe).  `REFUSED` and `STEP_REFUSED` say so.

Out of the python slave's reach (pythonfmu's binary, before or after any Python runs): NULL arguments are
dereferenced (the case ``null arguments`` runs on the native FMU only), and ``fmi2GetRealStatus`` returns the
NaN its wrapper starts with, with fmi2OK, before the first step (the case ``last successful time before a
step``: a strict xfail for the python FMU).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from ctypes import c_double, c_int, c_uint, c_void_p
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
BACKENDS = ("native", "python")


@dataclass(frozen=True)
class Expect:
    """The status each backend must return (None: the call is not made on that backend), and a fragment of
    the message the refusal logs (a string for both, or a {backend: fragment} dict)."""

    native: int | None
    python: int | None
    fragment: str | dict | None = None

    def status(self, backend: str) -> int | None:
        return getattr(self, backend)

    def text(self, backend: str) -> str | None:
        return self.fragment.get(backend) if isinstance(self.fragment, dict) else self.fragment


OK = Expect(0, 0)


def REFUSED(fragment=None) -> Expect:
    """A refused call: fmi2Error (native); fmi2Fatal, survivable (python: pythonfmu's only failure status)."""
    return Expect(3, 4, fragment)


def STEP_REFUSED(fragment=None) -> Expect:
    """A refused fmi2DoStep: fmi2Error (native); fmi2Discard (python: ``do_step`` returns False)."""
    return Expect(3, 2, fragment)


@dataclass(frozen=True)
class Case:
    """A model (a key of `MODELS`), the calls as (operation, *arguments, Expect), and whether it ends with a
    run from the start that must equal the kernel's (`reference`: the model that run must follow)."""

    model: str
    calls: tuple
    reference: str | None = None
    only: tuple = BACKENDS
    python_xfail: str | None = None
    notes: dict = field(default_factory=dict)


RUN = 120  # samples of the closing run: t_k = 0.02 k, `run_input`


def run_input(n: int = RUN) -> tuple[np.ndarray, np.ndarray]:
    t = 0.02 * np.arange(n)
    return t, 1.2 * np.sin(1.7 * t) + 0.4 * np.sin(4.3 * t + 0.3)


def _models() -> dict:
    """The models of the table (built lazily: the driver subprocess needs them only by name)."""
    from samples import rd_model, ri_model
    from test_inverse import ri2

    effects = [
        {"effect": "creep", "parameters": {"k": 0.2, "tau": 0.6}},
        {"effect": "backlash", "parameters": {"b": 0.1}},
    ]
    stable = ri_model(2)  # alpha(A+ - A-) = -3.1 < 0: convergent, no fit_info record
    unstable = {"A_plus": [[500.0, 0.0], [0.0, -1.5]]}  # an eigenvalue +500 on the rising branch
    return {
        "table": rd_model(2, effects),  # the paper's Example 3, g tabulated, with creep and backlash
        "ri": stable,
        "x0 1e308": stable.replace(x0=[1e308, -0.3]),
        # a hand-edited fitted model: its fit record says convergent, its parameters do not
        "A+ = 500, record says convergent": stable.replace(**unstable, fit_info={"convergence": {"satisfied": True}}),
        # exported with --allow-unstable (the record duhem export writes)
        "A+ = 500, exported with --allow-unstable": stable.replace(
            **unstable, fit_info={"convergence": {"satisfied": False}}
        ),
        # the compensator (duhem export --inverse) of a model with an input range: input y_ref, output u
        "compensator": ri2(),
    }


def _rate_nodes():
    from samples import rd_model

    return [float(v) for v in rd_model(2).g.v[:2]]


V1, V2 = _rate_nodes()  # g_v[1], g_v[2] of the table model: g_v[2] = V1 repeats a node

CASES = {
    "NaN input, then y, a step, terminate (the audit's segfault)": Case(
        "table",
        (
            ("init", 0.2, OK),
            ("set", "u", math.nan, REFUSED("not finite")),
            ("get", "y", OK),
            ("step", 0.05, OK),
            ("get", "y", OK),
            ("set", "u", math.nan, REFUSED("not finite")),
            ("terminate", OK),
            ("get", "y", OK),
        ),
    ),
    "NaN input, then terminate at once": Case(
        "table",
        (
            ("init", 0.2, OK),
            ("set", "u", math.nan, REFUSED("not finite")),
            ("terminate", OK),
        ),
    ),
    "infinite inputs, the state unchanged": Case(
        "table",
        (
            ("set", "u", math.inf, REFUSED("not finite")),
            ("set", "u", -math.inf, REFUSED("not finite")),
            ("init", 0.0, OK),
            ("set", "u", math.inf, REFUSED("not finite")),
            ("set", "u", -math.inf, REFUSED("not finite")),
            ("run", OK),
        ),
        reference="table",
    ),
    "NaN, infinite and out-of-range parameters": Case(
        "table",
        (
            ("set", "creep.tau", math.nan, REFUSED("not finite")),
            ("set", "x0[1]", math.inf, REFUSED("not finite")),
            ("set", "A[1,1]", -math.inf, REFUSED("not finite")),
            ("set", "g_g[3]", math.nan, REFUSED("not finite")),
            ("set", "creep.tau", 0.0, REFUSED("must be positive")),
            ("set", "backlash.b", -1.0, REFUSED("must be >= 0")),
            ("init", 0.0, OK),
            ("run", OK),
        ),
        reference="table",
    ),
    "unknown references, outputs, fixed parameters, structural constants": Case(
        "table",
        (
            ("set", 10**6, 1.0, REFUSED("unknown value reference")),
            ("set_int", "order", 3, REFUSED("structural")),
            ("set_int", "order", 2, OK),
            ("set_str", "kind", "ri", REFUSED("structural")),
            ("set_str", "kind", "rd", OK),
            ("init", 0.0, OK),
            ("get", 10**6, REFUSED("unknown value reference")),
            ("set", "y", 1.0, REFUSED("output cannot be set")),
            ("set", "A[1,1]", 1.0, REFUSED("a fixed parameter")),
            ("get_int", "order", OK),
            ("run", OK),
        ),
        reference="table",
    ),
    "bad steps change nothing": Case(
        "table",
        (
            ("init", 0.0, OK),
            ("step", 0.0, STEP_REFUSED("must be positive")),
            ("step", -0.1, STEP_REFUSED("must be positive")),
            ("step", math.nan, STEP_REFUSED("must be positive")),
            ("step_at", 1.0, 0.1, STEP_REFUSED({"native": "is not the FMU's time", "python": "but the FMU is at t"})),
            ("step_at", math.inf, 0.1, STEP_REFUSED()),
            ("run", OK),
        ),
        reference="table",
    ),
    "time overflow": Case(
        "table",
        (
            ("init", 0.0, OK),
            ("step", 1e308, OK),
            ("step", 1e308, STEP_REFUSED("overflow")),
            ("get", "y", OK),
        ),
    ),
    "calls out of sequence": Case(
        "table",
        (
            ("get", "y", REFUSED("illegal call sequence")),
            ("step", 0.1, STEP_REFUSED("illegal call sequence")),
            ("exit", REFUSED("illegal call sequence")),
            ("terminate", REFUSED("illegal call sequence")),
            ("setup", 0.0, OK),
            ("enter", OK),
            ("enter", REFUSED("illegal call sequence")),
            ("setup", 1.0, REFUSED("illegal call sequence")),
            ("exit", OK),
            ("exit", REFUSED("illegal call sequence")),
            ("set", "u", 0.4, OK),
            ("step", 0.05, OK),
            ("terminate", OK),
            ("terminate", REFUSED("illegal call sequence")),
            ("set", "u", 0.3, REFUSED("illegal call sequence")),
            ("step", 0.05, STEP_REFUSED("illegal call sequence")),
            ("get", "y", OK),
            ("reset", OK),
            ("init", 0.0, OK),
            ("run", OK),
        ),
        reference="table",
    ),
    "an invalid rate table is refused at initialisation, then corrected": Case(
        "table",
        (
            ("setup", 0.0, OK),
            ("set", "g_v[2]", V1, OK),
            ("enter", OK),
            ("exit", REFUSED("duplicate")),
            ("set", "g_v[2]", V2, OK),
            ("exit", OK),
            ("run", OK),
        ),
        reference="table",
    ),
    "a start state beyond 1e100 set by the host": Case(
        "table",
        (
            ("setup", 0.0, OK),
            ("set", "x0[1]", 1e200, OK),
            ("enter", OK),
            ("exit", REFUSED("beyond 1e")),
            ("step", 0.1, STEP_REFUSED("illegal call sequence")),
            ("set", "x0[1]", 0.1, OK),  # the table model's own x0[1]
            ("exit", OK),
            ("run", OK),
        ),
        reference="table",
    ),
    "corrupt and foreign FMU states": Case(
        "table",
        (
            ("init", 0.0, OK),
            # pythonfmu cannot refuse fmi2DeSerializeFMUstate safely (module docstring): fmi2SetFMUstate refuses
            ("deserialize", "short", Expect(3, 0, {"native": "expected"})),
            ("restore_deserialized", Expect(None, 4, {"python": "not a state of this FMU"})),
            ("deserialize", "zeros", Expect(3, 0, {"native": "checksum mismatch"})),
            ("restore_deserialized", Expect(None, 4, {"python": "not a state of this FMU"})),
            ("deserialize", "flipped", Expect(3, 0, {"native": "checksum mismatch"})),
            ("restore_deserialized", Expect(None, 4, {"python": "checksum mismatch"})),
            ("run", OK),
        ),
        reference="table",
    ),
    "a rollback after an error": Case(
        "table",
        (
            ("init", 0.0, OK),
            ("set", "u", 0.3, OK),
            ("step", 0.05, OK),
            ("save", OK),
            ("set", "u", math.nan, REFUSED("not finite")),
            ("set", "u", 0.8, OK),
            ("step", 0.05, OK),
            ("restore", OK),
            ("roundtrip", OK),
            ("get", "y", OK),
            ("step_at", 0.05, 0.05, OK),
        ),
    ),
    "status inquiries and input derivatives": Case(
        "table",
        (
            ("init", 0.0, OK),
            ("step", 0.05, OK),
            ("real_status", OK),
            ("do_step_status", Expect(2, 3)),
            # pythonfmu's own fmi2SetRealInputDerivatives: fmi2Error, "not supported" (the slave is not called)
            ("derivative", 2, 1.0, Expect(3, 3, {"native": "only order 1", "python": "not supported"})),
            ("get", "y", OK),
        ),
    ),
    "last successful time before a step": Case(
        "table",
        (
            ("init", 0.0, OK),
            ("real_status", OK),
        ),
        python_xfail="pythonfmu's fmi2GetRealStatus returns its initial lastSuccessfulTime, NaN, with fmi2OK "
        "before the first step (its binary; the slave is not called)",
    ),
    "huge inputs: an overflowing state is refused, not returned": Case(
        "ri",
        (
            ("init", 0.0, OK),
            ("step", 0.1, OK),
            ("set", "u", 1e308, OK),
            ("get", "y", REFUSED("not finite")),
            ("step", 0.1, STEP_REFUSED("not finite")),
            ("set", "u", 0.0, OK),
            ("get", "y", OK),
            ("step", 0.1, OK),
            ("get", "y", OK),
        ),
    ),
    "x0 = 1e308 exported: refused at initialisation, then corrected": Case(
        "x0 1e308",
        (
            ("setup", 0.0, OK),
            ("enter", OK),
            ("exit", REFUSED("beyond 1e")),
            ("set", "x0[1]", 0.4, OK),
            ("exit", OK),
            ("run", OK),
        ),
        reference="ri",
    ),
    "parameters set by the host that break the convergence condition": Case(
        "ri",
        (
            ("setup", 0.0, OK),
            ("set", "A_plus[1,1]", 50.0, OK),
            ("enter", OK),
            # the native FMU checks magnitude, not convergence: its overflow is refused when y is read
            ("exit", Expect(0, 4, {"python": "convergence condition is violated"})),
        ),
    ),
    "A+ = 500 with a fit record that says convergent": Case(
        "A+ = 500, record says convergent",
        (
            ("setup", 0.0, OK),
            ("enter", OK),
            ("exit", Expect(0, 4, {"python": "convergence condition is violated"})),
            ("step", 0.1, Expect(0, 2, {"python": "illegal call sequence"})),
            ("set", "u", 2.0, OK),  # the rising branch over 2: e^(1000) overflows
            ("get", "y", Expect(3, 4, {"native": "not finite", "python": "convergence condition is violated"})),
        ),
    ),
    "A+ = 500 exported with --allow-unstable: runs until it overflows": Case(
        "A+ = 500, exported with --allow-unstable",
        (
            ("init", 0.0, OK),
            ("step", 0.1, OK),
            ("set", "u", 2.0, OK),
            ("get", "y", REFUSED("not finite")),
            ("step", 0.1, STEP_REFUSED("not finite")),
            ("set", "u", 0.0, OK),
            ("get", "y", OK),
            ("step", 0.1, OK),
        ),
    ),
    "the compensator: a NaN reference, a set output, later calls": Case(
        "compensator",
        (
            ("init", 0.0, OK),
            ("set", "y_ref", math.nan, REFUSED("not finite")),
            ("get", "u", OK),
            ("set", "y_ref", 0.5, OK),
            ("get", "u", OK),
            ("step", 0.05, OK),
            ("set", "y_ref", math.inf, REFUSED("not finite")),
            ("set", "u", 1.0, REFUSED("output cannot be set")),
            ("step", -0.05, STEP_REFUSED("positive")),
            ("terminate", OK),
            ("set", "y_ref", 0.2, REFUSED("illegal call sequence")),
            ("get", "u", OK),
        ),
    ),
    "null arguments": Case(
        "table",
        (
            ("init", 0.0, OK),
            ("null", "fmi2GetReal vr", REFUSED("vr is NULL")),
            ("null", "fmi2SetReal value", REFUSED("value is NULL")),
            ("null", "fmi2GetFMUstate", REFUSED("FMUstate is NULL")),
            ("null", "fmi2SetFMUstate", REFUSED("FMUstate is NULL")),
            ("null", "fmi2DoStep component", Expect(3, None)),
            ("run", OK),
        ),
        reference="table",
        only=("native",),
        notes={"python": "pythonfmu's binary dereferences NULL arguments before the slave runs"},
    ),
}


# --------------------------------------------------------------------- the driver (a subprocess)


def _run_case(name: str, backend: str, fmu_path: str, unzipdir: str) -> None:
    """Run the case's calls on a fresh instance, then y, terminate and free; print one JSON line per call
    ({"op", "status", "values", "log"}) and "done"."""
    from fmpy import read_model_description
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave, fmi2DoStepStatus, fmi2LastSuccessfulTime

    from fitter.fmu.host import collecting_callbacks

    case = CASES[name]
    md = read_model_description(fmu_path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    (vr["<in>"],) = [v.valueReference for v in md.modelVariables if v.causality == "input"]
    (vr["<out>"],) = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    fmu = FMU2Slave(
        guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier, instanceName="misuse"
    )
    log: list[str] = []
    callbacks = collecting_callbacks(log)
    fmu.instantiate(callbacks=callbacks, loggingOn=True)
    c = fmu.component
    ref = lambda key: key if isinstance(key, int) else vr[key]
    memory = {"now": 0.0, "saved": None, "deserialized": None}

    def call(function, *args):
        """(status, result) of an fmpy call."""
        try:
            return 0, function(*args)
        except FMICallException as exc:
            return exc.status, None

    def execute(op, args):
        values = []
        if op == "init":
            status = max(
                call(fmu.setupExperiment, None, 0.0)[0],
                call(fmu.enterInitializationMode)[0],
                call(fmu.setReal, [vr["<in>"]], [float(args[0])])[0],
                call(fmu.exitInitializationMode)[0],
            )
            memory["now"] = 0.0
        elif op == "setup":
            status = call(fmu.setupExperiment, None, float(args[0]))[0]
        elif op == "enter":
            status = call(fmu.enterInitializationMode)[0]
        elif op == "exit":
            status = call(fmu.exitInitializationMode)[0]
        elif op == "terminate":
            status = call(fmu.terminate)[0]
        elif op == "reset":
            status = call(fmu.reset)[0]
            memory["now"] = 0.0
        elif op == "set":
            status = call(fmu.setReal, [ref(args[0])], [float(args[1])])[0]
        elif op == "get":
            status, result = call(fmu.getReal, [ref(args[0])])
            values = list(result or [])
        elif op == "set_int":
            status = call(fmu.setInteger, [ref(args[0])], [int(args[1])])[0]
        elif op == "get_int":
            status, result = call(fmu.getInteger, [ref(args[0])])
        elif op == "set_str":
            status = call(fmu.setString, [ref(args[0])], [str(args[1])])[0]
        elif op in ("step", "step_at"):
            t, h = (memory["now"], args[0]) if op == "step" else args
            status = call(fmu.doStep, float(t), float(h))[0]
            if status == 0:
                memory["now"] = t + h
        elif op == "save":
            status, memory["saved"] = call(fmu.getFMUstate)
            memory["saved at"] = memory["now"]
        elif op == "restore":
            status = call(fmu.setFMUstate, memory["saved"])[0]
            memory["now"] = memory["saved at"]
        elif op == "roundtrip":
            status, blob = call(fmu.serializeFMUstate, memory["saved"])
            if status == 0:
                status, state = call(fmu.deSerializeFMUstate, blob)
                if status == 0:
                    status = max(status, call(fmu.setFMUstate, state)[0])
                    fmu.freeFMUstate(state)
                    memory["now"] = memory["saved at"]
        elif op == "deserialize":
            status, state = call(fmu.getFMUstate)
            blob = bytes(fmu.serializeFMUstate(state))
            fmu.freeFMUstate(state)
            half = len(blob) // 2
            garbage = {
                "short": b"short",
                "zeros": bytes(len(blob)),
                "flipped": blob[:half] + bytes([blob[half] ^ 0x5A]) + blob[half + 1 :],
            }
            status, memory["deserialized"] = call(fmu.deSerializeFMUstate, garbage[args[0]])
        elif op == "restore_deserialized":
            if memory["deserialized"] is None:
                status = None
            else:
                status = call(fmu.setFMUstate, memory["deserialized"])[0]
                fmu.freeFMUstate(memory["deserialized"])
                memory["deserialized"] = None
        elif op == "real_status":
            status, result = call(fmu.getRealStatus, fmi2LastSuccessfulTime)
            values = [result] if status == 0 else []
        elif op == "do_step_status":
            status = call(fmu.getStatus, fmi2DoStepStatus)[0]
        elif op == "derivative":
            status = call(
                fmu.fmi2SetRealInputDerivatives,
                c,
                (c_uint * 1)(vr["u"]),
                1,
                (c_int * 1)(int(args[0])),
                (c_double * 1)(float(args[1])),
            )[0]
        elif op == "null":
            status = {
                "fmi2GetReal vr": lambda: call(fmu.fmi2GetReal, c, None, 1, None),
                "fmi2SetReal value": lambda: call(fmu.fmi2SetReal, c, (c_uint * 1)(vr["u"]), 1, None),
                "fmi2GetFMUstate": lambda: call(fmu.fmi2GetFMUstate, c, None),
                "fmi2SetFMUstate": lambda: call(fmu.fmi2SetFMUstate, c, c_void_p(None)),
                "fmi2DoStep component": lambda: call(fmu.fmi2DoStep, None, 0.0, 0.1, 0),
            }[args[0]]()[0]
        elif op == "run":
            t, u = run_input()
            status = 0
            for k in range(len(u)):
                status = max(status, call(fmu.setReal, [vr["<in>"]], [float(u[k])])[0])
                s, result = call(fmu.getReal, [vr["<out>"]])
                status = max(status, s)
                values.append(result[0] if s == 0 else None)
                if k + 1 < len(u):
                    status = max(status, call(fmu.doStep, float(t[k]), float(t[k + 1] - t[k]))[0])
            memory["now"] = float(t[-1])
        else:
            raise ValueError(f"unknown operation {op!r}")
        return status, [float(v) if v is not None else None for v in values]

    steps = [(op, tuple(args)) for op, *args, _ in case.calls]
    steps += [("get", ("<out>",)), ("terminate", ())]  # the later calls: after whatever the case did
    for op, args in steps:
        before = len(log)
        status, values = execute(op, args)
        print(
            json.dumps(
                {
                    "op": op,
                    "args": [a if not isinstance(a, float) or math.isfinite(a) else repr(a) for a in args],
                    "status": status,
                    "values": [v if v is None or math.isfinite(v) else repr(v) for v in values],
                    "log": log[before:],
                }
            ),
            flush=True,
        )
    fmu.fmi2FreeInstance(c)
    print(json.dumps({"op": "free"}), flush=True)
    print("done", flush=True)


if __name__ == "__main__" and len(sys.argv) == 6 and sys.argv[1] == "run":
    sys.path.insert(0, str(REPO))
    _run_case(*sys.argv[2:])
    sys.exit(0)


# --------------------------------------------------------------------- the tests
# (imported here: a case's subprocess runs the code above alone, before the repository is on its path)
import pytest  # noqa: E402

from fitter.core import simulate  # noqa: E402

MODELS = _models()


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """{(model, backend): (fmu path, unzip directory)}: every model of the table for both backends."""
    from fmpy import extract

    import build_fmu

    directory = tmp_path_factory.mktemp("misuse")
    out = {}
    for name, model in MODELS.items():
        for backend in BACKENDS:
            path = directory / f"{len(out)}_{backend}.fmu"
            build_fmu.build_fmu(
                model, path, backend=backend, allow_unstable="allow-unstable" in name, inverse=name == "compensator"
            )
            out[name, backend] = (str(path), extract(str(path), str(path.with_suffix(""))))
    return out


def _driven(case_name: str, backend: str, built) -> tuple[subprocess.CompletedProcess, list[dict]]:
    fmu_path, unzipdir = built[CASES[case_name].model, backend]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), str(REPO / "tests")])}
    result = subprocess.run(
        [sys.executable, __file__, "run", case_name, backend, fmu_path, unzipdir],
        check=False,
        capture_output=True,
        text=True,
        env=env,
        cwd=REPO,
        timeout=300,
    )
    records = [json.loads(line) for line in result.stdout.splitlines() if line.startswith("{")]
    return result, records


def _params():
    for name, case in CASES.items():
        for backend in BACKENDS:
            marks = []
            if backend not in case.only:
                marks.append(pytest.mark.skip(reason=case.notes.get(backend, "not for this backend")))
            if backend == "python" and case.python_xfail:
                marks.append(pytest.mark.xfail(reason=case.python_xfail, strict=True, raises=AssertionError))
            yield pytest.param(name, backend, marks=marks, id=f"{backend}: {name}")


@pytest.mark.parametrize("case_name, backend", list(_params()))
def test_misuse_is_refused_and_never_crashes(built, case_name, backend):
    case = CASES[case_name]
    result, records = _driven(case_name, backend, built)
    assert result.returncode == 0, (
        f"exit {result.returncode} (a crash) after "
        f"{records[-1]['op'] if records else 'no call'}\n{result.stderr[-3000:]}"
    )
    assert result.stdout.rstrip().endswith("done") and records[-1] == {"op": "free"}
    calls = records[: len(case.calls)]
    assert len(calls) == len(case.calls)
    for (op, *args, expect), record in zip(case.calls, calls):
        where = f"{op}{tuple(args)}: {record}"
        assert record["status"] == expect.status(backend), where
        fragment = expect.text(backend)
        if fragment is not None:
            assert any(fragment in line for line in record["log"]), where
    for record in records[:-1]:  # no non-finite value with fmi2OK, the later calls included
        if record["status"] == 0:
            assert all(v is not None and math.isfinite(float(v)) for v in record["values"]), record
    if case.reference:
        (run,) = [r for r in calls if r["op"] == "run"]
        t, u = run_input()
        y_ref = simulate(MODELS[case.reference], t, u).y
        assert np.ptp(y_ref) > 0.1
        assert np.abs(np.array(run["values"], dtype=float) - y_ref).max() <= 1e-9 * max(1.0, np.abs(y_ref).max())


def test_the_table_covers_what_the_issue_lists():
    """NaN and infinite inputs, calls after an error, huge states, non-finite outputs, on both backends."""
    both = [name for name, case in CASES.items() if case.only == BACKENDS]
    assert len(both) >= 15
    ops = {(op, *(a for a in args if isinstance(a, str))) for case in CASES.values() for op, *args, _ in case.calls}
    assert {("set", "u"), ("get", "y"), ("terminate",), ("step",), ("exit",)} <= ops
    values = [a for case in CASES.values() for op, *args, _ in case.calls for a in args if isinstance(a, float)]
    assert any(math.isnan(v) for v in values) and math.inf in values and -math.inf in values
    assert 1e308 in values and 1e200 in values
