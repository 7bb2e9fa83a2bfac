"""Automatic, reported preparation of a recording for identification.

Steps of `prepare` (each result is kept in the returned `Prepared`):

1. **Reversals** of the input (`fitter.data.cycles.find_reversals`, the
   threshold policy documented there).
2. **Cycles** (`fitter.data.cycles.cycle_reversals`): full cycles from one
   reversal to the second next; a record that is one whole period from
   mid-branch is one cycle (`fitter.data.cycles.period_cycle`).
3. **Settling** (`settled_start`): successive cycles are compared at matched
   input: on each branch, cycle k+1's output is interpolated linearly in u at
   cycle k's input samples over the input range both cover (2% trimmed at
   each end), the differences are averaged in 32 input bins, and d_k is the
   RMS of these bin means, less the drift per cycle (step 4), over both
   branches.  Cycle k is settled when every later d_j is below
   ``max(0.002 * range(y), 3 * noise of the bin means, 2 * min_j d_j)`` (the
   noise from the scatter within the bins; the last term keeps an irregular
   drift from counting as a transient).  Everything before the first
   settled cycle is the transient and is dropped.
4. **Drift** per cycle: the median over the later half of the cycle pairs of
   the mean binned difference (cycle k+1 minus cycle k), reported as a note
   when it exceeds the settling tolerance ("the loops do not close"); with
   a single cycle, its closure y(end) - y(start).
5. **Holds**: stretches of at least ``max(9 samples, 10% of the median
   branch length)`` where the input stays within a band of
   ``max(0.002 * range(u), 8 * noise_rms(u))`` (the spread of
   white noise over many samples stays below 8 RMS).

All indices in `Prepared` refer to the trimmed recording except
`transient_end`, the index in the original recording where it starts.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import maximum_filter1d, minimum_filter1d

from fitter.data.cycles import (
    PreparationError,
    closing_period,
    cycle_reversals,
    find_reversals,
    period_cycle,
    reversal_threshold,
)
from fitter.data.noise import noise_or_zero
from fitter.data.recordings import Recording

__all__ = ["Prepared", "settled_start", "cycle_differences", "find_holds", "branch_on_grid", "resample_time", "prepare"]

SETTLE_FRACTION = 0.002
SETTLE_BINS = 32
HOLD_FRACTION = 0.002
HOLD_MIN_SAMPLES = 9


def _bin_stats(u: np.ndarray, v: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per input bin: mean of v and the variance of that mean (scatter / count); bins with
    fewer than two samples are left out."""
    idx = np.digitize(u, edges) - 1
    ok = (idx >= 0) & (idx < len(edges) - 1)
    n = np.bincount(idx[ok], minlength=len(edges) - 1)
    s1 = np.bincount(idx[ok], weights=v[ok], minlength=len(edges) - 1)
    s2 = np.bincount(idx[ok], weights=v[ok] ** 2, minlength=len(edges) - 1)
    use = n >= 2
    mean = s1[use] / n[use]
    var = np.maximum(s2[use] / n[use] - mean**2, 0.0) * n[use] / (n[use] - 1)
    return mean, var / n[use]


def _branch_difference(u, y, a: slice, b: slice):
    """Bin means of y_b(u_a) - y_a over the common input range (2% trimmed at each end),
    y_b linearly interpolated in u (`branch_on_grid`), and the variance of each bin mean."""
    lo = max(u[a].min(), u[b].min())
    hi = min(u[a].max(), u[b].max())
    if not hi > lo:
        return np.zeros(0), np.zeros(0)
    pad = 0.02 * (hi - lo)
    ua, ya = u[a], y[a]
    keep = (ua >= lo + pad) & (ua <= hi - pad)
    if not keep.any():
        return np.zeros(0), np.zeros(0)
    diff = branch_on_grid(u[b], y[b], ua[keep]) - ya[keep]
    return _bin_stats(ua[keep], diff, np.linspace(lo + pad, hi - pad, SETTLE_BINS + 1))


def cycle_differences(u, y, cycles: list[tuple[int, int, int]]) -> tuple[list[np.ndarray], np.ndarray]:
    """Matched-input differences of successive cycles.

    Returns a list of len(cycles) - 1 arrays, the binned differences cycle
    k+1 minus cycle k at matched input over both branches, and for each the
    RMS those binned differences would have from noise alone, estimated from
    the scatter within the bins (so input noise and quantisation count too).
    """
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    diffs, noise = [], np.zeros(max(len(cycles) - 1, 0))
    for k in range(len(cycles) - 1):
        (a0, a1, a2), (b0, b1, b2) = cycles[k], cycles[k + 1]
        d1, w1 = _branch_difference(u, y, slice(a0, a1 + 1), slice(b0, b1 + 1))
        d2, w2 = _branch_difference(u, y, slice(a1, a2 + 1), slice(b1, b2 + 1))
        diffs.append(np.r_[d1, d2])
        noise[k] = np.sqrt(np.mean(np.r_[w1, w2])) if diffs[-1].size else 0.0
    return diffs, noise


def _settling(u, y, cycles) -> tuple[int, np.ndarray, float, float]:
    """(first settled cycle, drift-removed RMS differences, drift per cycle, tolerance)."""
    diffs, noise = cycle_differences(u, y, cycles)
    tol = SETTLE_FRACTION * float(np.ptp(y))
    if not diffs:
        return 0, np.zeros(0), 0.0, tol
    means = np.array([d.mean() if d.size else 0.0 for d in diffs])
    drift = float(np.median(means[len(means) // 2 :]))
    r = np.array([np.sqrt(np.mean((d - drift) ** 2)) if d.size else np.inf for d in diffs])
    tol = max(tol, 3.0 * float(np.max(noise)))
    floor = max(tol, 3.0 * float(np.median(r[len(r) // 2 :])))
    above = np.flatnonzero(r > floor)
    first = int(above[-1]) + 1 if above.size else 0
    return min(first, len(cycles) - 1), r, drift, tol


def settled_start(rec: Recording, *, threshold: float | None = None) -> int:
    """Index of the first sample of the first settled full cycle (0 without cycles).

    See step 3 of the module docstring.
    """
    cycles = cycle_reversals(rec, threshold=threshold)
    if not cycles:
        return 0
    k = _settling(rec.u, rec.y, cycles)[0]
    return cycles[k][0]


def find_holds(t, u, *, min_samples: int = HOLD_MIN_SAMPLES, band: float | None = None) -> list[tuple[int, int]]:
    """Holds of the input as [start, stop) index pairs (see step 5 of the module docstring).

    A hold is a run of at least `min_samples` samples in which the input
    stays within `band` (default ``max(0.002 range(u), 8 noise_rms(u))``);
    a step of more than `band` between two samples ends a hold (holds joined
    by steps of one sample are separate holds).
    """
    u = np.asarray(u, dtype=float)
    band = max(HOLD_FRACTION * float(np.ptp(u)), 8.0 * noise_or_zero(u)) if band is None else band
    L = int(min_samples) | 1
    if u.size < L:
        return []
    spread = maximum_filter1d(u, L) - minimum_filter1d(u, L)
    centre = spread <= band
    centre[: L // 2] = False
    centre[u.size - L // 2 :] = False
    mask = maximum_filter1d(centre.astype(np.uint8), L).astype(bool)
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    steps = np.flatnonzero(np.abs(np.diff(u)) > band) + 1  # a step of one sample ends a hold, the next begins
    holds = []
    for a, b in zip(edges[0::2], edges[1::2]):
        cuts = steps[(steps > a) & (steps < b)]
        holds += [(int(s), int(e)) for s, e in zip(np.r_[a, cuts], np.r_[cuts, b]) if e - s >= min_samples]
    return holds


def branch_on_grid(u, y, grid) -> np.ndarray:
    """Output of one monotone branch at the input values `grid` (linear interpolation).

    The samples are sorted by input (noise may make a measured branch
    locally non-monotone) and samples with equal input (quantisation) are
    averaged; y is then linearly interpolated in u, consistent with an input
    taken as piecewise linear between samples.  Raises `PreparationError`
    when `grid` leaves the branch's input range or the branch has fewer than
    two distinct input values.
    """
    u = np.asarray(u, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    grid = np.asarray(grid, dtype=float)
    if u.shape != y.shape:
        raise PreparationError(f"branch input and output differ in length ({u.size} and {y.size})")
    levels, inverse = np.unique(u, return_inverse=True)
    if levels.size < 2:
        raise PreparationError("branch has fewer than two distinct input values")
    means = np.bincount(inverse, weights=y) / np.bincount(inverse)
    slack = 1e-9 * (levels[-1] - levels[0])
    if grid.min() < levels[0] - slack or grid.max() > levels[-1] + slack:
        raise PreparationError(
            f"grid [{grid.min():.6g}, {grid.max():.6g}] leaves the branch's input "
            f"range [{levels[0]:.6g}, {levels[-1]:.6g}]"
        )
    return np.interp(grid, levels, means)


def resample_time(rec: Recording, dt: float | None = None) -> Recording:
    """The recording on a uniform time grid t0, t0 + dt, ... (default dt: median sample period).

    u and y are interpolated linearly (the input is piecewise linear between
    samples throughout the project).
    """
    step = float(np.median(np.diff(rec.t))) if dt is None else float(dt)
    if not step > 0:
        raise PreparationError(f"{rec.label}: time step must be positive, got {step}")
    t = rec.t[0] + step * np.arange(int(np.floor((rec.t[-1] - rec.t[0]) / step + 1e-9)) + 1)
    return Recording(
        t, np.interp(t, rec.t, rec.u), np.interp(t, rec.t, rec.y), rec.name, rec.input, rec.output, rec.source
    )


@dataclass
class Prepared:
    """A recording ready for identification, and what was done to it."""

    recording: Recording
    original: Recording
    reversals: np.ndarray
    cycles: list[slice]
    transient_end: int
    holds: list[tuple[int, int]]
    drift_per_cycle: float
    threshold: float
    noise_rms: float
    input_noise_rms: float
    cycle_difference: list[float] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def n_cycles(self) -> int:
        return len(self.cycles)

    def first_cycle(self) -> tuple[int, int]:
        """(s0, s1): first and last sample, both included, of the first settled full cycle.

        Without a full cycle: the whole recording when it is one closing
        period (`fitter.data.cycles.closing_period`).  The indices refer to
        `recording` (the trimmed recording; add `transient_end` for `original`).

        Raises
        ------
        PreparationError
            Neither a full cycle nor one closing period; the message names
            the recording and its number of reversals.
        """
        s = self.cycles[0] if self.cycles else closing_period(self.recording.u, self.reversals)
        if s is None:
            raise PreparationError(
                f"{self.recording.label}: too few cycles: no full input cycle "
                f"({len(self.reversals)} reversals) and the recording is not one "
                f"closing period"
            )
        return s.start, s.stop - 1

    def to_dict(self) -> dict:
        """JSON-able summary (indices refer to the trimmed recording)."""
        r = self.recording
        return {
            "recording": r.name,
            "source": r.source,
            "samples": len(self.original),
            "samples_used": len(r),
            "transient_end": self.transient_end,
            "transient_time": float(self.original.t[self.transient_end] - self.original.t[0]),
            "reversal_threshold": self.threshold,
            "reversals": [int(i) for i in self.reversals],
            "cycles": [[s.start, s.stop] for s in self.cycles],
            "n_cycles": self.n_cycles,
            "holds": [
                {
                    "start": a,
                    "stop": b,
                    "t_start": float(r.t[a]),
                    "t_stop": float(r.t[b - 1]),
                    "input": float(np.mean(r.u[a:b])),
                }
                for a, b in self.holds
            ],
            "drift_per_cycle": self.drift_per_cycle,
            "noise_rms": self.noise_rms,
            "input_noise_rms": self.input_noise_rms,
            "cycle_difference": self.cycle_difference,
            "notes": list(self.notes),
        }


def prepare(
    rec: Recording, *, min_cycles: int = 1, threshold: float | None = None, drop_transient: bool = True
) -> Prepared:
    """Find reversals, cycles, holds, the settled part and the drift of `rec`.

    Raises `PreparationError` ("too few cycles") when fewer than
    `min_cycles` full input cycles remain.  See the module docstring.
    """
    label = rec.label
    thr = reversal_threshold(rec.u) if threshold is None else float(threshold)
    r = find_reversals(rec.u, threshold=thr)
    cycles = cycle_reversals(rec.u, reversals=r)
    whole = period_cycle(rec.u, r) if not cycles else None
    n_cycles = len(cycles) + (whole is not None)
    if n_cycles < min_cycles:
        raise PreparationError(
            f"{label}: too few cycles: the input has {n_cycles} full cycle(s) "
            f"({len(r)} reversals by more than {thr:.4g}), at least {min_cycles} needed"
        )
    sigma, sigma_u = noise_or_zero(rec.y), noise_or_zero(rec.u)
    notes = [f"{len(r)} input reversals (threshold {thr:.4g}), {n_cycles} full cycle(s)"]
    first, d, drift, tol = _settling(rec.u, rec.y, cycles) if cycles else (0, np.zeros(0), 0.0, 0.0)
    start = cycles[first][0] if (cycles and drop_transient) else 0
    if len(cycles) == 1:
        drift = _closure(rec, cycles[0])
    if start:
        notes.append(
            f"dropped the start-up transient before the first settled cycle: samples "
            f"0-{start - 1} (t < {rec.t[start]:.6g}, {100 * start / len(rec.u):.0f}% of the samples), "
            f"{first} unsettled full cycle(s)"
        )
    if d.size and np.isfinite(d[-1]) and d[-1] > tol:
        notes.append(
            f"successive cycles still differ by {d[-1]:.3g} RMS beyond the drift "
            f"({100 * d[-1] / np.ptp(rec.y):.2g}% of the output range) at the end: "
            f"cycle-to-cycle variation, or not fully settled"
        )
    if cycles and abs(drift) > tol:
        notes.append(
            f"the loops do not close: the output drifts by {drift:.3g} per cycle "
            f"({100 * drift / np.ptp(rec.y):.2g}% of the output range)"
        )
    if n_cycles == 1:
        notes.append("only one full cycle: settling could not be checked")
    trimmed = rec.slice(slice(start, None))
    rev = r[r >= start] - start
    branch_len = np.median(np.diff(r)) if len(r) > 1 else len(rec.u)
    holds = find_holds(trimmed.t, trimmed.u, min_samples=max(HOLD_MIN_SAMPLES, int(0.1 * branch_len)))
    if holds:
        total = sum(trimmed.t[b - 1] - trimmed.t[a] for a, b in holds)
        notes.append(f"{len(holds)} input hold(s), {total:.4g} time units in all")
    return Prepared(
        recording=trimmed,
        original=rec,
        reversals=rev,
        cycles=[whole]
        if whole is not None
        else [slice(a - start, c - start + 1) for a, _, c in cycles[first if drop_transient else 0 :]],
        transient_end=int(start),
        holds=holds,
        drift_per_cycle=drift,
        threshold=thr,
        noise_rms=sigma,
        input_noise_rms=sigma_u,
        cycle_difference=[float(x) for x in d],
        notes=notes,
    )


def _closure(rec: Recording, cycle: tuple[int, int, int]) -> float:
    """Closure y(end) - y(start) of a single cycle (5-sample means about its end reversals)."""
    a, _, c = cycle
    return float(np.mean(rec.y[max(c - 2, 0) : c + 3]) - np.mean(rec.y[max(a - 2, 0) : a + 3]))
