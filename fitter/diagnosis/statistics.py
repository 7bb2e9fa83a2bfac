"""Is a candidate effect significant?  The likelihood-ratio test on autocorrelated residuals.

Test: likelihood ratio LR = n_eff ln(RSS_0 / RSS_1), RSS_0 of the model
without the candidate and RSS_1 with it, chi-square with as many degrees of
freedom as the effect has parameters.  Residuals of sampled dynamics are
autocorrelated, so n_eff = N (1 - rho) / (1 + rho), rho the lag-1
autocorrelation of the candidate's residual (AR(1) effective sample size,
`fitter.identification.refine.effective_samples`; rho clipped to
[0, 0.98]).

Consistency across recordings (`consistency_report`): a finding's effect is
refitted on each recording alone (everything else held); LR = n_eff
ln(RSS_joint / sum RSS_i), k (R - 1) degrees of freedom for k parameters and
R recordings.  The effect is *consistent* unless p < alpha and the separate
parameters remove at least `MIN_EXPLAINED` of the remaining residual energy:
the catalogue's functional form holds with one parameter set (a true effect
of the catalogue gives a gain of 0.1-0.3 %; a logarithmic creep, a pure delay
or a half-derivative fitted as `creep` give 4-12 %, with p < 1e-9).  A candidate is significant when p < alpha / (number
of candidates) (Bonferroni) and it removes at least `MIN_EXPLAINED` of the
residual energy it starts from.  Standard errors:
sqrt(diag(s^2 (J^T J)^+ N / n_eff)), s^2 = RSS_1 / (N - p), J the Jacobian of
the residual in theta (`RefineResult.stderr`; a log-parameter's error is scaled
back by its value).

A parameter whose uncertainty is as large as its value makes no finding (`determined`): an effect confirmed on
held-out data, where the likelihood test could not establish it, is a finding only when each of its strengths
(the basic-form parameters whose null is 0: a gain, a drift rate, a play) lies `COVERAGE` standard errors
from 0 (GUM's expanded uncertainty, coverage factor 2).  On a ferroelectric loop with switching found, a thermal
drift with kappa = -3.3e-5 +- 2.2e-5 (LR 1.6, p = 0.21) predicted the held-out files better by 16-78 %: the
refits without it from the joint values landed elsewhere, not a gain that kappa made.  An effect the likelihood
test establishes needs no such check (a relaxation spectrum's k, correlated with its shares and time
constants, has a standard error many times its value while p < 1e-300).

Does an input memory follow the input (`memory_response_report`)?  A creep
(and each creep of a relaxation spectrum: the effects with
`EffectSpec.memory_taus`) starts at rest at the first input (c_0 = k u_0),
so besides its response to input changes it carries a start transient
k (u_0 - mean u) e^{-(t - t_0)/tau}: a function of time alone, which a slow
drift of the measured output fits as well.  In the fit's neighbourhood (its
Jacobian in the other free parameters, the time constants held) the effect's
response L (its output per unit k) and the transients e^{-(t - t_0)/tau_i}
(one per time constant and run, and as many again log-spaced from three
samples to the run's duration, `START_TRANSIENTS`: a start-up transient of
the output, whatever its time constant, is not a memory of the input) are
given separate gains: the effect is the
input's memory only when the gain of L, with the transients free, has the
sign of k and is significant (LR = n_eff ln(RSS_without L / RSS_with L), one
degree of freedom, p < alpha / number of candidates).  Otherwise what it fits
is its start, a change in time (a drift: an exponential drift over the
experiment is fitted by a creep with tau near the duration, or a relaxation
spectrum, with no response, or one of the opposite sign, to the input).

Does a reversing effect swing both ways (`reversal_report`)?  An effect whose output is a state the input
drives both ways (`EffectSpec.reverses`: switching domains) fits a drift in time too, with one threshold
just beyond the input's tips and the other out of reach, where it moves one way a little at every tip.  Its
fitted output c (on each run, afresh, everything else off) started at its lowest state rises by
V+ = sum max(dc, 0), and started at its highest falls by V- = sum max(-dc, 0) (`EffectSpec.extremes`); it
reverses when min(V+, V-) >= `REVERSAL_MIN` max(V+, V-).  Domains that switch over at one tip and back at
the other give a ratio near 1, a drift 0.  The extreme starts, not the fitted one, make the answer a property
of the input's drive: a device poled at a run's start (the fitted state already at the first tip's side)
shows only its fall from there, though the input would switch it back (a piezo record of one cycle did, so
the answer turned on the last digits of the data).

Is the residual left explained (`remainder_report`)?  Under "explained" it is
the white measurement noise the noise level assumes; a remainder that a
missing effect leaves is smooth, so its samples correlate with their
neighbours.  The statistic is the lag-1 autocorrelation r1 of the residual
over neighbouring samples of each recording (Durbin-Watson's statistic is
2 (1 - r1)): for white noise r1 is 0 with standard deviation 1/sqrt(N) (N the
pairs), and for a slowly varying part s on top of white noise r1 is about
the share of the residual's energy that s carries.  The remainder is
*structured* when p < alpha (one-sided, normal: z = r1 sqrt(N)) and r1 >=
`MIN_EXPLAINED`: the diagnosis' own level and the size a candidate must
explain to be a finding, so a remainder is unexplained when an effect that
explained its structured part would itself be a finding.  No constant is
new (the concealed catalogue effects of the tests leave r1 between -0.04
and 0.01 at N = 1200, white noise's 0 +- 0.03).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2, norm

from fitter.core.effects import REGISTRY, Chain
from fitter.diagnosis.experiment import JoinedExperiment
from fitter.diagnosis.fitting import Fit, jacobian_rows

__all__ = [
    "ALPHA",
    "COVERAGE",
    "determined",
    "MIN_EXPLAINED",
    "NOISE_MARGIN",
    "REVERSAL_MIN",
    "consistency_report",
    "effect_report",
    "is_significant",
    "memory_response_report",
    "remainder_report",
    "reversal_report",
    "swing",
    "RESOLUTION",
]

ALPHA = 0.01
MIN_EXPLAINED = 0.02
NOISE_MARGIN = 1.2
RESOLUTION = 1e-3
"""A residual RMS below this fraction of the output range is below what an instrument resolves (0.1 % of full
scale, a good sensor's accuracy): the diagnosis declares no gap between files and nothing unexplained below it
(`fitter.diagnosis.file_gap`, the verdict), as the fit's generality property takes 1e-3 of the range for a
noise-free recording followed.  Effects found above the noise are still reported."""
REVERSAL_MIN = 0.25
"""Least ratio of the smaller to the larger one-way travel of a reversing effect's output (`reversal_report`)."""
COVERAGE = 2.0
"""Standard errors by which a strength of an effect confirmed on held-out data must lie from 0 (`determined`)."""
START_TRANSIENTS = 6
"""Generic start transients per run in `memory_response_report` (module docstring)."""


def _physical(fam, theta, se=None) -> tuple[dict, dict]:
    """The effect parameters of `theta` (and of its standard errors `se`) in physical units."""
    params, errs = {}, {}
    se = [0.0] * len(fam.keys) if se is None else se
    for (_, par), v, s in zip(fam.keys, theta[fam.n_base :], se):
        if par.log:
            params[par.name] = math.exp(v)
            errs[par.name] = math.exp(v) * float(s)
        else:
            params[par.name], errs[par.name] = float(v), float(s)
    return params, errs


def consistency_report(fit: Fit, per_recording: list[Fit], names: list[str], n_eff: float, alpha: float) -> dict:
    """Does one parameter set hold across the recordings (module docstring)?  `fit` is a candidate fit
    (one effect on top of the model so far), `per_recording` its refits on each recording alone
    (`fitting.fit_per_recording`), `names` the recordings' names."""
    k = len(fit.family.keys)
    rss_sep = sum(f.rss for f in per_recording)
    lr = n_eff * math.log(max(fit.rss, 1e-300) / max(rss_sep, 1e-300))
    p = float(chi2.sf(max(lr, 0.0), k * (len(per_recording) - 1)))
    gain = 1.0 - rss_sep / fit.rss if fit.rss > 0 else 0.0
    return {
        "per_recording": {name: _physical(fit.family, f.theta)[0] for name, f in zip(names, per_recording)},
        "p_value": p,
        "gain": gain,
        "consistent": not (p < alpha and gain >= MIN_EXPLAINED),
    }


def determined(report: dict, null: dict[str, float]) -> bool:
    """Whether each strength of a candidate (module docstring: its parameters whose `null` value is 0, with a
    standard error, fitted in the basic form) lies `COVERAGE` standard errors from 0."""
    errors = report["stderr"]
    return all(
        abs(value) >= COVERAGE * errors[name]
        for name, value in report["parameters"].items()
        if null.get(name) == 0.0 and errors.get(name, 0.0) > 0.0
    )


def effect_report(fit: Fit, base_rss: float, n_eff: float, df: int) -> dict:
    """Parameters, standard errors, LR, p-value and explained fraction of a candidate fit against `base_rss`."""
    fam = fit.family
    params, errs = _physical(fam, fit.theta, fit.result.stderr(n_eff)[fam.n_base :])
    lr = n_eff * math.log(max(base_rss, 1e-300) / max(fit.rss, 1e-300))
    return {
        "parameters": params,
        "stderr": errs,
        "lr": lr,
        "df": df,
        "p_value": float(chi2.sf(max(lr, 0.0), df)),
        "n_eff": n_eff,
        "explained_fraction": 1.0 - fit.rss / base_rss if base_rss > 0 else 0.0,
        "residual_rms": math.sqrt(fit.rss / max(int(fit.mask.sum()), 1)),
    }


def is_significant(report: dict, alpha: float, n_candidates: int) -> bool:
    """p < alpha / n_candidates (Bonferroni) and at least `MIN_EXPLAINED` of the residual energy removed."""
    return bool(report["p_value"] < alpha / n_candidates and report["explained_fraction"] >= MIN_EXPLAINED)


def memory_response_report(
    fit: Fit, ex: JoinedExperiment, name: str, n_eff: float, alpha: float, n_candidates: int
) -> dict:
    """Does the input memory `name` of `fit` (a creep or a relaxation spectrum: `EffectSpec.memory_taus`)
    follow the input, or only its start transient (module docstring)?  ``gain_response``: its gain k with
    the transient free (a free e^{-(t - t0)/tau_i} per time constant and run); ``follows_input``: that gain
    has the sign of k and p < alpha / n_candidates."""
    fam, mask = fit.family, fit.mask
    spec = REGISTRY[name]
    par = next(e.parameters for e in fam.effect_list(fit.theta) if e.effect == name)
    k, taus = float(par["k"]), spec.memory_taus(par)
    L = np.concatenate(_alone(spec, dict(par, k=1.0), ex))  # the output per unit k
    runs = ex.runs()
    E = np.zeros((len(ex.t), len(runs) * (len(taus) + START_TRANSIENTS)))
    for j, s in enumerate(runs):
        elapsed = ex.t[s] - ex.t[s][0]
        step = float(np.median(np.diff(ex.t[s]))) if s.stop - s.start > 1 else 1.0
        generic = np.geomspace(3 * step, max(elapsed[-1], 3 * step), START_TRANSIENTS)
        for i, tau in enumerate([*taus, *generic]):
            E[s, j * (len(taus) + START_TRANSIENTS) + i] = np.exp(-elapsed / tau)
    rows = jacobian_rows(ex, mask)  # the samples the Jacobian has (the optimised ones)
    L, E, J = L[rows], E[rows], fit.result.jac
    own = {fam.n_base + i for i, (e, _) in enumerate(fam.keys) if e == name}
    moving = [j for j in np.flatnonzero(np.any(J != 0, axis=0)) if j not in own]
    r = fit.residual[rows]

    coef, rss_with = _linear_fit(np.column_stack([J[:, moving], E, L]), r)
    _, rss_without = _linear_fit(np.column_stack([J[:, moving], E]), r + k * L)
    gain = k + float(coef[-1])
    lr = n_eff * math.log(max(rss_without, 1e-300) / max(rss_with, 1e-300))
    p = float(chi2.sf(max(lr, 0.0), 1))
    return {
        "gain_response": gain,
        "lr": lr,
        "p_value": p,
        "follows_input": bool(gain * k > 0 and p < alpha / n_candidates),
    }


def _alone(spec, par: dict, ex: JoinedExperiment) -> list[np.ndarray]:
    """The output of effect `spec` alone (the input as its only signal, y = 0 before it) at parameters `par`
    on each run of `ex` (`JoinedExperiment.runs`, which cover every sample), started afresh."""
    outputs = []
    for s in ex.runs():
        chain = Chain(t=ex.t[s], u=ex.u[s], h=np.diff(ex.t[s]), w=ex.u[s], y=np.zeros(s.stop - s.start))
        spec.apply(par, chain, None)
        outputs.append(chain.y)
    return outputs


def swing(outputs: list[np.ndarray]) -> tuple[float, float]:
    """(V+, V-): the total rise and the total fall of the signals in `outputs` (one per run)."""
    steps = np.concatenate([np.diff(c) for c in outputs]) if outputs else np.zeros(0)
    return float(np.sum(np.maximum(steps, 0.0))), float(np.sum(np.maximum(-steps, 0.0)))


def reversal_report(fit: Fit, ex: JoinedExperiment, name: str) -> dict:
    """Does the input drive the reversing effect `name` of `fit` both ways (module docstring)?  Its output
    alone on each run: ``rise`` V+ from its lowest start, ``fall`` V- from its highest, ``ratio`` min / max
    and ``reverses`` (ratio >= `REVERSAL_MIN`)."""
    spec = REGISTRY[name]
    low, high = spec.extremes(next(e.parameters for e in fit.family.effect_list(fit.theta) if e.effect == name))
    rise, fall = swing(_alone(spec, low, ex))[0], swing(_alone(spec, high, ex))[1]
    ratio = min(rise, fall) / max(rise, fall) if max(rise, fall) > 0 else 0.0
    return {"rise": rise, "fall": fall, "ratio": ratio, "reverses": bool(ratio >= REVERSAL_MIN)}


def _linear_fit(columns: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, float]:
    """Linear least squares of `target` on `columns`: (coefficients, residual sum of squares)."""
    coef, *_ = np.linalg.lstsq(columns, target, rcond=None)
    return coef, float(np.sum((target - columns @ coef) ** 2))


def remainder_report(ex: JoinedExperiment, residual: np.ndarray, mask: np.ndarray, alpha: float) -> dict:
    """Is the residual left white noise (module docstring)?  r1 over the neighbouring samples of each
    recording (both in `mask`), its one-sided p-value and ``structured``."""
    num = den = 0.0
    pairs = 0
    for i in range(len(ex.recordings)):
        s = ex.part(i)
        r, m = residual[s], mask[s]
        both = m[1:] & m[:-1]
        num += float(np.dot(r[1:][both], r[:-1][both]))
        den += float(np.dot(r[m], r[m]))
        pairs += int(np.count_nonzero(both))
    r1 = num / den if den > 0 else 0.0
    p = float(norm.sf(r1 * math.sqrt(max(pairs, 1))))
    return {"lag1": r1, "p_value": p, "pairs": pairs, "structured": bool(p < alpha and r1 >= MIN_EXPLAINED)}
