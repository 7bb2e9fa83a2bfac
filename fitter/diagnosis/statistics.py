"""Is a candidate effect significant?  The likelihood-ratio test on autocorrelated residuals.

Test: likelihood ratio LR = n_eff ln(RSS_0 / RSS_1), RSS_0 of the model
without the candidate and RSS_1 with it, chi-square with as many degrees of
freedom as the effect has parameters.  Residuals of sampled dynamics are
autocorrelated, so n_eff = N (1 - rho) / (1 + rho), rho the lag-1
autocorrelation of the candidate's residual (AR(1) effective sample size,
`fitter.identification.output_error.effective_samples`; rho clipped to
[0, 0.98]).  A candidate is significant when p < alpha / (number
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

__all__ = ["ALPHA", "MIN_EXPLAINED", "NOISE_MARGIN", "effect_report", "is_significant"]

ALPHA = 0.01
MIN_EXPLAINED = 0.02
NOISE_MARGIN = 1.2


def effect_report(fit: Fit, base_rss: float, n_eff: float, df: int) -> dict:
    """Parameters, standard errors, LR, p-value and explained fraction of a candidate fit against `base_rss`."""
    fam = fit.family
    se = fit.result.stderr(n_eff)[fam.n_base:]
    params, errs = {}, {}
    for (_, par), v, s in zip(fam.keys, fit.theta[fam.n_base:], se):
        if par.log:
            params[par.name] = math.exp(v)
            errs[par.name] = math.exp(v) * float(s)
        else:
            params[par.name], errs[par.name] = float(v), float(s)
    lr = n_eff * math.log(max(base_rss, 1e-300) / max(fit.rss, 1e-300))
    return {"parameters": params, "stderr": errs, "lr": lr, "df": df,
            "p_value": float(chi2.sf(max(lr, 0.0), df)), "n_eff": n_eff,
            "explained_fraction": 1.0 - fit.rss / base_rss if base_rss > 0 else 0.0,
            "residual_rms": math.sqrt(fit.rss / max(int(fit.mask.sum()), 1))}


def is_significant(report: dict, alpha: float, n_candidates: int) -> bool:
    """p < alpha / n_candidates (Bonferroni) and at least `MIN_EXPLAINED` of the residual energy removed."""
    return bool(report["p_value"] < alpha / n_candidates and report["explained_fraction"] >= MIN_EXPLAINED)
