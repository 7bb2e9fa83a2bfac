"""Triangle-wave records checked and parsed for Section V of Oh & Bernstein (2007).

A record is ``(t, u, y)`` sampled at a constant step delta under one triangle wave (20).
`parse_record` checks the arrays (finite, enough samples for the order, a constant step within `TOL`), reads
each interval's input slope (a on the rising, b on the falling branch, within `TOL`), finds the ramp runs and
their corners, and fits the `TriangleWave` through them; a record that is not a triangle wave is refused
with a one-line ``ValueError`` naming the record.  `fitter.identification.rd_triangles` identifies from them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fitter.identification.triangle_waves import TriangleWave

__all__ = ["TOL", "Record", "fail", "parse_record"]

TOL = 1e-6
"""Relative tolerance of a constant sampling step and of a ramp's constant slope."""


@dataclass
class Record:
    """One checked triangle-wave record and its ramp runs."""

    index: int
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    delta: float
    wave: TriangleWave
    runs: dict  # direction (+1 / -1) -> list of (first, last) sample indices on that ramp


def fail(i: int, msg: str):
    """Refuse record `i`: one line naming it."""
    raise ValueError(f"record {i}: {msg}")


def _check_arrays(i: int, rec, order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    try:
        t, u, y = (np.asarray(a, dtype=float).ravel() for a in rec)
    except (TypeError, ValueError):
        fail(i, "must be a tuple (t, u, y) of numeric arrays")
    if not (len(t) == len(u) == len(y)):
        fail(i, f"t, u, y differ in length ({len(t)}, {len(u)}, {len(y)})")
    for name, arr in (("t", t), ("u", u), ("y", y)):
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            fail(i, f"{name}[{bad[0]}] is {arr[bad[0]]} (NaN or infinite)")
    need = 2 * order + 4
    if len(t) < need:
        fail(i, f"{len(t)} samples are too few for order {order} (need at least {need})")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.flatnonzero(dt <= 0)[0])
        fail(i, f"time must increase: t[{k + 1}] = {t[k + 1]} after t[{k}] = {t[k]}")
    delta = float(np.median(dt))
    if np.max(np.abs(dt - delta)) > TOL * delta:
        k = int(np.argmax(np.abs(dt - delta)))
        fail(
            i,
            f"sampling is not uniform (t[{k + 1}] - t[{k}] = {dt[k]}, median {delta}); "
            "the DARMA models (31)-(32) need a fixed sampling period",
        )
    return t, u, y, delta


def _interval_types(i: int, v: np.ndarray) -> tuple[np.ndarray, float, float]:
    """+1 / -1 for intervals on the rising / falling ramp, 0 for corner intervals."""
    if not np.any(v > 0) or not np.any(v < 0):
        fail(
            i,
            "the input never "
            + ("rises" if not np.any(v > 0) else "falls")
            + ": a triangle wave (20) needs both branches",
        )
    a, b = float(np.median(v[v > 0])), float(np.median(v[v < 0]))
    kind = np.zeros(len(v), dtype=int)
    kind[np.abs(v - a) <= TOL * a] = 1
    kind[np.abs(v - b) <= TOL * -b] = -1
    zero = np.flatnonzero((kind[:-1] == 0) & (kind[1:] == 0))
    if zero.size:
        k = int(zero[0])
        fail(
            i,
            f"branch not monotone or not a ramp near samples {k}..{k + 2} (du/dt = {v[k]:.6g}, "
            f"{v[k + 1]:.6g}; the ramps have slopes a = {a:.6g}, b = {b:.6g}), or the branches are "
            "too short: each must span whole sample intervals (sample faster)",
        )
    return kind, a, b


def _runs(kind: np.ndarray) -> list[tuple[int, int, int]]:
    """Maximal runs (direction, first interval, last interval) of ramp intervals."""
    edges = np.flatnonzero(np.diff(kind)) + 1
    starts, stops = np.r_[0, edges], np.r_[edges, len(kind)]
    return [(int(kind[s]), int(s), int(e - 1)) for s, e in zip(starts, stops) if kind[s] != 0]


def _corners(i: int, t, u, runs, a: float, b: float) -> list[tuple[int, float, float]]:
    """Corners (direction of the preceding run, time, value) between consecutive runs."""
    out = []
    for (d0, _, e0), (d1, s1, _) in zip(runs[:-1], runs[1:]):
        if d0 == d1:
            fail(
                i,
                f"branch not monotone: the input turns back between samples {e0 + 1} and {s1} "
                "and resumes in the same direction",
            )
        if s1 == e0 + 1:
            out.append((d0, t[s1], u[s1]))
        else:
            k = e0 + 1
            s0, s1_ = (a, b) if d0 > 0 else (b, a)
            tc = (u[k + 1] - u[k] + s0 * t[k] - s1_ * t[k + 1]) / (s0 - s1_)
            out.append((d0, tc, u[k] + s0 * (tc - t[k])))
    return out


def _fit_wave(i: int, t, u, runs, a: float, b: float) -> TriangleWave:
    corners = _corners(i, t, u, runs, a, b)
    if not corners:
        fail(i, "the input has no corner (a single ramp): a triangle wave (20) needs both branches")
    tops = [c for c in corners if c[0] > 0]
    bottoms = [c for c in corners if c[0] < 0]
    u_hi = float(np.mean([c[2] for c in tops])) if tops else float(np.max(u))
    u_lo = float(np.mean([c[2] for c in bottoms])) if bottoms else float(np.min(u))
    amp = u_hi - u_lo
    for d, tc, uc in corners:
        ref = u_hi if d > 0 else u_lo
        if abs(uc - ref) > 1e3 * TOL * amp:
            fail(
                i,
                f"branch not monotone: the corner at t = {tc:.6g} has u = {uc:.6g} but the wave's "
                f"{'maximum' if d > 0 else 'minimum'} is {ref:.6g}",
            )
    t_min = bottoms[0][1] if bottoms else tops[0][1] - amp / a
    wave = TriangleWave(a=a, b=b, u_lo=u_lo, u_hi=u_hi, t_min=float(t_min))
    off = np.abs(wave(t) - u)
    if off.max() > 1e3 * TOL * amp:
        k = int(np.argmax(off))
        fail(
            i,
            f"u[{k}] = {u[k]:.6g} is off the triangle wave (expected {wave(t[k]):.6g}): "
            "branches must be monotone ramps of constant slope",
        )
    return wave


def parse_record(i: int, rec, order: int) -> Record:
    t, u, y, delta = _check_arrays(i, rec, order)
    v = np.diff(u) / np.diff(t)
    kind, a, b = _interval_types(i, v)
    runs = _runs(kind)
    wave = _fit_wave(i, t, u, runs, a, b)
    by_dir: dict = {1: [], -1: []}
    last = len(kind) - 1
    for d, s, e in runs:
        samples = e - s + 2
        if samples >= order + 2:
            by_dir[d].append((s, e + 1))
        elif s > 0 and e < last:
            name = "rising" if d > 0 else "falling"
            fail(
                i,
                f"the {name} branch at samples {s}..{e + 1} has {samples} samples on the ramp; "
                f"order {order} needs at least {order + 2} per branch (sample faster or use a "
                "slower triangle wave): branches too short",
            )
    return Record(index=i, t=t, u=u, y=y, delta=delta, wave=wave, runs=by_dir)


# ----------------------------------------------------------------------------- DARMA and transforms
