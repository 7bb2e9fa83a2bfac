"""Classical hysteresis models fitted as baselines: Preisach, Prandtl-Ishlinskii, Bouc-Wen.

A user choosing a hysteresis model wants to know how the semilinear Duhem fit
compares with the models they would otherwise pick.  The three estimators
here are the project's own numpy/scipy implementations, with a small common
interface (`Baseline`: ``fit`` on one or more recordings -> one parameter
set, ``predict``, ``score``, ``parameters``, ``to_dict``; `BASELINES` by
name) and `compare_baselines` for the side-by-side NRMSE.

Conventions shared with the Duhem fit
-------------------------------------
* **Samples and preparation.**  The raw recordings, every sample: nothing is
  resampled, trimmed or smoothed.  All three models are rate independent:
  their output depends on the path of u only, not on time.  A recording is
  refused (`BaselineError`, the message names it) when it has fewer than
  `MIN_SAMPLES` samples, no output, a constant input or output, or an input
  that never reverses (`fitter.data.cycles.find_reversals`, the project's
  one reversal rule), and (`fitter.identification.fit_data.FitError`) when
  the Duhem fit's preparation refuses it (no full cycle and not one closing
  period).  Where noise makes the input reverse at many more samples than
  at its true reversals, the Duhem fit runs its model on the input through
  a dead band, a play operator of width b (a multiple of the input noise,
  `fitter.identification.fit_data.prepare_for_fit`, the exported model's
  ``backlash`` effect).  The baselines take b from the same function (on the
  same recordings) and run on w = play_b[u] (w_0 =
  u_0) in the fit and in `predict` (``input_deadband`` in
  `Baseline.to_dict`; 0 for a clean input; ``deadband=False``: the raw u).
* **Units.**  Every model is fitted in normalised units, u_n = (u - u_mid) /
  u_half (u after the dead band) and y_n = (y - y_mid) / y_half, mid-range
  and half-range over all the fitted recordings; predictions are mapped
  back.  The Preisach relay grid and the play radii span [min u_n, max u_n]
  of the fitted data.
* **Initial state: fitted.**  Each fitted recording has its own initial
  state, fitted with the shared parameters (Bouc-Wen: z0; Preisach and
  Prandtl-Ishlinskii: the input history before the first sample, below).
  `predict` fits the initial state of the recording it is given to its
  output with the parameters fixed (as the Duhem model's ``x0="fitted"``:
  the least-squares initial state over all samples); for a recording
  without an output (y all NaN) it uses the state fitted to the first
  fitted recording, as the Duhem model stores the x0 of its first recording.
* **Score.**  `Baseline.score` is `fitter.data.metrics.compare` of `predict`
  over all samples: ``nrmse`` = RMS error / output range, the project's one
  NRMSE.

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

Bouc-Wen
--------
Output error on the samples (decimated, `BoucWen`), parameters by
the output-error engine (`refine`) from deterministic starts; the state is
integrated along u exactly up to a tabulated quadrature (`BoucWen`).
"""
from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import minimize_scalar, nnls

from fitter.core.effects import play_operator
from fitter.core.errors import DuhemError
from fitter.data.cycles import find_reversals
from fitter.data.metrics import compare
from fitter.data.recordings import Recording
from fitter.identification.fit_data import prepare_for_fit
from fitter.identification.exported import own_start
from fitter.identification.output_error import Options, refine
from fitter.identification.parametrisation import Parametrisation

__all__ = ["BaselineError", "Baseline", "Preisach", "PrandtlIshlinskii", "BoucWen", "BASELINES", "MIN_SAMPLES",
           "check_recordings", "compare_baselines", "comparison", "duhem_nrmse"]

MIN_SAMPLES = 10
"""Fewest samples a recording needs to be fitted by a baseline."""

_ROW_BLOCK = 4096
"""Rows per block of the Gram sums and of the relay states (bounds the memory)."""


class BaselineError(DuhemError):
    """Recordings a baseline cannot be fitted to, or a baseline used before it is fitted."""


def check_recordings(recordings: Sequence[Recording] | Recording) -> list[Recording]:
    """The recordings as a list, each checked for fitting (module docstring, "Samples and preparation").

    Raises
    ------
    BaselineError
        No recording; two with the same name; a recording with too few samples,
        no (finite) output, a constant input or output, or an input that never
        reverses.  The message names the recording.
    """
    recs = [recordings] if isinstance(recordings, Recording) else list(recordings)
    if not recs:
        raise BaselineError("no recordings to fit")
    names = [r.name for r in recs]
    if len(set(names)) != len(names):
        raise BaselineError(f"recording names must be distinct to report them apart: {names}")
    for rec in recs:
        if len(rec) < MIN_SAMPLES:
            raise BaselineError(f"{rec.label}: too few samples: {len(rec)}, at least {MIN_SAMPLES} needed")
        if not np.all(np.isfinite(rec.y)):
            raise BaselineError(f"{rec.label}: no output recorded (y is not finite): nothing to fit")
        if np.ptp(rec.u) == 0:
            raise BaselineError(f"{rec.label}: the input is constant ({rec.u[0]:g}): a hysteresis model "
                                f"needs an input that goes up and down")
        if np.ptp(rec.y) == 0:
            raise BaselineError(f"{rec.label}: the output is constant: the NRMSE (error / output range) is "
                                f"undefined")
        if find_reversals(rec.u).size == 0:
            raise BaselineError(f"{rec.label}: the input never reverses (it must go up and down at least "
                                f"once: a single loop, or periodically)")
    return recs


@dataclass(frozen=True)
class _Scale:
    """Mid-range and half-range of u and y over the fitted recordings (module docstring, "Units")."""

    u_mid: float
    u_half: float
    y_mid: float
    y_half: float

    @classmethod
    def of(cls, us: Sequence[np.ndarray], ys: Sequence[np.ndarray]) -> "_Scale":
        u_lo, u_hi = min(u.min() for u in us), max(u.max() for u in us)
        y_lo, y_hi = min(y.min() for y in ys), max(y.max() for y in ys)
        return cls(float(u_lo + u_hi) / 2, float(u_hi - u_lo) / 2, float(y_lo + y_hi) / 2, float(y_hi - y_lo) / 2)

    def u(self, u: np.ndarray) -> np.ndarray:
        return (u - self.u_mid) / self.u_half

    def y(self, y: np.ndarray) -> np.ndarray:
        return (y - self.y_mid) / self.y_half

    def y_back(self, y_n: np.ndarray) -> np.ndarray:
        return self.y_mid + self.y_half * y_n

    def u_back(self, u_n: np.ndarray) -> np.ndarray:
        return self.u_mid + self.u_half * u_n

    def to_dict(self) -> dict:
        return {"u_mid": self.u_mid, "u_half": self.u_half, "y_mid": self.y_mid, "y_half": self.y_half}


class Baseline(ABC):
    """A classical hysteresis model fitted to recordings (module docstring for the shared conventions).

    Subclasses set `name` and implement `_fit` and `_predict` in normalised
    units, and `parameters` and `_settings`/`_fitted` for `to_dict`.

    Parameters
    ----------
    deadband : run on the input through the Duhem fit's dead band for a noisy input (default), or on
        the raw input (module docstring, "Samples and preparation").
    """

    name: str = ""
    initial_state: str = ""
    """The initial state in words (for `to_dict`)."""

    def __init__(self, deadband: bool = True) -> None:
        self.deadband = bool(deadband)
        self.scale_: _Scale | None = None
        self.deadband_ = 0.0
        self.n_recordings_ = 0

    def fit(self, recordings: Sequence[Recording] | Recording) -> "Baseline":
        """Fit one parameter set to all `recordings` (one initial state each); returns self.

        Raises
        ------
        BaselineError
            A recording that cannot be fitted (`check_recordings`), or recordings on which the model's
            least-squares problem is singular (e.g. an input outlier that leaves one sample on its elements).
        FitError
            A recording the Duhem fit's preparation refuses (module docstring).
        """
        recs = check_recordings(recordings)
        self.deadband_ = float(prepare_for_fit(recs).deadband) if self.deadband else 0.0
        us, ys = [self._input(r) for r in recs], [r.y for r in recs]
        self.scale_ = _Scale.of(us, ys)
        self.n_recordings_ = len(recs)
        try:
            self._fit([self.scale_.u(u) for u in us], [self.scale_.y(y) for y in ys])
        except np.linalg.LinAlgError:
            raise BaselineError(f"{', '.join(r.label for r in recs)}: baseline {self.name!r} cannot be fitted: its "
                                f"least-squares problem is singular on these recordings") from None
        return self

    def _input(self, rec: Recording) -> np.ndarray:
        """The input the model runs on: u through the dead band of width `deadband_` (module docstring)."""
        return play_operator(rec.u, self.deadband_, float(rec.u[0])) if self.deadband_ > 0 else rec.u

    def predict(self, rec: Recording) -> np.ndarray:
        """The model's output on every sample of `rec` (initial state: module docstring)."""
        scale = self._scale()
        y_n = scale.y(rec.y) if np.all(np.isfinite(rec.y)) else None
        return scale.y_back(self._predict(scale.u(self._input(rec)), y_n))

    def score(self, rec: Recording) -> dict:
        """`fitter.data.metrics.compare` of `predict(rec)` with `rec` (``nrmse`` etc., all samples)."""
        if not np.all(np.isfinite(rec.y)):
            raise BaselineError(f"{rec.label}: no output recorded (y is not finite): nothing to score against")
        return compare(rec, self.predict(rec))

    @property
    @abstractmethod
    def parameters(self) -> int:
        """Number of fitted parameters (the initial state counts one per fitted recording)."""

    def to_dict(self) -> dict:
        """JSON-able description: name, number of parameters, settings, normalisation, fitted values."""
        scale = self._scale()
        return {"name": self.name, "parameters": self.parameters, "recordings": self.n_recordings_,
                "settings": self._settings(), "initial_state": self.initial_state,
                "input_deadband": self.deadband_, "normalisation": scale.to_dict(), "fitted": self._fitted()}

    def _scale(self) -> _Scale:
        if self.scale_ is None:
            raise BaselineError(f"the {self.name} baseline is not fitted yet: call fit(recordings) first")
        return self.scale_

    @abstractmethod
    def _fit(self, us: list[np.ndarray], ys: list[np.ndarray]) -> None:
        """Fit in normalised units, one (u_n, y_n) pair per recording."""

    @abstractmethod
    def _predict(self, u: np.ndarray, y: np.ndarray | None) -> np.ndarray:
        """Normalised output on u_n; the initial state fitted to y_n unless it is None."""

    @abstractmethod
    def _settings(self) -> dict:
        """The estimator's settings (constructor arguments)."""

    @abstractmethod
    def _fitted(self) -> dict:
        """The fitted values, normalised units (JSON-able)."""


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
    for a in range(rows.start, rows.stop, _ROW_BLOCK):
        d = p.design(slice(a, min(a + _ROW_BLOCK, rows.stop)), s0, y)
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
        for a in range(0, p.t_star, _ROW_BLOCK):
            b = min(a + _ROW_BLOCK, p.t_star)
            d = p.design(slice(a, b), p.s0[0], y)
            base += d.T @ d
            partial = np.cumsum(d, axis=0)
            inside = (self.cuts > a) & (self.cuts <= b)
            sums[inside] = running + partial[self.cuts[inside] - a - 1]
            running += partial[-1]
        return base, sums

    def __call__(self, k: int) -> np.ndarray:
        if k not in self._cache:
            self._cache[k] = self._constant(k) if self.constant else \
                self.tail + _gram(self.p, range(0, self.p.t_star), self.p.s0[k], self.y)
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
                self.tau[changed], self.tau[changed])
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


class _HysteronBaseline(Baseline):
    """y_n = c + d u_n + sigma sum_j w_j h_j[u_n], w_j >= 0 (module docstring, "Linear hysteron models")."""

    initial_state = ("the input history before the first sample, fitted per recording: a staircase from "
                     "saturation (below or above) through a turning point m to u_0")
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
        tau = (np.where(merged.any(axis=0), merged.argmax(axis=0), t_star) if t_star
               else np.zeros(lo.shape[1], dtype=np.int64))
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
        if self._linear_nonnegative:    # the linear term d >= 0 too: only c is free
            w, f, rss = _solve_normal(g, self.nonnegative, n_free=1)
            return w[1:], np.r_[f, w[0]], rss
        return _solve_normal(g, self.nonnegative)

    def _alternate(self, paths, ys, normals, sign: float, choice: list[int]):
        """Weights and histories by alternation from `choice` (module docstring);
        returns (sign, w, f, choice, rss)."""
        for _ in range(100):    # the squared error falls at every change: ends within a few rounds
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
        shift = steps.sum(axis=1, keepdims=True) - np.cumsum(steps, axis=1)      # sum over tau_j > t
        return np.sum((residual + shift[:, :p.t_star]) ** 2, axis=1)

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
        for a in range(0, len(u), _ROW_BLOCK):
            rows = slice(a, a + _ROW_BLOCK)
            out[rows] += np.clip(s0[used], p.lo[rows][:, used], p.hi[rows][:, used]) @ w[used]
        return out

    @property
    def parameters(self) -> int:
        self._scale()
        return len(self.weights_) + 2 + self.n_recordings_

    def _fitted(self) -> dict:
        return {"offset": self.offset_, "slope": self.slope_, "orientation": self.orientation_,
                "weights": [float(x) for x in self.weights_],
                "grid": [float(x) for x in self.edges_],
                "histories": [{"side": s, "turning_point": m} for s, m in self.histories_]}


class Preisach(_HysteronBaseline):
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
    weights non-negative and sigma = +-1 the loop's orientation (module
    docstring, "Linear hysteron models").

    Relay states are computed without a loop over time: for each threshold,
    the index of the last sample at or beyond it (np.maximum.accumulate over
    the sample indices); a relay is up when its last up-crossing is later than
    its last down-crossing.  Initial state: the fitted input history (module
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
        for a in range(0, n, _ROW_BLOCK):
            rows = slice(a, a + _ROW_BLOCK)
            last_up, last_down = up[rows][:, self._alpha_index], down[rows][:, self._beta_index]
            lo[rows] = np.where(last_up > last_down, 1, -1)
            hi[rows] = np.where(last_down > last_up, -1, 1)
        return lo, hi

    def _after(self, side: str, m: float) -> np.ndarray:
        if side == "below":
            return np.where(self.alpha_ <= m, 1, -1).astype(np.int8)
        return np.where(self.beta_ >= m, -1, 1).astype(np.int8)

    def _settings(self) -> dict:
        return {"levels": self.levels, "relays": self.levels * (self.levels + 1) // 2, "linear_term": True,
                "nonnegative": self.nonnegative, "deadband": self.deadband}


class PrandtlIshlinskii(_HysteronBaseline):
    """Prandtl-Ishlinskii model: a weighted sum of play operators, weights by NNLS.

    Model (normalised units)::

        y(t) = c + a_0 u(t) + sigma sum_{i=1}^{K-1} w_i F_{r_i}[u](t),   w_i >= 0,

    with play radii r_i = i/K (max u - min u)/2 over the fitted data, i = 0 ..
    K - 1 (K = 24 by default).  The radius-0 play is the identity, so its
    weight is a_0, left free (it is the model's linear term; c is free too);
    the others are non-negative, the classical condition that makes the PI
    operator invertible, and sigma = +-1 is the loop's orientation.  F_r is the play (backlash) operator of width 2r,
    `fitter.core.effects.play_operator`: w_k = min(u_k + r, max(u_k - r,
    w_{k-1})).  K + 1 coefficients (module docstring, "Linear hysteron
    models").  Initial play states: the fitted input history (module
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

    def __init__(self, levels: int = 24, nonnegative: bool = True, deadband: bool = True, invertible: bool = False,
                 min_slope: float = 0.05) -> None:
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
        super()._fit(us, [y - self.min_slope * u for u, y in zip(us, ys)])    # a_0 = min_slope + d, d >= 0
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
        return {"levels": self.levels, "plays": self.levels,
                "linear_term": (f"the radius-0 play, weight >= {self.min_slope:g}" if self.invertible
                                else "the radius-0 play, weight free"),
                "nonnegative": self.nonnegative, "deadband": self.deadband, "invertible": self.invertible}

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
            raise BaselineError("this Prandtl-Ishlinskii model runs on the input through a dead band, which has no "
                                "inverse: fit it with deadband=False to invert it")
        a = np.r_[self.slope_, self.orientation_ * self.weights_]
        r = np.r_[0.0, self.radii_]
        s = np.cumsum(a)
        if np.any(s <= 0):
            raise BaselineError("the Prandtl-Ishlinskii model is not invertible: its loop slope "
                                f"a_0 + sum a_i falls to {s.min():.3g} <= 0")
        r_inv = np.array([np.sum(a[:i + 1] * (r[i] - r[:i + 1])) for i in range(len(a))])
        a_inv = np.r_[1.0 / a[0], -a[1:] / (s[1:] * s[:-1])]
        side, m = self.histories_[0]
        z = np.r_[m, self._after(side, m)]
        tail = np.r_[np.cumsum((a * z)[::-1])[::-1][1:], 0.0]        # sum_{j>i} a_j z_j
        z_inv = s * z + tail
        v = scale.y(np.asarray(y, dtype=float)) - self.offset_
        u_n = a_inv[0] * v
        for ri, ai, zi in zip(r_inv[1:], a_inv[1:], z_inv[1:]):
            u_n = u_n + ai * play_operator(v, 2 * ri, zi)
        return scale.u_back(u_n)


# ---------------------------------------------------------------- Bouc-Wen
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
    return ((2 * s3 - 3 * s2 + 1) * ys[k] + (s3 - 2 * s2 + s) * h * ms[k] + (3 * s2 - 2 * s3) * ys[k + 1]
            + (s3 - s2) * h * ms[k + 1])


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
    return ((2 * s3 - 3 * s2 + 1) * y0 + (s3 - 2 * s2 + s) * h * ms.item(k) + (3 * s2 - 2 * s3) * y1
            + (s3 - s2) * h * ms.item(k + 1))


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
        for a, b, longest in reversed(pieces):              # each smooth piece, from the top down
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
                g = np.where(x <= zs, -np.expm1(n * np.log1p(-np.minimum(x / zs, 1.0))),
                             1 + q * np.abs(x / zs - 1) ** n)
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

    def __init__(self, max_samples: int = 6000, step: float = 0.01, starts: int = 3,
                 deadband: bool = True) -> None:
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
        grid = [np.r_[math.log(zs), q, n, [z0 * zs] * r] for zs in self._GRID["z_s"] for q in self._GRID["q"]
                for n in self._GRID["n"] for z0 in self._GRID["z0"]]
        costs = [float(np.sum(problem.residual(th) ** 2)) for th in grid]
        param = _BWParameters(np.array(lower), np.array(upper))
        options = Options(ftol=1e-8, xtol=1e-8, gtol=1e-8, max_nfev=100 * (3 + r), max_samples=None)
        best = None
        for k in np.argsort(costs, kind="stable")[:self.starts]:
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
        best = minimize_scalar(sse, bounds=(scan[max(k - 1, 0)], scan[min(k + 1, len(scan) - 1)]),
                               method="bounded", options={"xatol": 1e-9})
        return output(float(best.x) if best.fun <= errors[k] else float(scan[k]))

    @property
    def parameters(self) -> int:
        self._scale()
        return 6 + self.n_recordings_

    @property
    def beta(self) -> float:
        """beta of the model equation (normalised units, A = 1)."""
        return (1 + self.q_) / (2 * self.zs_ ** self.n_)

    @property
    def gamma(self) -> float:
        """gamma of the model equation (normalised units, A = 1)."""
        return (1 - self.q_) / (2 * self.zs_ ** self.n_)

    def _settings(self) -> dict:
        return {"max_samples": self.max_samples, "step": self.step, "starts": self.starts, "A": 1.0,
                "deadband": self.deadband}

    def _fitted(self) -> dict:
        return {"z_s": self.zs_, "q": self.q_, "n": self.n_, "beta": self.beta, "gamma": self.gamma,
                "k_u": self.k_u_, "k_z": self.k_z_, "c": self.c_, "z0": list(self.z0_)}


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
        """The output-error engine's interface (`fitter.identification.output_error.refine`): the stacked
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
                zs = base[:j - 3] + [self.model._states(flow, self.data[j - 3].runs, moved[j])] + base[j - 2:]
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


BASELINES: dict[str, type[Baseline]] = {cls.name: cls for cls in (Preisach, PrandtlIshlinskii, BoucWen)}
"""The baselines by name."""


def compare_baselines(recordings: Sequence[Recording], *, per_recording: bool = True,
                      names: Sequence[str] | None = None) -> dict:
    """NRMSE of each baseline on each recording, fitted per recording and once for all.

    Returns
    -------
    ``{name: {"per_recording": {rec.name: nrmse}, "one_for_all": {rec.name: nrmse},
    "cpu_seconds": {"per_recording": {rec.name: s}, "one_for_all": s}}}``:
    "per_recording" fits each recording alone (None when `per_recording` is
    false), "one_for_all" fits one parameter set to all recordings (one
    initial state each); the NRMSE is `Baseline.score`'s (all samples),
    the CPU time `time.process_time` of each fit.

    Raises
    ------
    BaselineError
        An unknown name, or a recording that cannot be fitted (`check_recordings`).
    """
    recs = check_recordings(recordings)
    chosen = list(BASELINES) if names is None else list(names)
    unknown = [n for n in chosen if n not in BASELINES]
    if unknown:
        raise BaselineError(f"unknown baseline(s) {unknown}: known are {list(BASELINES)}")
    out = {}
    for name in chosen:
        entry = {"per_recording": None, "one_for_all": {}, "cpu_seconds": {"per_recording": None}}
        if per_recording:
            entry["per_recording"], entry["cpu_seconds"]["per_recording"] = {}, {}
            for rec in recs:
                model, seconds = _timed_fit(BASELINES[name], [rec])
                entry["per_recording"][rec.name] = model.score(rec)["nrmse"]
                entry["cpu_seconds"]["per_recording"][rec.name] = seconds
        model, seconds = _timed_fit(BASELINES[name], recs)
        entry["one_for_all"] = {rec.name: model.score(rec)["nrmse"] for rec in recs}
        entry["cpu_seconds"]["one_for_all"] = seconds
        out[name] = entry
    return out


def duhem_nrmse(model, rec: Recording) -> float:
    """NRMSE of a Duhem model on `rec` under the baselines' initial-state policy: x0 fitted to this
    recording over all its samples (and the effects settled on it where the fit settled them,
    `fitter.identification.exported.own_start`), every sample scored; NaN when the simulation overflows."""
    start = own_start(model, rec)
    return float("nan") if start is None else compare(rec, start[1])["nrmse"]


def comparison(model, recordings: Sequence[Recording]) -> dict:
    """The Duhem model beside the baselines on the same recordings and error measure:
    ``{"duhem": {rec.name: nrmse}, "baselines": compare_baselines(...)}``; each baseline is fitted
    once for all recordings and, when there are several, to each recording alone."""
    recs = check_recordings(recordings)
    return {"duhem": {rec.name: duhem_nrmse(model, rec) for rec in recs},
            "baselines": compare_baselines(recs, per_recording=len(recs) > 1),
            "measure": "RMS error / output range over all samples, initial state fitted per recording"}


def _timed_fit(cls: type[Baseline], recs: list[Recording]) -> tuple[Baseline, float]:
    t0 = time.process_time()
    model = cls().fit(recs)
    return model, time.process_time() - t0
