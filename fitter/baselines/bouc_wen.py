"""The Bouc-Wen model fitted by output error.

Bouc-Wen
--------
Output error on the samples (decimated, `BoucWen`), parameters by
the output-error engine (`refine`) from deterministic starts; the state is
integrated along u exactly up to a tabulated quadrature (`BoucWen`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from fitter.baselines.base import Baseline, BaselineError
from fitter.identification.refine import Options, refine
from fitter.identification.parametrisation import Parametrisation

_SATURATION_GAP = 1e-13
"""Relative distance to the saturation state z_s below which the flow table treats z as z_s."""
_LOG_GAP = math.log(_SATURATION_GAP)
_Z0_BOUND = 5.0
_ZS_BOUNDS = (0.02, 20.0)
_WIDEST = math.log(1 + _Z0_BOUND / _ZS_BOUNDS[0])
"""Longest log-range of the zeta < 0 piece of the flow table (z0 bound over the smallest z_s)."""


def _hermite(x: np.ndarray, xs: np.ndarray, ys: np.ndarray, ms: np.ndarray) -> np.ndarray:
    """Cubic Hermite interpolation of (xs ascending, ys, slopes ms) at x, constant beyond the ends."""
    x = np.clip(x, xs[0], xs[-1])
    k = np.clip(np.searchsorted(xs, x, side="right") - 1, 0, len(xs) - 2)
    h = xs[k + 1] - xs[k]
    s = (x - xs[k]) / h
    s2, s3 = s * s, s * s * s
    return (
        (2 * s3 - 3 * s2 + 1) * ys[k]
        + (s3 - 2 * s2 + s) * h * ms[k]
        + (3 * s2 - 2 * s3) * ys[k + 1]
        + (s3 - s2) * h * ms[k + 1]
    )


def _hermite1(x: float, xs: np.ndarray, ys: np.ndarray, ms: np.ndarray) -> float:
    """`_hermite` for one value (float arithmetic: cheaper than numpy's for one value)."""
    k = int(xs.searchsorted(x, side="right")) - 1
    if k < 0:
        return ys.item(0)
    if k >= len(xs) - 1:
        return ys.item(-1)
    x0, x1, y0, y1 = xs.item(k), xs.item(k + 1), ys.item(k), ys.item(k + 1)
    h = x1 - x0
    s = (x - x0) / h
    s2, s3 = s * s, s * s * s
    return (
        (2 * s3 - 3 * s2 + 1) * y0
        + (s3 - 2 * s2 + s) * h * ms.item(k)
        + (3 * s2 - 2 * s3) * y1
        + (s3 - s2) * h * ms.item(k + 1)
    )


def _cumulative_simpson(f: np.ndarray, h: float) -> np.ndarray:
    """Cumulative integral of samples f (spacing h, at least 3) from the first: each interval by
    the parabola through it and its neighbour (h/12 (5 f_i + 8 f_i+1 - f_i+2), mirrored at the end)."""
    parts = np.empty(len(f) - 1)
    parts[:-1] = h / 12 * (5 * f[:-2] + 8 * f[1:-1] - f[2:])
    parts[-1] = h / 12 * (-f[-3] + 8 * f[-2] + 5 * f[-1])
    return np.r_[0.0, np.cumsum(parts)]


class _Table:
    """One side of the flow table: `forward` = (w ascending, T(w), dT/dw) and `inverse` = (T
    ascending, w(T), dw/dT)."""

    def __init__(self, w: np.ndarray, t: np.ndarray, dt: np.ndarray):
        self.forward = (w, t, dt)
        self.inverse = (t[::-1].copy(), w[::-1].copy(), 1 / dt[::-1])


class _Flow:
    """The Bouc-Wen state along a monotone stretch of input, exact up to a tabulated quadrature.

    With zeta = s z and v = s (u - u_a) >= 0 on a stretch of direction s
    (`BoucWen`), dzeta/dv = g(zeta) for both directions.  zeta tends to the
    fixed point z_s from below (zeta < z_s, g > 0) or above (g < 0).  On each
    side, with x = |zeta - z_s| = e^w, the travel needed to come from the end
    of the table to x is T(w) = int_w^{w_max} e^w' / |g(zeta(w'))| dw'
    (cumulative Simpson-type quadrature on a grid uniform in w, split at zeta = 0 where g
    has a kink, a fixed number of points per piece so that the table is a
    smooth function of the parameters, spacing at most `step`); the state
    after travel v from zeta_0 is zeta = z_s -+ e^{w(T(w_0) + v)}.  T(w) and
    its inverse w(T) are interpolated by cubic Hermite polynomials with the
    exact slopes dT/dw = -e^w / |g| (fourth order, like the quadrature).
    Near z_s the slope tends to the constant -z_s / n, so the table reaches
    x = 1e-13 z_s with few points, and beyond it zeta = z_s.
    """

    def __init__(self, zs: float, q: float, n: float, zmax: float, step: float):
        self.zs, self.q, self.n, self.zmax, self.step = zs, q, n, zmax, step
        self._sides: dict[int, _Table] = {}

    def _side(self, side: int) -> _Table:
        """The table of `side`, built when first needed (side +1 only for a z0 beyond z_s)."""
        if side not in self._sides:
            x_max = self.zs + self.zmax if side < 0 else self.zmax - self.zs
            self._sides[side] = self._table(self.zs, self.q, self.n, x_max, side, self.step)
        return self._sides[side]

    @staticmethod
    def _table(zs: float, q: float, n: float, x_max: float, side: int, step: float) -> _Table:
        """The table of zeta = zs + side x (x = e^w)."""
        w_sat, w_top = math.log(zs) + _LOG_GAP, math.log(x_max)
        if side < 0:
            pieces = [(w_sat, math.log(zs), -_LOG_GAP), (math.log(zs), w_top, _WIDEST)]
        else:
            pieces = [(w_sat, w_top, _WIDEST - _LOG_GAP)]
        ws, ts, fs, t_top = [], [], [], 0.0
        for a, b, longest in reversed(pieces):  # each smooth piece, from the top down
            w, dw = np.linspace(a, b, int(math.ceil(longest / step)) + 1, retstep=True)
            f = _Flow._integrand(np.exp(w), zs, q, n, side)
            below = _cumulative_simpson(f, dw)
            t = t_top + below[-1] - below
            cut = slice(0, -1) if ws else slice(None)
            ws.insert(0, w[cut])
            ts.insert(0, t[cut])
            fs.insert(0, f[cut])
            t_top = float(t[0])
        return _Table(np.concatenate(ws), np.concatenate(ts), -np.concatenate(fs))

    @staticmethod
    def _integrand(x: np.ndarray, zs: float, q: float, n: float, side: int) -> np.ndarray:
        """x / |g(zeta)| at zeta = zs + side x (-dT/dw with x = e^w)."""
        with np.errstate(divide="ignore"):
            if side < 0:
                g = np.where(
                    x <= zs, -np.expm1(n * np.log1p(-np.minimum(x / zs, 1.0))), 1 + q * np.abs(x / zs - 1) ** n
                )
            else:
                g = -np.expm1(n * np.log1p(x / zs))
        return x / np.abs(g)

    def start(self, zeta0: float) -> tuple[int, float]:
        """(side, T(zeta0)); side 0 when zeta0 is at z_s."""
        gap = zeta0 - self.zs
        if abs(gap) <= self.zs * _SATURATION_GAP:
            return 0, 0.0
        side = 1 if gap > 0 else -1
        return side, _hermite1(math.log(abs(gap)), *self._side(side).forward)

    def at(self, side: int, t: np.ndarray) -> np.ndarray:
        """zeta at table travel t (array) on `side` (0: z_s)."""
        if side == 0:
            return np.full(len(t), self.zs)
        return self.zs + side * np.exp(_hermite(t, *self._side(side).inverse))

    def at_scalar(self, side: int, t: float) -> float:
        """`at` for one travel."""
        if side == 0:
            return self.zs
        return self.zs + side * math.exp(_hermite1(t, *self._side(side).inverse))


@dataclass(frozen=True)
class _Runs:
    """Monotone stretches of one input (a held sample joins the stretch it is in; a reversal
    sample ends one stretch and starts the next): first sample, direction and travel
    s (u_end - u_start) of each stretch, and for samples 1 .. N-1 the stretch they end and the
    travel v = s (u_k - u_start) to them."""

    starts: np.ndarray
    ends: np.ndarray
    signs: np.ndarray
    travel: np.ndarray
    index: np.ndarray
    v: np.ndarray

    @classmethod
    def of(cls, u: np.ndarray) -> "_Runs":
        s = np.sign(np.diff(u))
        nz = np.flatnonzero(s)
        if nz.size == 0:
            s = np.ones_like(s)
        else:
            idx = np.where(s != 0, np.arange(len(s)), nz[0])
            np.maximum.accumulate(idx, out=idx)
            s = s[idx]
        cuts = np.r_[0, np.flatnonzero(np.diff(s)) + 1, len(s)]
        starts, ends, signs = cuts[:-1], cuts[1:], s[cuts[:-1]]
        index = np.repeat(np.arange(len(starts)), ends - starts)
        v = signs[index] * (u[1:] - u[starts[index]])
        return cls(starts, ends, signs, signs * (u[ends] - u[starts]), index, v)


class BoucWen(Baseline):
    """Bouc-Wen model, fitted by output error.

    Model (normalised units)::

        dz/dt = A du/dt - beta |du/dt| |z|^(n-1) z - gamma du/dt |z|^n,
        y = k_u u + k_z z + c,   z(t_0) = z0.

    It is rate independent: on a stretch where u moves in direction s =
    sign(du/dt), dz/du = A - |z|^n (beta s sign(z) + gamma).  A = 1 fixes the
    scale of z: z' = lambda z with (lambda A, lambda^(1-n) beta,
    lambda^(1-n) gamma, k_z / lambda, lambda z0) gives the same output, so of
    the classical 8 parameters (A, beta, gamma, n, k_u, k_z, c, z0) 7 are
    identifiable and fitted.  beta and gamma are parametrised by the
    saturation state z_s > 0 and the asymmetry q >= 0: beta + gamma = z_s^-n,
    beta - gamma = q z_s^-n, i.e. beta = (1 + q) / (2 z_s^n) > 0 and |gamma| <=
    beta (the usual condition for bounded, dissipative loops).  With zeta = s z
    and v = s (u - u_a), both directions obey dzeta/dv = g(zeta) =
    1 - (zeta/z_s)^n for zeta >= 0 and 1 + q (|zeta|/z_s)^n for zeta < 0.

    Discretisation.  Integrated along u, stretch by stretch (monotone runs of
    the samples), exactly except for the quadrature table of `_Flow` (grid
    spacing in log |zeta - z_s| at most `step`; halving it changes the output
    by less than 1e-6 of its range, and it agrees with scipy's solve_ivp,
    `tests/test_baselines.py`).  The state at the end of each stretch is
    carried forward in a loop over the stretches; the samples inside them are
    evaluated at once.  Being rate independent, the state at a sample depends
    only on the input values and the stretch ends before it, so a decimated
    record that keeps every stretch end has the same states at its samples.

    Fit.  At most `max_samples` samples of each recording enter the
    optimisation (every stretch end, the rest evenly spaced, each weighted by
    sqrt(N / kept) so that recordings count by their length); the score is
    on all samples.  k_u, k_z, c are solved by linear least squares inside
    the residual (variable projection); z_s (log scale, in [0.02, 20]), q (in
    [0, 20]), n (in [1, 5]) and one z0 per recording (in [-5, 5]) by
    the project's output-error engine (`refine`: bounded trust-region
    reflective least squares; forward differences, a recording's z0 moving
    only that recording's states) from
    the `starts` best points of a fixed grid of z_s, q, n and z0.

    Parameters
    ----------
    max_samples : samples per recording in the optimisation.
    step : largest spacing of the flow table (see Discretisation).
    starts : number of grid points refined by least squares.
    deadband : see `Baseline`.
    """

    name = "bouc_wen"
    initial_state = "z0, fitted per recording (a parameter of the fit)"
    Z0_BOUND = _Z0_BOUND
    ZS_BOUNDS = _ZS_BOUNDS
    Q_MAX = 20.0
    N_BOUNDS = (1.0, 5.0)
    _GRID = {"z_s": (0.1, 0.3, 1.0, 3.0), "q": (0.2, 1.0, 5.0), "n": (1.0, 2.0, 4.0), "z0": (-0.5, 0.0, 0.5)}
    """Starting grid (z0 as a fraction of z_s)."""

    def __init__(self, max_samples: int = 6000, step: float = 0.01, starts: int = 3, deadband: bool = True) -> None:
        super().__init__(deadband)
        self.max_samples, self.step, self.starts = int(max_samples), float(step), int(starts)
        self.zs_ = self.q_ = self.n_ = math.nan
        self.k_u_ = self.k_z_ = self.c_ = math.nan
        self.z0_: list[float] = []

    # simulation
    def _flow(self, zs: float, q: float, n: float) -> _Flow:
        return _Flow(zs, q, n, max(self.Z0_BOUND, zs) * (1 + 1e-9), self.step)

    @staticmethod
    def _states(flow: _Flow, runs: _Runs, z0: float) -> np.ndarray:
        """z on every sample, from z0 (class docstring, Discretisation)."""
        sides = np.empty(len(runs.starts), dtype=int)
        t0 = np.empty(len(runs.starts))
        z = z0
        for j, (s, travel) in enumerate(zip(runs.signs.tolist(), runs.travel.tolist())):
            side, t = flow.start(s * z)
            sides[j], t0[j] = side, t
            z = s * flow.at_scalar(side, t + travel)
        out = np.empty(len(runs.index) + 1)
        out[0] = z0
        side, t = sides[runs.index], t0[runs.index] + runs.v
        for value in np.unique(sides):
            sel = side == value
            out[1:][sel] = runs.signs[runs.index[sel]] * flow.at(int(value), t[sel])
        return out

    def simulate_states(self, u: np.ndarray, z0: float) -> np.ndarray:
        """The state z on the normalised input u_n from z0, with the fitted (or set) z_s, q, n."""
        if math.isnan(self.zs_):
            raise BaselineError("the bouc_wen baseline has no z_s, q, n yet: fit it or set them")
        return self._states(self._flow(self.zs_, self.q_, self.n_), _Runs.of(np.asarray(u, dtype=float)), z0)

    # fit
    @staticmethod
    def _decimate(u: np.ndarray, limit: int) -> np.ndarray:
        """Indices kept for the optimisation (class docstring, Fit)."""
        n = len(u)
        if n <= limit:
            return np.arange(n)
        runs = _Runs.of(u)
        ends = np.union1d(np.r_[runs.starts, runs.ends], [0, n - 1])
        even = np.linspace(0, n - 1, max(limit - len(ends), 2)).round().astype(int)
        return np.union1d(ends, even)

    def _fit(self, us: list[np.ndarray], ys: list[np.ndarray]) -> None:
        data = []
        for u, y in zip(us, ys):
            keep = self._decimate(u, self.max_samples)
            data.append(_BWData(u[keep], y[keep], _Runs.of(u[keep]), math.sqrt(len(u) / len(keep))))
        r = len(data)
        lower = [math.log(self.ZS_BOUNDS[0]), 0.0, self.N_BOUNDS[0]] + [-self.Z0_BOUND] * r
        upper = [math.log(self.ZS_BOUNDS[1]), self.Q_MAX, self.N_BOUNDS[1]] + [self.Z0_BOUND] * r
        problem = _BWProblem(self, data, np.array(upper))
        grid = [
            np.r_[math.log(zs), q, n, [z0 * zs] * r]
            for zs in self._GRID["z_s"]
            for q in self._GRID["q"]
            for n in self._GRID["n"]
            for z0 in self._GRID["z0"]
        ]
        costs = [float(np.sum(problem.residual(th) ** 2)) for th in grid]
        param = _BWParameters(np.array(lower), np.array(upper))
        options = Options(ftol=1e-8, xtol=1e-8, gtol=1e-8, max_nfev=100 * (3 + r), max_samples=None)
        best = None
        for k in np.argsort(costs, kind="stable")[: self.starts]:
            sol = refine(param, grid[k], problem, options, jac=problem.jacobian)
            if best is None or sol.cost < best.cost:
                best = sol
        theta = best.theta
        self.zs_, self.q_, self.n_ = math.exp(theta[0]), float(theta[1]), float(theta[2])
        self.z0_ = [float(z) for z in theta[3:]]
        self.k_u_, self.k_z_, self.c_ = problem.linear(theta)

    # predict
    def _predict(self, u: np.ndarray, y: np.ndarray | None) -> np.ndarray:
        flow, runs = self._flow(self.zs_, self.q_, self.n_), _Runs.of(u)

        def output(z0: float) -> np.ndarray:
            return self.k_u_ * u + self.k_z_ * self._states(flow, runs, z0) + self.c_

        if y is None:
            return output(self.z0_[0])

        def sse(z0: float) -> float:
            return float(np.sum((output(z0) - y) ** 2))

        scan = np.linspace(-self.Z0_BOUND, self.Z0_BOUND, 41)
        errors = [sse(z) for z in scan]
        k = int(np.argmin(errors))
        best = minimize_scalar(
            sse,
            bounds=(scan[max(k - 1, 0)], scan[min(k + 1, len(scan) - 1)]),
            method="bounded",
            options={"xatol": 1e-9},
        )
        return output(float(best.x) if best.fun <= errors[k] else float(scan[k]))

    @property
    def parameters(self) -> int:
        self._scale()
        return 6 + self.n_recordings_

    @property
    def beta(self) -> float:
        """beta of the model equation (normalised units, A = 1)."""
        return (1 + self.q_) / (2 * self.zs_**self.n_)

    @property
    def gamma(self) -> float:
        """gamma of the model equation (normalised units, A = 1)."""
        return (1 - self.q_) / (2 * self.zs_**self.n_)

    def _settings(self) -> dict:
        return {
            "max_samples": self.max_samples,
            "step": self.step,
            "starts": self.starts,
            "A": 1.0,
            "deadband": self.deadband,
        }

    def _fitted(self) -> dict:
        return {
            "z_s": self.zs_,
            "q": self.q_,
            "n": self.n_,
            "beta": self.beta,
            "gamma": self.gamma,
            "k_u": self.k_u_,
            "k_z": self.k_z_,
            "c": self.c_,
            "z0": list(self.z0_),
        }


@dataclass(frozen=True)
class _BWData:
    """One recording as the Bouc-Wen fit sees it: kept samples, their stretches, the weight."""

    u: np.ndarray
    y: np.ndarray
    runs: _Runs
    weight: float


class _BWProblem:
    """The variable-projection residual of `BoucWen` and its forward-difference Jacobian.

    theta = [log z_s, q, n, z0_1 .. z0_R]; the residual is the weighted
    output error after the least-squares k_u, k_z, c.
    """

    scale = 1.0

    def __init__(self, model: BoucWen, data: list[_BWData], upper: np.ndarray):
        self.model, self.data, self.upper = model, data, upper
        self._cache: tuple[bytes, list[np.ndarray]] | None = None

    def decimated(self, max_samples: int | None) -> "_BWProblem":
        """The samples are already the kept ones (`BoucWen._decimate`)."""
        return self

    def residuals(self, param, theta: np.ndarray):
        """The output-error engine's interface (`fitter.identification.refine.refine`): the stacked
        residual, theta as the 'model', and per recording (start, x0, residual, rho, effect state)."""
        r = self.residual(theta)
        parts = np.split(r, np.cumsum([len(d.u) for d in self.data])[:-1])
        return r, theta, [(0, z0, part, math.nan, None) for z0, part in zip(theta[3:], parts)]

    def states(self, theta: np.ndarray) -> list[np.ndarray]:
        key = np.asarray(theta, dtype=float).tobytes()
        if self._cache is None or self._cache[0] != key:
            flow = self.model._flow(math.exp(theta[0]), theta[1], theta[2])
            self._cache = key, [self.model._states(flow, d.runs, z0) for d, z0 in zip(self.data, theta[3:])]
        return self._cache[1]

    def _system(self, zs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        a = np.vstack([d.weight * np.column_stack([d.u, z, np.ones(len(d.u))]) for d, z in zip(self.data, zs)])
        return a, np.concatenate([d.weight * d.y for d in self.data])

    def _project(self, zs: list[np.ndarray]) -> np.ndarray:
        a, b = self._system(zs)
        return a @ np.linalg.lstsq(a, b, rcond=None)[0] - b

    def residual(self, theta: np.ndarray) -> np.ndarray:
        return self._project(self.states(theta))

    def linear(self, theta: np.ndarray) -> tuple[float, float, float]:
        """The least-squares k_u, k_z, c at theta."""
        a, b = self._system(self.states(theta))
        return tuple(float(x) for x in np.linalg.lstsq(a, b, rcond=None)[0])

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        base = list(self.states(theta))
        r0 = self._project(base)
        jac = np.empty((len(r0), len(theta)))
        flow = self.model._flow(math.exp(theta[0]), theta[1], theta[2])
        for j in range(len(theta)):
            h = 1e-6 * max(1.0, abs(theta[j]))
            h = -h if theta[j] + h > self.upper[j] else h
            moved = theta.copy()
            moved[j] += h
            if j < 3:
                zs = self.states(moved)
            else:
                zs = base[: j - 3] + [self.model._states(flow, self.data[j - 3].runs, moved[j])] + base[j - 2 :]
            jac[:, j] = (self._project(zs) - r0) / h
        self.states(theta)
        return jac


class _BWParameters(Parametrisation):
    """theta = [log z_s, q, n, z0_1 .. z0_R] of `_BWProblem`, within its bounds."""

    def __init__(self, lower: np.ndarray, upper: np.ndarray):
        self.lower, self.upper, self.size = lower, upper, len(lower)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.lower.copy(), self.upper.copy()

    def build(self, theta: np.ndarray) -> np.ndarray:
        return theta
