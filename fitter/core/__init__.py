"""Numpy-only core shipped inside FMUs: models, rate functions, the simulation kernel."""
from .kernel import AffineFlow, KernelError, Simulation, simulate
from .models import (Experiment, ModelFileError, RateDependentModel, RateIndependentModel,
                     Signal, Signals, load_model, model_from_dict, save_model)
from .stepper import Stepper
from .periodic import ConvergenceError, convergence_rho, limiting_loop, periodic_response
from .rates import CallableRate, RateFunction, TabulatedRate

__all__ = ["AffineFlow", "KernelError", "Simulation", "simulate", "Experiment", "ModelFileError",
           "RateDependentModel", "RateIndependentModel", "Signal", "Signals", "load_model",
           "model_from_dict", "save_model", "ConvergenceError", "convergence_rho", "limiting_loop",
           "periodic_response", "Stepper", "CallableRate", "RateFunction", "TabulatedRate"]
