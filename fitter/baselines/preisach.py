"""The discrete Preisach model (relays on a triangular grid), a `HysteronBaseline`."""

from __future__ import annotations

import numpy as np

from fitter.baselines.base import ROW_BLOCK
from fitter.baselines.hysterons import HysteronBaseline


class Preisach(HysteronBaseline):
    """Discrete Preisach model: a triangular grid of relays, weights by NNLS.

    Model (normalised units)::

        y(t) = c + d u(t) + sigma sum_{0 <= j <= i < L} w_ij R_ij[u](t),   w_ij >= 0,

    with the L + 1 grid levels e_0 = min u < e_1 < ... < e_L = max u of the
    fitted data (equally spaced) and the relay R_ij of thresholds alpha_i =
    e_{i+1} (up) > beta_j = e_j (down): R = +1 once u >= alpha_i, -1 once u <=
    beta_j, unchanged in between.  L(L+1)/2 relays (300 for L = 24), every one
    at least one grid step wide, so each switches up and down on the fitted
    data.  The linear term d u is included (chosen: it models the reversible,
    non-hysteretic part, e.g. a piezo's linear dielectric polarisation, that
    relays of finite width represent only in steps); c and d are free, the
    weights non-negative and sigma = +-1 the loop's orientation (`fitter.baselines.hysterons`
    docstring, "Linear hysteron models").

    Relay states are computed without a loop over time: for each threshold,
    the index of the last sample at or beyond it (np.maximum.accumulate over
    the sample indices); a relay is up when its last up-crossing is later than
    its last down-crossing.  Initial state: the fitted input history (`fitter.baselines.hysterons`
    docstring): ("below", m) leaves the relays with alpha <= m up and the
    others down, ("above", m) those with beta >= m down and the others up;
    the first sample u_0 then switches the relays it reaches.  L(L+1)/2 + 2
    coefficients.

    Parameters
    ----------
    levels : L, the number of grid steps (default 24).
    nonnegative : weights >= 0 (default, the classical Preisach density); False: free.
    deadband : see `Baseline`.
    """

    name = "preisach"
    _constant_prefix = True

    def _configure(self, lo: float, hi: float) -> None:
        i, j = np.tril_indices(self.levels)
        self._alpha_index, self._beta_index = i, j
        self.alpha_, self.beta_ = self.edges_[1:][i], self.edges_[:-1][j]

    @staticmethod
    def _last(hit: np.ndarray) -> np.ndarray:
        """Per column, the last row index <= k where `hit` is true (-1 before the first)."""
        idx = np.where(hit, np.arange(hit.shape[0], dtype=np.int32)[:, None], np.int32(-1))
        return np.maximum.accumulate(idx, axis=0)

    def _bounds(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        up = self._last(u[:, None] >= self.edges_[None, 1:])
        down = self._last(u[:, None] <= self.edges_[None, :-1])
        n, m = len(u), len(self.alpha_)
        lo, hi = np.empty((n, m), dtype=np.int8), np.empty((n, m), dtype=np.int8)
        for a in range(0, n, ROW_BLOCK):
            rows = slice(a, a + ROW_BLOCK)
            last_up, last_down = up[rows][:, self._alpha_index], down[rows][:, self._beta_index]
            lo[rows] = np.where(last_up > last_down, 1, -1)
            hi[rows] = np.where(last_down > last_up, -1, 1)
        return lo, hi

    def _after(self, side: str, m: float) -> np.ndarray:
        if side == "below":
            return np.where(self.alpha_ <= m, 1, -1).astype(np.int8)
        return np.where(self.beta_ >= m, -1, 1).astype(np.int8)

    def _settings(self) -> dict:
        return {
            "levels": self.levels,
            "relays": self.levels * (self.levels + 1) // 2,
            "linear_term": True,
            "nonnegative": self.nonnegative,
            "deadband": self.deadband,
        }
