"""The triangle wave (20) of Oh & Bernstein (2007) and a rate-dependent model's steady response to it.

`TriangleWave` is the periodic wave, `triangle_wave` its samples, and
`triangle_response` / `periodic_triangle_output` the model's limiting periodic
output under it (Theorem 1, exact at every sample: the input is linear between
grid points).  The records `fitter.identification.rd_triangles` identifies from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fitter.core import RateDependentModel, periodic_response

__all__ = ["TriangleWave", "triangle_wave", "triangle_response", "periodic_triangle_output"]


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

    The times are folded into one period [0, T) from a minimum; `periodic_response`
    over the sorted phases plus the corners (0, T_a, T) gives every sample
    exactly (the input is linear between grid points).  Raises
    `ConvergenceError` when rho >= 1.
    """
    tau = wave.phase(t)
    grid, inverse = np.unique(np.r_[tau, 0.0, wave.Ta, wave.T], return_inverse=True)
    y = periodic_response(model, grid, wave.value_at_phase(grid)).sim.y
    return y[inverse[: len(tau)]]


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
