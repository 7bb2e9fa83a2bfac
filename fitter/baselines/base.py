"""The interface every baseline shares (`Baseline`), its error, the recording checks and the unit scaling;
the conventions they follow (samples and preparation, units, initial state, score) are the `fitter.baselines`
docstring's.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fitter.core.effects import play_operator
from fitter.core.errors import DuhemError
from fitter.data.cycles import find_reversals
from fitter.data.metrics import compare
from fitter.data.recordings import Recording
from fitter.identification.fit_data import prepare_for_fit

MIN_SAMPLES = 10
"""Fewest samples a recording needs to be fitted by a baseline."""

ROW_BLOCK = 4096
"""Rows per block of the Gram sums and of the relay states (bounds the memory)."""


class BaselineError(DuhemError):
    """Recordings a baseline cannot be fitted to, or a baseline used before it is fitted."""


def check_recordings(recordings: Sequence[Recording] | Recording) -> list[Recording]:
    """The recordings as a list, each checked for fitting (`fitter.baselines` docstring, "Samples and preparation").

    Raises
    ------
    BaselineError
        No recording; two with the same name; a recording with too few samples,
        no (finite) output, a constant input or output, or an input that never
        reverses.  The message names the recording.
    """
    recs = [recordings] if isinstance(recordings, Recording) else list(recordings)
    if not recs:
        raise BaselineError("no recordings to fit")
    names = [r.name for r in recs]
    if len(set(names)) != len(names):
        raise BaselineError(f"recording names must be distinct to report them apart: {names}")
    for rec in recs:
        if len(rec) < MIN_SAMPLES:
            raise BaselineError(f"{rec.label}: too few samples: {len(rec)}, at least {MIN_SAMPLES} needed")
        if not np.all(np.isfinite(rec.y)):
            raise BaselineError(f"{rec.label}: no output recorded (y is not finite): nothing to fit")
        if np.ptp(rec.u) == 0:
            raise BaselineError(
                f"{rec.label}: the input is constant ({rec.u[0]:g}): a hysteresis model "
                f"needs an input that goes up and down"
            )
        if np.ptp(rec.y) == 0:
            raise BaselineError(f"{rec.label}: the output is constant: the NRMSE (error / output range) is undefined")
        if find_reversals(rec.u).size == 0:
            raise BaselineError(
                f"{rec.label}: the input never reverses (it must go up and down at least "
                f"once: a single loop, or periodically)"
            )
    return recs


@dataclass(frozen=True)
class _Scale:
    """Mid-range and half-range of u and y over the fitted recordings (`fitter.baselines` docstring, "Units")."""

    u_mid: float
    u_half: float
    y_mid: float
    y_half: float

    @classmethod
    def of(cls, us: Sequence[np.ndarray], ys: Sequence[np.ndarray]) -> "_Scale":
        u_lo, u_hi = min(u.min() for u in us), max(u.max() for u in us)
        y_lo, y_hi = min(y.min() for y in ys), max(y.max() for y in ys)
        return cls(float(u_lo + u_hi) / 2, float(u_hi - u_lo) / 2, float(y_lo + y_hi) / 2, float(y_hi - y_lo) / 2)

    def u(self, u: np.ndarray) -> np.ndarray:
        return (u - self.u_mid) / self.u_half

    def y(self, y: np.ndarray) -> np.ndarray:
        return (y - self.y_mid) / self.y_half

    def y_back(self, y_n: np.ndarray) -> np.ndarray:
        return self.y_mid + self.y_half * y_n

    def u_back(self, u_n: np.ndarray) -> np.ndarray:
        return self.u_mid + self.u_half * u_n

    def to_dict(self) -> dict:
        return {"u_mid": self.u_mid, "u_half": self.u_half, "y_mid": self.y_mid, "y_half": self.y_half}


class Baseline(ABC):
    """A classical hysteresis model fitted to recordings (`fitter.baselines` docstring for the shared conventions).

    Subclasses set `name` and implement `_fit` and `_predict` in normalised
    units, and `parameters` and `_settings`/`_fitted` for `to_dict`.

    Parameters
    ----------
    deadband : run on the input through the Duhem fit's dead band for a noisy input (default), or on
        the raw input (`fitter.baselines` docstring, "Samples and preparation").
    """

    name: str = ""
    initial_state: str = ""
    """The initial state in words (for `to_dict`)."""

    def __init__(self, deadband: bool = True) -> None:
        self.deadband = bool(deadband)
        self.scale_: _Scale | None = None
        self.deadband_ = 0.0
        self.n_recordings_ = 0

    def fit(self, recordings: Sequence[Recording] | Recording) -> "Baseline":
        """Fit one parameter set to all `recordings` (one initial state each); returns self.

        Raises
        ------
        BaselineError
            A recording that cannot be fitted (`check_recordings`), or recordings on which the model's
            least-squares problem is singular (e.g. an input outlier that leaves one sample on its elements).
        FitError
            A recording the Duhem fit's preparation refuses (`fitter.baselines` docstring).
        """
        recs = check_recordings(recordings)
        self.deadband_ = float(prepare_for_fit(recs).deadband) if self.deadband else 0.0
        us, ys = [self._input(r) for r in recs], [r.y for r in recs]
        self.scale_ = _Scale.of(us, ys)
        self.n_recordings_ = len(recs)
        try:
            self._fit([self.scale_.u(u) for u in us], [self.scale_.y(y) for y in ys])
        except np.linalg.LinAlgError:
            raise BaselineError(
                f"{', '.join(r.label for r in recs)}: baseline {self.name!r} cannot be fitted: its "
                f"least-squares problem is singular on these recordings"
            ) from None
        return self

    def _input(self, rec: Recording) -> np.ndarray:
        """The input the model runs on: u through the dead band of width `deadband_` (`fitter.baselines` docstring)."""
        return play_operator(rec.u, self.deadband_, float(rec.u[0])) if self.deadband_ > 0 else rec.u

    def predict(self, rec: Recording) -> np.ndarray:
        """The model's output on every sample of `rec` (initial state: `fitter.baselines` docstring)."""
        scale = self._scale()
        y_n = scale.y(rec.y) if np.all(np.isfinite(rec.y)) else None
        return scale.y_back(self._predict(scale.u(self._input(rec)), y_n))

    def score(self, rec: Recording) -> dict:
        """`fitter.data.metrics.compare` of `predict(rec)` with `rec` (``nrmse`` etc., all samples)."""
        if not np.all(np.isfinite(rec.y)):
            raise BaselineError(f"{rec.label}: no output recorded (y is not finite): nothing to score against")
        return compare(rec, self.predict(rec))

    @property
    @abstractmethod
    def parameters(self) -> int:
        """Number of fitted parameters (the initial state counts one per fitted recording)."""

    def to_dict(self) -> dict:
        """JSON-able description: name, number of parameters, settings, normalisation, fitted values."""
        scale = self._scale()
        return {
            "name": self.name,
            "parameters": self.parameters,
            "recordings": self.n_recordings_,
            "settings": self._settings(),
            "initial_state": self.initial_state,
            "input_deadband": self.deadband_,
            "normalisation": scale.to_dict(),
            "fitted": self._fitted(),
        }

    def _scale(self) -> _Scale:
        if self.scale_ is None:
            raise BaselineError(f"the {self.name} baseline is not fitted yet: call fit(recordings) first")
        return self.scale_

    @abstractmethod
    def _fit(self, us: list[np.ndarray], ys: list[np.ndarray]) -> None:
        """Fit in normalised units, one (u_n, y_n) pair per recording."""

    @abstractmethod
    def _predict(self, u: np.ndarray, y: np.ndarray | None) -> np.ndarray:
        """Normalised output on u_n; the initial state fitted to y_n unless it is None."""

    @abstractmethod
    def _settings(self) -> dict:
        """The estimator's settings (constructor arguments)."""

    @abstractmethod
    def _fitted(self) -> dict:
        """The fitted values, normalised units (JSON-able)."""
