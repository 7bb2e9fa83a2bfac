"""The native FMI 3.0 Co-Simulation FMU (``fmi_version=3``), loaded and driven with fmpy.

It is the FMI 2.0 FMU's model file and generated data behind the FMI 3.0
framework (fmu_src/native/cosimulation.c, FMI_VERSION 3): its outputs must equal the FMI
2.0 FMU's to 1e-12 at every output time, in a sample-and-step host and in
fmpy's `simulate_fmu`; fmpy's validator must find nothing; misuse of the
state machine must be refused with fmi3Error and a logged message, never a
crash (each case runs in a subprocess); a serialized state must round-trip
and a flipped byte must be refused.

Run as a script (``python tests/test_fmi3.py misuse FMU``) this file is the
driver those subprocesses execute.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import zipfile
from ctypes import byref, c_bool, c_double, c_uint32, c_void_p
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi3 import FMU3Slave, fmi3IntermediateUpdateCallback, fmi3LogMessageCallback  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from fitter.core import load_model, simulate  # noqa: E402
from fitter.fmu.host import simulate_fmu as simulate_fmu2  # noqa: E402
from fitter.fmu.native import build_gain_fmu, build_native_fmu  # noqa: E402
from fitter.fmu.native_sources import GAIN_FILE, c_sources, model_data_header, source_files  # noqa: E402
from samples import sampled_input  # noqa: E402
from test_fmu_native import ALL_EFFECTS, rd_model, ri_model  # noqa: E402

U, Y = 0, 1
FMI3_ERROR = 3
MODELS = {
    "demo": lambda: load_model(REPO / "examples" / "demo_truth.json"),
    "rd_effects": lambda: rd_model(ALL_EFFECTS),
    "ri_held": lambda: ri_model().replace(input_range=(-0.9, 1.1)),
}


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    """name -> {2: FMI 2.0 FMU, 3: FMI 3.0 FMU} of the same model."""
    directory = tmp_path_factory.mktemp("fmi3")
    return {
        name: {v: build_native_fmu(make(), directory / f"{name}_{v}.fmu", fmi_version=v) for v in (2, 3)}
        for name, make in MODELS.items()
    }


def _demo_input() -> tuple[np.ndarray, np.ndarray]:
    data = np.loadtxt(REPO / "examples" / "demo.csv", delimiter=",", skiprows=1)
    return data[:, 0], data[:, 1]


def _input(name: str) -> tuple[np.ndarray, np.ndarray]:
    return _demo_input() if name == "demo" else sampled_input()


class Fmi3Host:
    """Sample-and-step through fmpy's `FMU3Slave`: set u(t_k), read y(t_k), step to t_{k+1}."""

    def __init__(self, fmu_path: str, messages: list[str] | None = None):
        self.md = read_model_description(fmu_path)
        self.unzipdir = extract(fmu_path)
        self.messages = messages if messages is not None else []
        self.fmu = FMU3Slave(
            guid=self.md.guid,
            unzipDirectory=self.unzipdir,
            modelIdentifier=self.md.coSimulation.modelIdentifier,
            instanceName="test",
        )
        self.fmu.instantiate(logMessage=self._log)
        self.t = 0.0

    def _log(self, env, status, category, message):
        self.messages.append(message.decode())

    def start(self, t0: float = 0.0) -> "Fmi3Host":
        self.fmu.enterInitializationMode(startTime=t0)
        self.fmu.exitInitializationMode()
        self.t = t0
        return self

    def run(self, t, u) -> np.ndarray:
        y = np.empty(len(u))
        for k in range(len(u)):
            self.fmu.setFloat64([U], [u[k]])
            y[k] = self.fmu.getFloat64([Y])[0]
            if k + 1 < len(u):
                self.fmu.doStep(t[k], t[k + 1] - t[k])
                self.t = t[k + 1]
        return y

    def free(self) -> None:
        self.fmu.freeInstance()
        shutil.rmtree(self.unzipdir, ignore_errors=True)


def _run3(fmu_path: str, t, u) -> np.ndarray:
    host = Fmi3Host(fmu_path).start(float(t[0]))
    try:
        return host.run(t, u)
    finally:
        host.fmu.terminate()
        host.free()


# --------------------------------------------------------------------- results


@pytest.mark.parametrize("name", MODELS)
def test_fmi3_output_equals_fmi2_in_a_sample_and_step_host(fmus, name):
    t, u = _input(name)
    y2 = simulate_fmu2(fmus[name][2], t, u)
    y3 = _run3(fmus[name][3], t, u)
    assert np.ptp(y2) > 0.1
    assert np.abs(y3 - y2).max() <= 1e-12
    reference = simulate(MODELS[name](), t, u).y
    assert np.abs(y3 - reference).max() <= 1e-10 * max(1.0, np.abs(reference).max())


@pytest.mark.parametrize("name", MODELS)
def test_fmi3_output_equals_fmi2_in_fmpy_simulate_fmu(fmus, name):
    t, u = _input(name)
    signal = np.array(list(zip(t, u)), dtype=[("time", np.float64), ("u", np.float64)])
    step = float(t[1] - t[0])
    runs = {
        v: simulate_fmu(
            fmus[name][v],
            start_time=float(t[0]),
            stop_time=float(t[-1]),
            output_interval=step,
            input=signal,
            output=["y"],
        )
        for v in (2, 3)
    }
    assert np.array_equal(runs[2]["time"], runs[3]["time"]) and len(runs[3]) >= len(t) - 1
    assert np.abs(runs[3]["y"] - runs[2]["y"]).max() <= 1e-12


@pytest.mark.parametrize("name", MODELS)
def test_validate_fmu_finds_nothing(fmus, name):
    assert validate_fmu(fmus[name][3]) == []


def test_model_description_carries_the_fmi2_metadata(fmus):
    md2, md3 = (read_model_description(fmus["demo"][v]) for v in (2, 3))
    assert md3.fmiVersion == "3.0" and md3.guid and md3.guid != md2.guid
    for attribute in ("modelName", "description", "generationTool", "version"):
        assert getattr(md3, attribute) == getattr(md2, attribute) or attribute == "description"
    assert "FMI 3.0 has no input derivatives" in md3.description
    exp2, exp3 = md2.defaultExperiment, md3.defaultExperiment
    assert (exp3.startTime, exp3.stopTime, exp3.stepSize) == (exp2.startTime, exp2.stopTime, exp2.stepSize)
    units = {u.name: u for u in md3.unitDefinitions}
    assert {"V", "um", "s"} <= set(units) and units["um"].baseUnit.m == 1
    variables = {v.name: v for v in md3.modelVariables}
    assert [(v.name, v.valueReference) for v in md2.modelVariables] == [
        (v.name, v.valueReference) for v in md3.modelVariables if v.name != "time"
    ]
    assert variables["time"].causality == "independent"
    assert variables["u"].unit == "V" and variables["y"].unit == "um"
    for structural in ("order", "kind"):
        assert variables[structural].variability == "constant"
        assert variables[structural].causality == "local"
    assert md3.coSimulation.canGetAndSetFMUstate and md3.coSimulation.canSerializeFMUstate


def test_fmu_is_a_python_free_source_fmu(fmus, tmp_path):
    path = fmus["rd_effects"][3]
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
        build = zf.read("sources/buildDescription.xml").decode()
    assert {
        "binaries/x86_64-linux/semilinear_duhem.so",
        "sources/fmi3.c",
        "sources/cosimulation.c",
        "sources/duhem_model.c",
        "sources/model_data.h",
        "sources/fmi3Functions.h",
    } <= names
    assert '<SourceFile name="fmi3.c" />' in build
    with zipfile.ZipFile(path) as zf:
        zf.extract("binaries/x86_64-linux/semilinear_duhem.so", tmp_path)
    library = tmp_path / "binaries" / "x86_64-linux" / "semilinear_duhem.so"
    deps = subprocess.run(["ldd", str(library)], capture_output=True, text=True, check=True).stdout
    assert "python" not in deps.lower()
    symbols = subprocess.run(
        ["nm", "-D", "--defined-only", str(library)], capture_output=True, text=True, check=True
    ).stdout.split()[2::3]
    assert len(symbols) == 75 and all(s.startswith("fmi3") for s in symbols), symbols


def test_fmi3_sources_compile_without_warnings(tmp_path):
    for name, path in (source_files(3) | source_files(3, GAIN_FILE)).items():
        shutil.copyfile(path, tmp_path / name)
    for model in (ri_model(ALL_EFFECTS), rd_model(), load_model(REPO / "examples" / "demo_truth.json")):
        (tmp_path / "model_data.h").write_text(model_data_header(model, "{guid}"))
        result = subprocess.run(
            ["cc", "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-c", *c_sources(3), GAIN_FILE],
            cwd=tmp_path,
            capture_output=True,
            text=True,
        )
        assert result.returncode == 0, result.stderr


def test_gain_fmu_of_fmi3_is_valid_and_computes_k_u(tmp_path):
    path = build_gain_fmu(tmp_path / "gain3.fmu", fmi_version=3)
    assert validate_fmu(path) == []
    t = np.linspace(0.0, 1.0, 11)
    assert np.allclose(_run3(path, t, np.sin(t)), 2.0 * np.sin(t), rtol=0, atol=1e-15)


# --------------------------------------------------------------------- FMU state


def test_serialized_state_round_trips_and_every_flipped_byte_is_refused(fmus):
    t, u = sampled_input(200)
    host = Fmi3Host(fmus["rd_effects"][3]).start()
    fmu, k = host.fmu, 80
    host.run(t[: k + 1], u[: k + 1])
    state = fmu.getFMUState()
    blob = bytes(fmu.serializeFMUState(state))
    first = host.run(t[k:], u[k:])
    restored = fmu.deserializeFMUState(blob)
    fmu.setFMUState(restored)
    assert np.array_equal(host.run(t[k:], u[k:]), first)
    messages_before = len(host.messages)
    for i in range(len(blob)):
        corrupt = bytearray(blob)
        corrupt[i] ^= 0x10
        with pytest.raises(FMICallException):
            fmu.deserializeFMUState(bytes(corrupt))
    assert len(host.messages) - messages_before == len(blob)
    assert all("refused" in m for m in host.messages[messages_before:])
    with pytest.raises(FMICallException):
        fmu.deserializeFMUState(blob[:-1])
    for s in (state, restored):
        fmu.freeFMUState(s)
    host.free()


# --------------------------------------------------------------------- misuse

MISUSE_EXPECTED = {
    "doStep before initialization": "not allowed in state Instantiated",
    "setFloat64 of the output": "an output cannot be set",
    "setFloat64 of time": "the independent variable cannot be set",
    "setFloat64 NaN input": "not finite",
    "setFloat64 infinite parameter": "not finite",
    "setFloat64 parameter while stepping": "can only be set before",
    "setInt32 order": "structural",
    "setString kind": "structural",
    "getFloat64 unknown reference": "unknown value reference",
    "getFloat64 nValues mismatch": "nValues = 2 but nValueReferences = 1",
    "getFloat32 of any reference": "no variables of this type",
    "doStep zero step": "must be positive and finite",
    "doStep negative step": "must be positive and finite",
    "doStep NaN step": "must be positive and finite",
    "doStep wrong time": "is not the FMU's time",
    "doStep NULL out-argument": "is NULL",
    "enterEventMode": "no event mode",
    "enterConfigurationMode": "no structural parameters",
    "getOutputDerivatives": "maxOutputDerivativeOrder = 0",
    "getDirectionalDerivative": "not provided",
    "setFMUState of garbage": "was not made by fmi3GetFMUState",
    "exitInitializationMode while stepping": "not allowed in state StepMode",
    "doStep after terminate": "not allowed in state Terminated",
    "setFloat64 after terminate": "not allowed in state Terminated",
}
INSTANTIATION_EXPECTED = {
    "wrong token": "instantiationToken does not match",
    "empty name": "non-empty string",
    "event mode used": "no event mode",
    "model exchange": "Co-Simulation only",
}


def _misuse(fmu_path: str) -> dict:
    """Run every misuse case on one instance; case -> (status, last message), plus the output
    of a regular run afterwards (the refused calls must have changed nothing)."""
    messages: list[str] = []
    host = Fmi3Host(fmu_path, messages)
    fmu, c = host.fmu, host.fmu.component
    vr = (c_uint32 * 1)(U)
    flags = [c_bool(), c_bool(), c_bool()]
    last = c_double()
    cases = {}

    def case(name, call, *args):
        before = len(messages)
        try:
            call(*args)
            status = 0
        except FMICallException as exc:
            status = exc.status
        cases[name] = (status, messages[-1] if len(messages) > before else "")

    def step(h, t=None, out_args=True):
        pointers = (*map(byref, flags), byref(last)) if out_args else (None,) * 4
        fmu.fmi3DoStep(c, host.t if t is None else t, h, True, *pointers)

    case("doStep before initialization", step, 0.1)
    case("setFloat64 of the output", fmu.setFloat64, [Y], [1.0])
    fmu.enterInitializationMode(startTime=0.0)
    case("setFloat64 infinite parameter", fmu.setFloat64, [4], [math.inf])
    fmu.exitInitializationMode()
    case("setFloat64 of time", fmu.setFloat64, [len(host.md.modelVariables) - 1], [1.0])
    case("setFloat64 NaN input", fmu.setFloat64, [U], [math.nan])
    case("setInt32 order", fmu.setInt32, [2], [7])
    case("setString kind", fmu.setString, [3], ["xx"])
    case("getFloat64 unknown reference", fmu.getFloat64, [10_000])
    case("getFloat64 nValues mismatch", fmu.fmi3GetFloat64, c, vr, 1, (c_double * 2)(), 2)
    case("getFloat32 of any reference", fmu.getFloat32, [U])
    case("setFloat64 parameter while stepping", fmu.setFloat64, [4], [0.5])
    case("doStep zero step", step, 0.0)
    case("doStep negative step", step, -0.1)
    case("doStep NaN step", step, math.nan)
    case("doStep wrong time", step, 0.1, 5.0)
    case("doStep NULL out-argument", step, 0.1, None, False)
    case("enterEventMode", fmu.enterEventMode)
    case("enterConfigurationMode", fmu.fmi3EnterConfigurationMode, c)
    case("getOutputDerivatives", fmu.getOutputDerivatives, [Y], [1])
    case(
        "getDirectionalDerivative",
        fmu.fmi3GetDirectionalDerivative,
        c,
        vr,
        1,
        vr,
        1,
        (c_double * 1)(1.0),
        1,
        (c_double * 1)(),
        1,
    )
    case("setFMUState of garbage", fmu.fmi3SetFMUState, c, c_void_p(id(messages)))
    case("exitInitializationMode while stepping", fmu.exitInitializationMode)
    t, u = sampled_input(60)
    y = host.run(t, u)
    fmu.terminate()
    case("doStep after terminate", step, 0.1)
    case("setFloat64 after terminate", fmu.setFloat64, [U], [0.0])
    fmu.fmi3FreeInstance(None)
    host.free()
    return {"cases": cases, "y": list(y), "instantiation": _misuse_instantiation(fmu_path)}


def _misuse_instantiation(fmu_path: str) -> dict:
    """Instantiation arguments that must be refused: NULL instance and a logged message."""
    md = read_model_description(fmu_path)
    unzipdir = extract(fmu_path)
    fmu = FMU3Slave(
        guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier, instanceName="test"
    )
    results, messages = {}, []
    callback = fmi3LogMessageCallback(lambda env, status, category, message: messages.append(message.decode()))
    none = (c_uint32 * 0)()
    for name, token, instance, event_mode in (
        ("wrong token", b"{x}", b"a", False),
        ("empty name", md.guid.encode(), b"", False),
        ("event mode used", md.guid.encode(), b"a", True),
    ):
        handle = fmu.fmi3InstantiateCoSimulation(
            instance,
            token,
            b"",
            False,
            False,
            event_mode,
            False,
            none,
            0,
            None,
            callback,
            fmi3IntermediateUpdateCallback(),
        )
        results[name] = (handle is None, messages[-1] if messages else "")
    handle = fmu.fmi3InstantiateCoSimulation(
        b"a",
        md.guid.encode(),
        b"",
        False,
        False,
        False,
        False,
        (c_uint32 * 1)(Y),
        1,
        None,
        callback,
        fmi3IntermediateUpdateCallback(),
    )
    results["intermediate variables listed"] = (handle is None, messages[-1] if messages else "")
    if handle is not None:
        fmu.fmi3FreeInstance(handle)
    handle = fmu.fmi3InstantiateModelExchange(b"a", md.guid.encode(), b"", False, False, None, callback)
    results["model exchange"] = (handle is None, messages[-1])
    shutil.rmtree(unzipdir, ignore_errors=True)
    return results


def test_state_machine_misuse_is_refused_and_changes_nothing(fmus):
    path = fmus["rd_effects"][3]
    result = subprocess.run([sys.executable, __file__, "misuse", path], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads(result.stdout)
    for name, fragment in MISUSE_EXPECTED.items():
        status, message = report["cases"][name]
        assert status == FMI3_ERROR and fragment in message, (name, status, message)
    for name, fragment in INSTANTIATION_EXPECTED.items():
        refused, message = report["instantiation"][name]
        assert refused and fragment in message, (name, message)
    assert not report["instantiation"]["intermediate variables listed"][0]  # ignored, as the Reference-FMUs do
    t, u = sampled_input(60)
    assert np.abs(np.array(report["y"]) - simulate(MODELS["rd_effects"](), t, u).y).max() <= 1e-10


# --------------------------------------------------------------------- export


def test_cli_exports_fmi3_and_refuses_it_for_the_python_backend(tmp_path):
    from click.testing import CliRunner

    from fitter.cli import main

    model = str(REPO / "examples" / "demo_truth.json")
    runner = CliRunner()
    result = runner.invoke(main, ["export", model, "-o", str(tmp_path / "m.fmu"), "--fmi-version", "3", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["fmi_version"] == "3.0"
    assert read_model_description(str(tmp_path / "m.fmu")).fmiVersion == "3.0"
    result = runner.invoke(
        main, ["export", model, "-o", str(tmp_path / "p.fmu"), "--fmi-version", "3", "--backend", "python"]
    )
    assert result.exit_code == 1
    assert "FMI 3.0 export needs --backend native" in result.output
    assert not (tmp_path / "p.fmu").exists()


def test_fit_and_diagnose_write_fmi3_when_asked(tmp_path):
    """`--fmi-version` wherever an FMU is written: `duhem fit --fmu` and `duhem diagnose --fmu` write FMI 3.0 with
    it, and refuse it for the python backend before fitting (nothing written)."""
    from click.testing import CliRunner

    from fitter.cli import main

    demo = str(REPO / "examples" / "demo.csv")
    runner = CliRunner()
    fit = ["fit", demo, "-o", str(tmp_path / "m.json"), "--kind", "ri", "--order", "1", "--fmi-version", "3"]
    result = runner.invoke(main, [*fit, "--fmu", str(tmp_path / "m.fmu")])
    assert result.exit_code == 0, result.output
    assert read_model_description(str(tmp_path / "m.fmu")).fmiVersion == "3.0"
    result = runner.invoke(main, [*fit, "--fmu", str(tmp_path / "p.fmu"), "--backend", "python"])
    assert result.exit_code == 1 and "FMI 3.0 export needs --backend native" in result.output
    result = runner.invoke(
        main,
        ["diagnose", demo, "--base-order", "1", "--candidates", "viscous", "--fmu", str(tmp_path / "d.fmu")]
        + ["--fmi-version", "3"],
    )
    assert result.exit_code == 0, result.output
    assert read_model_description(str(tmp_path / "d.fmu")).fmiVersion == "3.0"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.fmu", "m.fmu", "m.json"]


def test_build_fmu_script_and_api_take_the_fmi_version(tmp_path):
    import build_fmu

    from fitter.fmu.build import FmuBuildError

    model = str(REPO / "examples" / "demo_truth.json")
    assert build_fmu.main([model, "-o", str(tmp_path / "s.fmu"), "--fmi-version", "3"]) == 0
    assert read_model_description(str(tmp_path / "s.fmu")).fmiVersion == "3.0"
    with pytest.raises(FmuBuildError, match="needs --backend native"):
        build_fmu.build_fmu(model, tmp_path / "p.fmu", backend="python", fmi_version=3)
    with pytest.raises(ValueError, match="unknown FMI version"):
        build_native_fmu(load_model(model), tmp_path / "x.fmu", fmi_version=4)


if __name__ == "__main__":
    if sys.argv[1:2] == ["misuse"]:
        print(json.dumps(_misuse(sys.argv[2])))
    else:
        sys.exit("usage: test_fmi3.py misuse FMU")
