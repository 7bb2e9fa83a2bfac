"""Co-simulation hosts shared by the FMU tests and the backend contract test.

`Host` is the sample-and-step driver every backend is checked with: at each
sample t_k the host sets u(t_k), reads y(t_k) and steps to t_{k+1}.
`Instance` drives an FMU through fmpy; `FmuCache` builds each FMU once per
test session.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

import build_fmu
from fitter.fmu.host import collecting_callbacks


class FmuCache:
    """Built and unzipped FMUs, one per (backend, model), for the whole session.

    Two models with the same JSON (`to_dict`) share one FMU, so test modules
    that export the same model do not build it twice.
    """

    def __init__(self, directory: Path):
        self._directory = Path(directory)
        self._built: dict[tuple[str, str], str] = {}
        self._unzipped: dict[str, tuple] = {}

    def build(self, model, backend: str) -> str:
        """Path of the FMU of `model` exported with `backend` ("python" or "native")."""
        key = (backend, json.dumps(model.to_dict(), sort_keys=True))
        if key not in self._built:
            target = self._directory / f"{backend}_{len(self._built)}.fmu"
            self._built[key] = build_fmu.build_fmu(model, target, backend=backend)
        return self._built[key]

    def unzipped(self, model, backend: str) -> tuple:
        """(model description, unzip directory) of the FMU of `model`."""
        path = self.build(model, backend)
        if path not in self._unzipped:
            self._unzipped[path] = (read_model_description(path), extract(path, str(Path(path).with_suffix(""))))
        return self._unzipped[path]


class Host:
    """Sample-and-step driving, shared by every backend.

    Subclasses provide the calls of one instance: ``sample(u) -> y`` (set the
    input, read the output), ``y()``, ``step(h)``, and the state calls
    ``get_state``, ``set_state``, ``free_state``, ``serialize`` (state -> bytes)
    and ``deserialize``.  `t` is the host's time.
    """

    t = 0.0

    def run(self, t, u) -> np.ndarray:
        """Sample-and-step through (t, u); y at every sample."""
        y = np.empty(len(u))
        for k in range(len(u)):
            y[k] = self.sample(u[k])
            if k + 1 < len(u):
                self.step(t[k + 1] - t[k])
        return y

    def rollback_runs(self, t, u, k) -> list[np.ndarray]:
        """Run to sample k, save the state (also serialized), run on; then replay
        from the saved and from the deserialized state.  Returns the three runs."""
        self.run(t[: k + 1], u[: k + 1])
        state = self.get_state()
        blob = self.serialize(state)
        runs = [self.run(t[k:], u[k:])]
        for saved in (state, self.deserialize(blob)):
            self.set_state(saved)
            self.t = t[k]
            runs.append(self.run(t[k:], u[k:]))
            self.free_state(saved)
        return runs


class Instance(Host):
    """An FMU2Slave instance with its log; variables by name.

    Subclasses choose the logging flag and whether `free` terminates first.
    """

    LOGGING_ON = True
    TERMINATE_ON_FREE = True

    def __init__(self, md, unzipdir, name="inst", start=None, u0=0.0, initialise=True):
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.fmu = FMU2Slave(
            guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name
        )
        self.log: list[str] = []
        self._callbacks = collecting_callbacks(self.log)
        self.fmu.instantiate(callbacks=self._callbacks, loggingOn=self.LOGGING_ON)
        self.t = 0.0
        if initialise:
            self.initialise(start, u0)

    def initialise(self, start=None, u0=0.0):
        self.fmu.setupExperiment(startTime=0.0)
        for key, value in (start or {}).items():
            self.set(key, value)
        self.fmu.enterInitializationMode()
        self.set("u", u0)
        self.fmu.exitInitializationMode()
        self.t = 0.0

    def set(self, name, value):
        self.fmu.setReal([self.vr[name]], [float(value)])

    def y(self):
        return self.fmu.getReal([self.vr["y"]])[0]

    def sample(self, u):
        self.set("u", u)
        return self.y()

    def step(self, h):
        self.fmu.doStep(currentCommunicationPoint=self.t, communicationStepSize=h)
        self.t += h

    def get_state(self):
        return self.fmu.getFMUstate()

    def set_state(self, state):
        self.fmu.setFMUstate(state)

    def free_state(self, state):
        self.fmu.freeFMUstate(state)

    def serialize(self, state) -> bytes:
        return self.fmu.serializeFMUstate(state)

    def deserialize(self, blob: bytes):
        return self.fmu.deSerializeFMUstate(blob)

    def free(self):
        if self.TERMINATE_ON_FREE:
            self.fmu.terminate()
        self.fmu.freeInstance()
