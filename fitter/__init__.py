"""Identification of semilinear Duhem hysteresis models (Oh & Bernstein, IEEE TAC 2007).

The public API, in one import root::

    from fitter import DuhemEstimator, load_recording      # estimator: fit / predict / score / diagnose / export
    from fitter import fit_recordings, diagnose, build_fmu  # the same, as functions
    from fitter import simulate, Stepper, load_model        # the one simulation kernel (fitter.core)
    from fitter import invert, compensate                   # the inverse model: a feedforward compensator

Packages, by responsibility (each depends only on those listed before it):
`fitter.core` (numpy only, shipped inside the FMUs: models, rates, kernel,
effects, periodic map, errors, atomic files) -> `fitter.data` (recordings,
cycles, preparation, metrics) -> `fitter.identification` (parametrisations,
the output-error engine, the paper's estimators, `fit_recordings`) ->
`fitter.diagnosis` -> `fitter.fmu` (model description, native and pythonfmu
builders, the fmpy host) -> `fitter.reports` -> `fitter.estimator`,
`fitter.batch` (`duhem batch` on Dask) -> `fitter.cli`.
"""

import importlib

from fitter.core import (
    Compensation,
    Compensator,
    ConvergenceError,
    DuhemError,
    KernelError,
    ModelFileError,
    RateDependentModel,
    RateIndependentModel,
    Stepper,
    TabulatedRate,
    compensate,
    invert,
    limiting_loop,
    load_model,
    periodic_response,
    save_model,
    simulate,
)
from fitter.core.effects import Effect

_LAZY = {
    "Recording": "fitter.data.recordings",
    "load_recording": "fitter.data.recordings",
    "load_recordings": "fitter.data.recordings",
    "Diagnosis": "fitter.diagnosis",
    "diagnose": "fitter.diagnosis",
    "DuhemEstimator": "fitter.estimator",
    "build_fmu": "fitter.fmu.build",
    "simulate_fmu": "fitter.fmu.host",
    "validate_fmu_file": "fitter.fmu.host",
    "FitResult": "fitter.identification.fit",
    "fit_recordings": "fitter.identification.fit",
    "identify_rd_triangles": "fitter.identification.rd_triangles",
    "identify_ri_loop": "fitter.identification.ri_loop",
}
"""The public names outside `fitter.core`, by the module that holds them: imported on first use (PEP 562), so
that a command or a worker process imports only the packages it runs (the diagnosis' scipy.stats, the FMU
host's fmpy) and not the whole library because it touched `fitter.core`."""


def __getattr__(name: str):
    """A name of `_LAZY`, imported from its module on first use."""
    if name not in _LAZY:
        raise AttributeError(f"module 'fitter' has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "Compensation",
    "Compensator",
    "ConvergenceError",
    "Diagnosis",
    "DuhemError",
    "DuhemEstimator",
    "Effect",
    "FitResult",
    "KernelError",
    "ModelFileError",
    "RateDependentModel",
    "RateIndependentModel",
    "Recording",
    "Stepper",
    "TabulatedRate",
    "build_fmu",
    "compensate",
    "diagnose",
    "fit_recordings",
    "identify_rd_triangles",
    "identify_ri_loop",
    "invert",
    "limiting_loop",
    "load_model",
    "load_recording",
    "load_recordings",
    "periodic_response",
    "save_model",
    "simulate",
    "simulate_fmu",
    "validate_fmu_file",
]
