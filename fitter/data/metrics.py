"""Error measures between a recording and a model's output.

Definitions (all on sampled signals, samples weighted equally)
--------------------------------------------------------------
* ``nrmse(y, y_hat) = sqrt(mean((y - y_hat)^2)) / (max(y) - min(y))``: the RMS
  error as a fraction of the data's output range.
* ``max_error(y, y_hat) = max |y - y_hat|``.
* ``loop_area(u, y)``: the *signed* area enclosed by the closed polygon
  (u_k, y_k) (shoelace formula, the curve closed by the segment from the last
  sample back to the first), equal to ``∮ u dy = -∮ y du`` around the
  curve as traversed: positive when the loop runs counter-clockwise
  in the (u, y) plane, i.e. the rising branch lies below the falling one, as
  for the paper's loops and a piezo's P-E loop.  Its unit is unit(u)*unit(y).
* ``noise_rms``: the estimated RMS of white measurement noise
  (`fitter.data.noise`); ``last_full_cycle``: the samples of the last full
  input cycle (`fitter.data.cycles`).
"""

from __future__ import annotations

import numpy as np

from fitter.data.cycles import PreparationError, last_full_cycle
from fitter.data.noise import NOISE_WINDOW, noise_rms

__all__ = ["nrmse", "max_error", "rms", "loop_area", "compare"]


def _pair(y, y_hat) -> tuple[np.ndarray, np.ndarray]:
    y = np.asarray(y, dtype=float).ravel()
    y_hat = np.asarray(y_hat, dtype=float).ravel()
    if y.shape != y_hat.shape:
        raise ValueError(f"data and model output differ in length ({len(y)} and {len(y_hat)})")
    if y.size == 0:
        raise ValueError("empty signal")
    return y, y_hat


def rms(e) -> float:
    """Root mean square sqrt(mean(e^2))."""
    e = np.asarray(e, dtype=float)
    return float(np.sqrt(np.mean(e * e)))


def nrmse(y, y_hat) -> float:
    """RMS error divided by the output range of the data, max(y) - min(y)."""
    y, y_hat = _pair(y, y_hat)
    span = float(np.ptp(y))
    if span == 0:
        raise ValueError("the data output is constant: NRMSE (error / output range) is undefined")
    return rms(y - y_hat) / span


def max_error(y, y_hat) -> float:
    """Largest absolute error max |y - y_hat|."""
    y, y_hat = _pair(y, y_hat)
    return float(np.max(np.abs(y - y_hat)))


def loop_area(u, y) -> float:
    """Signed enclosed area of the closed curve (u_k, y_k), shoelace formula.

    ``A = 1/2 sum_k (u_k y_{k+1} - u_{k+1} y_k)`` with index N = 0 (closed);
    positive for a counter-clockwise loop in the (u, y) plane.
    """
    u, y = _pair(u, y)
    return float(0.5 * np.sum(u * np.roll(y, -1) - np.roll(u, -1) * y))


def compare(rec, y_hat) -> dict:
    """Fit measures of a model output `y_hat` against recording `rec` (JSON-able dict).

    Keys: ``nrmse``, ``max_error`` over all samples; ``nrmse_last_cycle``,
    ``max_error_last_cycle`` over the last full input cycle
    (`last_full_cycle`; None when there is none), ``last_cycle`` [start,
    stop); ``loop_area``, ``loop_area_model`` (signed, last full cycle) and
    ``loop_area_error`` = (model - data) / |data| ; ``residual_rms`` (all
    samples), ``noise_rms`` (`noise_rms` of the data output) and
    ``samples``.  The NRMSE of the last cycle is normalised by that cycle's
    output range.
    """
    y, y_hat = _pair(rec.y, y_hat)
    out = {
        "samples": int(y.size),
        "nrmse": nrmse(y, y_hat),
        "max_error": max_error(y, y_hat),
        "residual_rms": rms(y - y_hat),
        "noise_rms": noise_rms(y) if y.size >= 2 * NOISE_WINDOW else None,
        "last_cycle": None,
        "nrmse_last_cycle": None,
        "max_error_last_cycle": None,
        "loop_area": None,
        "loop_area_model": None,
        "loop_area_error": None,
    }
    try:
        s = last_full_cycle(rec.u)
    except PreparationError:
        return out
    u = rec.u[s]
    a_data, a_model = loop_area(u, y[s]), loop_area(u, y_hat[s])
    out.update(
        last_cycle=[s.start, s.stop],
        nrmse_last_cycle=nrmse(y[s], y_hat[s]),
        max_error_last_cycle=max_error(y[s], y_hat[s]),
        loop_area=a_data,
        loop_area_model=a_model,
        loop_area_error=(a_model - a_data) / abs(a_data) if a_data != 0 else None,
    )
    return out
