"""Recordings: one experiment's sampled input and output, loaded from CSV."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .core.models import Signal

__all__ = ["Recording"]


@dataclass
class Recording:
    """One experiment: time t, input u, output y (equal-length float arrays).

    `name` is a short label (the file stem); `input` and `output` carry the
    column names and units; `source` is the file path (or "generated").
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    name: str = "recording"
    input: Signal = field(default_factory=lambda: Signal("u"))
    output: Signal = field(default_factory=lambda: Signal("y"))
    source: str = "generated"

    def __post_init__(self):
        self.t = np.asarray(self.t, dtype=float)
        self.u = np.asarray(self.u, dtype=float)
        self.y = np.asarray(self.y, dtype=float)
        if not (self.t.shape == self.u.shape == self.y.shape and self.t.ndim == 1):
            raise ValueError(f"{self.name}: t, u, y must be 1-D arrays of equal length")
