"""Linear hysteron models' shared machinery: element paths, normal equations, the NNLS solve and the
fitted input history (`HysteronBaseline`; `Preisach` and `PrandtlIshlinskii` build on it).

Input history (the initial state of relays and plays)
-----------------------------------------------------
The state of a relay or a play at the first sample depends on the input
before it.  The fitted history is a *staircase*: the input came from far
below (negative saturation), rose to a turning point m >= u_0 and fell to
u_0 ("below", m), or came from far above, fell to m <= u_0 and rose to u_0
("above", m).  ("below", u_0) is the input rising into u_0 from saturation,
("above", u_0) falling into it; a large m ("below") is the same as
("above", u_0), a small m ("above") the same as ("below", u_0).
Candidates: m = u_0 +- k Delta, k = 0 .. levels, Delta = the grid step of
the model (span of u_n / levels); histories leaving the same states are one
candidate.

Exact initial-state algebra.  A relay and a play both map their state before
a sample to the state after it by a clamp, x -> min(b, max(a, x)), and a
composition of clamps is a clamp.  So the state at sample k started from any
s0 is ``clip(s0, lo_k, hi_k)``, where lo and hi are the paths started from
-inf and +inf (for a relay, -1 and +1).  Once lo_k = hi_k the initial state is
forgotten; from the first sample T* where this holds for every element on,
the design matrix does not depend on the candidate.

Linear hysteron models (Preisach, Prandtl-Ishlinskii)
-----------------------------------------------------
y_n = c + d u_n + sigma sum_j w_j h_j[u_n](t) with w_j >= 0, c and d free,
and the orientation sigma = +1 or -1.  Non-negative weights make the
classical counter-clockwise loop (the rising branch below the falling one,
as a piezo's P-E loop); a clockwise loop (a friction force against the
velocity) needs sigma = -1: both are fitted and the one with the smaller
residual is kept (sigma is a structural choice and not counted as a
parameter; each recording's history counts as one).  ``nonnegative=False``
leaves the weights free (ordinary least squares; sigma is then moot).

The weights are the non-negative least-squares solution over all samples
of all recordings (scipy.optimize.nnls).  Each recording is reduced to its
normal equations, the Gram matrix of [1, u, h_1 .. h_M, y] (`_Normal`: the
rows from T* on once, the first T* rows per candidate history); c and d
are eliminated exactly (Schur complement) and NNLS runs on the Cholesky
factor of the reduced M x M matrix, with a 1e-10 relative ridge that keeps
it positive definite (`_solve_normal`): the minimiser of the squared error
over all samples, up to that ridge.

The histories are fitted by alternation from two starts, the first
candidate of each side for every recording (("below", u_0), and ("above",
u_0) unless that is a "below" candidate already, then the next "above"
one): weights for the current histories, then for each recording the
candidate with the least squared error under these weights, until no
history changes; the start (and sigma) with the smaller residual is kept.
Then, since the candidates of a recording form a cycle (("below", m) for
growing m ends at ("above", u_0), ("above", m) for falling m at ("below",
u_0)), each recording's history steps to its neighbours on the cycle, the
weights refitted at every step, as long as the squared error falls.  This
is a local search: the best history of the family is not guaranteed.
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import nnls

from fitter.baselines.base import ROW_BLOCK, Baseline, BaselineError


# ---------------------------------------------------------------- hysteron models (Preisach, PI)
@dataclass
class _Paths:
    """The element paths of one recording: lo, hi (N x M, module docstring "Exact initial-state
    algebra"), T* (rows from T* on do not depend on the initial state) and the candidate histories
    (their element states s0, one row each, and their (side, m))."""

    u: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    t_star: int
    tau: np.ndarray
    """Per element, the first row where lo = hi (T* if none before it)."""
    s0: np.ndarray
    histories: list[tuple[str, float]]
    starts: dict[str, int]
    """The first candidate of each side: ("below", u_0), and ("above", u_0) unless that is a
    "below" one already (then the next "above" one)."""

    def columns(self, rows: slice, s0: np.ndarray) -> np.ndarray:
        """Element states on `rows` started from s0 (float)."""
        return np.clip(s0, self.lo[rows], self.hi[rows]).astype(float)

    def design(self, rows: slice, s0: np.ndarray, y: np.ndarray | None = None) -> np.ndarray:
        """Design rows [1, u, h_1 .. h_M (, y)]."""
        u = self.u[rows]
        parts = [np.ones((len(u), 1)), u[:, None], self.columns(rows, s0)]
        return np.hstack(parts + ([y[rows, None]] if y is not None else []))


def _gram(p: _Paths, rows: range, s0: np.ndarray, y: np.ndarray) -> np.ndarray:
    """D^T D of the design rows [1, u, h(s0), y] in `rows`, summed block by block."""
    g = np.zeros((p.lo.shape[1] + 3,) * 2)
    for a in range(rows.start, rows.stop, ROW_BLOCK):
        d = p.design(slice(a, min(a + ROW_BLOCK, rows.stop)), s0, y)
        g += d.T @ d
    return g


class _Normal:
    """Normal equations (Gram of [1, u, h_1 .. h_M, y]) of one recording per candidate history.

    G(k) = Gram of the rows from T* on (once) + Gram of the first T* rows of
    candidate k.  With `constant_prefix` (relays: before a relay's first
    switch, at row tau_j, its state is its initial state), candidate k
    differs from candidate 0 by E[t, j] = s0_k[j] - s0_0[j] for t < tau_j, so
    G(k) = G(0) + X0^T E + E^T X0 + E^T E, where X0^T E is read from the
    prefix sums of candidate 0's design rows and (E^T E)_ij = e_i e_j
    min(tau_i, tau_j): O(M^2) per candidate instead of O(T* M^2).
    """

    def __init__(self, p: _Paths, y: np.ndarray, constant_prefix: bool):
        self.p, self.y, self.constant = p, y, constant_prefix
        self.tail = _gram(p, range(p.t_star, len(p.u)), p.s0[0], y)
        self._cache: dict[int, np.ndarray] = {}
        if constant_prefix:
            self.tau = p.tau
            self.cuts = np.unique(self.tau)
            self.base, self.sums = self._prefix(p, y)

    def _prefix(self, p: _Paths, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """G(0), and the sums of candidate 0's design rows t < c for each c in `cuts` (blocks of rows)."""
        base, running = self.tail.copy(), np.zeros(len(self.tail))
        sums = np.zeros((len(self.cuts), len(self.tail)))
        for a in range(0, p.t_star, ROW_BLOCK):
            b = min(a + ROW_BLOCK, p.t_star)
            d = p.design(slice(a, b), p.s0[0], y)
            base += d.T @ d
            partial = np.cumsum(d, axis=0)
            inside = (self.cuts > a) & (self.cuts <= b)
            sums[inside] = running + partial[self.cuts[inside] - a - 1]
            running += partial[-1]
        return base, sums

    def __call__(self, k: int) -> np.ndarray:
        if k not in self._cache:
            self._cache[k] = (
                self._constant(k)
                if self.constant
                else self.tail + _gram(self.p, range(0, self.p.t_star), self.p.s0[k], self.y)
            )
        return self._cache[k]

    def _constant(self, k: int) -> np.ndarray:
        p = self.p
        e = np.clip(p.s0[k], p.lo[0], p.hi[0]).astype(float) - np.clip(p.s0[0], p.lo[0], p.hi[0])
        changed = np.flatnonzero(e)
        g = self.base.copy()
        if changed.size:
            cols = changed + 2
            cross = e[changed, None] * self.sums[np.searchsorted(self.cuts, self.tau[changed])]  # (E^T X0)
            g[cols, :] += cross
            g[:, cols] += cross.T
            g[np.ix_(cols, cols)] += np.outer(e[changed], e[changed]) * np.minimum.outer(
                self.tau[changed], self.tau[changed]
            )
        return g


_MIN_RANK = 2
"""Fewest independent element columns (beyond 1 and u) a fit accepts: `_check_rank`."""
_RANK_TOL = 1e-9
"""Eigenvalues below this fraction of the largest count as zero in `_check_rank`."""


def _check_rank(g: np.ndarray) -> None:
    """Raise LinAlgError when the elements carry fewer than `_MIN_RANK` directions beyond [1, u].

    The element block's Gram with 1 and u eliminated (Schur complement) is
    tested for its numerical rank: eigenvalues above `_RANK_TOL` times the
    largest.  An input outlier leaves every element a combination of one
    spike and one step (rank <= 1, the rest at rounding, ~1e-15); a recording
    that drives the elements has a rank of tens (a 100-sample sine: 23 of 23
    plays, 47 relays), so the decision does not rest on a solver's last digits.
    """
    head, basis = slice(0, 2), slice(2, -1)
    g_hh = g[head, head]
    if np.linalg.matrix_rank(g_hh) < 2:
        raise np.linalg.LinAlgError("the input is constant")
    h = g[basis, basis] - g[head, basis].T @ np.linalg.solve(g_hh, g[head, basis])
    eig = np.linalg.eigvalsh(h)
    top = max(float(eig[-1]), 0.0)
    if top == 0.0 or int(np.sum(eig > _RANK_TOL * top)) < _MIN_RANK:
        raise np.linalg.LinAlgError("the elements carry fewer than two directions")


def _solve_normal(g: np.ndarray, nonnegative: bool, n_free: int = 2) -> tuple[np.ndarray, np.ndarray, float]:
    """Minimise ||D [f; w] - y||^2, f free, w >= 0 (or free), from the Gram of [D, y] (module docstring).

    The free f is eliminated (Schur complement), the reduced problem
    w^T H w - 2 g^T w + c is solved by NNLS on its Cholesky factor (H + a
    1e-10 relative ridge, so that it is positive definite), then f.
    Returns (w, f, rss); LinAlgError when `_check_rank` finds the problem singular.
    """
    _check_rank(g)
    free, basis = slice(0, n_free), slice(n_free, -1)
    g_ff, g_fp, g_fy = g[free, free], g[free, basis], g[free, -1]
    elim = np.linalg.solve(g_ff, np.column_stack([g_fp, g_fy]))
    h = g[basis, basis] - g_fp.T @ elim[:, :-1]
    rhs = g[basis, -1] - g_fp.T @ elim[:, -1]
    const = g[-1, -1] - g_fy @ elim[:, -1]
    ridge = 1e-10 * max(float(np.mean(np.diag(h))), 1e-300)
    chol = np.linalg.cholesky(h + ridge * np.eye(len(h)))
    b = solve_triangular(chol, rhs, lower=True)
    if nonnegative:
        w = nnls(chol.T, b, maxiter=50 * len(b))[0]
    else:
        w = solve_triangular(chol.T, b)
    fit = chol.T @ w - b
    f = elim[:, -1] - elim[:, :-1] @ w
    return w, f, max(float(fit @ fit - b @ b + const), 0.0)


class HysteronBaseline(Baseline):
    """y_n = c + d u_n + sigma sum_j w_j h_j[u_n], w_j >= 0 (module docstring, "Linear hysteron models")."""

    initial_state = (
        "the input history before the first sample, fitted per recording: a staircase from "
        "saturation (below or above) through a turning point m to u_0"
    )
    _constant_prefix = False
    """Whether an element keeps its initial state until its paths from -inf and +inf merge (`_Normal`)."""
    _linear_nonnegative = False
    """Whether the linear term d is constrained to d >= 0 like the weights (`PrandtlIshlinskii`, invertible)."""

    def __init__(self, levels: int = 24, nonnegative: bool = True, deadband: bool = True) -> None:
        super().__init__(deadband)
        if levels < 2:
            raise BaselineError(f"levels must be at least 2, not {levels}")
        self.levels = int(levels)
        self.nonnegative = bool(nonnegative)
        self.edges_: np.ndarray | None = None
        self.weights_: np.ndarray | None = None
        self.offset_ = 0.0
        self.slope_ = 0.0
        self.orientation_ = 1.0
        self.histories_: list[tuple[str, float]] = []

    # element-specific parts
    @abstractmethod
    def _configure(self, lo: float, hi: float) -> None:
        """Set the elements (thresholds or radii) for the fitted input range [lo, hi] (normalised)."""

    @abstractmethod
    def _bounds(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """lo, hi: the element paths on u started from -inf and +inf (N x M)."""

    @abstractmethod
    def _after(self, side: str, m: float) -> np.ndarray:
        """Element states after the history from saturation on `side` to the turning point m."""

    @property
    def _step(self) -> float:
        return float(self.edges_[-1] - self.edges_[0]) / self.levels

    def _paths(self, u: np.ndarray) -> _Paths:
        lo, hi = self._bounds(u)
        differ = np.flatnonzero(np.any(lo != hi, axis=1))
        t_star = int(differ[-1]) + 1 if differ.size else 0
        merged = lo[:t_star] == hi[:t_star]
        tau = (
            np.where(merged.any(axis=0), merged.argmax(axis=0), t_star)
            if t_star
            else np.zeros(lo.shape[1], dtype=np.int64)
        )
        steps = self._step * np.arange(self.levels + 1)
        histories = [("below", float(u[0] + s)) for s in steps] + [("above", float(u[0] - s)) for s in steps]
        s0 = np.array([self._after(side, m) for side, m in histories])
        # histories that leave the same element states are one candidate (the first of them kept)
        keep = np.sort(np.unique(np.clip(s0, lo[0], hi[0]), axis=0, return_index=True)[1])
        kept = [histories[k] for k in keep]
        starts = {side: next((i for i, h in enumerate(kept) if h[0] == side), 0) for side in ("below", "above")}
        return _Paths(u, lo, hi, t_star, tau, s0[keep], kept, starts)

    # fit
    def _fit(self, us: list[np.ndarray], ys: list[np.ndarray]) -> None:
        self.edges_ = np.linspace(min(u.min() for u in us), max(u.max() for u in us), self.levels + 1)
        self._configure(float(self.edges_[0]), float(self.edges_[-1]))
        paths = [self._paths(u) for u in us]
        normals = [_Normal(p, y, self._constant_prefix) for p, y in zip(paths, ys)]
        best = None
        for sign in (1.0, -1.0) if self.nonnegative else (1.0,):
            for start in ("below", "above"):
                found = self._alternate(paths, ys, normals, sign, [p.starts[start] for p in paths])
                if best is None or found[-1] < best[-1]:
                    best = found
        sign, w, f, choice, _ = self._walk(paths, normals, *best)
        self.orientation_, self.weights_, self.offset_, self.slope_ = sign, w, sign * f[0], sign * f[1]
        self.histories_ = [p.histories[k] for p, k in zip(paths, choice)]

    def _solve(self, normals, sign: float, choice: list[int]) -> tuple[np.ndarray, np.ndarray, float]:
        """(w, f, rss) for the histories `choice` and output sign `sign` (fitting sign * y)."""
        flip = np.ones(len(normals[0].tail))
        flip[-1] = sign
        g = sum(normal(k) for normal, k in zip(normals, choice)) * np.outer(flip, flip)
        if self._linear_nonnegative:  # the linear term d >= 0 too: only c is free
            w, f, rss = _solve_normal(g, self.nonnegative, n_free=1)
            return w[1:], np.r_[f, w[0]], rss
        return _solve_normal(g, self.nonnegative)

    def _alternate(self, paths, ys, normals, sign: float, choice: list[int]):
        """Weights and histories by alternation from `choice` (module docstring);
        returns (sign, w, f, choice, rss)."""
        for _ in range(100):  # the squared error falls at every change: ends within a few rounds
            w, f, rss = self._solve(normals, sign, choice)
            new = [self._best_history(p, sign * y, w, f, k) for p, y, k in zip(paths, ys, choice)]
            if new == choice:
                break
            fitted, choice = choice, new
        else:
            choice = fitted
        return sign, w, f, choice, rss

    def _walk(self, paths, normals, sign: float, w, f, choice: list[int], rss: float):
        """Refine the histories one recording at a time: step to the next candidate (cyclically, in
        either direction) while the refitted squared error falls (module docstring)."""
        moved = True
        while moved:
            moved = False
            for r, p in enumerate(paths):
                for step in (1, -1):
                    while True:
                        trial = list(choice)
                        trial[r] = (choice[r] + step) % len(p.s0)
                        w_t, f_t, rss_t = self._solve(normals, sign, trial)
                        if not rss_t < rss * (1 - 1e-9):
                            break
                        w, f, choice, rss, moved = w_t, f_t, trial, rss_t, True
        return sign, w, f, choice, rss

    def _history_errors(self, p: _Paths, y: np.ndarray, w: np.ndarray, f: np.ndarray) -> np.ndarray:
        """Squared error on the first T* rows of each candidate history with the coefficients fixed.

        With `_constant_prefix`, candidate k's output is candidate 0's plus
        sum_j w_j e_kj [t < tau_j] (`_Normal`), summed over the elements by
        their tau at once for all candidates.
        """
        rows = slice(0, p.t_star)
        base = f[0] + f[1] * p.u[rows] - y[rows]
        used = np.flatnonzero(w)
        lo, hi = p.lo[rows][:, used], p.hi[rows][:, used]
        if not self._constant_prefix:
            return np.array([np.sum((np.clip(s0[used], lo, hi) @ w[used] + base) ** 2) for s0 in p.s0])
        first = np.clip(p.s0[:, used], p.lo[0, used], p.hi[0, used]).astype(float)
        residual = np.clip(p.s0[0, used], lo, hi) @ w[used] + base
        steps = np.zeros((len(p.s0), p.t_star + 1))
        np.add.at(steps.T, p.tau[used], ((first - first[0]) * w[used]).T)
        shift = steps.sum(axis=1, keepdims=True) - np.cumsum(steps, axis=1)  # sum over tau_j > t
        return np.sum((residual + shift[:, : p.t_star]) ** 2, axis=1)

    def _best_history(self, p: _Paths, y: np.ndarray, w: np.ndarray, f: np.ndarray, current: int) -> int:
        """The candidate with the least error; the current one unless another is strictly better."""
        err = self._history_errors(p, y, w, f)
        k = int(np.argmin(err))
        return k if err[k] < err[current] * (1 - 1e-12) else current

    # predict
    def _predict(self, u: np.ndarray, y: np.ndarray | None) -> np.ndarray:
        p = self._paths(u)
        w = self.orientation_ * self.weights_
        if y is None:
            s0 = self._after(*self.histories_[0])
        else:
            s0 = p.s0[int(np.argmin(self._history_errors(p, y, w, np.array([self.offset_, self.slope_]))))]
        used = np.flatnonzero(w)
        out = self.offset_ + self.slope_ * u
        for a in range(0, len(u), ROW_BLOCK):
            rows = slice(a, a + ROW_BLOCK)
            out[rows] += np.clip(s0[used], p.lo[rows][:, used], p.hi[rows][:, used]) @ w[used]
        return out

    @property
    def parameters(self) -> int:
        self._scale()
        return len(self.weights_) + 2 + self.n_recordings_

    def _fitted(self) -> dict:
        return {
            "offset": self.offset_,
            "slope": self.slope_,
            "orientation": self.orientation_,
            "weights": [float(x) for x in self.weights_],
            "grid": [float(x) for x in self.edges_],
            "histories": [{"side": s, "turning_point": m} for s, m in self.histories_],
        }
