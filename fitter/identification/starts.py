"""Starting values for the output-error fits of `fit_recordings`.

Rate-independent (order n, canonical theta of `RICanonical`), best loop error
first: the order-(n-1) fit embedded (`embed`: extra fast, weakly observed
modes), a first-order branch regression dy/du = a y + b u + e on the averaged
loop, and the Section III identification (`identify_ri_loop`, odd orders,
q chosen by loop error among `Q_CANDIDATES` unless given).

Rate-dependent (`RDCanonical`): the order-(n-1) fit embedded, the Section V
triangle-wave identification (`identify_rd_triangles`, triangle inputs only;
its g, normalised to g(a_1) = 1, is converted explicitly to the fit's
normalisation g(v_ref) = v_ref), and the rising branch of the rate-independent
fit with g = |v|.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

from fitter.core.errors import DuhemError
from fitter.core.models import RateDependentModel, RateIndependentModel
from fitter.core.periodic import limiting_loop
from fitter.identification.parametrisation import RDCanonical, RICanonical
from fitter.identification.rd_triangles import identify_rd_triangles
from fitter.identification.ri_loop import identify_ri_loop

__all__ = ["ri_starts", "rd_starts", "generic_ri_starts", "embed", "Q_CANDIDATES", "GENERIC_RATES"]

Q_CANDIDATES = (1.0, 3.0, 7.0, 20.0)
GENERIC_RATES = (0.5, 2.0, 8.0)
"""Relaxation rates (per normalised input unit) of the generic first-order starts."""
_STARTS_KEPT = {"ri": 3, "rd": 2}


def _branch_regression(grid, y, rising: bool) -> tuple[float, float, float]:
    """First-order branch fit dy/du = a y + b u + e (least squares on the gradient), with
    a <= -0.05 on the rising and a >= 0.05 on the falling branch, so that condition (5),
    e^{beta (a+ - a-)} < 1, holds (the state relaxes along each branch)."""
    dy = np.gradient(y, grid)
    M = np.column_stack([y, grid, np.ones_like(grid)])
    lo = [0.05 if not rising else -np.inf, -np.inf, -np.inf]
    hi = [-0.05 if rising else np.inf, np.inf, np.inf]
    return tuple(lsq_linear(M, dy, bounds=(lo, hi)).x)


def _ri_first_order(grid, yr, yf) -> RateIndependentModel:
    ap, bp, ep = _branch_regression(grid, yr, True)
    am, bm, em = _branch_regression(grid, yf, False)
    return RateIndependentModel(
        A_plus=[[ap]], A_minus=[[am]], B_plus=[bp], B_minus=[bm], C=[1.0], E_plus=[ep], E_minus=[em]
    )


def _pad(M: np.ndarray, d: np.ndarray) -> np.ndarray:
    k, n = len(d), M.shape[0]
    return np.block([[M, np.zeros((n, k))], [np.zeros((k, n)), np.diag(d)]])


def embed(m, n: int):
    """Order-n model with nearly the same output: extra fast, weakly observed stable modes
    (relaxing on both branches), so that an order-(n-1) fit starts the order-n one."""
    k = n - m.order
    if k <= 0:
        return m
    extra = -np.arange(2.0, 2.0 + k) * 5.0

    def vec(v):
        return np.r_[v, np.zeros(k)]

    C = np.r_[m.C, 0.05 * np.ones(k)]
    if isinstance(m, RateDependentModel):
        return RateDependentModel(A=_pad(m.A, extra), B=vec(m.B), C=C, g=m.g, E=vec(m.E), D=m.D)
    return RateIndependentModel(
        A_plus=_pad(m.A_plus, extra),
        A_minus=_pad(m.A_minus, -extra),
        B_plus=vec(m.B_plus),
        B_minus=vec(m.B_minus),
        C=C,
        E_plus=vec(m.E_plus),
        E_minus=vec(m.E_minus),
        D=m.D,
    )


def _loop_error(m, grid, yr, yf) -> float:
    """RMS distance of the model's limiting loop from the averaged loop (inf if it does not converge)."""
    try:
        g, r, f, rho = limiting_loop(m, grid[0], grid[-1], len(grid))
    except (ValueError, np.linalg.LinAlgError):
        return np.inf
    return float(np.sqrt(np.mean((r - yr) ** 2) + np.mean((f - yf) ** 2))) if rho < 1 else np.inf


def _section3(grid, yr, yf, n: int, q: float | None, par: RICanonical, info: dict):
    """Section III start (q by loop error), or None."""
    errors = {}
    for qq in Q_CANDIDATES if q is None else (q,):
        try:
            mod = identify_ri_loop(grid, yr, yf, m=(n + 1) // 2, q=qq).model
            errors[qq] = (_loop_error(mod, grid, yr, yf), par.theta(mod))
        except (ValueError, np.linalg.LinAlgError, ArithmeticError) as exc:
            info.setdefault("ri_identification_errors", []).append(str(exc)[:200])
    if not errors:
        return None
    qq = min(errors, key=lambda k: errors[k][0])
    info["q"] = qq
    info["q_loop_errors"] = {str(k): v[0] for k, v in errors.items()}
    return errors[qq][0], errors[qq][1], f"section III, q = {qq}"


def ri_starts(grid, yr, yf, n: int, q: float | None, lower=None) -> tuple[list[np.ndarray], dict]:
    """Canonical starts for order n (module docstring) and a record of how they were chosen."""
    par = RICanonical(n)
    cands, info = [], {}
    if lower is not None:
        m = embed(lower, n)
        try:
            cands.append((_loop_error(m, grid, yr, yf) * 0.5, par.theta(m), f"order {n - 1} fit, embedded"))
        except np.linalg.LinAlgError as exc:  # (A+, C) of the embedding not observable: no canonical form
            info.setdefault("ri_identification_errors", []).append(f"order {n - 1} fit, embedded: {exc}")
    base = embed(_ri_first_order(grid, yr, yf), n)
    cands.append((_loop_error(base, grid, yr, yf), par.theta(base), "branch regression"))
    if n % 2 == 1:
        s3 = _section3(grid, yr, yf, n, q, par, info)
        if s3 is not None:
            cands.append(s3)
    cands = [c for c in cands if np.all(np.isfinite(c[1]))]
    cands.sort(key=lambda c: c[0])
    info["start"] = cands[0][2]
    info["start_loop_error"] = cands[0][0]
    return [c[1] for c in cands[: _STARTS_KEPT["ri"]]], info


def generic_ri_starts(n: int, lower=None) -> tuple[list[np.ndarray], dict]:
    """Starts for a general input (no loop to read them from): the order-(n-1) fit embedded, and,
    for each rate a of `GENERIC_RATES`, the model whose n modes relax at rates a, 2a, ..., n a on
    both branches (A+ = -diag(a, 2a, ...), A- = -A+, B = C = ones).  B, E, D and x0 are left to
    the fit's linear least squares (variable projection), so only the relaxation needs a start."""
    par = RICanonical(n)
    starts, info = [], {}
    if lower is not None:
        try:
            starts.append(par.theta(embed(lower, n)))
            info["start"] = f"order {n - 1} fit, embedded"
        except np.linalg.LinAlgError as exc:  # (A+, C) of the embedding not observable: no canonical form
            info.setdefault("ri_identification_errors", []).append(f"order {n - 1} fit, embedded: {exc}")
    ones = np.ones(n)
    for a in GENERIC_RATES:
        A = -a * np.diag(np.arange(1.0, n + 1))
        starts.append(par.theta(RateIndependentModel(A_plus=A, A_minus=-A, B_plus=ones, B_minus=ones, C=ones)))
    info.setdefault("start", f"generic relaxations (rates {list(GENERIC_RATES)} x 1..{n})")
    return starts, info


def _section5(param: RDCanonical, norm) -> np.ndarray:
    """Section V start converted to the fit's normalisation g(v_ref) = v_ref (k = g-hat(v_ref)/v_ref)."""
    m = identify_rd_triangles([(r.t, r.u, r.y) for r in norm], order=param.n).model
    vk = param.v_ref * np.exp(param.knots)
    gk = np.abs(m.g(vk))
    gv = np.abs(m.g(np.array([param.v_ref, -param.v_ref])))
    if not np.all(np.r_[gk, gv] > 0):
        raise DuhemError("identified g is not positive at the data's rates")
    k = gv[0] / param.v_ref
    h = np.log(gk / (k * vk))
    c = np.r_[np.log(gv[1] / gv[0]), h[np.abs(param.knots) != 0]]
    return param.theta(m.replace(A=m.A * k, B=m.B * k, E=m.E * k), c)


def rd_starts(param: RDCanonical, ri_model, lower, norm, triangle: bool) -> tuple[list[np.ndarray], dict]:
    """Starts for the rate-dependent fit (module docstring); `lower` is the order-(n-1) RefineResult."""
    starts, info = [], {}
    if lower is not None:
        m = embed(lower.model, param.n)
        starts.append(np.r_[param.theta(m)[: -1 - param.n_c], lower.theta[-1 - param.n_c :]])
        info["start"] = f"order {param.n - 1} fit, embedded"
    if triangle and len(norm) >= 2:
        try:
            starts.append(_section5(param, norm))
            info.setdefault("start", "section V triangle-wave identification")
        except (ValueError, np.linalg.LinAlgError, ArithmeticError) as exc:
            info["rd_identification_error"] = str(exc)[:200]
    if ri_model is not None:
        m = ri_model
        starts.append(
            param.theta(RateDependentModel(A=m.A_plus, B=m.B_plus, E=m.E_plus, C=m.C, D=m.D, g=lambda v: np.abs(v)))
        )
        info.setdefault("start", "rising branch of the rate-independent fit, g = |v|")
    starts = [th for th in starts if np.all(np.isfinite(th))]
    return starts[: _STARTS_KEPT["rd"]], info
