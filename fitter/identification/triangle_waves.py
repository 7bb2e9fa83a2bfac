"""The triangle wave (20) of Oh & Bernstein (2007) and a rate-dependent model's steady response to it.

`TriangleWave` is the periodic wave, `triangle_wave` its samples, and
`triangle_response` / `periodic_triangle_output` the model's limiting periodic
output under it (Theorem 1, exact at every sample: the input is linear between
grid points).  The records `fitter.identification.rd_triangles` identifies from.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fitter.core import AffineFlow, CallableRate, ConvergenceError, KernelError, RateDependentModel, periodic_response

__all__ = [
    "TriangleWave",
    "triangle_wave",
    "triangle_response",
    "periodic_triangle_output",
    "periodic_triangle_outputs",
    "two_level_rate",
]


@dataclass(frozen=True)
class TriangleWave:
    """The periodic triangle wave (20): minimum u_lo at t_min (+ multiples of T).

    It rises with slope a > 0 to u_hi in T_a = (u_hi - u_lo)/a, then falls with
    slope b < 0 back to u_lo in T_b = (u_hi - u_lo)/(-b); T = T_a + T_b.
    """

    a: float
    b: float
    u_lo: float
    u_hi: float
    t_min: float = 0.0

    @property
    def Ta(self) -> float:
        return (self.u_hi - self.u_lo) / self.a

    @property
    def Tb(self) -> float:
        return (self.u_hi - self.u_lo) / -self.b

    @property
    def T(self) -> float:
        return self.Ta + self.Tb

    def phase(self, t: np.ndarray) -> np.ndarray:
        """Time since the last minimum, in [0, T); values within 1e-9 T of a corner snap to it."""
        tau = np.mod(np.asarray(t, dtype=float) - self.t_min, self.T)
        eps = 1e-9 * self.T
        tau = np.where(np.abs(tau - self.Ta) < eps, self.Ta, tau)
        return np.where(self.T - tau < eps, 0.0, tau)

    def value_at_phase(self, tau: np.ndarray) -> np.ndarray:
        tau = np.asarray(tau, dtype=float)
        return np.where(tau <= self.Ta, self.u_lo + self.a * tau, self.u_hi + self.b * (tau - self.Ta))

    def __call__(self, t: np.ndarray) -> np.ndarray:
        return self.value_at_phase(self.phase(t))


def _wave_from_eq20(a: float, b: float, Ta: float, Tb: float) -> TriangleWave:
    if not (a > 0 and b < 0 and Ta > 0 and Tb > 0):
        raise ValueError(f"triangle wave (20) needs a > 0, b < 0, Ta > 0, Tb > 0; got a={a}, b={b}, Ta={Ta}, Tb={Tb}")
    if not np.isclose(a * Ta, -b * Tb, rtol=1e-9, atol=0):
        raise ValueError(
            f"triangle wave (20) is continuous only when a*Ta = -b*Tb; got a*Ta = {a * Ta}, -b*Tb = {-b * Tb}"
        )
    return TriangleWave(a=float(a), b=float(b), u_lo=-a * Ta / 2, u_hi=a * Ta / 2, t_min=0.0)


def triangle_wave(
    a: float, b: float, Ta: float, Tb: float, periods: int, delta: float
) -> tuple[np.ndarray, np.ndarray]:
    """Samples t_k = k delta, 0 <= t_k <= periods T, of the triangle wave (20).

    u(t) = a t - a q T - a T_a / 2 on [qT, qT + T_a) and
    b t - b (q+1) T + b T_b / 2 on [qT + T_a, (q+1) T), T = T_a + T_b, so u
    rises from -a T_a/2 at t = 0; continuity requires a T_a = -b T_b.
    """
    wave = _wave_from_eq20(a, b, Ta, Tb)
    if int(periods) != periods or periods < 1:
        raise ValueError(f"periods must be a positive integer, got {periods}")
    if not delta > 0:
        raise ValueError(f"sampling period delta must be > 0, got {delta}")
    k = int(np.floor(periods * wave.T / delta + 1e-9))
    t = delta * np.arange(k + 1)
    return t, wave(t)


def periodic_triangle_output(model: RateDependentModel, wave: TriangleWave, t: np.ndarray) -> np.ndarray:
    """The model's limiting periodic output (Theorem 1) at the times t under `wave`.

    The times are folded into one period [0, T) from a minimum.  A model without effects whose A is
    diagonalisable and whose rate is positive at both slopes is solved in closed form
    (`_closed_form_states`); otherwise `periodic_response` over the sorted phases plus the corners
    (0, T_a, T) gives every sample.  Both are exact at every sample (the input is linear between the
    corners) and agree to rounding (tests/test_rd_identification.py).  Raises `ConvergenceError` when
    rho >= 1.
    """
    tau = wave.phase(t)
    fl = _closed_form_flow(model)
    rates = None if fl is None else _rates(model, wave)
    if rates is None:
        grid, inverse = np.unique(np.r_[tau, 0.0, wave.Ta, wave.T], return_inverse=True)
        y = periodic_response(model, grid, wave.value_at_phase(grid)).sim.y
        return y[inverse[: len(tau)]]
    (X,) = _closed_form_states(fl, [wave], [rates], [tau])
    if X is None:
        raise ConvergenceError(
            "no limiting periodic map: spectral radius of the period map is >= 1 (condition (5) of Theorem 1 fails)"
        )
    return model.output(X, wave.value_at_phase(tau))


def periodic_triangle_outputs(
    model: RateDependentModel,
    waves: Sequence[TriangleWave],
    times: Sequence[np.ndarray],
    rates: Sequence[tuple[float, float]],
) -> list[np.ndarray | None]:
    """`periodic_triangle_output` of the model's A, B, E, C, D under each wave at its times, wave i with the
    rates ``rates[i]`` = (g(a_i), g(b_i)) at its two slopes (the model's own g is not used); None where there
    is no limiting periodic output.

    Every sample of every wave is solved in one pass in closed form (`_closed_form_states`) where it
    applies; otherwise each wave as `periodic_triangle_output` solves it, with the two-level rate
    `two_level_rate` of its rates."""
    taus = [w.phase(t) for w, t in zip(waves, times)]
    fl = _closed_form_flow(model)
    if fl is None or not all(np.isfinite(r).all() and min(r) > 0 for r in rates):
        return [
            _or_none(periodic_triangle_output, model.replace(g=two_level_rate(*r)), w, t)
            for w, t, r in zip(waves, times, rates)
        ]
    states = _closed_form_states(fl, waves, rates, taus)
    return [None if X is None else model.output(X, w.value_at_phase(tau)) for w, tau, X in zip(waves, taus, states)]


def two_level_rate(g_plus: float, g_minus: float) -> CallableRate:
    """The rate function g(v) = g_plus for v > 0, g_minus for v < 0, 0 at v = 0: one triangle wave's two
    slopes are all of g a model meets under it."""
    return CallableRate(lambda v: np.where(v > 0, g_plus, np.where(v < 0, g_minus, 0.0)))


def _or_none(function, *args):
    """function(*args), or None where the kernel finds no periodic output."""
    try:
        return function(*args)
    except (ConvergenceError, KernelError, np.linalg.LinAlgError):
        return None


def _closed_form_flow(model: RateDependentModel) -> AffineFlow | None:
    """The model's flow when the closed form applies to it: no effects, A diagonalisable."""
    if getattr(model, "effects", None):
        return None
    fl = AffineFlow(model.A, model.B, model.E)
    return fl if fl.modal else None


def _rates(model: RateDependentModel, wave: TriangleWave) -> tuple[float, float] | None:
    """(g(a), g(b)) of the wave's two slopes, None unless both are finite and positive."""
    g = np.asarray(model.g(np.array([wave.a, wave.b])), dtype=float)
    return (float(g[0]), float(g[1])) if np.all(np.isfinite(g)) and np.all(g > 0) else None


def _closed_form_states(
    fl: AffineFlow, waves: Sequence[TriangleWave], rates: Sequence[tuple[float, float]], taus: Sequence[np.ndarray]
) -> list[np.ndarray | None]:
    """The periodic states at the phases `taus` of each wave without stepping from sample to sample (None
    where rho >= 1).

    On each half of a wave the rate v is constant, so eq (18) is the affine ODE (K) of `fitter.core.flow`
    with s = g(v) tau: from the half's corner (p the corner's input, r = v / g(v), S = g(v) (tau - corner))
    the modal state is w(S) = e^{lambda S} w(0) + f(S) at every phase at once (`AffineFlow.modal_terms`).
    The period map is diagonal, w(T) = e^{z_a + z_b} w(0) + e^{z_b} f_a + f_b, so its fixed point is
    w(0) = (e^{z_b} f_a + f_b) / (1 - e^{z_a + z_b}) elementwise and rho the largest |e^{z_a + z_b}|
    (condition (5) of Theorem 1)."""
    P = len(waves)
    lo = np.array([[w.u_lo, w.a / g[0], g[0]] for w, g in zip(waves, rates)])
    hi = np.array([[w.u_hi, w.b / g[1], g[1]] for w, g in zip(waves, rates)])
    spans = np.r_[[w.Ta for w in waves], [w.Tb for w in waves]]
    both = np.vstack([lo, hi])
    z, f = fl.modal_terms(both[:, 0], both[:, 1], both[:, 2] * spans)
    with np.errstate(over="ignore", invalid="ignore"):
        decay = np.exp(z[:P] + z[P:])
        rho = np.max(np.abs(decay), axis=1)
        w_lo = (np.exp(z[P:]) * f[:P] + f[P:]) / (1.0 - decay)
        w_hi = np.exp(z[:P]) * w_lo + f[:P]
    rising = [tau <= w.Ta for w, tau in zip(waves, taus)]
    wave_of = np.concatenate([np.full(len(tau), i) for i, tau in enumerate(taus)])
    up = np.concatenate(rising)
    coef = np.where(up[:, None], lo[wave_of], hi[wave_of])
    since = np.concatenate(taus) - np.where(up, 0.0, np.array([w.Ta for w in waves])[wave_of])
    zs, fs = fl.modal_terms(coef[:, 0], coef[:, 1], coef[:, 2] * since)
    with np.errstate(over="ignore", invalid="ignore"):
        W = np.exp(zs) * np.where(up[:, None], w_lo[wave_of], w_hi[wave_of]) + fs
    X = (W @ fl.V.T).real
    ends = np.cumsum([0] + [len(tau) for tau in taus])
    return [X[ends[i] : ends[i + 1]] if rho[i] < 1 else None for i in range(P)]


def triangle_response(
    model: RateDependentModel,
    a: float,
    b: float,
    Ta: float,
    Tb: float,
    periods: int,
    delta: float,
    noise_pp: float = 0.0,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steady-state record (t, u, y) of `model` under the sampled triangle wave (20).

    y is the limiting periodic response (exact at each sample) plus, when
    noise_pp > 0, uniform noise on [-noise_pp/2, noise_pp/2] drawn from `rng`.
    """
    t, u = triangle_wave(a, b, Ta, Tb, periods, delta)
    y = periodic_triangle_output(model, _wave_from_eq20(a, b, Ta, Tb), t)
    if noise_pp > 0:
        if rng is None:
            raise ValueError("noise_pp > 0 needs a seeded rng (np.random.default_rng(seed))")
        y = y + rng.uniform(-noise_pp / 2, noise_pp / 2, size=y.shape)
    return t, u, y
