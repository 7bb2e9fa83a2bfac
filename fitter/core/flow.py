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

(K) is solved in the eigenbasis A = V diag(lambda) V^-1 with the phi-functions
phi1(z) = (e^z - 1)/z and phi2(z) = (e^z - 1 - z)/z^2:

    w(S) = e^{lambda S} w(0) + S phi1(lambda S) c0 + S^2 phi2(lambda S) c1,

c0 = V^-1 (B p + E), c1 = V^-1 B r.  Over many intervals with one A the scalar
recurrences w_{k+1} = a_k w_k + f_k are summed in closed form (cumulative
products as exponentials of cumulative sums), in chunks short enough that no
exponential overflows.  When V is ill-conditioned (defective A, e.g. the
Jordan blocks that a bilinear transform makes of a shift register) the kernel
falls back to the matrix exponential of the augmented matrix
[[A, B r, B p + E], [0, 0, 1], [0, 0, 0]] one interval at a time.

`kernel.simulate` (base model) and `effects.run_with_effects` (effect chain)
both run on these functions; `check_finite` and `check_increasing` are the
one place where samples are checked.  This module needs only numpy: it is
shipped inside the FMUs.
"""
from __future__ import annotations

import math

import numpy as np

from .errors import KernelError

__all__ = ["AffineFlow", "check_finite", "check_increasing", "expm", "flows", "integrate",
           "interval_coefficients", "linear_recurrence", "one_interval", "phi1", "phi2"]

_COND_LIMIT = 1e6
_CHUNK_SPAN = 300.0


def phi1(z: np.ndarray) -> np.ndarray:
    """(e^z - 1)/z, equal to 1 at z = 0; accurate for small |z|."""
    z = np.asarray(z, dtype=complex)
    out = np.ones_like(z)
    big = np.abs(z) >= 1e-8
    out[big] = np.expm1(z[big]) / z[big]
    small = ~big
    out[small] += z[small] / 2
    return out


_PHI2_SERIES = np.array([1.0 / np.prod(np.arange(1.0, k + 1)) for k in range(2, 20)])


def phi2(z: np.ndarray) -> np.ndarray:
    """(e^z - 1 - z)/z^2, equal to 1/2 at z = 0; Taylor series for |z| < 0.5."""
    z = np.asarray(z, dtype=complex)
    out = np.empty_like(z)
    small = np.abs(z) < 0.5
    zb = z[~small]
    out[~small] = (np.expm1(zb) - zb) / (zb * zb)
    zs = z[small]
    acc = np.full_like(zs, _PHI2_SERIES[-1])
    for c in _PHI2_SERIES[-2::-1]:
        acc = acc * zs + c
    out[small] = acc
    return out


_PHI2_POWERS = np.arange(len(_PHI2_SERIES))


def expm(M: np.ndarray) -> np.ndarray:
    """Matrix exponential by scaling and squaring of a degree-18 Taylor series.

    The matrix is scaled to 1-norm <= 0.5, where the truncation error is below
    1e-20 relative; used only by the fallback path and by tests.
    """
    M = np.asarray(M, dtype=float)
    norm = np.abs(M).sum(axis=0).max() if M.size else 0.0
    s = max(0, int(np.ceil(np.log2(norm / 0.5)))) if norm > 0.5 else 0
    X = M / (2.0 ** s)
    result = np.eye(M.shape[0])
    term = np.eye(M.shape[0])
    for k in range(1, 19):
        term = term @ X / k
        result = result + term
    for _ in range(s):
        result = result @ result
    return result


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

    def _augmented(self, p: float, r: float) -> np.ndarray:
        n = self.n
        M = np.zeros((n + 2, n + 2))
        M[:n, :n] = self.A
        M[:n, n] = self.B * r
        M[:n, n + 1] = self.B * p + self.E
        M[n, n + 1] = 1.0
        return M

    def step(self, x: np.ndarray, p: float, r: float, S: float) -> np.ndarray:
        """x(S) of (K) from x(0) = x."""
        if S == 0.0:
            return np.array(x, dtype=float)
        if not self.modal:
            Z = expm(self._augmented(p, r) * S)
            return Z[:self.n, :self.n] @ x + Z[:self.n, self.n + 1]
        z = self.lam * S
        if abs(S) * self._lam_max < 0.5:
            # the Taylor series of `phi2`, summed as (c_k lambda^k) S^k, c_k lambda^k precomputed
            p2 = self._phi2_terms @ (S ** _PHI2_POWERS)
            p1 = 1.0 + z * p2
        else:
            p1, p2 = phi1(z), phi2(z)
        w = np.exp(z) * (self.Vinv @ x) + (S * p1) * (self.beta * p + self.eps) \
            + (S * S * r) * p2 * self.beta
        return (self.V @ w).real

    def run(self, x0: np.ndarray, p: np.ndarray, r: np.ndarray, S: np.ndarray) -> np.ndarray:
        """States after each of N intervals, shape (N, n), from x0 before the first."""
        N = len(S)
        if N == 0:
            return np.zeros((0, self.n))
        if not self.modal:
            out = np.empty((N, self.n))
            x = np.asarray(x0, dtype=float)
            for k in range(N):
                x = self.step(x, p[k], r[k], S[k])
                out[k] = x
            return out
        z = np.outer(S, self.lam)
        a = np.exp(z)
        f = (S[:, None] * phi1(z)) * (np.outer(p, self.beta) + self.eps) \
            + (S[:, None] ** 2 * phi2(z)) * np.outer(r, self.beta)
        W = linear_recurrence(self.Vinv @ np.asarray(x0, dtype=float), z, a, f)
        return (W @ self.V.T).real


def linear_recurrence(w0: np.ndarray, z: np.ndarray, a: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Solve w_{k+1} = a_k w_k + f_k (a_k = e^{z_k}) for all k, vectorised.

    Within a chunk, w_{k+1} = P_{k+1} (w_c + sum_{j<=k} f_j / P_{j+1}) with
    P = exp(cumsum z) relative to the chunk's first state w_c; chunks are cut
    so that |Re cumsum z| stays below 300 and no exponential overflows.  The
    first step of every chunk is taken directly, so a single huge step is safe.
    """
    N = len(z)
    span = np.cumsum(np.abs(z.real).max(axis=1))
    if span[-1] < _CHUNK_SPAN:
        starts, ends = (0,), (N,)
    else:
        chunk_id = np.floor(span / _CHUNK_SPAN).astype(np.int64)
        starts = np.concatenate(([0], np.flatnonzero(np.diff(chunk_id)) + 1))
        ends = np.concatenate((starts[1:], [N]))
    W = np.empty_like(f)
    w = w0.astype(complex)
    for s0, s1 in zip(starts, ends):
        w = a[s0] * w + f[s0]
        W[s0] = w
        if s1 - s0 > 1:
            L = np.cumsum(z[s0 + 1:s1], axis=0)
            P = np.exp(L)
            W[s0 + 1:s1] = P * (w + np.cumsum(f[s0 + 1:s1] * np.exp(-L), axis=0))
            w = W[s1 - 1]
    return W


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
        raise KernelError(f"time must increase: t[{bad[0] + 1}] = {t[bad[0] + 1]} "
                          f"after t[{bad[0]}] = {t[bad[0]]}")


def interval_coefficients(model, t: np.ndarray, u: np.ndarray):
    """Per-interval (branch, p, r, S) of (K) for a sampled input; see module docstring.

    branch is +1 (u rises, or rate-dependent model), -1 (u falls); for the
    rate-independent model a held input (du = 0) keeps the previous branch.
    """
    du = np.diff(u)
    p = u[:-1]
    if model.kind == "ri":
        branch = np.sign(du)
        idx = np.where(branch != 0, np.arange(len(du)), 0)
        np.maximum.accumulate(idx, out=idx)
        branch = np.where(branch[idx] == 0, 1.0, branch[idx])
        return branch, p, np.ones_like(du), du
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
        return {1.0: AffineFlow(model.A_plus, model.B_plus, model.E_plus),
                -1.0: AffineFlow(model.A_minus, model.B_minus, model.E_minus)}
    f = AffineFlow(model.A, model.B, model.E)
    return {1.0: f, -1.0: f}


def integrate(fl: dict, x0: np.ndarray, branch: np.ndarray, p: np.ndarray, r: np.ndarray,
              S: np.ndarray) -> np.ndarray:
    """States (N+1, n) at the samples from x0, given the N intervals' (branch, p, r, S) of (K)."""
    X = np.empty((len(S) + 1, fl[1.0].n))
    X[0] = x0
    cuts = np.r_[0, np.flatnonzero(np.diff(branch)) + 1, len(S)]
    for s0, s1 in zip(cuts[:-1], cuts[1:]):
        if s1 > s0:
            X[s0 + 1:s1 + 1] = fl[branch[s0]].run(X[s0], p[s0:s1], r[s0:s1], S[s0:s1])
    return X
