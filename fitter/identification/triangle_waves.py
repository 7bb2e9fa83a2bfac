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
    "TriangleSamples",
    "two_level_rate",
    "closed_form_flow",
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
    (`TriangleSamples`); otherwise `periodic_response` over the sorted phases plus the corners
    (0, T_a, T) gives every sample.  Both are exact at every sample (the input is linear between the
    corners) and agree to rounding (tests/test_rd_identification.py).  Raises `ConvergenceError` when
    rho >= 1.
    """
    fl = closed_form_flow(model)
    rates = None if fl is None else _rates(model, wave)
    if rates is None:
        tau = wave.phase(t)
        grid, inverse = np.unique(np.r_[tau, 0.0, wave.Ta, wave.T], return_inverse=True)
        y = periodic_response(model, grid, wave.value_at_phase(grid)).sim.y
        return y[inverse[: len(tau)]]
    (y,) = TriangleSamples([wave], [t]).outputs(model, [rates], fl)
    if y is None:
        raise ConvergenceError(
            "no limiting periodic map: spectral radius of the period map is >= 1 (condition (5) of Theorem 1 fails)"
        )
    return y


class TriangleSamples:
    """The samples of one or more triangle waves, laid out once for the closed-form periodic output of
    many models (an estimator's evaluations): per sample its wave, its half and the time since that
    half's corner, and its input.

    Closed form: on each half of a wave the rate v is constant, so eq (18) is the affine ODE (K) of
    `fitter.core.flow` with s = g(v) tau: from the half's corner (p the corner's input, r = v / g(v),
    S = g(v) (tau - corner)) the modal state is w(S) = e^{lambda S} w(0) + f(S) at every phase at once
    (`AffineFlow.modal_terms`).  The period map is diagonal, w(T) = e^{z_a + z_b} w(0) + e^{z_b} f_a + f_b,
    so its fixed point is w(0) = (e^{z_b} f_a + f_b) / (1 - e^{z_a + z_b}) elementwise and rho the largest
    |e^{z_a + z_b}| (condition (5) of Theorem 1).
    """

    def __init__(self, waves: Sequence[TriangleWave], times: Sequence[np.ndarray]):
        self.waves, self.times = list(waves), list(times)
        taus = [w.phase(t) for w, t in zip(waves, times)]
        self.ends = np.cumsum([0] + [len(tau) for tau in taus])
        self.wave_of = np.repeat(np.arange(len(taus)), np.diff(self.ends))
        self.up = np.concatenate([tau <= w.Ta for w, tau in zip(waves, taus)])
        self.corners = np.array([[w.u_lo, w.a, w.Ta] for w in waves] + [[w.u_hi, w.b, w.Tb] for w in waves])
        Ta = self.corners[: len(taus), 2]
        self.since = np.concatenate(taus) - np.where(self.up, 0.0, Ta[self.wave_of])
        self.half = np.where(self.up, self.wave_of, self.wave_of + len(taus))
        self.u = np.concatenate([w.value_at_phase(tau) for w, tau in zip(waves, taus)])

    def outputs(
        self, model: RateDependentModel, rates: Sequence[tuple[float, float]], fl: AffineFlow | None = None
    ) -> list[np.ndarray | None]:
        """The periodic output of the model's A, B, E, C, D under each wave, wave i with the rates
        ``rates[i]`` = (g(a_i), g(b_i)) at its two slopes (the model's own g is not used); None where there
        is no limiting periodic output.  In closed form where it applies; otherwise each wave as
        `periodic_triangle_output` solves it with the two-level rate `two_level_rate` of its rates."""
        g = np.asarray(rates, dtype=float).reshape(-1, 2)
        fl = closed_form_flow(model) if fl is None else fl
        if fl is None or not (np.all(np.isfinite(g)) and np.all(g > 0)):
            return [
                _or_none(periodic_triangle_output, model.replace(g=two_level_rate(*r)), w, t)
                for w, t, r in zip(self.waves, self.times, g)
            ]
        X, rho = self._states(fl, g.T.ravel())
        y = model.output(X, self.u)
        return [y[a:b] if r < 1 else None for a, b, r in zip(self.ends[:-1], self.ends[1:], rho)]

    def _states(self, fl: AffineFlow, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The periodic states at every sample (class docstring) and each wave's rho; `g` the rates of the
        rising halves, then of the falling ones."""
        modal = self.periodic_modal(fl, g, fl.beta, fl.eps)
        return (modal.W @ fl.V.T).real, np.max(np.abs(modal.decay), axis=1)

    def periodic_modal(self, fl: AffineFlow, g: np.ndarray, beta: np.ndarray, eps: np.ndarray) -> "PeriodicModal":
        """The periodic modal states (class docstring) under the modal forcing (beta, eps) (`fl.beta`, `fl.eps`
        for the flow's own; unit vectors for the responses to each mode's forcing); `g` as `_states`."""
        P = len(self.waves)
        p, v, span = self.corners.T
        z, f = fl.modal_terms(p, v / g, g * span, modal_forcing=(beta, eps))
        with np.errstate(over="ignore", invalid="ignore"):
            decay = np.exp(z[:P] + z[P:])
            w_lo = (np.exp(z[P:]) * f[:P] + f[P:]) / (1.0 - decay)
            starts = np.vstack([w_lo, np.exp(z[:P]) * w_lo + f[:P]])
            h = self.half
            zs, fs = fl.modal_terms(p[h], v[h] / g[h], g[h] * self.since, modal_forcing=(beta, eps))
            W = np.exp(zs) * starts[h] + fs
        return PeriodicModal(z=z, zs=zs, starts=starts, W=W, decay=decay)


@dataclass(frozen=True)
class PeriodicModal:
    """`TriangleSamples.periodic_modal`: per half (rising halves, then falling) the exponents z = lambda g T_h at
    its end and its periodic start; per sample the exponents zs = lambda g tau since its half's corner and its
    periodic modal state W; per wave and mode e^{z_a + z_b} (`decay`, condition (5))."""

    z: np.ndarray
    zs: np.ndarray
    starts: np.ndarray
    W: np.ndarray
    decay: np.ndarray


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


def closed_form_flow(model: RateDependentModel) -> AffineFlow | None:
    """The model's flow when the closed form applies to it: no effects, A diagonalisable."""
    if getattr(model, "effects", None):
        return None
    fl = AffineFlow(model.A, model.B, model.E)
    return fl if fl.modal else None


def _rates(model: RateDependentModel, wave: TriangleWave) -> tuple[float, float] | None:
    """(g(a), g(b)) of the wave's two slopes, None unless both are finite and positive."""
    g = np.asarray(model.g(np.array([wave.a, wave.b])), dtype=float)
    return (float(g[0]), float(g[1])) if np.all(np.isfinite(g)) and np.all(g > 0) else None


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
