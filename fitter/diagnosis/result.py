"""The result of `fitter.diagnosis.diagnose`: `Diagnosis`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Diagnosis"]


@dataclass
class Diagnosis:
    """Result of `diagnose`; ``to_json()`` is the stable ``--json`` output."""

    noise_rms: float
    verdict: str  # "effects_found", "nothing_missing" or "unexplained" (findings then partial)
    baseline: dict
    mismatch: dict
    candidates: list
    findings: list
    extended: dict
    validation: dict | None
    comparison: str
    paragraph: str
    base_model: object
    extended_model: object
    baseline_output: np.ndarray = field(repr=False, default=None)
    extended_output: np.ndarray = field(repr=False, default=None)
    separate: bool = False  # the recordings were separate runs (`fitter.diagnosis.experiment`)
    noise: dict | None = None  # how noise_rms was estimated (`fitter.diagnosis.noise_floor.noise_floor`)
    file_gap: dict | None = None  # the base against its refits per recording (`fitter.diagnosis.file_gap`)
    file_gains: dict | None = None  # each recording's output gain, taken off first (`fitter.diagnosis.calibration`)

    def to_json(self) -> dict:
        """The JSON-able form (without the model outputs): the keys of `JSON_KEYS` in that order, the paragraph
        as ``summary`` and the models as their dicts."""
        out = {key: getattr(self, key) for key in JSON_KEYS}
        out["summary"] = out.pop("paragraph")
        out["base_model"], out["extended_model"] = self.base_model.to_dict(), self.extended_model.to_dict()
        return out


JSON_KEYS = ("verdict", "separate", "noise_rms", "noise", "baseline", "file_gap", "file_gains", "mismatch", "findings")
JSON_KEYS += ("candidates",)
JSON_KEYS += ("extended", "validation", "comparison", "paragraph")
"""The fields of `Diagnosis` in ``--json``, in order (then ``base_model``, ``extended_model``)."""
