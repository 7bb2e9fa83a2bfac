"""Reversals of an input signal and the full input cycles between them.

Reversals (`find_reversals`)
----------------------------
A hysteresis (zig-zag) detector.  While the input rises, its running maximum
is tracked; the maximum counts as a reversal only once the input has fallen
below it by more than a threshold ``h``, and vice versa.  The reversal index
is the first sample at the extreme; the start and the end of the signal are
not reversals.  The one threshold policy of the project (`reversal_threshold`)
is

    h = max(0.05 * range(u), 6 * noise_rms(u)),

so noise and quantisation steps never create reversals, and minor loops
smaller than 5% of the range are not split off.  Any other ``h`` may be
passed explicitly (``threshold=``); e.g. ``0.1 * range(u)`` counts only
reversals larger than 10% of the input range.

Cycles
------
* A **full cycle** (`cycle_reversals`, `split_cycles`) runs from one reversal
  to the second next (min -> max -> min or max -> min -> max), both ends
  included; consecutive cycles share their end sample.  The kind of start
  giving more cycles is used (ties: minima).
* A record without such a cycle that starts mid-branch, passes one maximum
  and one minimum and comes back to its starting input in the starting
  direction holds one whole **period** (`period_cycle`).
* The **last full cycle** (`last_full_cycle`, used by the error measures)
  runs from the third-last reversal to the last, whatever its kind, or is the
  whole period.
* A record is one **closing period** (`closing_period`) when it has at least
  two reversals, ends within 10% of the input range of its first input and
  moves in the same direction at both ends.
* A record is a **closed loop** (`closed_loop`) when it is one closing
  period whose output also ends within 10% of the output range of its first
  output: its first sample lies on the loop it repeats, a steady cycle (an
  experiment that starts from rest or from a virgin state does not close).
"""

from __future__ import annotations

import numpy as np

from fitter.core.errors import DuhemError
from fitter.data.noise import noise_or_zero
from fitter.data.recordings import Recording

__all__ = [
    "PreparationError",
    "REVERSAL_FRACTION",
    "REVERSAL_NOISE_FACTOR",
    "reversal_threshold",
    "find_reversals",
    "count_reversals",
    "cycle_reversals",
    "period_cycle",
    "closing_period",
    "single_loop",
    "split_cycles",
    "last_full_cycle",
    "closed_last_cycle",
    "closed_loop",
]

REVERSAL_FRACTION = 0.05
REVERSAL_NOISE_FACTOR = 6.0
PERIOD_CLOSURE = 0.01
"""`period_cycle`: a record ending this fraction of range(u) short of u[0] still closes."""
LOOSE_CLOSURE = 0.1
"""`closing_period`: |u[-1] - u[0]| below this fraction of range(u)."""


class PreparationError(DuhemError):
    """A recording that cannot be prepared (e.g. too few input cycles)."""


def _as_u(rec_or_u) -> np.ndarray:
    return np.asarray(rec_or_u.u if isinstance(rec_or_u, Recording) else rec_or_u, dtype=float).ravel()


def reversal_threshold(u) -> float:
    """Default reversal threshold ``max(0.05 * range(u), 6 * noise_rms(u))`` (noise 0 when u is short)."""
    u = np.asarray(u, dtype=float)
    return max(REVERSAL_FRACTION * float(np.ptp(u)), REVERSAL_NOISE_FACTOR * noise_or_zero(u))


def find_reversals(u, *, threshold: float | None = None) -> np.ndarray:
    """Indices of the input's reversals (alternating maxima and minima).

    An extreme counts once the input has moved back from it by more than
    `threshold` (default `reversal_threshold`); the start and the end of
    the signal are not reversals.  No reversal when the threshold is not
    positive (a constant input).
    """
    u = np.asarray(u, dtype=float).ravel()
    if u.size < 3:
        return np.zeros(0, dtype=int)
    thr = reversal_threshold(u) if threshold is None else float(threshold)
    if not thr > 0:
        return np.zeros(0, dtype=int)
    found = []
    i_max = i_min = 0
    direction = 0
    ext = 0
    for k in range(1, u.size):
        v = u[k]
        if direction == 0:
            if v > u[i_max]:
                i_max = k
            if v < u[i_min]:
                i_min = k
            if v - u[i_min] > thr:
                direction, ext = 1, k
            elif u[i_max] - v > thr:
                direction, ext = -1, k
        elif direction > 0:
            if v > u[ext]:
                ext = k
            elif u[ext] - v > thr:
                found.append(ext)
                direction, ext = -1, k
        else:
            if v < u[ext]:
                ext = k
            elif v - u[ext] > thr:
                found.append(ext)
                direction, ext = 1, k
    return np.asarray(found, dtype=int)


def count_reversals(u, *, threshold: float | None = None) -> int:
    """Number of `find_reversals` of u (same threshold)."""
    return int(find_reversals(u, threshold=threshold).size)


def cycle_reversals(
    rec_or_u, *, threshold: float | None = None, reversals: np.ndarray | None = None
) -> list[tuple[int, int, int]]:
    """Full cycles as (start, middle, end) reversal indices (see the module docstring)."""
    u = _as_u(rec_or_u)
    r = find_reversals(u, threshold=threshold) if reversals is None else np.asarray(reversals)
    if len(r) < 3:
        return []
    starts = [j for j in range(0, len(r) - 2, 2)], [j for j in range(1, len(r) - 2, 2)]
    first_is_min = u[r[0]] < u[r[1]]
    by_min = starts[0] if first_is_min else starts[1]
    by_max = starts[1] if first_is_min else starts[0]
    chosen = by_min if len(by_min) >= len(by_max) else by_max
    return [(int(r[j]), int(r[j + 1]), int(r[j + 2])) for j in chosen]


def period_cycle(u, reversals: np.ndarray) -> slice | None:
    """The whole-period cycle of a record with exactly two reversals, or None.

    A record that starts mid-branch, passes one maximum and one minimum and
    comes back to its starting input in the starting direction (e.g. one
    period of a triangle from 0 V) holds one full cycle: from sample 0 to the
    first sample after the second reversal at which the input is back at
    u[0], or to the last sample if it ends within ``0.01 * range(u)`` short
    of u[0].
    """
    u = np.asarray(u, dtype=float)
    r = np.asarray(reversals)
    if len(r) != 2:
        return None
    rising = u[r[0]] > u[r[1]]
    back = np.flatnonzero(u[r[1] :] >= u[0] if rising else u[r[1] :] <= u[0])
    if back.size:
        return slice(0, int(r[1] + back[0]) + 1)
    if abs(u[-1] - u[0]) <= PERIOD_CLOSURE * float(np.ptp(u)):
        return slice(0, u.size)
    return None


def closing_period(u, reversals: np.ndarray) -> slice | None:
    """The whole record as one cycle when it is one closing period, else None.

    Closing: at least two reversals, ``|u[-1] - u[0]| < 0.1 * range(u)`` and
    the same direction of motion at both ends, ``sign(u[1] - u[0]) ==
    sign(u[-1] - u[-2])``; or a `single_loop`.
    """
    u = np.asarray(u, dtype=float)
    if (
        len(reversals) >= 2
        and abs(u[-1] - u[0]) < LOOSE_CLOSURE * np.ptp(u)
        and np.sign(u[1] - u[0]) == np.sign(u[-1] - u[-2])
    ):
        return slice(0, u.size)
    return single_loop(u, reversals)


def closed_loop(rec: Recording) -> bool:
    """Whether `rec` is a closed loop (module docstring): one `closing_period` of its input, and
    ``|y[-1] - y[0]| < 0.1 * range(y)``."""
    u, y = _as_u(rec), np.asarray(rec.y, dtype=float)
    if u.size < 3 or closing_period(u, find_reversals(u)) is None:
        return False
    return bool(abs(y[-1] - y[0]) < LOOSE_CLOSURE * np.ptp(y))


def single_loop(u, reversals: np.ndarray) -> slice | None:
    """The whole record as one cycle when it is a single loop from one extreme to the other and back.

    One reversal, both ends within ``0.1 * range(u)`` of each other and on the
    side opposite the reversal (e.g. a B-H loop from -H_max to +H_max and back),
    so that the record closes: the cycle runs from the first to the last sample.
    """
    u = np.asarray(u, dtype=float)
    if len(reversals) != 1:
        return None
    span = float(np.ptp(u))
    k = int(reversals[0])
    ends_opposite = min(abs(u[0] - u[k]), abs(u[-1] - u[k])) > (1 - LOOSE_CLOSURE) * span
    if ends_opposite and abs(u[-1] - u[0]) < LOOSE_CLOSURE * span:
        return slice(0, u.size)
    return None


def split_cycles(rec_or_u, *, threshold: float | None = None) -> list[slice]:
    """Full input cycles of a recording (or input array) as slices.

    Each runs from a reversal to the second next one, both included, so
    u[s][0] and u[s][-1] are extremes of the same kind.  Without such a
    cycle, a record covering one whole period from mid-branch gives one
    cycle (`period_cycle`).
    """
    u = _as_u(rec_or_u)
    r = find_reversals(u, threshold=threshold)
    cycles = [slice(a, c + 1) for a, _, c in cycle_reversals(u, reversals=r)]
    if not cycles:
        whole = period_cycle(u, r)
        cycles = [whole] if whole is not None else []
    return cycles


def last_full_cycle(u, *, threshold: float | None = None) -> slice:
    """Samples of the last full input cycle: from the third-last reversal to the last, both included.

    A record with two reversals that covers one whole period gives that
    period (`period_cycle`).  Raises `PreparationError` when there is no
    full cycle.
    """
    r = find_reversals(u, threshold=threshold)
    if len(r) >= 3:
        return slice(int(r[-3]), int(r[-1]) + 1)
    whole = period_cycle(u, r)
    if whole is None:
        raise PreparationError(
            f"no full input cycle: the input reverses {len(r)} time(s) and does not cover a whole period"
        )
    return whole


def closed_last_cycle(t, u) -> tuple[slice, np.ndarray, np.ndarray]:
    """The last full input cycle (`last_full_cycle`) and its samples closed back to its starting input: one
    more sample, one median sample period later, at the cycle's first input (a measured cycle rarely ends
    exactly where it started; the closed one is the input that repeats it).  Raises `PreparationError`
    when there is no full cycle."""
    s = last_full_cycle(u)
    tc, uc = np.asarray(t)[s], np.asarray(u)[s]
    return s, np.r_[tc, tc[-1] + np.median(np.diff(tc))], np.r_[uc, uc[0]]
