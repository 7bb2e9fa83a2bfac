"""The stepping contract, the same for every backend that runs a model.

Backends: ``kernel`` (the in-process `fitter.core.Stepper`), ``python`` (the
pythonfmu FMU, driven by fmpy) and ``native`` (the C FMU, driven by fmpy).
A co-simulation host sets u(t_k), reads y(t_k) and steps to t_{k+1}; each
backend must then

* give y_k = `simulate`(model, t, u).y_k, the kernel's exact flow of the
  sampled input (to 1e-10 relative to max(1, |y|));
* start from x0 at the first input: y = C x0 + D u until the first step;
* return the same y when it is read again, and keep it when the host steps
  without a new input (du = 0 moves neither model);
* give the same y at the samples whether the host steps once or 10 or 100
  times per sample period (u linear in between);
* replay exactly from a saved state, also after serializing it.

Backend-specific behaviour (parameters, refusals, fuzzing, sanitizers,
metadata) is tested in test_fmu_python.py and test_fmu_native.py.
"""

from __future__ import annotations

import pickle
from typing import Callable

import numpy as np
import pytest
from samples import rd_model, ri_model, sampled_input
from fmu_host import FmuCache, Host, Instance

from fitter.core import Stepper, simulate

BACKENDS = ("kernel", "python", "native")
MODELS = {"ri": lambda: ri_model(3), "rd": lambda: rd_model(2)}
TOLERANCE = 1e-10


class StepperHost(Host):
    """The in-process kernel behind the host calls: a `fitter.core.Stepper`."""

    def __init__(self, model, u0: float = 0.0):
        self.stepper = Stepper(model, 0.0, u0)
        self.t = 0.0

    def sample(self, u: float) -> float:
        self.stepper.set_input(u)
        return self.y()

    def y(self) -> float:
        return self.stepper.output()

    def step(self, h: float) -> None:
        self.stepper.do_step(h)
        self.t += h

    def get_state(self) -> tuple:
        return self.stepper.get_state()

    def set_state(self, state: tuple) -> None:
        self.stepper.set_state(state)

    def free_state(self, state: tuple) -> None:
        """Nothing to release: the state is a value."""

    def serialize(self, state: tuple) -> bytes:
        return pickle.dumps(state)

    def deserialize(self, blob: bytes) -> tuple:
        return pickle.loads(blob)

    def free(self) -> None:
        """Nothing to release."""


def host_opener(backend: str, model, fmu_cache: FmuCache) -> Callable[..., Host]:
    """A function u0 -> a fresh, initialised host of `model` on `backend` (input u0 at t = 0)."""
    if backend == "kernel":
        return lambda u0=0.0: StepperHost(model, u0)
    md, unzipdir = fmu_cache.unzipped(model, backend)
    return lambda u0=0.0: Instance(md, unzipdir, "contract", u0=u0)


def assert_close(y, ref, what: str) -> None:
    error = np.abs(np.asarray(y) - ref).max()
    assert error <= TOLERANCE * max(1.0, np.abs(ref).max()), f"{what}: max |y - kernel| = {error:.3g}"


def check_output_equals_kernel(open_host, model) -> None:
    t, u = sampled_input()
    ref = simulate(model, t, u).y
    host = open_host(u[0])
    y = host.run(t, u)
    host.free()
    assert np.ptp(ref) > 0.1  # a real response, not a constant
    assert_close(y, ref, "sample-and-step output")


def check_x0_is_the_state_at_the_first_input(open_host, model) -> None:
    host = open_host(0.7)
    assert host.y() == pytest.approx(model.C @ model.x0 + model.D * 0.7, abs=1e-15)
    assert host.sample(-0.2) == pytest.approx(model.C @ model.x0 + model.D * -0.2, abs=1e-15)
    host.step(0.1)  # input held since t = 0: still at x0
    assert host.y() == pytest.approx(model.C @ model.x0 + model.D * -0.2, abs=1e-15)
    host.free()


def check_rereading_and_held_input(open_host) -> None:
    host = open_host()
    for k in range(1, 30):
        host.sample(np.sin(0.3 * k))
        host.step(0.1)
    y1 = host.sample(0.9)
    assert host.y() == y1 and host.y() == y1  # reading again changes nothing
    host.step(0.1)  # held input: the state does not move
    assert host.y() == y1
    assert host.sample(0.5) != y1
    host.free()


def substep_outputs(open_host, t, u, m: int) -> np.ndarray:
    """Host stepping m times per sample period, u linear between samples; y at the samples."""
    host = open_host(u[0])
    y = [host.sample(u[0])]
    for k in range(len(u) - 1):
        h = (t[k + 1] - t[k]) / m
        for j in range(1, m + 1):
            host.step(h)
            value = host.sample(u[k] + (u[k + 1] - u[k]) * j / m)
        y.append(value)
    host.free()
    return np.array(y)


def check_step_size_independence(open_host, model) -> None:
    t = np.arange(41) * 0.1
    u = np.interp(t, [0, 1.0, 2.5, 4.0], [0.0, 1.2, -0.8, 0.6])  # reversals at samples
    outputs = [substep_outputs(open_host, t, u, m) for m in (1, 10, 100)]
    assert np.abs(outputs[1] - outputs[0]).max() < 1e-10
    assert np.abs(outputs[2] - outputs[0]).max() < 1e-10
    assert np.abs(outputs[0] - simulate(model, t, u).y).max() < 1e-10


def check_rollback_replays_exactly(open_host, model) -> None:
    t, u = sampled_input(160)
    host = open_host(u[0])
    first, again, third = host.rollback_runs(t, u, 69)
    host.free()
    assert np.array_equal(first, again) and np.array_equal(first, third)
    assert_close(first, simulate(model, t, u).y[69:], "run after the saved state")


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("backend", BACKENDS)
def test_backend_keeps_the_stepping_contract(fmu_cache, backend, name):
    model = MODELS[name]()
    open_host = host_opener(backend, model, fmu_cache)
    check_output_equals_kernel(open_host, model)
    check_x0_is_the_state_at_the_first_input(open_host, model)
    check_rereading_and_held_input(open_host)
    check_step_size_independence(open_host, model)
    check_rollback_replays_exactly(open_host, model)
