"""Output-error fits of the diagnosis: the base model and each candidate effect.

Every fit is `fitter.identification.refine.refine` on the joined
experiment as one recording (x0 = "model": the initial state is part of
theta) or, for separate runs (`JoinedExperiment.separate`), on each recording
alone with its initial state fitted to it (x0 = "fit"; theta's x0 is then
held, and a fit's model carries the first recording's initial state; the effect chain of a recording that
is one closed loop, `fitter.data.cycles.closed_loop`, and no longer than its share of `SAMPLES`, starts from its state
settled on it, as `duhem fit --effects` starts it: `fitter.identification.effects_fit`; longer runs are decimated
for the optimisation, `SAMPLES`), with
the mask as 0/1 weights, residuals normalised by the output range and the
tolerances of `OPTIONS` (`problem`).  Separate runs each carry their
instrument's zero: every recording but the first has its output reference
fitted with its initial state (``Recordings.references``; the first's is the
base's own, its E), a property of the measurement, not of the material.  The parametrisation (`family`) is
`WithEffects(StateSpace(template), effects, ctx)`: the template's free
matrices and x0, then the candidate effects' parameters (registry order; a
``log`` parameter such as a time constant enters as its logarithm; a
``refinement`` parameter such as the switching thresholds' spread is held at its
default: the diagnosis tests each effect's basic form); the template's own
effects (those already found) are kept fixed.

Base model (`fit_base`): a first-order rate-independent model, eqs (1)-(2)
with C = 1, D = 0 (D is redundant at order 1): a grid over A+ = -A- < 0 (both
branches converge, condition (5)) with B+-, E+-, x0 (one per run) solved by
linear least squares, since the output is affine in them for fixed A, then a joint
nonlinear least-squares refinement; or a given model whose A, B, E (per
branch) and x0 are refined.

Candidates (`fit_family`): the base parameters and the effect's parameters
fitted jointly, started from the best of the effect's starting values.

Which base parameters move (`free_base`): all seven of a first-order
rate-independent base; for any other base (a given model, or one of order
2-4 from `fit_recordings`, already fitted by output error) its A matrices
(A+, A-, or A) are held and B, E and x0 move.  A full state-space A of order 3
adds 18 redundant directions (similarity transforms) to every candidate fit,
which made the diagnosis with an order-3 base take many minutes; with A held
the base refit and every candidate stay small problems, and the base and each
candidate are compared with the same freedom of the base.

Bounds: the effects' fitting bounds from the registry (`EffectSpec.bounds`);
for a first-order rate-independent base, A+ <= 0 <= A- (both branches
converge, condition (5)) and |A| <= 1000 / input range.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from fitter.core.effects import REGISTRY, EffectContext
from fitter.core.kernel import simulate
from fitter.core.models import RateIndependentModel, Signals
from fitter.data.cycles import closed_loop
from fitter.data.recordings import Recording
from fitter.diagnosis.experiment import JoinedExperiment
from fitter.identification.fit import FitResult, fit_recordings
from fitter.identification.output_error import Recordings
from fitter.identification.refine import Options, RefineResult, refine
from fitter.identification.parametrisation import StateSpace, WithEffects

__all__ = [
    "Fit",
    "duhem_fit",
    "family",
    "fit_base",
    "fit_family",
    "fit_per_recording",
    "joint_refit",
    "first_order_ri",
    "free_base",
    "problem",
    "jacobian_rows",
    "output_references",
    "refit",
    "with_refinements",
    "OPTIONS",
]

OPTIONS = Options(xtol=1e-7, ftol=1e-7, gtol=1e-8, max_samples=None, normalise=True)
"""Tolerances of every diagnosis fit; the budget is 30 (free parameters + 1) evaluations."""


SAMPLES = 2400
"""The samples every fit of separate runs optimises on: a run longer than its share (`SAMPLES` / runs) is decimated
for the optimisation (`fitter.identification.output_error`, "Decimation": every input reversal kept to within a
block), its residuals and statistics taken on every sample; on one clock every sample is optimised."""

REFINE_STEPS = 60
"""Steps of the joint refinement of `with_refinements` (a quarter of it for each start's screen): its
families are the largest of the diagnosis (switching refined: 12 parameters and the base's B, E)."""


@dataclass
class Fit:
    """A refinement of `family` on the experiment: residual y - yhat on every sample, the mask fitted."""

    family: WithEffects
    result: RefineResult
    mask: np.ndarray
    separate: bool = False
    steps: int | None = None
    """The iteration budget the fit had (None: the default of `_refine`); its refits (`refit`) have the same."""
    held_out: dict = field(default_factory=dict, repr=False, compare=False)
    """Residuals of each recording predicted by this fit refitted without it, by (recording, mask)
    (`fitter.diagnosis.held_out.held_out_residual`)."""

    @property
    def theta(self) -> np.ndarray:
        return self.result.theta

    @property
    def residual(self) -> np.ndarray:
        return np.concatenate(self.result.residuals)

    @property
    def rss(self) -> float:
        """Residual sum of squares over the fitted samples (`mask`)."""
        return self.result.rss

    @property
    def model(self):
        """The fitted model; for separate runs with the initial state fitted to the first recording."""
        if self.separate:
            return self.result.model.replace(x0=self.result.x0s[0])
        return self.result.model


def first_order_ri(
    a_plus: float,
    a_minus: float,
    b_plus: float,
    b_minus: float,
    e_plus: float,
    e_minus: float,
    x0: float,
    signals: Signals | None = None,
) -> RateIndependentModel:
    """The first-order rate-independent model dx = (A+- x + B+- u + E+-) du, y = x (C = 1, D = 0)."""
    return RateIndependentModel(
        A_plus=[[a_plus]],
        A_minus=[[a_minus]],
        B_plus=[b_plus],
        B_minus=[b_minus],
        C=[1.0],
        E_plus=[e_plus],
        E_minus=[e_minus],
        x0=[x0],
        signals=signals or Signals(),
    )


def _base_bounds(template, ex: JoinedExperiment) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A+ in [-a_max, 0], A- in [0, a_max] for a first-order RI template; otherwise unbounded."""
    if not (isinstance(template, RateIndependentModel) and template.order == 1):
        return None, None
    a_max = 1e3 / max(np.ptp(ex.u), 1e-300)
    lo, hi = np.full(7, -np.inf), np.full(7, np.inf)
    lo[:2], hi[:2] = [-a_max, 0.0], [0.0, a_max]
    return lo, hi


def family(
    template, effects: Sequence[str], ex: JoinedExperiment, ctx: EffectContext | None, refinements: bool = False
) -> WithEffects:
    """The parametrisation of `template` extended by `effects` (module docstring; `refinements`: the effects'
    refinement parameters fitted too, `with_refinements`)."""
    return WithEffects(StateSpace(template, *_base_bounds(template, ex)), effects, ctx, refinements=refinements)


def free_base(fam: WithEffects) -> np.ndarray | None:
    """The entries of theta that move (module docstring): None (all) for a first-order RI base, else all
    but the base's A matrices."""
    template = fam.base.template
    if isinstance(template, RateIndependentModel) and template.order == 1:
        return None
    held = [name.split("[")[0] in ("A_plus", "A_minus", "A") for name in fam.base.names()]
    return np.r_[~np.array(held, bool), np.ones(fam.size - fam.n_base, bool)]


def _effects_only(fam: WithEffects) -> np.ndarray:
    """The entries of theta that are the family's effect parameters (the base held)."""
    return np.r_[np.zeros(fam.n_base, bool), np.ones(fam.size - fam.n_base, bool)]


def problem(ex: JoinedExperiment, mask: np.ndarray) -> Recordings:
    """The output-error problem of every diagnosis fit (module docstring): the experiment as one recording
    (x0 = "model"), or its separate runs (x0 = "fit"), `mask` as 0/1 weights."""
    if ex.separate:
        share = _share(ex)
        return Recordings(
            list(ex.recordings),
            x0="fit",
            weights=[mask[s].astype(float) for s in ex.runs()],
            settle=[closed_loop(r) and len(r.t) <= share for r in ex.recordings],
            references=len(ex.recordings) > 1,
        )
    return Recordings([Recording(ex.t, ex.u, ex.y, "experiment")], x0="model", weights=[mask.astype(float)])


def jacobian_rows(ex: JoinedExperiment, mask: np.ndarray) -> np.ndarray:
    """The samples (indices into the joined arrays) that are the rows of a fit's Jacobian (`RefineResult.jac`):
    those of `mask` the optimisation scored (all of them, or for long separate runs their share, `SAMPLES`)."""
    rows = problem(ex, mask).rows(_share(ex))
    starts = [run.start for run in ex.runs()]
    return np.concatenate([start + r for start, r in zip(starts, rows)])


def _share(ex: JoinedExperiment) -> int | None:
    """The samples each separate run is optimised on at most (`SAMPLES`); None on one clock (all)."""
    return SAMPLES // len(ex.recordings) if ex.separate else None


def _refine(
    fam: WithEffects,
    theta0: np.ndarray,
    ex: JoinedExperiment,
    mask: np.ndarray,
    free: np.ndarray | None = None,
    iterations: int | None = None,
) -> Fit:
    """Minimise the sum over `mask` of (y - yhat(theta))^2; only the `free` entries of theta move (and
    never theta's x0 for separate runs: each run's initial state is fitted inside `problem`); at most
    `iterations` steps (default 30 (free parameters + 1); scipy's count, each step also takes one evaluation
    per free parameter for its Jacobian)."""
    if ex.separate:
        held = np.r_[[name.startswith("x0[") for name in fam.base.names()], np.zeros(fam.size - fam.n_base, bool)]
        free = ~held if free is None else free & ~held
    n_free = len(theta0) if free is None else int(np.count_nonzero(free))
    options = Options(**{**vars(OPTIONS), "max_nfev": iterations or 30 * (n_free + 1), "max_samples": _share(ex)})
    return Fit(fam, refine(fam, theta0, problem(ex, mask), options, free=free), mask, ex.separate, iterations)


def fit_family(
    template, effects: Sequence[str], base: np.ndarray, ex: JoinedExperiment, mask: np.ndarray, y_fit: np.ndarray
) -> Fit:
    """Joint fit of `template`'s parameters (from `base`) and `effects`, from the best effect start.

    The starts are screened with the base parameters held (cheap: only the
    effect parameters move); the joint fit starts from the best one.  Should
    it end above the nested model (the base with the effects switched off),
    it is refitted from there, so a candidate never explains a negative
    fraction.  `y_fit` is the output of the model the family extends.
    """
    fam = family(template, effects, ex, ex.effect_context(float(np.mean(y_fit))))
    starts = fam.starts()
    theta0 = np.r_[base, starts[0]]
    if len(starts) > 1:
        screened = [_refine(fam, np.r_[base, s], ex, mask, _effects_only(fam)) for s in starts]
        theta0 = min(screened, key=lambda f: f.rss).theta
    fit = _refine(fam, theta0, ex, mask, free_base(fam))
    null = np.r_[base, fam.null()]
    null_rss = float(np.sum(problem(ex, mask).residuals(fam, null)[0] ** 2))
    if fit.rss > null_rss * (1 + 1e-4):
        fit = _refine(fam, null, ex, mask, free_base(fam))
    return fit


def joint_refit(
    current: Fit, found: Sequence[str], name: str, start: Fit, ex: JoinedExperiment, mask: np.ndarray
) -> Fit:
    """Candidate `name` and the effects found so far (`found`, held in `fit_family`'s template) refitted
    together with the base (forward selection's joint refit) from two starts, the better kept: the found
    effects as `current` has them with the candidate as `start` (its own fit on the base, the first round)
    has it, and the other order (from `start`, the found effects fitted on top of it by `fit_family`, as if
    the candidate had been found first).  An effect found first keeps what a later candidate explains better
    unless the later one starts from its own account of the data (a relaxation spectrum that took a drift in
    time leaves a drift started at zero nothing to explain; the creep trapezoids need the first start, the
    other order alone left their drift in the spectrum; `tests/test_diagnose_joint.py` was built on the
    second).  Returned in `fit_family`'s form (the found effects in the template, the candidate's parameters in
    theta, its Jacobian there), so that the candidate's tests read it as they read `fit_family`'s."""
    ctx = ex.effect_context(float(np.mean(ex.y - current.residual)))
    names = [e for e in REGISTRY if e in found or e == name]
    own = next(e for e in start.model.effects if e.effect == name)
    other_order = fit_family(start.model, found, start.theta[: start.family.n_base], ex, mask, ex.y - start.residual)
    starts = [current.model.replace(effects=[*current.model.effects, own]), other_order.model]
    template = starts[0].replace(effects=[e for e in starts[0].effects if e.effect not in names], fit_info={})
    joint = family(template, names, ex, ctx)
    best = min((_refine(joint, joint.theta(m), ex, mask, free_base(joint)) for m in starts), key=lambda f: f.rss)
    ended = best.model
    fam = family(ended.replace(effects=[e for e in ended.effects if e.effect != name], fit_info={}), [name], ex, ctx)
    return replace(_refine(fam, fam.theta(ended), ex, mask, free_base(fam), 1), steps=None)


def fit_base(ex: JoinedExperiment, model, mask: np.ndarray) -> Fit:
    """Base fit: refine a given model, or a first-order RI model (grid over A, linear in B, E, x0)."""
    if model is not None:
        fam = family(model.replace(fit_info={}), [], ex, None)
        return _refine(fam, fam.theta(model), ex, mask, free_base(fam))
    span = max(np.ptp(ex.u), 1e-300)
    best = None
    for a in -np.geomspace(0.5, 64, 8) * 2 / span:  # inside the bounds of `_base_bounds`
        basis = _grid_basis(ex, a)
        coef, *_ = np.linalg.lstsq(basis[mask], ex.y[mask], rcond=None)
        rss = float(np.sum((ex.y[mask] - basis[mask] @ coef) ** 2))
        if best is None or rss < best[0]:
            best = (rss, a, coef)
    _, a, (bp, bm, ep, em, x0, *_) = best
    fam = family(first_order_ri(a, -a, bp, bm, ep, em, x0), [], ex, None)
    return _refine(fam, np.array([a, -a, bp, bm, ep, em, x0]), ex, mask)


def duhem_fit(ex: JoinedExperiment, mask: np.ndarray, order: int | None = None) -> tuple[FitResult, Fit]:
    """The rate-independent model `duhem fit` makes of the experiment's recordings (`fit_recordings`, kind "ri", the
    order by BIC or `order`): its `FitResult` and its base refined on the experiment (`fit_base`). Separate runs
    each carry their instrument's zero, which `duhem fit` fits where its test finds the zeros apart (its references
    are dropped here: `fit_base` fits them again); where it does not (single cycles taken as settled, zeros too
    close for its test), the fit is made again on the recordings less
    the references (`output_references`) that its first model, refined here (`fit_base`), finds (one alternation; a
    control of order 3 whose files' zeros differ by 15 % of the range got order 2 at 2.8 times the noise, then order
    3 at the noise). The levelled fit is taken when, refined on the recordings with their references (`fit_base`),
    it leaves no more than the first: references the data do not determine level the recordings by nonsense (a
    first-order base with A ~ 1e-11, the nearly straight branches of a ferroelectric loop: its state's and a
    reference's columns equal to 9e-10, split into -3.9e7 and 1.1e9; every order's levelled fit then left 1e5-1e11
    output ranges on the files, 47696 against the first fit's 6.6). The order BIC picks on the levelled recordings
    is not below the first fit's: the piezo triangles' levelled fit picked order 2, whose account with switching
    predicts the 0.01 Hz record at 11 % where order 3's does at 5 % (an order chosen by held-out prediction would
    settle this; not done: each order is a whole search). Its search optimises on the diagnosis' samples (`SAMPLES`,
    `_share`: long separate runs decimated, every input reversal kept; on one clock, or within the share, the same
    samples as `duhem fit`): on the four creep trapezoids (4 x 5000 samples) the two searches at `duhem fit`'s 3000
    samples per run took 504 s of a 937 s diagnosis."""
    share = _share(ex)
    base = {"kind": "ri", "max_samples": share, "retry_unsettled": False}
    fitted = remembered_fit(ex.recordings, order=order, **base)
    first = _unreferenced(fitted)
    refined = fit_base(ex, first.model, mask)
    refs = None if fitted.summary.get("references") else output_references(refined, ex)
    if refs is None:  # one recording, or `duhem fit` levelled the files itself
        return first, refined
    level = [Recording(r.t, r.u, r.y - refs[r.name], r.name, r.input, r.output, r.source) for r in ex.recordings]
    levelled = fit_recordings(level, order=order, references=False, **base)
    if levelled.model.order < first.model.order:
        levelled = fit_recordings(level, order=first.model.order, references=False, **base)
    again = fit_base(ex, levelled.model, mask)
    return (levelled, again) if again.rss <= refined.rss else (first, refined)


_FITS: dict[bytes, FitResult] = {}
"""The last `remembered_fit`, by its arguments' key."""


def remembered_fit(recordings: Sequence[Recording], **kwargs) -> FitResult:
    """`fit_recordings(recordings, **kwargs)`, the last call's result again when the recordings (names and samples)
    and arguments are the same: `fitter.diagnosis.calibration` fits the experiment before its base does."""
    key = _key(recordings, kwargs)
    if key not in _FITS:
        remember(recordings, fit_recordings(recordings, **kwargs), **kwargs)
    return _FITS[key]


def remember(recordings: Sequence[Recording], result: FitResult, **kwargs) -> None:
    """Keep `result` as `remembered_fit`'s for these recordings and arguments (the last one only)."""
    _FITS.clear()
    _FITS[_key(recordings, kwargs)] = result


def _key(recordings: Sequence[Recording], kwargs: dict) -> bytes:
    """`remembered_fit`'s key: the arguments, the recordings' names and samples."""
    return repr(sorted(kwargs.items())).encode() + b"".join(
        r.name.encode() + r.t.tobytes() + r.u.tobytes() + r.y.tobytes() for r in recordings
    )


def _unreferenced(fit: FitResult) -> FitResult:
    """`fit` without the output references and gains `duhem fit` found (its model's ``fit_info["references"]``,
    ``["gains"]``): the diagnosis fits each recording's reference with its own models (`fit_base`), on recordings
    already put in the model's frame by their gains (`fitter.diagnosis.calibration`)."""
    info = {k: v for k, v in fit.model.fit_info.items() if k not in ("references", "gains")}
    return replace(fit, model=fit.model.replace(fit_info=info))


def _grid_basis(ex: JoinedExperiment, a: float) -> np.ndarray:
    """Columns of the first-order base's output (A+ = a = -A-) per unit B+, B-, E+, E- and per unit initial
    state of each run (`JoinedExperiment.runs`): the output is their sum, weighted by the values."""
    runs = ex.runs()
    basis = np.zeros((len(ex.t), 4 + len(runs)))
    for r, s in enumerate(runs):
        for j in range(5):
            basis[s, j if j < 4 else 4 + r] = simulate(first_order_ri(a, -a, *np.eye(5)[j]), ex.t[s], ex.u[s]).y
    return basis


def with_refinements(fit: Fit, names: Sequence[str], ex: JoinedExperiment, mask: np.ndarray) -> Fit | None:
    """The effects `names` of `fit`'s model (found in their basic form) refitted jointly with their refinement
    parameters (`ParameterSpec.refinement`: switching's spreads and second population) and the base's free
    entries (`free_base`); None when none of `names` has a refinement.  Each refinement start of the effects'
    `EffectSpec.starts` (the basic parameters at their found values) is screened with the base held; the best is
    refined jointly (`REFINE_STEPS`)."""
    found = [e for e in fit.model.effects if e.effect in names]
    if not any(p.refinement for e in found for p in e.spec.parameters):
        return None
    kept = [e for e in fit.model.effects if e.effect not in names]
    template = fit.model.replace(effects=kept, fit_info={})
    y_fit = ex.y - fit.residual
    fam = family(template, [e.effect for e in found], ex, ex.effect_context(float(np.mean(y_fit))), True)
    combos = {}
    for combo in itertools.product(*[e.spec.starts(fam.ctx) for e in found]):
        values = [
            {p.name: (start if p.refinement else e.parameters)[p.name] for p in e.spec.parameters}
            for e, start in zip(found, combo)
        ]
        combos.setdefault(tuple(fam.encode(values)), None)
    base = fam.base.theta(template)
    screened = [_refine(fam, np.r_[base, np.array(c)], ex, mask, _effects_only(fam), REFINE_STEPS // 4) for c in combos]
    return _refine(fam, min(screened, key=lambda f: f.rss).theta, ex, mask, free_base(fam), REFINE_STEPS)


def refit(fit: Fit, ex: JoinedExperiment, mask: np.ndarray) -> Fit:
    """`fit`'s family refined on the samples of `mask`, from `fit`'s values, with the same free entries
    (`free_base`) and iteration budget (`Fit.steps`: a refined family, `with_refinements`, has
    `REFINE_STEPS`): the fit as it would have ended on that part of the data."""
    return _refine(fit.family, fit.theta, ex, mask, free_base(fit.family), fit.steps)


def output_references(fit: Fit, ex: JoinedExperiment) -> dict[str, float] | None:
    """Each separate run's output reference (its instrument's zero, `problem`) relative to the first's, by
    recording name: the mean of the fitted output minus the model's output from the run's fitted x0 (the
    first's is 0, the base's own); None for one clock or a single recording."""
    if not ex.separate or len(ex.recordings) < 2:
        return None
    model, fitted = fit.result.model, ex.y - fit.residual
    out = {}
    for k, (rec, x0) in enumerate(zip(ex.recordings, fit.result.x0s)):
        if x0 is None:
            return None
        out[rec.name] = float(np.mean(fitted[ex.part(k)] - simulate(model, rec.t, rec.u, x0=x0).y)) if k else 0.0
    return out


def fit_per_recording(fit: Fit, ex: JoinedExperiment, mask: np.ndarray) -> list[Fit]:
    """The last effect of `fit`'s family refitted on each recording alone (everything else held), started
    from the joint values: does one parameter set hold across the recordings?"""
    fam = fit.family
    return [_refine(fam, fit.theta, ex, mask & (ex.index == i), _effects_only(fam)) for i in range(len(ex.recordings))]
