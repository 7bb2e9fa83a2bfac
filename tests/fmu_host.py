"""A small fmpy co-simulation host shared by the FMU tests of both backends."""
from __future__ import annotations

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from fitter.fmu.host import collecting_callbacks


def unzip_all(fmus: dict, tmp_path_factory) -> dict:
    """name -> (model description, unzip directory) for built FMUs name -> path."""
    return {name: (read_model_description(path), extract(path, str(tmp_path_factory.mktemp(name))))
            for name, path in fmus.items()}


class Instance:
    """An FMU2Slave instance with its log; variables by name.

    The host sets u(t_k), reads y(t_k) and steps to t_{k+1}, as `run` does.
    Subclasses choose the logging flag and whether `free` terminates first.
    """

    LOGGING_ON = True
    TERMINATE_ON_FREE = True

    def __init__(self, md, unzipdir, name="inst", start=None, u0=0.0, initialise=True):
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                             modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
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

    def run(self, t, u):
        """Sample-and-step through (t, u); y at every sample."""
        y = np.empty(len(u))
        for k in range(len(u)):
            y[k] = self.sample(u[k])
            if k + 1 < len(u):
                self.step(t[k + 1] - t[k])
        return y

    def rollback_runs(self, t, u, k):
        """Run to sample k, save the state (also serialized), run on; then replay
        from the saved and from the deserialized state.  Returns the three runs."""
        self.run(t[:k + 1], u[:k + 1])
        state = self.fmu.getFMUstate()
        blob = self.fmu.serializeFMUstate(state)
        runs = [self.run(t[k:], u[k:])]
        for saved in (state, self.fmu.deSerializeFMUstate(blob)):
            self.fmu.setFMUstate(saved)
            self.t = t[k]
            runs.append(self.run(t[k:], u[k:]))
            self.fmu.freeFMUstate(saved)
        return runs

    def free(self):
        if self.TERMINATE_ON_FREE:
            self.fmu.terminate()
        self.fmu.freeInstance()
