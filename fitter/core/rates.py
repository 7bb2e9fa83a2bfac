"""Rate functions g(du/dt) of the rate-dependent semilinear Duhem model, eq (18).

The paper (Section IV) only asks that g be continuous with g(v) = 0 exactly when
v = 0.  Identification (eq 50) yields g at a finite set of slopes, so the
project stores g as a table and evaluates it with a documented rule:

* the node (0, 0) is always part of the table (the paper's g(0) = 0);
* between nodes, a monotone piecewise-cubic Hermite interpolant (PCHIP,
  Fritsch-Carlson slopes) is used, separately on v <= 0 and v >= 0.  Unlike a
  straight line from the origin to the slowest identified slope it follows the
  curvature of g near zero (the Example 3 sine at w = 0.5 needs that);
* beyond the outermost node on each side g is held constant (saturation), so
  an FMU driven faster than any identified slope stays bounded.

This module needs only numpy: it is shipped inside the FMUs.
"""

from __future__ import annotations

import bisect
from typing import Callable

import numpy as np

__all__ = ["RateFunction", "TabulatedRate", "CallableRate"]


class RateFunction:
    """Base class: a map v -> g(v) evaluated elementwise on arrays."""

    def __call__(self, v: np.ndarray | float) -> np.ndarray:
        raise NotImplementedError

    def to_dict(self) -> dict:
        raise TypeError(
            f"{type(self).__name__} cannot be saved to JSON; tabulate it first (TabulatedRate.from_function)"
        )


def _pchip_slopes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Fritsch-Carlson monotone slopes at the nodes of (x, y), x increasing."""
    h = np.diff(x)
    delta = np.diff(y) / h
    d = np.zeros_like(y)
    if len(x) == 2:
        d[:] = delta[0]
        return d
    w1, w2 = 2 * h[1:] + h[:-1], h[1:] + 2 * h[:-1]  # the interior nodes' weights, all at once
    with np.errstate(divide="ignore", invalid="ignore"):
        harmonic = (w1 + w2) / (w1 / delta[:-1] + w2 / delta[1:])
    d[1:-1] = np.where(delta[:-1] * delta[1:] <= 0, 0.0, harmonic)
    d[0] = _end_slope(h[0], h[1], delta[0], delta[1])
    d[-1] = _end_slope(h[-1], h[-2], delta[-1], delta[-2])
    return d


def _end_slope(h0: float, h1: float, d0: float, d1: float) -> float:
    """Three-point end slope, limited so that the interpolant stays monotone."""
    s = ((2 * h0 + h1) * d0 - h0 * d1) / (h0 + h1)
    if np.sign(s) != np.sign(d0):
        return 0.0
    if np.sign(d0) != np.sign(d1) and abs(s) > abs(3 * d0):
        return 3 * d0
    return s


class _Pchip:
    """Piecewise-cubic Hermite interpolant on one side of zero, constant outside."""

    def __init__(self, x: np.ndarray, y: np.ndarray):
        self.x = x
        self.y = y
        self.d = _pchip_slopes(x, y)
        self._xl, self._yl, self._dl = x.tolist(), y.tolist(), self.d.tolist()

    def __call__(self, v: np.ndarray) -> np.ndarray:
        vc = np.clip(v, self.x[0], self.x[-1])
        k = np.clip(np.searchsorted(self.x, vc) - 1, 0, len(self.x) - 2)
        return _hermite(self.x, self.y, self.d, k, vc)

    def scalar(self, v: float) -> float:
        """The same interpolant at one float (lists and bisect: no numpy overhead)."""
        x = self._xl
        vc = min(max(v, x[0]), x[-1])
        k = min(max(bisect.bisect_left(x, vc) - 1, 0), len(x) - 2)
        return _hermite(x, self._yl, self._dl, k, vc)


def _hermite(x, y, d, k, v):
    """Cubic Hermite interpolant on [x_k, x_{k+1}] with node values y and slopes d."""
    h = x[k + 1] - x[k]
    t = (v - x[k]) / h
    h00 = (1 + 2 * t) * (1 - t) ** 2
    h10 = t * (1 - t) ** 2
    h01 = t * t * (3 - 2 * t)
    h11 = t * t * (t - 1)
    return h00 * y[k] + h10 * h * d[k] + h01 * y[k + 1] + h11 * h * d[k + 1]


class TabulatedRate(RateFunction):
    """g from identified points (v_i, g_i), the paper's pointwise g-hat (eq 50).

    Parameters
    ----------
    v, g : array_like
        Slopes (nonzero, distinct) and the values of g there.  The origin is
        added.  At least one slope of each sign is needed for the model to move
        on both branches; a side without nodes evaluates to g = 0 there, which
        freezes the state on that branch (and is reported by `sides`).
    """

    def __init__(self, v, g):
        v = np.asarray(v, dtype=float).ravel()
        g = np.asarray(g, dtype=float).ravel()
        if v.shape != g.shape or v.size == 0:
            raise ValueError("rate table: v and g must be non-empty and of equal length")
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(g))):
            raise ValueError("rate table: v and g must be finite")
        if np.any(v == 0):
            raise ValueError("rate table: g(0) = 0 is implied; do not list v = 0")
        order = np.argsort(v)
        v, g = v[order], g[order]
        if np.any(np.diff(v) == 0):
            raise ValueError("rate table: duplicate slopes in v")
        self.v, self.g = v, g
        neg, pos = v < 0, v > 0
        self._neg = _Pchip(np.r_[v[neg], 0.0], np.r_[g[neg], 0.0]) if neg.any() else None
        self._pos = _Pchip(np.r_[0.0, v[pos]], np.r_[0.0, g[pos]]) if pos.any() else None

    @classmethod
    def from_function(cls, fun: Callable[[np.ndarray], np.ndarray], v) -> "TabulatedRate":
        """Tabulate a callable at the slopes `v`."""
        v = np.asarray(v, dtype=float)
        return cls(v, np.asarray(fun(v), dtype=float))

    def __call__(self, v):
        if isinstance(v, float):
            side = self._pos if v > 0 else (self._neg if v < 0 else None)
            return 0.0 if side is None else side.scalar(v)
        v = np.asarray(v, dtype=float)
        out = np.zeros_like(v)
        if self._pos is not None:
            m = v > 0
            out[m] = self._pos(v[m])
        if self._neg is not None:
            m = v < 0
            out[m] = self._neg(v[m])
        return out

    def to_dict(self) -> dict:
        return {
            "type": "table",
            "interpolation": "pchip-through-origin, constant beyond ends",
            "v": self.v.tolist(),
            "g": self.g.tolist(),
        }


class CallableRate(RateFunction):
    """g given as a Python callable (not serialisable; tabulate it to save)."""

    def __init__(self, fun: Callable[[np.ndarray], np.ndarray]):
        self.fun = fun

    def __call__(self, v):
        return np.asarray(self.fun(np.asarray(v, dtype=float)), dtype=float)


def as_rate(g) -> RateFunction:
    """Accept a RateFunction or a plain callable."""
    if isinstance(g, RateFunction):
        return g
    if callable(g):
        return CallableRate(g)
    raise TypeError("g must be a RateFunction or a callable")
