"""The catalogue of effects, one `EffectSpec` each, and `REGISTRY` (their math: the `fitter.core.effects`
docstring).
"""

from __future__ import annotations

import math

import numpy as np

from ..flow import branches
from ..recurrence import linear_recurrence
from .spec import INF, Chain, EffectContext, EffectSpec, ParameterSpec
from .switching import Switching


def _first_order(m0: float, target: np.ndarray, h: np.ndarray, tau: float) -> np.ndarray:
    """Exact samples of dm/dt = (z(t) - m)/tau, z linear between the samples `target`."""
    x = h / tau
    a = np.exp(-x)
    one_minus_a = -np.expm1(-x)
    q = np.where(x > 0, one_minus_a / np.where(x > 0, x, 1.0), 1.0)
    f = np.diff(target) * (1.0 - q) + one_minus_a * target[:-1]
    out = np.empty_like(target)
    out[0] = m0
    if len(h):
        W = linear_recurrence(np.array([m0], dtype=float), (-x)[:, None], a[:, None], f[:, None])
        out[1:] = W[:, 0]
    return out


def play_operator(u: np.ndarray, b: float, w0: float) -> np.ndarray:
    """Play operator of width b, vectorised over monotone runs of u.

    Within a run where u does not fall, w_k = max(w_start, u_k - b/2); where
    it does not rise, w_k = min(w_start, u_k + b/2); equal to the recursion
    of the module docstring.
    """
    h = b / 2
    w = np.empty_like(u)
    w[0] = min(u[0] + h, max(u[0] - h, w0))
    du = np.diff(u)
    sgn = branches(du)
    cuts = np.r_[0, np.flatnonzero(np.diff(sgn)) + 1, len(du)]
    for s0, s1 in zip(cuts[:-1], cuts[1:]):
        seg = u[s0 + 1 : s1 + 1]
        if s1 == s0:
            continue
        if sgn[s0] > 0:
            w[s0 + 1 : s1 + 1] = np.maximum(w[s0], seg - h)
        else:
            w[s0 + 1 : s1 + 1] = np.minimum(w[s0], seg + h)
    return w


def _taus(ctx: EffectContext) -> np.ndarray:
    """Starting time constants: geomspace(3 dt_min, max(duration / 10, 10 dt_min), 4)."""
    return np.geomspace(3 * ctx.dt_min, max(ctx.duration / 10, 10 * ctx.dt_min), 4)


class Backlash(EffectSpec):
    """Step 1 of the chain (module docstring): the play operator on the base input."""

    name = "backlash"
    description = "mechanical play: the input must travel b across a dead band before the output follows"
    stage = "input"
    timed = False
    loop_shape = True
    parameters = (ParameterSpec("b", 0.0, INF),)
    state = ("w",)
    example = {"b": 0.1}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        chain.w = play_operator(chain.u, p["b"], chain.u[0] if s0 is None else s0[0])
        return (float(chain.w[-1]),)

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        return [{"b": 0.01 * ctx.u_span}, {"b": 0.05 * ctx.u_span}]


class RateDependence(EffectSpec):
    """Step 2 of the chain: the base dynamics slowed by 1 / (1 + alpha |dw/dt|)."""

    name = "rate_dependence"
    description = "rate-dependent lag: the faster the input moves, the less the loop keeps up"
    stage = "rate"
    timed = True
    parameters = (ParameterSpec("alpha", 0.0, INF),)
    example = {"alpha": 0.3}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        s = 1.0 / (1.0 + p["alpha"] * np.abs(np.diff(chain.w) / chain.h))
        chain.r, chain.S = chain.r / s, chain.S * s
        return ()

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        return [{"alpha": 0.05 / ctx.v95}, {"alpha": 0.5 / ctx.v95}]


class Creep(EffectSpec):
    """Step 4 of the chain: y += c, dc/dt = (k u - c) / tau."""

    name = "creep"
    description = "creep of the material: a slow first-order approach of the output after input changes"
    stage = "output"
    additive = True
    timed = True
    parameters = (ParameterSpec("k", -INF, INF), ParameterSpec("tau", 0.0, INF, strict=True, log=True))
    state = ("c",)
    example = {"k": 0.05, "tau": 3.0}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        k = p["k"]
        c = _first_order(k * chain.u[0] if s0 is None else s0[0], k * chain.u, chain.h, p["tau"])
        chain.y = chain.y + c
        return (float(c[-1]),)

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        return [{"k": 0.0, "tau": float(tau)} for tau in _taus(ctx)]

    def memory_taus(self, p: dict[str, float]) -> list[float]:
        return [p["tau"]]

    def null(self, ctx: EffectContext) -> dict[str, float]:
        return {"k": 0.0, "tau": 10 * ctx.dt_min}


RELAXATION_TERMS = 4
"""Number of time constants of the `relaxation` spectrum."""


def relaxation_taus(tau_min: float, tau_max: float, m: int = RELAXATION_TERMS) -> np.ndarray:
    """tau_i = tau_min (tau_max / tau_min)^(i / (m - 1)), i = 0..m-1: log-spaced from tau_min to tau_max."""
    return tau_min * (tau_max / tau_min) ** (np.arange(m) / (m - 1))


class Relaxation(EffectSpec):
    """Step 5 of the chain: y += sum_i c_i, dc_i/dt = (k_i u - c_i) / tau_i, tau_i log-spaced (a Prony series)."""

    name = "relaxation"
    description = (
        "a relaxation spectrum of the material: the output follows input changes through several time "
        "constants (dielectric or viscoelastic relaxation; the longest also takes a leakage current)"
    )
    stage = "output"
    additive = True
    timed = True
    parameters = (
        (ParameterSpec("k", -INF, INF),)
        + tuple(ParameterSpec(f"w{i}", 0.0, INF) for i in range(2, RELAXATION_TERMS + 1))
        + (
            ParameterSpec("tau_min", 0.0, INF, strict=True, log=True),
            ParameterSpec("tau_max", 0.0, INF, strict=True, log=True),
        )
    )
    state = tuple(f"c{i + 1}" for i in range(RELAXATION_TERMS))
    example = {"k": 0.08, "w2": 1.0, "w3": 1.0, "w4": 1.0, "tau_min": 0.3, "tau_max": 30.0}

    @staticmethod
    def gains(p: dict[str, float]) -> list[float]:
        """k_i = k w_i / (w_1 + ... + w_m), w_1 = 1."""
        w = [1.0] + [p[f"w{i}"] for i in range(2, RELAXATION_TERMS + 1)]
        total = sum(w)
        return [p["k"] * wi / total for wi in w]

    def c_constants(self) -> dict[str, int | float | tuple[float, ...]]:
        """The number of first-order terms."""
        return {"TERMS": RELAXATION_TERMS}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        ends = []
        for i, (k, tau) in enumerate(zip(self.gains(p), relaxation_taus(p["tau_min"], p["tau_max"]))):
            c = _first_order(k * chain.u[0] if s0 is None else s0[i], k * chain.u, chain.h, float(tau))
            chain.y = chain.y + c
            ends.append(float(c[-1]))
        return tuple(ends)

    def bounds(self, ctx: EffectContext) -> dict[str, tuple[float, float]]:
        """The default bounds, but tau_max up to 10 durations: a time constant beyond the experiment turns its
        state into the integral of u (a leakage current), not a drift in time, so it stays this effect's.  The
        shares w_i within 1e-2..1e2 of the first term's: a term of a hundredth of another's share is below what a
        recording determines, and unbounded shares trade off with the time constants without end (the tests'
        seed-0 relaxation experiment ended, on one machine, at shares of 4e8 and k half the truth's, 1.19 times
        the noise; within these bounds at k 6 % from the truth's, at the noise)."""
        out = super().bounds(ctx)
        out["tau_max"] = (out["tau_max"][0], 10 * out["tau_max"][1])
        for i in range(2, RELAXATION_TERMS + 1):
            out[f"w{i}"] = (1e-2, 1e2)
        return out

    def memory_taus(self, p: dict[str, float]) -> list[float]:
        return [float(tau) for tau in relaxation_taus(p["tau_min"], p["tau_max"])]

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        """The null spectrum (3 samples to the duration), and one from a thousandth to a third of the duration."""
        null = self.null(ctx)
        return [null, dict(null, tau_min=null["tau_max"] / 1000, tau_max=null["tau_max"] / 3)]

    def null(self, ctx: EffectContext) -> dict[str, float]:
        """k = 0, equal shares, tau from 3 samples to the duration (at least 30 samples)."""
        return dict(
            {"k": 0.0, **{f"w{i}": 1.0 for i in range(2, RELAXATION_TERMS + 1)}},
            tau_min=3 * ctx.dt_min,
            tau_max=max(ctx.duration, 30 * ctx.dt_min),
        )


class Viscous(EffectSpec):
    """Step 7 of the chain: y += c du/dt."""

    name = "viscous"
    description = "viscous damping: an output offset proportional to the input rate"
    stage = "output"
    additive = True
    timed = True
    parameters = (ParameterSpec("c", -INF, INF),)
    example = {"c": 0.02}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        chain.y = chain.y + p["c"] * np.r_[0.0, np.diff(chain.u) / chain.h]
        return ()


class ThermalDrift(EffectSpec):
    """Step 8 of the chain: y *= 1 - kappa W, W the input travel."""

    name = "thermal_drift"
    description = "thermal drift: the gain changes in proportion to the input travel (self-heating)"
    stage = "output"
    steady = False
    timed = False
    parameters = (ParameterSpec("kappa", -INF, INF),)
    state = ("W",)
    example = {"kappa": 0.01}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        W = (0.0 if s0 is None else s0[0]) + np.r_[0.0, np.cumsum(np.abs(np.diff(chain.u)))]
        chain.y = chain.y * (1.0 - p["kappa"] * W)
        return (float(W[-1]),)

    def afresh(self, p: dict[str, float]) -> tuple:
        """No travel yet: W_0 = 0."""
        return (0.0,)


class Saturation(EffectSpec):
    """Step 9 of the chain: y -> y_c + tanh(beta (y - y_c)) / beta."""

    name = "saturation"
    description = "saturation: the output flattens smoothly (tanh) away from a centre y_c"
    stage = "output"
    timed = False
    loop_shape = True
    parameters = (ParameterSpec("y_c", -INF, INF), ParameterSpec("beta", 0.0, INF))
    example = {"y_c": 0.0, "beta": 0.4}
    strength = "beta"

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        yc, beta = p["y_c"], p["beta"]
        if beta > 0:
            chain.y = yc + np.tanh(beta * (chain.y - yc)) / beta
        return ()

    def bounds(self, ctx: EffectContext) -> dict[str, tuple[float, float]]:
        return {**super().bounds(ctx), "y_c": (ctx.y_min, ctx.y_max)}

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        half = max(ctx.y_max - ctx.y_min, 1e-300) / 2
        return [{"y_c": ctx.y_mean, "beta": 0.5 / half}, {"y_c": ctx.y_mean, "beta": 1.5 / half}]

    def null(self, ctx: EffectContext) -> dict[str, float]:
        return {"y_c": ctx.y_mean, "beta": 0.0}


class SensorLag(EffectSpec):
    """Step 10 of the chain: the measured output m, dm/dt = (y - m) / tau."""

    name = "sensor_lag"
    description = "sensor lag: the measurement follows the output as a first-order low-pass"
    origin = "measurement"
    stage = "output"
    follows_output = True
    timed = True
    parameters = (ParameterSpec("tau", 0.0, INF, log=True),)
    state = ("m", "y")
    example = {"tau": 0.05}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        target, tau = chain.y, p["tau"]
        y_last = float(target[-1]) if s0 is None or len(target) > 1 else s0[1]
        if tau > 0:
            if s0 is not None:
                target = target.copy()
                target[0] = s0[1]
            chain.y = _first_order(target[0] if s0 is None else s0[0], target, chain.h, tau)
        return (float(chain.y[-1]), y_last)

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        return [{"tau": float(tau)} for tau in _taus(ctx)[:3]]

    def null(self, ctx: EffectContext) -> dict[str, float]:
        return {"tau": math.exp(math.log(0.05 * ctx.dt_min) + 1e-6)}


class MeasurementDrift(EffectSpec):
    """Step 11 of the chain: y += rate (t - t_0), a measurement drift linear in time."""

    name = "measurement_drift"
    description = (
        "a measurement drift of the output, linear in time (an offset current integrated by the "
        "charge amplifier, a wandering sensor zero): a property of the measurement, not of the material"
    )
    origin = "measurement"
    stage = "output"
    steady = False
    additive = True
    offset = "d"
    timed = True
    parameters = (ParameterSpec("rate", -INF, INF),)
    state = ("d",)
    example = {"rate": 0.01}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        d = (0.0 if s0 is None else s0[0]) + p["rate"] * (chain.t - chain.t[0])
        chain.y = chain.y + d
        return (float(d[-1]),)

    def afresh(self, p: dict[str, float]) -> tuple:
        """At its origin: d_0 = 0 + rate (t_0 - t_0), as `apply` computes it (NaN for an infinite rate)."""
        return (0.0 + p["rate"] * 0.0,)


REGISTRY: dict[str, EffectSpec] = {
    spec.name: spec
    for spec in (
        Backlash(),
        RateDependence(),
        Creep(),
        Relaxation(),
        Switching(),
        Viscous(),
        ThermalDrift(),
        Saturation(),
        SensorLag(),
        MeasurementDrift(),
    )
}
"""Effect name -> `EffectSpec`, in chain order."""
