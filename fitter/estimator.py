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

import inspect
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

    Every option of ``duhem fit`` and ``duhem export`` is a constructor parameter, under the name of the
    function it goes to (`fit_recordings`, `build_fmu`); `get_params` / `set_params` follow scikit-learn's
    conventions (the constructor's parameters, by name).

    Parameters
    ----------
    kind : "auto" (BIC), "ri" (eqs 1-2) or "rd" (eqs 18-19) (``--kind``).
    order : state dimension; None chooses it by BIC (``--order``).
    q : bound of the Section III constrained least squares (a start only); None chooses it (``--q``).
    x0 : "fitted" or "periodic" (``--x0``).
    faithful_minor_loops : keep the minor loops near the data (``--faithful-minor-loops``).
    effects : effects of the catalogue fitted with the base (``--effects``).
    held : effect parameters held at known values, ``{"effect.parameter": value}`` (``--hold``).
    backend : "native" or "python", the FMU `export` builds (``--backend``).
    fmi_version : 2 or 3 (``--fmi-version``).
    platforms : the native FMU's binaries, None for all (``--platforms``).
    allow_unstable : export a model that fails the convergence check (``--allow-unstable``).
    progress : `fitter.progress.Progress` callback for one-line status messages.

    Attributes (after `fit`)
    ------------------------
    model_ : the fitted model (physical units), a `RateIndependentModel` or `RateDependentModel`.
    summary_ : JSON-able fit summary (candidates, per-recording metrics, convergence, preparation).
    result_ : the `FitResult` (parameters, covariance, `predict`, `band`).
    """

    def __init__(
        self,
        kind: str = "auto",
        order: int | None = None,
        q: float | None = None,
        x0: str = "fitted",
        faithful_minor_loops: bool = False,
        effects: Sequence[str] = (),
        held: dict[str, float] | None = None,
        backend: str = "native",
        fmi_version: int = 2,
        platforms: str | Sequence[str] | None = None,
        allow_unstable: bool = False,
        progress: Progress = silent,
    ):
        self.kind, self.order, self.q, self.x0 = kind, order, q, x0
        self.faithful_minor_loops, self.effects, self.held = faithful_minor_loops, effects, held
        self.backend, self.fmi_version, self.platforms = backend, fmi_version, platforms
        self.allow_unstable, self.progress = allow_unstable, progress

    @classmethod
    def _param_names(cls) -> list[str]:
        return [name for name in inspect.signature(cls.__init__).parameters if name != "self"]

    def get_params(self, deep: bool = True) -> dict:
        """The constructor's parameters and their values (`deep` is accepted for scikit-learn; nothing is
        nested)."""
        return {name: getattr(self, name) for name in self._param_names()}

    def set_params(self, **params) -> "DuhemEstimator":
        """Set constructor parameters by name; an unknown name is a ValueError naming the known ones."""
        unknown = sorted(set(params) - set(self._param_names()))
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown} of DuhemEstimator: known are {self._param_names()}")
        for name, value in params.items():
            setattr(self, name, value)
        return self

    def fit(self, recordings: Sequence[Recording]) -> "DuhemEstimator":
        """Fit to one or more recordings with the same columns; returns self."""
        self.result_: FitResult = fit_recordings(
            list(recordings),
            kind=self.kind,
            order=self.order,
            q=self.q,
            x0=self.x0,
            faithful_minor_loops=self.faithful_minor_loops,
            effects=tuple(self.effects),
            held=self.held,
            progress=self.progress,
        )
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

    def export(self, path: str | os.PathLike, **options) -> str:
        """Build the Co-Simulation FMU of the fitted model with the estimator's `backend`, `fmi_version`,
        `platforms` and `allow_unstable`, any of them overridden by name in `options`; returns its path."""
        chosen = {name: getattr(self, name) for name in ("backend", "fmi_version", "platforms", "allow_unstable")}
        unknown = sorted(set(options) - set(chosen))
        if unknown:
            raise ValueError(f"unknown export option(s) {unknown}: known are {sorted(chosen)}")
        chosen.update(options)
        platforms = chosen.pop("platforms")
        native = {"platforms": platforms} if chosen["backend"] == "native" else {}
        return build_fmu(self._fitted().model, path, **chosen, **native)
