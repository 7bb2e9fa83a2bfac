"""Drive an exported FMU with fmpy, and validate its modelDescription (FMPy style).

Simulation and validation are kept apart: `validate_fmu_file` only reads the
file; `simulate_fmu` loads the binary and runs it.

`simulate_fmu` is the host that the FMU's input semantics are written for: at
every sample t_k it sets u(t_k), reads y(t_k), then steps to t_{k+1}.  With
that host the FMU reproduces `fitter.core.simulate` of the sampled input.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

__all__ = ["simulate_fmu", "validate_fmu_file", "FmuRunError"]


class FmuRunError(RuntimeError):
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


def _check_input(t, u) -> tuple[np.ndarray, np.ndarray]:
    u = np.asarray(u, dtype=float).ravel()
    t = np.arange(len(u), dtype=float) if t is None else np.asarray(t, dtype=float).ravel()
    if len(t) != len(u):
        raise ValueError(f"t and u differ in length ({len(t)} and {len(u)})")
    if len(u) == 0:
        raise ValueError("empty input")
    for name, a in (("t", t), ("u", u)):
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise ValueError(f"{name}[{bad[0]}] is {a[bad[0]]} (NaN or infinite)")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        raise ValueError(f"time must increase: t[{bad[0] + 1}] = {t[bad[0] + 1]} "
                         f"after t[{bad[0]}] = {t[bad[0]]}")
    return t, u


def _value_references(md) -> tuple[int, int]:
    refs = {v.name: v.valueReference for v in md.modelVariables}
    missing = [n for n in ("u", "y") if n not in refs]
    if missing:
        raise FmuRunError(f"the FMU has no variable(s) {', '.join(missing)}: not a duhem FMU")
    return refs["u"], refs["y"]


def simulate_fmu(fmu_path: str | os.PathLike, t, u) -> np.ndarray:
    """Output y at every sample of (t, u), from the FMU driven by fmpy's `FMU2Slave`.

    At each sample k: set u_k, read y_k, then ``doStep(t_k, t_{k+1} - t_k)``.
    `t` may be None for the sample index (rate-independent models ignore time).
    Raises `FmuRunError` when the FMU fails (with fmpy's message).
    """
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    t, u = _check_input(t, u)
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
    instantiated = False
    try:
        fmu.instantiate()
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
        raise FmuRunError(f"{fmu_path}: {exc}") from exc
    finally:
        if instantiated:
            fmu.freeInstance()
        else:
            fmu.freeLibrary()
        shutil.rmtree(unzipdir, ignore_errors=True)
    return y
