"""Does one model hold across the recordings?  The joint fit against the same model refitted on each recording.

A diagnosis fits one model to every recording of an experiment.  When the recordings differ by something the
model does not carry (a rate or an amplitude it does not follow, a gain or an operating condition that differs
between files), the joint fit settles between them, and its residual is much larger than that of the same model
fitted to each recording alone.  Such a gap is a finding about the data, never noise (`file_gap`):

    ratio = RMS(joint residual) / RMS(per-recording residuals),

over the fitted samples, where each recording's residual is the smaller of `fitter.diagnosis.fitting.refit` of the
joint fit on that recording alone (the same free entries, from the joint values) and of the rate-independent model
`duhem fit` makes of that recording alone (its order by BIC, from its own fitted start: a first-order base refitted
per file cannot show what a file's own loop needs).  A ratio above `GAP` is a gap, where the joint residual is
above `RESOLUTION` of the output range (below it, no instrument tells the files apart).
The per-recording residual also bounds the noise: a model of the recording cannot leave less than its noise (its
few parameters fit a negligible part of it), so a noise estimate above it was inflated (an input's quantisation
carried through a steep model, say) and is capped there (`capped_noise`).

A gain per file: each recording's output regressed on the joint fit's output, y_i ~ g_i yhat_i + c_i (linear
least squares).  When that leaves the joint residual within `NOISE_MARGIN` of the noise, the recordings differ
by a gain and an offset per file (an instrument's calibration, or an operating condition such as a normal
force): a property of each file, like its output reference, not physics of the material.
"""

from __future__ import annotations

import numpy as np

from fitter.data.metrics import rms
from fitter.diagnosis.experiment import JoinedExperiment
from fitter.core.errors import DuhemError, KernelError
from fitter.core.kernel import simulate
from fitter.diagnosis.fitting import Fit, _share, refit
from fitter.identification.file_gains import gain_and_zero
from fitter.identification.fit import fit_recordings
from fitter.diagnosis.statistics import NOISE_MARGIN, RESOLUTION

__all__ = ["GAP", "capped_noise", "file_gap", "gain_per_file"]

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
        fitted = gain_and_zero(ex.y[rows], yhat[rows]) if np.count_nonzero(rows) >= 3 else None
        if fitted is None:
            continue
        gains[rec.name], c = fitted
        residual[part] = ex.y[part] - (fitted[0] * yhat[part] + c)
    return gains, residual


def _duhem_fits(ex: JoinedExperiment) -> np.ndarray:
    """Per recording, the residual of `fit_recordings` of it alone (kind "ri", order by BIC, the diagnosis' sample
    budget `fitting._share`), its model from its stored x0 (the recording's own fitted start); inf where no model
    of it alone could be fitted."""
    out = np.full(len(ex.y), np.inf)
    for i, rec in enumerate(ex.recordings):
        with np.errstate(all="ignore"):
            try:
                result = fit_recordings([rec], kind="ri", max_samples=_share(ex))
                out[ex.part(i)] = rec.y - simulate(result.model, rec.t, rec.u).y
            except (DuhemError, KernelError):  # no model of this file alone: the refit stands for it
                continue
    return np.where(np.isfinite(out), out, np.inf)


def file_gap(ex: JoinedExperiment, fit: Fit, mask: np.ndarray) -> dict | None:
    """The joint `fit` against its refits on each recording alone (module docstring); None for one recording.

    Returns ``{"joint_rms", "per_file_rms", "ratio", "gap", "per_recording": {name: {"joint", "own"}},
    "gains", "gain_rms"}`` (``gain_explains`` is added by `capped_noise`).
    """
    if len(ex.recordings) < 2:
        return None
    own = np.zeros(len(ex.y))
    duhem = _duhem_fits(ex)
    per = {}
    for i, rec in enumerate(ex.recordings):
        rows = np.zeros(len(ex.y), bool)
        rows[ex.part(i)] = True
        rows &= mask
        alone = refit(fit, ex, rows).residual
        own[rows] = alone[rows] if rms(alone[rows]) <= rms(duhem[rows]) else duhem[rows]
        per[rec.name] = {"joint": rms(fit.residual[rows]), "own": rms(own[rows])}
    joint, mine = rms(fit.residual[mask]), rms(own[mask])
    gains, gained = gain_per_file(ex, fit, mask)
    ratio = joint / mine if mine > 0 else float("inf")
    return {
        "joint_rms": joint,
        "per_file_rms": mine,
        "ratio": ratio,
        "gap": bool(ratio > GAP and joint > RESOLUTION * float(np.ptp(ex.y[mask]))),
        "per_recording": per,
        "gains": gains,
        "gain_rms": rms(gained[mask]),
    }


def capped_noise(floor: dict, gap: dict | None) -> dict:
    """The noise floor (`fitter.diagnosis.noise_floor.noise_floor`) capped at the per-recording fits' residual
    (module docstring; ``capped_from`` keeps the estimate), and `gap`'s ``gain_explains`` set: a gap that a gain
    and an offset per file take to within `NOISE_MARGIN` of the noise."""
    if gap is None:
        return floor
    out = dict(floor)
    if gap["per_file_rms"] < floor["rms"]:
        out.update(
            rms=gap["per_file_rms"],
            capped_from=floor["rms"],
            method=floor["method"] + "; capped at the residual of the base refitted on each recording alone, "
            "which the noise cannot exceed",
        )
    gap["gain_explains"] = bool(gap["gap"] and gap["gain_rms"] <= NOISE_MARGIN * out["rms"])
    return out
