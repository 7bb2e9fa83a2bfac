"""The native (C) FMI 2.0 Co-Simulation FMU, loaded and driven with fmpy.

The FMU's output must equal the Python kernel's (`fitter.core.simulate`,
`fitter.core.Stepper`) for every model kind and effect; its shared library
must need no Python; it must refuse bad calls with fmi2Error and a logged
message and never crash, also under random call sequences (hypothesis, run in
a subprocess so that a crash fails the test instead of killing pytest) and
under AddressSanitizer and UBSan.  The stepping contract it shares with the
kernel and the pythonfmu FMU is in test_contract.py.

Run as a script (``python tests/test_fmu_native.py fuzz FMU MODEL EXAMPLES`` or
``... check FMU MODEL``, MODEL a key of `MODELS`) this file is the driver that
those subprocesses execute.
"""

from __future__ import annotations

import copy
import json
import math
import os
import shutil
import subprocess
import sys
import zipfile
from ctypes import byref, c_char_p, c_double, c_int, c_size_t, c_uint, c_void_p
from pathlib import Path

import numpy as np
import pytest
from fmu_host import Instance as FmuInstance

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi2 import (  # noqa: E402
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CoSimulation,
    fmi2DoStepStatus,
    fmi2LastSuccessfulTime,
    fmi2ModelExchange,
)

from fitter.core import (  # noqa: E402
    RateDependentModel,
    RateIndependentModel,
    Stepper,
    TabulatedRate,
    model_from_dict,
    simulate,
)
from fitter.core.effects import REGISTRY  # noqa: E402
from fitter.fmu.host import collecting_callbacks, simulate_fmu, validate_fmu_file  # noqa: E402
from fitter.fmu.variables import model_variables  # noqa: E402
from fitter.fmu.native import NativeBuildError, build_native_fmu  # noqa: E402
from fitter.fmu.native_sources import NATIVE_EFFECTS  # noqa: E402
from samples import sampled_input  # noqa: E402

ALL_EFFECTS = [
    {"effect": "backlash", "parameters": {"b": 0.15}},
    {"effect": "rate_dependence", "parameters": {"alpha": 0.4}},
    {"effect": "creep", "parameters": {"k": 0.2, "tau": 0.6}},
    {
        "effect": "relaxation",
        "parameters": {"k": 0.08, "w2": 0.3, "w3": 1.5, "w4": 0.2, "tau_min": 0.05, "tau_max": 20.0},
    },
    {
        "effect": "switching",
        "parameters": {
            "S1": 0.25,
            "u_up1": 0.2,
            "u_dn1": -0.3,
            "width1": 0.08,
            "q1": -0.5,
            "spread1": 0.12,
            "S2": 0.1,
            "u_up2": 0.5,
            "u_dn2": -0.6,
            "width2": 0.2,
            "q2": 0.3,
        },
    },
    {"effect": "viscous", "parameters": {"c": 0.03}},
    {"effect": "thermal_drift", "parameters": {"kappa": 0.02}},
    {"effect": "saturation", "parameters": {"y_c": 0.1, "beta": 0.7}},
    {"effect": "sensor_lag", "parameters": {"tau": 0.08}},
    {"effect": "measurement_drift", "parameters": {"rate": -0.04}},
]


def g3(v):
    v = np.asarray(v, dtype=float)
    return np.where(v >= 0, (v / 3 - 1) ** 3 + 1, 1 - np.exp(v))


def ri_model(effects=()):
    """Order 3 with E and D (a fitted model's full parameter set)."""
    A_p = np.array([[-2.0, 1.0, 0.0], [-1.0, -2.0, 0.5], [0.0, -0.5, -1.0]])
    A_m = np.array([[-1.5, -1.0, 0.2], [1.0, -1.5, 0.0], [0.0, 0.3, -2.0]])
    return RateIndependentModel(
        A_plus=A_p,
        A_minus=A_m,
        B_plus=[1.0, 0.5, -0.2],
        B_minus=[0.8, -0.4, 0.3],
        E_plus=[0.1, 0.0, -0.05],
        E_minus=[-0.1, 0.02, 0.0],
        C=[1.0, -0.5, 0.25],
        D=0.4,
        x0=[0.2, -0.1, 0.05],
        effects=list(effects),
    )


def rd_model(effects=()):
    """The paper's Example 3 with g tabulated on both sides, plus E and D."""
    nodes = np.geomspace(0.05, 6.0, 9)
    g = TabulatedRate.from_function(g3, np.r_[-nodes[::-1], nodes])
    return RateDependentModel(
        A=[[0, 1], [-3, -1]], B=[1, 0], C=[1, 1], E=[0.1, -0.05], D=0.05, g=g, x0=[0.1, -0.2], effects=list(effects)
    )


def rd_one_sided():
    """g known for rising input only: falling input freezes the state."""
    return RateDependentModel(A=[[-1.0]], B=[1.0], C=[2.0], g=TabulatedRate([0.5, 2.0], [0.4, 1.1]))


def ri_small(effects=()):
    """Paper Example 1 (order 2); with creep and backlash for the fuzz test."""
    A = np.array([[-1.0, 4.0], [-4.0, -1.0]])
    return RateIndependentModel(
        A_plus=A, A_minus=-A, B_plus=[0.0, 1.0], B_minus=[0.0, -1.0], C=[0, 1], x0=[0.15, 0.15], effects=list(effects)
    )


def rd_small(effects=()):
    """Order 2, a four-node rate table (for the fuzz test)."""
    return RateDependentModel(
        A=[[-2.0, 0.3], [0.0, -1.0]],
        B=[2.0, 1.0],
        C=[1.0, 0.5],
        E=[0.1, 0.0],
        g=TabulatedRate([-1.0, -0.3, 0.4, 1.5], [0.8, 0.3, 0.35, 1.2]),
        effects=list(effects),
    )


FUZZ_EFFECTS = [
    {"effect": "creep", "parameters": {"k": 0.2, "tau": 0.6}},
    {"effect": "backlash", "parameters": {"b": 0.1}},
]
FUZZ_RD_EFFECTS = [
    {"effect": "rate_dependence", "parameters": {"alpha": 0.3}},
    {"effect": "sensor_lag", "parameters": {"tau": 0.05}},
]
# The parameters each fuzz model's sequences set (g_v can collide: an invalid rate table).
FUZZ_PARAMETERS = {
    "fuzz": ["x0[1]", "C[1]", "creep.tau", "backlash.b"],
    "fuzz_rd": ["x0[2]", "g_v[1]", "g_v[4]", "g_g[2]", "sensor_lag.tau", "rate_dependence.alpha"],
}

MODELS = {
    "ri": ri_model,
    "rd": rd_model,
    "rd_one_sided": rd_one_sided,
    "ri_effects": lambda: ri_model(ALL_EFFECTS),
    "rd_effects": lambda: rd_model(ALL_EFFECTS),
    "fuzz": lambda: ri_small(FUZZ_EFFECTS),
    "fuzz_rd": lambda: rd_small(FUZZ_RD_EFFECTS),
    "ri_held": lambda: ri_model().replace(input_range=(-0.9, 1.1)),
    "rd_held_effects": lambda: rd_model(ALL_EFFECTS).replace(input_range=(-1.2, 0.7)),
}


@pytest.fixture(scope="module")
def fmus(fmu_cache):
    return {name: fmu_cache.build(make(), "native") for name, make in MODELS.items()}


@pytest.fixture(scope="module")
def unzipped(fmu_cache):
    return {name: fmu_cache.unzipped(make(), "native") for name, make in MODELS.items()}


class Instance(FmuInstance):
    """The shared host; logging off, and `free` does not terminate (instances may be in error)."""

    LOGGING_ON = False
    TERMINATE_ON_FREE = False


def status_of(call, *args) -> int:
    """The fmi2Status of a raw fmpy call (fmpy raises on anything above fmi2Warning)."""
    try:
        call(*args)
    except FMICallException as exc:
        return exc.status
    return 0


# --------------------------------------------------------------------- results


@pytest.mark.parametrize("name", [name for name in MODELS if name not in ("ri", "rd")])  # test_contract.py
def test_output_equals_python_kernel(fmus, name):
    t, u = sampled_input()
    ref = simulate(MODELS[name](), t, u).y
    y = simulate_fmu(fmus[name], t, u)
    assert np.ptp(ref) > 0.1
    assert np.abs(y - ref).max() <= 1e-10 * max(1.0, np.abs(ref).max())


def test_c_reads_the_registrys_numbers(tmp_path, monkeypatch):
    """Every native effect's fixed numbers (`EffectSpec.c_constants`) are macros of the generated header, and the
    C computes with them: with the switching integrals capped at 0.05 instead of 40 (a cap that binds on every
    interval), kernel and C still agree to 1e-10, and both differ from the uncapped output."""
    import fitter.core.effects.switching as switching
    from fitter.fmu.native_sources import model_data_header

    model = ri_model(ALL_EFFECTS)
    header = model_data_header(model, "{guid}")
    for name, spec in REGISTRY.items():
        for key in spec.c_constants() if name in NATIVE_EFFECTS else ():
            assert f"#define DUHEM_{name.upper()}_{key} " in header, (name, key)
    t, u = sampled_input()
    before = simulate(model, t, u).y
    monkeypatch.setattr(switching, "_MAX_DECAY", 0.05)
    assert "#define DUHEM_SWITCHING_MAX_DECAY 0.05" in model_data_header(model, "{guid}")
    ref = simulate(model, t, u).y
    y = simulate_fmu(build_native_fmu(model, tmp_path / "capped.fmu", platforms="host"), t, u)
    assert np.abs(ref - before).max() > 1e-3
    assert np.abs(y - ref).max() <= 1e-10 * max(1.0, np.abs(ref).max())


@pytest.mark.parametrize("name", MODELS)
def test_validate_fmu_is_empty(fmus, name):
    assert validate_fmu_file(fmus[name]) == []


def test_shared_library_needs_no_python(fmus, unzipped):
    md, unzipdir = unzipped["rd_effects"]
    library = Path(unzipdir) / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    deps = subprocess.run(["ldd", str(library)], capture_output=True, text=True, check=True).stdout
    names = {line.split()[0].split(".so")[0] for line in deps.splitlines() if line.strip()}
    assert "python" not in deps.lower()
    assert names <= {"linux-vdso", "libc", "libm", "/lib64/ld-linux-x86-64"}, names
    symbols = subprocess.run(
        ["nm", "-D", "--defined-only", str(library)], capture_output=True, text=True, check=True
    ).stdout.split()[2::3]
    assert symbols and all(s.startswith("fmi2") for s in symbols), symbols
    assert md.coSimulation.needsExecutionTool is False
    with zipfile.ZipFile(fmus["rd_effects"]) as zf:
        names = set(zf.namelist())
    assert {
        "sources/fmi2.c",
        "sources/cosimulation.c",
        "sources/duhem_model.c",
        "sources/model_data.h",
        "sources/fmi2Functions.h",
    } <= names
    assert md.buildConfigurations[0].sourceFileSets[0].sourceFiles == ["fmi2.c", "duhem_model.c"]
    with zipfile.ZipFile(fmus["rd_effects"]) as zf:
        shipped = model_from_dict(json.loads(zf.read("resources/model.json")))
    assert shipped.to_dict() == MODELS["rd_effects"]().to_dict()


def test_source_fmu_compiles_with_fmpy(unzipped, tmp_path):
    from fmpy.build import build_platform_binary

    if shutil.which("cmake") is None:
        pytest.skip("cmake is not installed (fmpy compiles source FMUs with cmake)")
    md, unzipdir = unzipped["rd_effects"]
    copy_dir = tmp_path / "fmu"
    shutil.copytree(unzipdir, copy_dir)
    shutil.rmtree(copy_dir / "binaries")
    (tmp_path / "build").mkdir()
    build_platform_binary(copy_dir, build_dir=tmp_path / "build")
    t, u = sampled_input(150)
    inst = Instance(md, str(copy_dir))
    y = inst.run(t, u)
    inst.free()
    assert np.abs(y - simulate(MODELS["rd_effects"](), t, u).y).max() < 1e-10


def test_sources_compile_without_warnings(tmp_path):
    from fitter.fmu.native_sources import c_sources, model_data_header, source_files

    for name, path in source_files(2).items():
        shutil.copyfile(path, tmp_path / name)
    for model in (ri_model(ALL_EFFECTS), rd_model(), ri_small()):
        (tmp_path / "model_data.h").write_text(model_data_header(model, "{guid}"))
        result = subprocess.run(
            ["cc", "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-c", *c_sources(2)],
            cwd=tmp_path,
            capture_output=True,
            text=True,
        )
        assert result.returncode == 0, result.stderr


C_HOST = r"""
/* A Python-free co-simulation host: dlopen the FMU's library, sample-and-step u = sin(0.7 t). */
#include <dlfcn.h>
#include <math.h>
#include <stdio.h>
#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...)
{
    (void)env; (void)name; (void)category;
    fprintf(stderr, "[%d] %s\n", (int)status, message);
}

#define LOAD(type, name) type *name = (type *)dlsym(lib, #name)

int main(int argc, char **argv)
{
    void *lib = argc == 3 ? dlopen(argv[1], RTLD_NOW | RTLD_LOCAL) : NULL;
    const fmi2CallbackFunctions callbacks = {logger, NULL, NULL, NULL, NULL};
    const fmi2ValueReference u_ref = 0, y_ref = 1;
    fmi2Component c;
    int k;
    if (!lib) return 2;
    LOAD(fmi2InstantiateTYPE, fmi2Instantiate);
    LOAD(fmi2SetupExperimentTYPE, fmi2SetupExperiment);
    LOAD(fmi2EnterInitializationModeTYPE, fmi2EnterInitializationMode);
    LOAD(fmi2ExitInitializationModeTYPE, fmi2ExitInitializationMode);
    LOAD(fmi2SetRealTYPE, fmi2SetReal);
    LOAD(fmi2GetRealTYPE, fmi2GetReal);
    LOAD(fmi2DoStepTYPE, fmi2DoStep);
    LOAD(fmi2TerminateTYPE, fmi2Terminate);
    LOAD(fmi2FreeInstanceTYPE, fmi2FreeInstance);
    c = fmi2Instantiate("host", fmi2CoSimulation, argv[2], "", &callbacks, fmi2False, fmi2False);
    if (!c || fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0)
        || fmi2EnterInitializationMode(c) || fmi2ExitInitializationMode(c)) return 3;
    for (k = 0; k < 200; k++) {
        double t = 0.05 * k, u = sin(0.7 * t), y;
        if (fmi2SetReal(c, &u_ref, 1, &u) || fmi2GetReal(c, &y_ref, 1, &y)
            || fmi2DoStep(c, t, 0.05, fmi2True)) return 4;
        printf("%.17g\n", y);
    }
    fmi2Terminate(c);
    fmi2FreeInstance(c);
    return dlclose(lib);
}
"""


def _run_c_host(unzipdir: str, md, tmp_path: Path, flags: tuple[str, ...] = ()) -> np.ndarray:
    (tmp_path / "host.c").write_text(C_HOST)
    subprocess.run(
        ["cc", *flags, "-I", str(Path(unzipdir) / "sources"), "host.c", "-o", "host", "-ldl", "-lm"],
        cwd=tmp_path,
        check=True,
    )
    library = Path(unzipdir) / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    result = subprocess.run([str(tmp_path / "host"), str(library), md.guid], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    return np.array(result.stdout.split(), dtype=float)


def test_python_free_c_host_runs_the_fmu(unzipped, tmp_path):
    md, unzipdir = unzipped["rd_effects"]
    y = _run_c_host(unzipdir, md, tmp_path)
    t = 0.05 * np.arange(200)
    assert np.abs(y - simulate(MODELS["rd_effects"](), t, np.sin(0.7 * t)).y).max() < 1e-10


# --------------------------------------------------------------------- FMI behaviour


def test_fmu_state_rollback_and_serialisation_with_effects_are_exact(unzipped):
    md, unzipdir = unzipped["ri_effects"]
    inst = Instance(md, unzipdir)
    t, u = sampled_input(160)
    first, again, third = inst.rollback_runs(t, u, 69)
    assert np.array_equal(first, again) and np.array_equal(first, third)
    assert np.abs(first - simulate(MODELS["ri_effects"](), t, u).y[69:]).max() < 1e-10
    inst.free()


def test_reset_restores_the_start(unzipped):
    md, unzipdir = unzipped["ri_effects"]
    t, u = sampled_input(120)
    inst = Instance(md, unzipdir, start={"x0[1]": 0.9, "creep.k": 0.5})
    changed = inst.run(t, u)
    inst.fmu.reset()
    inst.initialise()
    default = inst.run(t, u)
    inst.free()
    model = ri_model(ALL_EFFECTS)
    assert np.abs(default - simulate(model, t, u).y).max() < 1e-10
    effects = [e.to_dict() for e in model.effects]
    effects[2]["parameters"]["k"] = 0.5
    model = model.replace(x0=np.r_[0.9, model.x0[1:]], effects=effects)
    assert np.abs(changed - simulate(model, t, u).y).max() < 1e-10


def test_instances_with_different_parameters_do_not_interfere(unzipped):
    md, unzipdir = unzipped["ri"]
    a = Instance(md, unzipdir, "a")
    b = Instance(md, unzipdir, "b", start={"C[1]": 0.5, "x0[2]": -0.3, "A_plus[1,1]": -2.5})
    md3, unzipdir3 = unzipped["rd"]
    c = Instance(md3, unzipdir3, "c", start={"g_g[12]": 0.9})
    t, u = sampled_input(200)
    ys = np.empty((3, len(u)))
    for k in range(len(u)):
        ys[:, k] = [inst.sample(u[k]) for inst in (a, b, c)]
        if k + 1 < len(u):
            for inst in (a, b, c):
                inst.step(t[k + 1] - t[k])
    base = ri_model()
    C, x0, A_plus = base.C.copy(), base.x0.copy(), base.A_plus.copy()
    C[0], x0[1], A_plus[0, 0] = 0.5, -0.3, -2.5
    model_b = base.replace(C=C, x0=x0, A_plus=A_plus)
    table = rd_model().g
    model_c = rd_model().replace(g=TabulatedRate(table.v, np.r_[table.g[:11], 0.9, table.g[12:]]))
    assert np.abs(ys[0] - simulate(ri_model(), t, u).y).max() < 1e-10
    assert np.abs(ys[1] - simulate(model_b, t, u).y).max() < 1e-10
    assert np.abs(ys[2] - simulate(model_c, t, u).y).max() < 1e-10
    assert np.abs(ys[0] - ys[1]).max() > 0.1 and np.abs(ys[2] - simulate(rd_model(), t, u).y).max() > 1e-3
    for inst in (a, b, c):
        inst.free()


def _expect_error(inst, fragment, call, *args):
    before = len(inst.log)
    with pytest.raises(FMICallException) as info:
        call(*args)
    assert info.value.status == 3
    assert any(fragment in line for line in inst.log[before:]), inst.log[before:]


def test_refused_calls_report_and_change_nothing(unzipped):
    md, unzipdir = unzipped["rd_effects"]
    t, u = sampled_input(80)
    inst = Instance(md, unzipdir, initialise=False)
    fmu, c, vr = inst.fmu, inst.fmu.component, inst.vr
    _expect_error(inst, "illegal call sequence", fmu.doStep, 0.0, 0.1)
    _expect_error(inst, "illegal call sequence", fmu.getReal, [vr["y"]])
    _expect_error(inst, "must be positive", fmu.setReal, [vr["creep.tau"]], [0.0])
    _expect_error(inst, "must be >= 0", fmu.setReal, [vr["backlash.b"]], [-1.0])
    _expect_error(inst, "unknown value reference", fmu.setReal, [10**6], [1.0])
    _expect_error(inst, "structural", fmu.setInteger, [vr["order"]], [3])
    fmu.setInteger([vr["order"]], [2])
    _expect_error(inst, "structural", fmu.setString, [vr["kind"]], ["ri"])
    fmu.setString([vr["kind"]], ["rd"])
    inst.initialise(u0=u[0])
    _expect_error(inst, "not finite", fmu.setReal, [vr["u"]], [math.nan])
    _expect_error(inst, "not finite", fmu.setReal, [vr["u"]], [math.inf])
    _expect_error(inst, "A[1,1] (value reference 4) = 1: a fixed parameter", fmu.setReal, [vr["A[1,1]"]], [1.0])
    _expect_error(inst, "output cannot be set", fmu.setReal, [vr["y"]], [1.0])
    _expect_error(inst, "must be positive", fmu.doStep, 0.0, 0.0)
    _expect_error(inst, "must be positive", fmu.doStep, 0.0, -0.1)
    _expect_error(inst, "must be positive", fmu.doStep, 0.0, math.nan)
    _expect_error(inst, "is not the FMU's time", fmu.doStep, 1.0, 0.1)
    _expect_error(inst, "unknown value reference", fmu.getReal, [10**6])
    _expect_error(inst, "vr is NULL", fmu.fmi2GetReal, c, None, 1, None)
    _expect_error(inst, "value is NULL", fmu.fmi2SetReal, c, (c_uint * 1)(vr["u"]), 1, None)
    _expect_error(inst, "FMUstate is NULL", fmu.fmi2GetFMUstate, c, None)
    _expect_error(inst, "FMUstate is NULL", fmu.fmi2SetFMUstate, c, None)
    _expect_error(inst, "unknown log category", fmu.fmi2SetDebugLogging, c, 1, 1, (c_char_p * 1)(b"logNothing"))
    state = fmu.getFMUstate()
    size = len(fmu.serializeFMUstate(state))
    fmu.freeFMUstate(state)
    _expect_error(inst, "checksum mismatch", fmu.deSerializeFMUstate, bytes(size))
    _expect_error(inst, "expected", fmu.deSerializeFMUstate, b"short")
    set_time = fmu.dll.fmi2SetTime
    set_time.argtypes, set_time.restype = [c_void_p, c_double], c_int
    assert set_time(c, 0.0) == 3 and "Model Exchange is not supported" in inst.log[-1]
    _expect_error(
        inst,
        "only order 1 is supported",
        fmu.fmi2SetRealInputDerivatives,
        c,
        (c_uint * 1)(inst.vr["u"]),
        1,
        (c_int * 1)(2),
        (c_double * 1)(1.0),
    )
    assert status_of(fmu.getStatus, fmi2DoStepStatus) == 2  # fmi2Discard
    assert fmu.getRealStatus(fmi2LastSuccessfulTime) == 0.0
    y = inst.run(t, u)  # every refusal left the instance as it was
    inst.fmu.terminate()
    _expect_error(inst, "illegal call sequence", fmu.doStep, inst.t, 0.1)
    inst.free()
    assert np.abs(y - simulate(MODELS["rd_effects"](), t, u).y).max() < 1e-10


def test_invalid_rate_table_is_reported_at_initialisation(unzipped):
    md, unzipdir = unzipped["rd"]
    inst = Instance(md, unzipdir, initialise=False)
    inst.fmu.setupExperiment(startTime=0.0)
    inst.set("g_v[2]", rd_model().g.v[0])
    inst.fmu.enterInitializationMode()
    _expect_error(inst, "duplicate", inst.fmu.exitInitializationMode)
    inst.set("g_v[2]", rd_model().g.v[1])
    inst.fmu.exitInitializationMode()
    inst.free()


def test_instantiate_rejects_wrong_guid_and_type(unzipped):
    md, unzipdir = unzipped["ri"]
    log: list[str] = []
    callbacks = collecting_callbacks(log)
    fmu = FMU2Slave(
        guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier, instanceName="x"
    )
    assert fmu.fmi2Instantiate(b"x", fmi2CoSimulation, b"{wrong}", b"", byref(callbacks), 0, 0) is None
    assert fmu.fmi2Instantiate(b"x", fmi2ModelExchange, md.guid.encode(), b"", byref(callbacks), 0, 0) is None
    assert fmu.fmi2Instantiate(b"", fmi2CoSimulation, md.guid.encode(), b"", byref(callbacks), 0, 0) is None
    assert fmu.fmi2Instantiate(b"x", fmi2CoSimulation, md.guid.encode(), b"", None, 0, 0) is None
    assert any("does not match" in m for m in log) and any("Co-Simulation only" in m for m in log)
    assert any("non-empty" in m for m in log)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE()  # NULL: the FMU declares
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE()  # canNotUseMemoryManagementFunctions
    component = fmu.fmi2Instantiate(b"x", fmi2CoSimulation, md.guid.encode(), b"", byref(callbacks), 0, 0)
    assert component is not None
    fmu.fmi2FreeInstance(component)
    fmu.freeLibrary()


def test_every_core_effect_runs_natively():
    from fitter.core.effects import REGISTRY

    assert NATIVE_EFFECTS == {name for name, spec in REGISTRY.items() if spec.native}
    assert NATIVE_EFFECTS == set(REGISTRY) == {e["effect"] for e in ALL_EFFECTS}


@pytest.mark.parametrize("name", sorted(NATIVE_EFFECTS))
def test_each_native_effect_equals_python_and_checks_its_ranges(name, tmp_path):
    """Every native effect of the registry alone, at its example, and its parameter ranges in C."""
    spec = REGISTRY[name]
    model = ri_model([{"effect": name, "parameters": dict(spec.example)}])
    path = build_native_fmu(model, tmp_path / f"{name}.fmu")
    t, u = sampled_input(200)
    ref = simulate(model, t, u).y
    assert np.abs(simulate_fmu(path, t, u) - ref).max() <= 1e-10 * max(1.0, np.abs(ref).max())
    assert np.abs(ref - simulate(ri_model(), t, u).y).max() > 1e-4
    md = read_model_description(path)
    inst = Instance(md, extract(path, str(tmp_path / "unzipped")), initialise=False)
    for par in spec.parameters:
        for value in (math.nan, math.inf):
            _expect_error(inst, "not finite", inst.fmu.setReal, [inst.vr[f"{name}.{par.name}"]], [value])
        if par.lower > -math.inf:
            low = par.lower if par.strict else par.lower - 1e-9 * max(1.0, abs(par.lower))
            _expect_error(inst, f"must be {par.rule()}", inst.fmu.setReal, [inst.vr[f"{name}.{par.name}"]], [low])
        if par.upper < math.inf:
            _expect_error(
                inst,
                f"must be {par.rule()}",
                inst.fmu.setReal,
                [inst.vr[f"{name}.{par.name}"]],
                [par.upper * (1 + 1e-9) + 1e-9],
            )
    inst.free()


def test_effect_without_native_implementation_is_refused(tmp_path, monkeypatch):
    import fitter.fmu.native_sources as native_sources

    monkeypatch.setattr(native_sources, "NATIVE_EFFECTS", native_sources.NATIVE_EFFECTS - {"creep"})
    with pytest.raises(ValueError, match="'creep' is not supported by the native backend"):
        build_native_fmu(ri_small(FUZZ_EFFECTS), tmp_path / "m.fmu")
    assert list(tmp_path.iterdir()) == []


def test_build_fmu_dispatches_to_the_native_backend(tmp_path):
    import build_fmu

    path = build_fmu.build_fmu(ri_small(), tmp_path / "m.fmu", backend="native", model_name="Example 1")
    md = read_model_description(path)
    assert md.modelName == "Example 1" and md.coSimulation.needsExecutionTool is False
    t, u = sampled_input(60)
    assert np.abs(simulate_fmu(path, t, u) - simulate(ri_small(), t, u).y).max() < 1e-10


def test_missing_compiler_and_failed_build_leave_no_file(tmp_path):
    from fitter.core import CallableRate

    target = tmp_path / "m.fmu"
    model = rd_model().replace(g=CallableRate(g3))
    with pytest.raises(TypeError, match="tabulate"):
        build_native_fmu(model, target)
    with pytest.raises(NativeBuildError, match="--backend python"):
        build_native_fmu(ri_small(), target, cc="no-such-compiler-xyz")
    with pytest.raises(NativeBuildError, match="compiler failed"):
        build_native_fmu(ri_small(), target, cc="false")
    assert list(tmp_path.iterdir()) == []


def test_benchmark_gain_fmu_is_valid_and_computes_k_u(tmp_path):
    from fitter.fmu.native import build_gain_fmu

    path = build_gain_fmu(tmp_path / "gain.fmu")
    t, u = sampled_input(50)
    assert validate_fmu_file(path) == []
    assert np.array_equal(simulate_fmu(path, t, u), 2.0 * u)


# --------------------------------------------------------------------- robustness


def _driver(mode: str, fmu_path: Path, *arguments, env: dict | None = None):
    environment = {**os.environ, "PYTHONPATH": str(REPO), **(env or {})}
    return subprocess.run(
        [sys.executable, __file__, mode, str(fmu_path), *map(str, arguments)],
        capture_output=True,
        text=True,
        env=environment,
        cwd=REPO,
        timeout=300,
    )


@pytest.mark.parametrize("name", FUZZ_PARAMETERS)
def test_random_call_sequences_never_crash(fmus, name):
    result = _driver("fuzz", fmus[name], name, 250)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "fuzz: 250 sequences" in result.stdout


def test_sanitized_build_runs_clean(tmp_path):
    runtime = subprocess.run(["cc", "-print-file-name=libasan.so"], capture_output=True, text=True).stdout.strip()
    assert os.path.isabs(runtime), "the C compiler ships no AddressSanitizer runtime"
    env = {
        "LD_PRELOAD": runtime,
        "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=1",
        "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1",
    }
    runs = [
        ("fuzz", "fuzz", (60,), "fuzz: 60 sequences"),
        ("fuzz", "fuzz_rd", (60,), "fuzz: 60 sequences"),
        ("check", "rd_effects", (), "check: rd_effects kernel match"),
        ("check", "rd_one_sided", (), "check: rd_one_sided kernel match"),
    ]
    for mode, name, arguments, expected in runs:
        path = build_native_fmu(MODELS[name](), tmp_path / f"{name}.fmu", sanitize=True)
        result = _driver(mode, Path(path), name, *arguments, env=env)
        assert result.returncode == 0, result.stdout + result.stderr
        assert expected in result.stdout
        assert "AddressSanitizer" not in result.stderr and "runtime error" not in result.stderr
    # and in a sanitized C host, without LD_PRELOAD
    path = tmp_path / "rd_effects.fmu"
    unzipdir = extract(str(path), str(tmp_path / "unzipped"))
    y = _run_c_host(
        unzipdir,
        read_model_description(str(path)),
        tmp_path,
        ("-fsanitize=address,undefined", "-fno-sanitize-recover=undefined"),
    )
    t = 0.05 * np.arange(200)
    assert np.abs(y - simulate(MODELS["rd_effects"](), t, np.sin(0.7 * t)).y).max() < 1e-10


# --------------------------------------------------------------------- fuzz driver


class Reference:
    """What the FMU must do: the FMI 2.0 CS state machine and the Python Stepper.

    `invalid`: the parameters set so far make no model (a rate table with a
    repeated or zero slope); the FMU must then refuse to compute y and to end
    initialization.
    """

    def __init__(self, model, variables):
        self.base = model.to_dict()
        self.paths = {v.name: v.path for v in variables}
        self.reset()

    def reset(self):
        self.mode, self.values, self.t0 = "instantiated", copy.deepcopy(self.base), 0.0
        self.stepper = Stepper(model_from_dict(self.values), 0.0, 0.0)
        self.invalid = False

    @staticmethod
    def accepts(name, value):
        """Finite, and within an effect parameter's range (`fitter.core.effects.REGISTRY`)."""
        effect, _, param = name.partition(".")
        spec = REGISTRY.get(effect)
        par = next((p for p in spec.parameters if p.name == param), None) if spec else None
        return par.allows(value) if par else math.isfinite(value)

    def set_parameter(self, name, value):
        node = self.values
        for key in self.paths[name][:-1]:
            node = node[key]
        node[self.paths[name][-1]] = value
        try:
            model = model_from_dict(self.values)
        except ValueError:
            self.invalid = True
            return
        self.invalid = False
        self.stepper = Stepper(model, self.t0, self.stepper.u)


def _loaded(fmu_path: str):
    """An uninstantiated FMU2Slave of the FMU, and logging callbacks."""
    md = read_model_description(fmu_path)
    fmu = FMU2Slave(
        guid=md.guid,
        unzipDirectory=extract(fmu_path),
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName="driver",
    )
    return fmu, collecting_callbacks([])


def _kernel_match(fmu, callbacks, model) -> None:
    """Sample-and-step run equals `simulate`; a serialized mid-run state replays it exactly."""
    vr = {v.name: v.value_reference for v in model_variables(model)}
    t, u = sampled_input(150)
    fmu.instantiate(callbacks=callbacks)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    y, blob = [], None
    for k in range(len(u)):
        fmu.setReal([vr["u"]], [u[k]])
        y.append(fmu.getReal([vr["y"]])[0])
        if k == 60:
            state = fmu.getFMUstate()
            blob = fmu.serializeFMUstate(state)
            fmu.freeFMUstate(state)
        if k + 1 < len(u):
            fmu.doStep(t[k], t[k + 1] - t[k])
    state = fmu.deSerializeFMUstate(blob)
    fmu.setFMUstate(state)
    fmu.freeFMUstate(state)
    replay = [fmu.getReal([vr["y"]])[0]]
    for k in range(61, len(u)):
        fmu.doStep(t[k - 1], t[k] - t[k - 1])
        fmu.setReal([vr["u"]], [u[k]])
        replay.append(fmu.getReal([vr["y"]])[0])
    fmu.fmi2FreeInstance(fmu.component)  # keeps the library loaded, unlike freeInstance
    assert np.abs(np.array(y) - simulate(model, t, u).y).max() < 1e-10
    assert replay == y[60:]


def _fuzz(fmu_path: str, name: str, examples: int) -> None:
    from hypothesis import HealthCheck, given, settings, strategies as st

    fmu, callbacks = _loaded(fmu_path)
    model = MODELS[name]()
    variables = model_variables(model)
    vr = {v.name: v.value_reference for v in variables}
    _kernel_match(fmu, callbacks, model)
    print("fuzz: kernel match")

    values = st.sampled_from([0.3, -0.5, 1.2, 0.0, math.nan, math.inf, -math.inf]) | st.floats(-2.0, 2.0)
    set_u = st.tuples(st.just("set_u"), values)
    get_y = st.tuples(st.just("get_y"))
    step = st.tuples(
        st.just("step"),
        st.sampled_from([0.05, 0.3, 1e-3, 0.05, 0.0, -0.1, math.nan]),
        st.sampled_from([0.0, 0.0, 0.0, 1.0]),
    )
    ops = st.one_of(  # stepping calls repeated: drawn more often
        set_u,
        get_y,
        step,
        set_u,
        get_y,
        step,
        st.tuples(
            st.sampled_from(
                [
                    "setup",
                    "enter",
                    "exit",
                    "terminate",
                    "reset",
                    "get_state",
                    "status",
                    "discard",
                    "get_unknown",
                    "null",
                ]
            )
        ),
        st.tuples(
            st.just("set_param"),
            st.sampled_from(FUZZ_PARAMETERS[name]),
            values | st.sampled_from([-1.0, -0.3, 0.4, 1.5]),
        ),
        st.tuples(st.sampled_from(["set_state", "free_state", "roundtrip"]), st.integers(0, 3)),
        st.tuples(st.just("garbage"), st.binary(max_size=64)),
        st.tuples(st.just("set_order"), st.integers(1, 3)),
    )

    tally = {True: 0, False: 0}

    def expect(status, ok):
        assert status == (0 if ok else 3), (status, ok)
        tally[ok] += 1

    prefixes = st.sampled_from([[], [("enter",)], [("enter",), ("exit",)]])

    @settings(
        max_examples=examples, derandomize=True, deadline=None, database=None, suppress_health_check=list(HealthCheck)
    )
    @given(prefixes, st.lists(ops, min_size=10, max_size=40))
    def sequence(prefix, calls):
        calls = prefix + calls
        ref = Reference(model, variables)
        fmu.instantiate(callbacks=callbacks)
        c = fmu.component
        states: list[tuple] = []
        try:
            for op in calls:
                run(op, ref, c, states)
        finally:
            for handle, _ in states:
                fmu.freeFMUstate(handle)
            fmu.fmi2FreeInstance(c)

    def run(op, ref, c, states):
        kind, mode = op[0], ref.mode
        configure = mode in ("instantiated", "initialization")
        if kind == "setup":
            expect(status_of(fmu.setupExperiment, None, 0.0, 0.5), mode == "instantiated")
            if mode == "instantiated":
                ref.t0 = 0.5
                ref.stepper.reset(0.5, ref.stepper.u, ref.stepper.x_a)
        elif kind in ("enter", "exit", "terminate"):
            source, target, call = {
                "enter": ("instantiated", "initialization", fmu.enterInitializationMode),
                "exit": ("initialization", "stepping", fmu.exitInitializationMode),
                "terminate": ("stepping", "terminated", fmu.terminate),
            }[kind]
            ok = mode == source and not (kind == "exit" and ref.invalid)
            expect(status_of(call), ok)
            ref.mode = target if ok else mode
        elif kind == "reset":
            expect(status_of(fmu.reset), True)
            ref.reset()
        elif kind == "get_y":
            readable = mode in ("initialization", "stepping", "terminated") and not ref.invalid
            try:
                value = fmu.getReal([vr["y"]])[0]
                assert readable
                expected = ref.stepper.output()
                assert abs(value - expected) <= 1e-10 * max(1.0, abs(expected)), (value, expected)
            except FMICallException as exc:
                assert exc.status == 3 and not readable
        elif kind == "get_state":
            handle = fmu.getFMUstate()
            states.append((handle, copy.deepcopy(ref.__dict__)))
        elif kind in ("set_state", "free_state", "roundtrip") and op[1] < len(states):
            handle, saved = states[op[1]]
            if kind == "set_state":
                fmu.setFMUstate(handle)
                ref.__dict__.update(copy.deepcopy(saved))
            elif kind == "free_state":
                fmu.freeFMUstate(handle)
                assert handle.value is None
                states.pop(op[1])
            else:
                copy_handle = fmu.deSerializeFMUstate(fmu.serializeFMUstate(handle))
                states.append((copy_handle, copy.deepcopy(saved)))
        elif kind == "garbage":
            expect(status_of(fmu.deSerializeFMUstate, op[1] or b"\0"), False)
        elif kind == "status":
            ok = mode in ("stepping", "terminated")
            value = c_double()
            expect(status_of(fmu.fmi2GetRealStatus, c, fmi2LastSuccessfulTime, byref(value)), ok)
            assert not ok or value.value == ref.stepper.t
        elif kind == "discard":
            assert status_of(fmu.getStatus, fmi2DoStepStatus) == (2 if mode in ("stepping", "terminated") else 3)
        elif kind == "get_unknown":
            expect(status_of(fmu.getReal, [4242]), False)
        elif kind == "null":
            expect(status_of(fmu.fmi2GetReal, c, None, 1, None), False)
            expect(status_of(fmu.fmi2GetFMUstate, c, None), False)
            expect(status_of(fmu.fmi2SerializedFMUstateSize, c, None, byref(c_size_t())), False)
            expect(status_of(fmu.fmi2SetString, c, None, 1, None), False)
            expect(status_of(fmu.fmi2DoStep, None, 0.0, 0.1, 0), False)
            expect(status_of(fmu.fmi2SetFMUstate, c, c_void_p(None)), False)
        elif kind == "set_u":
            ok = mode != "terminated" and math.isfinite(op[1])
            expect(status_of(fmu.setReal, [vr["u"]], [op[1]]), ok)
            if ok:
                ref.stepper.set_input(op[1])
        elif kind == "set_param":
            ok = configure and ref.accepts(op[1], op[2])
            expect(status_of(fmu.setReal, [vr[op[1]]], [op[2]]), ok)
            if ok:
                ref.set_parameter(op[1], op[2])
        elif kind == "set_order":
            ok = mode != "terminated" and op[1] == model.order
            expect(status_of(fmu.setInteger, [vr["order"]], [op[1]]), ok)
        elif kind == "step":
            h, offset = op[1], op[2]
            ok = mode == "stepping" and math.isfinite(h) and h > 0 and offset == 0.0
            expect(status_of(fmu.doStep, ref.stepper.t + offset, h), ok)
            if ok:
                ref.stepper.do_step(h)

    sequence()
    fmu.freeLibrary()
    print(f"fuzz: {examples} sequences, {tally[True]} calls accepted, {tally[False]} refused")


if __name__ == "__main__" and len(sys.argv) == 5 and sys.argv[1] == "fuzz":
    _fuzz(sys.argv[2], sys.argv[3], int(sys.argv[4]))
elif __name__ == "__main__" and len(sys.argv) == 4 and sys.argv[1] == "check":
    loaded = _loaded(sys.argv[2])
    _kernel_match(*loaded, MODELS[sys.argv[3]]())
    loaded[0].freeLibrary()
    print(f"check: {sys.argv[3]} kernel match")


# --------------------------------------------------------------------- input interpolation


def _standard_host(md, unzipdir, t, u, derivatives: bool) -> np.ndarray:
    """The co-simulation loop of fmpy's simulate_fmu, fmusim and the Compliance Checker: set u(t_k)
    (and, with `derivatives`, du/dt = (u_k+1 - u_k) / h by fmi2SetRealInputDerivatives, as fmpy's
    set_input_derivatives=True does), doStep(t_k, h), record y at t_k+1.  (fmpy 0.3.32's own
    set_input_derivatives fails for a single input: it assigns one derivative into a 9-element array.)"""
    inst = Instance(md, unzipdir, u0=u[0])
    y = np.empty(len(t))
    y[0] = inst.y()
    for k in range(len(t) - 1):
        h = t[k + 1] - t[k]
        inst.set("u", u[k])
        if derivatives:
            inst.fmu.fmi2SetRealInputDerivatives(
                inst.fmu.component, (c_uint * 1)(inst.vr["u"]), 1, (c_int * 1)(1), (c_double * 1)((u[k + 1] - u[k]) / h)
            )
        inst.step(h)
        y[k + 1] = inst.y()
    inst.free()
    return y


@pytest.mark.parametrize("name", ["ri", "rd_effects"])
def test_input_derivatives_remove_the_one_step_lag_of_a_standard_host(unzipped, name):
    """With canInterpolateInputs and du/dt set, a standard host's loop reproduces the in-process simulation of
    the piecewise-linear input at every output time; without, y(t_k+1) is the Stepper's output for the input
    held at u(t_k) (the documented one-step lag)."""
    t = np.linspace(0.0, 6.0, 601)
    u = 1.3 * np.sin(1.9 * t) + 0.4 * np.sin(5.1 * t + 0.2)
    ref = simulate(MODELS[name](), t, u).y
    md, unzipdir = unzipped[name]
    assert md.coSimulation.canInterpolateInputs
    with_d = _standard_host(md, unzipdir, t, u, True)
    assert np.abs(with_d - ref).max() <= 1e-9 * max(1.0, np.abs(ref).max())
    held = _standard_host(md, unzipdir, t, u, False)
    st = Stepper(MODELS[name](), t0=t[0], u0=u[0])  # the documented lag: y(t_k+1) for u held at u(t_k)
    step_ref = [st.output()]
    for k in range(len(t) - 1):
        st.set_input(u[k])
        st.do_step(t[k + 1] - t[k])
        step_ref.append(st.output())
    assert np.abs(held[1:] - np.array(step_ref[1:])).max() <= 1e-9 * max(1.0, np.abs(ref).max())
    assert np.abs(held - ref).max() > 1e-3 * np.ptp(ref)


def test_input_derivatives_of_order_two_or_of_a_parameter_are_refused(unzipped):
    md, unzipdir = unzipped["ri"]
    inst = Instance(md, unzipdir)
    vr = (c_uint * 1)(inst.vr["u"])
    assert (
        status_of(inst.fmu.fmi2SetRealInputDerivatives, inst.fmu.component, vr, 1, (c_int * 1)(2), (c_double * 1)(1.0))
        == 3
    )
    assert any("only order 1 is supported" in line for line in inst.log)
    param = next(v.valueReference for v in md.modelVariables if v.causality == "parameter")
    assert (
        status_of(
            inst.fmu.fmi2SetRealInputDerivatives,
            inst.fmu.component,
            (c_uint * 1)(param),
            1,
            (c_int * 1)(1),
            (c_double * 1)(1.0),
        )
        == 3
    )
    assert (
        status_of(
            inst.fmu.fmi2SetRealInputDerivatives, inst.fmu.component, vr, 1, (c_int * 1)(1), (c_double * 1)(math.nan)
        )
        == 3
    )
    inst.free()


def test_metadata_version_units_and_a_rounded_step(tmp_path):
    """generationTool and version carry the package version; an SI unit gets its BaseUnit (um: m, factor
    1e-6; V: kg m^2 s^-3 A^-1); the DefaultExperiment step is written as a person would (0.0025)."""
    from fitter.core.models import Experiment, Signal, Signals
    from fitter.fmu.model_description import package_version

    model = ri_model().replace(
        signals=Signals(input=Signal("u", "V", "voltage"), output=Signal("y", "um", "stroke")),
        experiment=Experiment(0.0, 6.0, 0.0024999999999999467),
    )
    md = read_model_description(build_native_fmu(model, str(tmp_path / "m.fmu")))
    assert md.generationTool == f"semilinear-duhem {package_version()}" and md.version == package_version()
    assert md.defaultExperiment.stepSize == "0.0025"
    units = {u.name: u.baseUnit for u in md.unitDefinitions}
    assert (units["um"].m, units["um"].factor) == (1, 1e-6)
    assert (units["V"].kg, units["V"].m, units["V"].s, units["V"].A, units["V"].factor) == (1, 2, -3, -1, 1.0)
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(tmp_path / "m.fmu")) == []


def test_a_model_with_timed_effects_is_not_called_rate_independent(tmp_path):
    md = read_model_description(build_native_fmu(ri_model(ALL_EFFECTS), str(tmp_path / "e.fmu")))
    assert md.modelName == ("semilinear Duhem RI model, order 3 with " + ", ".join(e["effect"] for e in ALL_EFFECTS))
    assert "so the model is not rate independent although its base is" in md.description
    plain = read_model_description(build_native_fmu(ri_model(), str(tmp_path / "p.fmu")))
    assert plain.modelName == "semilinear Duhem RI model, order 3" and "not rate independent" not in plain.description


def test_every_single_byte_flip_of_a_serialized_state_is_refused(unzipped):
    """The serialized state carries a CRC-32 of its header and model bytes: each of its bytes flipped in turn
    is refused with fmi2Error (before: 352 of 416 flips were accepted silently); the intact state restores."""
    md, unzipdir = unzipped["ri_effects"]
    inst = Instance(md, unzipdir, u0=0.2)
    inst.sample(0.7)
    inst.step(0.05)
    fmu = inst.fmu
    state = fmu.getFMUstate()
    blob = bytes(fmu.serializeFMUstate(state))
    fmu.freeFMUstate(state)
    refused = 0
    for i in range(len(blob)):
        bad = bytearray(blob)
        bad[i] ^= 0x5A
        try:
            fmu.freeFMUstate(fmu.deSerializeFMUstate(bytes(bad)))
        except FMICallException as exc:
            refused += exc.status == 3
    assert refused == len(blob)
    good = fmu.deSerializeFMUstate(blob)
    y = inst.sample(1.1)
    inst.sample(-0.4)
    fmu.setFMUstate(good)
    assert inst.sample(1.1) == y
    fmu.freeFMUstate(good)
    inst.free()


def _started(model, t, u, reverse: bool = False):
    """`model` with its effects' stored start settled on (t, u) (or on the reversed input)."""
    from fitter.core.effects import settled_state, with_start
    from fitter.core.kernel import flows

    return with_start(model, settled_state(model, t, -u if reverse else u, model.x0, flows(model)))


@pytest.mark.parametrize("make", [ri_model, rd_model])
def test_stored_effect_start_and_its_parameters_run_as_in_python(make, tmp_path):
    """A model whose effects store their start (a fit on single cycles) starts there in the native FMU, and
    the ``<effect>.start.<state>`` parameters move it, as `duhem validate --x0 fitted` sets them."""
    from fitter.fmu.variables import start_state_values

    t, u = sampled_input(200)
    model = _started(make(ALL_EFFECTS), t, u)
    path = build_native_fmu(model, tmp_path / "started.fmu")
    ref = simulate(model, t, u).y
    scale = max(1.0, np.abs(ref).max())
    assert np.abs(simulate_fmu(path, t, u) - ref).max() <= 1e-10 * scale
    assert np.abs(ref - simulate(make(ALL_EFFECTS), t, u).y).max() > 1e-3
    other = _started(make(ALL_EFFECTS), t, u, reverse=True).replace(x0=np.asarray(model.x0) + 0.05)
    moved = simulate(other, t, u).y
    assert np.abs(moved - ref).max() > 1e-3
    assert np.abs(simulate_fmu(path, t, u, start=start_state_values(other)) - moved).max() <= 1e-10 * scale


_FREED_TWICE = """
import sys
from ctypes import c_double, c_uint
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

path = sys.argv[1]
md = read_model_description(path)
fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(path), modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName="twice")
fmu.instantiate()
c = fmu.component
fmu.fmi2FreeInstance(c)
fmu.fmi2FreeInstance(c)
try:
    status = fmu.fmi2GetReal(c, (c_uint * 1)(1), 1, (c_double * 1)())
except FMICallException as exc:
    status = exc.status
print("status", status, flush=True)
"""


def test_a_freed_instance_is_refused_not_read(tmp_path):
    """fmi2FreeInstance twice, then fmi2GetReal on the freed component (a careless host): the native FMU refuses
    both (fmi2Error) without reading freed memory (the live instances are a list the component is looked up in;
    a check of the instance's own magic number read the freed block).  Under AddressSanitizer, which reports any
    read of freed memory; in a subprocess, so that a crash fails the test, not pytest."""
    runtime = subprocess.run(["cc", "-print-file-name=libasan.so"], capture_output=True, text=True).stdout.strip()
    assert os.path.isabs(runtime), "the C compiler ships no AddressSanitizer runtime"
    env = {**os.environ, "LD_PRELOAD": runtime, "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=1"}
    path = build_native_fmu(MODELS["ri"](), tmp_path / "ri.fmu", sanitize=True)
    result = subprocess.run(
        [sys.executable, "-c", _FREED_TWICE, str(path)], capture_output=True, text=True, timeout=120, env=env
    )
    assert result.returncode == 0 and "AddressSanitizer" not in result.stderr, result.stderr[-2000:]
    assert result.stdout.strip().endswith("status 3")
