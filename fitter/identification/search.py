"""The order and kind search of `fitter.identification.fit.fit_recordings` (its module docstring, items 4-5): one
candidate per order and kind, refined from its starts with the convergence barrier, and the schedule that fits the
two kinds' chains of candidates side by side.

Each rate-independent candidate of order n starts from the one of order n - 1, and each rate-dependent one from
the rate-independent fit of its order and the rate-dependent one below it.  So the two chains are fitted in
rounds: round r fits the rate-independent candidate of the r-th order beside the rate-dependent one of the
(r-1)-th (`fitter.workers.side_by_side`), each on a core and both once one lane ends.  The candidates are those of
fitting them in turn (every fit is deterministic, whichever process runs it); on two cores the piezo search's
wall time falls from the sum of the two chains towards the longer one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial
from typing import Callable

import numpy as np

from fitter.data.noise import noise_or_zero
from fitter.identification.fit_data import FitData, FitError, RateLevels, averaged_loop
from fitter.identification.output_error import Recordings
from fitter.identification.parametrisation import RDCanonical, RICanonical
from fitter.identification.refine import Barrier, Options, RefineResult, refine, with_covariance
from fitter.identification.starts import generic_ri_starts, rd_starts, ri_starts
from fitter.progress import Progress, silent
from fitter.workers import parallel_map, side_by_side

__all__ = [
    "Candidate",
    "FIT_OPTIONS",
    "BARRIER_INSIDE",
    "MISFIT",
    "barrier_excesses",
    "misfit_ratio",
    "order_search",
    "refined_further",
]

MAX_NFEV = 60
RACE_NFEV = 3
RACE_NFEV_GENERIC = 10
RACE_KEEP = 1
"""The rate-independent starts' race (`_race`): `RACE_NFEV` evaluations per start read off the averaged loop (near
the optimum: Section III, the branch regression, the lower order embedded), `RACE_NFEV_GENERIC` per start of a
general input (`generic_ri_starts`: relaxation rates guessed blind, whose objectives after a few evaluations do
not rank them).  Measured on 17 random one-offset draws of the model class (tests/generality_draws.py, seeds 0-59
of `spec_from_seed`, at most 1500 samples): 3 evaluations let three fits stop in a local minimum of an order that
is not the truth's (2.5-3.9 x the bound, where 10 reach 0.0-1.75 x); on the piezo triangles (loop starts) 10
evaluations move the ri3 fit into another minimum, and the rd3 started from it into its worse one (1 Hz 7.1 %
against 2.8 %)."""
BARRIER_INSIDE = 1e-4
"""The barrier penalty starts this far inside each limit: a penalty of weight 1e3 lets the optimum overshoot
its zero by about gradient / 1e3 (1e-6 to 4e-6 measured on the piezo rate-dependent fits), and a fit beyond
a limit is not eligible (`fitter.identification.fit._meets_barrier`)."""
GLOBAL_STARTS = 4
GLOBAL_FROM_ORDER = 3
GLOBAL_SCALE = 0.5
"""Global stage of the rate-dependent fits of order >= `GLOBAL_FROM_ORDER`: `GLOBAL_STARTS` restarts from
the best local fit with its nonlinear entries (A's polynomial, the rate table) moved by GLOBAL_SCALE
max(|theta|, 1) times a seeded normal draw.  Measured on the three piezo rates: the local fits of order 3
and 4 end in minima of 1.2-3x the best cost, depending on the start and on the numerical stack; with the
rate-independent race at 10 evaluations the rd3 started from the ri3 fit ended at BIC -5779 (1 Hz 7.1 %), and
restarts at half this scale (eight of them too) stayed there, while these reach -5901 (2.8 %)."""
MISFIT = 2.0
"""A fit whose residual RMS exceeds this many times the output's white noise has not followed the data: the kept
candidate is refined further (`refined_further`), and the summary's ``misfit`` says so when it still does."""
HARDER_NFEV = 4 * MAX_NFEV
"""The evaluation budget of `refined_further`."""
FIT_OPTIONS = Options(ftol=1e-9, xtol=1e-10, max_nfev=MAX_NFEV, max_samples=3000, eliminate=True, compiled=True)
"""Evaluations on the compiled modal scan (`Options.compiled`, numba): on the three piezo rates the search took
23.4 s instead of 30.8 s on one process, and piezo.best's twelve draws at rounding level were all within issue 35's
bound against 9 of 12 on numpy's sums (median 28.6 s against 31.1 s)."""


@dataclass
class Candidate:
    """One order and kind of the search: its parametrisation, its best refinement, where it started."""

    param: RICanonical | RDCanonical
    res: RefineResult
    start_info: dict

    @property
    def bic(self) -> float:
        N = len(self.res.weighted)
        return float(N * np.log(self.res.rss / N) + self.param.size * np.log(N))

    def with_covariance(self, data: FitData, fit_options: Options) -> Candidate:
        """This candidate with its refinement's covariance (`fitter.identification.refine.with_covariance`): the
        search refines every start without it (`_candidate`), and only the candidate a fit keeps needs it."""
        return replace(self, res=with_covariance(self.res, self.param, _problem(data), fit_options))


def _problem(data: FitData) -> Recordings:
    """The output-error problem of every candidate: the prepared recordings, normalised, with the fit's x0 mode,
    start groups and references."""
    return Recordings(data.norm, x0=data.x0_mode, cycles=data.cycles, starts=data.starts, references=data.references)


def _barrier(param: RICanonical | RDCanonical, data: FitData) -> Barrier:
    """The search's `Barrier` on theta: `barrier_excesses` of the parametrisation's model over the data's input
    range, the penalty starting `BARRIER_INSIDE` before each limit; rate-independent, rho of condition (5) <= 0.99,
    the branch amplification over the fitted span <= 1e6 (`RICanonical.amplification`: a branch that expands a state
    error by 1e15 while the other contracts converges, but makes the model's output depend on rounding) and,
    with faithful minor loops, every settled minor loop within half an output range of the data
    (`RICanonical.minor_loop_extent`);
    rate-dependent, max Re eig(A) <= -1e-3 (normalised units; A is Hurwitz by construction, the barrier
    keeps a margin from 0) and every mode damped (`RDCanonical.damping_excess` <= 0: a nearly undamped
    oscillation fits the data by cancellation and blows up at rates it was not fitted on)."""
    lo, hi = data.input_range()

    def excesses(th: np.ndarray) -> list[float]:
        try:
            with np.errstate(all="ignore"):
                model = param.build(th) if np.all(np.isfinite(th)) else None
        except (ValueError, np.linalg.LinAlgError):
            model = None
        return barrier_excesses(param, model, lo, hi)

    return Barrier(excesses, BARRIER_INSIDE)


def barrier_excesses(
    param: RICanonical | RDCanonical, model, lo: float, hi: float, output: tuple[float, float] = (0.0, 1.0)
) -> list[float]:
    """`param.excesses(model, lo, hi, output)` (each <= 0 where met); inf where one cannot be evaluated (or `model`
    is None)."""
    try:
        with np.errstate(all="ignore"):
            vals = [np.inf] * param.barriers if model is None else param.excesses(model, lo, hi, output)
    except (ValueError, np.linalg.LinAlgError):
        vals = [np.inf] * param.barriers
    return [float(v) if np.isfinite(v) else np.inf for v in vals]


def _candidate(
    param,
    starts,
    data: FitData,
    info,
    progress: Progress,
    fit_options: Options = FIT_OPTIONS,
    race_nfev: int = RACE_NFEV,
) -> Candidate:
    """Best refinement over the starts, with the convergence barrier.

    Rate-independent, with several starts: each first gets `race_nfev` evaluations; the `RACE_KEEP` of lowest
    objective (output error plus barrier) are refined further, each with the rest of the `MAX_NFEV` budget (one
    by one, the best so far kept: a result holds residuals on every sample), and the lowest kept.
    Rate-dependent (at most two starts): each start is refined in full, on parallel processes, and the lowest
    objective kept; a race picked the start that ended worse (measured on the three piezo rates: rd3 from
    the rate-independent fit's branch raced ahead of the embedded rd2 and ended at BIC -5779 against
    -5901, 7.1 % NRMSE at 1 Hz against 2.8 %).  Rate-dependent candidates of order >= `GLOBAL_FROM_ORDER`
    then get the global stage (`_global_stage`).  No refinement computes its covariance, which only the
    candidate a fit keeps needs (`Candidate.with_covariance`: the same numbers, some p evaluations for each of the
    others saved; on piezo.best twenty of its 22 such Jacobians, about 2 s of one core's 55 s)."""
    problem = _problem(data)
    pen = _barrier(param, data)
    fit_options = replace(fit_options, covariance=False)

    def run(theta0, options):
        try:
            return refine(param, theta0, problem, options, penalty=pen, progress=progress)
        except (ValueError, np.linalg.LinAlgError):
            return None

    def objective(res: RefineResult) -> float:
        """What the refinement minimises: the output error's cost plus the barrier's."""
        return res.cost + 0.5 * float(np.sum(pen(res.theta) ** 2))

    race = param.kind == "ri" and len(starts) > 1
    if race:
        best = _race(starts, run, objective, fit_options, race_nfev)
    else:
        best = None
        for res in parallel_map(lambda th0: run(th0, fit_options), starts):
            if res is not None and (best is None or objective(res) < objective(best)):
                best = res
            del res
    if best is None:
        raise FitError(f"{param.kind} order {param.n}: every start failed to simulate")
    if param.kind == "rd" and param.n >= GLOBAL_FROM_ORDER:
        best = _global_stage(param, best, run, objective, fit_options)
    return Candidate(param, best, info)


def _race(
    starts: list[np.ndarray],
    run: Callable[[np.ndarray, Options], RefineResult | None],
    objective: Callable[[RefineResult], float],
    fit_options: Options,
    nfev: int = RACE_NFEV,
) -> RefineResult | None:
    """`_candidate`'s race: `nfev` evaluations from every start, the rest of the budget for the
    `RACE_KEEP` best of them, the lowest objective kept.  Only the parameters of the raced runs are kept between
    the two stages, and the finished run a continuation does not improve on is rerun for one evaluation (its
    count and its budget flag are the continuation's), so that at most two results are held at a time."""
    heats = []
    for th0 in starts:
        res = run(th0, replace(fit_options, max_nfev=nfev))
        if res is not None:
            heats.append((objective(res), res.theta))
        del res
    best = None
    for heat, theta in sorted(heats, key=lambda h: h[0])[:RACE_KEEP]:
        more = run(theta, replace(fit_options, max_nfev=MAX_NFEV - nfev))
        if more is None or objective(more) > heat:
            hit = more is not None and more.budget_hit
            del more
            more = run(theta, replace(fit_options, max_nfev=1))
            more = None if more is None else replace(more, budget_hit=hit)
        if more is not None and (best is None or objective(more) < objective(best)):
            best = more
        del more
    return best


def _global_stage(
    param: RDCanonical,
    best: RefineResult,
    run: Callable[[np.ndarray, Options], RefineResult | None],
    objective: Callable[[RefineResult], float],
    fit_options: Options = FIT_OPTIONS,
) -> RefineResult:
    """The lowest objective among `best` and `GLOBAL_STARTS` full refinements (`fit_options`) from perturbed
    copies of it (`GLOBAL_SCALE`; seeded by the order, so a fit is repeatable), run on parallel processes."""
    rng, theta = np.random.default_rng(param.n), best.theta
    moving = np.ones(param.size, bool)
    moving[list(param.linear_entries())] = False
    scale = GLOBAL_SCALE * np.maximum(np.abs(theta), 1.0)
    steps = [scale * rng.standard_normal(param.size) for _ in range(GLOBAL_STARTS)]
    for res in parallel_map(lambda step: run(theta + step * moving, fit_options), steps):
        if res is not None and objective(res) < objective(best):
            best = res
    return best


def order_search(
    data: FitData,
    kind: str,
    orders,
    q,
    levels: RateLevels,
    progress: Progress,
    faithful: bool = False,
    fit_options: Options = FIT_OPTIONS,
) -> list[Candidate]:
    """Candidates of the order and kind search (`fitter.identification.fit`'s module docstring, item 5): the
    rate-independent ones of `orders` upward (kind "rd": the first order alone, as a start; they stop when BIC
    rises where no rate-dependent one follows), then, where the rate-dependent kind is searched (kind "rd", or
    "auto" on two rate levels or more), the rate-dependent ones upward until BIC rises; `faithful`: the
    rate-independent candidates keep their settled minor loops near the data (`fit_recordings`).  Round r fits
    the r-th rate-independent order beside the (r-1)-th rate-dependent one (module docstring)."""
    loop = averaged_loop(data.loops) if data.loops is not None else None
    ri_fits: dict[int, Candidate] = {}
    rd_fits: dict[int, Candidate] = {}

    def ri(n: int, report: Progress) -> Candidate:
        lower = ri_fits.get(n - 1)
        lower_model = lower.res.model if lower else None
        if loop is not None:
            starts, info = ri_starts(*loop, n, q, lower_model)
        else:
            starts, info = generic_ri_starts(n, lower_model)
        nfev = RACE_NFEV if loop is not None else RACE_NFEV_GENERIC
        return _candidate(RICanonical(n, faithful), starts, data, info, report, fit_options, nfev)

    def rd(n: int, report: Progress) -> Candidate:
        param = RDCanonical(n, levels.v_ref, levels.knots)
        ri_fit, lower = ri_fits.get(n), rd_fits.get(n - 1)
        model, res = (ri_fit.res.model if ri_fit else None), (lower.res if lower else None)
        starts, info = rd_starts(param, model, res, data.norm, levels.triangle)
        return _candidate(param, starts, data, info, report, fit_options)

    ri_orders = list(orders if kind != "rd" else orders[:1])
    rd_orders = list(orders) if kind == "rd" or (kind == "auto" and levels.levels >= 2) else []
    for r in range(max(len(ri_orders), len(rd_orders) + 1)):
        n_ri = ri_orders[r] if r < len(ri_orders) else None
        n_rd = rd_orders[r - 1] if 1 <= r <= len(rd_orders) else None
        if n_ri is not None and n_rd is not None:
            progress(f"rate-independent model, order {n_ri}, beside rate-dependent model, order {n_rd}", None)
            ri_fits[n_ri], rd_fits[n_rd] = side_by_side(partial(ri, n_ri, silent), partial(rd, n_rd, progress))
        elif n_ri is not None:
            progress(f"rate-independent model, order {n_ri}", None)
            ri_fits[n_ri] = ri(n_ri, progress)
        elif n_rd is not None:
            progress(f"rate-dependent model, order {n_rd}", None)
            rd_fits[n_rd] = rd(n_rd, progress)
        if n_ri in ri_fits and n_ri - 1 in ri_fits and ri_fits[n_ri].bic > ri_fits[n_ri - 1].bic:
            if kind == "ri" or levels.levels < 2:
                del ri_orders[r + 1 :]
        if n_rd in rd_fits and n_rd - 1 in rd_fits and rd_fits[n_rd].bic > rd_fits[n_rd - 1].bic:
            del rd_orders[r:]
    return (list(ri_fits.values()) if kind in ("auto", "ri") else []) + list(rd_fits.values())


def misfit_ratio(cand: Candidate, data: FitData) -> float:
    """The candidate's residual RMS over its fitted samples, sqrt(RSS / N), in times the output's white noise
    (`fitter.data.noise.noise_rms` of the prepared outputs, the median; at least 1e-6 of their range, so that
    noise-free data are not asked for rounding)."""
    outputs = [r.y for r in data.norm]
    floor = 1e-6 * max(float(np.ptp(np.concatenate(outputs))), 1e-300)
    noise = max(float(np.median([noise_or_zero(y) for y in outputs])), floor)
    return float(np.sqrt(cand.res.rss / max(len(cand.res.weighted), 1))) / noise


def refined_further(
    cand: Candidate, data: FitData, progress: Progress, fit_options: Options = FIT_OPTIONS
) -> Candidate:
    """The candidate refined on from its end with `HARDER_NFEV` evaluations (with the barrier), for a fit that
    leaves more than `MISFIT` times the noise: a budget hit, not the model class, is the first suspect."""
    more = _candidate(
        cand.param, [cand.res.theta], data, dict(cand.start_info), progress, replace(fit_options, max_nfev=HARDER_NFEV)
    )
    more.start_info["refined_further"] = HARDER_NFEV
    return more
