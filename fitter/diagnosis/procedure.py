"""Diagnose a model-data mismatch: locate it, name the physics left out, model it.

One experiment is a list of recordings on one clock, simulated as one signal,
or separate runs, each simulated alone from its own fitted initial state
(``separate``; `fitter.diagnosis.experiment`).

Procedure (`diagnose`)
----------------------
1. Base model, made adequate before effects are added
   (`fitter.diagnosis.base.adequate_base`): the first-order base or the
   order `duhem fit` chooses, whichever accounts for the data without
   handing a missing order to the effects.  When the first-order base with
   its findings (steps 3-4) stays above `FAR_FROM_NOISE` times the noise,
   or above `NOISE_MARGIN` times it with a first finding that does not hold
   with one parameter set across the recordings and is not significant on
   the higher-order base (it stood in for the order), the search is run on
   the higher order too (`_higher_order_account`), and its account
   (refined, step 4) is taken when it predicts held-out recordings better
   (`fitter.diagnosis.held_out.prediction_error`: each recording predicted
   by the account refitted without it, the mean NRMSE; one recording: the
   lower BIC; scikit-learn's model selection), and, in the second case,
   reaches the noise.  The piezo triangles need the order `duhem fit`
   chooses, with switching: the first-order base with saturation stays
   hundreds of times the noise away.  Or a fixed order, or a given model.
2. Noise level sigma: the residual the true model would leave
   (`fitter.diagnosis.noise_floor.noise_floor`): the output's white noise
   (`fitter.data.metrics.noise_rms`, median over the recordings) and the
   input's, carried to the output by the first-order base (errors in
   variables; ``noise`` in the JSON says how it was estimated).  Locating (`fitter.diagnosis.locate.locate_mismatch`):
   residual RMS per recording, per branch, per input-range bin, its
   correlation across recordings with log rate, start time and amplitude, and
   a model-free comparison of a repeated run with its original.
3. Candidates (`fitter.core.effects.REGISTRY`): each is fitted jointly with the
   base parameters (`fitter.diagnosis.fitting.fit_family`: the output-error
   engine `fitter.identification.refine`, several starts for its nonlinear parameters) and tested
   against the model without it (`fitter.diagnosis.statistics`: likelihood
   ratio with an AR(1) effective sample size, Bonferroni over the candidates,
   at least `MIN_EXPLAINED` of the residual energy removed), or, when that
   test cannot establish it (a few long loops: an effective sample size of a
   dozen), confirmed on held-out data: with two or more recordings, each
   predicted better by the model with the effect fitted without it
   (`fitter.diagnosis.held_out.confirmed`; ``confirmed_held_out``), its strengths two standard errors from 0
   (`statistics.determined`: a parameter whose uncertainty is as large as its value makes no finding).  A creep or a
   relaxation spectrum must also follow the input
   (`statistics.memory_response_report`): its start transient alone is a
   change in time, a drift, not a memory of the material; one that fits only
   its start is not significant.  A reversing effect (switching domains,
   `EffectSpec.reverses`) must be driven both ways by the input, up from its lowest state and down from its
   highest (`statistics.reversal_report`): one that moves one way only is a drift.
4. The significant candidates are ranked by BIC, N ln(RSS / N) + p ln N over
   the fitted samples, p the effect's parameters, and for separate recordings
   the reference each but the first fits with its x0 (`EffectSpec.offset`;
   the likelihood ratio counts them too) (lowest first: between two
   effects that leave nearly the same residual, the one with fewer parameters;
   a flexible effect such as `relaxation`, six parameters, must remove more
   than its extra parameters' worth); the winner is added, and the remaining
   candidates are tested again on top of it (the findings held), a
   measurement effect that was significant in the first round also refitted
   jointly with the findings from its own first-round fit
   (`fitter.diagnosis.fitting.joint_refit`: on the creep trapezoids a
   relaxation spectrum found first had taken the integrated offset current,
   which a drift started at zero could not take back; a material candidate
   is not, since a joint refit of two material effects drew a Bouc-Wen loop
   with a start-up transient to the noise as creep and saturation),
   while the residual stays above `NOISE_MARGIN` times the noise (at most
   `max_findings`); none is added when the base residual is already within
   `NOISE_MARGIN` of the noise (they are still tested and listed: over many
   samples an effect can be "significant" while it fits noise).  The
   extended model is checked on data not used to fit it: refitted without
   the last recording (the repeat), it predicts that
   recording; the runner-up gets the same hold-out check, and the report says
   why the winner wins (residual, hold-out error, where the difference lies).
   Each finding is also refitted on every recording alone
   (`fitter.diagnosis.statistics.consistency_report`, its ``consistency``):
   when one parameter set does not hold across the recordings, the paragraph
   says that the data follow the effect only approximately (the nearest
   catalogue effect, not necessarily the physics).  Last, the findings,
   tested in their basic form, are refitted with their refinements
   (`_refined`: switching's threshold spreads and second population), taken
   when the BIC, counting the refinement parameters, is lower: the extended
   model is the refined one; the findings after a refined first one are kept
   only when the refined model with them predicts the held-out recordings
   better (`fitter.diagnosis.held_out.prediction_error`) than the first
   finding alone, refined from its own basic fit (on the piezo triangles'
   unlevelled ri3 base, rate_dependence, significant on top of switching's
   basic form, made the refined model's 1 Hz prediction worse: 8.9 %
   against 4.0 %).  A refined fit's held-out refits have its iteration
   budget (`fitter.diagnosis.fitting.REFINE_STEPS`).

Every finding carries its origin (`fitter.core.effects.EffectSpec.origin`):
the material's physics or the measuring chain (a sensor lag, a drift of the
measured output), or, for a partial finding (below) of an effect that only
changes the loop's shape (`EffectSpec.loop_shape`: saturation, backlash),
``loop_shape``: a hysteresis of another class than the base's (a Bouc-Wen or
a Preisach loop) draws such shapes too, and the data cannot tell the two
apart unless the extended model reaches the noise (on a Bouc-Wen loop the
order-2 Duhem base leaves 6.8 times the noise, saturation removes 77 % of it
and leaves 3.3 times, structured), so the material's saturation or play is
not claimed then.  A rate- or time-dependent finding (switching, relaxation,
viscous ...) cannot be drawn by any rate-independent base class, so it is
the material's even when partial.  ``extended`` lists them apart
(``material_effects``, ``measurement_effects``, ``loop_shape_effects``) and
the paragraph says which is which.

The remainder (``extended["remainder"]``, `_remainder`): is the residual the
extended model leaves the noise?  `statistics.remainder_report` tests it
for structure (the lag-1 autocorrelation over neighbouring samples, which
white noise keeps at 0 +- 1/sqrt(N)); it is *explained* when it is not
structured and its RMS is within `NOISE_MARGIN` of the noise.  It also says
where it is largest (recording, branch, input range).

The per-recording check (`fitter.diagnosis.file_gap`), before the search:
the base is refitted on each recording alone; their residual caps the noise
(a noise estimate above what a model per recording leaves was inflated); a
joint residual more than `GAP` times theirs is a finding (the recordings
differ by physics the model does not carry), never noise: the verdict is
then not "nothing_missing", unless a gain and an offset per file (an
instrument's calibration, an operating condition) take the joint residual to
the noise; and a remainder more than `GAP` times the per-recording fits' is
not explained.

The verdict: "effects_found" (findings, and the remainder explained),
"nothing_missing" (no finding and the base residual within `NOISE_MARGIN`
of the noise, or of `RESOLUTION` of the output range where the noise is
below it: a noise-free recording) or "unexplained": the residual is not explained, either with
no finding (above the noise, no candidate significant) or with findings
that leave a structured remainder or one above `NOISE_MARGIN` times the
noise.  Findings of an "unexplained" diagnosis are *partial* (``partial``
is true in each): the nearest effects of the catalogue, not necessarily the
physics; what is missing is another functional form, an effect outside the
catalogue, or a base model too simple, and the paragraph says so and where
the remainder lives.  The result is a `Diagnosis`; ``to_json()`` is the
stable ``--json`` output.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from fitter.core.effects import ORIGINS, REGISTRY, with_start
from fitter.data.metrics import nrmse, rms
from fitter.data.recordings import Recording
from fitter.diagnosis.base import adequate_base, below_order, check_explains
from fitter.diagnosis.calibration import calibrated_base
from fitter.diagnosis.experiment import DiagnoseError, JoinedExperiment, join_recordings
from fitter.diagnosis.file_gap import GAP, capped_noise, file_gap
from fitter.diagnosis.fitting import (
    Fit,
    duhem_fit,
    fit_base,
    fit_family,
    fit_per_recording,
    output_references,
    with_refinements,
)
from fitter.diagnosis.locate import locate_mismatch, where_differs
from fitter.diagnosis.result import Diagnosis
from fitter.diagnosis.held_out import held_out_nrmse, prediction_error
from fitter.diagnosis.statistics import ALPHA, NOISE_MARGIN, RESOLUTION, consistency_report, remainder_report
from fitter.diagnosis.rounds import bic, candidate_round
from fitter.diagnosis.text import comparison_text, summary_paragraph
from fitter.identification.exported import described, fitted_range
from fitter.identification.refine import effective_samples
from fitter.progress import Progress, silent

__all__ = ["CANDIDATES", "CLAIMS", "FAR_FROM_NOISE", "LOOP_SHAPE", "diagnose"]

CANDIDATES = tuple(name for name, spec in REGISTRY.items() if spec.searched)
"""The effects tested by default (`EffectSpec.searched`)."""
LOOP_SHAPE = "loop_shape"
"""The origin of a partial finding of a loop-shape effect (module docstring): not claimed as the material's."""
CLAIMS = (*ORIGINS, LOOP_SHAPE)
"""The origins a finding can have, each listed apart in ``extended`` (``<origin>_effects``)."""
FAR_FROM_NOISE = 10.0
"""An account (a base and its findings) that leaves over this many times the noise has missed most of the
structure (99 % of the residual energy is not noise): the higher-order base is searched too, and the account
that predicts better is taken (`_higher_order_account`)."""
_FINDING_KEYS = (
    "effect",
    "origin",
    "p_value",
    "parameters",
    "stderr",
    "explained_fraction",
    "residual_rms",
    "lr",
    "df",
    "n_eff",
    "confirmed_held_out",
    "held_out_rss",
    "held_out_rss_without",
)


def diagnose(
    recordings: Sequence[Recording],
    *,
    model=None,
    progress: Progress = silent,
    candidates: Sequence[str] = CANDIDATES,
    alpha: float = ALPHA,
    max_findings: int = 2,
    base_order: int | None = None,
    separate: bool | None = None,
) -> Diagnosis:
    """Diagnose one experiment; see the module docstring for the procedure.

    Parameters
    ----------
    recordings : the experiment's recordings, in time order: on one clock, or each on its own.
    model : optional base model (`RateIndependentModel` or `RateDependentModel`); its A, B, E, x0 are
        refined on the experiment.
    base_order : without `model`: None (default) takes the base from
        `fitter.diagnosis.fitting.duhem_fit` (`fit_recordings(recordings, kind="ri")`), the order chosen by BIC as
        `duhem fit` chooses it; 2-4 the same with that order; 1 fits the first-order base here (fast:
        every candidate fit refits its 7 parameters).  A fitted base of order 2-4 is refined like a
        given model (its A matrices held).
    progress : callback ``progress(message, fraction_done)`` (`fitter.progress`).
    candidates : effect names to test (default `CANDIDATES`, the effects of `fitter.core.effects.REGISTRY`
        searched by default); those the base model already has (a given model's effects, or the input dead
        band of a fitted base) are skipped.
    alpha : family-wise significance level (Bonferroni over the candidates).
    max_findings : most effects added to the model.
    separate : the recordings are separate runs, each on its own clock (`join_recordings`): each is
        simulated alone from the initial state fitted to it, as `duhem fit` and the baselines score.
        None (default): separate runs when a file starts at or before its predecessor ends
        (`fitter.diagnosis.experiment.own_clocks`), else one clock; True or False forces a reading.

    Raises
    ------
    DiagnoseError : too few samples, an input that never reverses, recordings of different columns,
        overlapping clocks, non-finite values, an output the base does not relate to its input
        (`fitter.diagnosis.base.check_explains`).
    """
    unknown = [c for c in candidates if c not in REGISTRY]
    if unknown:
        raise DiagnoseError(f"unknown candidate effect {unknown[0]!r} (known: {', '.join(REGISTRY)})")
    progress("fitting the base model", 0.0)
    ex, mask, first, floor, gains = calibrated_base(join_recordings(recordings, separate), model is None, base_order)
    noise = floor["rms"]
    n_steps = len(candidates) * (3 if model is None and base_order is None else 2) + 5
    done = [1]

    def tick(msg):
        done[0] += 1
        progress(msg, min(done[0] / n_steps, 0.99))

    alternative, below = None, False
    if model is None and base_order is None:
        base, first_round, alternative, below = adequate_base(ex, first, mask, noise, candidates, alpha, tick)
    else:
        if model is None and base_order != 1:
            base = duhem_fit(ex, mask, base_order)[1]
        else:
            base = first if model is None else fit_base(ex, model, mask)
        first_round = None
    check_explains(ex, base)
    tick("refitting the base on each recording alone")
    gap = file_gap(ex, base, mask)
    floor = capped_noise(floor, gap)
    noise = floor["rms"]
    account = _refined(
        ex,
        _search(
            ex,
            base,
            first_round,
            below_order(candidates) if below else candidates,
            mask,
            noise,
            alpha,
            max_findings,
            tick,
        ),
        mask,
        tick,
    )
    if alternative is not None:
        first_base = base
        base, account = _higher_order_account(
            ex, base, account, alternative, candidates, mask, noise, alpha, max_findings, tick
        )
        if base is not first_base:  # the per-recording check of the base kept
            gap = file_gap(ex, base, mask)
            floor = capped_noise(floor, gap)
            noise = floor["rms"]
    current, findings, tested, fits = account
    mismatch = locate_mismatch(ex, base.residual, noise)
    tick("checking on held-out data")
    remainder = _remainder(ex, current, mask, noise, alpha, gap)
    for f in findings:
        f["partial"] = not remainder["explained"]
        if f["partial"] and REGISTRY[f["effect"]].loop_shape:
            f["origin"] = LOOP_SHAPE
    validation, comparison = _validate(ex, base, findings, tested, fits, mask, noise)
    ext_model = described(_with_first_start(current), ex.recordings).replace(
        fit_info={
            "method": "duhem diagnose",
            "effects": [f["effect"] for f in findings],
            "noise_rms": noise,
            "x0": {
                "stored": np.ravel(current.model.x0).tolist(),
                "recording": ex.recordings[0].name,
                "u0": float(ex.u[0]),
            },
            "fitted_range": fitted_range(ex.recordings),
        }
    )
    extended = dict(
        _summary(ex, current, noise),
        effects=[e.to_dict() for e in ext_model.effects],
        heldout_nrmse_per_recording=held_out_nrmse(ex, current, mask),
        **{f"{origin}_effects": [f["effect"] for f in findings if f["origin"] == origin] for origin in CLAIMS},
        remainder=remainder,
    )
    baseline = _summary(ex, base, noise)
    progress("done", 1.0)
    diag = Diagnosis(
        noise_rms=noise,
        noise=floor,
        verdict=_verdict(findings, baseline, remainder, max(noise, RESOLUTION * float(np.ptp(ex.y[mask]))), gap),
        baseline=baseline,
        mismatch=mismatch,
        candidates=tested,
        findings=findings,
        extended=extended,
        validation=validation,
        comparison=comparison,
        paragraph="",
        base_model=described(base.model, ex.recordings),
        extended_model=ext_model,
        baseline_output=ex.y - base.residual,
        extended_output=ex.y - current.residual,
        separate=ex.separate,
        file_gap=gap,
        file_gains=gains,
    )
    diag.paragraph = summary_paragraph(diag)
    return diag


def _search(
    ex: JoinedExperiment,
    base: Fit,
    first_round: list | None,
    candidates: Sequence[str],
    mask: np.ndarray,
    noise: float,
    alpha: float,
    max_findings: int,
    tick: Callable[[str], None],
) -> tuple:
    """Steps 3-4 on `base` (module docstring): (extended fit, findings, first-round candidate reports with
    their rank, first-round fits by effect).  `first_round`: the base's first round when already run."""
    present = {e.effect for e in base.model.effects}
    candidates = [c for c in candidates if c not in present]
    current, findings, tested, fits, starts = base, [], [], {}, {}
    remaining = list(candidates)
    while remaining and len(findings) < max_findings:
        round_results = (
            first_round
            if first_round is not None and not findings
            else candidate_round(
                ex, current, remaining, mask, alpha, len(candidates), tick, [f["effect"] for f in findings], starts
            )
        )
        if not findings:
            tested = [dict(r, rank=j + 1) for j, (r, _) in enumerate(round_results)]
            fits = {r["effect"]: f for r, f in round_results}
            starts = {r["effect"]: f for r, f in round_results if r["significant"] and r["origin"] == "measurement"}
        if rms(current.residual) <= NOISE_MARGIN * noise:
            break  # the model is adequate already: a significant candidate would fit noise
        winner = next(((r, f) for r, f in round_results if r["significant"]), None)
        if winner is None:
            break
        rep, current = winner
        findings.append({k: rep[k] for k in _FINDING_KEYS + ("response", "reversal") if k in rep})
        findings[-1]["consistency"] = _consistency(ex, current, mask, alpha)
        remaining = [c for c in remaining if c != rep["effect"]]
        if rms(current.residual) <= NOISE_MARGIN * noise:
            break
    return current, findings, tested, fits


def _higher_order_account(
    ex: JoinedExperiment,
    base: Fit,
    account: tuple,
    alternative: tuple,
    candidates: Sequence[str],
    mask: np.ndarray,
    noise: float,
    alpha: float,
    max_findings: int,
    tick: Callable[[str], None],
) -> tuple[Fit, tuple]:
    """Step 1's second account (module docstring): the first-order `base` and its `account`, or the base of
    `alternative` (the order `duhem fit` chooses, its fit and parameter count) with its own account (refined,
    `_refined`).  Far from the noise (over `FAR_FROM_NOISE` times it) the first-order account is no account of
    the data, and the one that predicts held-out recordings better is taken (`_account_error`).  Nearer,
    the higher order is searched only when the first finding is inconsistent across the recordings and not
    significant on the higher-order base (it stood in for the order), and its account is taken when it reaches
    the noise and predicts better."""
    findings, left = account[1], rms(account[0].residual)
    if left <= NOISE_MARGIN * noise:
        return base, account
    far = left > FAR_FROM_NOISE * noise
    if not far and (not findings or (findings[0]["consistency"] or {}).get("consistent", False)):
        return base, account
    high, k_high = alternative
    if (
        not far
        and candidate_round(ex, high, [findings[0]["effect"]], mask, alpha, len(candidates), tick)[0][0]["significant"]
    ):
        return base, account
    other = _refined(ex, _search(ex, high, None, candidates, mask, noise, alpha, max_findings, tick), mask, tick)
    adequate = far or (other[1] and rms(other[0].residual) <= NOISE_MARGIN * noise)
    if adequate and _account_error(ex, other, k_high, mask) < _account_error(ex, account, base.family.n_base, mask):
        return high, other
    return base, account


def _refined(ex: JoinedExperiment, account: tuple, mask: np.ndarray, tick: Callable[[str], None]) -> tuple:
    """Step 4's last part (module docstring): the account (`_search`) with its extended fit's findings, tested
    in their basic form, refitted with their refinement parameters (`fitter.diagnosis.fitting.with_refinements`)
    when the BIC counting them (`bic`) is lower; the first finding alone, refined from its own basic fit on
    the base (the first round's, not the joint fit with the later findings taken out), when it predicts the
    held-out recordings at least as well (`fitter.diagnosis.held_out.prediction_error`) as all of them."""
    fit, findings = account[0], account[1]
    if not findings:
        return account
    tick("refining the findings")
    names = [f["effect"] for f in findings]
    refined = with_refinements(fit, names, ex, mask)
    extra = sum(p.refinement for f in findings for p in REGISTRY[f["effect"]].parameters)
    if refined is None or bic(refined, extra) >= bic(fit, 0):
        return account
    if len(names) > 1 and len(ex.recordings) > 1:
        first = with_refinements(account[3][names[0]], names[:1], ex, mask)
        if first is not None and prediction_error(ex, first, mask) <= prediction_error(ex, refined, mask):
            return (first, findings[:1], *account[2:])
    return (refined, *account[1:])


def _account_error(ex: JoinedExperiment, account: tuple, k_base: int, mask: np.ndarray) -> float:
    """How well a base with its findings (an account, `_search`) generalises: its prediction error on held-out
    recordings (`fitter.diagnosis.held_out.prediction_error`), or with a single recording its BIC (`k_base`
    base parameters plus the findings' parameters)."""
    current, findings = account[0], account[1]
    if len(ex.recordings) > 1:
        return prediction_error(ex, current, mask)
    return bic(current, k_base + sum(len(f["parameters"]) for f in findings))


def _consistency(ex: JoinedExperiment, fit: Fit, mask: np.ndarray, alpha: float) -> dict | None:
    """`statistics.consistency_report` of a finding (None with a single recording: not testable)."""
    if len(ex.recordings) < 2:
        return None
    per = fit_per_recording(fit, ex, mask)
    return consistency_report(fit, per, [r.name for r in ex.recordings], effective_samples(fit.residual[mask]), alpha)


def _remainder(ex: JoinedExperiment, fit: Fit, mask: np.ndarray, noise: float, alpha: float, gap: dict | None) -> dict:
    """The residual the extended model leaves: `statistics.remainder_report` (is it white noise?), its
    RMS against the noise, ``explained`` (RMS within `NOISE_MARGIN` of the noise, not structured, and not
    more than `GAP` times the base refitted on each recording alone, `file_gap`: ``per_file_ratio``) and
    where it is largest (recording, branch, input range: `locate.locate_mismatch`)."""
    rep = remainder_report(ex, fit.residual, mask, alpha)
    where = locate_mismatch(ex, fit.residual, noise)
    worst_range = max(
        (b for b in where["per_input_range"] if b["residual_rms"] is not None), key=lambda b: b["residual_rms"]
    )
    branches = {k: v for k, v in where["per_branch"].items() if v is not None}
    left = rms(fit.residual[mask])
    per_file = left / gap["per_file_rms"] if gap and gap["per_file_rms"] > 0 else None
    rep.update(
        residual_rms=left,
        noise_ratio=left / noise if noise else None,
        per_file_ratio=per_file,
        explained=bool(
            left <= NOISE_MARGIN * noise
            and not rep["structured"]
            and not (per_file is not None and per_file > GAP and left > NOISE_MARGIN * noise)
        ),
        worst_recording=where["worst_recording"],
        worst_branch=max(branches, key=branches.get),
        worst_input_range=[worst_range["u_from"], worst_range["u_to"]],
        per_recording={p["name"]: p["residual_rms"] for p in where["per_recording"]},
        per_branch=where["per_branch"],
    )
    return rep


def _verdict(findings: list, baseline: dict, remainder: dict, noise: float, gap: dict | None) -> str:
    """The verdict (module docstring): "effects_found" when the findings leave an explained remainder,
    "nothing_missing" when there are none and the base residual is within `NOISE_MARGIN` of the noise (at least
    `RESOLUTION` of the output range: `noise` as given), or
    when the only difference between the recordings is a gain and an offset per file (`file_gap`'s
    ``gain_explains``: a property of each file), else "unexplained" (a gap between the joint base and the
    per-recording fits is never noise)."""
    if findings:
        return "effects_found" if remainder["explained"] else "unexplained"
    if gap and gap["gap"]:
        return "nothing_missing" if gap["gain_explains"] else "unexplained"
    if baseline["residual_rms"] <= NOISE_MARGIN * noise:
        return "nothing_missing"
    return "unexplained"


def _validate(
    ex: JoinedExperiment, base: Fit, findings: list, tested: list, fits: dict, mask: np.ndarray, noise: float
) -> tuple[dict | None, str]:
    """Hold out the last recording: refit base (+ winner, + runner-up) on the rest, predict it."""
    if len(ex.recordings) < 2 or not findings:
        return None, ""
    train = mask.copy()
    train[ex.part(len(ex.recordings) - 1)] = False
    hold = ~train
    out = {"held_out": ex.recordings[-1].name}
    win = findings[0]["effect"]
    runner = next((c for c in tested if c["effect"] != win), None)
    names = [win] + ([runner["effect"]] if runner is not None else [])
    base_hold = fit_family(base.model, [], base.theta, ex, train, ex.y - base.residual)
    out["base"] = rms(base_hold.residual[hold])
    for name in names:
        f = fits[name]
        fit = fit_family(
            f.family.base.template, f.family.effects, f.theta[: f.family.n_base], ex, train, ex.y - f.residual
        )
        out[name] = rms(fit.residual[hold])
    worst = ""
    if runner is not None:
        worst = where_differs(ex, fits[win].residual, fits[runner["effect"]].residual)
        out["confirmed"] = bool(out[win] < out["base"] and out[win] <= out[runner["effect"]])
    else:
        out["confirmed"] = bool(out[win] < out["base"])
    return out, comparison_text(findings[0], runner, out, noise, worst)


def _with_first_start(fit: Fit):
    """`fit`'s model with its effects' stored start the first recording's (settled on it where it is a closed
    loop, `fitter.diagnosis.fitting.problem`), so that the model runs from where the fit started it."""
    states = fit.result.states
    if fit.separate and states and states[0] is not None:
        return with_start(fit.model, states[0])
    return fit.model


def _summary(ex: JoinedExperiment, model_fit: Fit, noise: float) -> dict:
    yhat = ex.y - model_fit.residual
    return {
        "nrmse": nrmse(ex.y, yhat),
        "residual_rms": rms(model_fit.residual),
        "references": output_references(model_fit, ex),
        "noise_ratio": rms(model_fit.residual) / noise if noise else None,
        "nrmse_per_recording": {r.name: nrmse(ex.y[ex.part(i)], yhat[ex.part(i)]) for i, r in enumerate(ex.recordings)},
    }
