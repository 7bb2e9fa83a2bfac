"""The batch's constants and its error (the `fitter.batch` docstring says what each means)."""

from __future__ import annotations

import re

from fitter.core.errors import DuhemError

BATCH_FORMAT = 1
"""Version of the per-device outputs; part of the input hash (a change re-runs every device)."""
OUTLIER_Z = 3.5
"""A device is an outlier for a parameter when its robust z-score exceeds this (Iglewicz & Hoaglin)."""
MIN_GROUP = 4
"""Fewest devices of one kind and order among which outliers are looked for."""
RETRIES = 2
"""Dask ``retries=`` of a device task (an unexpected exception; a dead worker is the scheduler's affair)."""
DASK_MISSING = (
    "duhem batch needs dask.distributed, which is not installed: "
    "pip install 'semilinear-duhem[batch]' (or: pip install 'dask[distributed]')"
)

REQUIRED = ("device", "recordings")
OPTIONAL = ("time", "input", "output", "input_unit", "output_unit")
DEFAULT_COLUMNS = {"time": "time", "input": "u", "output": "y"}
RESERVED = {"summary.csv", "summary.json", "index.html"}
SAFE_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}$")
KNOWN_ERRORS = (DuhemError, ValueError, OSError, ArithmeticError)


class BatchError(DuhemError):
    """A bad manifest or batch option; the message names the file, row and value."""
