"""The pythonfmu FMI 2.0 Co-Simulation export, loaded and driven with fmpy.

Models are built directly: the paper's Example 1 (rate independent), an
Example-3-like rate-dependent model with a tabulated g, the true model of a
noisy generated recording (order 3, with E and D), and Example 1 with effect
extensions.  FMUs are built once per module.
"""
import json
import sys
import zipfile
from xml.etree import ElementTree as ET

import numpy as np
import pytest
from fmu_host import Instance as FmuInstance, unzip_all
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

import build_fmu
from fitter.core import (Experiment, RateDependentModel, RateIndependentModel, Signal, Signals,
                         TabulatedRate, model_from_dict, save_model, simulate)
from fitter.fmu.host import collecting_callbacks, simulate_fmu, validate_fmu_file
from fitter.fmu.model_description import model_description_xml, model_variables

A1 = np.array([[-1.0, 4.0], [-4.0, -1.0]])
B1 = np.array([0.0, 1.0])


def example1():
    return RateIndependentModel(A_plus=A1.copy(), A_minus=-A1, B_plus=B1.copy(), B_minus=-B1, C=[0, 1],
                                x0=[0.15, 0.15], experiment=Experiment(0.0, 40.0, 0.02))


def g3(v):
    v = np.asarray(v, dtype=float)
    return np.where(v >= 0, (v / 3 - 1) ** 3 + 1, 1 - np.exp(v))


def example3():
    nodes = np.geomspace(0.05, 6.0, 10)
    g = TabulatedRate.from_function(g3, np.r_[-nodes[::-1], nodes])
    return RateDependentModel(A=[[0, 1], [-3, -1]], B=[1, 0], C=[1, 1], g=g, x0=[0.1, -0.2],
                              D=0.05)


def noisy_truth():
    A_p = np.array([[-2.0, 1.0, 0.0], [-1.0, -2.0, 0.5], [0.0, -0.5, -1.0]])
    A_m = np.array([[-1.5, -1.0, 0.2], [1.0, -1.5, 0.0], [0.0, 0.3, -2.0]])
    return RateIndependentModel(
        A_plus=A_p, A_minus=A_m, B_plus=[1.0, 0.5, -0.2], B_minus=[0.8, -0.4, 0.3],
        E_plus=[0.1, 0.0, -0.05], E_minus=[-0.1, 0.02, 0.0], C=[1.0, -0.5, 0.25], D=0.4,
        x0=[0.2, -0.1, 0.05],
        signals=Signals(Signal("V_in", "V", "piezo drive voltage"),
                        Signal("disp", "um", "stage displacement")),
        experiment=Experiment(0.0, 12.0, 0.01))


def example1_with_effects():
    d = example1().to_dict()
    d["effects"] = [{"effect": "backlash", "parameters": {"b": 0.1}},
                    {"effect": "creep", "parameters": {"k": 0.2, "tau": 0.5}},
                    {"effect": "sensor_lag", "parameters": {"tau": 0.05}}]
    return model_from_dict(d)


def periodic_input(cycles=4, per_cycle=250, period=3.0):
    t = np.linspace(0.0, cycles * period, cycles * per_cycle + 1)
    return t, 1.5 * np.sin(2 * np.pi * t / period) + 0.4 * np.sin(6 * np.pi * t / period)


MODELS = {"example1": example1, "example3": example3, "noisy": noisy_truth,
          "effects": example1_with_effects}


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    out = tmp_path_factory.mktemp("fmus")
    return {name: build_fmu.build_fmu(make(), out / f"{name}.fmu") for name, make in MODELS.items()}


@pytest.fixture(scope="module")
def unzipped(fmus, tmp_path_factory):
    return unzip_all(fmus, tmp_path_factory)


class Instance(FmuInstance):
    """The shared host with logging on (pythonfmu logs only then)."""


@pytest.mark.parametrize("name", MODELS)
def test_validate_fmu_has_no_findings(fmus, name):
    assert validate_fmu_file(fmus[name]) == []


@pytest.mark.parametrize("name", MODELS)
def test_closed_curve_matches_in_process_kernel(fmus, name):
    t, u = periodic_input()
    y_fmu = simulate_fmu(fmus[name], t, u)
    ref = simulate(MODELS[name](), t, u).y
    assert np.abs(y_fmu - ref).max() < 1e-9
    assert np.ptp(ref[-250:]) > 0.1          # a real loop, not a constant


def test_noisy_recording_is_matched_within_its_noise(fmus):
    rng = np.random.default_rng(7)
    t, u = periodic_input()
    sigma = 0.01
    y_data = simulate(noisy_truth(), t, u).y + sigma * rng.standard_normal(len(u))
    residual = simulate_fmu(fmus["noisy"], t, u) - y_data
    assert 0.85 * sigma < np.sqrt(np.mean(residual[-250:] ** 2)) < 1.15 * sigma


def test_model_description_interface(fmus):
    md = read_model_description(fmus["noisy"])
    model = noisy_truth()
    var = {v.name: v for v in md.modelVariables}
    assert (var["u"].causality, var["y"].causality) == ("input", "output")
    assert var["u"].unit == "V" and var["y"].unit == "um"
    assert "V_in" in var["u"].description and "disp" in var["y"].description
    assert var["order"].start == "3" and var["kind"].start == "ri"
    assert float(var["A_minus[2,1]"].start) == model.A_minus[1, 0]
    assert float(var["E_plus[3]"].start) == model.E_plus[2]
    assert float(var["D"].start) == model.D
    assert all(var[f"x0[{i + 1}]"].causality == "parameter" and var[f"x0[{i + 1}]"].variability
               == "fixed" for i in range(3))
    (out,) = md.outputs
    assert out.variable.name == "y" and [d.name for d in out.dependencies] == ["u"]
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    assert md.coSimulation.canHandleVariableCommunicationStepSize
    assert (md.defaultExperiment.startTime, md.defaultExperiment.stopTime,
            md.defaultExperiment.stepSize) == ("0.0", "12.0", "0.01")
    assert "straight line" in md.description and md.generationTool.startswith("semilinear-duhem")
    rd = {v.name for v in read_model_description(fmus["example3"]).modelVariables}
    assert {"A[2,1]", "g_v[1]", "g_g[20]"} <= rd and "g_v[21]" not in rd
    eff = {v.name: v for v in read_model_description(fmus["effects"]).modelVariables}
    assert float(eff["creep.tau"].start) == 0.5 and eff["backlash.b"].causality == "parameter"


def test_model_json_travels_in_resources(fmus, tmp_path):
    with zipfile.ZipFile(fmus["example3"]) as z:
        names = z.namelist()
        shipped = json.loads(z.read("resources/model.json"))
    save_model(example3(), tmp_path / "m.json")
    assert shipped == json.loads((tmp_path / "m.json").read_text())
    assert any(n.startswith("resources/duhem_core_") and n.endswith("/kernel.py") for n in names)


@pytest.mark.parametrize("name", ["example1", "example3", "effects"])
def test_fmu_state_rollback_and_serialisation_are_exact(unzipped, name):
    md, unzipdir = unzipped[name]
    inst = Instance(md, unzipdir)
    t, u = periodic_input(cycles=1, per_cycle=120)
    first, again, third = inst.rollback_runs(t, u, 49)
    ref = simulate(MODELS[name](), t, u).y[49:]
    assert np.array_equal(first, again) and np.array_equal(first, third)
    assert np.abs(first - ref).max() < 1e-9
    inst.free()


def test_instances_with_different_parameters_do_not_interfere(unzipped):
    md, unzipdir = unzipped["example1"]
    a = Instance(md, unzipdir, "a")
    b = Instance(md, unzipdir, "b", start={"C[1]": 0.5, "x0[2]": -0.3, "A_plus[1,1]": -2.0})
    md3, unzipdir3 = unzipped["example3"]
    c = Instance(md3, unzipdir3, "c")
    t, u = periodic_input(cycles=1, per_cycle=200)
    ya, yb, yc = np.empty(len(u)), np.empty(len(u)), np.empty(len(u))
    for k in range(len(u)):
        ya[k], yb[k], yc[k] = a.sample(u[k]), b.sample(u[k]), c.sample(u[k])
        if k + 1 < len(u):
            for inst in (a, b, c):
                inst.step(t[k + 1] - t[k])
    model_b = example1()
    model_b.C[0], model_b.x0[1], model_b.A_plus[0, 0] = 0.5, -0.3, -2.0
    assert np.abs(ya - simulate(example1(), t, u).y).max() < 1e-9
    assert np.abs(yb - simulate(model_b, t, u).y).max() < 1e-9
    assert np.abs(yc - simulate(example3(), t, u).y).max() < 1e-9
    assert np.abs(ya - yb).max() > 0.1
    for inst in (a, b, c):
        inst.free()


def test_reset_returns_to_the_exported_model(unzipped):
    md, unzipdir = unzipped["example1"]
    inst = Instance(md, unzipdir, start={"C[1]": 2.0})
    t, u = periodic_input(cycles=1, per_cycle=80)
    inst.run(t, u)
    inst.fmu.reset()
    inst.t = 0.0
    inst.initialise()
    assert np.abs(inst.run(t, u) - simulate(example1(), t, u).y).max() < 1e-9
    inst.free()


def substep_outputs(md, unzipdir, t, u, m):
    """Host stepping m times per sample period, u linear between samples; y at the samples."""
    inst = Instance(md, unzipdir, u0=u[0])
    y = [inst.sample(u[0])]
    for k in range(len(u) - 1):
        h = (t[k + 1] - t[k]) / m
        for j in range(1, m + 1):
            inst.step(h)
            value = inst.sample(u[k] + (u[k + 1] - u[k]) * j / m)
        y.append(value)
    inst.free()
    return np.array(y)


@pytest.mark.parametrize("name", ["example1", "example3"])
def test_output_at_communication_points_does_not_depend_on_step_size(unzipped, name):
    md, unzipdir = unzipped[name]
    t = np.arange(41) * 0.1
    u = np.interp(t, [0, 1.0, 2.5, 4.0], [0.0, 1.2, -0.8, 0.6])   # reversals at samples
    outputs = [substep_outputs(md, unzipdir, t, u, m) for m in (1, 10, 100)]
    assert np.abs(outputs[1] - outputs[0]).max() < 1e-10
    assert np.abs(outputs[2] - outputs[0]).max() < 1e-10
    assert np.abs(outputs[0] - simulate(MODELS[name](), t, u).y).max() < 1e-10


def test_output_right_after_initialisation(unzipped):
    md, unzipdir = unzipped["noisy"]
    model = noisy_truth()
    inst = Instance(md, unzipdir, u0=0.7)
    assert inst.y() == pytest.approx(model.C @ model.x0 + model.D * 0.7, abs=1e-15)
    assert inst.sample(-0.2) == pytest.approx(model.C @ model.x0 + model.D * -0.2, abs=1e-15)
    inst.free()


def test_reading_without_new_input_holds(unzipped):
    md, unzipdir = unzipped["example3"]
    inst = Instance(md, unzipdir)
    for k in range(1, 30):
        inst.sample(np.sin(0.3 * k))
        inst.step(0.1)
    y1 = inst.sample(0.9)
    assert inst.y() == y1 and inst.y() == y1
    inst.step(0.1)                       # held input: the state does not move
    assert inst.y() == y1
    assert inst.sample(0.5) != y1
    inst.free()


def test_fixed_parameter_is_rejected_after_initialisation(unzipped):
    md, unzipdir = unzipped["example1"]
    inst = Instance(md, unzipdir)
    with pytest.raises(FMICallException):
        inst.set("C[2]", 3.0)
    assert any("variability 'fixed'" in line and "C[2]" in line for line in inst.log)
    # pythonfmu reports every rejection as fmi2Fatal: no further call (not even
    # fmi2FreeInstance) is allowed on the instance.


def test_structural_parameter_change_is_rejected(unzipped):
    md, unzipdir = unzipped["example1"]
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="s")
    log = []
    callbacks = collecting_callbacks(log)
    fmu.instantiate(callbacks=callbacks, loggingOn=True)
    fmu.setInteger([vr["order"]], [2])              # its own value is accepted
    with pytest.raises(FMICallException):
        fmu.setInteger([vr["order"]], [3])
    assert any("order is structural" in line for line in log)


def test_invalid_parameter_values_are_reported_at_initialisation(unzipped):
    md, unzipdir = unzipped["example3"]
    inst = Instance(md, unzipdir, initialise=False)
    with pytest.raises(FMICallException):
        inst.initialise(start={"g_v[2]": example3().g.v[0]})
    assert any("rate table" in line and "duplicate" in line for line in inst.log)


def test_build_is_atomic_and_errors_are_clear(tmp_path, monkeypatch):
    from fitter.core import CallableRate
    model = example3()
    model.g = CallableRate(g3)
    target = tmp_path / "m.fmu"
    with pytest.raises(TypeError, match="tabulate"):
        build_fmu.build_fmu(model, target)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="unknown FMU backend"):
        build_fmu.build_fmu(example1(), target, backend="java")
    with pytest.raises(TypeError, match="unknown option"):
        build_fmu.build_fmu(example1(), target, colour="red")
    monkeypatch.setitem(sys.modules, "fitter.fmu.native", None)
    with pytest.raises(build_fmu.FmuBuildError, match="native FMU backend is not available"):
        build_fmu.build_fmu(example1(), target, backend="native")
    assert list(tmp_path.iterdir()) == []


def test_command_line_builds_from_json(tmp_path, capsys):
    save_model(example1(), tmp_path / "m.json")
    assert build_fmu.main([str(tmp_path / "m.json"), "-o", str(tmp_path / "m.fmu")]) == 0
    assert validate_fmu_file(tmp_path / "m.fmu") == []
    assert build_fmu.main([str(tmp_path / "missing.json"), "-o", str(tmp_path / "x.fmu")]) == 1
    assert "missing.json: no such file" in capsys.readouterr().err
    assert not (tmp_path / "x.fmu").exists()


def test_native_capabilities_and_source_files():
    xml = model_description_xml(example1(), model_identifier="duhem_native", guid="{0}",
                                backend="native", source_files=["sources/fmi2.c", "sources/model.c"])
    root = ET.fromstring(xml)
    cosim = root.find("CoSimulation")
    assert cosim.get("needsExecutionTool") == "false" and cosim.get("modelIdentifier") == "duhem_native"
    assert [f.get("name") for f in cosim.find("SourceFiles")] == ["sources/fmi2.c", "sources/model.c"]
    refs = [v.value_reference for v in model_variables(example1())]
    assert refs == list(range(len(refs)))
