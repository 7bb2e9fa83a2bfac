"""Several runs of one device written by instruments of different gains: one output gain per recording.

Separate runs are often written by instruments calibrated anew (a charge amplifier's range, a load cell's
sensitivity) or made under an operating condition that scales the output (the normal force of a friction
contact).  Each recording's output is then g_i times the device's plus its reference r_i:

    y_i = g_i yhat_i + r_i,   g_0 = 1, r_0 = 0 (the first recording's frame is the model's own).

The gains are a property of the files, like the references (`fitter.identification.run_starts.zeros_apart`), not
physics of the device.  `fit_recordings` finds them so:

1. **Detection** (`gains_apart`): the best candidate of the search (with its references), each recording from
   its own fitted initial state; each recording's output regressed on the candidate's, y_i ~ a_i yhat_i + b_i
   (linear least squares).  The gains are apart when that lowers the RSS on the N prepared samples below
   1 / `SHARED_START_RSS` of it and by more than BIC allows for the R gains and the first reference:
   N ln(RSS / RSS_g) > R ln N, every a_i positive.  Where they are not, and runs start alike each from its own
   start, the same test under their start groups (`fitter.identification.fit_data.start_groups`), with references:
   a flexible model's own start per run can mimic the run's gain (an ri4 fitted to three 190-sample runs of an ri1
   device at gains 1 / 0.57 / 1.02 regressed to 1 / 0.98 / 1.00 from its own starts, and missed the later runs by
   59 and 37 % from the stored x0), one state for the runs that start alike cannot.  Where the one stored x0 does
   not suit those runs (`fitter.identification.run_starts.apart`) and the regression shows no gains, the candidate
   is refined under their start groups with and without the gains (`_refined_apart`), and the gains are apart
   when that leaves below 1 / `SHARED_START_RSS` of the RSS and passes BIC's test.  Where none of that shows
   gains, the same refined test is made on the search's lowest order (under the start groups, if any): the least
   flexible model has the fewest ways to mimic a gain (two noise-free runs of a first-order device from one start,
   the second at gain 0.904: an ri4 fitted each to 1e-12 of the range without a gain, and regressed to gains
   1.0009 / 0.9989 by the diagnosis' first-order base; the first-order candidate refined with the gain found it
   to nine digits).
2. **Rounds** (`calibrated_search`): the recordings are put in the first one's frame, y_i / g_i with
   g_i = a_i / a_0, and searched again with references (orders up to the first search's choice; runs that share
   an initial state in the first search share it here, `fitter.identification.fit_data.start_groups`).  Every
   candidate of that search is refined jointly with the gains (`refined_gains`, `WithGains`: the regression's gains
   are biased by the joint model's compromise between the files, where a flexible model gives a file's loops of
   another input span another size: an ri2 device of three files at gains 1 / 0.7 / 1.35 regressed to
   1 / 0.73 / 1.13 after three rounds), and the gains of the one of lowest BIC (`_least_bic_gains`: a flexible
   model refined with them can trade a gain for its own modes) rescale the recordings for the next round, until
   every gain moves by less than `GAIN_TOLERANCE` or after `ROUNDS` rounds.
3. **Kept** (`_kept`) where its BIC on the raw outputs is lower (and, for gains only the lowest order showed, its
   raw RSS below 1 / `SHARED_START_RSS` of the first search's: a lowest order that misses the device's physics,
   rate dependence say, lets gains absorb some of it, and three noisy runs of an rd1 device at three rates then
   kept gains of 1.012 / 0.996 by BIC), the R - 1 gains counted: N ln(RSS_raw / N) +
   p ln N, with RSS_raw = sum_i g_i^2 RSS_i of each recording's residual in the model's frame (`raw_rss`); for runs
   that start alike searched under their start groups where the first search fitted each from its own start,
   where its RSS_raw is within `SHARED_START_RSS` times the first's (the shared-start rule of `fit_recordings`:
   three runs of an ri3 device at gains 1 / 1.15 / 1.05, searched from their own starts, ri4 at 0.83x the noise
   from them and 66x and 20x from the stored x0 on the later runs, kept over the gained search by BIC).

The model is the first recording's; the gains are in its ``fit_info["gains"]`` and the summary's ``gains``, and
every score of a recording compares it in the model's frame (`fitter.identification.exported.levelled`: the
NRMSE, RMS over range, is the same in both).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Sequence

import numpy as np

from fitter.core.errors import DuhemError
from fitter.data.recordings import Recording
from fitter.identification.exported import SHARED_START_RSS
from fitter.identification.fit_data import FitData, prepare_for_fit, start_groups
from fitter.identification.output_error import Recordings, divided
from fitter.identification.parametrisation import Parametrisation
from fitter.identification.refine import Options, refine
from fitter.identification.run_starts import apart
from fitter.identification.search import Candidate

__all__ = [
    "GAIN_TOLERANCE",
    "ROUNDS",
    "WithGains",
    "calibrated_search",
    "gain_and_zero",
    "gains_apart",
    "in_frame",
    "raw_rss",
    "refined_gains",
]

GAIN_TOLERANCE = 1e-3
"""The rounds stop when every recording's gain moves by less than this fraction (module docstring, item 2)."""
ROUNDS = 2
"""At most this many searches on the rescaled recordings (module docstring, item 2)."""
GAIN_BOUND = 100.0
"""A recording's gain is fitted within [1 / GAIN_BOUND, GAIN_BOUND] of the first's."""

Best = Callable[[Sequence[Candidate], FitData, Sequence[Recording]], Candidate]
Search = Callable[..., list[Candidate]]


def _own_residuals(cand: Candidate, data: FitData) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per prepared recording (normalised), (y, yhat) from its own fitted initial state (and its start group's
    and reference, as the data has them)."""
    problem = _problem(data, data.references)
    with np.errstate(all="ignore"):
        info = problem.residuals(cand.param, cand.res.theta)[2]
    return [(rec.y[s:], rec.y[s:] - r) for rec, (s, _, r, _, _) in zip(data.norm, info)]


def gain_and_zero(y: np.ndarray, yhat: np.ndarray) -> tuple[float, float] | None:
    """(g, c) of y ~ g yhat + c by linear least squares; None where yhat is constant or not finite."""
    if not (np.all(np.isfinite(yhat)) and np.ptp(yhat) > 0):
        return None
    (g, c), *_ = np.linalg.lstsq(np.column_stack([yhat, np.ones(len(yhat))]), y, rcond=None)
    return float(g), float(c)


def _regressed(pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, float, float]:
    """(a_i per recording, RSS of y - yhat, RSS of y_i - a_i yhat_i - b_i) over the recordings (`gain_and_zero`
    per recording); NaN gains where a recording's model output is constant or not finite."""
    gains, before, after = [], 0.0, 0.0
    for y, yhat in pairs:
        fitted = gain_and_zero(y, yhat)
        if fitted is None:
            return np.full(len(pairs), np.nan), np.inf, np.inf
        g, c = fitted
        gains.append(g)
        before += float(np.sum((y - yhat) ** 2))
        after += float(np.sum((y - (g * yhat + c)) ** 2))
    return np.array(gains), before, after


def gains_apart(cand: Candidate, data: FitData, recordings: Sequence[Recording]) -> np.ndarray | None:
    """The gains g_i = a_i / a_0 of the recordings relative to the first where they are apart (module docstring,
    item 1); None where they are not, or the recordings are not several of distinct names fitted each from a
    fitted initial state (x0 "fit")."""
    names = [r.name for r in recordings]
    if not _several(data, recordings):
        return None
    pairs = _own_residuals(cand, data)
    a, before, after = _regressed(pairs)
    n = sum(len(y) for y, _ in pairs)
    before, after = before + n * 1e-18, after + n * 1e-18  # rounding in normalised units
    if not (np.all(np.isfinite(a)) and np.all(a > 0) and np.isfinite(after)):
        return None
    if SHARED_START_RSS * after < before and n * np.log(before / after) > len(names) * np.log(n):
        return a / a[0]
    return None


class WithGains(Parametrisation):
    """A base parametrisation plus the log output gains of the recordings but the first: theta = [base...,
    ln g_1, ..., ln g_{R-1}]; the model built carries them in ``fit_info["gains"]``, which `Recordings` applies
    (each recording's output g times the model's).  The gains are not linear entries: the base's are."""

    def __init__(self, base: Parametrisation, names: Sequence[str]):
        self.base, self.gained = base, list(names[1:])
        self.size = base.size + len(self.gained)

    def names(self) -> list[str]:
        return self.base.names() + [f"ln gain {n}" for n in self.gained]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.base.bounds()
        k = len(self.gained)
        return np.r_[lo, [-np.log(GAIN_BOUND)] * k], np.r_[hi, [np.log(GAIN_BOUND)] * k]

    def build(self, theta: np.ndarray):
        model = self.base.build(theta[: self.base.size])
        gains = dict(zip(self.gained, np.exp(theta[self.base.size :]).tolist()))
        return model.replace(fit_info=dict(model.fit_info, gains=gains))

    def linear_entries(self) -> dict[int, tuple[str, int]]:
        return self.base.linear_entries()


def refined_gains(cand: Candidate, data: FitData, options: Options) -> tuple[np.ndarray, float] | None:
    """(gains, BIC): the gains of the recordings relative to the first (1 for the first) that the candidate refined
    jointly with them finds on `data` (`WithGains`; output error with variable projection, each recording from its
    own start or its start group's, with its reference), from gains 1, and the refinement's N ln(RSS / N) + p ln N
    (p its parameters and the gains, on the samples it optimised); None where the refinement fails."""
    param = WithGains(cand.param, [r.name for r in data.norm])
    problem = _problem(data, True)
    theta0 = np.r_[cand.res.theta, np.zeros(len(param.gained))]
    try:
        res = refine(param, theta0, problem, options)
    except (DuhemError, ValueError, np.linalg.LinAlgError):
        return None
    gains = np.r_[1.0, np.exp(res.theta[cand.param.size :])]
    n = len(res.weighted)
    bic = n * np.log(max(res.rss, 1e-300) / n) + param.size * np.log(n)
    return (gains, float(bic)) if np.all(np.isfinite(gains)) and np.isfinite(bic) else None


def _least_bic_gains(cands: Sequence[Candidate], data: FitData, options: Options) -> np.ndarray | None:
    """The gains of the candidate whose refinement with them (`refined_gains`) has the lowest BIC: a flexible
    model's joint refinement can trade a gain for its own modes (three 155-sample runs of an rd1 device at gains
    1 / 0.577 / 0.740: an rd3 refined with them to 1 / 0.676 / 0.819, the rd1 to 1 / 0.576 / 0.739)."""
    refined = [g for g in (refined_gains(c, data, options) for c in cands) if g is not None]
    return min(refined, key=lambda gb: gb[1])[0] if refined else None


def in_frame(recordings: Sequence[Recording], gains: Sequence[float]) -> list[Recording]:
    """The recordings in the first one's frame: each output divided by its gain (module docstring)."""
    return [divided(r, g) for r, g in zip(recordings, gains)]


def _problem(data: FitData, references: bool) -> Recordings:
    """The output-error problem of the prepared recordings (normalised), each from its own fitted start or its
    start group's, with `references`."""
    return Recordings(data.norm, x0="fit", cycles=data.cycles, starts=data.starts, references=references)


def _apart(
    cand: Candidate, data: FitData, recordings: Sequence[Recording], options: Options, lowest: Candidate | None = None
) -> tuple[list[int] | None, np.ndarray | None, bool]:
    """(start groups, gains, whether `lowest` showed them) of `gains_apart` on `data`, or, where they are not apart
    there and several runs start alike each from its own start, under their start groups with references (module
    docstring, item 1: each run's own start can mimic its gain, the one state of runs that start alike cannot);
    where neither shows them, the search's `lowest` order refined with and without the gains (`_refined_apart`,
    under those start groups)."""
    gains = gains_apart(cand, data, recordings)
    starts, at = data.starts, data
    if gains is None and data.starts is None:
        groups = start_groups(data.recs)
        if len(set(groups)) < len(groups):
            starts, at = groups, replace(data, starts=groups, references=True)
            gains = gains_apart(cand, at, recordings)
            if gains is None and apart(cand, data, recordings):
                gains = _refined_apart(cand, at, options)
    if gains is None and lowest is not None and lowest is not cand and _several(data, recordings):
        gains = _refined_apart(lowest, replace(at, references=True), options)
        return starts, gains, gains is not None
    return starts, gains, False


def _several(data: FitData, recordings: Sequence[Recording]) -> bool:
    """Whether the recordings are several, of distinct names, each fitted from a fitted initial state (x0 "fit")."""
    names = [r.name for r in recordings]
    return data.x0_mode == "fit" and len(names) >= 2 and len(set(names)) == len(names)


def _refined_apart(cand: Candidate, data: FitData, options: Options) -> np.ndarray | None:
    """The gains where the candidate refined with them on `data` (`WithGains`) leaves below 1 / `SHARED_START_RSS`
    of the RSS it leaves refined without them, and less by more than BIC allows for the R - 1 gains; None where it
    does not (module docstring, item 1: a model fitted from each run's own start can be too far from one that fits
    the runs from their one start for a regression to show the gains: an ri4 of two noise-free runs of an rd4 device
    at gains 1 / 1.79 regressed to 1 / 1.08 under their one start)."""
    problem = _problem(data, True)
    try:
        plain = refine(cand.param, cand.res.theta, problem, options)
    except (DuhemError, ValueError, np.linalg.LinAlgError):
        return None
    refined = refined_gains(replace(cand, res=plain), data, options)
    if refined is None:
        return None
    gains = refined[0]
    param = WithGains(cand.param, [r.name for r in data.norm])
    with np.errstate(all="ignore"):
        without = problem.projected(cand.param, plain.theta)[0]
        gained = problem.projected(param, np.r_[plain.theta, np.log(gains[1:])])[0]
    n = len(gained)  # every sample, both (the refinements optimise on `options`' decimated ones)
    before, after = float(without @ without) + n * 1e-18, float(gained @ gained) + n * 1e-18
    bic = n * np.log(before / after) > (len(gains) - 1) * np.log(n)
    return gains if SHARED_START_RSS * after < before and bic else None


def raw_rss(cand: Candidate, data: FitData, gains: Sequence[float]) -> tuple[float, int]:
    """(RSS on the raw outputs, samples): each prepared recording's residual from its own start in the model's
    frame, times the normalisation's output scale and the recording's gain (module docstring, item 3)."""
    pairs = _own_residuals(cand, data)
    rss = sum(float(np.sum(((y - yhat) * data.scaling.y_s * g) ** 2)) for (y, yhat), g in zip(pairs, gains))
    return rss, sum(len(y) for y, _ in pairs)


def _bic(cand: Candidate, data: FitData, gains: Sequence[float]) -> float:
    """N ln(RSS_raw / N) + p ln N, p the candidate's parameters and the gains other than the first's."""
    rss, n = raw_rss(cand, data, gains)
    p = cand.param.size + sum(g != 1.0 for g in gains[1:]) + (len(gains) - 1) * bool(data.references)
    return float(n * np.log(max(rss, 1e-300) / n) + p * np.log(n))


def _kept(
    found: Candidate, scaled: FitData, gains: np.ndarray, first: Candidate, data: FitData, by_lowest: bool
) -> bool:
    """Whether the gained search's best candidate (`found` on `scaled`) is kept over the first search's (module
    docstring, item 3): for runs that start alike fitted under their start groups where the first search fitted
    each from its own start, its raw RSS within `SHARED_START_RSS` times the first's (the shared-start rule of
    `fitter.identification.fit`: the own starts have parameters BIC does not count, and mimic the gains); else
    the lower BIC on the raw outputs, the gains counted; for gains that only the lowest order showed (`by_lowest`),
    also its raw RSS below 1 / `SHARED_START_RSS` of the first's."""
    ones = np.ones(len(gains))
    rss, rss_first = raw_rss(found, scaled, gains)[0], raw_rss(first, data, ones)[0]
    if by_lowest and not SHARED_START_RSS * rss < rss_first:
        return False
    if scaled.starts is not None and data.starts is None:
        return rss <= SHARED_START_RSS * rss_first
    return _bic(found, scaled, gains) < _bic(first, data, ones)


def calibrated_search(
    data: FitData, cands, recordings: Sequence[Recording], search: Search, best: Best, options: Options, progress
) -> tuple[FitData, list[Candidate], list[Recording], np.ndarray | None]:
    """(data, candidates, recordings in the model's frame, gains or None): the search's, or, where the gains are
    apart (`gains_apart`), the last round's on the recordings rescaled by them, when its BIC on the raw outputs is
    lower (module docstring)."""
    first = best(cands, data, recordings)
    lowest = min(cands, key=lambda c: (c.param.n, c.param.kind != "ri"))
    starts, gains, by_lowest = _apart(first, data, recordings, options, lowest)
    if gains is None:
        return data, cands, list(recordings), None
    progress("the recordings' outputs have different gains: fitting each in the first one's scale", None)
    total = gains
    orders = tuple(range(1, first.param.n + 1))
    for _ in range(ROUNDS):
        frame = in_frame(recordings, total)
        scaled = replace(prepare_for_fit(frame, settled=False), references=True, starts=starts)
        found, used = search(scaled, orders), total
        step = _least_bic_gains(found, scaled, options)
        if step is None or np.max(np.abs(step - 1.0)) < GAIN_TOLERANCE:
            break
        total = total * step
    if _kept(best(found, scaled, frame), scaled, used, first, data, by_lowest):
        return scaled, found, frame, used
    return data, cands, list(recordings), None
