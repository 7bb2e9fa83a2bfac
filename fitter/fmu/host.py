"""Drive an exported FMU with fmpy, and validate its modelDescription (FMPy style).

Simulation and validation are kept apart: `validate_fmu_file` only reads the
file; `simulate_fmu` loads the binary and runs it.

`simulate_fmu` is the host that the FMU's input semantics are written for: at
every sample t_k it sets u(t_k), reads y(t_k), then steps to t_{k+1}.  With
that host the FMU reproduces `fitter.core.simulate` of the sampled input.
"""
from __future__ import annotations

import json
import os
import shutil
import zipfile
from ctypes import byref
from pathlib import Path

import numpy as np

from fitter.core.errors import DuhemError
from fitter.core.models import model_from_dict
from fitter.data.recordings import check_samples

_FMI2_FATAL = 4

__all__ = ["simulate_fmu", "validate_fmu_file", "model_in_fmu", "collecting_callbacks", "FmuRunError"]


class FmuRunError(DuhemError, RuntimeError):
    """The FMU could not be loaded or driven; the message says why."""


def validate_fmu_file(fmu_path: str | os.PathLike) -> list[str]:
    """fmpy's findings on the FMU's modelDescription (empty: valid).

    Checks the XML schema, variable names, ModelStructure, start values,
    causality/variability combinations and units (`fmpy.validation.validate_fmu`).
    """
    from fmpy.validation import validate_fmu

    if not Path(fmu_path).is_file():
        raise FileNotFoundError(f"{fmu_path}: no such FMU file")
    return list(validate_fmu(str(fmu_path)))


def model_in_fmu(fmu_path: str | os.PathLike):
    """The model stored in the FMU's ``resources/model.json`` (None when there is none)."""
    with zipfile.ZipFile(fmu_path) as z:
        if "resources/model.json" not in z.namelist():
            return None
        data = json.loads(z.read("resources/model.json").decode("utf-8"))
    return model_from_dict(data, source=f"{fmu_path}!resources/model.json")


def _check_input(t, u, fmu_path) -> tuple[np.ndarray, np.ndarray]:
    """t (the sample index when None) and u as float arrays, checked by `check_samples`."""
    u = np.asarray(u, dtype=float).ravel()
    t = np.arange(u.size, dtype=float) if t is None else np.asarray(t, dtype=float).ravel()
    t, u, _ = check_samples(t, u, source=f"input of {Path(fmu_path).name}", min_samples=1)
    return t, u


def _value_references(md) -> tuple[int, int]:
    refs = {v.name: v.valueReference for v in md.modelVariables}
    missing = [n for n in ("u", "y") if n not in refs]
    if missing:
        raise FmuRunError(f"the FMU has no variable(s) {', '.join(missing)}: not a duhem FMU")
    return refs["u"], refs["y"]


def collecting_callbacks(messages: list[str]):
    """fmpy FMI 2.0 callbacks whose logger appends "[STATUS] message" to `messages`.

    Keep the returned object alive as long as the instance lives.  Instantiate
    with ``loggingOn=True``: pythonfmu FMUs pass even their fatal errors to the
    logger only when logging is on.
    """
    from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                           fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
    from fmpy import calloc, free
    from fmpy.logging import addLoggerProxy

    labels = ["OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING"]

    def logger(component, instance_name, status, category, message):
        label = labels[status] if 0 <= status < len(labels) else str(status)
        messages.append(f"[{label}] {message.decode('utf-8', 'replace')}")

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    addLoggerProxy(byref(callbacks))
    return callbacks


def _release(fmu, instantiated: bool) -> None:
    """Free the instance (or only the library when instantiation failed).

    Not called after fmi2Fatal: FMI 2.0 allows no further call then, and a
    pythonfmu FMU crashes on fmi2FreeInstance after a fatal error (its
    exception path already released its Python objects).
    """
    if instantiated:
        fmu.freeInstance()
    else:
        fmu.freeLibrary()


def simulate_fmu(fmu_path: str | os.PathLike, t, u) -> np.ndarray:
    """Output y at every sample of (t, u), from the FMU driven by fmpy's `FMU2Slave`.

    At each sample k: set u_k, read y_k, then ``doStep(t_k, t_{k+1} - t_k)``.
    `t` may be None for the sample index (rate-independent models ignore time).
    Raises `FmuRunError` when the FMU fails (with fmpy's message).
    """
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    t, u = _check_input(t, u, fmu_path)
    if not Path(fmu_path).is_file():
        raise FileNotFoundError(f"{fmu_path}: no such FMU file")
    md = read_model_description(str(fmu_path))
    if md.coSimulation is None:
        raise FmuRunError(f"{fmu_path}: not a Co-Simulation FMU")
    vr_u, vr_y = _value_references(md)
    unzipdir = extract(str(fmu_path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="duhem")
    y = np.empty(len(u))
    messages: list[str] = []
    callbacks = collecting_callbacks(messages)
    instantiated = fatal = False
    try:
        fmu.instantiate(callbacks=callbacks, loggingOn=True)
        instantiated = True
        fmu.setupExperiment(startTime=float(t[0]))
        fmu.enterInitializationMode()
        fmu.setReal([vr_u], [float(u[0])])
        fmu.exitInitializationMode()
        for k in range(len(u)):
            fmu.setReal([vr_u], [float(u[k])])
            y[k] = fmu.getReal([vr_y])[0]
            if k + 1 < len(u):
                fmu.doStep(currentCommunicationPoint=float(t[k]),
                           communicationStepSize=float(t[k + 1] - t[k]))
        fmu.terminate()
    except Exception as exc:  # fmpy raises FMICallException (and OSError on load)
        fatal = getattr(exc, "status", None) == _FMI2_FATAL
        log = "; ".join(messages[-3:])
        raise FmuRunError(f"{fmu_path}: {exc}" + (f" FMU log: {log}" if log else "")) from exc
    finally:
        if not fatal:
            _release(fmu, instantiated)
        shutil.rmtree(unzipdir, ignore_errors=True)
    return y
