"""Effect extensions of the semilinear Duhem models (what `duhem diagnose` adds).

An effect is a small, exactly discretised extension with its own parameters,
stored in the model JSON as ``"effects": [{"effect": name, "parameters": {...}}]``
(absent = none).  `kernel.simulate` and `stepper.Stepper` both run the chain
below through `run_with_effects`, so FMUs run it unchanged.

Input semantics are the kernel's: the input u is piecewise linear between the
samples t_0 < t_1 < ... (for a rate-independent model without time, t_k = k).
On interval k (from sample k to k+1): h_k = t_{k+1} - t_k, du_k = u_{k+1} - u_k,
v_k = du_k / h_k (constant on the interval).

The chain, always applied in this order whatever the order of the list:

1. ``backlash`` {b >= 0}: the base model sees the play operator's output
   w_k = min(u_k + b/2, max(u_k - b/2, w_{k-1})), w_0 = u_0, taken piecewise
   linear between samples (exact for a rate-independent base, whose state
   depends only on the path of w; for a rate-dependent base this is the
   specified discretisation).
2. ``rate_dependence`` {alpha >= 0}: the base dynamics are slowed by
   s(v) = 1 / (1 + alpha |v|), v the rate of the base input w on the
   interval: rate-independent base, dx/dt = v s(|v|) (A± x + B± w + E±) (the
   paper's g(du/dt) of eq (18), on top of eqs (1)-(2)); rate-dependent base,
   g(v) becomes g(v) s(v).  Exact, since v is constant per interval: in the
   kernel's interval coefficients (p, r, S) of (K), S -> S s and r -> r / s.
3. Base output y_b = C x + D w.
4. ``creep`` {k, tau > 0}: an extra state dc/dt = (k u - c) / tau, c_0 = k u_0,
   y += c.  Exact for u linear on the interval:
   c_{k+1} = a c_k + k [du_k (1 - q) + (1 - a) u_k], a = e^{-h/tau},
   q = (1 - a) / (h / tau).
5. ``viscous`` {c}: y += c v, v the rate of u on the interval that ends at the
   sample (0 at the first sample).
6. ``thermal_drift`` {kappa}: y *= 1 - kappa W, W_k = sum_{j<k} |du_j| the
   input travel since the start of the experiment (W_0 = 0).
7. ``saturation`` {y_c, beta >= 0}: y -> y_c + tanh(beta (y - y_c)) / beta
   (beta = 0: unchanged; y_s = 1/beta is the saturation half-range).
8. ``sensor_lag`` {tau >= 0}: the measured output m obeys dm/dt = (y - m)/tau
   with y (the output of steps 3-7) taken linear between samples, m_0 = y_0:
   m_{k+1} = a m_k + dy_k (1 - q) + (1 - a) y_k with a, q as in 4 (tau = 0:
   m = y).

The chain's state at a sample is `EffectState` (w, c, W, m, y): the play
output, the creep state, the travel, the measured output, and the output before
the lag.  This module needs only numpy: it is shipped inside the FMUs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from .errors import EffectError, KernelError
from .kernel import _linear_recurrence, integrate, interval_coefficients

__all__ = ["EFFECTS", "EffectError", "Effect", "EffectState", "effects_from_list", "run_with_effects"]




_REAL = (-math.inf, math.inf)
_NONNEG = (0.0, math.inf)
_POS = (0.0, math.inf, "positive")

EFFECTS: dict[str, dict[str, tuple]] = {
    "backlash": {"b": _NONNEG},
    "rate_dependence": {"alpha": _NONNEG},
    "creep": {"k": _REAL, "tau": _POS},
    "viscous": {"c": _REAL},
    "thermal_drift": {"kappa": _REAL},
    "saturation": {"y_c": _REAL, "beta": _NONNEG},
    "sensor_lag": {"tau": _NONNEG},
}
"""Effect name -> parameter name -> allowed range, in the chain's order."""

_TIMED = {"rate_dependence", "creep", "viscous", "sensor_lag"}


@dataclass
class Effect:
    """One effect: its name (a key of `EFFECTS`) and its parameters."""

    effect: str
    parameters: dict = field(default_factory=dict)

    def __post_init__(self):
        spec = EFFECTS.get(self.effect)
        if spec is None:
            raise EffectError(f"unknown effect {self.effect!r} (known: {', '.join(EFFECTS)})")
        if not isinstance(self.parameters, dict) or set(self.parameters) != set(spec):
            got = sorted(self.parameters) if isinstance(self.parameters, dict) else self.parameters
            raise EffectError(f"effect {self.effect!r}: parameters must be {sorted(spec)}, got {got}")
        clean = {}
        for name, rng in spec.items():
            try:
                value = float(self.parameters[name])
            except (TypeError, ValueError):
                raise EffectError(f"effect {self.effect!r}: parameter {name} is not a number") from None
            strict = len(rng) > 2
            if not math.isfinite(value) or value < rng[0] or (strict and value <= rng[0]):
                need = "positive" if strict else (">= 0" if rng[0] == 0 else "finite")
                raise EffectError(f"effect {self.effect!r}: parameter {name} = {value} must be {need}")
            clean[name] = value
        self.parameters = clean

    def to_dict(self) -> dict:
        return {"effect": self.effect, "parameters": dict(self.parameters)}


def effects_from_list(items) -> list[Effect]:
    """Validate a list of `Effect` or ``{"effect", "parameters"}`` dicts (each name at most once)."""
    if items is None:
        return []
    if not isinstance(items, (list, tuple)):
        raise EffectError(f"'effects' must be a list, got {type(items).__name__}")
    out = []
    for item in items:
        if isinstance(item, Effect):
            out.append(Effect(item.effect, dict(item.parameters)))
        elif isinstance(item, dict) and set(item) == {"effect", "parameters"}:
            out.append(Effect(item["effect"], item["parameters"]))
        else:
            raise EffectError(f"each effect must be {{'effect': name, 'parameters': {{...}}}}, got {item!r}")
    names = [e.effect for e in out]
    dup = [n for n in set(names) if names.count(n) > 1]
    if dup:
        raise EffectError(f"effect {dup[0]!r} is listed more than once")
    return out


class EffectState(NamedTuple):
    """State of the effect chain at one sample (see the module docstring)."""

    w: float
    c: float
    W: float
    m: float
    y: float


def _play(u: np.ndarray, b: float, w0: float) -> np.ndarray:
    """Play operator of width b, vectorised over monotone runs of u.

    Within a run where u does not fall, w_k = max(w_start, u_k - b/2); where
    it does not rise, w_k = min(w_start, u_k + b/2); equal to the recursion
    of the module docstring.
    """
    h = b / 2
    w = np.empty_like(u)
    w[0] = min(u[0] + h, max(u[0] - h, w0))
    du = np.diff(u)
    sgn = np.sign(du)
    idx = np.where(sgn != 0, np.arange(len(du)), 0)
    np.maximum.accumulate(idx, out=idx)
    sgn = np.where(sgn[idx] == 0, 1.0, sgn[idx])
    cuts = np.r_[0, np.flatnonzero(np.diff(sgn)) + 1, len(du)]
    for s0, s1 in zip(cuts[:-1], cuts[1:]):
        seg = u[s0 + 1:s1 + 1]
        if s1 == s0:
            continue
        if sgn[s0] > 0:
            w[s0 + 1:s1 + 1] = np.maximum(w[s0], seg - h)
        else:
            w[s0 + 1:s1 + 1] = np.minimum(w[s0], seg + h)
    return w


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
        W = _linear_recurrence(np.array([m0]), (-x)[:, None].astype(complex), a[:, None].astype(complex),
                               f[:, None].astype(complex))
        out[1:] = W[:, 0].real
    return out


def run_with_effects(model, t: np.ndarray, u: np.ndarray, x0: np.ndarray, fl: dict,
                     state0: EffectState | None = None):
    """Simulate `model` with its effects over the samples (t, u).

    Parameters
    ----------
    model : model with a non-empty ``effects`` list
    t, u : checked sample arrays (t increasing where a timed effect is present)
    x0 : base state at the first sample
    fl : the model's flows (`kernel.flows`)
    state0 : effect state at the first sample; None starts the chain afresh
        (w_0 = u_0, c_0 = k u_0, W_0 = 0, m_0 = y_0).

    Returns
    -------
    X : (N, n) base states, y : (N,) measured outputs, end : `EffectState` at the last sample.
    """
    eff = {e.effect: e.parameters for e in model.effects}
    h = np.diff(t)
    if _TIMED & set(eff):
        bad = np.flatnonzero(h <= 0)
        if bad.size:
            raise KernelError(f"time must increase: t[{bad[0] + 1}] = {t[bad[0] + 1]} "
                              f"after t[{bad[0]}] = {t[bad[0]]}")
    w = u
    if "backlash" in eff:
        w = _play(u, eff["backlash"]["b"], u[0] if state0 is None else state0.w)
    branch, p, r, S = interval_coefficients(model, t, w)
    if "rate_dependence" in eff:
        s = 1.0 / (1.0 + eff["rate_dependence"]["alpha"] * np.abs(np.diff(w) / h))
        r, S = r / s, S * s
    X = integrate(fl, x0, branch, p, r, S)
    y = X @ model.C + model.D * w
    c_end = 0.0
    if "creep" in eff:
        k, tau = eff["creep"]["k"], eff["creep"]["tau"]
        c = _first_order(k * u[0] if state0 is None else state0.c, k * u, h, tau)
        y = y + c
        c_end = c[-1]
    if "viscous" in eff:
        y = y + eff["viscous"]["c"] * np.r_[0.0, np.diff(u) / h]
    W = (0.0 if state0 is None else state0.W) + np.r_[0.0, np.cumsum(np.abs(np.diff(u)))]
    if "thermal_drift" in eff:
        y = y * (1.0 - eff["thermal_drift"]["kappa"] * W)
    if "saturation" in eff:
        yc, beta = eff["saturation"]["y_c"], eff["saturation"]["beta"]
        if beta > 0:
            y = yc + np.tanh(beta * (y - yc)) / beta
    y_pre = y
    if "sensor_lag" in eff and eff["sensor_lag"]["tau"] > 0:
        target = y_pre.copy()
        if state0 is not None:
            target[0] = state0.y
        y = _first_order(target[0] if state0 is None else state0.m, target, h, eff["sensor_lag"]["tau"])
    end = EffectState(w=float(w[-1]), c=float(c_end), W=float(W[-1]), m=float(y[-1]), y=float(y_pre[-1]))
    return X, y, end
