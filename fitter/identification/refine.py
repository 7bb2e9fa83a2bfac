"""The output-error engine: the one least-squares fitter of the package.

`refine(param, theta0, problem, options)` minimises the simulation error

    J(theta) = sum_i sum_k w_ik (y_ik - yhat_ik(theta))^2,
    yhat_i = simulate(param.build(theta), t_i, u_i, x0=x0_i(theta)).y

with `scipy.optimize.least_squares` (trust-region reflective, parameters scaled
by the Jacobian's column norms, the bounds of the `Parametrisation`; MINPACK's Levenberg-Marquardt on
an unbounded problem whose `Options.method` asks for it).  Used by
`fit_recordings`, the diagnosis and the Section V estimator; each passes its
`Options` (tolerances, budget, decimation).  The problems it solves (residuals
of a theta, initial states, variable projection, decimation, the failure policy)
are in `fitter.identification.output_error`.

Jacobian
--------
The solver asks for J at its start and after every accepted step.  Every `Options.jacobian_refresh`-th time
it gets forward differences (scipy's own, of step `Options.diff_step`: one evaluation per moving parameter);
the times between, Broyden's rank-one secant update of the last one from the step s just accepted,

    J+ = J + (df - J s) s^T / (s^T s),    df = r(theta + s) - r(theta),

which costs no evaluation and makes J+ s = df exact (Dennis & Schnabel, Numerical Methods for Unconstrained
Optimization, 1983, Section 8.3).  The covariance below always rests on forward differences at the optimum.

A `Barrier` penalty's rows are differenced only near the barrier: where every excess is farther inside than
`Barrier.margin` at the point, no forward difference can reach the barrier, their differences are zero, and the
penalty is not evaluated at the shifted points (`_Objective.penalty_held`; the barrier's eigenvalue problems were a
third of an order search's time).  The numbers are those of differencing it.  MINPACK's method (``"lm"``)
differences by itself, penalty and all.

Compiled kernel
---------------
With `Options.compiled` the solver's evaluations run the kernel's modal pass compiled
(`fitter.core.scans.compiled_scans`, numba): numpy's closed-form sums cost some twenty array passes of numpy
calls per evaluation, which on recordings of some hundred samples is most of a fit's time.

Processes
---------
A forward-difference Jacobian's evaluations are independent: they run on up to `fitter.workers.workers()` forked
processes (`fitter.workers.evaluation_map`, scipy's ``workers``), once one Jacobian took long enough to repay a
fork; the result is the same to the last digit on any number of processes (tested).

Threads
-------
The evaluations are many small array operations: BLAS runs single-threaded
during `refine` (`fitter.workers.one_blas_thread`), since its worker threads only cost CPU on
matrices this small (measured: twice the CPU, the same wall time).

Uncertainty
-----------
J is a forward-difference Jacobian at the optimum (in output units; of the kept samples
when decimated, the information then scaled by N_all / N_kept).
sigma^2 = RSS / (N - p), cov = sigma^2 (J^T J)^+ (N / n_eff), the
pseudo-inverse taken as S (S J^T J S)^+ S with S = diag(1 / ||J_j||) (so a
parameter's error does not depend on the units of the others), n_eff the
effective sample size (N when not given; the diagnosis passes the AR(1)
value of `effective_samples` for autocorrelated residuals).
"""

from __future__ import annotations

import multiprocessing
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Iterator, Sequence

import numpy as np
from scipy.optimize import least_squares
from scipy.optimize._numdiff import approx_derivative

from fitter.core.scans import compiled_scans
from fitter.identification.parametrisation import Parametrisation
from fitter.progress import Progress, silent
from fitter.workers import evaluation_map, one_blas_thread

__all__ = ["Barrier", "Options", "RefineResult", "refine", "with_covariance", "jacobian", "effective_samples"]


@dataclass(frozen=True)
class Options:
    """Tolerances, budget and policies of `refine` (scipy ``least_squares`` names)."""

    ftol: float = 1e-6
    xtol: float = 1e-8
    gtol: float = 1e-8
    max_nfev: int | None = None
    max_samples: int | None = 6000
    normalise: bool = False
    """Divide the residuals by the data's output range (scale-free tolerances)."""
    covariance: bool = True
    """Compute the Jacobian at the optimum for `RefineResult.covariance` (with elimination, p more
    evaluations); False leaves ``jac`` zero (a start's trial run)."""
    diff_step: float | None = None
    """Relative step of the forward-difference Jacobian (scipy's ``diff_step``: h = diff_step max(1, |theta|));
    None: scipy's sqrt(eps) = 1.5e-8.  That is below the projected residuals' rounding noise: on the piezo
    triangles' rate-independent order-3 fit its Jacobian columns were 10-100 % off those of 1e-6 with
    variable projection (0.5-2 % without); 1e-6 and 1e-5 agree to 0.1-2.6 %.  Every fit keeps the default for
    now: with 1e-6 the piezo effect fit ended in a worse minimum (0.64/0.80/0.85 % against 0.40/0.55/0.68 %)
    and the base search moved the piezo diagnosis (see `compiled`); open."""
    compiled: bool = False
    """Run the evaluations on the kernel's compiled modal scan (`fitter.core.scans.compiled_scans`, numba): the
    order and kind search does (`fitter.identification.search.FIT_OPTIONS`), and so do the effect fits
    (`fitter.identification.effects_fit.OPTIONS`).  Its rounding differs from the numpy sums' by about 1e-15, and
    a fit whose minimum turns on rounding (piezo.best's rate-independent base, which leads a short race of starts)
    may end in another one: such a choice is judged on draws at rounding level (`bench/fit_rounding.py`), not on
    one run."""
    jacobian_refresh: int = 1
    """Forward differences at every `jacobian_refresh`-th Jacobian the solver asks for, Broyden's secant
    update at the others (module docstring, `SecantJacobian`); 1: differences every time (scipy's own).  The
    effect fits take 2 (`fitter.identification.effects_fit.OPTIONS`, measured there)."""
    method: str = "trf"
    """scipy's ``least_squares`` method: ``"trf"`` (trust-region reflective, with the parametrisation's bounds)
    or ``"lm"`` (MINPACK's Levenberg-Marquardt, for a problem with no bounds: its step is a QR in Fortran where
    trf's is an SVD and its bookkeeping in Python: on Example 2's records, 2-4 ms of a 17-20 ms fit with the exact
    Jacobian; the Section V estimator takes it, `fitter.identification.wave_output_error`)."""
    eliminate: bool = False
    """Eliminate the parameters in which the model is linear (`Parametrisation.linear_entries`)
    by linear least squares at every evaluation (variable projection, module docstring)."""


@dataclass(frozen=True)
class Barrier:
    """A penalty of `refine` that keeps theta inside a barrier: the rows weight max(0, e_k + inside) of the
    excesses e(theta) (each <= 0 where the model is acceptable; one that cannot be evaluated, inf or nan, gives a
    row of `weight`).  The penalty starts `inside` before each limit (a penalty of weight 1e3 lets the optimum
    overshoot its zero by about gradient / 1e3)."""

    excesses: Callable[[Any], Sequence[float]]
    inside: float
    weight: float = 1e3
    margin: float = 1e-3
    """`clear`'s distance from the penalty's start: a forward difference (a relative step of 1.5e-8) that moved an
    excess this far would need a slope of some 1e5 per unit of theta."""

    def __call__(self, theta) -> np.ndarray:
        return self.rows(self.excesses(theta))

    def rows(self, excesses: Sequence[float]) -> np.ndarray:
        """weight max(0, e + inside) per excess, `weight` where e is not finite."""
        e = np.asarray(excesses, dtype=float) + self.inside
        return np.where(np.isfinite(e), self.weight * np.maximum(e, 0.0), self.weight)

    def clear(self, theta) -> bool:
        """Whether every excess at theta is finite and more than `margin` before the penalty's start."""
        e = np.asarray(self.excesses(theta), dtype=float) + self.inside
        return bool(np.all(np.isfinite(e)) and np.all(e < -self.margin))

    def composed(self, to: Callable[[Any], Any]) -> "Barrier":
        """The same barrier of to(theta) (e.g. of a parametrisation's model)."""
        return replace(self, excesses=lambda theta: self.excesses(to(theta)))


@dataclass
class RefineResult:
    """Outcome of `refine`.

    theta: optimum; model: param.build(theta); residuals: per part, y - yhat on
    the fitted samples (from `starts[i]` on; all samples, masked ones included);
    starts, x0s, rho: per recording (see `Recordings`); states: per recording, the effect chain state it
    started from where that is not the model's own start (`simulate_from`), else None; cost: 0.5 sum w r^2 on
    all samples; jac: Jacobian of the weighted residuals (output units);
    info_scale: N_all / N_kept (decimation).
    """

    theta: np.ndarray
    model: Any
    residuals: list[np.ndarray]
    weighted: np.ndarray
    jac: np.ndarray
    nfev: int
    success: bool
    message: str = ""
    starts: list[int] = field(default_factory=list)
    x0s: list = field(default_factory=list)
    rho: list[float] = field(default_factory=list)
    states: list = field(default_factory=list)
    info_scale: float = 1.0
    budget_hit: bool = False
    """The solver stopped at its evaluation budget (`Options.max_nfev`) before its tolerances were met."""

    @property
    def rss(self) -> float:
        """Weighted residual sum of squares over the fitted samples."""
        return float(np.sum(self.weighted**2))

    @property
    def cost(self) -> float:
        return 0.5 * self.rss

    @property
    def sigma(self) -> float:
        return float(np.sqrt(self.rss / max(len(self.weighted) - len(self.theta), 1)))

    def covariance(self, n_eff: float | None = None) -> np.ndarray:
        """sigma^2 (info_scale J^T J)^+ N / n_eff (module docstring), the pseudo-inverse taken of the
        column-equilibrated J (the same in any units of the parameters)."""
        n = len(self.weighted)
        inflate = 1.0 if n_eff is None else n / max(n_eff, 1.0)
        norms = np.linalg.norm(self.jac, axis=0)
        norms = np.where(norms > 0, norms, 1.0)
        scaled = self.jac / norms
        inverse = np.linalg.pinv(self.info_scale * (scaled.T @ scaled)) / np.outer(norms, norms)
        return self.sigma**2 * inverse * inflate

    def stderr(self, n_eff: float | None = None) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance(n_eff)), 0, None))


def effective_samples(residual: np.ndarray) -> float:
    """AR(1) effective sample size N (1 - r1) / (1 + r1), r1 the lag-1 autocorrelation in [0, 0.98]."""
    r = residual - residual.mean()
    r1 = float(np.dot(r[1:], r[:-1]) / max(np.dot(r, r), 1e-300))
    r1 = min(max(r1, 0.0), 0.98)
    return len(r) * (1 - r1) / (1 + r1)


# ----------------------------------------------------------------------------- refine
def jacobian(fun: Callable[[np.ndarray], np.ndarray], theta: np.ndarray, f0: np.ndarray | None = None) -> np.ndarray:
    """Forward-difference Jacobian of a vector function, steps 1e-6 (1 + |theta_j|)."""
    f0 = fun(theta) if f0 is None else f0
    J = np.empty((len(f0), len(theta)))
    for j in range(len(theta)):
        h = 1e-6 * (1.0 + abs(theta[j]))
        th = theta.copy()
        th[j] += h
        J[:, j] = (fun(th) - f0) / h
    return J


def _scans(options: Options):
    """The kernel's pass for `options`' evaluations: `compiled_scans()` with `Options.compiled`, else none."""
    return compiled_scans() if options.compiled else nullcontext()


def refine(
    param: Parametrisation,
    theta0: np.ndarray,
    problem,
    options: Options = Options(),
    *,
    penalty: Callable[[np.ndarray], np.ndarray] | None = None,
    free: np.ndarray | None = None,
    jac: Callable[[np.ndarray], np.ndarray] | None = None,
    progress: Progress = silent,
) -> RefineResult:
    """Output-error least squares of `param.build(theta)` on `problem`.

    Parameters
    ----------
    param : the theta -> model map (its bounds are the optimisation's bounds).
    theta0 : start (moved inside the bounds by 1e-9 (1 + |theta|) where needed).
    problem : `Recordings` or any object with ``residuals(param, theta) -> (r, model, info)`` (info: per
        recording (start, x0, residual, rho, effect state), as `Recordings.residuals`),
        ``decimated(max_samples)`` and ``scale`` (output range).
    options : tolerances, budget, decimation, normalisation.
    penalty : optional theta -> extra residuals (e.g. a convergence barrier), of the theta whose residuals they
        join: with elimination, its linear entries at their least-squares values.
    free : boolean mask of the entries of theta that move (default all).
    jac : optional theta -> Jacobian of the problem's residuals in all entries of theta (a problem that
        differentiates more cheaply than by plain forward differences); not with a penalty or elimination.
    progress : `fitter.progress.Progress`, called with a one-line status at the end.
    """
    obj = _Objective(param, theta0, problem, options, penalty, free)
    lo, hi = param.bounds()
    if jac is not None and (penalty is not None or obj.lin.any()):
        raise ValueError("a problem's own Jacobian cannot be combined with a penalty or elimination")
    with (
        np.errstate(all="ignore"),
        one_blas_thread(),
        _scans(options),
        evaluation_map(obj) if jac is None else nullcontext() as mapper,
    ):
        bounds = (lo[obj.moving], hi[obj.moving])
        secant = None
        if jac is not None:

            def jac_moving(z: np.ndarray) -> np.ndarray:
                return jac(obj.full_theta(z))[:, obj.moving] / obj.scale

        elif options.method == "lm" and options.jacobian_refresh == 1:
            jac_moving = "2-point"  # MINPACK's own forward differences (lmdif)
        else:
            jac_moving = secant = SecantJacobian(obj, options.jacobian_refresh, options.diff_step, bounds, mapper)
        sol = least_squares(
            obj,
            obj.theta0[obj.moving],
            jac=jac_moving,
            bounds=bounds,
            method=options.method,
            x_scale="jac",
            diff_step=options.diff_step,
            ftol=options.ftol,
            xtol=options.xtol,
            gtol=options.gtol,
            max_nfev=options.max_nfev,
            workers=mapper,
        )
    progress(f"output-error refinement: cost {sol.cost:.4g} after {sol.nfev} evaluations", None)
    theta = obj.full_theta(sol.x)
    if obj.lin.any():
        theta = obj.coarse.projected(param, theta)[1]
    weighted, model, info = problem.residuals(param, theta)
    if not options.covariance:
        J = np.broadcast_to(0.0, (len(weighted), len(theta)))  # zero, in no memory
    elif obj.lin.any():
        J = _eliminated_jacobian(obj, theta, options)
    else:
        J_free = sol.jac.toarray() if hasattr(sol.jac, "toarray") else np.asarray(sol.jac)
        if secant is not None and not secant.differenced:
            with np.errstate(all="ignore"), one_blas_thread(), _scans(options):
                J_free = secant.differences(sol.x, obj.last(sol.x))  # on this process: the map has ended
        J_free = J_free[: len(J_free) - (0 if penalty is None else len(penalty(theta)))]
        J = np.zeros((len(J_free), len(theta)))
        J[:, obj.free] = J_free * obj.scale
    return RefineResult(
        theta=theta,
        model=model,
        residuals=[i[2] for i in info],
        weighted=weighted,
        jac=J,
        nfev=int(sol.nfev),
        success=bool(sol.success),
        message=str(sol.message),
        starts=[i[0] for i in info],
        x0s=[i[1] for i in info],
        rho=[float(i[3]) for i in info],
        states=[i[4] for i in info],
        info_scale=len(weighted) / len(J),
        budget_hit=int(sol.status) == 0,
    )


def with_covariance(
    res: RefineResult, param: Parametrisation, problem, options: Options, free: np.ndarray | None = None
) -> RefineResult:
    """`res`, refined with `options` but without `Options.covariance`, with the Jacobian (and information scale) that
    the refinement with it would have given: forward differences of the problem's residuals at ``res.theta`` in the
    free entries, the same numbers.  For a search that keeps one of several refinements: only that one needs it.
    Needs `Options.eliminate` (otherwise the refinement's Jacobian is its solver's last one)."""
    obj = _Objective(param, res.theta, problem, options, None, free)
    if not obj.lin.any():
        raise ValueError("a covariance after the refinement needs its linear entries eliminated")
    J = _eliminated_jacobian(obj, res.theta, options)
    return replace(res, jac=J, info_scale=len(res.weighted) / len(J))


def _eliminated_jacobian(obj: "_Objective", theta: np.ndarray, options: Options) -> np.ndarray:
    """The Jacobian at the optimum `theta` of a refinement with elimination: forward differences of the
    (decimated) problem's residuals in every free entry (`_free_jacobian`), zero columns for the others."""
    with _scans(options):
        J_free = _free_jacobian(obj.coarse, obj.param, theta, obj.free) / obj.scale
    J = np.zeros((len(J_free), len(theta)))
    J[:, obj.free] = J_free * obj.scale  # divided and multiplied back as the solver's Jacobian is: the same bits
    return J


class SecantJacobian:
    """The solver's Jacobian (module docstring): forward differences at the first and every `refresh`-th call,
    Broyden's update from the last call's Jacobian at the others (the last one kept when the step is zero).

    Called by ``least_squares`` at its start and after each accepted step, when the objective's last evaluation
    was at that point (`_Objective.last`: no evaluation repeated).  The differences are scipy's ``2-point`` ones
    (``approx_derivative``, what ``least_squares`` itself calls for ``jac="2-point"``: the same steps, the bounds
    kept, the columns mapped by ``workers``).
    """

    def __init__(self, objective: "_Objective", refresh: int, diff_step: float | None, bounds, workers=None):
        self.objective, self.refresh, self.diff_step = objective, refresh, diff_step
        self.bounds, self.workers = bounds, workers
        self.calls = 0
        self.differenced = True
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def differences(self, z: np.ndarray, r: np.ndarray, workers=None) -> np.ndarray:
        """Forward differences of the objective at z, where its value is r (the columns mapped by `workers`); a
        `Barrier`'s rows zero where it is clear at z (`_Objective.penalty_held`)."""
        with self.objective.penalty_held(z):
            return approx_derivative(
                self.objective, z, method="2-point", rel_step=self.diff_step, f0=r, bounds=self.bounds, workers=workers
            )

    def __call__(self, z: np.ndarray) -> np.ndarray:
        r = self.objective.last(z)
        self.differenced = self._last is None or self.calls % self.refresh == 0
        if self.differenced:
            J = self.differences(z, r, self.workers)
        else:
            z0, r0, J0 = self._last
            s = z - z0
            J = J0 + np.outer(r - r0 - J0 @ s, s / (s @ s)) if s.any() else J0
        self.calls += 1
        self._last = (z.copy(), r.copy(), J)
        return J.copy(order="K")  # the differences' own layout, as scipy's "2-point" passes it: its SVD rounds alike


class _Objective:
    """The residual function `refine` minimises, of the moving entries z of theta: theta0 moved
    inside the bounds, the problem decimated, the linear entries eliminated when asked
    (`Options.eliminate`), the penalty appended."""

    def __init__(self, param: Parametrisation, theta0, problem, options: Options, penalty=None, free=None):
        self.param, self.penalty = param, penalty
        theta0 = np.asarray(theta0, dtype=float)
        lo, hi = param.bounds()
        pad = 1e-9 * (np.abs(theta0) + 1)
        self.theta0 = np.minimum(np.maximum(theta0, lo + pad), hi - pad)
        self.free = np.ones(len(theta0), bool) if free is None else np.asarray(free, bool)
        self.coarse = problem.decimated(options.max_samples)
        self.scale = problem.scale if options.normalise else 1.0
        self.lin = np.zeros(len(theta0), bool)
        if options.eliminate and hasattr(self.coarse, "projected"):
            self.lin[list(param.linear_entries())] = True
            self.lin &= bool(self.free[self.lin].all())
        self.moving = self.free & ~self.lin
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._rows = 0
        self._held = multiprocessing.RawValue("b", 0) if isinstance(penalty, Barrier) else None
        """Whether the penalty is held at zero (`penalty_held`): in memory shared with the processes that
        `fitter.workers.evaluation_map` forks later, so that every process evaluates the same function."""

    def full_theta(self, z: np.ndarray) -> np.ndarray:
        theta = self.theta0.copy()
        theta[self.moving] = z
        return theta

    def __call__(self, z: np.ndarray) -> np.ndarray:
        theta = self.full_theta(z)
        if self.lin.any():
            r, theta = self.coarse.projected(self.param, theta)
        else:
            r = self.coarse.residuals(self.param, theta)[0]
        r = r / self.scale
        if self.penalty is not None:
            extra = np.zeros(self._rows) if self._held is not None and self._held.value else self.penalty(theta)
            self._rows = len(extra)
            r = np.r_[r, extra]
        self._last = (z.copy(), r, theta)
        return r

    @contextmanager
    def penalty_held(self, z: np.ndarray) -> Iterator[None]:
        """Within: a `Barrier` penalty's rows are zero without being evaluated, where it is `Barrier.clear` at z
        (the point a Jacobian is taken at, at the theta its penalty was evaluated with); else the penalty as
        always."""
        hold = self._held is not None and self._rows > 0 and self.penalty.clear(self._theta_at(z))
        if hold:
            self._held.value = 1
        try:
            yield
        finally:
            if hold:
                self._held.value = 0

    def last(self, z: np.ndarray) -> np.ndarray:
        """The objective at z: its last evaluation when that was at z, else a new one."""
        if self._last is None or not np.array_equal(self._last[0], z):
            self(z)
        return self._last[1]

    def _theta_at(self, z: np.ndarray) -> np.ndarray:
        """The theta of the objective's evaluation at z (with elimination, its linear entries solved)."""
        self.last(z)
        return self._last[2]


def _free_jacobian(problem, param: Parametrisation, theta: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Forward-difference Jacobian of `problem.residuals` in the free entries of theta."""

    def fun(z):
        th = theta.copy()
        th[free] = z
        with np.errstate(all="ignore"):
            return problem.residuals(param, th)[0]

    return jacobian(fun, theta[free])
