"""The compensator FMU (`duhem export --inverse`): `fitter.core.inverse.Compensator` as an FMI 2.0 / 3.0 slave.

Run as a script (``python tests/test_fmu_compensator.py misuse FMU``) this file is the driver that the
sanitized-build test runs in a subprocess (so a crash fails the test instead of killing pytest).

Checked with fmpy: the FMU's u equals `Compensator.run` (native 1e-10, python 1e-12); the cascade compensator
FMU -> plant FMU tracks y_ref within 1e-6 of its range, both in one co-simulation loop (set y_ref(t_k), read
u(t_k), set the plant's u, read y(t_k), step both) and as two runs of the standard host loop with input
derivatives (fmpy's simulate_fmu loop: set the input and its slope, step, record after the step); in fmusim's
loop (set y_ref(t_k), step, read u before the next y_ref) u read after the step is the sample's u on a backlash model
(native FMI 2.0 and 3.0, python); FMI 3.0 gives the FMI 2.0 numbers; `fmpy.validation.validate_fmu` finds nothing;
misuse (NaN y_ref, a step after terminate, a corrupt state) is an error status with a logged reason, never a crash;
rollback and serialized state replay exactly.  Models: the monotone test models of test_inverse.py (rate independent,
rate dependent, with effects).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from ctypes import c_double, c_int, c_uint
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

from fitter.fmu.host import collecting_callbacks

FMI2_DISCARD, FMI2_ERROR = 2, 3
REPO = Path(__file__).resolve().parents[1]


class Slave:
    """An FMU2Slave instance with its log; variables by name."""

    def __init__(self, path: str, start: float = 0.0, unzipped: tuple | None = None):
        self._owned = unzipped is None
        self.md, self.unzipdir = unzipped or (read_model_description(path), extract(path))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.fmu = FMU2Slave(
            guid=self.md.guid,
            unzipDirectory=self.unzipdir,
            modelIdentifier=self.md.coSimulation.modelIdentifier,
            instanceName="c",
        )
        self.log: list[str] = []
        self._callbacks = collecting_callbacks(self.log)
        self.fmu.instantiate(callbacks=self._callbacks, loggingOn=True)
        self.fmu.setupExperiment(startTime=start)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        self.t = start

    def set(self, name, value):
        self.fmu.setReal([self.vr[name]], [float(value)])

    def get(self, name):
        return self.fmu.getReal([self.vr[name]])[0]

    def step(self, h):
        self.fmu.doStep(currentCommunicationPoint=self.t, communicationStepSize=h)
        self.t += h

    def derivative(self, name, value):
        self.fmu.fmi2SetRealInputDerivatives(
            self.fmu.component, (c_uint * 1)(self.vr[name]), 1, (c_int * 1)(1), (c_double * 1)(value)
        )

    def free(self):
        self.fmu.terminate()
        self.fmu.freeInstance()
        if self._owned:
            shutil.rmtree(self.unzipdir, ignore_errors=True)


def _misuse(path: str, sequences: int) -> None:
    rng = np.random.default_rng(11)
    statuses = set()
    foreign = b"\x00" * 16
    unzipped = (read_model_description(path), extract(path))
    for _ in range(sequences):
        s = Slave(path, unzipped=unzipped)
        states = []
        for _ in range(40):
            op = rng.integers(9)
            try:
                if op == 0:
                    s.set("y_ref", rng.choice([rng.normal(3.0, 4.0), np.nan, np.inf, -1e300, 1e6]))
                elif op in (1, 2):
                    s.get("u")
                elif op == 3:
                    h = rng.choice([0.01, 0.1, -0.1, 0.0, np.nan, 1e300])
                    s.fmu.doStep(currentCommunicationPoint=s.t + rng.choice([0.0, 0.0, 1.0]), communicationStepSize=h)
                    s.t += h
                elif op == 4:
                    states.append(s.fmu.getFMUstate())
                elif op == 5 and states:
                    s.fmu.setFMUstate(states[int(rng.integers(len(states)))])
                elif op == 6 and states:
                    blob = bytearray(s.fmu.serializeFMUstate(states[-1]))
                    if rng.random() < 0.5:
                        blob[int(rng.integers(len(blob)))] ^= 0xFF
                    s.fmu.setFMUstate(s.fmu.deSerializeFMUstate(bytes(blob)))
                elif op == 7:
                    s.fmu.deSerializeFMUstate(foreign)
                elif op == 8:
                    s.derivative("y_ref", rng.choice([0.5, np.nan, -2.0]))
                statuses.add(0)
            except FMICallException as exc:
                assert exc.status == FMI2_ERROR, exc.status
                statuses.add(exc.status)
        for state in states:
            s.fmu.freeFMUstate(state)
        s.free()
    shutil.rmtree(unzipped[1], ignore_errors=True)
    print(f"misuse: {sequences} sequences, statuses {sorted(statuses)}")


if __name__ == "__main__":  # the misuse driver: numpy and fmpy only (matplotlib breaks under ASan)
    _misuse(sys.argv[2], int(sys.argv[3]))
    sys.exit(0)

import pytest  # noqa: E402
from click.testing import CliRunner  # noqa: E402
from fmpy.fmi3 import FMU3Slave  # noqa: E402
from test_inverse import rd1, reversals, ri2  # noqa: E402

from fitter.cli import main  # noqa: E402
from fitter.core import Compensator, InverseError, save_model, simulate  # noqa: E402
from fitter.core.effects import Effect  # noqa: E402
from fitter.core.models import Signal, Signals  # noqa: E402
from fitter.fmu.build import build_fmu  # noqa: E402
from fitter.fmu.host import validate_fmu_file  # noqa: E402

TOL = {"native": 1e-10, "python": 1e-12}


def effects_model():
    return ri2(
        [
            Effect("backlash", {"b": 0.3}),
            Effect("creep", {"k": 0.1, "tau": 0.4}),
            Effect("saturation", {"y_c": 4.0, "beta": 0.05}),
        ]
    )


def named(model):
    return model.replace(
        signals=Signals(Signal("voltage", "V", "drive voltage"), Signal("displacement", "um", "stack displacement"))
    )


MODELS = {"ri2": lambda: named(ri2()), "rd1": rd1, "effects": effects_model}
KINDS = [("ri2", "native"), ("rd1", "native"), ("effects", "native"), ("ri2", "python"), ("effects", "python")]


def reference(name: str, n: int = 161, span: float = 4.0):
    """A reference the plant reaches (its response to seeded random reversals: minor loops in major ones)."""
    t = np.linspace(0.0, span, n)
    u = reversals(5, per=int(np.ceil(n / 12)))[:n]
    return t, simulate(MODELS[name](), t, u).y


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    """(name, backend, fmi_version) -> compensator FMU; (name, backend, "plant") -> the model's FMU."""
    d = tmp_path_factory.mktemp("compensator")
    out = {}
    for name, backend in KINDS:
        out[name, backend, 2] = build_fmu(
            MODELS[name](), d / f"{name}_{backend}_comp.fmu", backend=backend, inverse=True
        )
        out[name, backend, "plant"] = build_fmu(MODELS[name](), d / f"{name}_{backend}.fmu", backend=backend)
    for name in ("ri2", "effects"):
        out[name, "native", 3] = build_fmu(
            MODELS[name](), d / f"{name}_native3_comp.fmu", backend="native", inverse=True, fmi_version=3
        )
    return out


def compensate_fmu(path: str, t, y_ref) -> np.ndarray:
    """Sample and step: set y_ref(t_k), read u(t_k), step to t_k+1."""
    comp = Slave(path, float(t[0]))
    u = np.empty(len(t))
    for k in range(len(t)):
        comp.set("y_ref", y_ref[k])
        u[k] = comp.get("u")
        if k + 1 < len(t):
            comp.step(t[k + 1] - t[k])
    comp.free()
    return u


def standard_host(path: str, t, x, inp: str, out: str) -> np.ndarray:
    """The loop of fmpy's simulate_fmu with set_input_derivatives=True: set x(t_k) and (x_k+1 - x_k) / h, step,
    record the output at t_k+1 (fmpy 0.3.32's own set_input_derivatives fails for a single input)."""
    s = Slave(path, float(t[0]))
    s.set(inp, x[0])
    y = np.empty(len(t))
    y[0] = s.get(out)
    for k in range(len(t) - 1):
        h = t[k + 1] - t[k]
        s.set(inp, x[k])
        s.derivative(inp, (x[k + 1] - x[k]) / h)
        s.step(h)
        y[k + 1] = s.get(out)
    s.free()
    return y


# ----------------------------------------------------------------------------- numbers


@pytest.mark.parametrize("name,backend", KINDS)
def test_fmu_output_equals_compensator_run(fmus, name, backend):
    t, y_ref = reference(name)
    u = compensate_fmu(fmus[name, backend, 2], t, y_ref)
    ref = Compensator(MODELS[name](), t0=float(t[0])).run(t, y_ref)
    assert ref.n_clamped == 0 and np.ptp(ref.u) > 1.0
    assert np.abs(u - ref.u).max() <= TOL[backend] * max(1.0, np.abs(ref.u).max())


@pytest.mark.parametrize("backend", ["native", "python"])
def test_unreachable_reference_is_clamped_as_in_python(fmus, backend):
    """A sine of the output far beyond the reachable range: u stays in the input range, equals the clamped
    `Compensator.run`, never NaN."""
    t = np.linspace(0.0, 3.0, 61)
    y_ref = 2.0 + 40.0 * np.sin(2 * np.pi * t / 1.5)
    u = compensate_fmu(fmus["ri2", backend, 2], t, y_ref)
    ref = Compensator(MODELS["ri2"]()).run(t, y_ref)
    assert ref.n_clamped > 20 and np.all(np.isfinite(u)) and u.min() >= -3.0 and u.max() <= 5.0
    assert np.abs(u - ref.u).max() <= TOL[backend] * 5.0


@pytest.mark.parametrize("name,backend", KINDS)
def test_cascade_of_compensator_and_plant_fmus_tracks_the_reference(fmus, name, backend):
    """One co-simulation loop: set y_ref(t_k) on the compensator, read u(t_k), set it on the plant FMU, read
    y(t_k), step both."""
    t, y_ref = reference(name)
    comp, plant = Slave(fmus[name, backend, 2], 0.0), Slave(fmus[name, backend, "plant"], 0.0)
    y = np.empty(len(t))
    for k in range(len(t)):
        comp.set("y_ref", y_ref[k])
        plant.set("u", comp.get("u"))
        y[k] = plant.get("y")
        if k + 1 < len(t):
            comp.step(t[k + 1] - t[k])
            plant.step(t[k + 1] - t[k])
    comp.free()
    plant.free()
    assert np.abs(y - y_ref).max() <= 1e-6 * np.ptp(y_ref)


def test_cascade_in_the_standard_host_loop_with_input_derivatives(fmus):
    """simulate_fmu's loop (input and slope set, step, record after it) for the compensator, then for the plant:
    with dy_ref/dt the compensator's u at t_k+1 reaches y_ref(t_k+1), so the plant follows y_ref."""
    t, y_ref = reference("rd1")
    md = read_model_description(fmus["rd1", "native", 2])
    assert md.coSimulation.canInterpolateInputs
    u = standard_host(fmus["rd1", "native", 2], t, y_ref, "y_ref", "u")
    assert np.abs(u - Compensator(rd1()).run(t, y_ref).u).max() <= 1e-10 * max(1.0, np.abs(u).max())
    y = standard_host(fmus["rd1", "native", "plant"], t, u, "u", "y")
    assert np.abs(y - y_ref).max() <= 1e-6 * np.ptp(y_ref)


@pytest.mark.parametrize("name", ["ri2", "effects"])
def test_fmi3_compensator_gives_the_fmi2_numbers(fmus, name):
    t, y_ref = reference(name)
    u2 = compensate_fmu(fmus[name, "native", 2], t, y_ref)
    md = read_model_description(fmus[name, "native", 3])
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unzipdir = extract(fmus[name, "native", 3])
    fmu = FMU3Slave(
        guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier, instanceName="c3"
    )
    fmu.instantiate()
    fmu.enterInitializationMode(startTime=0.0)
    fmu.exitInitializationMode()
    u3 = np.empty(len(t))
    for k in range(len(t)):
        fmu.setFloat64([vr["y_ref"]], [y_ref[k]])
        u3[k] = fmu.getFloat64([vr["u"]])[0]
        if k + 1 < len(t):
            fmu.doStep(t[k], t[k + 1] - t[k])
    fmu.terminate()
    fmu.freeInstance()
    shutil.rmtree(unzipdir, ignore_errors=True)
    assert np.abs(u3 - u2).max() <= 1e-12 * max(1.0, np.abs(u2).max())


def fmusim_order(path: str, version: int, t, y_ref) -> np.ndarray:
    """The loop of fmusim (Reference-FMUs): set y_ref(t_k), step from t_k, read u at t_k+1 before y_ref(t_k+1) is
    set, so that u is solved again at t_k+1 for the unchanged y_ref(t_k).  Returns those reads, u after step k."""
    if version == 2:
        s = Slave(path, float(t[0]))
        put, get, step, free = (lambda v: s.set("y_ref", v)), (lambda: s.get("u")), s.step, s.free
    else:
        md = read_model_description(path)
        vr = {v.name: v.valueReference for v in md.modelVariables}
        unzipdir = extract(path)
        fmu = FMU3Slave(
            guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier, instanceName="c3"
        )
        fmu.instantiate()
        fmu.enterInitializationMode(startTime=float(t[0]))
        fmu.exitInitializationMode()
        now = [float(t[0])]

        def put(v):
            fmu.setFloat64([vr["y_ref"]], [v])

        def get():
            return fmu.getFloat64([vr["u"]])[0]

        def step(h):
            fmu.doStep(now[0], h)
            now[0] += h

        def free():
            fmu.terminate()
            fmu.freeInstance()
            shutil.rmtree(unzipdir, ignore_errors=True)

    after = np.empty(len(t) - 1)
    for k in range(len(t) - 1):
        put(y_ref[k])
        step(t[k + 1] - t[k])
        after[k] = get()
    free()
    return after


def test_u_read_after_the_step_keeps_the_held_input_in_fmusim_order(tmp_path):
    """Continuity (fitter.core.inverse, "Which root"): read after the step with y_ref unchanged, u is the sample's
    own u, not the other root across backlash's dead band (fmusim found 605 of 2400 samples off by exactly b on
    the fitted demo model).  Rate independent with backlash: the held input gives the same output at t_k+1."""
    model = named(ri2([Effect("backlash", {"b": 0.3})]))
    t = np.linspace(0.0, 4.0, 161)
    y_ref = simulate(model, t, reversals(5, per=14)[: len(t)]).y
    ref = Compensator(model, t0=0.0).run(t, y_ref)
    assert ref.n_clamped == 0
    for backend, version in (("native", 2), ("native", 3), ("python", 2)):
        path = build_fmu(
            model, tmp_path / f"backlash_{backend}{version}.fmu", backend=backend, inverse=True, fmi_version=version
        )
        after = fmusim_order(path, version, t, y_ref)
        assert np.abs(after - ref.u[:-1]).max() <= 1e-9 * max(1.0, np.abs(ref.u).max()), (backend, version)


# ----------------------------------------------------------------------------- description


def test_validate_fmu_finds_nothing(fmus):
    for key, path in fmus.items():
        assert validate_fmu_file(path) == [], key


@pytest.mark.parametrize("backend,version", [("native", 2), ("python", 2), ("native", 3)])
def test_metadata_names_the_compensator_and_turns_the_signals_round(fmus, backend, version):
    md = read_model_description(fmus["ri2", backend, version])
    assert md.modelName == "compensator (inverse of the semilinear Duhem RI model, order 2)"
    assert md.description.startswith("Feedforward hysteresis compensator") and "[-3, 5]" in md.description
    assert md.coSimulation.modelIdentifier == "duhem_compensator"
    var = {v.name: v for v in md.modelVariables}
    assert (var["u"].causality, var["u"].unit, var["u"].valueReference) == ("output", "V", 0)
    assert (var["y_ref"].causality, var["y_ref"].unit, var["y_ref"].valueReference) == ("input", "um", 1)
    assert "column 'displacement'" in var["y_ref"].description and "column 'voltage'" in var["u"].description
    # an unset reference keeps u in the middle of the range, exactly (the start is the plant's output there)
    assert float(var["y_ref"].start) == float(simulate(MODELS["ri2"](), [0.0], [1.0]).y[0])
    assert "A_plus[1,1]" in var and var["A_plus[1,1]"].causality == "parameter"
    if version == 2:
        assert md.outputs[0].variable.name == "u" and [d.name for d in md.outputs[0].dependencies] == ["y_ref"]


# ----------------------------------------------------------------------------- misuse and state


def test_native_misuse_is_an_error_status_and_changes_nothing(fmus):
    comp = Slave(fmus["effects", "native", 2])
    comp.set("y_ref", 1.0)
    comp.step(0.05)
    comp.set("y_ref", 1.2)
    u = comp.get("u")
    for call, why in (
        (lambda: comp.set("y_ref", float("nan")), "not finite"),
        (lambda: comp.set("u", 0.3), "an output cannot be set"),
        (lambda: comp.derivative("y_ref", float("inf")), "not finite"),
        (lambda: comp.fmu.doStep(currentCommunicationPoint=comp.t, communicationStepSize=-0.1), ""),
        (lambda: comp.fmu.deSerializeFMUstate(b"\x00" * 64), ""),
    ):
        with pytest.raises(FMICallException) as exc:
            call()
        assert exc.value.status == FMI2_ERROR and why in comp.log[-1]
    assert comp.get("u") == u and comp.get("y_ref") == 1.2
    comp.fmu.terminate()
    with pytest.raises(FMICallException) as exc:
        comp.fmu.doStep(currentCommunicationPoint=comp.t, communicationStepSize=0.1)
    assert exc.value.status == FMI2_ERROR
    comp.fmu.freeInstance()


def test_python_misuse_is_an_error_status_with_its_reason(fmus):
    """A step after terminate or a bad step: fmi2Discard, the state kept; a NaN y_ref or a foreign state:
    pythonfmu's fmi2Fatal (the only status its setters have) with the reason logged, no crash."""
    comp = Slave(fmus["ri2", "python", 2])
    comp.set("y_ref", 1.0)
    u = comp.get("u")
    with pytest.raises(FMICallException) as exc:
        comp.fmu.doStep(currentCommunicationPoint=comp.t, communicationStepSize=-0.1)
    assert exc.value.status == FMI2_DISCARD and "positive and finite" in comp.log[-1]
    assert comp.get("u") == u
    comp.fmu.terminate()
    with pytest.raises(FMICallException) as exc:
        comp.fmu.doStep(currentCommunicationPoint=comp.t, communicationStepSize=0.1)
    assert exc.value.status == FMI2_DISCARD and "after fmi2Terminate" in comp.log[-1]
    comp.fmu.freeInstance()
    for bad, why in (
        (lambda s: s.set("y_ref", float("nan")), "is not finite"),
        (
            lambda s: s.fmu.setFMUstate(s.fmu.deSerializeFMUstate(json.dumps({"x": 1}).encode())),
            "not a state of this FMU",
        ),
    ):
        s = Slave(fmus["ri2", "python", 2])
        with pytest.raises(FMICallException) as exc:
            bad(s)
        assert exc.value.status >= FMI2_ERROR and any(why in line for line in s.log)
        # after fmi2Fatal no call is allowed, not even fmi2FreeInstance (FMI 2.0, 4.2.2)


@pytest.mark.parametrize("backend", ["native", "python"])
def test_rollback_and_serialized_state_replay_exactly(fmus, backend):
    t, y_ref = reference("effects", n=61)
    k = 25
    comp = Slave(fmus["effects", backend, 2])
    runs = []

    def run_from(j):
        out = []
        for i in range(j, len(t)):
            comp.set("y_ref", y_ref[i])
            out.append(comp.get("u"))
            if i + 1 < len(t):
                comp.step(t[i + 1] - t[i])
        return np.array(out)

    first = run_from(0)
    comp.free()
    comp = Slave(fmus["effects", backend, 2])
    for i in range(k):
        comp.set("y_ref", y_ref[i])
        comp.step(t[i + 1] - t[i])
    state = comp.fmu.getFMUstate()
    blob = comp.fmu.serializeFMUstate(state)
    runs.append(run_from(k))
    for saved in (state, comp.fmu.deSerializeFMUstate(blob)):
        comp.fmu.setFMUstate(saved)
        comp.t = t[k]
        runs.append(run_from(k))
        comp.fmu.freeFMUstate(saved)
    comp.free()
    for run in runs:
        assert np.array_equal(run, first[k:])


def test_compensator_source_compiles_without_warnings(tmp_path):
    from fitter.fmu.variables import reference_start
    from fitter.fmu.native_sources import COMPENSATOR_FILE, c_sources, compensator_data_header, source_files

    for name, path in source_files(2, COMPENSATOR_FILE).items():
        shutil.copyfile(path, tmp_path / name)
    for model in (rd1(), effects_model()):
        (tmp_path / "model_data.h").write_text(compensator_data_header(model, "{guid}", reference_start(model)))
        result = subprocess.run(
            ["cc", "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-c", *c_sources(2, COMPENSATOR_FILE)],
            cwd=tmp_path,
            capture_output=True,
            text=True,
        )
        assert result.returncode == 0, result.stderr


# ----------------------------------------------------------------------------- build and CLI


def test_models_the_compensator_cannot_serve_are_refused(tmp_path):
    with pytest.raises(InverseError, match="input range"):
        build_fmu(ri2().replace(input_range=None), tmp_path / "c.fmu", inverse=True)
    lagged = ri2([Effect("sensor_lag", {"tau": 0.05})])
    with pytest.raises(InverseError, match="measurement"):
        build_fmu(lagged, tmp_path / "c.fmu", inverse=True)
    assert not list(tmp_path.iterdir())


def test_export_inverse_command(tmp_path):
    model = tmp_path / "model.json"
    save_model(ri2([Effect("sensor_lag", {"tau": 0.05})]), model)
    runner = CliRunner()
    out = tmp_path / "comp.fmu"
    result = runner.invoke(main, ["export", str(model), "--inverse", "-o", str(out), "--backend", "python"])
    assert result.exit_code != 0 and "--measurement drop" in result.output and not out.exists()
    result = runner.invoke(
        main,
        ["export", str(model), "--inverse", "--measurement", "drop", "-o", str(out), "--backend", "python", "--json"],
    )
    assert result.exit_code == 0, result.output
    info = json.loads(result.stdout)
    assert info["inverse"] is True and info["backend"] == "python"
    md = read_model_description(str(out))
    assert md.modelName.startswith("compensator (inverse of") and "sensor_lag" not in md.description
    result = runner.invoke(main, ["export", str(model), "--measurement", "drop", "-o", str(out)])
    assert result.exit_code != 0 and "add --inverse" in result.output


# ----------------------------------------------------------------------------- sanitized build, random misuse


def test_sanitized_compensator_survives_random_misuse(tmp_path):
    """AddressSanitizer and UBSan build of the native compensator, driven in a subprocess by `_misuse`: random
    call sequences (NaN, infinite and unreachable references, bad and mistimed steps, corrupt and foreign
    states, calls after terminate); every call returns OK or an error status, the process never crashes."""
    from fitter.fmu.native import build_native_compensator

    runtime = subprocess.run(["cc", "-print-file-name=libasan.so"], capture_output=True, text=True).stdout.strip()
    if not os.path.isabs(runtime):
        pytest.skip("the C compiler ships no AddressSanitizer runtime")
    path = build_native_compensator(effects_model(), tmp_path / "comp.fmu", sanitize=True)
    env = {
        **os.environ,
        "PYTHONPATH": str(REPO),
        "LD_PRELOAD": runtime,
        "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=1",
        "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1",
    }
    result = subprocess.run(
        [sys.executable, __file__, "misuse", str(path), "60"],
        capture_output=True,
        text=True,
        env=env,
        cwd=REPO,
        timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "misuse: 60 sequences" in result.stdout
    assert "AddressSanitizer" not in result.stderr and "runtime error" not in result.stderr
