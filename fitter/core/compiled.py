"""The kernel's modal recurrence compiled (numba): one pass over the intervals, a few operations per state.

`fitter.core.flow` solves eq (K) over N intervals in the eigenbasis of each branch's A: in modal coordinates
w = V^-1 x every interval is the scalar affine step

    w <- e^{z} w + S phi1(z) (beta p + eps) + S^2 phi2(z) beta r,      z = lambda S,             (M)

(beta = V^-1 B, eps = V^-1 E; the module docstring of `fitter.core.flow`), and a change of branch maps the
state through x = Re(V w), w' = V'^-1 x.  numpy sums (M) in closed form over segments (cumulative sums of the
exponents, some twenty array passes of every (interval, state, column) entry, each a numpy call); on
recordings of some hundred samples the calls' overhead and the passes cost more than the arithmetic.  Here
(M) runs as it reads, interval after interval, in compiled code: the same exact flow, the same
phi-functions (`phi1`, `phi2` of `fitter.core.flow`: the Taylor series of phi2 below |z| = 0.5, phi1 by
expm1 above |z| = 1e-8), agreeing with the numpy sums to rounding (tests/test_kernel_compiled.py).  The
recordings of one evaluation run in one call, each restarted from its own start (`modal_scan`'s ``starts``,
`fitter.core.flow.integrate_runs`), with each recording's own numbers.

Why numba: the recurrence is a loop the numpy form cannot express without those passes; numba compiles it
from this Python source at first use (cached on disk), with wheels on every platform the package supports
and no compiler on the user's machine.  The FMUs ship `fitter.core` without this module
(`fitter.fmu.build`): inside an FMU the kernel runs the numpy sums.
"""

from __future__ import annotations

import cmath
import math

import numpy as np
from numba import njit

__all__ = ["modal_scan"]

_PHI2_SERIES = np.array([1.0 / math.factorial(k) for k in range(2, 20)])


@njit(cache=True)
def _flow_factors(z: complex, series: np.ndarray) -> tuple[complex, complex, complex]:
    """(e^z, phi1(z), phi2(z)): below |z| = 0.5 phi2 by the Taylor series of `fitter.core.flow.phi2`, then
    phi1 = 1 + z phi2 and e^z = 1 + z phi1; above, e^z, phi1 = (e^z - 1)/z and phi2 = (phi1 - 1)/z (no
    cancellation there)."""
    if abs(z) < 0.5:
        p2 = complex(series[-1])
        for k in range(len(series) - 2, -1, -1):
            p2 = p2 * z + series[k]
        p1 = 1.0 + z * p2
        return 1.0 + z * p1, p1, p2
    e = cmath.exp(z)
    p1 = (e - 1.0) / z
    return e, p1, (p1 - 1.0) / z


@njit(cache=True)
def _product(M, w, out):
    """out = M w, M (n, n), w (n, m), all complex: the sums over k in ascending order."""
    n, m = w.shape
    for i in range(n):
        for j in range(m):
            acc = 0j
            for k in range(n):
                acc += M[i, k] * w[k, j]
            out[i, j] = acc


@njit(cache=True)
def _scan(lam, V, Vinv, beta, eps, index, p, r, S, X0, series, starts, rows):
    """The states (N, n, m) after each interval; with `rows` (per branch the output row C V, complex (n,); empty
    for none) the outputs C x (N, 1, m) instead: Re(sum_k (C V)_k w_k), ascending k, the rounding of the first
    state's row of Re(V w) when C = e1."""
    N, n, m = len(S), X0.shape[0], X0.shape[1]
    out_rows = len(rows) > 0
    X = np.empty((N, 1 if out_rows else n, m))
    w = np.zeros((n, m), dtype=np.complex128)
    x0 = X0.astype(np.complex128)
    b = index[0]
    x = np.empty((n, m), dtype=np.complex128)
    run = 0
    for t in range(N):
        if run < len(starts) and t == starts[run]:  # a run's first interval: w = V^-1 x0 on its branch
            b = index[t]
            _product(Vinv[b], x0, w)
            run += 1
        elif index[t] != b:  # a change of branch: x = Re(V w), w' = V'^-1 x
            _product(V[b], w, x)
            b = index[t]
            _product(Vinv[b], x.real.astype(np.complex128), w)
        s = S[t]
        for i in range(n):
            z = lam[b, i] * s
            e, p1, p2 = _flow_factors(z, series)
            c1 = s * p1
            a = c1 * p[t] + s * s * p2 * r[t]
            for j in range(m):
                w[i, j] = e * w[i, j] + a * beta[b, i, j] + c1 * eps[b, i, j]
        if out_rows:
            for j in range(m):
                acc = 0j
                for k in range(n):
                    acc += rows[b, k] * w[k, j]
                X[t, 0, j] = acc.real
        else:
            _product(V[b], w, x)
            X[t] = x.real
    return X


def modal_scan(used: dict, force: dict, X0: np.ndarray, branch, p, r, S, starts=None, C=None) -> np.ndarray:
    """States after each interval (N, n) or (N, n, m), every flow in `used` modal:
    `fitter.core.scans.integrate_modal` by (M) interval after interval (module docstring).  `force`: per
    branch None (the flow's own B, E) or m forcing columns (B, E), each (n, m).  `starts`: the first interval
    of each of several runs laid end to end (ascending, from 0; default one run): each run starts from X0, in
    the modal coordinates of its first interval's branch, as a scan of that run alone would
    (`fitter.core.flow.integrate_runs`).  `C` (n,): the outputs C x (N,) or (N, m) instead of the states, from
    the modal states through the rows C V of each branch (n products an interval instead of n^2; for C = e1
    the same numbers as the states' first entry)."""
    keys = list(used)
    flows = [used[b] for b in keys]
    cols = X0.reshape(X0.shape[0], -1).astype(float)
    m = cols.shape[1]
    beta, eps = [], []
    for b, fl in zip(keys, flows):
        if force[b] is None:
            beta.append(np.repeat(fl.beta.astype(complex)[:, None], m, axis=1))
            eps.append(np.repeat(fl.eps.astype(complex)[:, None], m, axis=1))
        else:
            beta.append((fl.Vinv @ force[b][0]).astype(complex))
            eps.append((fl.Vinv @ force[b][1]).astype(complex))
    index = np.searchsorted(np.array(keys), branch).astype(np.int64) if len(keys) > 1 else np.zeros(len(S), np.int64)
    X = _scan(
        np.stack([fl.lam.astype(complex) for fl in flows]),
        np.stack([fl.V.astype(complex) for fl in flows]),
        np.stack([fl.Vinv.astype(complex) for fl in flows]),
        np.stack(beta),
        np.stack(eps),
        index,
        np.ascontiguousarray(p, dtype=float),
        np.ascontiguousarray(np.broadcast_to(r, S.shape), dtype=float),
        np.ascontiguousarray(S, dtype=float),
        cols,
        _PHI2_SERIES,
        np.zeros(1, np.int64) if starts is None else np.asarray(starts, dtype=np.int64),
        np.zeros((0, 0), complex) if C is None else np.stack([np.asarray(C, float) @ fl.V for fl in flows]),
    )
    return X.reshape((len(S),) + (X0.shape if C is None else X0.shape[1:]))
