"""The Prandtl-Ishlinskii model (weighted play operators), a `HysteronBaseline`."""

from __future__ import annotations

import math

import numpy as np

from fitter.baselines.base import BaselineError
from fitter.baselines.hysterons import HysteronBaseline
from fitter.core.effects import play_operator


class PrandtlIshlinskii(HysteronBaseline):
    """Prandtl-Ishlinskii model: a weighted sum of play operators, weights by NNLS.

    Model (normalised units)::

        y(t) = c + a_0 u(t) + sigma sum_{i=1}^{K-1} w_i F_{r_i}[u](t),   w_i >= 0,

    with play radii r_i = i/K (max u - min u)/2 over the fitted data, i = 0 ..
    K - 1 (K = 24 by default).  The radius-0 play is the identity, so its
    weight is a_0, left free (it is the model's linear term; c is free too);
    the others are non-negative, the classical condition that makes the PI
    operator invertible, and sigma = +-1 is the loop's orientation.  F_r is the play (backlash) operator of width 2r,
    `fitter.core.effects.play_operator`: w_k = min(u_k + r, max(u_k - r,
    w_{k-1})).  K + 1 coefficients (`fitter.baselines.hysterons` docstring, "Linear hysteron
    models").  Initial play states: the fitted input history (`fitter.baselines.hysterons`
    docstring): ("below", m) leaves w = min(m - r, u_0 + r), ("above", m)
    leaves w = max(m + r, u_0 - r).

    Parameters
    ----------
    levels : K, the number of plays including the identity (default 24).
    nonnegative : weights >= 0 (default, the classical invertible PI operator); False: free.
    deadband : see `Baseline`.
    invertible : also constrain the linear term, a_0 >= `min_slope` (normalised units, where the loop's mean
        slope is about 1): every slope of the loop is then positive and `invert` exists (the classical
        invertible PI operator; the free a_0 of the default fit may be negative, a loop that moves against
        its input just after a reversal).  Needs ``nonnegative`` and the counter-clockwise orientation.
    """

    name = "prandtl_ishlinskii"

    def __init__(
        self,
        levels: int = 24,
        nonnegative: bool = True,
        deadband: bool = True,
        invertible: bool = False,
        min_slope: float = 0.05,
    ) -> None:
        super().__init__(levels, nonnegative, deadband)
        self.invertible = bool(invertible)
        self.min_slope = float(min_slope)
        if self.invertible and not (self.nonnegative and self.min_slope > 0):
            raise BaselineError("an invertible Prandtl-Ishlinskii fit needs nonnegative weights and min_slope > 0")
        self._linear_nonnegative = self.invertible

    def _fit(self, us: list[np.ndarray], ys: list[np.ndarray]) -> None:
        if not self.invertible:
            super()._fit(us, ys)
            return
        super()._fit(us, [y - self.min_slope * u for u, y in zip(us, ys)])  # a_0 = min_slope + d, d >= 0
        self.slope_ += self.min_slope

    def _configure(self, lo: float, hi: float) -> None:
        self.radii_ = np.arange(1, self.levels) / self.levels * (hi - lo) / 2

    def _bounds(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lo = np.column_stack([play_operator(u, 2 * r, -math.inf) for r in self.radii_])
        hi = np.column_stack([play_operator(u, 2 * r, math.inf) for r in self.radii_])
        return lo, hi

    def _after(self, side: str, m: float) -> np.ndarray:
        return m - self.radii_ if side == "below" else m + self.radii_

    def _settings(self) -> dict:
        return {
            "levels": self.levels,
            "plays": self.levels,
            "linear_term": (
                f"the radius-0 play, weight >= {self.min_slope:g}"
                if self.invertible
                else "the radius-0 play, weight free"
            ),
            "nonnegative": self.nonnegative,
            "deadband": self.deadband,
            "invertible": self.invertible,
        }

    def invert(self, y: np.ndarray) -> np.ndarray:
        """The input that makes the fitted model output y: the analytic inverse PI operator.

        With a_0 the linear term (the radius-0 play), a_i = sigma w_i and radii r_i, the inverse of
        H[u] = sum_i a_i F_{r_i}[u] (Kuhnen 2003) is the PI operator of radii r'_i = sum_{j<=i} a_j (r_i - r_j)
        and weights a'_0 = 1 / a_0, a'_i = -a_i / (s_i s_{i-1}), s_i = sum_{j<=i} a_j, applied to y - c, its
        initial play states z'_i = s_i z_i + sum_{j>i} a_j z_j from the forward states z_i (z_0 the input)
        of the first fitted recording's input history.  It exists when every s_i > 0 (the loop's slope
        never vanishes); u is returned in the data's units.

        Raises
        ------
        BaselineError
            Not fitted, fitted on the input through a dead band (fit with ``deadband=False``: the dead band
            has no inverse), or not invertible (some s_i <= 0).
        """
        scale = self._scale()
        if self.deadband_ > 0:
            raise BaselineError(
                "this Prandtl-Ishlinskii model runs on the input through a dead band, which has no "
                "inverse: fit it with deadband=False to invert it"
            )
        a = np.r_[self.slope_, self.orientation_ * self.weights_]
        r = np.r_[0.0, self.radii_]
        s = np.cumsum(a)
        if np.any(s <= 0):
            raise BaselineError(
                "the Prandtl-Ishlinskii model is not invertible: its loop slope "
                f"a_0 + sum a_i falls to {s.min():.3g} <= 0"
            )
        r_inv = np.array([np.sum(a[: i + 1] * (r[i] - r[: i + 1])) for i in range(len(a))])
        a_inv = np.r_[1.0 / a[0], -a[1:] / (s[1:] * s[:-1])]
        side, m = self.histories_[0]
        z = np.r_[m, self._after(side, m)]
        tail = np.r_[np.cumsum((a * z)[::-1])[::-1][1:], 0.0]  # sum_{j>i} a_j z_j
        z_inv = s * z + tail
        v = scale.y(np.asarray(y, dtype=float)) - self.offset_
        u_n = a_inv[0] * v
        for ri, ai, zi in zip(r_inv[1:], a_inv[1:], z_inv[1:]):
            u_n = u_n + ai * play_operator(v, 2 * ri, zi)
        return scale.u_back(u_n)
