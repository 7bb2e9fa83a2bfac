"""The noise floor of an output-error fit: output noise, and input noise carried through the model.

A diagnosis compares a model's residual with the noise: a residual at the
noise leaves nothing to explain.  An output-error fit simulates the model on
the *recorded* input u = u_true + e_u, so even the true model leaves

    r = y - yhat(u) = e_y - [yhat(u_true + e_u) - yhat(u_true)],

whose variance is sigma_y^2 + sigma_in^2: the output noise sigma_y plus the
input noise as the model passes it to its output, sigma_in (errors in
variables).  With a noisy input (a measured voltage, say) the output noise
alone under-states the floor, and the base is then "inadequate" at a
residual the true model itself leaves.

Estimates (`noise_floor`):

* sigma_y and sigma_u: `fitter.data.noise.noise_rms` of each recording's
  output and input (white noise seen through a local quadratic fit, or the
  spectral floor where the local fit read an input of few samples per cycle
  as noise; for quantised data the quantisation noise), the median over the
  recordings;
* sigma_in: the RMS change of the output of a reference model when white
  noise of RMS sigma_u (seeded, `DRAWS` draws) is added to the recorded
  input, each run simulated from the model's initial state.  For the
  sensitivity to be that of the device and not of a fit's accidental modes,
  the reference is the first-order rate-independent base
  (`fitter.diagnosis.fitting.fit_base`: stable by its bounds, the branch
  slopes of the data); the difference of two perturbed inputs that both
  carry the recorded noise is the noise's own effect to first order.

A noise-free input (piecewise linear, as generated) gives sigma_u near 0 and
the floor is sigma_y, as before this correction.
"""

from __future__ import annotations

import numpy as np

from fitter.core.errors import KernelError
from fitter.core.kernel import simulate
from fitter.data.noise import noise_rms
from fitter.diagnosis.experiment import JoinedExperiment

__all__ = ["DRAWS", "noise_floor"]

DRAWS = 3
"""Seeded input-noise draws averaged (in the mean square) for sigma_in."""


def _median_noise(signals: list[np.ndarray]) -> float:
    """Median `noise_rms` over the signals long enough to estimate it (0 if none is)."""
    values = [noise_rms(s) for s in signals if len(s) >= 14]
    return float(np.median(values)) if values else 0.0


def noise_floor(ex: JoinedExperiment, reference) -> dict:
    """The residual RMS the true model would leave on `ex` (module docstring).

    Returns ``{"rms": sqrt(sigma_y^2 + sigma_in^2), "output": sigma_y, "input": sigma_u,
    "through_input": sigma_in, "method": <one sentence>}``.
    """
    sigma_y = _median_noise([r.y for r in ex.recordings])
    sigma_u = _median_noise([r.u for r in ex.recordings])
    sigma_in = _through_input(ex, reference, sigma_u) if sigma_u > 0 else 0.0
    return {
        "rms": float(np.hypot(sigma_y, sigma_in)),
        "output": sigma_y,
        "input": sigma_u,
        "through_input": sigma_in,
        "method": "white noise on the output and on the input (each the local quadratic fit's estimate, or the "
        "spectral floor's where that is under half of it: the signal's curvature, not noise; median over "
        "recordings), the input's carried to the output by the first-order base (seeded input perturbations); "
        "rms = sqrt(output^2 + through_input^2)",
    }


def _through_input(ex: JoinedExperiment, reference, sigma_u: float) -> float:
    """RMS output change of `reference` under white input noise of RMS `sigma_u` (`DRAWS` seeded draws)."""
    rng = np.random.default_rng(0)
    squares = []
    with np.errstate(all="ignore"):
        for run in ex.runs():
            t, u = ex.t[run], ex.u[run]
            try:
                y0 = simulate(reference, t, u).y
                diffs = [simulate(reference, t, u + sigma_u * rng.standard_normal(len(u))).y - y0 for _ in range(DRAWS)]
            except KernelError:
                return 0.0
            squares.append(np.mean(np.square(diffs)) * len(u))
    value = float(np.sqrt(np.sum(squares) / len(ex.t)))
    return value if np.isfinite(value) else 0.0
