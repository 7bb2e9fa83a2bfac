"""The base model of a diagnosis, made adequate before any effect is tested (step 1 of
`fitter.diagnosis.procedure`).

By default the first-order rate-independent model (eqs (1)-(2) with C = 1, D = 0, fitted by
`fitter.diagnosis.fitting.fit_base`) or the order `duhem fit` chooses (BIC over orders 1-4,
`fitter.identification.fit.fit_recordings`; separate runs levelled to one instrument zero,
`fitting.duhem_fit`).  The higher order is the base when it brings the residual to the noise and the
first-order base with its best effect does not (a missing order is not "explained" by whichever effect absorbs
it), and of the orders 2 .. n that bring it there settled, the lowest (`_settled_lower_order`: BIC may pick an
order above one that is already adequate, unless that one leaves a structured residual where the order BIC
picks leaves a white one); when both do, the one that predicts the held-out last recording better (an effect
is not hidden by an extra order that fits as well but generalises worse; one recording: the lower BIC); a
higher order that leaves a misfit above the noise is not taken alone (the misfit is then physics for the
effects to explain), unless the first-order account fails (`fitter.diagnosis.procedure`'s higher-order
account).  On a base below the order `duhem fit` chooses, the reversing effects (switching) are not tested
(`below_order`): they add a hysteretic state and there stand in for the states the base lacks.

A higher order that reaches the noise with a loop still far from settled when the experiment ends
(`_unsettled_rms` beyond `NOISE_MARGIN` times the noise: a rate-independent base fits a drift of the output
with a loop that keeps moving) counts as one that leaves a misfit, unless a lower order 2 .. n - 1 reaches
the noise settled (`_settled_lower_order`: the unsettled loop is then a mode the data do not determine, not
a drift, and that order is the base); and the first-order base with its best effect is not preferred when
it leaves a structured residual and the higher order a white one.  The base's A, B, E (per branch) and x0
are refined (`fitter.diagnosis.fitting.fit_base`).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from fitter.core.effects import REGISTRY
from fitter.core.errors import DuhemError, KernelError
from fitter.core.kernel import simulate
from fitter.core.periodic import fixed_point
from fitter.data.cycles import closed_last_cycle
from fitter.data.metrics import rms
from fitter.diagnosis.experiment import DiagnoseError, JoinedExperiment
from fitter.diagnosis.fitting import Fit, duhem_fit, fit_family
from fitter.diagnosis.held_out import held_out_residual
from fitter.diagnosis.rounds import bic, candidate_round
from fitter.diagnosis.statistics import NOISE_MARGIN, remainder_report
from fitter.identification.explained import EXPLAINED_MIN
from fitter.identification.fit import FitResult
from fitter.identification.fit_data import PERIODIC_SPREAD, extremes_spread

__all__ = ["adequate_base", "below_order", "check_explains"]


def adequate_base(
    ex: JoinedExperiment,
    first: Fit,
    mask: np.ndarray,
    noise: float,
    candidates: Sequence[str],
    alpha: float,
    tick: Callable[[str], None],
) -> tuple[Fit, list | None, tuple | None, bool]:
    """The base (module docstring), when it is the first-order base its first round of candidate
    tests (reused by the search), the higher-order alternative (its fit and parameter count, for the
    procedure's higher-order account) and whether the base is below the order `duhem fit` chooses (its
    candidates then `below_order`).

    The order-n base is taken only when it alone is adequate (residual within `NOISE_MARGIN` of the
    noise): otherwise the misfit is more than a missing order, and the first-order base stays for the
    effects to explain.  When the first-order base with its best significant effect is adequate too, both
    accounts are refitted without the last recording and predict it: the lower hold-out error wins (two
    accounts that fit equally well, e.g. an extra order and backlash, are told apart by how they
    generalise to another rate or amplitude).  With a single recording the lower BIC wins (parameters:
    7 for the first-order base plus the effect's; for the order-n base its canonical parameters
    (`fit_recordings`) plus its n initial states)."""
    if rms(first.residual) <= NOISE_MARGIN * noise:
        return first, None, None, False
    tick("choosing the base order (BIC)")
    higher, high = duhem_fit(ex, mask)
    order = higher.model.order
    if order == 1:
        return first, None, None, False
    k_high = _parameters(higher, order)
    lower = _settled_lower_order(ex, mask, noise, order)
    if not _settled_at_noise(high, ex, noise):
        return (lower[1], None, None, True) if lower is not None else (first, None, (high, k_high), True)
    lowered = lower is not None and (_structured(ex, high, mask, alpha) or not _structured(ex, lower[1], mask, alpha))
    if lowered:
        (higher, high), order = lower, lower[0].model.order
        k_high = _parameters(higher, order)
    below = below_order(candidates)
    results = candidate_round(ex, first, below, mask, alpha, len(below), tick)
    best = next((f for r, f in results if r["significant"]), None)
    if (
        best is None
        or rms(best.residual) > NOISE_MARGIN * noise
        or _structured(ex, best, mask, alpha)
        and not _structured(ex, high, mask, alpha)
    ):
        return high, None, None, lowered
    if len(ex.recordings) > 1:
        better = _held_out_rms(ex, best, mask) < _held_out_rms(ex, high, mask)
    else:
        better = bic(best, best.family.size) < bic(high, k_high)
    return (first, results, None, True) if better else (high, None, None, lowered)


def _parameters(fit: FitResult, order: int) -> int:
    """The parameters of the order-`order` candidate of `fit` (`fit_recordings`) plus its `order` initial states."""
    return next(c["parameters"] for c in fit.summary["candidates"] if c["order"] == order) + order


def below_order(candidates: Sequence[str]) -> list[str]:
    """The candidates tested on a base below the order `duhem fit` chooses: not the reversing effects
    (`EffectSpec.reverses`), which add a hysteretic state and on such a base stand in for the states it
    lacks (switching fitted a Bouc-Wen loop's shape, and its drift with it, on a first-order base)."""
    return [c for c in candidates if not REGISTRY[c].reverses]


def _settled_at_noise(fit: Fit, ex: JoinedExperiment, noise: float) -> bool:
    """Whether a base leaves a residual within `NOISE_MARGIN` of the noise with a loop settled when the
    experiment ends (`_unsettled_rms` within the same margin): an adequate base (module docstring)."""
    return bool(rms(fit.residual) <= NOISE_MARGIN * noise and _unsettled_rms(fit, ex) <= NOISE_MARGIN * noise)


def _settled_lower_order(
    ex: JoinedExperiment, mask: np.ndarray, noise: float, order: int
) -> tuple[FitResult, Fit] | None:
    """The lowest order 2 .. `order` - 1 whose base (`fit_recordings` at that order, as ``duhem fit --order``)
    is adequate (`_settled_at_noise`), or None: the base is the lowest adequate order.  When the order BIC picks
    reaches the noise only with a loop that is not settled (a mode the data do not determine), a lower order
    that reaches it settled is the base, and the misfit is not handed to the effects; when it reaches the noise
    settled, a lower order that does too is its account (an order-2 truth with noise on its input: BIC picked
    order 3, settled or not depending on where its fit ended)."""
    for k in range(2, order):
        result, fit = duhem_fit(ex, mask, k)
        if _settled_at_noise(fit, ex, noise):
            return result, fit
    return None


def _structured(ex: JoinedExperiment, fit: Fit, mask: np.ndarray, alpha: float) -> bool:
    """Whether `fit` leaves a structured residual (`statistics.remainder_report`): not white noise."""
    return remainder_report(ex, fit.residual, mask, alpha)["structured"]


def _unsettled_rms(fit: Fit, ex: JoinedExperiment) -> float:
    """How far the base of `fit` is from settled when the experiment ends: the RMS over the last full input
    cycle (closed, `fitter.data.cycles.closed_last_cycle`) of its output from its state there minus its output
    from that cycle's periodic state (the fixed point of its period map); inf when the cycle's map does not
    converge, 0 without a full cycle.  A rate-independent base that fits a change in time
    (a drift of the output) does so with a loop that never settles: large here although its residual is
    at the noise.  An input that does not repeat one cycle (a general input, as `duhem fit` reads it:
    `fitter.identification.fit_data.extremes_spread` above `PERIODIC_SPREAD`) has no settled loop to be far
    from: 0 (its last "cycle" between two reversals is not a period, and the fixed point of its map is not a
    state the experiment was heading for)."""
    model, run = fit.model, ex.runs()[-1]
    t, u = ex.t[run], ex.u[run]
    if extremes_spread(u) > PERIODIC_SPREAD:
        return 0.0
    try:
        cycle, tc, uc = closed_last_cycle(t, u)
    except DuhemError:
        return 0.0
    x0 = fit.result.x0s[-1] if ex.separate else None
    with np.errstate(all="ignore"):
        try:
            state = simulate(model, t, u, x0=x0).x[cycle.start]
            settled, rho = fixed_point(model, tc, uc)
            if settled is None or not rho < 1:
                return np.inf
            return rms(simulate(model, tc, uc, x0=state).y - simulate(model, tc, uc, x0=settled).y)
        except (KernelError, np.linalg.LinAlgError):
            return np.inf


def _held_out_rms(ex: JoinedExperiment, fit: Fit, mask: np.ndarray) -> float:
    """RMS error on the last recording of `fit`'s family refitted on the others: from the best of its effects'
    starts (`fit_family`), or for refined effects (the procedure's refined findings) from `fit`'s values
    (`fitter.diagnosis.held_out.held_out_residual`, once per fit)."""
    last = len(ex.recordings) - 1
    fam = fit.family
    if any(par.refinement for _, par in fam.keys):
        return rms(held_out_residual(ex, fit, mask, last))
    train = mask.copy()
    train[ex.part(last)] = False
    again = fit_family(fam.base.template, fam.effects, fit.theta[: fam.n_base], ex, train, ex.y - fit.residual)
    return rms(again.residual[~train])


def check_explains(ex: JoinedExperiment, base: Fit) -> None:
    """Refuse an experiment whose output the base does not relate to its input: a recording where the base explains
    less than `EXPLAINED_MIN` of the output's variance (R^2 = 1 - SSE / SST on its samples,
    `fitter.identification.explained`, the test by which `duhem fit` refuses to save a model of noise).  Its
    output looks like noise: there is no model to say anything is missing from, and "nothing missing" would read as
    a model that fits."""
    for i, rec in enumerate(ex.recordings):
        y, r = ex.y[ex.part(i)], base.residual[ex.part(i)]
        sst = float(np.sum((y - np.mean(y)) ** 2))
        r2 = 1.0 - float(np.sum(r**2)) / sst if sst > 0 else 1.0
        if not r2 >= EXPLAINED_MIN:
            raise DiagnoseError(
                f"{rec.label}: the base model explains {max(r2, 0.0):.3g} of the output's variance (R^2; at least "
                f"{EXPLAINED_MIN:g} for a model that relates the output to the input): the output looks like noise, "
                "with nothing the input drives to diagnose; check the --input and --output columns"
            )
