"""The baselines by name (`BASELINES`) and the side-by-side comparison with a Duhem model."""

from __future__ import annotations

import time
from typing import Sequence

from fitter.baselines.base import Baseline, BaselineError, check_recordings
from fitter.baselines.bouc_wen import BoucWen
from fitter.baselines.prandtl_ishlinskii import PrandtlIshlinskii
from fitter.baselines.preisach import Preisach
from fitter.data.metrics import compare
from fitter.data.recordings import Recording
from fitter.identification.exported import own_start

BASELINES: dict[str, type[Baseline]] = {cls.name: cls for cls in (Preisach, PrandtlIshlinskii, BoucWen)}
"""The baselines by name."""


def compare_baselines(
    recordings: Sequence[Recording], *, per_recording: bool = True, names: Sequence[str] | None = None
) -> dict:
    """NRMSE of each baseline on each recording, fitted per recording and once for all.

    Returns
    -------
    ``{name: {"per_recording": {rec.name: nrmse}, "one_for_all": {rec.name: nrmse},
    "cpu_seconds": {"per_recording": {rec.name: s}, "one_for_all": s}}}``:
    "per_recording" fits each recording alone (None when `per_recording` is
    false), "one_for_all" fits one parameter set to all recordings (one
    initial state each); the NRMSE is `Baseline.score`'s (all samples),
    the CPU time `time.process_time` of each fit.

    Raises
    ------
    BaselineError
        An unknown name, or a recording that cannot be fitted (`check_recordings`).
    """
    recs = check_recordings(recordings)
    chosen = list(BASELINES) if names is None else list(names)
    unknown = [n for n in chosen if n not in BASELINES]
    if unknown:
        raise BaselineError(f"unknown baseline(s) {unknown}: known are {list(BASELINES)}")
    out = {}
    for name in chosen:
        entry = {"per_recording": None, "one_for_all": {}, "cpu_seconds": {"per_recording": None}}
        if per_recording:
            entry["per_recording"], entry["cpu_seconds"]["per_recording"] = {}, {}
            for rec in recs:
                model, seconds = _timed_fit(BASELINES[name], [rec])
                entry["per_recording"][rec.name] = model.score(rec)["nrmse"]
                entry["cpu_seconds"]["per_recording"][rec.name] = seconds
        model, seconds = _timed_fit(BASELINES[name], recs)
        entry["one_for_all"] = {rec.name: model.score(rec)["nrmse"] for rec in recs}
        entry["cpu_seconds"]["one_for_all"] = seconds
        out[name] = entry
    return out


def duhem_nrmse(model, rec: Recording) -> float:
    """NRMSE of a Duhem model on `rec` under the baselines' initial-state policy: x0 fitted to this
    recording over all its samples (and the effects settled on it where the fit settled them,
    `fitter.identification.exported.own_start`), every sample scored; NaN when the simulation overflows."""
    start = own_start(model, rec)
    return float("nan") if start is None else compare(rec, start[1])["nrmse"]


def comparison(model, recordings: Sequence[Recording]) -> dict:
    """The Duhem model beside the baselines on the same recordings and error measure:
    ``{"duhem": {rec.name: nrmse}, "baselines": compare_baselines(...)}``; each baseline is fitted
    once for all recordings and, when there are several, to each recording alone."""
    recs = check_recordings(recordings)
    return {
        "duhem": {rec.name: duhem_nrmse(model, rec) for rec in recs},
        "baselines": compare_baselines(recs, per_recording=len(recs) > 1),
        "measure": "RMS error / output range over all samples, initial state fitted per recording",
    }


def _timed_fit(cls: type[Baseline], recs: list[Recording]) -> tuple[Baseline, float]:
    t0 = time.process_time()
    model = cls().fit(recs)
    return model, time.process_time() - t0
