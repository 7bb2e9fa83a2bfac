"""How `fitter.core.flow.integrate` runs over a recording's intervals: three passes of one exact flow.

* `integrate_modal`: every flow modal, numpy.  The intervals are cut into segments (a branch change, or the
  span limit of `fitter.core.recurrence.linear_recurrence`); each segment's scalar recurrences
  w_{k+1} = e^{z_k} w_k + f_k are summed in closed form (cumulative sums of the exponents) and only the
  segments' end states are chained, by `affine_scan`.
* `fitter.core.compiled.modal_scan`: the same recurrences interval after interval, compiled (numba); used
  inside `compiled_scans()` (the optimiser's evaluations, `fitter.identification.refine`), where it can be
  imported.  It is not shipped in the FMUs.
* `integrate_dense`: a flow not modal (ill-conditioned eigenvectors): every interval's affine map from the
  block matrix exponential (`AffineFlow.affine_maps`), composed by `affine_scan`.

Needs only numpy (shipped inside the FMUs).
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Callable, Iterator

import numpy as np

from .recurrence import CHUNK_SPAN

__all__ = ["modal_pass", "compiled_scans", "integrate_modal", "integrate_dense", "affine_scan"]

_COMPILED: ContextVar[bool] = ContextVar("compiled_scans", default=False)
_LOADED: dict[str, Callable | None] = {}


@contextmanager
def compiled_scans() -> Iterator[bool]:
    """Within: the modal pass is `fitter.core.compiled.modal_scan` (numba) where it can be imported (not in an
    FMU, nor without numba); yields whether it can.  Its import and cached compilation take about a second
    once per process, which a few hundred evaluations repay; outside, the numpy sums (no import)."""
    token = _COMPILED.set(True)
    try:
        yield _compiled() is not None
    finally:
        _COMPILED.reset(token)


def _compiled() -> Callable | None:
    """`fitter.core.compiled.modal_scan`, imported once; None where it cannot be."""
    if "scan" not in _LOADED:
        try:
            from .compiled import modal_scan
        except ImportError:
            modal_scan = None
        _LOADED["scan"] = modal_scan
    return _LOADED["scan"]


def modal_pass() -> Callable:
    """The modal pass in effect: `fitter.core.compiled.modal_scan` inside `compiled_scans()` (where it can be
    imported), else `integrate_modal`."""
    return (_compiled() if _COMPILED.get() else None) or integrate_modal


def _columns(a: np.ndarray, extra: int) -> np.ndarray:
    """`a` with `extra` trailing axes of length 1 (broadcast over initial states)."""
    return a.reshape(a.shape + (1,) * extra)


def _segmented_cumsum(x: np.ndarray, head: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Cumulative sum along axis 0 restarting at every True of `head` (`first`: its indices).

    One `np.cumsum` per segment (a Python loop, about 3 us a segment), or a
    Hillis-Steele scan over the whole array (log2 of the longest segment
    passes, about 3 ns an entry each), whichever is estimated cheaper.
    """
    ends = np.append(first[1:], len(x))
    passes = max(1, math.ceil(math.log2(max(int((ends - first).max()), 2))))
    if len(first) * 1000 <= passes * x.size:
        out = np.empty_like(x)
        for a, b in zip(first.tolist(), ends.tolist()):
            np.cumsum(x[a:b], axis=0, out=out[a:b])
        return out
    v, h = x.copy(), head.copy()
    d = 1
    while d < len(x) and not h[d:].all():
        add = np.where(_columns(h[d:], v.ndim - 1), 0, v[:-d])
        h[d:] = h[d:] | h[:-d]
        v[d:] = v[d:] + add
        d *= 2
    return v


def _stacked_matvec(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """M_s x_s, M (..., n, n), x (..., n) or (..., n, m), by matmul (einsum: 3-5 times as long here)."""
    return np.matmul(M, x[..., None])[..., 0] if x.ndim == M.ndim - 1 else np.matmul(M, x)


def integrate_modal(used: dict, force: dict, X0: np.ndarray, branch, p, r, S) -> np.ndarray:
    """States after each interval, all flows modal (`fitter.core.flow.integrate`; module docstring)."""
    N, n, extra = len(S), X0.shape[0], X0.ndim - 1
    dtype = complex if any(np.iscomplexobj(flow.lam) for flow in used.values()) else float
    z = np.empty((N, n), dtype=dtype)
    f = np.empty((N, n) + X0.shape[1:], dtype=dtype)
    for b, flow in used.items():
        sel = branch == b
        z[sel], fb = flow.modal_terms(p[sel], r[sel], S[sel], force[b])
        f[sel] = fb if fb.ndim == f.ndim else _columns(fb, extra)
    chunk = np.floor(np.cumsum(np.abs(z.real).max(axis=1)) / CHUNK_SPAN)
    head = np.empty(N, bool)
    head[0] = True
    np.not_equal(branch[1:], branch[:-1], out=head[1:])
    head[1:] |= chunk[1:] != chunk[:-1]
    first = np.flatnonzero(head)
    last = np.append(first[1:] - 1, N - 1)
    L = _segmented_cumsum(np.where(head[:, None], 0, z), head, first)
    decayed = f * _columns(np.exp(-L), extra)
    decayed[first] = 0
    F = _segmented_cumsum(decayed, head, first)
    # segment s maps its entry state x_s to its exit state: in modal coordinates w = V^-1 x_s,
    # W0 = e^{z_first} w + f_first (its first interval), w_out = P_last (W0 + F_last); as a map on x,
    # x_{s+1} = V diag(P_last e^{z_first}) V^-1 x_s + V P_last (f_first + F_last): chained by `affine_scan`
    ez0, f0 = np.exp(z[first]), f[first]
    PL, FL = np.exp(L[last]), F[last]
    keys = list(used)
    index = np.searchsorted(np.array(keys), branch[first]) if len(keys) > 1 else np.zeros(len(first), int)
    V = np.stack([used[b].V for b in keys])[index]
    Vinv = np.stack([used[b].Vinv for b in keys])[index]
    M = ((V * (PL * ez0)[:, None, :]) @ Vinv).real
    c = _stacked_matvec(V, _columns(PL, extra) * (f0 + FL)).real
    entry = np.concatenate([X0[None], affine_scan(M, c, X0)[:-1]])
    W0 = _columns(ez0, extra) * _stacked_matvec(Vinv, entry) + f0
    seg = np.cumsum(head) - 1
    # not in place: a complex product written over an operand rounded differently (friction fits, 1e-15)
    W = _columns(np.exp(L), extra) * (W0[seg] + F)
    X = np.empty((N, n) + X0.shape[1:])
    for b, flow in used.items():
        sel = branch == b
        X[sel] = (np.matmul(flow.V, W[sel]) if extra else W[sel] @ flow.V.T).real
    return X


def integrate_dense(used: dict, force: dict, X0: np.ndarray, branch, p, r, S) -> np.ndarray:
    """States after each interval from the intervals' affine maps x_{k+1} = M_k x_k + g_k
    (`AffineFlow.affine_maps`), chained by `affine_scan`."""
    N, n, extra = len(S), X0.shape[0], X0.ndim - 1
    M = np.empty((N, n, n))
    g = np.empty((N, n) + X0.shape[1:])
    for b, flow in used.items():
        sel = np.flatnonzero(branch == b)
        M[sel], gb = flow.affine_maps(p[sel], r[sel], S[sel], force[b])
        g[sel] = gb if gb.ndim == g.ndim else _columns(gb, extra)
    return affine_scan(M, g, X0)


def affine_scan(M: np.ndarray, g: np.ndarray, X0: np.ndarray, block: int = 32) -> np.ndarray:
    """States x_1..x_K of x_{k+1} = M_k x_k + g_k from x_0 = X0 ((n,) or (n, m)): prefix compositions
    within blocks of `block` maps (log2(block) stacked products), the blocks chained in order.  Fewer than
    `block` maps make one block of the next power of two: the prefix of map k takes the passes of stride <= k
    only, so it is the same product in any block longer than k."""
    K, n = len(M), X0.shape[0]
    block = min(block, 1 << max(K - 1, 0).bit_length())
    nb = -(-K // block)
    Mp = np.broadcast_to(np.eye(n), (nb * block, n, n)).copy()
    gp = np.zeros((nb * block, n) + X0.shape[1:])
    Mp[:K], gp[:K] = M, g
    P, c = Mp.reshape(nb, block, n, n), gp.reshape((nb, block, n) + X0.shape[1:])
    d = 1
    while d < block:
        P_new, c_new = P.copy(), c.copy()
        P_new[:, d:] = P[:, d:] @ P[:, :-d]
        c_new[:, d:] = _stacked_matvec(P[:, d:], c[:, :-d]) + c[:, d:]
        P, c, d = P_new, c_new, 2 * d
    out = np.empty((nb, block, n) + X0.shape[1:])
    x = X0
    for i in range(nb):
        out[i] = P[i] @ x + c[i]
        x = out[i, -1]
    return out.reshape((nb * block, n) + X0.shape[1:])[:K]
