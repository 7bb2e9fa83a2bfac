"""The pythonfmu FMI 2.0 Co-Simulation export, loaded and driven with fmpy.

Models: the paper's Example 1 (rate independent), the suite's rate-dependent
model of order 2 (Example 3 with a tabulated g), the true model of a noisy
generated recording (`ri_model(3)`, with E and D), and Example 1 with effect
extensions.  The stepping contract shared with the kernel and the native FMU
is in test_contract.py; FMUs come from the session's `fmu_cache`.
"""

import json
import zipfile
from xml.etree import ElementTree as ET

import numpy as np
import pytest
from samples import noisy_recording, rd_model, ri_model
from fmu_host import Instance  # logging on: pythonfmu logs only then
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

import build_fmu
from fitter.core import CallableRate, model_from_dict, save_model, simulate
from fitter.fmu.host import collecting_callbacks, simulate_fmu, validate_fmu_file
from fitter.fmu.model_description import model_description_xml
from fitter.fmu.variables import model_variables
from fitter.paper.example1 import true_model as example1
from fitter.paper.example3 import g_true as g3


def example1_with_effects():
    d = example1().to_dict()
    d["effects"] = [
        {"effect": "backlash", "parameters": {"b": 0.1}},
        {"effect": "creep", "parameters": {"k": 0.2, "tau": 0.5}},
        {"effect": "sensor_lag", "parameters": {"tau": 0.05}},
    ]
    return model_from_dict(d)


def periodic_input(cycles=4, per_cycle=250, period=3.0):
    t = np.linspace(0.0, cycles * period, cycles * per_cycle + 1)
    return t, 1.5 * np.sin(2 * np.pi * t / period) + 0.4 * np.sin(6 * np.pi * t / period)


MODELS = {
    "example1": example1,
    "example3": lambda: rd_model(2),
    "noisy": lambda: ri_model(3),
    "effects": example1_with_effects,
    "held": lambda: example1_with_effects().replace(input_range=(-1.0, 1.2)),
}


@pytest.fixture(scope="module")
def fmus(fmu_cache):
    return {name: fmu_cache.build(make(), "python") for name, make in MODELS.items()}


@pytest.fixture(scope="module")
def unzipped(fmu_cache):
    return {name: fmu_cache.unzipped(make(), "python") for name, make in MODELS.items()}


@pytest.mark.parametrize("name", MODELS)
def test_validate_fmu_has_no_findings(fmus, name):
    assert validate_fmu_file(fmus[name]) == []


@pytest.mark.parametrize("name", ["example1", "effects", "held"])  # example3, noisy: test_contract.py
def test_closed_curve_matches_in_process_kernel(fmus, name):
    t, u = periodic_input()
    y_fmu = simulate_fmu(fmus[name], t, u)
    ref = simulate(MODELS[name](), t, u).y
    assert np.abs(y_fmu - ref).max() < 1e-9
    assert np.ptp(ref[-250:]) > 0.1  # a real loop, not a constant


def test_noisy_recording_is_matched_within_its_noise(fmus):
    t, u = periodic_input()
    sigma = 0.01
    data = noisy_recording(ri_model(3), t, u, noise=sigma, seed=7, relative=False)
    residual = simulate_fmu(fmus["noisy"], t, u) - data.y
    assert 0.85 * sigma < np.sqrt(np.mean(residual[-250:] ** 2)) < 1.15 * sigma


def test_model_description_interface(fmus):
    md = read_model_description(fmus["noisy"])
    model = ri_model(3)
    var = {v.name: v for v in md.modelVariables}
    assert (var["u"].causality, var["y"].causality) == ("input", "output")
    assert var["u"].unit == "V" and var["y"].unit == "um"
    assert "V_in" in var["u"].description and "disp" in var["y"].description
    assert var["order"].start == "3" and var["kind"].start == "ri"
    assert float(var["A_minus[2,1]"].start) == model.A_minus[1, 0]
    assert float(var["E_plus[3]"].start) == model.E_plus[2]
    assert float(var["D"].start) == model.D
    assert all(
        var[f"x0[{i + 1}]"].causality == "parameter" and var[f"x0[{i + 1}]"].variability == "fixed" for i in range(3)
    )
    (out,) = md.outputs
    assert out.variable.name == "y" and [d.name for d in out.dependencies] == ["u"]
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    assert md.coSimulation.canHandleVariableCommunicationStepSize
    assert (md.defaultExperiment.startTime, md.defaultExperiment.stopTime, md.defaultExperiment.stepSize) == (
        "0.0",
        "12.0",
        "0.01",
    )
    assert "straight line" in md.description and md.generationTool.startswith("semilinear-duhem")
    rd = {v.name for v in read_model_description(fmus["example3"]).modelVariables}
    assert {"A[2,1]", "g_v[1]", "g_g[20]"} <= rd and "g_v[21]" not in rd
    eff = {v.name: v for v in read_model_description(fmus["effects"]).modelVariables}
    assert float(eff["creep.tau"].start) == 0.5 and eff["backlash.b"].causality == "parameter"


def test_model_json_travels_in_resources(fmus, tmp_path):
    with zipfile.ZipFile(fmus["example3"]) as z:
        names = z.namelist()
        shipped = json.loads(z.read("resources/model.json"))
    save_model(rd_model(2), tmp_path / "m.json")
    assert shipped == json.loads((tmp_path / "m.json").read_text())
    assert any(n.startswith("resources/duhem_core_") and n.endswith("/kernel.py") for n in names)


def test_fmu_state_rollback_and_serialisation_with_effects_are_exact(unzipped):
    md, unzipdir = unzipped["effects"]
    inst = Instance(md, unzipdir)
    t, u = periodic_input(cycles=1, per_cycle=120)
    first, again, third = inst.rollback_runs(t, u, 49)
    ref = simulate(example1_with_effects(), t, u).y[49:]
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
    base = example1()
    C, x0, A_plus = base.C.copy(), base.x0.copy(), base.A_plus.copy()
    C[0], x0[1], A_plus[0, 0] = 0.5, -0.3, -2.0
    model_b = base.replace(C=C, x0=x0, A_plus=A_plus)
    assert np.abs(ya - simulate(example1(), t, u).y).max() < 1e-9
    assert np.abs(yb - simulate(model_b, t, u).y).max() < 1e-9
    assert np.abs(yc - simulate(rd_model(2), t, u).y).max() < 1e-9
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
    fmu = FMU2Slave(
        guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier, instanceName="s"
    )
    log = []
    callbacks = collecting_callbacks(log)
    fmu.instantiate(callbacks=callbacks, loggingOn=True)
    fmu.setInteger([vr["order"]], [2])  # its own value is accepted
    with pytest.raises(FMICallException):
        fmu.setInteger([vr["order"]], [3])
    assert any("order is structural" in line for line in log)


def test_invalid_parameter_values_are_reported_at_initialisation(unzipped):
    md, unzipdir = unzipped["example3"]
    inst = Instance(md, unzipdir, initialise=False)
    with pytest.raises(FMICallException):
        inst.initialise(start={"g_v[2]": rd_model(2).g.v[0]})
    assert any("rate table" in line and "duplicate" in line for line in inst.log)


def test_build_is_atomic_and_errors_are_clear(tmp_path):
    model = rd_model(2).replace(g=CallableRate(g3))
    target = tmp_path / "m.fmu"
    with pytest.raises(TypeError, match="tabulate"):
        build_fmu.build_fmu(model, target)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="unknown FMU backend"):
        build_fmu.build_fmu(example1(), target, backend="java")
    with pytest.raises(TypeError, match="unknown option"):
        build_fmu.build_fmu(example1(), target, colour="red")
    assert list(tmp_path.iterdir()) == []


def test_command_line_builds_from_json(tmp_path, capsys):
    save_model(example1(), tmp_path / "m.json")
    assert build_fmu.main([str(tmp_path / "m.json"), "-o", str(tmp_path / "m.fmu")]) == 0
    assert validate_fmu_file(tmp_path / "m.fmu") == []
    assert build_fmu.main([str(tmp_path / "missing.json"), "-o", str(tmp_path / "x.fmu")]) == 1
    assert "missing.json: no such file" in capsys.readouterr().err
    assert not (tmp_path / "x.fmu").exists()


def test_native_capabilities_and_source_files():
    xml = model_description_xml(
        example1(),
        model_identifier="duhem_native",
        guid="{0}",
        backend="native",
        source_files=["sources/fmi2.c", "sources/model.c"],
    )
    root = ET.fromstring(xml)
    cosim = root.find("CoSimulation")
    assert cosim.get("needsExecutionTool") == "false" and cosim.get("modelIdentifier") == "duhem_native"
    assert [f.get("name") for f in cosim.find("SourceFiles")] == ["sources/fmi2.c", "sources/model.c"]
    refs = [v.value_reference for v in model_variables(example1())]
    assert refs == list(range(len(refs)))


def test_bad_steps_and_steps_after_terminate_are_refused_and_change_nothing(unzipped):
    """The slave checks fmi2DoStep itself (a negative, NaN or mistimed step, a step after fmi2Terminate): a
    logged error and fmi2Discard (pythonfmu's status for a refused step; an exception would become
    fmi2Fatal), the state unchanged, and the instance frees cleanly."""
    md, unzipdir = unzipped["example1"]
    inst = Instance(md, unzipdir, u0=0.0)
    inst.set("u", 0.5)
    inst.step(0.1)
    y = inst.y()
    for t, h, why in (
        (inst.t, -0.1, "must be positive and finite"),
        (inst.t, float("nan"), "positive and finite"),
        (inst.t + 5.0, 0.1, "but the FMU is at t"),
    ):
        with pytest.raises(FMICallException) as exc:
            inst.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        assert exc.value.status == 2 and why in inst.log[-1]
    assert inst.y() == y
    inst.fmu.terminate()
    with pytest.raises(FMICallException) as exc:
        inst.fmu.doStep(currentCommunicationPoint=inst.t, communicationStepSize=0.1)
    assert exc.value.status == 2 and "called after fmi2Terminate" in inst.log[-1]
    inst.fmu.freeInstance()


def test_stored_effect_start_and_its_parameters_run_as_in_process(tmp_path):
    """The Python FMU of a model whose effects store their start runs from it, and its
    ``<effect>.start.<state>`` parameters move it (`duhem validate --x0 fitted`)."""
    from fitter.core.effects import settled_state, with_start
    from fitter.core.kernel import flows
    from fitter.fmu.variables import start_state_values

    t, u = periodic_input(cycles=2)
    fresh = example1_with_effects()
    model = with_start(fresh, settled_state(fresh, t, u, fresh.x0, flows(fresh)))
    path = build_fmu.build_fmu(model, tmp_path / "started.fmu", backend="python")
    ref = simulate(model, t, u).y
    assert np.abs(simulate_fmu(path, t, u) - ref).max() < 1e-9
    assert np.abs(ref - simulate(fresh, t, u).y).max() > 1e-3
    other = with_start(fresh, settled_state(fresh, t, -u, fresh.x0, flows(fresh)))
    moved = simulate(other, t, u).y
    assert np.abs(moved - ref).max() > 1e-3
    assert np.abs(simulate_fmu(path, t, u, start=start_state_values(other)) - moved).max() < 1e-9
