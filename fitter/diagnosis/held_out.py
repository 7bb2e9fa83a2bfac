"""Held-out prediction: each recording predicted by the model fitted without it (leave one recording out).

A diagnosis chooses structure by how a model predicts data it was not
fitted to, not by its in-sample fit alone (scikit-learn's model selection).
For an experiment of K >= 2 recordings, recording k is predicted by the
family refitted on the other K - 1 (`fitter.diagnosis.fitting.refit`, from
the joint values, with the same free parameters); the prediction runs as
every score of the project does: the held-out recording's initial state
(and, for separate runs, its output reference) fitted to it, nothing else.

`held_out_rss` gives the squared prediction error per recording.  An effect
is *confirmed on held-out data* (`confirmed`) when, added to the model, it
lowers the prediction error of every recording, and of a typical one (the
geometric mean of the ratios) by at least `HELD_OUT_GAIN`: an effect that only bends the fit toward noise or
toward one recording's peculiarity does not predict the others better.
With a single recording there is nothing to hold out (None).  The recordings' refits run on several
processes (`fitter.workers`).
"""

from __future__ import annotations

import numpy as np

from fitter.data.metrics import nrmse
from fitter.diagnosis.experiment import JoinedExperiment
from fitter.diagnosis.fitting import Fit, refit
from fitter.workers import parallel_map

__all__ = ["HELD_OUT_GAIN", "confirmed", "held_out_nrmse", "held_out_residual", "held_out_rss", "prediction_error"]

HELD_OUT_GAIN = 0.25
"""Fraction of the held-out squared error of a typical recording that an effect must remove (`confirmed`;
every recording's own must fall by a fifth of it)."""


def _held_out_residuals(
    ex: JoinedExperiment, fit: Fit, mask: np.ndarray, ks: list[int] | None = None
) -> list[np.ndarray] | None:
    """Residual y - yhat on the fitted samples of each recording of `ks` (default all), `fit` refitted without
    it (`held_out_residual`, on several processes); None for a single recording."""
    if len(ex.recordings) < 2:
        return None
    ks = list(range(len(ex.recordings))) if ks is None else ks
    out = parallel_map(lambda k: held_out_residual(ex, fit, mask, k), ks)
    fit.held_out.update({(k, mask.tobytes()): r for k, r in zip(ks, out)})  # computed in other processes
    return out


def _nrmse(ex: JoinedExperiment, mask: np.ndarray, k: int, residual: np.ndarray) -> float:
    """NRMSE of recording `k`'s fitted samples predicted with `residual` y - yhat."""
    y = ex.y[ex.part(k)][mask[ex.part(k)]]
    return nrmse(y, y - residual)


def prediction_error(ex: JoinedExperiment, fit: Fit, mask: np.ndarray) -> float:
    """The mean NRMSE of the recordings predicted by `fit` refitted without each (leave one recording out), over
    those whose start a prediction knows: every separate run (its initial state fitted to it), on one clock
    every recording but the first (its state carried in from the recordings before it; the first's would be
    the model's x0 fitted to later data only, unconstrained).  Each recording on its own range, so that a
    model is not chosen for predicting one of them."""
    ks = list(range(0 if ex.separate else 1, len(ex.recordings)))
    return float(np.mean([_nrmse(ex, mask, k, r) for k, r in zip(ks, _held_out_residuals(ex, fit, mask, ks))]))


def held_out_residual(ex: JoinedExperiment, fit: Fit, mask: np.ndarray, k: int) -> np.ndarray:
    """Residual y - yhat on recording `k`'s fitted samples, `fit` refitted without it (`refit`); computed once
    per fit, recording and mask (`Fit.held_out`)."""
    key = (k, mask.tobytes())
    if key not in fit.held_out:
        part = ex.part(k)
        train = mask.copy()
        train[part] = False
        fit.held_out[key] = refit(fit, ex, train).residual[part][mask[part]]
    return fit.held_out[key]


def held_out_rss(ex: JoinedExperiment, fit: Fit, mask: np.ndarray) -> np.ndarray | None:
    """Squared prediction error of each recording (leave one recording out; None for one recording)."""
    parts = _held_out_residuals(ex, fit, mask)
    return None if parts is None else np.array([float(np.sum(r**2)) for r in parts])


def held_out_nrmse(ex: JoinedExperiment, fit: Fit, mask: np.ndarray) -> dict[str, float] | None:
    """NRMSE of each recording predicted by `fit` refitted without it, by recording name (None for one)."""
    parts = _held_out_residuals(ex, fit, mask)
    if parts is None:
        return None
    return {rec.name: _nrmse(ex, mask, k, r) for k, (rec, r) in enumerate(zip(ex.recordings, parts))}


def confirmed(with_effect: np.ndarray | None, without: np.ndarray | None) -> bool:
    """Whether an effect predicts held-out recordings better (module docstring): the ratios q_k of each
    recording's squared error with the effect to without it all below 1 - `HELD_OUT_GAIN` / 5, and their
    geometric mean below 1 - `HELD_OUT_GAIN` (ratios, so that one recording the model without the effect
    predicts badly does not decide for the others)."""
    if with_effect is None or without is None:
        return False
    q = np.asarray(with_effect, dtype=float) / np.maximum(np.asarray(without, dtype=float), 1e-300)
    return bool(
        np.all(q < 1.0 - HELD_OUT_GAIN / 5) and np.exp(np.mean(np.log(np.maximum(q, 1e-300)))) <= 1.0 - HELD_OUT_GAIN
    )
