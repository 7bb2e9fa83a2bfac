"""First-order linear recurrences w_{k+1} = a_k w_k + f_k, elementwise, solved without a Python loop per step.

The kernel's modal flows (`fitter.core.flow`) and the effects' states (`fitter.core.effects.catalogue`) are
such recurrences: a_k = e^{z_k} is a step's exact decay (or rotation) and f_k its exact forced part, so the
solution is exact up to rounding whatever the steps' sizes.
"""

from __future__ import annotations

import numpy as np

__all__ = ["linear_recurrence", "CHUNK_SPAN"]

CHUNK_SPAN = 300.0
"""Largest |Re sum z| within one chunk of `linear_recurrence`'s cumulative-sum form (e^300 is far from overflow)."""


def linear_recurrence(w0: np.ndarray, z: np.ndarray, a: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Solve w_{k+1} = a_k w_k + f_k (a_k = e^{z_k}) for all k, vectorised.

    Within a chunk, w_{k+1} = P_{k+1} (w_c + sum_{j<=k} f_j / P_{j+1}) with
    P = exp(cumsum z) relative to the chunk's first state w_c; chunks are cut
    so that |Re cumsum z| stays below 300 and no exponential overflows.  The
    first step of every chunk is taken directly, so a single huge step is safe.
    Where that needs many chunks (strongly decaying steps, such as a switching
    effect's fully switched intervals) and no step grows (Re z <= 0), the
    recurrence is solved by `_decaying_scan` instead, in log2 N passes.
    Real or complex: the result has f's type (real for the effects' real states).
    """
    N = len(z)
    span = np.cumsum(np.abs(z.real).max(axis=1))
    if span[-1] < CHUNK_SPAN:
        starts, ends = (0,), (N,)
    else:
        chunk_id = np.floor(span / CHUNK_SPAN).astype(np.int64)
        starts = np.concatenate(([0], np.flatnonzero(np.diff(chunk_id)) + 1))
        ends = np.concatenate((starts[1:], [N]))
        if len(starts) > np.log2(N) / 2 and np.all(z.real <= 0.0):
            return _decaying_scan(w0, a, f)
    W = np.empty_like(f)
    w = w0.astype(f.dtype)
    for s0, s1 in zip(starts, ends):
        w = a[s0] * w + f[s0]
        W[s0] = w
        if s1 - s0 > 1:
            L = np.cumsum(z[s0 + 1 : s1], axis=0)
            P = np.exp(L)
            W[s0 + 1 : s1] = P * (w + np.cumsum(f[s0 + 1 : s1] * np.exp(-L), axis=0))
            w = W[s1 - 1]
    return W


def _decaying_scan(w0: np.ndarray, a: np.ndarray, f: np.ndarray) -> np.ndarray:
    """w_1..w_N of w_{k+1} = a_k w_k + f_k by a Hillis-Steele scan of the maps (a, f): after the pass of
    distance d, entry k holds the composition of the maps k-2d+1..k (products of the a's, |a| <= 1, never
    overflow); w_0 is folded into the first map's constant."""
    F = f.astype(np.result_type(f, a, w0), copy=True)
    A = np.broadcast_to(a, F.shape).astype(F.dtype, copy=True)
    F[0] = F[0] + A[0] * w0
    d = 1
    while d < len(F):
        F[d:] = F[d:] + A[d:] * F[:-d]
        A[d:] = A[d:] * A[:-d]
        d *= 2
    return F
