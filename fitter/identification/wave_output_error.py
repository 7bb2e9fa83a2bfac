"""The improved triangle estimator's output-error problem (`fitter.identification.rd_triangles`, step 3).

theta = [alpha (n), beta (n), g_plus of waves 2..p, g_minus of waves 1..p] of the observable canonical form (49)
(`canonical`); the residuals are every sample of every record against the model's limiting periodic output in
closed form (`TriangleSamples`), and their Jacobian is exact (`triangle_sensitivities.output_derivatives`) where
the closed form applies.  In a refinement (`WaveRecords.joint`) one pass of `output_derivatives` gives both: the
solver asks for the Jacobian at each trial point it accepts, and one pass costs two thirds of the residuals and the
Jacobian apart (0.46 ms and 0.9 ms on Example 2's 772 samples).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fitter.core import ConvergenceError, RateDependentModel
from fitter.identification.output_error import FAIL
from fitter.identification.parametrisation import Parametrisation
from fitter.identification.refine import Options
from fitter.identification.triangle_records import Record
from fitter.identification.triangle_sensitivities import OutputDerivatives, output_derivatives
from fitter.identification.triangle_waves import TriangleSamples, closed_form_flow, two_level_rate

__all__ = ["canonical", "alpha_directions", "WaveParameters", "WaveRecords", "OPTIONS"]


def canonical(alpha: np.ndarray, beta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Observable canonical form (49) with the sign fixed: first column -alpha."""
    n = len(alpha)
    A = np.zeros((n, n))
    A[:, 0] = -np.asarray(alpha)
    A[: n - 1, 1:] = np.eye(n - 1)
    C = np.zeros(n)
    C[0] = 1.0
    return A, np.asarray(beta, dtype=float).copy(), C


def _model(A, B, C, g) -> RateDependentModel:
    return RateDependentModel(A=A, B=B, C=C, g=g)


def alpha_directions(n: int) -> list[np.ndarray]:
    """d A / d alpha_j of the canonical form (49) (`canonical`: A's first column is -alpha)."""
    out = []
    for j in range(n):
        dA = np.zeros((n, n))
        dA[j, 0] = -1.0
        out.append(dA)
    return out


class WaveParameters(Parametrisation):
    """Parameters of the improved estimator, step 3: theta = [alpha (n), beta (n), g_plus of
    waves 2..p, g_minus of waves 1..p]; `common` gives the common (A, B, C) of the canonical form (49)
    and each wave's two rates (the wave's model is (A, B, C) with `two_level_rate` of them)."""

    def __init__(self, order: int, waves: int):
        self.n, self.p = order, waves
        self.size = 2 * order + 2 * waves - 1

    def unpack(self, theta: np.ndarray):
        n, p = self.n, self.p
        alpha, beta = theta[:n], theta[n : 2 * n]
        gp = np.concatenate(([1.0], theta[2 * n : 2 * n + p - 1]))
        gm = theta[2 * n + p - 1 :]
        return alpha, beta, gp, gm

    def pack(self, alpha, beta, gp, gm) -> np.ndarray:
        return np.concatenate((alpha, beta, gp[1:], gm))

    def common(self, theta: np.ndarray) -> tuple[RateDependentModel, list[tuple[float, float]]]:
        """The common (A, B, C) as a model (its g the first wave's) and each wave's (g_plus, g_minus)."""
        alpha, beta, gp, gm = self.unpack(theta)
        A, B, C = canonical(alpha, beta)
        return _model(A, B, C, two_level_rate(gp[0], gm[0])), list(zip(gp, gm))

    def groups(self) -> list[np.ndarray]:
        """Columns of theta that forward differences can move together (`WaveRecords.jacobian`): each of
        alpha and beta alone, then all g_plus, then all g_minus (wave i depends on its own rates only)."""
        n, p = self.n, self.p
        return [np.array([j]) for j in range(2 * n)] + [2 * n + np.arange(p - 1), 2 * n + p - 1 + np.arange(p)]

    def wave_of(self, column: int) -> int | None:
        """The wave whose rate is theta[column], None for alpha and beta."""
        n, p = self.n, self.p
        if column < 2 * n:
            return None
        return column - 2 * n + 1 if column < 2 * n + p - 1 else column - (2 * n + p - 1)


@dataclass
class WaveRecords:
    """The output-error problem of the improved estimator: every sample of every record
    against the model's limiting periodic output (`TriangleSamples`, laid out once)."""

    recs: list[Record]
    joint: bool = False
    """Evaluate the Jacobian with every residual evaluation where the closed form applies and keep it for
    `jacobian` at the same theta (a refinement: module docstring); False: the residuals alone."""
    samples: TriangleSamples = field(init=False)
    _last: tuple = field(init=False, default=(None, None))
    _flow: tuple = field(init=False, default=(None, None, None))
    _jac: tuple = field(init=False, default=(None, None))

    def __post_init__(self):
        self.samples = TriangleSamples([r.wave for r in self.recs], [r.t for r in self.recs])

    @property
    def scale(self) -> float:
        return max(float(np.ptp(np.concatenate([r.y for r in self.recs]))), 1e-300)

    def decimated(self, max_samples) -> "WaveRecords":
        return self

    def _common(self, param: WaveParameters, theta: np.ndarray):
        """`WaveParameters.common` and the closed form's flow (None where it does not apply), the model and
        flow kept from the last call with the same alpha, beta and first wave's rates (the optimiser evaluates
        the residuals, then the Jacobian, at each accepted theta)."""
        alpha, beta, gp, gm = param.unpack(theta)
        key = np.concatenate((alpha, beta, gp[:1], gm[:1])).tobytes()
        if self._flow[0] != key:
            model = param.common(theta)[0]
            self._flow = (key, model, closed_form_flow(model))
        return self._flow[1], list(zip(gp, gm)), self._flow[2]

    def residuals(self, param: WaveParameters, theta: np.ndarray):
        """y - yhat stacked over the records (the engine's failure value where a record's
        periodic response does not exist), the common model (`WaveParameters.common`) and the per-record
        residuals.  The last evaluation's, when it was at the same theta (the optimiser's last trial is its
        result, which `refine` and the estimator evaluate again)."""
        if np.array_equal(self._last[0], theta):
            return self._last[1]
        model, rates, fl = self._common(param, theta)
        d = self._derivatives(param, model, rates, fl) if self.joint else None
        if d is None:
            outputs = self.samples.outputs(model, rates, fl)
        else:
            self._jac = (theta.copy(), self._assembled(param, d))
            y, ends = d.y + model.D * self.samples.u, self.samples.ends
            outputs = [y[a:b] if r < 1 else None for a, b, r in zip(ends[:-1], ends[1:], d.rho)]
        parts = [
            rec.y - y if y is not None else np.full(len(rec.y), FAIL * max(float(np.ptp(rec.y)), 1e-300))
            for rec, y in zip(self.recs, outputs)
        ]
        stacked = np.concatenate(parts)
        self._last = (theta.copy(), (stacked, model, [(0, None, r, np.nan, None) for r in parts]))
        return self._last[1]

    def jacobian(self, param: WaveParameters, theta: np.ndarray) -> np.ndarray:
        """d(residuals)/d(theta): exact (`output_derivatives`, A along d A / d alpha_j = -e_j e_1^T) where the
        closed form applies, else `difference_jacobian`; rows of a wave without a periodic output are zero
        (its residuals are the constant failure value)."""
        if np.array_equal(self._jac[0], theta):
            return self._jac[1]
        model, rates, fl = self._common(param, theta)
        d = self._derivatives(param, model, rates, fl)
        return self.difference_jacobian(param, theta) if d is None else self._assembled(param, d)

    def _derivatives(self, param: WaveParameters, model, rates, fl) -> OutputDerivatives | None:
        """`output_derivatives` at the common model and rates (`_common`), None where the closed form does not
        apply (no modal flow, or a rate not finite and positive)."""
        g = np.asarray(rates, dtype=float)
        if fl is None or not (np.all(np.isfinite(g)) and np.all(g > 0)):
            return None
        return output_derivatives(self.samples, fl, model.C, g.T.ravel(), alpha_directions(param.n))

    def _assembled(self, param: WaveParameters, d: OutputDerivatives) -> np.ndarray:
        """The Jacobian of the residuals in theta from the output's derivatives (`jacobian`)."""
        n, p = param.n, param.p
        wave, up = self.samples.wave_of, self.samples.up
        rows = np.arange(len(wave))
        J = np.zeros((len(wave), param.size))
        J[:, :n], J[:, n : 2 * n] = -d.d_A, -d.d_B
        d_plus, d_minus = np.where(up, d.d_own, d.d_other), np.where(up, d.d_other, d.d_own)
        later = wave >= 1
        J[rows[later], 2 * n + wave[later] - 1] = -d_plus[later]
        J[rows, 2 * n + p - 1 + wave] = -d_minus
        J[d.rho[wave] >= 1] = 0.0
        return J

    def difference_jacobian(self, param: WaveParameters, theta: np.ndarray) -> np.ndarray:
        """Forward differences of `residuals` (steps 1e-6 (1 + |theta_j|), as `refine.jacobian`) in
        2 n + 2 evaluations (Curtis, Powell and Reid's column grouping, `WaveParameters.groups`): the rates
        of all waves move at once, and each wave's rows take the difference of its own rate.  The residuals
        at theta are those of the last evaluation when it was at theta (the optimiser evaluates there first)."""
        r0 = self.residuals(param, theta)[0]
        wave_of_row = self.samples.wave_of
        h = 1e-6 * (1.0 + np.abs(theta))
        J = np.zeros((len(r0), param.size))
        for group in param.groups():
            th = theta.copy()
            th[group] += h[group]
            d = self.residuals(param, th)[0] - r0
            if len(group) == 1:
                J[:, group[0]] = d / h[group[0]]
                continue
            column_of_wave = np.full(param.p, -1)
            column_of_wave[[param.wave_of(j) for j in group]] = group
            column = column_of_wave[wave_of_row]
            rows = np.flatnonzero(column >= 0)
            J[rows, column[rows]] = d[rows] / h[column[rows]]
        return J

    def best_beta(self, param: WaveParameters, alpha, gp, gm) -> np.ndarray:
        """Variable projection: the periodic response is linear in B for fixed A and g."""
        n = param.n
        A, _, C = canonical(alpha, np.zeros(n))
        rates = list(zip(gp, gm))
        cols = []
        for e in np.eye(n):
            outputs = self.samples.outputs(_model(A, e, C, two_level_rate(gp[0], gm[0])), rates)
            if any(y is None for y in outputs):
                raise ConvergenceError("the start's A has no limiting periodic response (condition (5) fails)")
            cols.append(np.concatenate(outputs))
        return np.linalg.lstsq(np.column_stack(cols), np.concatenate([r.y for r in self.recs]), rcond=None)[0]


OPTIONS = Options(ftol=1e-10, xtol=1e-10, gtol=1e-10, max_nfev=200, max_samples=None, method="lm")
