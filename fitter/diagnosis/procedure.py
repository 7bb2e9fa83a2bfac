"""Diagnose a model-data mismatch: locate it, name the physics left out, model it.

One experiment is a list of recordings whose time is the experiment clock: it
runs on from file to file (gaps allowed).  The recordings are simulated as one
signal: the input is piecewise linear between all samples, including across a
gap (the straight line from the last sample of one file to the first of the
next), so model states, creep and the input travel of a thermal drift carry
over from file to file.

Procedure (`diagnose`)
----------------------
1. Base model: a first-order rate-independent model, eqs (1)-(2) with C = 1,
   D = 0 (D is redundant at order 1), fitted by output error (`_fit_base`: a
   grid over A+ = -A- < 0 (both branches converge, condition (5)) with B±,
   E±, x0 solved by linear least squares, since the
   output is affine in them for fixed A, then a joint nonlinear least-squares
   refinement), or a given model whose A, B, E (per branch) and x0 are refined.
2. Noise level sigma: `fitter.data.metrics.noise_rms` of each recording's output,
   pooled (median).  Locating (`locate_mismatch`): residual RMS per recording,
   per branch (rising / falling / held input), per input-range bin, its
   correlation across recordings with log rate, start time and amplitude, and
   a model-free comparison of a repeated run with its original.
3. Candidates (`fitter.core.effects.EFFECTS`): each is fitted jointly with the
   base parameters (scipy ``least_squares``, several starts for its nonlinear
   parameters).  Test: likelihood ratio LR = n_eff ln(RSS_0 / RSS_1), chi-square
   with as many degrees of freedom as the effect has parameters.  Residuals of
   sampled dynamics are autocorrelated, so n_eff = N (1 - rho) / (1 + rho),
   rho the lag-1 autocorrelation of the candidate's residual (AR(1) effective
   sample size; rho clipped to [0, 0.98]).  A candidate is significant when
   p < alpha / (number of candidates) (Bonferroni) and it removes at least
   `MIN_EXPLAINED` of the baseline residual energy.  Standard errors:
   sqrt(diag(s^2 (J^T J)^+ N / n_eff)), s^2 = RSS_1 / (N - p).
4. The significant candidates are ranked by their residual (lowest first); the
   winner is added, and the remaining candidates are tested again on top of it
   while the residual stays above `NOISE_MARGIN` times the noise (at most
   `max_findings`).  The extended model is checked on data not used to fit
   it: refitted without the last recording (the repeat), it predicts that
   recording; the runner-up gets the same hold-out check, and the report says
   why the winner wins (residual, hold-out error, where the difference lies).

The verdict: "effects_found" (findings non-empty), "nothing_missing" (no
finding and the base residual within `NOISE_MARGIN` of the noise) or
"unexplained" (no finding, residual above the noise: the missing physics is
not in the catalogue, or the base model is too simple).  The result is a
`Diagnosis`; ``to_json()`` is the stable ``--json`` output.
"""
from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable, Iterator, Sequence

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import chi2

from fitter.core.errors import DuhemError
from fitter.core.effects import EFFECTS, Effect
from fitter.core.kernel import KernelError, simulate
from fitter.core.models import RateDependentModel, RateIndependentModel, Signals
from fitter.data.metrics import noise_rms, nrmse, rms
from fitter.data.recordings import Recording

__all__ = ["DiagnoseError", "Diagnosis", "JoinedExperiment", "diagnose", "locate_mismatch", "rich_progress",
           "synthetic_experiment", "CANDIDATES"]

CANDIDATES = tuple(EFFECTS)
ALPHA = 0.01
MIN_EXPLAINED = 0.02
NOISE_MARGIN = 1.2
MIN_SAMPLES = 200
Progress = Callable[[str, float], None]


class DiagnoseError(DuhemError):
    """Input that cannot be diagnosed (named file, column, row, value)."""


# --------------------------------------------------------------------------- experiment
@dataclass
class JoinedExperiment:
    """The recordings of one experiment, concatenated on the experiment clock."""

    recordings: list
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    index: np.ndarray          # recording number of each sample
    bounds: list               # [start, stop) of each recording in the arrays

    def part(self, i: int) -> slice:
        return slice(*self.bounds[i])


def _experiment(recordings: Sequence[Recording]) -> JoinedExperiment:
    recs = list(recordings)
    if not recs:
        raise DiagnoseError("no recordings given")
    first = recs[0]
    for r in recs[1:]:
        if (r.input.name, r.output.name) != (first.input.name, first.output.name):
            raise DiagnoseError(f"{r.source}: columns ({r.input.name}, {r.output.name}) differ from "
                                f"{first.source}: ({first.input.name}, {first.output.name}); one experiment "
                                "needs the same input and output in every recording")
    for r in recs:
        for name in ("t", "u", "y"):
            a = getattr(r, name)
            bad = np.flatnonzero(~np.isfinite(a))
            if bad.size:
                raise DiagnoseError(f"{r.source}: column {name}, row {bad[0]}: value {a[bad[0]]} is not finite")
        dt = np.diff(r.t)
        bad = np.flatnonzero(dt <= 0)
        if bad.size:
            raise DiagnoseError(f"{r.source}: time does not increase at row {bad[0] + 1} "
                                f"(t = {r.t[bad[0] + 1]} after {r.t[bad[0]]})")
    for a, b in zip(recs[:-1], recs[1:]):
        if b.t[0] <= a.t[-1]:
            raise DiagnoseError(f"{b.source}: starts at t = {b.t[0]} before {a.source} ends (t = {a.t[-1]}); "
                                "the recordings of one experiment must share one clock that runs on from "
                                "file to file (shift the time of later files)")
    n = sum(len(r.t) for r in recs)
    if n < MIN_SAMPLES:
        raise DiagnoseError(f"{n} samples in all ({', '.join(r.source for r in recs)}): too short to "
                            f"diagnose (at least {MIN_SAMPLES} needed)")
    u = np.concatenate([r.u for r in recs])
    if _reversals(u) < 2:
        raise DiagnoseError(f"the input ({first.input.name}) reverses fewer than twice over the experiment "
                            f"({', '.join(r.source for r in recs)}): no hysteresis loop to diagnose")
    stops = np.cumsum([len(r.t) for r in recs])
    bounds = [(int(s - len(r.t)), int(s)) for s, r in zip(stops, recs)]
    return JoinedExperiment(recs, np.concatenate([r.t for r in recs]), u, np.concatenate([r.y for r in recs]),
                      np.concatenate([np.full(len(r.t), i) for i, r in enumerate(recs)]), bounds)


def _reversals(u: np.ndarray) -> int:
    """Input reversals larger than 10% of the input range (noise-proof turning points)."""
    span = np.ptp(u)
    if span == 0:
        return 0
    thr = 0.1 * span
    count, direction = 0, 0
    lo = hi = u[0]
    for v in u:
        hi, lo = max(hi, v), min(lo, v)
        if direction >= 0 and v < hi - thr:
            count += direction > 0
            direction, lo = -1, v
        elif direction <= 0 and v > lo + thr:
            count += direction < 0
            direction, hi = 1, v
    return count


# --------------------------------------------------------------------------- parametrised models
class _Family:
    """Base model + effects as a map theta -> model.

    theta = [base parameters..., effect parameters...]; effect time constants
    (creep tau, sensor_lag tau) enter as log(tau).  Bounds (`_bounds`): the
    effects' ranges; tau within [0.05 dt_min, 10 x duration]; the saturation
    centre y_c within the output's range; for the default base, A+ <= 0 <= A-
    (both branches converge, condition (5)) and |A| <= 1000 / input range.
    """

    def __init__(self, template, effects: Sequence[str], fixed_effects: Sequence[Effect] = ()):
        self.template = template
        self.fixed = list(fixed_effects)
        self.names = list(effects)
        self.base_keys = _free_keys(template)
        self.shapes = [np.shape(getattr(template, k)) for k in self.base_keys]
        self.n_base = int(sum(int(np.prod(s)) for s in self.shapes))
        self.effect_keys = [(e, p) for e in self.names for p in EFFECTS[e]]

    def split(self, theta):
        return theta[:self.n_base], theta[self.n_base:]

    def effect_params(self, theta) -> list[Effect]:
        vals = theta[self.n_base:]
        out: dict = {}
        for (e, p), v in zip(self.effect_keys, vals):
            out.setdefault(e, {})[p] = math.exp(v) if p == "tau" else float(v)
        return [Effect(e, out[e]) for e in self.names]

    def build(self, theta):
        base, _ = self.split(theta)
        kw = {k: getattr(self.template, k) for k in self.template.PARAMS}
        i = 0
        for k, s in zip(self.base_keys, self.shapes):
            n = int(np.prod(s))
            kw[k] = np.reshape(base[i:i + n], s)
            i += n
        cls = type(self.template)
        extra = {"g": self.template.g} if isinstance(self.template, RateDependentModel) else {}
        return cls(signals=self.template.signals, experiment=self.template.experiment,
                   effects=self.fixed + self.effect_params(theta), **kw, **extra)

    def base_theta(self, model) -> np.ndarray:
        return np.concatenate([np.ravel(getattr(model, k)) for k in self.base_keys])


def _free_keys(model) -> list[str]:
    if isinstance(model, RateIndependentModel):
        return ["A_plus", "A_minus", "B_plus", "B_minus", "E_plus", "E_minus", "x0"]
    return ["A", "B", "E", "x0"]


def _ri1(a_plus, a_minus, b_plus, b_minus, e_plus, e_minus, x0, signals=None) -> RateIndependentModel:
    return RateIndependentModel(A_plus=[[a_plus]], A_minus=[[a_minus]], B_plus=[b_plus], B_minus=[b_minus],
                                C=[1.0], E_plus=[e_plus], E_minus=[e_minus], x0=[x0],
                                signals=signals or Signals())


# --------------------------------------------------------------------------- fitting
@dataclass
class _Fit:
    family: _Family
    theta: np.ndarray
    residual: np.ndarray
    jac: np.ndarray
    mask: np.ndarray

    @property
    def rss(self) -> float:
        return float(np.sum(self.residual[self.mask] ** 2))

    @property
    def model(self):
        return self.family.build(self.theta)


def _simulate(model, ex: JoinedExperiment) -> np.ndarray:
    return simulate(model, ex.t, ex.u).y


def _least_squares(family: _Family, theta0: np.ndarray, ex: JoinedExperiment, mask: np.ndarray,
                   lower: np.ndarray, upper: np.ndarray, free: np.ndarray | None = None) -> _Fit:
    """Minimise sum over `mask` of (y - yhat(theta))^2; only the `free` entries of theta move."""
    scale = max(np.ptp(ex.y), 1e-300)
    free = np.ones(len(theta0), bool) if free is None else free
    pad = 1e-9 * (np.abs(theta0) + 1)
    theta0 = np.minimum(np.maximum(theta0, lower + pad), upper - pad)

    def full_theta(z):
        theta = theta0.copy()
        theta[free] = z
        return theta

    def fun(z):
        try:
            y = _simulate(family.build(full_theta(z)), ex)
        except (KernelError, ValueError, FloatingPointError):
            return np.full(int(mask.sum()), 1e3)
        r = (ex.y - y)[mask] / scale
        return np.where(np.isfinite(r), r, 1e3)

    with np.errstate(all="ignore"):
        res = least_squares(fun, theta0[free], bounds=(lower[free], upper[free]), x_scale="jac", method="trf",
                            xtol=1e-7, ftol=1e-7, gtol=1e-8, max_nfev=30 * (int(free.sum()) + 1))
    theta = full_theta(res.x)
    full = ex.y - _simulate(family.build(theta), ex)
    jac = np.zeros((res.jac.shape[0], len(theta)))
    jac[:, free] = res.jac * scale
    return _Fit(family, theta, full, jac, mask)


def _bounds(family: _Family, ex: JoinedExperiment) -> tuple[np.ndarray, np.ndarray]:
    lo = np.full(family.n_base, -np.inf)
    hi = np.full(family.n_base, np.inf)
    if family.base_keys[:2] == ["A_plus", "A_minus"] and family.n_base == 7:
        a_max = 1e3 / max(np.ptp(ex.u), 1e-300)
        lo[:2], hi[:2] = [-a_max, 0.0], [0.0, a_max]
    elo, ehi = [], []
    for e, p in family.effect_keys:
        rng = EFFECTS[e][p]
        if p == "tau":
            dt = _min_dt(ex)
            elo.append(math.log(dt * 0.05))
            ehi.append(math.log(max(np.ptp(ex.t), dt) * 10))
        elif p == "y_c":
            elo.append(float(ex.y.min()))
            ehi.append(float(ex.y.max()))
        else:
            elo.append(rng[0])
            ehi.append(rng[1])
    return np.r_[lo, elo], np.r_[hi, ehi]


def _min_dt(ex: JoinedExperiment) -> float:
    """The shortest of the recordings' median sample periods."""
    return float(min(np.median(np.diff(r.t)) for r in ex.recordings))


def _effect_starts(name: str, ex: JoinedExperiment, y_fit: np.ndarray) -> list[list[float]]:
    """Starting values of an effect's parameters (several for nonlinear ones)."""
    dt = _min_dt(ex)
    span_u, span_y = np.ptp(ex.u), max(np.ptp(ex.y), 1e-300)
    vmax = float(np.percentile(np.abs(np.diff(ex.u) / np.diff(ex.t)), 95)) or 1.0
    duration = np.ptp(ex.t)
    taus = np.geomspace(3 * dt, max(duration / 10, 10 * dt), 4)
    if name == "backlash":
        return [[0.01 * span_u], [0.05 * span_u]]
    if name == "rate_dependence":
        return [[0.05 / vmax], [0.5 / vmax]]
    if name == "creep":
        return [[0.0, math.log(tau)] for tau in taus]
    if name == "viscous":
        return [[0.0]]
    if name == "thermal_drift":
        return [[0.0]]
    if name == "saturation":
        yc = float(np.mean(y_fit))
        return [[yc, 0.5 / (span_y / 2)], [yc, 1.5 / (span_y / 2)]]
    if name == "sensor_lag":
        return [[math.log(tau)] for tau in taus[:3]]
    raise KeyError(name)


def _fit_family(family: _Family, base: np.ndarray, ex: JoinedExperiment, mask: np.ndarray,
                y_fit: np.ndarray) -> _Fit:
    """Joint fit of base + effects, started from the best of the effects' starting values.

    The starts are screened with the base parameters held (cheap: only the
    effect parameters move); the joint fit starts from the best one.  Should
    it end above the nested model (the base with the effect switched off,
    `_null_effect`), it is refitted from there, so a candidate never explains
    a negative fraction.
    """
    lower, upper = _bounds(family, ex)
    starts = [[]]
    for name in family.names:
        starts = [s + e for s in starts for e in _effect_starts(name, ex, y_fit)]
    theta0 = np.r_[base, starts[0]]
    if len(starts) > 1:
        effect_only = np.r_[np.zeros(family.n_base, bool), np.ones(len(theta0) - family.n_base, bool)]
        screened = [_least_squares(family, np.r_[base, s], ex, mask, lower, upper, effect_only) for s in starts]
        theta0 = min(screened, key=lambda f: f.rss).theta
    fit = _least_squares(family, theta0, ex, mask, lower, upper)
    null = np.r_[base, sum((_null_effect(name, ex, y_fit) for name in family.names), [])]
    null_rss = float(np.sum((ex.y - _simulate(family.build(null), ex))[mask] ** 2))
    if fit.rss > null_rss * (1 + 1e-4):
        fit = _least_squares(family, null, ex, mask, lower, upper)
    return fit


def _null_effect(name: str, ex: JoinedExperiment, y_fit: np.ndarray) -> list[float]:
    """Effect parameters (in theta's coordinates) at which the effect (almost) vanishes: the nested model."""
    if name == "creep":
        return [0.0, math.log(10 * _min_dt(ex))]
    if name == "saturation":
        return [float(np.mean(y_fit)), 0.0]
    if name == "sensor_lag":
        return [math.log(0.05 * _min_dt(ex)) + 1e-6]
    return [0.0]


def _fit_base(ex: JoinedExperiment, model, mask: np.ndarray) -> _Fit:
    """Base fit: refine a given model, or a first-order RI model (grid over A, linear in B, E, x0)."""
    if model is not None:
        family = _Family(RateIndependentModel(**{k: getattr(model, k) for k in model.PARAMS},
                                              signals=model.signals) if model.kind == "ri"
                         else RateDependentModel(**{k: getattr(model, k) for k in model.PARAMS}, g=model.g,
                                                 signals=model.signals), [], list(model.effects))
        theta = family.base_theta(model)
        lo, hi = _bounds(family, ex)
        return _least_squares(family, theta, ex, mask, lo, hi)
    span = max(np.ptp(ex.u), 1e-300)
    best = None
    for a in -np.geomspace(0.5, 64, 8) * 2 / span:  # inside the bounds of `_bounds`
        basis = [_simulate(_ri1(a, -a, *(np.eye(5)[j])), ex) for j in range(5)]
        basis = np.column_stack(basis)
        coef, *_ = np.linalg.lstsq(basis[mask], ex.y[mask], rcond=None)
        rss = float(np.sum((ex.y[mask] - basis[mask] @ coef) ** 2))
        if best is None or rss < best[0]:
            best = (rss, a, coef)
    _, a, (bp, bm, ep, em, x0) = best
    family = _Family(_ri1(a, -a, bp, bm, ep, em, x0), [])
    lo, hi = _bounds(family, ex)
    return _least_squares(family, np.array([a, -a, bp, bm, ep, em, x0]), ex, mask, lo, hi)


# --------------------------------------------------------------------------- statistics
def _n_eff(residual: np.ndarray) -> float:
    r = residual - residual.mean()
    rho = float(np.dot(r[1:], r[:-1]) / max(np.dot(r, r), 1e-300))
    rho = min(max(rho, 0.0), 0.98)
    return len(r) * (1 - rho) / (1 + rho)


def _stderr(fit: _Fit, n_eff: float) -> np.ndarray:
    J = fit.jac
    n, p = J.shape
    s2 = fit.rss / max(n - p, 1)
    cov = s2 * np.linalg.pinv(J.T @ J) * (n / max(n_eff, 1.0))
    return np.sqrt(np.clip(np.diag(cov), 0, None))


def _effect_report(fit: _Fit, base_rss: float, n_eff: float, df: int) -> dict:
    fam = fit.family
    se = _stderr(fit, n_eff)[fam.n_base:]
    params, errs = {}, {}
    for (e, p), v, s in zip(fam.effect_keys, fit.theta[fam.n_base:], se):
        if p == "tau":
            params[p] = math.exp(v)
            errs[p] = math.exp(v) * float(s)
        else:
            params[p], errs[p] = float(v), float(s)
    lr = n_eff * math.log(max(base_rss, 1e-300) / max(fit.rss, 1e-300))
    return {"parameters": params, "stderr": errs, "lr": lr, "df": df,
            "p_value": float(chi2.sf(max(lr, 0.0), df)), "n_eff": n_eff,
            "explained_fraction": 1.0 - fit.rss / base_rss if base_rss > 0 else 0.0,
            "residual_rms": math.sqrt(fit.rss / max(int(fit.mask.sum()), 1))}


# --------------------------------------------------------------------------- locating
def _rate(u: np.ndarray, t: np.ndarray) -> float:
    v = np.abs(np.diff(u) / np.diff(t))
    moving = v > 0.05 * v.max() if v.size and v.max() > 0 else np.zeros_like(v, bool)
    return float(np.median(v[moving])) if moving.any() else 0.0


def _corr(a: Sequence[float], b: Sequence[float]) -> float | None:
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) < 3 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    return float(np.corrcoef(a, b)[0, 1])


def _repeat_pair(ex: JoinedExperiment) -> tuple[int, int] | None:
    """(original, repeat): the last recording when an earlier one has the same length, rate and amplitude."""
    last = len(ex.recordings) - 1
    if last < 1:
        return None
    r = ex.recordings[last]
    for i, o in enumerate(ex.recordings[:last]):
        if len(o.u) == len(r.u) and np.allclose(o.u - o.u.mean(), r.u - r.u.mean(), atol=0.02 * np.ptp(r.u)) \
                and np.isclose(_rate(o.u, o.t), _rate(r.u, r.t), rtol=0.05):
            return i, last
    return None


def locate_mismatch(ex: JoinedExperiment, residual: np.ndarray, noise: float) -> dict:
    """Where the residual lives: per recording, branch, input range; growth; repeat."""
    du = np.r_[0.0, np.diff(ex.u)]
    tol = 1e-9 * np.ptp(ex.u)
    per = []
    for i, r in enumerate(ex.recordings):
        s = ex.part(i)
        per.append({"name": r.name, "t_start": float(r.t[0]), "t_stop": float(r.t[-1]),
                    "rate": _rate(r.u, r.t), "amplitude": float(np.ptp(r.u) / 2),
                    "residual_rms": rms(residual[s]), "noise_ratio": rms(residual[s]) / noise if noise else None,
                    "residual_mean": float(np.mean(residual[s]))})
    branches = {}
    for name, sel in (("rising", du > tol), ("falling", du < -tol), ("held", np.abs(du) <= tol)):
        branches[name] = rms(residual[sel]) if sel.any() else None
    edges = np.linspace(ex.u.min(), ex.u.max(), 6)
    bins = np.clip(np.digitize(ex.u, edges[1:-1]), 0, 4)
    by_input = [{"u_from": float(edges[j]), "u_to": float(edges[j + 1]),
                 "residual_rms": rms(residual[bins == j]) if (bins == j).any() else None} for j in range(5)]
    rms_rec = [p["residual_rms"] for p in per]
    growth = {"with_rate": _corr(np.log([max(p["rate"], 1e-300) for p in per]), rms_rec),
              "with_time": _corr([p["t_start"] for p in per], rms_rec),
              "with_amplitude": _corr([p["amplitude"] for p in per], rms_rec)}
    out = {"per_recording": per, "per_branch": branches, "per_input_range": by_input, "growth": growth,
           "worst_recording": per[int(np.argmax(rms_rec))]["name"], "repeat": None}
    pair = _repeat_pair(ex)
    if pair is not None:
        a, b = (ex.recordings[i] for i in pair)
        diff = rms(b.y - a.y)
        out["repeat"] = {"original": a.name, "repeat": b.name, "data_difference_rms": diff,
                         "expected_from_noise": math.sqrt(2) * noise,
                         "residual_rms_original": per[pair[0]]["residual_rms"],
                         "residual_rms_repeat": per[pair[1]]["residual_rms"]}
    return out


# --------------------------------------------------------------------------- result
@dataclass
class Diagnosis:
    """Result of `diagnose`; ``to_json()`` is the stable ``--json`` output."""

    noise_rms: float
    verdict: str               # "effects_found", "nothing_missing" or "unexplained"
    baseline: dict
    mismatch: dict
    candidates: list
    findings: list
    extended: dict
    validation: dict | None
    comparison: str
    paragraph: str
    base_model: object
    extended_model: object
    baseline_output: np.ndarray = field(repr=False, default=None)
    extended_output: np.ndarray = field(repr=False, default=None)

    def to_json(self) -> dict:
        return {"verdict": self.verdict, "noise_rms": self.noise_rms, "baseline": self.baseline, "mismatch": self.mismatch,
                "findings": self.findings, "candidates": self.candidates, "extended": self.extended,
                "validation": self.validation, "comparison": self.comparison, "summary": self.paragraph,
                "base_model": self.base_model.to_dict(), "extended_model": self.extended_model.to_dict()}


def _per_recording_nrmse(ex: JoinedExperiment, yhat: np.ndarray) -> dict:
    return {r.name: nrmse(ex.y[ex.part(i)], yhat[ex.part(i)]) for i, r in enumerate(ex.recordings)}


def _summary(ex: JoinedExperiment, model_fit: _Fit, noise: float) -> dict:
    yhat = ex.y - model_fit.residual
    return {"nrmse": nrmse(ex.y, yhat), "residual_rms": rms(model_fit.residual),
            "noise_ratio": rms(model_fit.residual) / noise if noise else None,
            "nrmse_per_recording": _per_recording_nrmse(ex, yhat)}


# --------------------------------------------------------------------------- the procedure
def diagnose(recordings: Sequence[Recording], *, model=None, progress: Progress | None = None,
             candidates: Sequence[str] = CANDIDATES, alpha: float = ALPHA, max_findings: int = 2,
             base_order: int | None = 1) -> Diagnosis:
    """Diagnose one experiment; see the module docstring for the procedure.

    Parameters
    ----------
    recordings : the experiment's recordings, in time order, on one clock.
    model : optional base model (`RateIndependentModel` or `RateDependentModel`); its A, B, E, x0 are
        refined on the experiment.
    base_order : without `model`: 1 (default) fits the first-order rate-independent base here (fast;
        every candidate fit refits its 7 parameters); any other value (None = chosen by BIC) takes the
        base from `fitter.identification.fit.fit_recordings(recordings, kind="ri", order=base_order)`, which is then
        refined like a given model (more parameters: slower, and a flexible base absorbs part of what
        an effect would explain).
    progress : optional callback ``progress(message, fraction_done)``; see `rich_progress`.
    candidates : effect names to test (default all of `fitter.core.effects.EFFECTS`).
    alpha : family-wise significance level (Bonferroni over the candidates).
    max_findings : most effects added to the model.

    Raises
    ------
    DiagnoseError : too few samples, an input that never reverses, recordings of different columns,
        overlapping clocks, non-finite values.
    """
    report = progress or (lambda msg, frac: None)
    unknown = [c for c in candidates if c not in EFFECTS]
    if unknown:
        raise DiagnoseError(f"unknown candidate effect {unknown[0]!r} (known: {', '.join(EFFECTS)})")
    ex = _experiment(recordings)
    mask = np.ones(len(ex.t), bool)
    report("fitting the base model", 0.0)
    noise = float(np.median([noise_rms(r.y) for r in ex.recordings if len(r.y) >= 14]))
    if model is None and base_order != 1:
        from fitter.identification.fit import fit_recordings
        model = fit_recordings(ex.recordings, kind="ri", order=base_order).model
    base = _fit_base(ex, model, mask)
    mismatch = locate_mismatch(ex, base.residual, noise)
    n_steps = len(candidates) * 2 + 4
    done = [1]

    def tick(msg):
        done[0] += 1
        report(msg, min(done[0] / n_steps, 0.99))

    current, findings, tested, fits = base, [], [], {}
    fixed: list[Effect] = list(base.family.fixed)
    remaining = list(candidates)
    while remaining and len(findings) < max_findings:
        round_results = []
        cur_rss = current.rss
        for name in remaining:
            tick(f"testing {name}")
            fam = _Family(base.family.template, [name], fixed)
            fit = _fit_family(fam, current.theta[:fam.n_base], ex, mask, ex.y - current.residual)
            rep = _effect_report(fit, cur_rss, _n_eff(fit.residual), len(EFFECTS[name]))
            rep["effect"] = name
            rep["significant"] = bool(rep["p_value"] < alpha / len(candidates)
                                      and rep["explained_fraction"] >= MIN_EXPLAINED)
            round_results.append((rep, fit))
        round_results.sort(key=lambda rf: rf[1].rss)
        if not findings:
            tested = [dict(r, rank=j + 1) for j, (r, _) in enumerate(round_results)]
            fits = {r["effect"]: f for r, f in round_results}
        winner = next(((r, f) for r, f in round_results if r["significant"]), None)
        if winner is None:
            break
        rep, fit = winner
        findings.append({k: rep[k] for k in ("effect", "p_value", "parameters", "stderr", "explained_fraction",
                                             "residual_rms", "lr", "df", "n_eff")})
        fixed = fixed + fit.family.effect_params(fit.theta)
        current = fit
        remaining = [c for c in remaining if c != rep["effect"]]
        if rms(current.residual) <= NOISE_MARGIN * noise:
            break
    tick("checking on held-out data")
    validation, comparison = _validate(ex, base, findings, tested, fits, mask, noise)
    ext_model = current.model
    ext_model.fit_info = {"method": "duhem diagnose", "effects": [f["effect"] for f in findings],
                          "noise_rms": noise}
    extended = dict(_summary(ex, current, noise), effects=[e.to_dict() for e in ext_model.effects])
    baseline = _summary(ex, base, noise)
    report("done", 1.0)
    if findings:
        verdict = "effects_found"
    elif baseline["residual_rms"] <= NOISE_MARGIN * noise:
        verdict = "nothing_missing"
    else:
        verdict = "unexplained"
    diag = Diagnosis(noise_rms=noise, verdict=verdict, baseline=baseline, mismatch=mismatch, candidates=tested,
                     findings=findings, extended=extended, validation=validation, comparison=comparison,
                     paragraph="", base_model=base.model, extended_model=ext_model,
                     baseline_output=ex.y - base.residual, extended_output=ex.y - current.residual)
    diag.paragraph = _paragraph(diag, ex)
    return diag


def _validate(ex: JoinedExperiment, base: _Fit, findings: list, tested: list, fits: dict, mask: np.ndarray,
              noise: float) -> tuple[dict | None, str]:
    """Hold out the last recording: refit base (+ winner, + runner-up) on the rest, predict it."""
    if len(ex.recordings) < 2 or not findings:
        return None, ""
    held = ex.recordings[-1].name
    train = mask.copy()
    train[ex.part(len(ex.recordings) - 1)] = False
    hold = ~train
    out = {"held_out": held}
    names = [findings[0]["effect"]]
    runner = next((c for c in tested if c["effect"] != names[0]), None)
    if runner is not None:
        names.append(runner["effect"])
    base_hold = _fit_family(_Family(base.family.template, [], base.family.fixed), base.theta, ex, train,
                            ex.y - base.residual)
    out["base"] = rms(base_hold.residual[hold])
    for name in names:
        f = fits[name]
        fit = _fit_family(f.family, f.theta[:f.family.n_base], ex, train, ex.y - f.residual)
        out[name] = rms(fit.residual[hold])
    win = names[0]
    text = f"{win} leaves a residual of {findings[0]['residual_rms']:.3g} (noise {noise:.3g})"
    if runner is not None:
        text += (f"; the runner-up {runner['effect']} leaves {runner['residual_rms']:.3g}"
                 f" (explains {100 * runner['explained_fraction']:.0f}% against "
                 f"{100 * findings[0]['explained_fraction']:.0f}%)")
        text += (f". Refitted without {held}, {win} predicts it with a residual of {out[win]:.3g}, "
                 f"{runner['effect']} with {out[runner['effect']]:.3g}, the base model with {out['base']:.3g}")
        worst = _where_differs(ex, fits[win].residual, fits[runner["effect"]].residual)
        text += f". The runner-up's extra error is largest {worst}"
        out["confirmed"] = bool(out[win] < out["base"] and out[win] <= out[runner["effect"]])
        if not out["confirmed"]:
            text += (f". Caution: on the held-out run {win} does not predict better than "
                     f"{'the base model' if out[win] >= out['base'] else runner['effect']}, so the hold-out "
                     "check does not confirm it")
    else:
        out["confirmed"] = bool(out[win] < out["base"])
    return out, text


def _where_differs(ex: JoinedExperiment, r_win: np.ndarray, r_run: np.ndarray) -> str:
    extra = r_run ** 2 - r_win ** 2
    per = [(float(np.sum(extra[ex.part(i)])), r.name) for i, r in enumerate(ex.recordings)]
    rec = max(per)[1]
    du = np.r_[0.0, np.diff(ex.u)]
    held = np.abs(du) <= 1e-9 * np.ptp(ex.u)
    parts = {"while the input holds": float(np.sum(extra[held])) / max(held.sum(), 1),
             "while the input moves": float(np.sum(extra[~held])) / max((~held).sum(), 1)}
    where = max(parts, key=parts.get) if held.any() else "while the input moves"
    return f"in {rec} and {where}"


def _paragraph(d: Diagnosis, ex: JoinedExperiment) -> str:
    b, e = d.baseline, d.extended
    m = d.mismatch
    text = (f"The base model leaves a residual of {b['residual_rms']:.3g} RMS against a noise level of "
            f"{d.noise_rms:.3g} estimated from the data ({_times(b['residual_rms'], d.noise_rms)}); "
            f"the largest mismatch is in {m['worst_recording']}.")
    g = m["growth"]
    trends = [f"{'increases' if v > 0 else 'decreases'} with {k.split('_')[1]} (r = {v:.2f})"
              for k, v in g.items() if v is not None and abs(v) >= 0.7]
    if trends and b["residual_rms"] > NOISE_MARGIN * d.noise_rms:
        text += " Across recordings it " + ", ".join(trends) + "."
    rep = m.get("repeat")
    if rep:
        text += (f" The repeated run {rep['repeat']} differs from {rep['original']} by {rep['data_difference_rms']:.3g}"
                 f" RMS (noise alone: {rep['expected_from_noise']:.3g}).")
    if not d.findings and d.verdict == "nothing_missing":
        return text + " No candidate effect explains a significant part of it: nothing is missing."
    if not d.findings:
        best = d.candidates[0] if d.candidates else None
        more = (f" (the best, {best['effect']}, explains {100 * best['explained_fraction']:.0f}%, "
                f"p = {best['p_value']:.2g} with an effective sample size of {best['n_eff']:.0f})") if best else ""
        return text + (" The residual is above the noise, but no candidate effect explains a significant part of "
                       f"it{more}: what is missing is not in the catalogue (or the base model is too simple).")
    for f in d.findings:
        params = ", ".join(f"{k} = {v:.3g} ± {f['stderr'][k]:.2g}" for k, v in f["parameters"].items())
        text += (f" The model had no {f['effect'].replace('_', ' ')}; adding it ({params}) removes "
                 f"{100 * f['explained_fraction']:.0f}% of the residual ({_p_text(f['p_value'])}).")
    if d.comparison:
        text += " " + d.comparison + "."
    text += (f" The extended model leaves {e['residual_rms']:.3g} RMS ({_times(e['residual_rms'], d.noise_rms)}); "
             f"NRMSE {100 * b['nrmse']:.2f}% -> {100 * e['nrmse']:.2f}%.")
    return text


def _p_text(p: float) -> str:
    return "p < 1e-300" if p == 0 else f"p = {p:.2g}"


def _times(value: float, noise: float) -> str:
    if noise <= 0:
        return "no noise level"
    ratio = value / noise
    if ratio > 100:
        return "over 100 times the noise: a systematic misfit"
    return f"{ratio:.2f} times the noise"


# --------------------------------------------------------------------------- progress
@contextmanager
def rich_progress(description: str = "diagnosing") -> Iterator[Progress]:
    """A rich progress bar as a `diagnose` progress callback (on stderr)."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress as RichProgress, TextColumn, TimeElapsedColumn

    with RichProgress(TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(),
                      console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(description, total=1.0)

        def update(message: str, fraction: float) -> None:
            bar.update(task, completed=fraction, description=f"{description}: {message}")

        yield update


# --------------------------------------------------------------------------- demonstration data
TRUTH_BASE = dict(a_plus=-3.0, a_minus=3.0, b_plus=3.0, b_minus=-3.0, e_plus=-1.5, e_minus=-1.5, x0=-1 / 6)
DEFAULT_RUNS = ((40.0, 1.0), (8.0, 1.0), (2.0, 1.0), (40.0, 1.0))
STRENGTH = {"backlash": "b", "rate_dependence": "alpha", "creep": "k", "viscous": "c",
            "thermal_drift": "kappa", "saturation": "beta", "sensor_lag": "tau"}


def _runs_signal(runs, samples: int, cycles: int, hold: float, gap: float):
    """Trapezoidal triangles (holds of fraction `hold` at each tip), each run starting and ending at -amplitude."""
    ts, us = [], []
    t0 = 0.0
    for period, amp in runs:
        duration = cycles * period
        t = t0 + np.linspace(0.0, duration, samples)
        phase = ((t - t0) / period) % 1.0
        ramp = (1 - 2 * hold) / 2
        knots = np.array([0.0, hold / 2, hold / 2 + ramp, 1.5 * hold + ramp, 1.5 * hold + 2 * ramp, 1.0])
        u = amp * np.interp(phase, knots, [-1, -1, 1, 1, -1, -1])
        ts.append(t)
        us.append(u)
        t0 = t[-1] + gap
    return ts, us


def _effect_for(name: str, strength: float, y_mid: float) -> Effect:
    params = {"backlash": {"b": strength}, "rate_dependence": {"alpha": strength},
              "creep": {"k": strength, "tau": 3.0}, "viscous": {"c": strength},
              "thermal_drift": {"kappa": strength}, "saturation": {"y_c": y_mid, "beta": strength},
              "sensor_lag": {"tau": strength}}[name]
    return Effect(name, params)


def synthetic_experiment(effect: str | None = None, *, seed: int = 0, samples: int = 3000,
                         runs: Sequence[tuple[float, float]] = DEFAULT_RUNS, cycles: int = 2,
                         size: float = 0.02, snr: float = 15.0, hold: float = 0.1,
                         gap: float = 1.0, base: dict | None = None) -> tuple[list[Recording], dict]:
    """An experiment generated by the project's simulator with one effect concealed.

    Base: first-order rate-independent model `TRUTH_BASE` (loop between u = -1 and 1, y range about 2,
    x0 on the settled loop at u = -1), or `base` (the keyword arguments of `_ri1`).
    Each run (period s, amplitude) is `cycles` trapezoidal triangles with holds of fraction `hold` at the
    tips, `samples` samples, `gap` seconds apart; the last default run repeats the first.  The effect's
    strength is set (bisection) so that max |y_with - y_without| = `size` times the output range; white
    Gaussian noise of RMS (size x range) / `snr` is added (seeded).  Returns (recordings, truth), truth a
    JSON-able dict with the base model, the effect and the noise level.
    """
    ts, us = _runs_signal(runs, samples, cycles, hold, gap)
    t, u = np.concatenate(ts), np.concatenate(us)
    base = _ri1(**(base or TRUTH_BASE))
    y0 = simulate(base, t, u).y
    yrange = float(np.ptp(y0))
    truth = {"base_model": base.to_dict(), "effect": None, "seed": seed, "size": size, "snr": snr}
    model = base
    if effect is not None:
        mid = float((y0.max() + y0.min()) / 2)

        def deviation(s):
            m = RateIndependentModel(**{k: getattr(base, k) for k in base.PARAMS},
                                     effects=[_effect_for(effect, s, mid)])
            return float(np.max(np.abs(simulate(m, t, u).y - y0))), m

        lo, hi = 1e-8, 1.0
        while deviation(hi)[0] < size * yrange:
            hi *= 4
        for _ in range(50):
            mid_s = math.sqrt(lo * hi)
            if deviation(mid_s)[0] < size * yrange:
                lo = mid_s
            else:
                hi = mid_s
        model = deviation(hi)[1]
        truth["effect"] = model.effects[0].to_dict()
    y = simulate(model, t, u).y
    sigma = size * yrange / snr
    y = y + np.random.default_rng(seed).normal(0.0, sigma, len(y))
    truth["noise_rms"] = sigma
    recs, i = [], 0
    for j, (tt, (period, amp)) in enumerate(zip(ts, runs)):
        n = len(tt)
        name = f"run{j + 1}_{1 / period:g}Hz_{amp:g}" + ("_repeat" if j and (period, amp) == tuple(runs[0]) else "")
        recs.append(Recording(t=t[i:i + n], u=u[i:i + n], y=y[i:i + n], name=name, source=f"{name}.csv"))
        i += n
    return recs, truth

