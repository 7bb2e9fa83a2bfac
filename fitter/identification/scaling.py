"""Affine normalisation of recordings and its exact inverse on models.

u_n = (u - u_c)/u_s, y_n = (y - y_c)/y_s (mid-range, half-range over all
recordings).  Fitting happens in these units; `Normalisation.to_physical` maps a
model back exactly: for the rate-independent model (1)-(2)
A+- -> A+-/u_s, B+- -> B+-/u_s^2, E+- -> (E+- - B+- u_c/u_s)/u_s; for the
rate-dependent model (18)-(19) A stays, B -> B/u_s, E -> E - B u_c/u_s and
g(v) = g_n(v/u_s); both C -> y_s C, D -> y_s D/u_s, and the output offset
k = y_c - y_s D u_c/u_s is absorbed in the state (x -> x + x_c with C x_c = k,
E -> E - A x_c), so no output constant is needed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fitter.core.errors import DuhemError
from fitter.core.models import RateIndependentModel
from fitter.core.rates import TabulatedRate
from fitter.data.recordings import Recording

__all__ = ["Normalisation"]


@dataclass(frozen=True)
class Normalisation:
    """u_n = (u - u_c)/u_s, y_n = (y - y_c)/y_s; see the module docstring."""

    u_c: float
    u_s: float
    y_c: float
    y_s: float

    @classmethod
    def of(cls, recs: Sequence[Recording]) -> "Normalisation":
        u = np.concatenate([r.u for r in recs])
        y = np.concatenate([r.y for r in recs])
        us, ys = 0.5 * np.ptp(u), 0.5 * np.ptp(y)
        if not (us > 0 and ys > 0):
            column = recs[0].input.name if not us > 0 else recs[0].output.name
            raise DuhemError(
                f"{', '.join(r.label for r in recs)}: the {'input' if not us > 0 else 'output'} "
                f"(column {column!r}) is constant over all recordings: nothing to fit"
            )
        return cls(0.5 * (u.max() + u.min()), us, 0.5 * (y.max() + y.min()), ys)

    def normalise(self, rec: Recording) -> Recording:
        return Recording(
            rec.t,
            (rec.u - self.u_c) / self.u_s,
            (rec.y - self.y_c) / self.y_s,
            rec.name,
            rec.input,
            rec.output,
            rec.source,
        )

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
        if isinstance(m, RateIndependentModel):
            Ap, Am = m.A_plus / s, m.A_minus / s
            Ep = (m.E_plus - m.B_plus * c / s) / s
            Em = (m.E_minus - m.B_minus * c / s) / s
            C, D, (Ep, Em), x0 = self._output(m.C, m.D, [Ap, Am], [Ep, Em], m.x0)
            return m.replace(
                A_plus=Ap,
                A_minus=Am,
                B_plus=m.B_plus / s**2,
                B_minus=m.B_minus / s**2,
                C=C,
                E_plus=Ep,
                E_minus=Em,
                D=D,
                x0=x0,
            )
        E = m.E - m.B * c / s
        C, D, (E,), x0 = self._output(m.C, m.D, [m.A], [E], m.x0)
        return m.replace(B=m.B / s, C=C, E=E, D=D, x0=x0, g=TabulatedRate(m.g.v * s, m.g.g))
