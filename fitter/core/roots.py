"""A root of a scalar function in a bracket: Brent's method (Brent 1973, as scipy's ``brentq``), numpy-only so
that it ships inside FMUs with `fitter.core` (used by the compensator, `fitter.core.inverse`)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["brent"]

_EPS = np.finfo(float).eps


def brent(
    f,
    a: float,
    b: float,
    fa: float,
    fb: float,
    xtol: float,
    ftol: float = math.inf,
    xfloor: float = 0.0,
    maxiter: int = 200,
):
    """A root of f in [a, b] with fa, fb of opposite signs (Brent 1973, as scipy's brentq); returns (x, f(x)).

    It stops when the bracket is below xtol, as scipy's brentq, if then |f(x)| <= ftol; else it goes on with
    the bracket tolerance xfloor (a steep branch: the residual is brought under ftol where the input's
    resolution allows)."""
    xpre, xcur, fpre, fcur = a, b, fa, fb
    xblk, fblk, spre, scur = 0.0, 0.0, 0.0, 0.0
    rtol = 4 * _EPS
    for _ in range(maxiter):
        if fpre != 0 and fcur != 0 and (fpre < 0) != (fcur < 0):
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if abs(fblk) < abs(fcur):
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        delta = (xtol + rtol * abs(xcur)) / 2
        sbis = (xblk - xcur) / 2
        if fcur == 0 or abs(sbis) < delta:
            if fcur == 0 or abs(fcur) <= ftol or xtol <= xfloor:
                return xcur, fcur
            xtol = xfloor  # polish: from here on the finer bracket tolerance
            delta = (xtol + rtol * abs(xcur)) / 2
            if abs(sbis) < delta:
                return xcur, fcur
        if abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:
                stry = -fcur * (xcur - xpre) / (fcur - fpre)
            else:
                dpre = (fpre - fcur) / (xpre - xcur)
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
            if 2 * abs(stry) < min(abs(spre), 3 * abs(sbis) - delta):
                spre, scur = scur, stry
            else:
                spre = scur = sbis
        else:
            spre = scur = sbis
        xpre, fpre = xcur, fcur
        xcur = xcur + (scur if abs(scur) > delta else (delta if sbis > 0 else -delta))
        fcur = f(xcur)
    return xcur, fcur
