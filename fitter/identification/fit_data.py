"""Recordings made ready for `fit_recordings`: cleaned, normalised, with cycles and loops.

0. Periodic or general input: an experiment that repeats one cycle has its
   peaks (and its troughs) at nearly the same input (spread at most
   `PERIODIC_SPREAD` of the input range); anything else (random or
   broadband inputs, planned blocks of different amplitude) is a *general*
   input: no cycles or loops are taken from it, every sample is fitted with
   the initial state fitted, from generic starts (``FitData.loops`` None).
1. Preparation (`fitter.data.preparation.prepare`): input reversals, settled
   cycles (the start-up transient is dropped), holds, drift; the notes go into
   the summary.  A recording whose input never reverses, or that holds
   neither a full cycle nor one closing period (a single loop from one
   extreme to the other and back counts), is rejected (`FitError`).
2. The model is fitted on the *raw* input (what an FMU will be driven with),
   on every sample when the initial state is fitted (``x0_mode = "fit"``,
   several cycles: the start-up transient is then the initial state's to
   explain, and what is optimised is what `exported.score` reports); from the
   first settled cycle when each recording holds a single cycle (``"periodic"``).
   Where measurement noise on u makes it reverse at many more samples than
   its true reversals (more than `NOISY_RUNS` times), the noise reversals
   would switch the branches of a rate-independent model at every sample; the
   fitted model then carries a dead band on its input, the play operator
   (`backlash` effect) of width b = `DEADBAND_SIGMAS` x the input's noise RMS,
   so that the model itself ignores reversals smaller than the noise, in the
   fit and in the FMU alike (``FitData.deadband``, stated in the notes).  b is
   fixed, so the fit runs the base model on the play operator's output
   (computed once) and the exported model carries the `backlash` effect: the
   same input-output map.  The
   input made monotone between reversals (isotonic regression,
   `monotone_input`) is used only for the loops that give starting values.
3. Normalisation (`Normalisation`, mid-range and half-range of all recordings).
4. The averaged loop: the settled branches resampled on a uniform input grid
   and averaged over cycles and recordings (the input-domain
   reparameterisation of Section III), a start for rate-independent fits.
5. Rate levels: the distinct input rates (median |du/dt| per recording,
   grouped so that no level spans more than a factor 1.5: five rates spread
   over 1.9x are two levels, not one chain), the reference rate and the knots
   of g.  The number of levels is at least that of the legs' mean rates
   (`leg_rates`, grouped the same way): one recording whose legs are driven at
   several speeds has several rate levels too.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from scipy.optimize import isotonic_regression

from fitter.core.effects import play_operator
from fitter.core.errors import DuhemError
from fitter.data.preparation import PreparationError, Prepared, branch_on_grid, find_reversals, prepare
from fitter.data.recordings import Recording
from fitter.identification.scaling import Normalisation

__all__ = [
    "FitError",
    "FitData",
    "RateLevels",
    "prepare_for_fit",
    "monotone_input",
    "averaged_loop",
    "rate_levels",
    "extremes_spread",
    "GRID_POINTS",
    "PERIODIC_SPREAD",
]

GRID_POINTS = 101
NOISY_RUNS = 2.0
DEADBAND_SIGMAS = 6.0
PERIODIC_SPREAD = 0.1
"""Largest spread of an input's peaks (and of its troughs), as a fraction of its range, for a
repeated-cycle experiment; beyond it the input is fitted as a general one (step 0)."""


class FitError(DuhemError):
    """Recordings that cannot be fitted (too few cycles, an input that never reverses, ...)."""


@dataclass
class FitData:
    """Prepared recordings: physical (trimmed, raw input) and normalised, with cycles and the
    loops (monotone input) that give starting values.

    x0_mode: "periodic" when every recording holds a single cycle (transient and
    loop cannot be told apart, so each is taken as settled), else "fit".
    """

    preps: list[Prepared]
    recs: list[Recording]
    norm: list[Recording]
    cycles: list[tuple[int, int] | None]
    loops: list[list[Recording]] | None
    """The settled cycles as loops (starting values); None for a general input (step 0)."""
    notes: list[list[str]]
    scaling: Normalisation
    x0_mode: str = "fit"
    deadband: float = 0.0
    """Width b of the input dead band (physical input units; 0: none), step 2 of the module docstring."""
    starts: list[int] | None = None
    """With x0 "fit": the recordings' start groups (`start_groups`), each group fitted from one initial state
    (`fitter.identification.output_error.Recordings`' ``starts``); None: each recording from its own."""
    references: bool = False
    """With x0 "fit": every recording but the first has its own output reference, fitted with its initial state
    (`fitter.identification.output_error.Recordings`' ``references``: separate runs, each written by an
    instrument zeroed anew)."""

    def input_range(self) -> tuple[float, float]:
        """Smallest and largest normalised input over all recordings."""
        return min(r.u.min() for r in self.norm), max(r.u.max() for r in self.norm)


def monotone_input(u: np.ndarray, reversals: np.ndarray) -> np.ndarray:
    """u made monotone between successive reversals by isotonic regression (least squares).

    Segments run from one reversal to the next (and from the ends to the
    first and last reversal); each is replaced by its best non-decreasing or
    non-increasing approximation.  A noise-free piecewise-monotone input is
    returned unchanged.
    """
    u = np.asarray(u, dtype=float)
    out = u.copy()
    cuts = np.r_[0, np.asarray(reversals, dtype=int), len(u) - 1]
    for a, b in zip(cuts[:-1], cuts[1:]):
        if b - a < 1:
            continue
        seg = u[a : b + 1]
        out[a : b + 1] = isotonic_regression(seg, increasing=bool(seg[-1] >= seg[0])).x
    return out


def _loop_pieces(rec: Recording, prep: Prepared, cycle: tuple[int, int]) -> list[Recording]:
    """Each settled cycle as one loop min -> max -> min (rotated to start at its minimum;
    the cycle's end sample is taken as equal to its first)."""
    slices = prep.cycles or [slice(cycle[0], cycle[1] + 1)]
    pieces = []
    for s in slices:
        u, y = rec.u[s], rec.y[s]
        k = int(np.argmin(u))
        idx = np.r_[np.arange(k, len(u)), np.arange(1, k + 1)] if k else np.arange(len(u))
        pieces.append(Recording(np.arange(len(idx), dtype=float), u[idx], y[idx], rec.name))
    return pieces


def _prepare_one(rec: Recording) -> tuple[Prepared, Recording, tuple[int, int], list[str]]:
    reversals = find_reversals(rec.u)
    if len(reversals) < 1:
        raise FitError(
            f"{rec.label}: the input never reverses (it must go up and down at least once: "
            f"a single loop, or periodically)"
        )
    try:
        prep = prepare(rec, min_cycles=0)
        cycle = prep.first_cycle()
    except PreparationError as exc:
        raise FitError(str(exc)) from None
    r = prep.recording
    um = monotone_input(r.u, prep.reversals)
    return prep, Recording(r.t, um, r.y, r.name, r.input, r.output, r.source), cycle, list(prep.notes)


def _direction_changes(u: np.ndarray) -> int:
    """Sign changes of du (held samples skipped)."""
    d = np.sign(np.diff(u))
    d = d[d != 0]
    return int(np.count_nonzero(d[1:] != d[:-1]))


def _deadband(preps: list[Prepared], notes: list[list[str]]) -> float:
    """Step 2 of the module docstring: b = DEADBAND_SIGMAS x input noise RMS, or 0."""
    noisy = [_direction_changes(p.recording.u) > NOISY_RUNS * (len(p.reversals) + 1) for p in preps]
    if not any(noisy):
        return 0.0
    b = DEADBAND_SIGMAS * max(p.input_noise_rms for p in preps)
    for p, n, is_noisy in zip(preps, notes, noisy):
        if is_noisy:
            n.append(
                f"the input reverses at {_direction_changes(p.recording.u)} samples but has "
                f"{len(p.reversals)} true reversals (noise on the input, RMS {p.input_noise_rms:.3g}): "
                f"the model carries an input dead band (play operator) of width {b:.3g} "
                f"({DEADBAND_SIGMAS:g} x the noise), in the fit and in the exported model"
            )
    return b


def _fit_input(prep: Prepared, b: float, whole: bool) -> Recording:
    """The recording the model is fitted on: all raw samples (`whole`) or the trimmed ones, its
    input through the dead band of width b (from the first raw sample, w_0 = u_0, as the
    exported model runs it) when b > 0."""
    r = prep.original if whole else prep.recording
    if b <= 0:
        return r
    w = play_operator(prep.original.u, b, float(prep.original.u[0]))[0 if whole else prep.transient_end :]
    return Recording(r.t, w, r.y, r.name, r.input, r.output, r.source)


def extremes_spread(u: np.ndarray) -> float:
    """Largest range of the input's peaks or of its troughs, as a fraction of its range (0 with at most
    one of each): small for a repeated cycle, large for a random input or blocks of different amplitude."""
    r = find_reversals(u)
    if len(r) < 3:
        return 0.0
    first_is_peak = u[r[0]] > u[r[1]]
    peaks, troughs = (r[0::2], r[1::2]) if first_is_peak else (r[1::2], r[0::2])
    return float(max(np.ptp(u[peaks]), np.ptp(u[troughs])) / max(np.ptp(u), 1e-300))


def _prepare_general(recordings: Sequence[Recording]) -> FitData:
    """Step 0, a general input: every sample fitted, initial state fitted, no loops."""
    preps, notes = [], []
    for rec in recordings:
        if len(find_reversals(rec.u)) < 1:
            raise FitError(f"{rec.label}: the input never reverses (it must go up and down at least once)")
        prep = prepare(rec, min_cycles=0, drop_transient=False)
        preps.append(prep)
        notes.append(
            list(prep.notes)
            + [
                f"the input does not repeat one cycle (its peaks or troughs spread over "
                f"{100 * extremes_spread(rec.u):.0f}% of the input range): fitted as a general input, on every "
                f"sample, with the initial state fitted and generic starting values (no input dead band: the "
                f"reversals of such an input cannot be told from noise)"
            ]
        )
    recs = [_fit_input(p, 0.0, True) for p in preps]
    try:
        scaling = Normalisation.of(recs)
    except DuhemError as exc:
        raise FitError(str(exc)) from None
    return FitData(
        preps, recs, [scaling.normalise(r) for r in recs], [None] * len(recs), None, notes, scaling, "fit", 0.0
    )


SAME_START = 0.02
"""Recordings whose first inputs differ by at most this fraction of the input range start at one input level
(`start_groups`)."""


def start_groups(recordings: Sequence[Recording], tolerance: float = SAME_START) -> list[int]:
    """A group index per recording: recordings whose first input lies within `tolerance` of the input range
    (over all of them) of a group's first member's first input share its index (groups in order of first
    members, from 0).  Runs of one device reset to one state before each run start from one state only where
    they start at one input: the coordinates x' = x + K u give the rate-independent class the same input-output
    map for every K, so the data do not define "the same state" at two input levels."""
    span = max(float(np.ptp(np.concatenate([r.u for r in recordings]))), 1e-300)
    firsts, groups = [], []
    for r in recordings:
        u0 = float(r.u[0])
        g = next((k for k, f in enumerate(firsts) if abs(u0 - f) <= tolerance * span), None)
        if g is None:
            firsts.append(u0)
            g = len(firsts) - 1
        groups.append(g)
    return groups


def prepare_for_fit(recordings: Sequence[Recording], settled: bool = True, shared_start: bool = False) -> FitData:
    """Steps 0-3 of the module docstring for every recording; `settled` False: the initial state fitted
    (``x0_mode = "fit"``) even where every recording holds a single cycle; `shared_start`: with x0 "fit", the
    recordings that start at one input level (`start_groups`) share their initial state."""
    data = _prepared(recordings, settled)
    if shared_start and data.x0_mode == "fit":
        data = replace(data, starts=start_groups(data.recs))
    return data


def _prepared(recordings: Sequence[Recording], settled: bool) -> FitData:
    """`prepare_for_fit` but the start groups."""
    if not recordings:
        raise FitError("no recordings to fit")
    if any(extremes_spread(rec.u) > PERIODIC_SPREAD for rec in recordings):
        return _prepare_general(recordings)
    preps, cycles, loops, notes = [], [], [], []
    for rec in recordings:
        prep, clean, cycle, n = _prepare_one(rec)
        preps.append(prep)
        cycles.append(cycle)
        loops.append(_loop_pieces(clean, prep, cycle))
        notes.append(n)
    b = _deadband(preps, notes)
    x0_mode = "periodic" if settled and all(len(p.cycles) <= 1 for p in preps) else "fit"
    whole = x0_mode == "fit"
    recs = [_fit_input(p, b, whole) for p in preps]
    if whole:
        cycles = [(s0 + p.transient_end, s1 + p.transient_end) for (s0, s1), p in zip(cycles, preps)]
    try:
        scaling = Normalisation.of(recs)
    except DuhemError as exc:
        raise FitError(str(exc)) from None
    norm = [scaling.normalise(r) for r in recs]
    loops = [[scaling.normalise(p) for p in pieces] for pieces in loops]
    return FitData(preps, recs, norm, cycles, loops, notes, scaling, x0_mode, b)


def averaged_loop(loops: list[list[Recording]], points: int = GRID_POINTS):
    """Rising and falling branches on a common uniform input grid, averaged over all cycles.  Each cycle is
    split at its largest input into a rising and a falling branch; the grid is the input range every branch
    covers (a cycle that does not close, ending above its start, has a falling branch shorter than its
    rising one), less 1 % at each end."""
    pieces = [(p, int(np.argmax(p.u))) for ps in loops for p in ps]
    lo = max(max(p.u[: k + 1].min(), p.u[k:].min()) for p, k in pieces)
    hi = min(p.u[k] for p, k in pieces)
    if not hi > lo:
        raise FitError(
            f"{pieces[0][0].label}: the cycles' rising and falling branches share no input range "
            f"(each must sweep from its lowest to its highest input and back)"
        )
    span = hi - lo
    grid = np.linspace(lo + 0.01 * span, hi - 0.01 * span, points)
    rising = [branch_on_grid(p.u[: k + 1], p.y[: k + 1], grid) for p, k in pieces]
    falling = [branch_on_grid(p.u[k:], p.y[k:], grid) for p, k in pieces]
    return grid, np.mean(rising, axis=0), np.mean(falling, axis=0)


@dataclass(frozen=True)
class RateLevels:
    """Input rates of the data (normalised units): reference rate, log-rate knots of g, the
    number of distinct levels and whether all inputs are triangle waves (|du/dt| constant
    within 15 %); for other inputs the knots are 7 quantiles of the pooled log-rates."""

    v_ref: float
    knots: np.ndarray
    levels: int
    triangle: bool


def _rate_groups(meds: np.ndarray, factor: float = 1.5) -> list[np.ndarray]:
    """Sorted rates grouped so that no group spans more than `factor` (a new group starts where a
    rate exceeds `factor` x its group's first: rates are not chained into one level)."""
    groups = [[meds[0]]]
    for v in meds[1:]:
        if v > factor * groups[-1][0]:
            groups.append([v])
        else:
            groups[-1].append(v)
    return [np.array(g) for g in groups]


LEG_SPAN = 0.1
"""`leg_rates` counts the legs that span at least this fraction of the recording's input range."""


def leg_rates(rec: Recording) -> np.ndarray:
    """The mean input rate |u(end) - u(start)| / (t(end) - t(start)) of each leg of `rec` (its stretches between
    consecutive reversals, `fitter.data.cycles.find_reversals`, and the ends) that spans at least `LEG_SPAN` of its
    input range: legs driven at several speeds within one recording show as several rates."""
    ends = np.r_[0, find_reversals(rec.u), len(rec.u) - 1].astype(int)
    du = np.abs(np.diff(rec.u[ends]))
    dt = np.diff(rec.t[ends])
    keep = (du >= LEG_SPAN * max(float(np.ptp(rec.u)), 1e-300)) & (dt > 0)
    return du[keep] / dt[keep]


def rate_levels(norm: Sequence[Recording], legs: bool = True) -> RateLevels:
    """Step 5 of the module docstring; `legs` False: the levels of the recordings' median rates alone."""
    meds, pooled, triangle = [], [], True
    for r in norm:
        v = np.abs(np.diff(r.u) / np.diff(r.t))
        if not np.any(v > 0):
            raise FitError(
                f"{r.label}: the input does not move at the scale of all recordings together (another "
                f"recording's input range is so much wider that this one's span is below its rounding): "
                f"fit the recordings apart, or remove the outlier that widens the range"
            )
        v = v[v > 1e-3 * np.median(v[v > 0])]
        meds.append(np.median(v))
        pooled.append(v)
        inner = (v > np.quantile(v, 0.1)) & (v < np.quantile(v, 0.9))
        if not inner.any() or np.std(v[inner]) > 0.15 * np.median(v):
            triangle = False
    groups = _rate_groups(np.sort(meds))
    speeds = np.concatenate([leg_rates(r) for r in norm]) if legs else np.zeros(0)
    count = max(len(groups), len(_rate_groups(np.sort(speeds))) if len(speeds) else 1)
    levels = np.array([np.exp(np.mean(np.log(g))) for g in groups])
    if not triangle:
        v = np.concatenate(pooled)
        levels = np.exp(np.unique(np.quantile(np.log(v), np.linspace(0.02, 0.99, 7))))
    v_ref = float(levels[len(levels) // 2])
    return RateLevels(v_ref, np.log(levels / v_ref), count, triangle)
