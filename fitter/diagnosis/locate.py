"""Where a residual lives: per recording, branch, input range, across recordings, in a repeat.

`locate_mismatch`: the residual RMS per recording, per branch (rising /
falling / held input, each with at least `_branch_min` samples), per
input-range bin (5 equal bins), its correlation across recordings with log
rate, start time and amplitude, and a model-free
comparison of a repeated run with its original (the RMS of their output
difference against sqrt(2) x noise, what noise alone would give).
`where_differs` names where one candidate's residual exceeds another's.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from fitter.data.metrics import rms
from fitter.diagnosis.experiment import JoinedExperiment

__all__ = ["locate_mismatch", "where_differs"]


def _rate(u: np.ndarray, t: np.ndarray) -> float:
    """Median |du/dt| over the samples where the input moves (above 5% of its fastest rate)."""
    v = np.abs(np.diff(u) / np.diff(t))
    moving = v > 0.05 * v.max() if v.size and v.max() > 0 else np.zeros_like(v, bool)
    return float(np.median(v[moving])) if moving.any() else 0.0


def _corr(a: Sequence[float], b: Sequence[float]) -> float | None:
    """Pearson correlation, None with fewer than 3 points or a constant series."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) < 3 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    return float(np.corrcoef(a, b)[0, 1])


def _repeat_pair(ex: JoinedExperiment) -> tuple[int, int] | None:
    """(original, repeat): the last recording when an earlier one has the same length, rate and amplitude."""
    last = len(ex.recordings) - 1
    if last < 1:
        return None
    r = ex.recordings[last]
    for i, o in enumerate(ex.recordings[:last]):
        if (
            len(o.u) == len(r.u)
            and np.allclose(o.u - o.u.mean(), r.u - r.u.mean(), atol=0.02 * np.ptp(r.u))
            and np.isclose(_rate(o.u, o.t), _rate(r.u, r.t), rtol=0.05)
        ):
            return i, last
    return None


def _input_steps(ex: JoinedExperiment) -> np.ndarray:
    """Per sample, the input's change over the interval that ends there; at each recording's first sample
    (no interval of its own) the change over the interval that follows it."""
    du = np.empty(len(ex.u))
    for i in range(len(ex.recordings)):
        s = ex.part(i)
        d = np.diff(ex.u[s])
        du[s] = np.r_[d[:1], d] if len(d) else 0.0
    return du


def _branch_min(n: int) -> int:
    """The fewest samples a branch needs for its residual RMS to be reported: 10, or 1 % of the `n` samples
    (a triangle sampled symmetrically about its tips holds for single intervals there)."""
    return max(10, int(0.01 * n))


def _held(ex: JoinedExperiment) -> np.ndarray:
    """Per sample, True where the input holds (`_input_steps` within 1e-9 of its range)."""
    return np.abs(_input_steps(ex)) <= 1e-9 * np.ptp(ex.u)


def locate_mismatch(ex: JoinedExperiment, residual: np.ndarray, noise: float) -> dict:
    """Where the residual lives: per recording, branch (each sample on the branch of the interval that ends
    there, `_input_steps`), input range; growth; repeat."""
    du = _input_steps(ex)
    tol = 1e-9 * np.ptp(ex.u)
    per = []
    for i, r in enumerate(ex.recordings):
        s = ex.part(i)
        per.append(
            {
                "name": r.name,
                "t_start": float(r.t[0]),
                "t_stop": float(r.t[-1]),
                "rate": _rate(r.u, r.t),
                "amplitude": float(np.ptp(r.u) / 2),
                "residual_rms": rms(residual[s]),
                "noise_ratio": rms(residual[s]) / noise if noise else None,
                "residual_mean": float(np.mean(residual[s])),
            }
        )
    branches = {}
    for name, sel in (("rising", du > tol), ("falling", du < -tol), ("held", np.abs(du) <= tol)):
        branches[name] = rms(residual[sel]) if np.count_nonzero(sel) >= _branch_min(len(du)) else None
    edges = np.linspace(ex.u.min(), ex.u.max(), 6)
    bins = np.clip(np.digitize(ex.u, edges[1:-1]), 0, 4)
    by_input = [
        {
            "u_from": float(edges[j]),
            "u_to": float(edges[j + 1]),
            "residual_rms": rms(residual[bins == j]) if (bins == j).any() else None,
        }
        for j in range(5)
    ]
    rms_rec = [p["residual_rms"] for p in per]
    growth = {
        "with_rate": _corr(np.log([max(p["rate"], 1e-300) for p in per]), rms_rec),
        "with_time": _corr([p["t_start"] for p in per], rms_rec),
        "with_amplitude": _corr([p["amplitude"] for p in per], rms_rec),
    }
    out = {
        "per_recording": per,
        "per_branch": branches,
        "per_input_range": by_input,
        "growth": growth,
        "worst_recording": per[int(np.argmax(rms_rec))]["name"],
        "repeat": None,
    }
    pair = _repeat_pair(ex)
    if pair is not None:
        a, b = (ex.recordings[i] for i in pair)
        diff = rms(b.y - a.y)
        out["repeat"] = {
            "original": a.name,
            "repeat": b.name,
            "data_difference_rms": diff,
            "expected_from_noise": math.sqrt(2) * noise,
            "residual_rms_original": per[pair[0]]["residual_rms"],
            "residual_rms_repeat": per[pair[1]]["residual_rms"],
        }
    return out


def where_differs(ex: JoinedExperiment, r_win: np.ndarray, r_run: np.ndarray) -> str:
    """Where the runner-up's residual `r_run` exceeds the winner's `r_win` most: the recording and
    whether the input holds or moves (per sample)."""
    extra = r_run**2 - r_win**2
    per = [(float(np.sum(extra[ex.part(i)])), r.name) for i, r in enumerate(ex.recordings)]
    rec = max(per)[1]
    held = _held(ex)
    parts = {
        "while the input holds": float(np.sum(extra[held])) / max(held.sum(), 1),
        "while the input moves": float(np.sum(extra[~held])) / max((~held).sum(), 1),
    }
    where = max(parts, key=parts.get) if held.any() else "while the input moves"
    return f"in {rec} and {where}"
