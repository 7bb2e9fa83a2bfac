"""Fit semilinear Duhem models to real recordings (noisy, transient, any periodic input, several rates).

Pipeline of `fit_recordings`
----------------------------
1. **Preparation** (`fitter.data.preparation.prepare`): input reversals, settled
   cycles (the start-up transient is dropped), holds, drift; the notes go into
   the summary.  A recording whose input never reverses twice, or that holds
   neither a full cycle nor one closing period, is rejected (`FitError`).
   The input is then made monotone between reversals (isotonic regression),
   so that measurement noise on u creates no spurious branch switches.
2. **Normalisation**: u_n = (u - u_c)/u_s, y_n = (y - y_c)/y_s (mid-range,
   half-range).  Fitting happens in these units; `_Scaling.to_physical` maps
   the model back exactly: for the rate-independent model (1)-(2)
   A± -> A±/u_s, B± -> B±/u_s^2, E± -> (E± - B± u_c/u_s)/u_s; for the
   rate-dependent model (18)-(19) A stays, B -> B/u_s, E -> E - B u_c/u_s and
   g(v) = g_n(v/u_s); both C -> y_s C, D -> y_s D/u_s, and the output offset
   k = y_c - y_s D u_c/u_s is absorbed in the state (x -> x + x_c with
   C x_c = k, E -> E - A x_c), so no output constant is needed.
3. **Parameterisation** (order n, observability canonical form of (A+, C) or
   (A, C): C = e1, A+ (or A) a companion matrix with free last row):
   rate-independent theta = [a+ (n), A- (n^2), B+, B-, E+, E- (n each), D];
   rate-dependent theta = [a (n), B, E (n each), D, c] with
   g_n(v) = |v| exp(cs [v < 0] + h(ln(|v|/v_ref))), h piecewise linear in the
   log-rate between knots at the data's rates (the distinct triangle slopes,
   which makes it the paper's pointwise g-hat of eq 50, or 5 quantiles of the
   rates of other inputs), constant beyond them; g_n >= 0 with g_n(0) = 0
   (paper: g(0) = 0 only at 0).  The scale of g is fixed by h(0) = 0 at the
   reference rate v_ref (g_n(v_ref) = v_ref).
   The model carries g as a `TabulatedRate` at 97 nodes +-v_ref 10^[-3..3].
4. **Initial estimates**: rate-independent from the loop (the settled branches
   resampled on a uniform input grid and averaged over cycles and recordings:
   the input-domain reparameterisation of Section III) by
   `fitter.identification.ri_loop.identify_ri_loop` when available, and always by a
   first-order branch regression dy/du = a y + b u + e (each branch); the best
   start is kept.  Rate-dependent: `identify_rd_triangles` (Section V) when all
   inputs are triangle waves, else the rising-branch part of the
   rate-independent fit with g = |v|.
5. **Output-error refinement** (`fitter.identification.output_error.refine`).  Initial
   state ``x0="fit"``: the state at the first kept sample of each recording is
   eliminated by linear least squares, so what remains of a slowly decaying
   transient after the preparation's cut is fitted, not mistaken for the loop.
   When every recording holds a single cycle (e.g. the piezo files), a free
   initial state would let a barely convergent model mimic a non-closing loop,
   so ``x0="periodic"`` is used instead: the cycle is taken as settled.
   The convergence condition is enforced: for the rate-dependent model with
   g >= 0 the period map is e^{A sum g dt}, so rho < 1 iff A is Hurwitz, which
   the parameterisation guarantees (A's characteristic polynomial is built
   from positive factors); for the rate-independent model
   rho(e^{beta A+} e^{-beta A-}) < 1, condition (5), is kept by a barrier
   residual 1e3 max(0, rho - 0.99) added to the objective.  The optimiser
   (trust-region reflective) stops after `MAX_NFEV` iterations per start.
6. **Selection**: orders n = 1, 2, 3 are fitted upward, each started from
   the order n-1 fit (extra fast, weakly observed modes) and the other
   starts; for ``kind="auto"`` RI vs RD, and the order, by
   BIC = N ln(RSS/N) + p ln N on the stacked residuals (the RD order search
   stops when BIC rises; ``kind="rd"`` fits only the order-1 RI model, as a
   start).  q (the bound of the Section III constrained least squares) is
   chosen by the loop error of the Section III estimate; it only shapes a
   start.  All candidates are listed in the summary.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import isotonic_regression

from fitter.core.errors import DuhemError
from fitter.core.models import Experiment, RateDependentModel, RateIndependentModel, Signals
from fitter.core.periodic import convergence_rho
from fitter.core.rates import TabulatedRate
from fitter.data.metrics import compare
from fitter.identification.output_error import RefineResult, cycle_fixed_point, jacobian, refine
from fitter.data.preparation import PreparationError, Prepared, branch_on_grid, find_reversals, prepare
from fitter.data.recordings import Recording

__all__ = ["FitError", "FitResult", "fit_recordings", "monotone_input"]

ORDERS = (1, 2, 3)
X0_TEXT = {"fit": "fitted per recording (linear least squares) at its first kept sample; the per-recording "
                  "metrics are those of the fit (FitResult.predict starts from the periodic state instead)",
           "periodic": "every recording holds a single cycle, so transient and loop cannot be told apart: "
                       "each is taken as settled and starts from the fixed point of its one-cycle map"}
Q_CANDIDATES = (1.0, 3.0, 7.0, 20.0)
GRID_POINTS = 101
RATE_NODES = np.logspace(-3, 3, 97)
RHO_MARGIN = 0.99
MAX_NFEV = 60


class FitError(DuhemError):
    """Recordings that cannot be fitted (too few cycles, an input that never reverses, ...)."""


# ----------------------------------------------------------------------------- scaling
@dataclass
class _Scaling:
    """Affine normalisation u_n = (u - u_c)/u_s, y_n = (y - y_c)/y_s; see the module docstring."""

    u_c: float
    u_s: float
    y_c: float
    y_s: float

    @classmethod
    def of(cls, recs: Sequence[Recording]) -> "_Scaling":
        u = np.concatenate([r.u for r in recs])
        y = np.concatenate([r.y for r in recs])
        us, ys = 0.5 * np.ptp(u), 0.5 * np.ptp(y)
        if not (us > 0 and ys > 0):
            raise FitError("the input or the output is constant over all recordings")
        return cls(0.5 * (u.max() + u.min()), us, 0.5 * (y.max() + y.min()), ys)

    def normalise(self, rec: Recording) -> Recording:
        return Recording(rec.t, (rec.u - self.u_c) / self.u_s, (rec.y - self.y_c) / self.y_s,
                         rec.name, rec.input, rec.output, rec.source)

    def _output(self, C, D, A_list, E_list, x0):
        """Map C, D to physical units and absorb the output offset into the state."""
        C2 = self.y_s * np.asarray(C, dtype=float)
        D2 = self.y_s * D / self.u_s
        k = self.y_c - self.y_s * D * self.u_c / self.u_s
        xc = k * C2 / (C2 @ C2)
        E2 = [E - A @ xc for A, E in zip(A_list, E_list)]
        return C2, D2, E2, np.asarray(x0, dtype=float) + xc

    def to_physical(self, m):
        """The normalised-units model `m` in physical units (exact)."""
        s, c = self.u_s, self.u_c
        if m.kind == "ri":
            Ap, Am = m.A_plus / s, m.A_minus / s
            Ep = (m.E_plus - m.B_plus * c / s) / s
            Em = (m.E_minus - m.B_minus * c / s) / s
            C, D, (Ep, Em), x0 = self._output(m.C, m.D, [Ap, Am], [Ep, Em], m.x0)
            return RateIndependentModel(A_plus=Ap, A_minus=Am, B_plus=m.B_plus / s ** 2,
                                        B_minus=m.B_minus / s ** 2, C=C, E_plus=Ep, E_minus=Em,
                                        D=D, x0=x0)
        E = m.E - m.B * c / s
        C, D, (E,), x0 = self._output(m.C, m.D, [m.A], [E], m.x0)
        g = TabulatedRate(m.g.v * s, m.g.g)
        return RateDependentModel(A=m.A, B=m.B / s, C=C, g=g, E=E, D=D, x0=x0)


# ------------------------------------------------------------------ parameterisations
def _companion(a: np.ndarray) -> np.ndarray:
    n = len(a)
    A = np.zeros((n, n))
    A[np.arange(n - 1), np.arange(1, n)] = 1.0
    A[-1] = a
    return A


def _observability(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    rows = [C]
    for _ in range(len(C) - 1):
        rows.append(rows[-1] @ A)
    return np.array(rows)


def _hurwitz_poly(th: np.ndarray) -> np.ndarray:
    """Coefficients p_0..p_{n-1} of a Hurwitz polynomial s^n + p_{n-1} s^{n-1} + ... + p_0.

    n = 1: s + e^th0; n = 2: s^2 + e^th1 s + e^th0; n = 3: (s + r)(s^2 + b s + c) with
    (r, c, b) = e^th.  Every theta gives a Hurwitz polynomial and every Hurwitz
    polynomial of order <= 3 has a theta, so the convergence condition holds by construction.
    """
    e = np.exp(np.clip(th, -30, 30))
    if len(th) == 1:
        return e
    if len(th) == 2:
        return e
    r, c, b = e
    return np.array([r * c, c + r * b, r + b])


def _hurwitz_theta(lam: np.ndarray) -> np.ndarray:
    """Inverse of `_hurwitz_poly` for the eigenvalues `lam` (unstable ones reflected)."""
    lam = np.where(lam.real >= 0, -np.abs(lam.real) - 1e-3 + 1j * lam.imag, lam)
    n = len(lam)
    if n == 3:
        k = int(np.argmin(np.abs(lam.imag)))
        r = -lam[k].real
        rest = np.delete(lam, k)
        quad = np.real(np.poly(rest))
        return np.log([r, quad[2], quad[1]])
    poly = np.real(np.poly(lam))[1:][::-1]
    return np.log(poly)


@dataclass
class _RIParam:
    """Rate-independent canonical parameters (see module docstring, item 3)."""

    n: int
    kind: str = "ri"

    @property
    def size(self) -> int:
        return self.n * self.n + 5 * self.n + 1

    def names(self) -> list[str]:
        n = self.n
        return ([f"A_plus[{n - 1},{j}]" for j in range(n)]
                + [f"A_minus[{i},{j}]" for i in range(n) for j in range(n)]
                + [f"{p}[{i}]" for p in ("B_plus", "B_minus", "E_plus", "E_minus") for i in range(n)]
                + ["D"])

    def build(self, th: np.ndarray) -> RateIndependentModel:
        n = self.n
        a, rest = th[:n], th[n:]
        Am, rest = rest[:n * n].reshape(n, n), rest[n * n:]
        Bp, Bm, Ep, Em = (rest[i * n:(i + 1) * n] for i in range(4))
        return RateIndependentModel(A_plus=_companion(a), A_minus=Am, B_plus=Bp, B_minus=Bm,
                                    C=np.eye(n)[0], E_plus=Ep, E_minus=Em, D=rest[4 * n])

    def theta(self, m: RateIndependentModel) -> np.ndarray:
        """Canonical theta of an (observable) model of order n: x -> O x."""
        T = _observability(m.A_plus, m.C)
        Ti = np.linalg.inv(T)
        return np.r_[(T @ m.A_plus @ Ti)[-1], (T @ m.A_minus @ Ti).ravel(), T @ m.B_plus,
                     T @ m.B_minus, T @ m.E_plus, T @ m.E_minus, m.D]

    def rho(self, m, u_min: float, u_max: float) -> float:
        """rho(e^{beta A+} e^{-beta A-}) of condition (5) (inf when it overflows)."""
        with np.errstate(all="ignore"):
            M_ok = np.all(np.isfinite(m.A_plus)) and np.abs(m.A_plus).max() * (u_max - u_min) < 600 \
                and np.abs(m.A_minus).max() * (u_max - u_min) < 600
            return convergence_rho(m, u_min, u_max) if M_ok else np.inf


@dataclass
class _RDParam:
    """Rate-dependent canonical parameters with g tabulated at knots (module docstring, item 3)."""

    n: int
    v_ref: float
    knots: np.ndarray
    kind: str = "rd"

    @property
    def n_c(self) -> int:
        return len(self.knots) - 1

    @property
    def size(self) -> int:
        return 3 * self.n + 2 + self.n_c

    def names(self) -> list[str]:
        n = self.n
        rates = [f"g_log_at_{self.v_ref * np.exp(k):.4g}" for k in self.knots if k != 0.0]
        return ([f"A_poly[{j}]" for j in range(n)] + [f"B[{i}]" for i in range(n)]
                + [f"E[{i}]" for i in range(n)] + ["D", "g_sign"] + rates)

    def g_values(self, c: np.ndarray, v: np.ndarray) -> np.ndarray:
        """g_n(v) = |v| exp(cs [v<0] + h(s)), s = ln(|v|/v_ref), h linear between the knots
        (h = 0 at the reference knot s = 0, constant beyond the outer knots)."""
        s = np.log(np.abs(v) / self.v_ref)
        k0 = int(np.argmin(np.abs(self.knots)))
        h = np.interp(s, self.knots, np.insert(np.asarray(c[1:], dtype=float), k0, 0.0))
        return np.abs(v) * np.exp(np.clip(c[0] * (v < 0) + h, -30, 30))

    def build(self, th: np.ndarray) -> RateDependentModel:
        n = self.n
        nodes = np.r_[-self.v_ref * RATE_NODES[::-1], self.v_ref * RATE_NODES]
        g = TabulatedRate(nodes, self.g_values(th[3 * n + 1:], nodes))
        return RateDependentModel(A=_companion(-_hurwitz_poly(th[:n])), B=th[n:2 * n],
                                  E=th[2 * n:3 * n], C=np.eye(n)[0], D=th[3 * n], g=g)

    def theta_from(self, A, B, E, C, D, c=None) -> np.ndarray:
        T = _observability(A, C)
        c = np.zeros(1 + self.n_c) if c is None else c
        return np.r_[_hurwitz_theta(np.linalg.eigvals(A)), T @ B, T @ E, D, c]

    def rho(self, m, u_min: float, u_max: float) -> float:
        """Spectral abscissa test: rho < 1 iff A is Hurwitz (g >= 0); returned as max Re(lambda)."""
        return float(np.max(np.linalg.eigvals(m.A).real))


# --------------------------------------------------------------------- preparation
@dataclass
class _Data:
    """Prepared recordings: physical (trimmed, monotone input) and normalised, with cycles."""

    preps: list[Prepared]
    recs: list[Recording]
    norm: list[Recording]
    cycles: list[tuple[int, int]]
    loops: list[list[Recording]]
    notes: list[list[str]]
    x0_mode: str = "fit"


def monotone_input(u: np.ndarray, reversals: np.ndarray) -> np.ndarray:
    """u made monotone between successive reversals by isotonic regression (least squares).

    Segments run from one reversal to the next (and from the ends to the
    first and last reversal); each is replaced by its best non-decreasing or
    non-increasing approximation, so noise on u creates no spurious branch
    switches.  A noise-free piecewise-monotone input is returned unchanged.
    """
    u = np.asarray(u, dtype=float)
    out = u.copy()
    cuts = np.r_[0, np.asarray(reversals, dtype=int), len(u) - 1]
    for a, b in zip(cuts[:-1], cuts[1:]):
        if b - a < 1:
            continue
        seg = u[a:b + 1]
        rising = seg[-1] >= seg[0]
        out[a:b + 1] = isotonic_regression(seg, increasing=rising).x
    return out


def _cycle_of(prep: Prepared) -> tuple[int, int]:
    """(s0, s1) of the first settled cycle, or the whole recording when it is one closing period."""
    if prep.cycles:
        return prep.cycles[0].start, prep.cycles[0].stop - 1
    u = prep.recording.u
    if len(prep.reversals) >= 2 and abs(u[-1] - u[0]) < 0.1 * np.ptp(u) \
            and np.sign(u[1] - u[0]) == np.sign(u[-1] - u[-2]):
        return 0, len(u) - 1
    raise FitError(f"{prep.recording.name}: too few cycles: no full input cycle "
                   f"({len(prep.reversals)} reversals) and the recording is not one closing period")


def _loop_pieces(rec: Recording, prep: Prepared, cycle: tuple[int, int]) -> list[Recording]:
    """Each settled cycle as one loop min -> max -> min (rotated to start at its minimum;
    the cycle's end sample is taken as equal to its first)."""
    slices = prep.cycles or [slice(cycle[0], cycle[1] + 1)]
    pieces = []
    for s in slices:
        u, y = rec.u[s], rec.y[s]
        k = int(np.argmin(u))
        idx = np.r_[np.arange(k, len(u)), np.arange(1, k + 1)] if k else np.arange(len(u))
        pieces.append(Recording(np.arange(len(idx), dtype=float), u[idx], y[idx], rec.name))
    return pieces


def _prepare_all(recordings: Sequence[Recording]) -> tuple[_Data, _Scaling]:
    if not recordings:
        raise FitError("no recordings to fit")
    preps, recs, cycles, loops, notes = [], [], [], [], []
    for rec in recordings:
        if len(find_reversals(rec.u)) < 2:
            raise FitError(f"{rec.name}: the input never reverses twice (it must go up and down "
                           f"periodically; found {len(find_reversals(rec.u))} reversal(s))")
        try:
            prep = prepare(rec, min_cycles=0)
        except PreparationError as exc:
            raise FitError(str(exc)) from None
        cyc = _cycle_of(prep)
        r = prep.recording
        um = monotone_input(r.u, prep.reversals)
        changed = int(np.sum(np.abs(um - r.u) > 0))
        clean = Recording(r.t, um, r.y, r.name, r.input, r.output, r.source)
        n = list(prep.notes)
        if changed:
            n.append(f"input made monotone between reversals (isotonic regression): {changed} samples "
                     f"moved by at most {np.max(np.abs(um - r.u)):.3g}")
        preps.append(prep)
        recs.append(clean)
        cycles.append(cyc)
        loops.append(_loop_pieces(clean, prep, cyc))
        notes.append(n)
    scaling = _Scaling.of(recs)
    norm = [scaling.normalise(r) for r in recs]
    loops = [[scaling.normalise(p) for p in pieces] for pieces in loops]
    x0_mode = "periodic" if all(len(p.cycles) <= 1 for p in preps) else "fit"
    return _Data(preps, recs, norm, cycles, loops, notes, x0_mode), scaling


def _averaged_loop(loops: list[list[Recording]], points: int = GRID_POINTS):
    """Rising and falling branches on a common uniform input grid, averaged over all cycles."""
    lo = max(p.u.min() for ps in loops for p in ps)
    hi = min(p.u.max() for ps in loops for p in ps)
    span = hi - lo
    grid = np.linspace(lo + 0.01 * span, hi - 0.01 * span, points)
    rising, falling = [], []
    for ps in loops:
        for p in ps:
            k = int(np.argmax(p.u))
            rising.append(branch_on_grid(p.u[:k + 1], p.y[:k + 1], grid))
            falling.append(branch_on_grid(p.u[k:], p.y[k:], grid))
    return grid, np.mean(rising, axis=0), np.mean(falling, axis=0)


# ------------------------------------------------------------------ initial estimates
def _branch_regression(grid, y, rising: bool) -> tuple[float, float, float]:
    """First-order branch fit dy/du = a y + b u + e (least squares on the gradient), with
    a <= -0.05 on the rising and a >= 0.05 on the falling branch, so that condition (5),
    e^{beta (a+ - a-)} < 1, holds (the state relaxes along each branch)."""
    from scipy.optimize import lsq_linear
    dy = np.gradient(y, grid)
    M = np.column_stack([y, grid, np.ones_like(grid)])
    lo = [-np.inf if not rising else -np.inf, -np.inf, -np.inf]
    hi = [-0.05 if rising else np.inf, np.inf, np.inf]
    if not rising:
        lo[0] = 0.05
    return tuple(lsq_linear(M, dy, bounds=(lo, hi)).x)


def _ri_first_order(grid, yr, yf) -> RateIndependentModel:
    ap, bp, ep = _branch_regression(grid, yr, True)
    am, bm, em = _branch_regression(grid, yf, False)
    return RateIndependentModel(A_plus=[[ap]], A_minus=[[am]], B_plus=[bp], B_minus=[bm], C=[1.0],
                                E_plus=[ep], E_minus=[em])


def _pad(M: np.ndarray, d: np.ndarray) -> np.ndarray:
    k, n = len(d), M.shape[0]
    return np.block([[M, np.zeros((n, k))], [np.zeros((k, n)), np.diag(d)]])


def _embed(m, n: int):
    """Order-n model with nearly the same output: extra fast, weakly observed stable modes
    (relaxing on both branches), so that an order-(n-1) fit starts the order-n one."""
    k = n - m.order
    if k <= 0:
        return m
    extra = -np.arange(2.0, 2.0 + k) * 5.0
    vec = lambda v: np.r_[v, np.zeros(k)]
    C = np.r_[m.C, 0.05 * np.ones(k)]
    if m.kind == "rd":
        return RateDependentModel(A=_pad(m.A, extra), B=vec(m.B), C=C, g=m.g, E=vec(m.E), D=m.D)
    return RateIndependentModel(A_plus=_pad(m.A_plus, extra), A_minus=_pad(m.A_minus, -extra),
                                B_plus=vec(m.B_plus), B_minus=vec(m.B_minus), C=C,
                                E_plus=vec(m.E_plus), E_minus=vec(m.E_minus), D=m.D)


def _loop_error(m, grid, yr, yf) -> float:
    from fitter.core.periodic import limiting_loop
    try:
        g, r, f, rho = limiting_loop(m, grid[0], grid[-1], len(grid))
    except (ValueError, np.linalg.LinAlgError):
        return np.inf
    return float(np.sqrt(np.mean((r - yr) ** 2) + np.mean((f - yf) ** 2))) if rho < 1 else np.inf


def _ri_starts(grid, yr, yf, n: int, q: float | None, lower=None) -> tuple[list[np.ndarray], dict]:
    """Canonical starts for order n, best loop error first: the order-(n-1) fit embedded,
    the first-order branch regression embedded, and Section III identification (q chosen by
    loop error among Q_CANDIDATES unless given)."""
    par = _RIParam(n)
    cands, info = [], {}
    if lower is not None:
        m = _embed(lower, n)
        cands.append((_loop_error(m, grid, yr, yf) * 0.5, par.theta(m), f"order {n - 1} fit, embedded"))
    base = _embed(_ri_first_order(grid, yr, yf), n)
    cands.append((_loop_error(base, grid, yr, yf), par.theta(base), "branch regression"))
    try:
        from fitter.identification.ri_loop import identify_ri_loop
    except ImportError:
        identify_ri_loop = None
    if identify_ri_loop is not None and n % 2 == 1:
        errors = {}
        for qq in (Q_CANDIDATES if q is None else (q,)):
            try:
                mod = identify_ri_loop(grid, yr, yf, m=(n + 1) // 2, q=qq).model
                errors[qq] = (_loop_error(mod, grid, yr, yf), par.theta(mod))
            except (ValueError, np.linalg.LinAlgError, ArithmeticError) as exc:
                info.setdefault("ri_identification_errors", []).append(str(exc)[:200])
        if errors:
            qq = min(errors, key=lambda k: errors[k][0])
            info["q"] = qq
            info["q_loop_errors"] = {str(k): v[0] for k, v in errors.items()}
            cands.append((errors[qq][0], errors[qq][1], f"section III, q = {qq}"))
    cands = [c for c in cands if np.all(np.isfinite(c[1]))]
    cands.sort(key=lambda c: c[0])
    info["start"] = cands[0][2]
    info["start_loop_error"] = cands[0][0]
    return [c[1] for c in cands[:3]], info


# --------------------------------------------------------------------- fitting
@dataclass
class _Candidate:
    param: object
    res: RefineResult
    rss: float
    n_samples: int
    rhos: list[float]
    start_info: dict

    @property
    def bic(self) -> float:
        N = self.n_samples
        return float(N * np.log(self.rss / N) + self.param.size * np.log(N))


def _barrier(param, data: _Data) -> Callable[[np.ndarray], np.ndarray]:
    lo = min(r.u.min() for r in data.norm)
    hi = max(r.u.max() for r in data.norm)

    def pen(th):
        try:
            m = param.build(th)
            with np.errstate(all="ignore"):
                val = param.rho(m, lo, hi) if np.all(np.isfinite(th)) else np.inf
        except (ValueError, np.linalg.LinAlgError):
            val = np.inf
        if not np.isfinite(val):
            return np.array([1e3])
        limit = RHO_MARGIN if param.kind == "ri" else -1e-3
        return np.array([1e3 * max(0.0, val - limit)])
    return pen


def _convergence_ok(param, m, data: _Data) -> tuple[bool, float]:
    lo = min(r.u.min() for r in data.norm)
    hi = max(r.u.max() for r in data.norm)
    val = param.rho(m, lo, hi)
    return (val < 1 if param.kind == "ri" else val < 0), val


def _refine(param, theta0, data: _Data, progress) -> RefineResult:
    """Refine from theta0; the rate-independent model carries a barrier on condition (5)
    (the rate-dependent one satisfies its condition by construction)."""
    pen = _barrier(param, data) if param.kind == "ri" else None
    return refine(param.build, theta0, data.norm, x0=data.x0_mode, cycles=data.cycles,
                  progress=progress, penalty=pen, max_nfev=MAX_NFEV)


def _candidate(param, starts, data: _Data, info, progress) -> _Candidate:
    best = None
    for th0 in starts:
        try:
            res = _refine(param, th0, data, progress)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if best is None or res.cost < best.cost:
            best = res
    if best is None:
        raise FitError(f"{param.kind} order {param.n}: every start failed to simulate")
    r = np.concatenate(best.residuals)
    return _Candidate(param, best, float(np.sum(r ** 2)), len(r), best.rho, info)


def _rate_levels(data: _Data) -> tuple[float, np.ndarray, int, bool]:
    """v_ref, the g knots (ln(rate/v_ref)), the number of distinct rate levels (normalised
    units) and whether all inputs are triangle waves (|du/dt| constant within 15%)."""
    meds, pooled, triangle = [], [], True
    for r in data.norm:
        v = np.abs(np.diff(r.u) / np.diff(r.t))
        v = v[v > 1e-3 * np.median(v[v > 0])]
        meds.append(np.median(v))
        pooled.append(v)
        inner = (v > np.quantile(v, 0.1)) & (v < np.quantile(v, 0.9))
        if not inner.any() or np.std(v[inner]) > 0.15 * np.median(v):
            triangle = False
    meds = np.sort(meds)
    groups = np.split(meds, np.flatnonzero(meds[1:] / meds[:-1] > 1.5) + 1)
    levels = np.array([np.exp(np.mean(np.log(g))) for g in groups])
    if not triangle:
        v = np.concatenate(pooled)
        levels = np.exp(np.unique(np.quantile(np.log(v), np.linspace(0.02, 0.99, 7))))
    v_ref = float(levels[len(levels) // 2])
    return v_ref, np.log(levels / v_ref), len(groups), triangle


def _rd_starts(param: _RDParam, ri: _Candidate | None, lower: _Candidate | None, data: _Data,
               triangle: bool):
    """Starts for the rate-dependent fit: the order-(n-1) fit embedded, Section V (triangle
    waves only), and the rising branch of the rate-independent fit with g = |v|."""
    starts, info = [], {}
    if lower is not None:
        m = _embed(lower.res.model, param.n)
        starts.append(np.r_[param.theta_from(m.A, m.B, m.E, m.C, m.D)[:-1 - param.n_c],
                            lower.res.theta[-1 - param.n_c:]])
        info["start"] = f"order {param.n - 1} fit, embedded"
    if triangle and len(data.norm) >= 2:
        try:
            from fitter.identification.rd_triangles import identify_rd_triangles
            ident = identify_rd_triangles([(r.t, r.u, r.y) for r in data.norm], order=param.n)
            m = ident.model
            vk = param.v_ref * np.exp(param.knots)
            gk = np.abs(m.g(vk))
            gv = np.abs(m.g(np.array([param.v_ref, -param.v_ref])))
            if not np.all(np.r_[gk, gv] > 0):
                raise ValueError("identified g is not positive at the data's rates")
            k = gv[0] / param.v_ref
            h = np.log(gk / (k * vk))
            c = np.r_[np.log(gv[1] / gv[0]), h[np.abs(param.knots) != 0]]
            starts.append(param.theta_from(m.A * k, m.B * k, m.E * k, m.C, m.D, c))
            info.setdefault("start", "section V triangle-wave identification")
        except (ImportError, ValueError, np.linalg.LinAlgError, ArithmeticError) as exc:
            info["rd_identification_error"] = str(exc)[:200]
    if ri is not None:
        m = ri.res.model
        starts.append(param.theta_from(m.A_plus, m.B_plus, m.E_plus, m.C, m.D))
        info.setdefault("start", "rising branch of the rate-independent fit, g = |v|")
    starts = [th for th in starts if np.all(np.isfinite(th))]
    return starts[:2], info


# ---------------------------------------------------------------------- results
@dataclass
class FitResult:
    """A fitted model (physical units) and its JSON-able summary.

    `predict(rec)` and `band(rec)` give the model output for any recording
    with the same columns (input made monotone between reversals), started
    from the periodic state of its first settled cycle: a prediction, nothing
    is fitted to `rec` (NaN before that cycle, the dropped transient).
    """

    model: object
    summary: dict
    theta: np.ndarray
    cov: np.ndarray
    build: Callable[[np.ndarray], object] = field(repr=False)

    def _start(self, rec: Recording) -> tuple[int, tuple[int, int], np.ndarray]:
        """First kept sample, first settled cycle (relative to it) and the monotone input."""
        prep = prepare(rec, min_cycles=0)
        u = monotone_input(prep.recording.u, prep.reversals)
        return prep.transient_end, _cycle_of(prep), u

    def _simulate(self, model, rec: Recording, start: int, cyc, u) -> np.ndarray:
        from fitter.core.kernel import simulate
        t = rec.t[start:]
        x0, _ = cycle_fixed_point(model, t[cyc[0]:cyc[1] + 1], u[cyc[0]:cyc[1] + 1])
        y = np.full(len(rec.u), np.nan)
        y[start + cyc[0]:] = simulate(model, t[cyc[0]:], u[cyc[0]:], x0=x0).y
        return y

    def predict(self, rec: Recording) -> np.ndarray:
        """Model output on the samples of `rec` (NaN on the dropped transient)."""
        start, cyc, u = self._start(rec)
        return self._simulate(self.model, rec, start, cyc, u)

    def band(self, rec: Recording, level: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
        """Uncertainty band y_hat -+ level * sd, sd^2 = diag(J cov J^T) (linearised, J by differences)."""
        start, cyc, u = self._start(rec)
        ok = None

        def fun(th):
            nonlocal ok
            y = self._simulate(self.build(th), rec, start, cyc, u)
            ok = np.isfinite(y)
            return np.where(ok, y, 0.0)
        y0 = fun(self.theta)
        mask = ok.copy()
        J = jacobian(fun, self.theta, y0)
        sd = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", J, self.cov, J), 0, None))
        y0 = np.where(mask, y0, np.nan)
        return y0 - level * sd, y0 + level * sd


def _signals(recordings: Sequence[Recording]) -> Signals:
    r = recordings[0]
    return Signals(input=r.input, output=r.output)


def _experiment(recordings: Sequence[Recording]) -> Experiment:
    r = max(recordings, key=lambda rec: rec.t[-1] - rec.t[0])
    return Experiment(start_time=float(r.t[0]), stop_time=float(r.t[-1]),
                      step_size=float(np.median(np.diff(r.t))))


def fit_recordings(recordings: Sequence[Recording], *, kind: str = "auto", order: int | None = None,
                   q: float | None = None, progress: Callable[[str], None] | None = None) -> FitResult:
    """Fit a semilinear Duhem model to one or more recordings (see the module docstring).

    Parameters
    ----------
    recordings : periodic experiments (one per rate, say) with the same columns.
    kind : "ri" (rate-independent, eqs 1-2), "rd" (rate-dependent, eqs 18-19) or "auto" (BIC).
    order : state dimension n; default chosen by BIC among 1, 2, 3.
    q : bound of the Section III constrained least squares; default chosen by loop error.
    progress : called with one-line status messages.

    Returns
    -------
    FitResult with `.model` (physical units, signals and experiment filled in) and `.summary`.
    """
    if kind not in ("auto", "ri", "rd"):
        raise ValueError(f"kind must be 'auto', 'ri' or 'rd', not {kind!r}")
    if order is not None and order not in ORDERS:
        raise ValueError(f"order must be one of {ORDERS}, not {order!r}")
    say = progress or (lambda s: None)
    data, scaling = _prepare_all(recordings)
    grid, yr, yf = _averaged_loop(data.loops)
    v_ref, knots, levels, triangle = _rate_levels(data)
    orders = ORDERS if order is None else (order,)
    cands: list[_Candidate] = []
    ri_fits: dict[int, _Candidate] = {}
    ri_orders = orders if kind != "rd" else orders[:1]
    for n in ri_orders:
        say(f"rate-independent model, order {n}")
        lower = ri_fits.get(n - 1)
        starts, info = _ri_starts(grid, yr, yf, n, q, lower.res.model if lower else None)
        ri_fits[n] = _candidate(_RIParam(n), starts, data, info, progress)
        if kind in ("auto", "ri"):
            cands.append(ri_fits[n])
        if lower is not None and ri_fits[n].bic > lower.bic and kind == "ri":
            break
    if kind == "rd" or (kind == "auto" and levels >= 2):
        rd_fits: dict[int, _Candidate] = {}
        for n in orders:
            say(f"rate-dependent model, order {n}")
            param = _RDParam(n, v_ref, knots)
            starts, info = _rd_starts(param, ri_fits.get(n), rd_fits.get(n - 1), data, triangle)
            rd_fits[n] = _candidate(param, starts, data, info, progress)
            cands.append(rd_fits[n])
            if n - 1 in rd_fits and rd_fits[n].bic > rd_fits[n - 1].bic:
                break
    best = min(cands, key=lambda c: c.bic)
    return _result(best, cands, data, scaling, recordings, kind, q, levels, triangle, v_ref)


def _result(best: _Candidate, cands, data: _Data, scaling: _Scaling, recordings, kind, q, levels,
            triangle, v_ref) -> FitResult:
    param, res = best.param, best.res
    build = lambda th: scaling.to_physical(param.build(th))
    model = build(res.theta)
    model.signals = _signals(recordings)
    model.experiment = _experiment(recordings)
    ok, val = _convergence_ok(param, res.model, data)
    rhos = [cycle_fixed_point(res.model, r.t[a:b + 1], r.u[a:b + 1])[1]
            for r, (a, b) in zip(data.norm, data.cycles)]
    per_rec = []
    for rec, prep, r, s in zip(data.recs, data.preps, res.residuals, res.starts):
        y_hat = np.full(len(rec.y), np.nan)
        y_hat[s:] = rec.y[s:] - r * scaling.y_s
        seg = rec.slice(slice(s, None))
        m = compare(seg, y_hat[s:])
        m.update(recording=rec.name, transient_end=prep.transient_end)
        per_rec.append(m)
    stderr = dict(zip(param.names(), zip(res.theta.tolist(), res.stderr.tolist())))
    summary = {
        "kind": param.kind, "order": param.n,
        "q": q if q is not None else next((c.start_info["q"] for c in cands if "q" in c.start_info), None),
        "q_why": "given" if q is not None else "lowest loop error of the Section III estimate among "
                 f"{list(Q_CANDIDATES)} (a start for the output-error refinement only)",
        "why": _why(best, cands, kind, levels),
        "candidates": [{"kind": c.param.kind, "order": c.param.n, "parameters": c.param.size,
                        "rss_normalised": c.rss, "bic": c.bic, "start": c.start_info.get("start")}
                       for c in cands],
        "recordings": per_rec,
        "parameters_normalised": {k: {"value": v, "stderr": e} for k, (v, e) in stderr.items()},
        "normalisation": vars(scaling),
        "convergence": {"satisfied": bool(ok),
                        "quantity": "rho(e^{beta A+} e^{-beta A-}) (condition 5)" if param.kind == "ri"
                        else "max Re eig(A) (< 0 <=> rho(period map) < 1 since g >= 0)",
                        "value": val, "rho_per_recording": rhos},
        "rate_levels": levels, "triangle_inputs": triangle,
        "v_ref": v_ref * scaling.u_s if param.kind == "rd" else None,
        "x0": X0_TEXT[data.x0_mode],
        "optimiser": {"success": res.success, "nfev": res.nfev, "message": res.message},
        "preparation": [dict(p.to_dict(), notes=n) for p, n in zip(data.preps, data.notes)],
    }
    model.fit_info = {k: summary[k] for k in ("kind", "order", "why", "convergence")}
    cov = res.cov
    return FitResult(model=model, summary=_jsonable(summary), theta=res.theta, cov=cov, build=build)


def _why(best: _Candidate, cands, kind: str, levels: int) -> str:
    ranked = sorted(cands, key=lambda c: c.bic)
    text = (f"lowest BIC ({best.bic:.1f}) among {len(cands)} candidate(s) "
            f"({', '.join(f'{c.param.kind}{c.param.n}: {c.bic:.1f}' for c in ranked)})")
    if kind != "auto":
        text = f"kind {kind!r} requested; order by " + text
    if levels < 2 and best.param.kind == "rd":
        text += "; note: a single input rate, so g is barely identifiable"
    if levels < 2 and kind == "auto":
        text += ("; rate-dependent candidates not tried: the recordings have a single input rate, "
                 "from which rate dependence cannot be established (use --kind rd to force it)")
    return text


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj
