"""Exact derivatives of the closed-form periodic triangle output (`TriangleSamples`).

The improved estimator of `fitter.identification.rd_triangles` refines A, B and the rates g by output error;
this module gives its Jacobian in one pass instead of by forward differences.

Setting (`TriangleSamples`' docstring).  In modal coordinates w = V^-1 x (A = V diag(lambda) V^-1, b = V^-1 B,
E = 0), on a half with rate g, corner input p and input slope v, at the time tau since the corner,

    w(tau) = e^{x} w_st + b F,   x = lambda g tau,   F = p g tau phi1(x) + v g tau^2 phi2(x)

(eq (18) with u = p + v tau; `fitter.core.flow`'s phi functions), w_st the half's start.  The periodic starts
follow from w_lo = e^{x_b} w_hi + b F_b, w_hi = e^{x_a} w_lo + b F_a (x_a, x_b, F_a, F_b at the halves' ends).
Every mode is decoupled, so W = U b with U the response to unit modal forcing.

Derivatives, with phi1'(x) = (1 + (x - 1) e^x)/x^2 and phi2'(x) = (2 + x + (x - 2) e^x)/x^3:

* a half's rate g:  d/dg [e^x w_st + b F](tau) = tau e^x (lambda w_st + b p) + b v tau^2 phi1'(x);
* a mode's eigenvalue (unit forcing):  d/dlambda [e^x U_st + F](tau) = g tau (e^x U_st + p g tau phi1'(x)
  + v g tau^2 phi2'(x));
* the starts: with q_h the derivative of half h's end at a fixed start and h' its partner,
  d w_st(h) = (q_h' + e^{x_h'} q_h) / (1 - e^{x_a + x_b}) (differentiate the fixed point);
* A in a direction dA: M = V^-1 dA V gives d lambda_k = M_kk and dV = V (F o M), F_kl = 1/(lambda_l - lambda_k)
  off the diagonal (distinct eigenvalues, which the closed form's well-conditioned V implies), so
  db = -V^-1 dV b and the output row c = V^T C moves by dV^T C;
* B:  W is linear in b = V^-1 B, so dy/dB_j = Re(U (c o V^-1[:, j])).

The output is y = Re(W c) + D u; none of the derivatives depends on D.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fitter.core import AffineFlow

__all__ = ["OutputDerivatives", "output_derivatives", "dphi1", "dphi2"]

_SMALL = 0.5
_SERIES = {k: [m / np.prod(np.arange(1.0, m + k + 1)) for m in range(1, 19)] for k in (1, 2)}
"""The coefficients m / (m + k)! of phi_k' = sum_{m >= 1} m z^(m-1) / (m + k)!, to the term below 1e-17 at |z| = 0.5."""


def _series_derivative(z: np.ndarray, k: int) -> np.ndarray:
    """phi_k'(z) by its Taylor series (Horner)."""
    coef = _SERIES[k]
    acc = np.full_like(z, coef[-1])
    for c in coef[-2::-1]:
        acc = acc * z + c
    return acc


def _derivative(z, k: int, closed) -> np.ndarray:
    z = np.asarray(z, dtype=complex if np.iscomplexobj(z) else float)
    out = np.empty_like(z)
    small = np.abs(z) < _SMALL
    out[small] = _series_derivative(z[small], k)
    out[~small] = closed(z[~small])
    return out


def dphi1(z) -> np.ndarray:
    """phi1'(z) = (1 + (z - 1) e^z)/z^2, 1/2 at 0 (Taylor series for |z| < 0.5; no overflow as Re z -> -inf)."""
    return _derivative(z, 1, lambda x: (1.0 + (x - 1.0) * np.exp(x)) / (x * x))


def dphi2(z) -> np.ndarray:
    """phi2'(z) = (2 + z + (z - 2) e^z)/z^3, 1/6 at 0 (Taylor series for |z| < 0.5)."""
    return _derivative(z, 2, lambda x: (2.0 + x + (x - 2.0) * np.exp(x)) / (x * x * x))


@dataclass
class OutputDerivatives:
    """The periodic output and its derivatives at every sample (N samples, P waves).

    y : (N,) the output without D u;  rho : (P,) each wave's |e^{x_a + x_b}| maximum (condition (5));
    d_A : (N, len(directions)) along each direction of A;  d_B : (N, n) in each entry of B;
    d_own, d_other : (N,) in the rate of the sample's own half, and of the other half of its wave.
    """

    y: np.ndarray
    rho: np.ndarray
    d_A: np.ndarray
    d_B: np.ndarray
    d_own: np.ndarray
    d_other: np.ndarray


def _start_derivative(q: np.ndarray, E: np.ndarray, den: np.ndarray, partner: np.ndarray) -> np.ndarray:
    """d w_st per half from the end derivatives q at fixed starts (module docstring)."""
    return (q[partner] + E[partner] * q) / den


def _forcing_derivatives(x: np.ndarray, tau: np.ndarray, g: np.ndarray, p: np.ndarray, v: np.ndarray):
    """At x = lambda g tau (p, v, g per entry): dF/dlambda = g tau (p g tau phi1'(x) + v g tau^2 phi2'(x)) of the
    unit forcing F, and the ramp's part v tau^2 phi1'(x) of d/dg (module docstring)."""
    S = g * tau
    dphi1_x = dphi1(x)
    dF_dlam = S[:, None] * ((p * S)[:, None] * dphi1_x + (v * g * tau**2)[:, None] * dphi2(x))
    ramp = (v * tau**2)[:, None] * dphi1_x
    return dF_dlam, ramp


def output_derivatives(
    samples, fl: AffineFlow, C: np.ndarray, g: np.ndarray, directions: Sequence[np.ndarray] = ()
) -> OutputDerivatives:
    """Derivatives of the closed-form periodic output of (fl.A, fl.B, C) under `samples`' waves.

    `g` are the rates of the rising halves, then of the falling ones (as `TriangleSamples._states`), all
    positive; `fl` must be modal with E = 0; `directions` are the matrices dA along which d_A differentiates.
    The periodic states are `TriangleSamples.periodic_modal`'s under unit modal forcing.
    """
    if not fl.modal or np.any(fl.eps != 0):
        raise ValueError("output_derivatives needs a diagonalisable A and E = 0")
    P, n = len(samples.waves), len(fl.lam)
    lam, b, cv = fl.lam, fl.beta, fl.V.T @ np.asarray(C, dtype=float)
    p, v, span = samples.corners.T
    partner = (np.arange(2 * P) + P) % (2 * P)
    h, tau = samples.half, samples.since
    unit = samples.periodic_modal(fl, g, np.ones(n), np.zeros(n))
    U_st, U = unit.starts, unit.W
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        E, Es = np.exp(unit.z), np.exp(unit.zs)
        den = np.tile(1.0 - unit.decay, (2, 1))
        dF_end, ramp_end = _forcing_derivatives(unit.z, span, g, p, v)
        dF_at, ramp_at = _forcing_derivatives(unit.zs, tau, g[h], p[h], v[h])
        W, W_st = U * b, U_st * b
        # the rates
        q = span[:, None] * E * (lam * W_st + b * p[:, None]) + b * ramp_end
        own_st, other_st = E[partner] * q / den, q[partner] / den
        in_half = tau[:, None] * Es * (lam * W_st[h] + b * p[h][:, None]) + b * ramp_at
        # the eigenvalues (unit forcing), then A's directions
        q_lam = (g * span)[:, None] * E * U_st + dF_end
        dU = Es * _start_derivative(q_lam, E, den, partner)[h] + (g[h] * tau)[:, None] * Es * U_st[h] + dF_at
        d_A = [_along(dA, fl, b, cv, C, U, dU, W) for dA in directions]
    return OutputDerivatives(
        y=(W @ cv).real,
        rho=np.max(np.abs(unit.decay), axis=1),
        d_A=np.column_stack(d_A) if d_A else np.zeros((len(h), 0)),
        d_B=(U @ (cv[:, None] * fl.Vinv)).real,
        d_own=((in_half + Es * own_st[h]) @ cv).real,
        d_other=((Es * other_st[h]) @ cv).real,
    )


def _along(dA, fl: AffineFlow, b, cv, C, U, dU, W) -> np.ndarray:
    """dy along dA: eigenvalue, eigenvector and modal-forcing changes (module docstring)."""
    lam = fl.lam
    M = fl.Vinv @ dA @ fl.V
    gap = lam[None, :] - lam[:, None]
    off = ~np.eye(len(lam), dtype=bool)
    Fm = np.zeros_like(M, dtype=complex)
    Fm[off] = 1.0 / gap[off]
    dV = fl.V @ (Fm * M)
    db = -fl.Vinv @ dV @ b
    dcv = dV.T @ np.asarray(C, dtype=float)
    return ((dU * (np.diag(M) * b) + U * db) @ cv + W @ dcv).real
