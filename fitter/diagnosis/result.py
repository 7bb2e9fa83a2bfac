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

    def to_json(self) -> dict:
        """The JSON-able form (without the model outputs)."""
        return {
            "verdict": self.verdict,
            "separate": self.separate,
            "noise_rms": self.noise_rms,
            "noise": self.noise,
            "baseline": self.baseline,
            "mismatch": self.mismatch,
            "findings": self.findings,
            "candidates": self.candidates,
            "extended": self.extended,
            "validation": self.validation,
            "comparison": self.comparison,
            "summary": self.paragraph,
            "base_model": self.base_model.to_dict(),
            "extended_model": self.extended_model.to_dict(),
        }
