"""Numpy-only core shipped inside FMUs: models, rate functions, the simulation kernel."""

from .errors import ConvergenceError, DuhemError, EffectError, KernelError, ModelFileError
from .kernel import AffineFlow, Simulation, simulate
from .inverse import Compensation, Compensator, InverseError, compensate, invert
from .models import (
    Experiment,
    RateDependentModel,
    RateIndependentModel,
    Signal,
    Signals,
    load_model,
    model_from_dict,
    save_model,
)
from .stepper import Stepper
from .periodic import convergence_rho, limiting_loop, periodic_response
from .rates import CallableRate, RateFunction, TabulatedRate

__all__ = [
    "AffineFlow",
    "DuhemError",
    "EffectError",
    "KernelError",
    "Simulation",
    "simulate",
    "Experiment",
    "ModelFileError",
    "RateDependentModel",
    "RateIndependentModel",
    "Signal",
    "Signals",
    "load_model",
    "model_from_dict",
    "save_model",
    "ConvergenceError",
    "convergence_rho",
    "limiting_loop",
    "periodic_response",
    "Stepper",
    "CallableRate",
    "RateFunction",
    "TabulatedRate",
    "Compensation",
    "Compensator",
    "InverseError",
    "compensate",
    "invert",
]
