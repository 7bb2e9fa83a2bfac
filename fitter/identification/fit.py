"""Fit semilinear Duhem models to real recordings (noisy, transient, any periodic input, several rates).

Pipeline of `fit_recordings`
----------------------------
1. **Preparation** (`fitter.identification.fit_data`): reversals, settled
   cycles, holds, drift, the input made monotone between reversals,
   normalisation, the averaged loop and the input's rate levels.
2. **Parametrisation** (`fitter.identification.parametrisation`): the
   canonical forms `RICanonical` (eqs 1-2) and `RDCanonical` (eqs 18-19, g
   tabulated, g(v_ref) = v_ref), fitted in normalised units and mapped back
   exactly (`Physical`).
3. **Starts** (`fitter.identification.starts`): the loop methods of the
   paper (Section III, Section V) and simple branch regressions.
4. **Output-error refinement** (`fitter.identification.refine.refine`).
   Initial state ``x0="fit"`` (recordings with several cycles, and general
   inputs): every sample is fitted and the state at each recording's first
   sample is eliminated by linear least squares, so a start-up transient is
   the initial state's to explain, not mistaken for the loop.  When every
   recording holds a single cycle (e.g. the piezo files), a free initial state would let a barely convergent model
   mimic a non-closing loop, so ``x0="periodic"`` is used instead: the cycle
   is taken as settled.  Unless a recording does not close (a staircase from
   rest, a creep trapezoid) and the settled fit leaves more than `MISFIT`
   times the noise: the search is then run with the initial state fitted
   too, and the mode whose best candidate has the lower BIC on every raw
   sample (each recording from its own fitted start, `raw_bic`) is kept.
   Several recordings fitted each from its own initial state, of which some
   start at one input level (`start_groups`), are stored with one x0 for
   those when it suits them (`fitter.identification.exported`).  Where the
   stored x0 leaves more than `SHARED_START_RSS` times the RSS of their own
   starts (`apart`), the search is run again with one initial state per
   start group (orders up to the first search's choice), and kept if its RSS is within that factor of the first
   search's from the own starts (the runs do start from one state; else they
   were made after other histories, and the first search is kept).
   Several recordings fitted each from its own initial state whose outputs have different zeros (separate runs,
   an instrument zeroed anew for each: `zeros_apart`, a constant fitted per recording lowers the best candidate's
   RSS by more than BIC allows) are searched again with an output reference per recording but the first,
   fitted with its initial state (`Recordings`' ``references``), and that search is kept where its BIC, the
   references counted, is lower; for runs that start alike the same test under their one start decides whether
   their shared-start search has references.  The references are a property of the files, not of the device: the
   model is the first recording's (its reference is the model's own); the others' are in the summary's
   ``references`` and the model's ``fit_info``, and every score of a recording adds its reference to the model's output
   (`exported.file_reference`).  Several recordings whose outputs have different gains (an instrument calibrated
   anew, an operating condition that scales the output) are searched again in the first one's frame, each divided
   by its gain, the gains refined jointly with the model (`fitter.identification.file_gains`), and kept where their
   BIC on the raw outputs is lower; the gains are in the summary's ``gains`` and the model's ``fit_info``, and every
   score applies them (`exported.calibrated`, `exported.levelled`).
   The convergence condition is enforced: for the rate-dependent model with g >= 0 the period map is e^{A sum g dt}, so
   rho < 1 iff A is Hurwitz, which the parametrisation guarantees; for the
   rate-independent model condition (5), rho(e^{beta A+} e^{-beta A-}) < 1, is
   required of every minor loop of the stored input range (sub-span b: radius
   raised to beta / b, `fitter.core.periodic.minor_loop_rho`), so that the
   saved model also converges on inputs other than the fitted one, and kept by
   a barrier residual 1e3 max(0, rho - 0.99 + `BARRIER_INSIDE`) added to the
   objective (it starts just inside the limit, so that the fit ends inside
   it).  The linear parameters (B, E, D, x0) are eliminated by least squares
   at every evaluation (variable projection).  Rate-independent starts race:
   each gets `RACE_NFEV` evaluations (`RACE_NFEV_GENERIC` for the generic
   starts of a general input), the `RACE_KEEP` best continue to `MAX_NFEV`
   in all; rate-dependent starts are each refined in full.
   Rate-dependent fits of order >= 3 add a global stage: seeded perturbed
   restarts of the best fit (`_global_stage`), since they have local minima.
   Evaluations run on the compiled modal scan (`FIT_OPTIONS`, `COMPILED_MAX_SAMPLES`).  Items 3-5 are
   `fitter.identification.search`, which fits the two kinds' candidates side by side.
5. **Selection**: orders n = 1, ..., 4 (`ORDERS`) are fitted upward, each
   started from the order n-1 fit and the other starts; for ``kind="auto"`` RI vs RD, and
   the order, by BIC = N ln(RSS/N) + p ln N on the stacked residuals (the
   order search stops when BIC rises, for the rate-independent models too when no
   rate-dependent one follows; ``kind="rd"`` fits only the order-1 RI
   model, as a start).  ``kind="auto"`` tries rate-dependent models only when
   the recordings have at least two rate levels; beyond `COMPILED_MAX_SAMPLES`
   samples in all, only levels of the recordings' own rates count, not those
   of one recording's legs (a rate-dependent search there is approximate on
   the decimated samples, and a random drive of 1e6 samples took it from 34 s
   and 355 MB to 156 s and 1.1 GB for the same ri2 model).  All candidates are listed
   in the summary.
6. **Effects** (``effects``, `fitter.identification.effects_fit`): the best
   rate-independent and the best rate-dependent candidate (lowest BIC within
   the barrier) are each screened with the named effects of the catalogue on
   the raw recordings (`effects_fit.screen_effects`); the screened starts of
   lowest BIC on every sample (the effects' parameters counted) among both
   race (`effects_fit.race_effects`), the raced one of lower BIC is refined on
   to convergence and kept, and the summary's ``effects`` lists both kinds.  The effect chain of a recording
   that is a closed loop starts settled on it, and the model stores the
   first recording's (`fitter.identification.effects_fit`).

The summary (scores per recording, convergence, minor loops, why) is built by
`fitter.identification.fit_summary`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from fitter.core.errors import KernelError
from fitter.core.files import jsonable
from fitter.core.kernel import simulate
from fitter.core.periodic import fixed_point
from fitter.data.cycles import closed_loop
from fitter.data.preparation import prepare
from fitter.data.recordings import Recording, check_scale
from fitter.identification.fit_data import (
    FitData,
    FitError,
    RateLevels,
    monotone_input,
    prepare_for_fit,
    rate_levels,
    start_groups,
)
from fitter.identification.effects_fit import check_effects, check_held, effects_bic, race_effects, screen_effects
from fitter.identification.exported import (
    NRMSE_CONVENTION,
    X0_POLICIES,
    fitted_range,
    SHARED_START_RSS,
    calibrated,
    raw_input_rho,
)
from fitter.identification import fit_summary
from fitter.identification.file_gains import calibrated_search
from fitter.identification.refine import Barrier, Options, RefineResult, jacobian
from fitter.identification.run_starts import (
    alike,
    apart,
    base_model,
    raw_bic,
    referenced,
    start_rss,
    stored_with,
    zeros_apart,
)
from fitter.identification.parametrisation import Parametrisation, Physical, RDCanonical, RICanonical, WithEffects
from fitter.identification.search import (
    BARRIER_INSIDE,
    FIT_OPTIONS,
    MISFIT,
    Candidate,
    barrier_excesses,
    misfit_ratio,
    order_search,
    refined_further,
)
from fitter.identification.starts import Q_CANDIDATES
from fitter.progress import Progress, silent
from fitter.workers import one_blas_thread

__all__ = ["FitError", "FitResult", "fit_recordings", "monotone_input", "ORDERS"]

ORDERS = (1, 2, 3, 4)
COMPILED_MAX_SAMPLES = 200_000
"""Longer recordings (all of them together) are fitted on numpy's sums: numba's import adds about 115 MB resident,
and the 1e6-sample fit of `bench/long_recordings.py` peaked at 439 MB with it against 338 MB without (target 400)."""

X0_TEXT = {
    "fit": "during the fit, every sample is fitted and the state at each recording's first sample is "
    "fitted (linear least squares)",
    "periodic": "every recording holds a single cycle, so transient and loop cannot be told apart: "
    "each is taken as settled and starts from the fixed point of its one-cycle map",
}


# ---------------------------------------------------------------------- results
@dataclass
class FitResult:
    """A fitted model (physical units) and its JSON-able summary.

    `simulate(rec)` is the saved model on the samples of `rec` from its stored
    x0 (the one definition of the model's output: what the summary's NRMSE,
    the report and `duhem validate` use); `band(rec)` its uncertainty band.
    `predict(rec)` is a prediction independent of the initial state: the model
    started from the periodic state of the first settled cycle of `rec` (NaN
    before it, the dropped transient).
    """

    model: object
    summary: dict
    theta: np.ndarray
    cov: np.ndarray
    param: Parametrisation

    def build(self, theta: np.ndarray):
        """The saved model with parameters `theta` (its x0 kept; its effects kept unless theta holds them)."""
        model = self.param.build(theta)
        return model.replace(x0=self.model.x0, effects=model.effects or self.model.effects)

    def simulate(self, rec: Recording) -> np.ndarray:
        """The saved model's output on every sample of `rec`, from its stored x0, plus the output reference the
        fit found for a recording of its name, times its gain (`exported.calibrated`; none for any other)."""
        return calibrated(self.model, rec, simulate(self.model, rec.t, rec.u).y)

    def predict(self, rec: Recording) -> np.ndarray:
        """Output from the periodic state of the first settled cycle of `rec` (NaN before it), plus the file's
        output reference and gain as in `simulate`."""
        prep = prepare(rec, min_cycles=0)
        s0, s1 = prep.first_cycle()
        a = prep.transient_end + s0
        x0, _ = fixed_point(self.model, rec.t[a : prep.transient_end + s1 + 1], rec.u[a : prep.transient_end + s1 + 1])
        y = np.full(len(rec.u), np.nan)
        y[a:] = simulate(self.model, rec.t[a:], rec.u[a:], x0=self.model.x0 if x0 is None else x0).y
        return calibrated(self.model, rec, y)

    def band(self, rec: Recording, level: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
        """`simulate(rec)` -+ level * sd, sd^2 = diag(J cov J^T) (linearised, J by differences)."""
        y0 = self.simulate(rec)
        J = jacobian(lambda th: simulate(self.build(th), rec.t, rec.u).y, self.theta, y0)
        sd = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", J, self.cov, J), 0, None))
        return y0 - level * sd, y0 + level * sd


def fit_recordings(
    recordings: Sequence[Recording],
    *,
    kind: str = "auto",
    order: int | None = None,
    q: float | None = None,
    x0: str = "fitted",
    faithful_minor_loops: bool = False,
    effects: Sequence[str] = (),
    held: dict[str, float] | None = None,
    progress: Progress = silent,
    max_samples: int | None = None,
    retry_unsettled: bool = True,
    references: bool = True,
) -> FitResult:
    """Fit a semilinear Duhem model to one or more recordings (see the module docstring).

    Parameters
    ----------
    recordings : periodic experiments (one per rate, say) with the same columns.
    kind : "ri" (rate-independent, eqs 1-2), "rd" (rate-dependent, eqs 18-19) or "auto" (BIC).
    order : state dimension n; default chosen by BIC among 1, 2, 3.
    q : bound of the Section III constrained least squares; default chosen by loop error.
    x0 : the stored initial state, "fitted" or "periodic" (`fitter.identification.exported`).
    faithful_minor_loops : a further barrier on the rate-independent candidates: the turning points of the
        settled minor loops (8 sub-spans at 5 places each, `RICanonical.minor_loop_extent`) within half an
        output range of the recorded output over the stored input range, so that the model stays near the
        data on loops smaller than the recorded ones (the summary's ``minor_loops``; a semilinear model's
        small loops settle on a centre line affine in u).  It costs accuracy on the recorded loops where they
        switch sharply (piezo triangles, measured in the README); rate-dependent candidates are unchanged.
        With `effects` the barrier stays on during their joint refinement, on the base's minor loops (effects
        left out; a bounded additive effect such as switching can then carry the sharp switching).
    effects : names of catalogue effects (`fitter.core.effects.REGISTRY`) fitted jointly with the base (module
        docstring, item 6); needs x0 "fitted".
    held : effect parameters held at known values, ``{"effect.parameter": value}``
        (`fitter.identification.effects_fit.check_held`), not fitted and not counted.
    progress : `fitter.progress.Progress` callback, called with one-line status messages.
    max_samples : the samples each recording's output error is optimised on in the order and kind search
        (decimated beyond, every input reversal kept: `fitter.identification.output_error`); default
        `FIT_OPTIONS`'s.  `duhem diagnose` passes its own budget (`fitter.diagnosis.fitting.SAMPLES`).
    retry_unsettled : refit single cycles that do not close with their initial state free when the settled fit
        leaves over `MISFIT` times the noise, and runs that start alike from one initial state when the one stored
        x0 does not suit them (module docstring, item 4; with `references`, the latter is done where their zeros
        differ).  `duhem diagnose` turns it off for its base: what keeps a cycle from closing (a drift, creep) is
        for its effects to name, not for the base's start.

    Returns
    -------
    FitResult with `.model` (physical units, signals and experiment filled in) and `.summary`.
    """
    if kind not in ("auto", "ri", "rd"):
        raise ValueError(f"kind must be 'auto', 'ri' or 'rd', not {kind!r}")
    if order is not None and order not in ORDERS:
        raise ValueError(f"order must be one of {ORDERS}, not {order!r}")
    if x0 not in X0_POLICIES:
        raise ValueError(f"x0 must be one of {X0_POLICIES}, not {x0!r}")
    effects = check_effects(effects)
    held = check_held(held, effects)
    if effects and x0 != "fitted":
        raise ValueError("effects are fitted with x0 'fitted' (their initial state is fitted per recording)")
    check_scale(recordings)
    with one_blas_thread():  # small matrices: one thread, the same rounding every run
        data = prepare_for_fit(recordings)
        long = sum(len(r.t) for r in recordings) > COMPILED_MAX_SAMPLES
        levels = rate_levels(data.norm, legs=not long)  # module docstring, item 5
        orders = ORDERS if order is None else (order,)
        options = replace(
            FIT_OPTIONS, compiled=not long, max_samples=FIT_OPTIONS.max_samples if max_samples is None else max_samples
        )

        def search(d: FitData, ords: tuple[int, ...] = orders) -> list[Candidate]:
            return order_search(d, kind, ords, q, levels, progress, faithful_minor_loops, options)

        data, cands = _closed_or_free(data, search(data), recordings, search, progress, retry_unsettled)
        frame, gains = list(recordings), None  # the recordings in the model's frame (`file_gains`)
        if references:
            data, cands = _levelled(data, cands, frame, search, progress)
        if retry_unsettled or references:
            data, cands = _shared(data, cands, frame, search, progress, orders, references, retry_unsettled)
        if references:
            data, cands, frame, gains = calibrated_search(data, cands, frame, search, _best, options, progress)
        eligible = [c for c in cands if _meets_barrier(c, data, frame)] or cands
        best = _harder_if_misfit(min(eligible, key=lambda c: c.bic), data, frame, progress, options)
        cands = [best if c.param is best.param else c for c in cands]
        eligible = [best if c.param is best.param else c for c in eligible]
        extended = _with_effects(eligible, data, frame, effects, held, progress) if effects else None
        result = _result(best, cands, data, frame, kind, q, levels, x0, options, extended)
        return result if gains is None else _with_gains(result, gains, recordings)


def _with_gains(result: FitResult, gains: np.ndarray, recordings) -> FitResult:
    """`result`, fitted on the recordings in the first one's frame (`file_gains`), with the recordings' gains and
    their references in the recordings' own units (the frame's times the gain) in its model's ``fit_info`` and
    its summary (``gains``, ``references``)."""
    g = {r.name: float(k) for r, k in zip(recordings[1:], gains[1:])}
    refs = {k: v * g[k] for k, v in (result.model.fit_info.get("references") or {}).items()}
    model = result.model.replace(fit_info=dict(result.model.fit_info, gains=g, references=refs))
    summary = dict(result.summary, references=fit_summary.references(model, recordings))
    summary["gains"] = fit_summary.gains(model, recordings)
    return replace(result, model=model, summary=jsonable(summary))


Search = Callable[..., list[Candidate]]
"""`order_search` with the fit's options: (prepared data, orders) -> candidates."""


def _closed_or_free(data: FitData, cands, recordings, search: Search, progress: Progress, retry: bool):
    """(data, candidates) of the search, or, when single cycles do not close (`_unsettled`, with `retry`), of the
    search with their initial states fitted where its best candidate has the lower BIC on every raw sample
    (`raw_bic`; module docstring, item 4)."""
    if not (retry and _unsettled(cands, data, recordings)):
        return data, cands
    progress("the recordings do not close: fitting their initial states instead", None)
    free = prepare_for_fit(recordings, settled=False)
    others = search(free)
    if raw_bic(_best(others, free, recordings), free, recordings) < raw_bic(
        _best(cands, data, recordings), data, recordings
    ):
        return free, others
    return data, cands


def _levelled(data: FitData, cands, recordings, search: Search, progress: Progress):
    """(data, candidates), or, where the recordings' outputs have different zeros from their own starts
    (`zeros_apart`), those of the search with an output reference per recording when its BIC, the references
    counted, is lower (module docstring, item 4)."""
    if not zeros_apart(_best(cands, data, recordings), data, recordings):
        return data, cands
    progress("the recordings' outputs have different zeros: fitting a reference per recording", None)
    levelled = replace(data, references=True)
    others = search(levelled)
    extra = (len(recordings) - 1) * np.log(len(_best(others, levelled, recordings).res.weighted))
    if _best(others, levelled, recordings).bic + extra < _best(cands, data, recordings).bic:
        return levelled, others
    return data, cands


def _shared(
    data: FitData, cands, recordings, search: Search, progress: Progress, orders, references: bool, retry: bool
):
    """(data, candidates), or, where the one x0 stored for runs that start alike does not suit them (`apart`),
    those of the search with one initial state per start group (orders up to the first's choice; with an output
    reference per recording where their zeros differ under the groups, `zeros_apart`) when it fits them within
    `SHARED_START_RSS` times the first search's RSS from their own starts (module docstring, item 4).  Without
    `retry` (`fit_recordings`' ``retry_unsettled``) only where the zeros differ."""
    first = _best(cands, data, recordings) if alike(data, recordings) else None
    if first is None or not apart(first, data, recordings):
        return data, cands
    groups = start_groups(data.recs)
    levelled = references and zeros_apart(first, data, recordings, groups)
    if not (retry or levelled):
        return data, cands
    progress("one stored initial state does not suit the recordings that start alike: fitting them so", None)
    shared = replace(data, starts=groups, references=data.references or levelled)
    others = search(shared, tuple(n for n in orders if n <= first.param.n))  # runs that share a state: no more
    joint, _ = start_rss(_best(others, shared, recordings), shared, recordings)
    if joint <= SHARED_START_RSS * start_rss(first, data, recordings)[1]:
        return shared, others
    return data, cands


def _best(cands: Sequence[Candidate], data: FitData, recordings) -> Candidate:
    """The candidate of lowest BIC among those inside the barrier (all, when none is)."""
    return min([c for c in cands if _meets_barrier(c, data, recordings)] or cands, key=lambda c: c.bic)


def _unsettled(cands: Sequence[Candidate], data: FitData, recordings) -> bool:
    """Whether the recordings were taken as settled cycles (``x0_mode`` "periodic") though one of them does not
    close (`fitter.data.cycles.closed_loop`: a staircase from rest, a creep trapezoid) and the best candidate
    leaves more than `MISFIT` times the noise: its initial state is then fitted too (`fit_recordings`)."""
    if data.x0_mode != "periodic" or all(closed_loop(r) for r in recordings):
        return False
    return misfit_ratio(_best(cands, data, recordings), data) > MISFIT


def _harder_if_misfit(best: Candidate, data: FitData, recordings, progress: Progress, options: Options) -> Candidate:
    """`best`, or, when it leaves more than `MISFIT` times the noise (`misfit_ratio`) where its refinement stopped
    at its evaluation budget, its further refinement (`refined_further`) if that lowers its BIC and stays inside
    the barrier (a refinement that met its tolerances gains nothing from a larger budget)."""
    ratio = misfit_ratio(best, data)
    if ratio <= MISFIT or not best.res.budget_hit:
        return best
    progress(f"the {best.param.kind}{best.param.n} fit leaves {ratio:.1f} times the noise: refining it further", None)
    more = refined_further(best, data, progress, options)
    return more if more.bic < best.bic and _meets_barrier(more, data, recordings) else best


@dataclass
class _Extended:
    """The base candidate and its joint refinement with the effects (`effects_fit.fit_effects`)."""

    candidate: Candidate
    model: object
    res: RefineResult
    param: WithEffects
    tried: list


def _with_effects(
    eligible: Sequence[Candidate],
    data: FitData,
    recordings,
    effects: Sequence[str],
    held: dict[str, float],
    progress: Progress,
) -> _Extended:
    """Module docstring, item 6: the best candidate of each kind extended by `effects` and screened
    (`effects_fit.screen_effects`); the screened starts of lowest BIC N ln(RSS/N) + p ln N on every raw
    sample (p: the base's and the effects' parameters) among both kinds race (`effects_fit.race_effects`),
    and the raced base of lowest BIC is finished (`RacedEffects.finish`) and kept; ``tried`` gives every
    kind's BIC, the others' at the end of their race or, when none of their starts raced, of their best
    screened start (``raced`` false)."""
    cands, screened = [], []
    for kind in ("ri", "rd"):
        of_kind = [c for c in eligible if c.param.kind == kind]
        if not of_kind:
            continue
        cand = min(of_kind, key=lambda c: c.bic)
        progress(f"{kind}{cand.param.n} with {', '.join(effects)}", None)
        base = base_model(cand, data, recordings)
        barrier = _physical_barrier(cand.param, data, recordings)
        cands.append(cand)
        screened.append(screen_effects(base, recordings, effects, barrier, progress, held, data.references))
    sizes = [c.param.size for c in cands]
    raced = race_effects(screened, lambda i, res: effects_bic(sizes[i], res, screened[i].fam), progress)
    chosen = min(
        (i for i, r in enumerate(raced) if r is not None),
        key=lambda i: effects_bic(sizes[i], raced[i].best, raced[i].fam),
    )
    model, res, fam = raced[chosen].finish(progress)
    tried = []
    for i, (cand, scr, race) in enumerate(zip(cands, screened, raced)):
        res_i, fam_i = (res, fam) if i == chosen else (race.best, race.fam) if race else (scr.screened[0], scr.fam)
        tried.append(fit_summary.tried_entry(cand, res_i, fam_i, raced=race is not None, finished=i == chosen))
    return _Extended(cands[chosen], model, res, fam, tried)


def _physical_barrier(param: RICanonical | RDCanonical, data: FitData, recordings) -> Barrier:
    """The search's barrier (`fitter.identification.search.barrier_excesses`, `BARRIER_INSIDE`) on a model in
    physical units over the recordings' input range (condition (5), the branch amplification and the damping are
    invariant under the normalisation of `scaling`; the settled minor loops of faithful minor loops are put on its
    output scale).  They depend on the base alone (its effects left out), so they are computed once per base: the
    effects' columns of a finite-difference Jacobian reuse them."""
    lo, hi = fit_summary.raw_range(recordings)
    output = (data.scaling.y_c, data.scaling.y_s)
    cache: dict[bytes, list[float]] = {}

    def excesses(model) -> list[float]:
        key = b"".join(np.asarray(getattr(model, k), dtype=float).tobytes() for k in model.PARAMS if k != "x0")
        if key not in cache:
            cache.clear()
            cache[key] = barrier_excesses(param, model, lo, hi, output)
        return cache[key]

    return Barrier(excesses, BARRIER_INSIDE)


def _meets_barrier(cand: Candidate, data: FitData, recordings) -> bool:
    """Whether the candidate ends inside the search's barrier (`fitter.identification.search._barrier`; every
    excess <= 0, 1e-9 slack) and converges on every raw input (`exported.raw_input_rho` < 1, the export's check):
    the barrier is a penalty, so a fit can end beyond it; such a candidate is chosen only when none meets it (a
    branch that amplifies state errors by more than the bound turns rounding into visible output differences
    between the kernel and an FMU; a model that fails the raw-input check is not exported)."""
    with np.errstate(all="ignore"):
        try:
            model = cand.param.build(cand.res.theta)
            if not all(e <= 1e-9 for e in cand.param.excesses(model, *data.input_range())):
                return False
            return all(r is None or r < 1 for r in raw_input_rho(base_model(cand, data, recordings), recordings))
        except (ValueError, np.linalg.LinAlgError, KernelError):
            return False


def _result(
    best: Candidate,
    cands,
    data: FitData,
    recordings,
    kind,
    q,
    levels: RateLevels,
    x0_policy: str,
    fit_options: Options,
    extended: _Extended | None = None,
) -> FitResult:
    """The fit's result from the kept candidate (`best`, or the base of `extended`), its covariance computed now
    (`Candidate.with_covariance`, with the search's `fit_options`)."""
    if extended is not None:
        best = extended.candidate
    param, res = best.param, best.with_covariance(data, fit_options).res
    physical = Physical(param, data.scaling)
    stderr = res.stderr()
    r0 = recordings[0]
    if extended is None:
        model = stored_with(base_model(best, data, recordings), data, recordings, x0_policy)
    else:
        model = referenced(extended.model, data, recordings)
    scores = fit_summary.per_recording(model, None if extended else res, data, recordings)
    bad = next((m["recording"] for m in scores if not np.isfinite(m["nrmse"])), None)
    if bad is not None:
        raise FitError(
            f"{bad}: the fitted model gives a non-finite output on its own recording (raw input, stored "
            "x0), so it is not saved; check the recording's scale and units"
        )
    summary = {
        "kind": param.kind,
        "order": param.n,
        "q": q if q is not None else next((c.start_info["q"] for c in cands if "q" in c.start_info), None),
        "q_why": "given"
        if q is not None
        else "lowest loop error of the Section III estimate among "
        f"{list(Q_CANDIDATES)} (a start for the output-error refinement only)",
        "why": fit_summary.why(
            best, cands, kind, levels.levels, [c for c in cands if not _meets_barrier(c, data, recordings)]
        ),
        "candidates": [
            {
                "kind": c.param.kind,
                "order": c.param.n,
                "parameters": c.param.size,
                "rss_normalised": c.res.rss,
                "bic": c.bic,
                "start": c.start_info.get("start"),
            }
            for c in cands
        ],
        "recordings": scores,
        "nrmse_convention": NRMSE_CONVENTION,
        "parameters_normalised": {
            k: {"value": v, "stderr": e} for k, v, e in zip(param.names(), res.theta.tolist(), stderr.tolist())
        },
        "normalisation": vars(data.scaling),
        "convergence": fit_summary.convergence(best, data, model, recordings, scores, extended is not None),
        "fitted_range": fitted_range(recordings),
        "input_deadband": data.deadband,
        "rate_levels": levels.levels,
        "triangle_inputs": levels.triangle,
        "v_ref": levels.v_ref * data.scaling.u_s if param.kind == "rd" else None,
        "x0": {
            "policy": x0_policy,
            "stored": model.x0.tolist(),
            "recording": r0.name,
            "u0": float(r0.u[0]),
            "fit": X0_TEXT[data.x0_mode],
        },
        "optimiser": fit_summary.optimiser(res),
        "misfit": fit_summary.misfit(scores, MISFIT, "refined_further" in best.start_info, bool(res.budget_hit)),
        "preparation": [dict(p.to_dict(), notes=n) for p, n in zip(data.preps, data.notes)],
    }
    if extended is not None:
        summary["effects"] = fit_summary.effects_summary(extended, recordings)
        names = ", ".join(e["effect"] for e in summary["effects"]["fitted"])
        summary["why"] += (
            f"; extended by {names} on the {summary['effects']['base']} base (the lower BIC with "
            f"the effects, {summary['effects']['bic']:.1f})"
        )
    summary["references"] = fit_summary.references(model, recordings)
    model = model.replace(
        fit_info=jsonable(
            {k: summary[k] for k in ("kind", "order", "why", "convergence", "fitted_range", "x0", "nrmse_convention")}
            | {"references": model.fit_info.get("references") or {}}
        )
    )
    summary["minor_loops"] = fit_summary.minor_loops(model, recordings, getattr(param, "faithful_minor_loops", False))
    model = model.replace(
        fit_info=dict(
            model.fit_info,
            minor_loops=jsonable({k: summary["minor_loops"][k] for k in ("excursion", "faithful", "constrained")}),
        )
    )
    if extended is not None:
        return FitResult(
            model=model,
            summary=jsonable(summary),
            theta=extended.res.theta,
            cov=extended.res.covariance(),
            param=extended.param,
        )
    return FitResult(model=model, summary=jsonable(summary), theta=res.theta, cov=res.covariance(), param=physical)
