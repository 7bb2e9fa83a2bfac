"""A round of candidate tests (steps 3-4 of `fitter.diagnosis.procedure`): each effect fitted jointly on top of
the current model, tested, and the round ranked by BIC.

Each candidate is fitted with the base parameters (`fitter.diagnosis.fitting.fit_family`) and tested against the
model without it (`fitter.diagnosis.statistics`: likelihood ratio with an AR(1) effective sample size, Bonferroni
over the candidates, at least `MIN_EXPLAINED` of the residual energy removed), or, when that test cannot establish
it, confirmed on held-out recordings (`fitter.diagnosis.held_out.confirmed`) with its strengths determined
(`statistics.determined`).  A memory (creep, relaxation) must
follow the input (`statistics.memory_response_report`) and a reversing effect swing both ways
(`statistics.reversal_report`).  The round is sorted by

    BIC = N ln(RSS / N) + p ln N

over the fitted samples, p the effect's fitted values (`freedoms`).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from fitter.core.effects import REGISTRY
from fitter.diagnosis.experiment import JoinedExperiment
from fitter.diagnosis.fitting import Fit, fit_family, joint_refit
from fitter.diagnosis.held_out import confirmed, held_out_rss
from fitter.diagnosis.statistics import (
    MIN_EXPLAINED,
    determined,
    effect_report,
    is_significant,
    memory_response_report,
    reversal_report,
)
from fitter.workers import parallel_map
from fitter.identification.refine import effective_samples

__all__ = ["bic", "candidate_round", "freedoms"]


def bic(fit: Fit, n_parameters: int) -> float:
    """BIC = N ln(RSS / N) + k ln N over the fitted samples (the criterion `duhem fit` orders by)."""
    N = int(np.count_nonzero(fit.mask))
    return float(N * np.log(max(fit.rss, 1e-300) / N) + n_parameters * np.log(N))


def candidate_round(
    ex: JoinedExperiment,
    current: Fit,
    names: Sequence[str],
    mask: np.ndarray,
    alpha: float,
    n_candidates: int,
    tick: Callable[[str], None],
    found: Sequence[str] = (),
    starts: dict[str, Fit] | None = None,
) -> list[tuple[dict, Fit]]:
    """Fit and test each candidate on top of `current` (base + the effects `found`; the candidates' fits and
    held-out refits on several processes, `fitter.workers`); sorted by BIC (`bic`, the effect's
    parameters counted: `fitter.diagnosis.procedure`, step 4).  A candidate with a fit in `starts` (its
    first-round fit, where it was significant) is also refitted jointly with the found effects from there
    (`fitting.joint_refit`), and the better of the two fits is tested."""
    for name in names:
        tick(f"testing {name}")
    starts = starts or {}

    def one(name: str) -> tuple[dict, Fit]:
        return _candidate(ex, current, name, mask, alpha, n_candidates, found, starts.get(name))

    results = parallel_map(one, list(names))
    if any("held_out_rss" in rep for rep, _ in results):
        without = held_out_rss(ex, current, mask)
        ctx = ex.effect_context(float(np.mean(ex.y)))
        for rep, _ in results:
            if "held_out_rss" in rep:
                rep["held_out_rss_without"] = without.tolist()
                rep["confirmed_held_out"] = confirmed(np.array(rep["held_out_rss"]), without)
                rep["significant"] = rep["confirmed_held_out"] and determined(rep, REGISTRY[rep["effect"]].null(ctx))
    for rep, fit in results:
        name = rep["effect"]
        if rep["significant"] and REGISTRY[name].memory_taus(rep["parameters"]) is not None:
            rep["response"] = memory_response_report(fit, ex, name, rep["n_eff"], alpha, n_candidates)
            rep["significant"] = rep["response"]["follows_input"]
        if rep["significant"] and REGISTRY[name].reverses:
            rep["reversal"] = reversal_report(fit, ex, name)
            rep["significant"] = rep["reversal"]["reverses"]
    results.sort(key=lambda rf: bic(rf[1], freedoms(rf[0]["effect"], ex)))
    return results


def _candidate(
    ex: JoinedExperiment,
    current: Fit,
    name: str,
    mask: np.ndarray,
    alpha: float,
    n_candidates: int,
    found: Sequence[str] = (),
    start: Fit | None = None,
) -> tuple[dict, Fit]:
    """One candidate of `candidate_round`: its fit on top of `current` (and, with a `start` and effects
    `found`, the better of that and their joint refit) and report (significance by the likelihood ratio);
    with two or more recordings, one it cannot establish that explains at least `MIN_EXPLAINED` also gets
    its held-out squared errors (``held_out_rss``), for `candidate_round` to confirm against the model
    without it."""
    fit = fit_family(current.model, [name], current.theta[: current.family.n_base], ex, mask, ex.y - current.residual)
    if start is not None and found:
        joint = joint_refit(current, found, name, start, ex, mask)
        fit = joint if joint.rss < fit.rss else fit
    rep = effect_report(fit, current.rss, effective_samples(fit.residual), freedoms(name, ex))
    rep.update(effect=name, origin=REGISTRY[name].origin)
    rep["significant"] = is_significant(rep, alpha, n_candidates)
    if not rep["significant"] and rep["explained_fraction"] >= MIN_EXPLAINED and len(ex.recordings) > 1:
        rep["held_out_rss"] = held_out_rss(ex, fit, mask).tolist()
    return rep, fit


def freedoms(name: str, ex: JoinedExperiment) -> int:
    """The number of values an effect adds to the fit: its parameters fitted in its basic form (not those
    declared ``refinement``, held at their defaults: `fitter.diagnosis.fitting`) and, for separate recordings
    (each with its initial state fitted), the reference of each but the first (`EffectSpec.offset`; the
    first's is the base's, `fitter.identification.output_error.Recordings`)."""
    spec = REGISTRY[name]
    fitted = sum(not p.refinement for p in spec.parameters)
    return fitted + (len(ex.recordings) - 1 if ex.separate and spec.offset else 0)
