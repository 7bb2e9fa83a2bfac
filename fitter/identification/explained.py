"""Whether a fit found anything to model: the share of the output's variance its model explains.

Per recording, the saved model's output y_hat from the better of its stored
x0 and the recording's own fitted start (`fitter.identification.exported.own_start`),
and the coefficient of determination

    R^2 = 1 - sum_k (y_k - y_hat_k)^2 / sum_k (y_k - mean(y))^2.

A model that relates the output to the input reproduces most of the output's
variance (R^2 near 1: 0.99998 on examples/demo.csv, 0.99986 on the piezo
triangle recording slow_T06); an output that is noise has nothing the input
explains, and the best model does little better than the output's mean (R^2
near 0: 0.0026 on seeded white noise).  A recording with R^2 < `EXPLAINED_MIN`
= 0.5 (the model explains less than half the output's variance: its residual
RMS exceeds 1/sqrt(2) of the output's standard deviation: an NRMSE of 0.20
on a triangle-shaped output, 0.25 on a sine, far beyond the few per cent of
the project's fits of real hysteresis data) is reported as having nothing to
model: `check_explained` refuses it unless the caller insists.  Beside it, the
white-noise estimate of the output (`fitter.data.noise.noise_rms`) says how
much of the output's spread is sample-to-sample noise.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fitter.core.errors import DuhemError, KernelError
from fitter.core.kernel import simulate
from fitter.data.noise import noise_or_zero
from fitter.data.recordings import Recording
from fitter.identification.exported import levelled, own_start

__all__ = [
    "EXPLAINED_MIN",
    "NothingToModelError",
    "explained_variance",
    "unexplained",
    "explained_text",
    "check_explained",
]

EXPLAINED_MIN = 0.5
"""Smallest R^2 of a recording whose output the model relates to its input (module docstring)."""


class NothingToModelError(DuhemError):
    """The fitted model explains too little of a recording's output: the output looks like noise."""


def _best_output(model, rec: Recording) -> np.ndarray:
    """The model's output on `rec` from its stored x0 or from the recording's own start, whichever is closer."""
    with np.errstate(all="ignore"):
        try:
            outputs = [simulate(model, rec.t, rec.u).y]
        except KernelError:
            outputs = []
    start = own_start(model, rec)
    if start is not None:
        outputs.append(start[1])
    finite = [y for y in outputs if np.all(np.isfinite(y))]
    return min(finite, key=lambda y: float(np.sum((rec.y - y) ** 2))) if finite else np.full(len(rec.y), np.nan)


def explained_variance(model, recordings: Sequence[Recording]) -> list[dict]:
    """Per recording: ``r2`` (module docstring; -inf when the model's output is not finite), ``residual_rms``,
    ``output_std`` (the recorded output's standard deviation), ``noise_rms`` (its white-noise estimate) and
    ``threshold`` = `EXPLAINED_MIN`."""
    rows = []
    for rec in [levelled(model, r) for r in recordings]:
        y_hat = _best_output(model, rec)
        sst, sse = float(np.sum((rec.y - np.mean(rec.y)) ** 2)), float(np.sum((rec.y - y_hat) ** 2))
        r2 = 1.0 - sse / sst if sst > 0 and np.isfinite(sse) else (1.0 if sst == 0 and sse == 0 else -np.inf)
        rows.append(
            {
                "recording": rec.name,
                "source": rec.label,
                "r2": r2,
                "residual_rms": float(np.sqrt(sse / len(rec.y))),
                "output_std": float(np.std(rec.y)),
                "noise_rms": noise_or_zero(rec.y),
                "threshold": EXPLAINED_MIN,
            }
        )
    return rows


def unexplained(rows: Sequence[dict]) -> dict | None:
    """The row of `explained_variance` with the lowest R^2 when it is below its threshold, else None."""
    worst = min(rows, key=lambda r: r["r2"], default=None)
    return worst if worst is not None and worst["r2"] < worst["threshold"] else None


def explained_text(row: dict) -> str:
    """The numbers of a row that has nothing to model, in words."""
    return (
        f"the fitted model explains R^2 = {row['r2']:.3g} of the output's variance (residual RMS "
        f"{row['residual_rms']:.4g} against the output's standard deviation {row['output_std']:.4g}; its "
        f"white-noise estimate is {row['noise_rms']:.4g}; real hysteresis gives R^2 > 0.99, the limit is "
        f"{row['threshold']:g}): the output looks like noise, with no relation to the input"
    )


def check_explained(rows: Sequence[dict], *, allow_noise: bool = False) -> dict | None:
    """The `unexplained` row of `explained_variance`, returned under `allow_noise` (the caller warns).

    Raises
    ------
    NothingToModelError
        A recording's R^2 is below its threshold and `allow_noise` is false; the message starts with the
        recording's file and gives the numbers.
    """
    row = unexplained(rows)
    if row is not None and not allow_noise:
        raise NothingToModelError(
            f"{row['source']}: {explained_text(row)}; no model written: check the output "
            "column (--output), or pass --allow-noise to save the model anyway"
        )
    return row
