"""Is a candidate effect significant?  The likelihood-ratio test on autocorrelated residuals.

Test: likelihood ratio LR = n_eff ln(RSS_0 / RSS_1), RSS_0 of the model
without the candidate and RSS_1 with it, chi-square with as many degrees of
freedom as the effect has parameters.  Residuals of sampled dynamics are
autocorrelated, so n_eff = N (1 - rho) / (1 + rho), rho the lag-1
autocorrelation of the candidate's residual (AR(1) effective sample size,
`fitter.identification.output_error.effective_samples`; rho clipped to
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
"""
from __future__ import annotations

import math

from scipy.stats import chi2

from fitter.diagnosis.fitting import Fit

__all__ = ["ALPHA", "MIN_EXPLAINED", "NOISE_MARGIN", "consistency_report", "effect_report", "is_significant"]

ALPHA = 0.01
MIN_EXPLAINED = 0.02
NOISE_MARGIN = 1.2


def _physical(fam, theta, se=None) -> tuple[dict, dict]:
    """The effect parameters of `theta` (and of its standard errors `se`) in physical units."""
    params, errs = {}, {}
    se = [0.0] * len(fam.keys) if se is None else se
    for (_, par), v, s in zip(fam.keys, theta[fam.n_base:], se):
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
    return {"per_recording": {name: _physical(fit.family, f.theta)[0] for name, f in zip(names, per_recording)},
            "p_value": p, "gain": gain, "consistent": not (p < alpha and gain >= MIN_EXPLAINED)}


def effect_report(fit: Fit, base_rss: float, n_eff: float, df: int) -> dict:
    """Parameters, standard errors, LR, p-value and explained fraction of a candidate fit against `base_rss`."""
    fam = fit.family
    params, errs = _physical(fam, fit.theta, fit.result.stderr(n_eff)[fam.n_base:])
    lr = n_eff * math.log(max(base_rss, 1e-300) / max(fit.rss, 1e-300))
    return {"parameters": params, "stderr": errs, "lr": lr, "df": df,
            "p_value": float(chi2.sf(max(lr, 0.0), df)), "n_eff": n_eff,
            "explained_fraction": 1.0 - fit.rss / base_rss if base_rss > 0 else 0.0,
            "residual_rms": math.sqrt(fit.rss / max(int(fit.mask.sum()), 1))}


def is_significant(report: dict, alpha: float, n_candidates: int) -> bool:
    """p < alpha / n_candidates (Bonferroni) and at least `MIN_EXPLAINED` of the residual energy removed."""
    return bool(report["p_value"] < alpha / n_candidates and report["explained_fraction"] >= MIN_EXPLAINED)
