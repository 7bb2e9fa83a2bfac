"""Identification of semilinear Duhem hysteresis models (Oh & Bernstein, IEEE TAC 2007).

The numpy-only core (models, rate functions, the one simulation kernel) lives in
`fitter.core` and is shipped unchanged inside the exported FMUs.
"""
from .core import (ConvergenceError, KernelError, ModelFileError, RateDependentModel,
                   RateIndependentModel, Stepper, TabulatedRate, limiting_loop, load_model,
                   periodic_response, save_model, simulate)

__all__ = ["ConvergenceError", "KernelError", "ModelFileError", "RateDependentModel",
           "RateIndependentModel", "Stepper", "TabulatedRate", "limiting_loop", "load_model",
           "periodic_response", "save_model", "simulate"]
