"""The project's exception hierarchy: every domain error is a `DuhemError`.

`DuhemError` subclasses `ValueError` so that callers who catch bad input as
``ValueError`` keep working.  The CLI maps any `DuhemError` to one line on
stderr and a non-zero exit; anything else is a bug.  This module needs only
the standard library: it is shipped inside the FMUs with the rest of `core`.
"""

from __future__ import annotations

__all__ = ["DuhemError", "KernelError", "ModelFileError", "EffectError", "ConvergenceError"]


class DuhemError(ValueError):
    """Base of every error this package raises on purpose (bad input, impossible request)."""


class KernelError(DuhemError):
    """A simulation that cannot be run (bad samples, overflow, invalid model for the input)."""


class ModelFileError(DuhemError):
    """A model file or dict that is not a valid model."""


class EffectError(DuhemError):
    """An effect description that is not valid."""


class ConvergenceError(DuhemError):
    """The convergence condition (spectral radius of the period map < 1) does not hold."""
