"""The exported FMUs inside a system simulator: libcosim (the Open Simulation Platform's co-simulation engine,
`libcosimpy` from the package index), not a loop written for the test.

The system steps with a fixed macro step h: before each step the host sets the inputs it drives (here an
override manipulator, libcosim's way to drive a variable from outside the system) and after it passes each
connected output to its input.  So an FMU's input is held over each step (no input derivatives), and the
recorded output after the step from t_k is the model's output at t_k: one step late, as fmusim and fmpy's
`simulate_fmu` (docs/fmu.md, "Input interpolation").

What is checked:
- a fitted model's FMU, its input driven by the system and nothing else set (no start values: the FMU starts
  at the input its x0 was fitted at, `first_input`), gives the in-process simulation of the recording to 1e-9
  of the output range, the first sample included;
- a system of two FMUs, the compensator (`--inverse`) driving the plant through a connection, the reference
  driven by the system: the plant follows the reference to 1e-6 of its range, one step late (the
  compensator's u after the step from t_k is its u for y_ref(t_k); the connection hands it to the plant,
  which holds it over the next step), again with no start value set.

OMSimulator, the system simulator the issue names, does not install here: its package on the index is a
source distribution that downloads its binaries from build.openmodelica.org while it builds.
"""

from __future__ import annotations

import numpy as np
import pytest

from fitter.core import simulate
from fitter.fmu.build import build_fmu
from fitter.identification.fit import fit_recordings

from samples import noisy_recording
from test_inverse import reversals, ri2

cosim = pytest.importorskip("libcosimpy", reason="libcosimpy (the test dependency) did not install")
from libcosimpy.CosimEnums import CosimExecutionState  # noqa: E402
from libcosimpy.CosimExecution import CosimExecution  # noqa: E402
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level  # noqa: E402
from libcosimpy.CosimManipulator import CosimManipulator  # noqa: E402
from libcosimpy.CosimObserver import CosimObserver  # noqa: E402
from libcosimpy.CosimSlave import CosimLocalSlave  # noqa: E402

log_output_level(CosimLogLevel.ERROR)
H = 0.01


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A second-order model fitted to a seeded noisy recording of `ri2` whose first input is 1.0 (not 0),
    with its FMU and its compensator FMU (native, FMI 2.0)."""
    u = reversals(seed=4)
    t = H * np.arange(len(u))
    fit = fit_recordings([noisy_recording(ri2(), t, u, noise=0.002, seed=5)], kind="ri", order=2)
    d = tmp_path_factory.mktemp("system")
    return (
        fit.model,
        t,
        u,
        build_fmu(fit.model, d / "plant.fmu", backend="native"),
        build_fmu(fit.model, d / "comp.fmu", backend="native", inverse=True),
    )


class System:
    """A libcosim execution with fixed step H, FMUs by instance name, an override manipulator and a
    last-value observer."""

    def __init__(self, fmus: dict[str, str]):
        self.execution = CosimExecution.from_step_size(step_size=int(round(H * 1e9)))  # nanoseconds
        self.index = {
            name: self.execution.add_local_slave(CosimLocalSlave(fmu_path=path, instance_name=name))
            for name, path in fmus.items()
        }
        self.refs = {
            name: {v.name.decode(): v.reference for v in self.execution.slave_variables(i)}
            for name, i in self.index.items()
        }
        self.manipulator = CosimManipulator.create_override()
        self.observer = CosimObserver.create_last_value()
        self.execution.add_manipulator(manipulator=self.manipulator)
        self.execution.add_observer(observer=self.observer)

    def connect(self, source: str, output: str, target: str, input_: str) -> None:
        self.execution.connect_real_variables(
            self.index[source], self.refs[source][output], self.index[target], self.refs[target][input_]
        )

    def run(self, driven: tuple[str, str], values, recorded: tuple[str, str]) -> np.ndarray:
        """Set `driven` to each value before a step; `recorded` after it."""
        (dn, dv), (rn, rv) = driven, recorded
        out = []
        for v in values:
            self.manipulator.slave_real_values(self.index[dn], [self.refs[dn][dv]], [float(v)])
            assert self.execution.step()
            out.append(self.observer.last_real_values(self.index[rn], [self.refs[rn][rv]])[0])
        assert self.execution.status().state != CosimExecutionState.ERROR.value
        return np.array(out)


def test_fitted_fmu_in_the_system_gives_the_in_process_simulation(fitted):
    model, t, u, plant, _ = fitted
    assert model.first_input == u[0] == 1.0
    y_fmu = System({"plant": plant}).run(("plant", "u"), u, ("plant", "y"))
    y = simulate(model, t, u).y
    assert np.max(np.abs(y_fmu - y)) <= 1e-9 * np.ptp(y)  # y after the step from t_k: y(t_k)
    assert abs(y_fmu[0] - y[0]) <= 1e-12 * np.ptp(y)  # started at first_input, no start value set


def test_compensator_drives_the_plant_in_the_system(fitted):
    """Compensator FMU -> plant FMU through a connection: the plant's output is the reference, one step late."""
    model, t, u, plant, comp = fitted
    y_ref = simulate(model, t, u).y  # a reference the plant can follow, starting where it starts
    system = System({"comp": comp, "plant": plant})
    system.connect("comp", "u", "plant", "u")
    y = system.run(("comp", "y_ref"), y_ref, ("plant", "y"))
    assert np.max(np.abs(y[1:] - y_ref[:-1])) <= 1e-6 * np.ptp(y_ref)
    assert np.max(np.abs(y - y_ref)) > 1e-3 * np.ptp(y_ref)  # the lag is real, not a loose tolerance
