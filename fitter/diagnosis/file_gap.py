"""Does one model hold across the recordings?  The joint fit against the same model refitted on each recording.

A diagnosis fits one model to every recording of an experiment.  When the recordings differ by something the
model does not carry (a rate or an amplitude it does not follow, a gain or an operating condition that differs
between files), the joint fit settles between them, and its residual is much larger than that of the same model
fitted to each recording alone.  Such a gap is a finding about the data, never noise (`file_gap`):

    ratio = RMS(joint residual) / RMS(per-recording residuals),

over the fitted samples, where each recording's residual is that of `fitter.diagnosis.fitting.refit` of the
joint fit on that recording alone (the same free entries, from the joint values).  A ratio above `GAP`, with
the joint residual above `NOISE_MARGIN` times the noise, is a gap.

A gain per file: each recording's output regressed on the joint fit's output, y_i ~ g_i yhat_i + c_i (linear
least squares).  When that leaves the joint residual within `NOISE_MARGIN` of the noise, the recordings differ
by a gain and an offset per file (an instrument's calibration, or an operating condition such as a normal
force): a property of each file, like its output reference, not physics of the material.
"""

from __future__ import annotations

import numpy as np

from fitter.data.metrics import rms
from fitter.diagnosis.experiment import JoinedExperiment
from fitter.diagnosis.fitting import Fit, refit
from fitter.diagnosis.statistics import NOISE_MARGIN

__all__ = ["GAP", "file_gap", "gain_per_file"]

GAP = 2.0
"""A joint residual more than this many times the per-recording fits' is a gap (module docstring)."""


def gain_per_file(ex: JoinedExperiment, fit: Fit, mask: np.ndarray) -> tuple[dict[str, float], np.ndarray]:
    """Per recording, the gain g_i of y_i ~ g_i yhat_i + c_i on its fitted samples (module docstring), and the
    residual of that regression on every sample (the joint residual where a recording has too few samples)."""
    yhat = ex.y - fit.residual
    residual = fit.residual.copy()
    gains = {}
    for i, rec in enumerate(ex.recordings):
        part = np.zeros(len(ex.y), bool)
        part[ex.part(i)] = True
        rows = part & mask
        if np.count_nonzero(rows) < 3 or np.ptp(yhat[rows]) == 0:
            continue
        X = np.column_stack([yhat[rows], np.ones(np.count_nonzero(rows))])
        (g, c), *_ = np.linalg.lstsq(X, ex.y[rows], rcond=None)
        gains[rec.name] = float(g)
        residual[part] = ex.y[part] - (g * yhat[part] + c)
    return gains, residual


def file_gap(ex: JoinedExperiment, fit: Fit, mask: np.ndarray, noise: float) -> dict | None:
    """The joint `fit` against its refits on each recording alone (module docstring); None for one recording.

    Returns ``{"joint_rms", "per_file_rms", "ratio", "gap", "per_recording": {name: {"joint", "own"}},
    "gains", "gain_rms", "gain_explains"}``.
    """
    if len(ex.recordings) < 2:
        return None
    own = np.zeros(len(ex.y))
    per = {}
    for i, rec in enumerate(ex.recordings):
        rows = np.zeros(len(ex.y), bool)
        rows[ex.part(i)] = True
        rows &= mask
        alone = refit(fit, ex, rows)
        own[rows] = alone.residual[rows]
        per[rec.name] = {"joint": rms(fit.residual[rows]), "own": rms(alone.residual[rows])}
    joint, mine = rms(fit.residual[mask]), rms(own[mask])
    gains, gained = gain_per_file(ex, fit, mask)
    ratio = joint / mine if mine > 0 else float("inf")
    gap = bool(ratio > GAP and joint > NOISE_MARGIN * noise)
    return {
        "joint_rms": joint,
        "per_file_rms": mine,
        "ratio": ratio,
        "gap": gap,
        "per_recording": per,
        "gains": gains,
        "gain_rms": rms(gained[mask]),
        "gain_explains": bool(gap and rms(gained[mask]) <= NOISE_MARGIN * noise),
    }
