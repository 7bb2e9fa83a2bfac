"""Separate runs written by instruments of different gains: the diagnosis works in the model's frame.

Files that differ only by an instrument's gain and zero are a clean experiment: the gain, like the reference, is a
property of the file (an instrument's calibration, or an operating condition that scales the output, such as a
friction contact's normal force), not physics of the device.  `duhem fit` finds them
(`fitter.identification.file_gains`); `calibrated_frame` takes its gains off the recordings before the diagnosis
(each output divided by its gain, `fitter.identification.file_gains.in_frame`), so that neither the base nor an
effect is asked to explain them, and the diagnosis reports them as the files' (``file_gains``).  The fit is the
one the diagnosis' base makes of the experiment anyway (`fitter.diagnosis.fitting.duhem_fit`, kind "ri", the
diagnosis' sample budget), kept for it in the model's frame (`fitting.remember`); it is made only where the
first-order base (`fitting.fit_base`) leaves more than `NOISE_MARGIN` times the noise (`calibrated_base`: where it does
not, the diagnosis makes no duhem fit either, and nothing is left for a gain to explain).  One clock (one run) has
one instrument: no gains.
"""

from __future__ import annotations

import numpy as np

from fitter.data.metrics import rms
from fitter.diagnosis.experiment import JoinedExperiment, join_recordings
from fitter.diagnosis.fitting import Fit, _share, fit_base, remember, remembered_fit
from fitter.diagnosis.noise_floor import noise_floor
from fitter.diagnosis.statistics import NOISE_MARGIN
from fitter.identification.file_gains import in_frame

__all__ = ["calibrated_base", "calibrated_frame"]


def calibrated_base(
    ex: JoinedExperiment, calibrate: bool, order: int | None
) -> tuple[JoinedExperiment, np.ndarray, Fit, dict, dict[str, float] | None]:
    """(experiment, mask of its fitted samples, first-order base, noise floor, gains): the diagnosis' first base
    (`fit_base`) and noise floor (`noise_floor`) on `ex`, or, with `calibrate`, where that base leaves more than
    `NOISE_MARGIN` times the noise and the files' gains differ (`calibrated_frame`), on the experiment in the
    model's frame (module docstring)."""
    mask = np.ones(len(ex.t), bool)
    first = fit_base(ex, None, mask)
    floor = noise_floor(ex, first.model)
    if not calibrate or rms(first.residual) <= NOISE_MARGIN * floor["rms"]:
        return ex, mask, first, floor, None
    framed, gains = calibrated_frame(ex, order)
    if gains is None:
        return ex, mask, first, floor, None
    mask = np.ones(len(framed.t), bool)
    first = fit_base(framed, None, mask)
    return framed, mask, first, noise_floor(framed, first.model), gains


def calibrated_frame(
    ex: JoinedExperiment, order: int | None = None
) -> tuple[JoinedExperiment, dict[str, float] | None]:
    """(the experiment in the model's frame, the gains of its recordings relative to the first), or (`ex`, None)
    where `duhem fit` of its separate runs (at `order`, default by BIC) finds no gains (module docstring)."""
    if not ex.separate or len(ex.recordings) < 2:
        return ex, None
    kwargs = {"order": order, "kind": "ri", "max_samples": _share(ex), "retry_unsettled": False}
    result = remembered_fit(ex.recordings, **kwargs)
    gains = result.model.fit_info.get("gains")
    if not gains:
        return ex, None
    frame = in_frame(ex.recordings, [gains.get(r.name, 1.0) for r in ex.recordings])
    framed = join_recordings(frame, True)
    remember(framed.recordings, result, **kwargs)
    return framed, dict(gains)
