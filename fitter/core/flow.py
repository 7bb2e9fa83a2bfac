"""Exact flows of the semilinear Duhem models over sample intervals (the kernel's numerics).

Everything reduces to one primitive, the exact solution of the affine ODE

    dx/ds = A x + B (p + r s) + E,      0 <= s <= S,                      (K)

over one sample interval, where s is the interval's own independent variable:

* rate-independent model, eqs (1)-(3): on an interval where u moves from u_k to
  u_{k+1} the input is monotone, so by Proposition 1 x is a function of u with
  dx/du = A± x + B± u + E± (A+ when u rises, A- when it falls).  With
  s = u - u_k: S = u_{k+1} - u_k (negative on a falling interval), p = u_k, r = 1.
  The result depends on the input samples only, not on their timing.
* rate-dependent model, eq (18): the input is taken piecewise linear between
  samples, so on an interval v = du/dt is constant and dx/dt = g(v)(A x + B u + E).
  With s = g(v) tau: S = g(v) h, p = u_k, r = v / g(v) (r = 0 when g(v) = 0,
  where nothing moves).

(K) is solved in the eigenbasis A = V diag(lambda) V^-1 (in real arithmetic
when every eigenvalue is real) with the phi-functions
phi1(z) = (e^z - 1)/z and phi2(z) = (e^z - 1 - z)/z^2:

    w(S) = e^{lambda S} w(0) + S phi1(lambda S) c0 + S^2 phi2(lambda S) c1,

c0 = V^-1 (B p + E), c1 = V^-1 B r.  Over many intervals with one A the scalar
recurrences w_{k+1} = a_k w_k + f_k are summed in closed form (cumulative
products as exponentials of cumulative sums), in chunks short enough that no
exponential overflows, or interval after interval by compiled code in the
optimiser (`fitter.core.scans`).  When V is ill-conditioned (defective A, e.g. the
Jordan blocks that a bilinear transform makes of a shift register) the kernel
falls back to the same phi-functions as matrices, blocks of
expm([[A S, I, 0], [0, 0, I], [0, 0, 0]]) computed on n x n blocks
(`phi_blocks`, `AffineFlow.affine_maps`, the native FMU's flow, same numbers),
for all intervals at once.

`kernel.simulate` (base model) and `effects.run_with_effects` (effect chain)
both run on these functions; `check_finite` and `check_increasing` are the
one place where samples are checked.  This module needs only numpy: it is
shipped inside the FMUs.
"""

from __future__ import annotations

import math
from typing import Iterator

import numpy as np

from .errors import KernelError
from .scans import integrate_dense, integrate_modal, modal_pass

__all__ = [
    "AffineFlow",
    "branches",
    "check_finite",
    "check_increasing",
    "expm",
    "flows",
    "integrate",
    "integrate_blocks",
    "integrate_runs",
    "interval_coefficients",
    "one_interval",
    "phi1",
    "phi2",
    "phi_blocks",
]

_COND_LIMIT = 1e6
_BLOCK = 1 << 16
"""Intervals that `integrate` sums at a time (its work arrays are a few times block x n x m)."""


def phi1(z: np.ndarray) -> np.ndarray:
    """(e^z - 1)/z, equal to 1 at z = 0; accurate for small |z| (real for real z)."""
    z = np.asarray(z, dtype=complex if np.iscomplexobj(z) else float)
    big = np.abs(z) >= 1e-8
    if big.all():
        return np.expm1(z) / z
    out = np.ones_like(z)
    out[big] = np.expm1(z[big]) / z[big]
    small = ~big
    out[small] += z[small] / 2
    return out


_PHI2_SERIES = np.array([1.0 / np.prod(np.arange(1.0, k + 1)) for k in range(2, 20)])


def phi2(z: np.ndarray) -> np.ndarray:
    """(e^z - 1 - z)/z^2, equal to 1/2 at z = 0; Taylor series for |z| < 0.5 (real for real z)."""
    z = np.asarray(z, dtype=complex if np.iscomplexobj(z) else float)
    small = np.abs(z) < 0.5
    if small.all():
        return _phi2_series(z)
    out = np.empty_like(z)
    zb = z[~small]
    out[~small] = (np.expm1(zb) - zb) / (zb * zb)
    out[small] = _phi2_series(z[small])
    return out


def _phi2_series(z: np.ndarray) -> np.ndarray:
    """The Taylor series of `phi2` at z (|z| < 0.5), by Horner's rule."""
    acc = np.full_like(z, _PHI2_SERIES[-1])
    for c in _PHI2_SERIES[-2::-1]:
        acc = acc * z + c  # not in place: taken back with `integrate_modal`'s W (cee844c), not shown to round alike
    return acc


_PHI2_POWERS = np.arange(len(_PHI2_SERIES))


def expm(M: np.ndarray) -> np.ndarray:
    """Matrix exponential of one (m, m) matrix or of a stack (N, m, m), by scaling and squaring
    of a degree-18 Taylor series.

    Each matrix is scaled to 1-norm <= 0.5, where the truncation error is below
    1e-20 relative; a matrix with a NaN or infinite entry gives NaN.  Used by the
    fallback path of `integrate` (a stack of interval flows), by `AffineFlow.step`
    and by condition (5).
    """
    M = np.asarray(M, dtype=float)
    stack = M if M.ndim == 3 else M[None]
    m = stack.shape[-1]
    result = np.broadcast_to(np.eye(m), stack.shape).copy()
    if stack.size == 0:
        return result if M.ndim == 3 else result[0]
    norm = np.abs(stack).sum(axis=-2).max(axis=-1)
    finite = np.isfinite(norm)
    norm = np.where(finite, norm, 0.0)
    s = np.where(norm > 0.5, np.ceil(np.log2(np.maximum(norm, 0.5) / 0.5)), 0).astype(np.int64)
    X = stack / np.exp2(s)[:, None, None]
    term = result.copy()
    for k in range(1, 19):
        term = term @ X / k
        result += term
    for i in range(int(s.max())):
        sel = s > i
        result[sel] = result[sel] @ result[sel]
    result[~finite] = np.nan
    return result if M.ndim == 3 else result[0]


_SMALL_STACK = 64
"""Up to this many matrices, `_product` forms all the terms at once and sums them with one call."""
TAYLOR_DEGREE = 18
"""The highest degree of `phi_blocks`' Taylor series (the degree of `scipy.linalg.expm`'s, reached
only where `taylor_degree`'s bound asks for it)."""
TAYLOR_TAIL = 2.0**-56
"""`taylor_degree`'s bound on the first omitted term, theta^(m-1) / (m+1)! (duhem_model.c's TAYLOR_TAIL)."""


def _product(L: np.ndarray, R: np.ndarray) -> np.ndarray:
    """L R for stacks laid out (n, n, N), the stack index last: every entry sums L[i, j] R[j, c] over
    ascending j, one rounding per product and per sum, as the native FMU's `product` does (numpy's
    matmul may order the sums otherwise), so that `phi_blocks` gives the C's numbers.

    A small stack takes two numpy calls: the products L[i, j] R[j, c] as one array, summed over j
    by `np.add.accumulate` (sequential by definition: ((t0 + t1) + t2) + ...); a large one adds
    the terms j = 1, 2, ... in place (the same sums, less memory traffic)."""
    if L.shape[-1] <= _SMALL_STACK:
        return np.add.accumulate(L[:, :, None] * R[None], axis=1)[:, -1]
    P = L[:, :1] * R[:1]
    for j in range(1, L.shape[1]):
        P += L[:, j : j + 1] * R[j : j + 1]
    return P


def taylor_degree(theta: np.ndarray) -> np.ndarray:
    """The degree m of `phi_blocks`' Taylor series for scaled blocks a of 1-norm theta <= 0.5: the least
    m >= 2 with theta^(m-1) / (m+1)! <= `TAYLOR_TAIL`, at most `TAYLOR_DEGREE`.

    The first omitted terms are T2_(m+1) = c^2 a^(m-1) / (m+1)!, T1_(m+1) = c a^m / (m+1)! and
    T0_(m+1) = a^(m+1) / (m+1)!, against blocks F2 ~ c^2 / 2, F1 ~ c, F0 ~ I; the later terms shrink
    by theta / (k+2) <= 1/8 each, so the tail is below 2.3 theta^(m-1) / (m+1)! of F2 (1.5e-17 at
    the tail bound 2^-56): 15 at theta = 0.5, 7 for a step with theta = 5e-3 (18 before: the cost of
    a native FMU step at order 4 was mostly its Taylor terms).  The bound's products are the
    native FMU's (`taylor_degree` in duhem_model.c), so both choose the same degree."""
    theta = np.asarray(theta, dtype=float)
    bound = theta / 6.0  # theta^(m-1) / (m+1)! at m = 2
    m = np.full(theta.shape, 2, dtype=np.int64)
    for k in range(2, TAYLOR_DEGREE):
        more = ~(bound <= TAYLOR_TAIL)
        if not more.any():
            break
        m = np.where(more, k + 1, m)
        bound = np.where(more, bound * (theta / (k + 2)), bound)
    return m


def phi_blocks(AS: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """F0 = e^{AS}, F1 = phi1(AS), F2 = phi2(AS) for a stack (N, n, n) of matrices AS: the top
    blocks of

        e^X = [[F0, F1, F2], [0, I, I], [0, 0, I]],   X = [[AS, I, 0], [0, 0, I], [0, 0, 0]]   (3n x 3n)

    (Van Loan 1978), computed as `expm` computes e^X (scaling to 1-norm <= 0.5, Taylor
    series, squaring) but on the n x n blocks, O(n^3) instead of O((3n)^3), and the series cut at
    the degree its terms need (`taylor_degree`):

    * scaling: the 1-norm of X is max(|AS|_1, 1) (the identity blocks' columns sum to 1); with s
      the least number of halvings bringing it to <= 0.5, Y = X / 2^s = [[a, cI, 0], [0, 0, cI],
      [0, 0, 0]], a = AS / 2^s, c = 2^-s;
    * Taylor: Y^k = [[a^k, c a^(k-1), c^2 a^(k-2)], [0, 0, [k = 1] cI], [0, 0, 0]]
      (a^-1 = a^-2 = 0), so the terms T_k = T_(k-1) Y / k have the top blocks
      T0_k = T0_(k-1) a / k, T1_k = (c T0_(k-1)) / k, T2_k = (c T1_(k-1)) / k, and
      e^Y = sum_(k<=m) T_k (m = `taylor_degree`) = [[F0, F1, F2], [0, I, cI], [0, 0, I]];
    * squaring: [[F0, F1, F2], [0, I, cI], [0, 0, I]]^2
      = [[F0 F0, F0 F1 + F1, F0 F2 + c F1 + F2], [0, I, 2c I], [0, 0, I]], s times, c doubling up
      to 1 (in the phi-functions, the doubling formulas phi1(2z) = (e^z + 1) phi1(z) / 2 and
      phi2(2z) = (e^z phi2(z) + phi1(z) + phi2(z)) / 4; Skaflestad & Wright 2009).

    Every entry is the sum of the 3n x 3n product with its zero terms dropped, in the same order:
    the numbers of the 3n x 3n algorithm cut at the same degree with its products summed in
    ascending order (`_product`), and those of the native FMU's `phi_blocks` (duhem_model.c),
    operation for operation.  A stack entry with a NaN or infinite entry gives NaN blocks.  The
    work arrays are laid out (n, n, N), so that every numpy operation runs over the stack, and
    [T0, T1, T2], [F0, F1, F2] are stacked, so that a Taylor term costs few numpy calls (one
    interval, `AffineFlow.step`).
    """
    AS = np.asarray(AS, dtype=float)
    n = AS.shape[-1]
    column = np.abs(AS).sum(axis=-2).max(axis=-1, initial=0.0)
    norm = np.maximum(column, 1.0)
    finite = np.isfinite(norm)
    # s: the least s >= 0 with norm / 2^s <= 0.5, from the exact binary exponent (norm = m 2^e,
    # 0.5 <= m < 1): s = e when m = 0.5, else e + 1 (what halving norm until <= 0.5 counts)
    mant, expo = np.frexp(np.where(finite, norm, 1.0))
    s = np.where(mant > 0.5, expo + 1, expo).astype(np.int64)
    # sorted by decreasing s, the squarings run on leading slices of the stack (views)
    order = np.argsort(-s, kind="stable")
    s = s[order]
    scale = np.exp2(s.astype(float))
    a = np.ascontiguousarray(np.where(finite[order, None, None], AS[order], 0.0).transpose(1, 2, 0)) / scale
    c = 1.0 / scale
    degree = taylor_degree(np.where(finite, column, 0.0)[order] / scale)
    lowest = int(degree.min(initial=TAYLOR_DEGREE))
    # k = 1: T0 = I a / 1 = a, T1 = (c I) / 1, T2 = 0; F = I + T (F0 = I + T0, F1 = T1, F2 = T2)
    T = np.zeros((3,) + a.shape)
    T[0] = a
    T[1] = np.eye(n)[:, :, None] * c
    F = T.copy()
    F[0] += np.eye(n)[:, :, None]
    for k in range(2, int(degree.max(initial=2)) + 1):
        P = _product(T[0], a)
        T[1:] = T[:2] * c / k  # T2 = (c T1) / k, T1 = (c T0) / k, from the previous T0, T1
        np.divide(P, k, out=T[0])  # T0 = (T0 a) / k
        F += T if k <= lowest else np.where(k <= degree, T, 0.0)  # past its degree, an entry adds nothing
    F0, F1, F2 = F
    counts = np.searchsorted(-s, -np.arange(1, int(s.max(initial=0)) + 1), side="right")
    for m in counts:
        f0, f1, f2, cm = F0[..., :m], F1[..., :m], F2[..., :m], c[:m]
        f2[...] = _product(f0, f2) + f1 * cm + f2
        f1[...] = _product(f0, f1) + f1
        f0[...] = _product(f0, f0)
        cm *= 2.0
    out = []
    for G in (F0, F1, F2):
        H = np.empty(AS.shape)
        H[order] = G.transpose(2, 0, 1)
        H[~finite] = np.nan
        out.append(H)
    return out[0], out[1], out[2]


class AffineFlow:
    """Exact flow of (K) for one matrix A; see the module docstring.

    Parameters
    ----------
    A : (n, n) array
    B, E : (n,) arrays
        The forcing directions of (K).
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, E: np.ndarray):
        self.A = np.asarray(A, dtype=float)
        self.B = np.asarray(B, dtype=float)
        self.E = np.asarray(E, dtype=float)
        self.n = self.A.shape[0]
        lam, V = np.linalg.eig(self.A)
        cond = np.linalg.cond(V)
        self.modal = bool(np.isfinite(cond) and cond < _COND_LIMIT)
        if self.modal:
            self.lam = lam
            self.V = V
            Vinv = np.linalg.inv(V)
            self.beta = Vinv @ self.B
            self.eps = Vinv @ self.E
            self.Vinv = Vinv
            self._lam_max = float(np.abs(lam).max())
            self._phi2_terms = lam[:, None] ** _PHI2_POWERS * _PHI2_SERIES

    def step(self, x: np.ndarray, p: float, r: float, S: float) -> np.ndarray:
        """x(S) of (K) from x(0) = x."""
        if S == 0.0:
            return np.array(x, dtype=float)
        if not self.modal:
            M, g = self.affine_maps(np.array([p]), np.array([r]), np.array([S]))
            return M[0] @ x + g[0]
        z = self.lam * S
        if abs(S) * self._lam_max < 0.5:
            # the Taylor series of `phi2`, summed as (c_k lambda^k) S^k, c_k lambda^k precomputed
            p2 = self._phi2_terms @ (S**_PHI2_POWERS)
            p1 = 1.0 + z * p2
        else:
            p1, p2 = phi1(z), phi2(z)
        w = np.exp(z) * (self.Vinv @ x) + (S * p1) * (self.beta * p + self.eps) + (S * S * r) * p2 * self.beta
        return (self.V @ w).real

    def modal_terms(
        self,
        p: np.ndarray,
        r: np.ndarray,
        S: np.ndarray,
        forcing: tuple[np.ndarray, np.ndarray] | None = None,
        modal_forcing: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per interval, in modal coordinates w = V^-1 x: exponents z = lambda S (N, n) and forcing
        f with w(S) = e^z w(0) + f (module docstring), (N, n); with `modal_forcing` = (beta, eps), modal
        vectors (n,) in place of the flow's own V^-1 B, V^-1 E; with `forcing` = (B, E), m forcing
        columns of shape (n, m) in place of the flow's own, f is (N, n, m)."""
        z = np.outer(S, self.lam)
        c1, c2 = S[:, None] * phi1(z), S[:, None] ** 2 * phi2(z)
        if forcing is None:
            beta, eps = (self.beta, self.eps) if modal_forcing is None else modal_forcing
            return z, (c1 * p[:, None] + c2 * r[:, None]) * beta + c1 * eps
        beta, eps = self.Vinv @ forcing[0], self.Vinv @ forcing[1]
        f = (c1 * p[:, None] + c2 * r[:, None])[:, :, None] * beta
        f += c1[:, :, None] * eps
        return z, f

    def affine_maps(
        self, p: np.ndarray, r: np.ndarray, S: np.ndarray, forcing: tuple[np.ndarray, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per interval, x(S) = M x(0) + g with M = e^{A S}, g = S K1 (B p + E) + S^2 K2 B r, where
        [[M, K1, K2], ...] = expm([[A S, I, 0], [0, 0, I], [0, 0, 0]]), computed on the n x n
        blocks by `phi_blocks` (all intervals at once).

        This is the phi-function form of the module docstring (S K1 = S phi1(A S),
        S^2 K2 = S^2 phi2(A S)), balanced so that the input level p does not enter the
        matrix: its norm, and the number of squarings, is that of A S (the native FMU's
        flow is the same, with the same numbers).  M is (N, n, n); g is (N, n), or (N, n, m)
        for m forcing columns (B, E) as in `modal_terms`.
        """
        M, K1, K2 = phi_blocks(self.A * S[:, None, None])
        K1 = K1 * S[:, None, None]
        K2 = K2 * (S**2)[:, None, None]
        if forcing is None:
            return M, (
                np.einsum("kij,j->ki", K1, self.B) * p[:, None]
                + K1 @ self.E
                + np.einsum("kij,j->ki", K2, self.B) * r[:, None]
            )
        B, E = forcing
        g = (
            np.einsum("kij,jm->kim", K1, B) * p[:, None, None]
            + np.einsum("kij,jm->kim", K1, E)
            + np.einsum("kij,jm->kim", K2, B) * r[:, None, None]
        )
        return M, g

    def run(self, x0: np.ndarray, p: np.ndarray, r: np.ndarray, S: np.ndarray) -> np.ndarray:
        """States after each of N intervals, shape (N, n), from x0 before the first."""
        return integrate({1.0: self}, x0, np.ones(len(S)), p, r, S)[1:]


def check_finite(name: str, a) -> np.ndarray:
    """`a` as a flat float array; KernelError naming the first NaN or infinite entry."""
    a = np.asarray(a, dtype=float).ravel()
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise KernelError(f"{name}[{bad[0]}] is {a[bad[0]]} (NaN or infinite)")
    return a


def check_increasing(t: np.ndarray) -> None:
    """KernelError at the first k where t_{k+1} > t_k fails (time must increase strictly)."""
    bad = np.flatnonzero(~(np.diff(t) > 0))
    if bad.size:
        raise KernelError(f"time must increase: t[{bad[0] + 1}] = {t[bad[0] + 1]} after t[{bad[0]}] = {t[bad[0]]}")


def branches(du: np.ndarray) -> np.ndarray:
    """The branch of each input interval, eq (1): +1 where u rises, -1 where it falls; a held input (du = 0)
    keeps the previous branch, +1 before the first move."""
    branch = np.sign(du)
    if not branch.all():
        idx = np.where(branch != 0, np.arange(len(du)), 0)
        np.maximum.accumulate(idx, out=idx)
        branch = branch[idx]
        branch[branch == 0] = 1.0
    return branch


def interval_coefficients(model, t: np.ndarray, u: np.ndarray):
    """Per-interval (branch, p, r, S) of (K) for a sampled input; see module docstring.

    branch is +1 (u rises, or rate-dependent model), -1 (u falls); for the
    rate-independent model a held input (du = 0) keeps the previous branch
    (+1 before the first move), and r = 1 is a read-only broadcast array.
    """
    du = np.diff(u)
    p = u[:-1]
    if model.kind == "ri":
        return branches(du), p, np.broadcast_to(1.0, du.shape), du
    check_increasing(t)
    dt = np.diff(t)
    v = du / dt
    gv = np.asarray(model.g(v), dtype=float)
    bad = np.flatnonzero(~np.isfinite(gv))
    if bad.size:
        raise KernelError(f"g(du/dt) is not finite at slope {v[bad[0]]}")
    safe = np.where(gv != 0, gv, 1.0)
    r = np.where(gv != 0, v / safe, 0.0)
    return np.ones_like(du), p, r, gv * dt


def one_interval(model, t_a: float, t: float, u_a: float, u: float) -> tuple:
    """(branch, p, r, S) of `interval_coefficients` for one interval, on floats.

    The communication-point stepper calls this once per step; it avoids numpy
    array overhead and must agree exactly with the vectorised function.
    """
    du = u - u_a
    if model.kind == "ri":
        return (1.0 if du >= 0 else -1.0), u_a, 1.0, du
    h = t - t_a
    if not h > 0:
        check_increasing(np.array([t_a, t]))
    v = du / h
    gv = float(model.g(v))
    if not math.isfinite(gv):
        raise KernelError(f"g(du/dt) is not finite at slope {v}")
    return 1.0, u_a, (v / gv if gv != 0.0 else 0.0), gv * h


def flows(model) -> dict:
    """The AffineFlow objects of a model, keyed by branch (+1 / -1)."""
    if model.kind == "ri":
        return {
            1.0: AffineFlow(model.A_plus, model.B_plus, model.E_plus),
            -1.0: AffineFlow(model.A_minus, model.B_minus, model.E_minus),
        }
    f = AffineFlow(model.A, model.B, model.E)
    return {1.0: f, -1.0: f}


def integrate(
    fl: dict,
    x0: np.ndarray,
    branch: np.ndarray,
    p: np.ndarray,
    r: np.ndarray,
    S: np.ndarray,
    forcing: dict | None = None,
) -> np.ndarray:
    """States at the samples given the N intervals' (branch, p, r, S) of (K).

    x0 is one initial state (n,) or m of them as the columns of an (n, m)
    array; the result is (N+1, n) or (N+1, n, m).  `forcing` (with m columns
    only) replaces the flows' B and E per column: {branch: (B, E)}, each (n, m);
    column j is then the response to x0[:, j] and the forcing B[:, j] u + E[:, j]
    (the responses the output-error engine needs to eliminate parameters that
    enter linearly).  The states come from `integrate_blocks`.
    """
    X0 = np.asarray(x0, dtype=float)
    out = np.empty((len(S) + 1,) + X0.shape)
    out[0] = X0
    k = 1
    for X in integrate_blocks(fl, X0, branch, p, r, S, forcing):
        out[k : k + len(X)] = X
        k += len(X)
    return out


def integrate_blocks(
    fl: dict,
    x0: np.ndarray,
    branch: np.ndarray,
    p: np.ndarray,
    r: np.ndarray,
    S: np.ndarray,
    forcing: dict | None = None,
) -> Iterator[np.ndarray]:
    """The states after each interval of `integrate` (x_1 ... x_N), in consecutive pieces of at most
    `_BLOCK` intervals: (k, n) or (k, n, m) arrays.

    When every flow used is modal, the modal pass in effect (`fitter.core.scans.modal_pass`: the numpy sums
    over segments, or the compiled scan inside `fitter.core.scans.compiled_scans`); otherwise every
    interval's affine map comes from the block matrix exponential of `AffineFlow.affine_maps` and the maps
    are composed by a blocked prefix scan (`fitter.core.scans`).  Each piece starts from the last state
    of the one before (a piece boundary is one more segment start), so the
    work arrays are those of one piece: a caller that reduces the states as
    they come (`kernel.state_blocks`) needs memory for one piece only.
    """
    x = np.asarray(x0, dtype=float)
    if len(S) == 0:
        return
    used = {b: fl[b] for b in np.unique(branch)}
    force = {b: None if forcing is None else forcing[b] for b in used}
    run = modal_pass() if all(flow.modal for flow in used.values()) else integrate_dense
    for a in range(0, len(S), _BLOCK):
        b = min(a + _BLOCK, len(S))
        X = run(used, force, x, branch[a:b], p[a:b], r[a:b], S[a:b])
        x = X[-1]
        yield X


def integrate_runs(
    fl: dict, x0: np.ndarray, runs: list[tuple], forcing: dict | None = None, C: np.ndarray | None = None
) -> list[np.ndarray] | None:
    """`integrate_blocks` of several runs from the same x0 (each run its (branch, p, r, S)) in one call of the
    compiled scan: per run, its states x_1 ... x_N, the same numbers as its own `integrate_blocks` gives.

    Each run is one piece there: it starts from x0 in the modal coordinates of its first interval's branch,
    and the scan restarts there at every run's first interval (`fitter.core.compiled.modal_scan`'s ``starts``).
    What a recording's intervals cost in numpy calls besides the scan (the flows' modal forcing stacked, the
    branches indexed, the scan dispatched) is then paid once for all the recordings of an evaluation.  None
    where that is not so: outside `fitter.core.scans.compiled_scans`, with a flow used that is not modal, or
    with a run that is empty or longer than one piece (the caller then integrates run by run).  `C`: the outputs
    C x per run instead of the states (`fitter.core.compiled.modal_scan`'s ``C``)."""
    scan = modal_pass()
    if scan is integrate_modal or not all(0 < len(S) <= _BLOCK for *_, S in runs):
        return None
    branch = np.concatenate([run[0] for run in runs])
    used = {b: fl[b] for b in np.unique(branch)}
    if not all(flow.modal for flow in used.values()):
        return None
    force = {b: None if forcing is None else forcing[b] for b in used}
    p, r, S = (np.concatenate([np.broadcast_to(run[k], run[3].shape) for run in runs]) for k in (1, 2, 3))
    ends = np.cumsum([len(run[3]) for run in runs])
    firsts = np.r_[0, ends[:-1]]
    X = scan(used, force, np.asarray(x0, dtype=float), branch, p, r, S, firsts, C)
    return [X[a:b] for a, b in zip(firsts, ends)]
