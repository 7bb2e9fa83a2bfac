"""Level of white measurement noise on a sampled signal.

``noise_rms(y)``: the RMS of additive white noise, from two estimates, each of which a deterministic signal
can only inflate: the local one, unless the spectral one is below `CURVATURE` times it (the two agree on
white noise; the local one then read the signal's curvature as noise):

* local (`local_noise_rms`): the high-pass residual of a local quadratic fit (Savitzky-Golay, `NOISE_WINDOW`
  = 7 samples): for white noise of variance s^2 the residual has variance s^2 (1 - h0), h0 = the filter's
  centre weight, so

      s = robust_rms(residual) / sqrt(1 - h0),   robust_rms = 1.4826 * median |residual|

  (the median discards the few samples at sharp reversals, where a quadratic does not fit the signal).  It
  assumes the noise-free signal is locally smooth on the 7-sample scale; for quantised data it estimates the
  quantisation noise (step / sqrt(12)).  A signal with few samples per cycle (a sine of 8-20 samples per
  period) is not: its curvature reads as noise;
* spectral (`spectral_noise_rms`, from `SPECTRAL_MIN` samples): white noise has a flat one-sided power
  spectral density 2 s^2 (unit sampling rate); Welch's estimate (Hann windows of `SPECTRAL_SEGMENT` samples,
  linear trend removed) puts a periodic signal in a few harmonic bins and a piecewise-smooth one in the lowest
  ones, so the median over the bins is the noise's: s = sqrt(median(P) / 2).  Coloured content spread over
  the whole band (a measured drive's own jitter) inflates it, and the local estimate is then the smaller.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "NOISE_WINDOW",
    "CURVATURE",
    "SPECTRAL_MIN",
    "local_noise_rms",
    "spectral_noise_rms",
    "noise_rms",
    "noise_or_zero",
]

NOISE_WINDOW = 7
"""Samples in the local quadratic fit of `local_noise_rms`."""
SPECTRAL_SEGMENT = 256
"""Samples per Welch segment of `spectral_noise_rms` (fewer for a shorter signal)."""
CURVATURE = 0.5
"""`noise_rms` takes the spectral estimate when it is below this fraction of the local one."""
SPECTRAL_MIN = 64
"""Shorter signals get the local estimate alone: too few spectral bins for a median."""


def local_noise_rms(y) -> float:
    """The local quadratic estimate of the module docstring."""
    from scipy.signal import savgol_coeffs, savgol_filter  # here: importing scipy.signal takes 0.8 s

    y = np.asarray(y, dtype=float).ravel()
    residual = y - savgol_filter(y, NOISE_WINDOW, 2, mode="interp")
    h0 = savgol_coeffs(NOISE_WINDOW, 2)[NOISE_WINDOW // 2]
    return float(1.4826 * np.median(np.abs(residual)) / np.sqrt(1.0 - h0))


def spectral_noise_rms(y) -> float:
    """The spectral estimate of the module docstring: sqrt(median(P) / 2) of Welch's one-sided PSD P (unit rate;
    the zero-frequency bin left out)."""
    from scipy.signal import welch

    y = np.asarray(y, dtype=float).ravel()
    _, P = welch(y, fs=1.0, nperseg=min(SPECTRAL_SEGMENT, y.size), window="hann", detrend="linear")
    return float(np.sqrt(np.median(P[1:]) / 2.0))


def noise_rms(y) -> float:
    """Estimated RMS of white measurement noise on y (see the module docstring).

    Raises `ValueError` for fewer than ``2 * NOISE_WINDOW`` samples.
    """
    y = np.asarray(y, dtype=float).ravel()
    if y.size < 2 * NOISE_WINDOW:
        raise ValueError(f"noise estimate needs at least {2 * NOISE_WINDOW} samples, got {y.size}")
    local = local_noise_rms(y)
    if y.size < SPECTRAL_MIN:
        return local
    spectral = spectral_noise_rms(y)
    return spectral if spectral < CURVATURE * local else local


def noise_or_zero(y) -> float:
    """`noise_rms(y)`, or 0.0 when y is too short to estimate it."""
    y = np.asarray(y, dtype=float).ravel()
    return noise_rms(y) if y.size >= 2 * NOISE_WINDOW else 0.0
