"""`DuhemEstimator`: the estimator-style entry point (fit / predict / score / diagnose / export).

In the spirit of pysindy and sysidentpy: hyper-parameters in the constructor,
`fit(recordings)` sets the trailing-underscore attributes, the other methods
use them.  It adds no numerics of its own: it calls `fit_recordings`,
`fitter.diagnosis.diagnose` and `fitter.fmu.build.build_fmu`, which stay
available as functions.

Example
-------
>>> from fitter import DuhemEstimator, load_recording          # doctest: +SKIP
>>> est = DuhemEstimator(kind="ri").fit([load_recording("examples/demo.csv")])
>>> est.score(load_recording("examples/demo.csv"))              # NRMSE, fraction of the range
>>> est.export("demo.fmu")                                      # native FMI 2.0 FMU
"""
from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from fitter.core.errors import DuhemError
from fitter.core.models import save_model
from fitter.data.metrics import nrmse
from fitter.data.recordings import Recording
from fitter.diagnosis import Diagnosis, diagnose
from fitter.fmu.build import build_fmu
from fitter.identification.fit import FitResult, fit_recordings
from fitter.progress import Progress, silent

__all__ = ["DuhemEstimator", "NotFittedError"]


class NotFittedError(DuhemError):
    """`predict`, `score`, `diagnose` or `export` called before `fit`."""


class DuhemEstimator:
    """Identify a semilinear Duhem model from recordings.

    Parameters
    ----------
    kind : "auto" (BIC), "ri" (eqs 1-2) or "rd" (eqs 18-19).
    order : state dimension; None chooses it by BIC among 1, 2, 3.
    q : bound of the Section III constrained least squares (a start only); None chooses it.
    progress : `fitter.progress.Progress` callback for one-line status messages.

    Attributes (after `fit`)
    ------------------------
    model_ : the fitted model (physical units), a `RateIndependentModel` or `RateDependentModel`.
    summary_ : JSON-able fit summary (candidates, per-recording metrics, convergence, preparation).
    result_ : the `FitResult` (parameters, covariance, `predict`, `band`).
    """

    def __init__(self, kind: str = "auto", order: int | None = None, q: float | None = None,
                 progress: Progress = silent):
        self.kind, self.order, self.q, self.progress = kind, order, q, progress

    def fit(self, recordings: Sequence[Recording]) -> "DuhemEstimator":
        """Fit to one or more recordings with the same columns; returns self."""
        self.result_: FitResult = fit_recordings(list(recordings), kind=self.kind, order=self.order, q=self.q,
                                                 progress=self.progress)
        self.model_ = self.result_.model
        self.summary_ = self.result_.summary
        return self

    def _fitted(self) -> FitResult:
        if not hasattr(self, "result_"):
            raise NotFittedError("this DuhemEstimator is not fitted yet: call fit(recordings) first")
        return self.result_

    def predict(self, recording: Recording) -> np.ndarray:
        """The fitted model's output on every sample of `recording`, from its stored x0
        (`FitResult.simulate`: what the exported FMU gives)."""
        return self._fitted().simulate(recording)

    def score(self, recording: Recording) -> float:
        """NRMSE (RMS error / output range) of `predict` over all samples: the figure of the fit
        summary and of `duhem validate`."""
        return nrmse(recording.y, self.predict(recording))

    def diagnose(self, recordings: Sequence[Recording], **options) -> Diagnosis:
        """`fitter.diagnosis.diagnose` with this fitted model as the base model."""
        return diagnose(list(recordings), model=self._fitted().model, **options)

    def save(self, path: str | os.PathLike) -> None:
        """Write the fitted model as JSON (atomically)."""
        save_model(self._fitted().model, path)

    def export(self, path: str | os.PathLike, *, backend: str = "native") -> str:
        """Build an FMI 2.0 Co-Simulation FMU of the fitted model; returns its path."""
        return build_fmu(self._fitted().model, path, backend=backend)
