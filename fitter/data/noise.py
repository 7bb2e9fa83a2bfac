"""Level of white measurement noise on a sampled signal.

``noise_rms(y)``: the RMS of additive white noise, estimated from the
high-pass residual of a local quadratic fit (Savitzky-Golay, `NOISE_WINDOW`
= 7 samples): for white noise of variance s^2 the residual has variance
s^2 (1 - h0), h0 = the filter's centre weight, so

    s = robust_rms(residual) / sqrt(1 - h0),   robust_rms = 1.4826 * median |residual|

(the median discards the few samples at sharp reversals, where a quadratic
does not fit the signal).  Assumes the noise-free signal is locally smooth on
the 7-sample scale; for quantised data it estimates the quantisation noise
(step / sqrt(12)).
"""

from __future__ import annotations

import numpy as np

__all__ = ["NOISE_WINDOW", "noise_rms", "noise_or_zero"]

NOISE_WINDOW = 7
"""Samples in the local quadratic fit of `noise_rms`."""


def noise_rms(y) -> float:
    """Estimated RMS of white measurement noise on y (see the module docstring).

    Raises `ValueError` for fewer than ``2 * NOISE_WINDOW`` samples.
    """
    from scipy.signal import savgol_coeffs, savgol_filter  # here: importing scipy.signal takes 0.8 s

    y = np.asarray(y, dtype=float).ravel()
    if y.size < 2 * NOISE_WINDOW:
        raise ValueError(f"noise estimate needs at least {2 * NOISE_WINDOW} samples, got {y.size}")
    residual = y - savgol_filter(y, NOISE_WINDOW, 2, mode="interp")
    h0 = savgol_coeffs(NOISE_WINDOW, 2)[NOISE_WINDOW // 2]
    return float(1.4826 * np.median(np.abs(residual)) / np.sqrt(1.0 - h0))


def noise_or_zero(y) -> float:
    """`noise_rms(y)`, or 0.0 when y is too short to estimate it."""
    y = np.asarray(y, dtype=float).ravel()
    return noise_rms(y) if y.size >= 2 * NOISE_WINDOW else 0.0
