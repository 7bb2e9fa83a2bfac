"""Decimation of long recordings for the output-error search (`fitter.identification.output_error`'s module
docstring, "Decimation"): every turning point of the input kept (of a noisy input, its reversals above the noise),
and an evenly spread subset of samples scored."""

from __future__ import annotations

import numpy as np

from fitter.core.flow import branches
from fitter.data.noise import noise_or_zero

__all__ = ["significant_turns", "keep_indices", "turning_points", "REVERSAL_NOISE", "DENSE_TURNS"]


def turning_points(u: np.ndarray) -> np.ndarray:
    """Indices where the input turns: the samples where the kernel's branch changes (`fitter.core.flow.branches`),
    so the input is monotone between consecutive turning points."""
    branch = branches(np.diff(u))
    return np.flatnonzero(branch[1:] != branch[:-1]) + 1


REVERSAL_NOISE = 4.0
"""On an input that turns every few samples (`DENSE_TURNS`), a reversal smaller than this many times the input's
white-noise RMS (`fitter.data.noise`) is the noise's, not the drive's: the decimation does not keep it
(`significant_turns`)."""
DENSE_TURNS = 8
"""An input with a turning point every this many samples or more often is taken as noisy: the decimation keeps
its `significant_turns` only.  A sparser input keeps every turning point (a drive of short runs has a noise
estimate inflated by its corners, and its small reversals are the drive's)."""


def significant_turns(u: np.ndarray, h: float) -> np.ndarray:
    """The turning points of u (`turning_points`) at which the input then moves back by more than `h`
    (the running extremes of a threshold-h peak detector), and the last candidate extreme.

    With h = 0 every turning point.  Between consecutive kept points the input is monotone to within h, so a
    rate-independent model's state on the kept samples differs from the one on every sample by the state's
    response to reversals of at most h (the input noise's own, for h a few times its RMS)."""
    turns = turning_points(u)
    if h <= 0 or len(turns) < 2:
        return turns
    values = u[turns].tolist()
    up, c, kept = values[0] >= u[0], 0, []
    for k in range(1, len(values)):
        v = values[k]
        if (v > values[c]) if up else (v < values[c]):
            c = k
        elif (values[c] - v if up else v - values[c]) > h:
            kept.append(c)
            up, c = not up, k
    kept.append(c)
    return turns[np.asarray(kept, dtype=int)]


def keep_indices(u: np.ndarray, max_samples: int | None, cycle) -> tuple[np.ndarray, np.ndarray]:
    """Decimation (module docstring): the kept samples (every turning point, or of a densely turning input its
    `significant_turns` above `REVERSAL_NOISE` times its noise, the cycle's ends, every j-th sample and the
    last) and, of them, those scored (a boolean mask: the every-j-th samples and the last)."""
    n = len(u)
    if max_samples is None or n <= max_samples:
        return np.arange(n), np.ones(n, dtype=bool)
    ends = [] if cycle is None else [cycle[0], cycle[1]]
    scored = np.r_[np.arange(0, n, int(np.ceil(n / max_samples))), n - 1]
    turns = turning_points(u)
    if len(turns) > n / DENSE_TURNS:
        turns = significant_turns(u, REVERSAL_NOISE * noise_or_zero(u))
    keep = np.unique(np.r_[scored, turns, ends]).astype(int)
    return keep, np.isin(keep, scored)
