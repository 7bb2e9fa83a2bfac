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
from fitter.data.recordings import Recording, load_recording, load_recordings
from fitter.diagnosis import Diagnosis, diagnose
from fitter.estimator import DuhemEstimator
from fitter.fmu.build import build_fmu
from fitter.fmu.host import simulate_fmu, validate_fmu_file
from fitter.identification.fit import FitResult, fit_recordings
from fitter.identification.rd_triangles import identify_rd_triangles
from fitter.identification.ri_loop import identify_ri_loop

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
