"""Output-error refinement of a semilinear Duhem model on sampled recordings.

Given a map ``build: theta -> model`` (any model `fitter.core.simulate` accepts)
and recordings (t_k, u_k, y_k), `refine` minimises the stacked simulation error

    J(theta) = sum_i sum_k w_ik (y_ik - yhat_ik(theta))^2,
    yhat_i = simulate(build(theta), t_i, u_i, x0=x0_i(theta)).y

with `scipy.optimize.least_squares` (trust-region reflective, parameters scaled
by the Jacobian's column norms, forward-difference Jacobian).  The input is
piecewise linear between samples, as in the kernel.

Initial state (option ``x0``)
-----------------------------
The simulated state is affine in its initial value: x_k = Phi_k x_0 + c_k (every
interval flow of the kernel is affine).  This gives three exact choices:

* ``"model"``: x_0 = build(theta).x0 for every recording, all samples fitted.
* ``"fit"``: x_0 of each recording is eliminated by linear least squares
  (variable projection): x_0 = argmin ||y - C Phi x_0 - C c - D u||, so a
  start-up transient is fitted without adding parameters to theta.  Phi_k is
  computed over a prefix (twice the first cycle, doubled until
  max|Phi| < 1e-9, i.e. until x_0 no longer matters), and x_0 is fitted on
  that prefix; the rest of the recording is one plain simulation.
* ``"periodic"`` (settled): each recording is fitted from the start of its
  first settled cycle (sample s0; the samples before s0 are the transient and
  are dropped), and x(s0) is the fixed point x* = (I - Phi)^-1 c of the affine
  one-cycle map over [s0, s1] (Theorem 1).  When the measured cycle does not
  close exactly (u[s1] != u[s0]) the map is taken over the samples as they are;
  x* is then the state that the recorded cycle would return to.  This needs
  rho(Phi) < 1 (the convergence condition); otherwise the recording is started
  from the model's x0 and the result is flagged in ``RefineResult.rho``.

Speed
-----
Each residual evaluation costs one simulation per recording (plus order+1
simulations of one cycle for ``"periodic"``, order+1 full ones for ``"fit"``).
Recordings longer than ``max_samples`` are decimated for the optimisation:
from each block of k consecutive samples the first one and the samples with
the block's largest and smallest input are kept, so every input reversal
survives to within a block.  For a rate-independent model the decimated
simulation is exact at the kept samples wherever the input is monotone
between them (Proposition 1); for a rate-dependent one the kept input is a
piecewise-linear approximation.  The final residuals, Jacobian and covariance
are evaluated on all samples; for a decimated problem the Jacobian is that of
the kept samples and J^T J is scaled by N_all / N_kept (the information of an
oversampled recording grows with its sample count).

Uncertainty
-----------
sigma^2 = sum r^2 / (N - p), cov = sigma^2 (J^T J)^+ (pseudo-inverse, so
redundant directions get no spurious precision), stderr = sqrt(diag cov).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import least_squares

from fitter.core.kernel import KernelError, flows, simulate
from fitter.data.recordings import Recording

__all__ = ["RefineResult", "refine", "simulate_from", "cycle_fixed_point", "jacobian",
           "X0_MODES"]

X0_MODES = ("model", "fit", "periodic")
LSQ_METHOD = "trf"
FTOL = 1e-6  # relative cost decrease below which the optimiser stops (noise-level gains)
_FAIL = 1e3  # residual (in units of the output's std) returned where simulation fails


@dataclass
class RefineResult:
    """Outcome of `refine`.

    theta: optimum; model: build(theta); residuals: per recording, y - yhat on
    the fitted samples (from `starts[i]` on); starts: first fitted sample per
    recording; x0s: initial state used at `starts[i]`; cost: 0.5 sum w r^2;
    jac: d(sqrt(w) r)/d theta on all fitted samples; cov, stderr, sigma: see
    the module docstring; rho: spectral radius of each recording's one-cycle
    map (``"periodic"`` only, else NaN).
    """

    theta: np.ndarray
    model: object
    residuals: list[np.ndarray]
    starts: list[int]
    x0s: list[np.ndarray]
    cost: float
    jac: np.ndarray
    cov: np.ndarray
    stderr: np.ndarray
    sigma: float
    nfev: int
    success: bool
    message: str = ""
    rho: list[float] = field(default_factory=list)


def _affine_parts(model, t, u, cache) -> tuple[np.ndarray, np.ndarray]:
    """c_k (states from x0 = 0) and Phi_k (k, n, n): x_k = Phi_k x0 + c_k."""
    n = model.order
    c = simulate(model, t, u, x0=np.zeros(n), flow_cache=cache).x
    Phi = np.stack([simulate(model, t, u, x0=e, flow_cache=cache).x - c for e in np.eye(n)],
                   axis=2)
    return c, Phi


def cycle_fixed_point(model, t, u, cache=None) -> tuple[np.ndarray, float]:
    """Fixed point x* = (I - Phi)^-1 c of the one-cycle map over the given samples, and rho(Phi).

    The samples are one cycle of input (u[-1] close to u[0]; not enforced).
    Returns (model.x0, rho) when rho >= 1 (no fixed point to converge to).
    """
    cache = flows(model) if cache is None else cache
    n = model.order
    c = simulate(model, t, u, x0=np.zeros(n), flow_cache=cache).x[-1]
    Phi = np.column_stack([simulate(model, t, u, x0=e, flow_cache=cache).x[-1] - c
                           for e in np.eye(n)])
    if not (np.all(np.isfinite(Phi)) and np.all(np.isfinite(c))):
        return np.array(model.x0, dtype=float), np.inf
    rho = float(np.max(np.abs(np.linalg.eigvals(Phi))))
    if not rho < 1:
        return np.array(model.x0, dtype=float), rho
    return np.linalg.solve(np.eye(n) - Phi, c), rho


def simulate_from(model, t, u, y, mode: str, cycle: tuple[int, int] | None):
    """Simulate one recording under an initial-state mode (see module docstring).

    Returns (start, x0, yhat, rho): yhat covers samples start..end.
    """
    cache = flows(model)
    if mode == "model":
        return 0, np.array(model.x0, dtype=float), simulate(model, t, u, flow_cache=cache).y, np.nan
    if mode == "fit":
        n_pre = len(u) if cycle is None else min(len(u), max(2 * (cycle[1] + 1), 64))
        while True:
            c, Phi = _affine_parts(model, t[:n_pre], u[:n_pre], cache)
            if n_pre == len(u) or np.max(np.abs(Phi[-1])) < 1e-9:
                break
            n_pre = min(len(u), 2 * n_pre)
        G = np.einsum("j,kjl->kl", model.C, Phi)
        base = c @ model.C + model.D * u[:n_pre]
        if not (np.all(np.isfinite(G)) and np.all(np.isfinite(base))):
            raise KernelError("simulation overflowed")
        x0, *_ = np.linalg.lstsq(G, y[:n_pre] - base, rcond=None)
        if n_pre == len(u):
            return 0, x0, base + G @ x0, np.nan
        return 0, x0, simulate(model, t, u, x0=x0, flow_cache=cache).y, np.nan
    if mode != "periodic":
        raise ValueError(f"x0 must be one of {X0_MODES}, not {mode!r}")
    s0, s1 = cycle
    x0, rho = cycle_fixed_point(model, t[s0:s1 + 1], u[s0:s1 + 1], cache)
    return s0, x0, simulate(model, t[s0:], u[s0:], x0=x0, flow_cache=cache).y, rho


def _keep_indices(u: np.ndarray, max_samples: int | None, cycle) -> np.ndarray:
    """Decimation keeping each block's first, max-input and min-input samples."""
    n = len(u)
    if max_samples is None or n <= max_samples:
        return np.arange(n)
    k = int(np.ceil(3 * n / max_samples))
    nb = n // k
    blocks = u[:nb * k].reshape(nb, k)
    base = np.arange(nb) * k
    keep = np.r_[base, base + blocks.argmax(axis=1), base + blocks.argmin(axis=1),
                 np.arange(nb * k, n), n - 1]
    if cycle is not None:
        keep = np.r_[keep, cycle[0], cycle[1]]
    return np.unique(keep)


@dataclass
class _Problem:
    """Recordings (possibly decimated) with their weights and cycles."""

    t: list[np.ndarray]
    u: list[np.ndarray]
    y: list[np.ndarray]
    w: list[np.ndarray]
    cycles: list[tuple[int, int] | None]
    scale: list[float]


def _problem(recordings, weights, cycles, max_samples) -> _Problem:
    p = _Problem([], [], [], [], [], [])
    for i, rec in enumerate(recordings):
        cyc = cycles[i]
        keep = _keep_indices(rec.u, max_samples, cyc)
        w = np.ones(len(rec.u)) if weights is None else np.broadcast_to(
            np.asarray(weights[i], dtype=float), rec.u.shape)
        p.t.append(rec.t[keep])
        p.u.append(rec.u[keep])
        p.y.append(rec.y[keep])
        p.w.append(np.sqrt(w[keep]))
        if cyc is not None:
            pos = np.searchsorted(keep, cyc)
            cyc = (int(pos[0]), int(pos[1]))
        p.cycles.append(cyc)
        p.scale.append(float(np.std(rec.y)) or 1.0)
    return p


def _residuals(build, theta, prob: _Problem, mode: str):
    """Stacked weighted residuals, plus per-recording (start, x0, r, rho)."""
    parts, info = [], []
    try:
        model = build(theta)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        model = None
    for t, u, y, w, cyc, sc in zip(prob.t, prob.u, prob.y, prob.w, prob.cycles, prob.scale):
        start = cyc[0] if (mode == "periodic" and cyc is not None) else 0
        try:
            if model is None:
                raise KernelError("model could not be built")
            with np.errstate(all="ignore"):
                s, x0, yhat, rho = simulate_from(model, t, u, y, mode, cyc)
            r = y[s:] - yhat
            if not np.all(np.abs(r) < _FAIL * sc * 1e3):
                raise KernelError("simulation diverged")
        except (KernelError, ValueError, np.linalg.LinAlgError):
            s, x0, rho = start, None, np.nan
            r = np.full(len(y) - start, _FAIL * sc)
        parts.append(r * w[s:])
        info.append((s, x0, r, rho))
    return np.concatenate(parts), model, info


def jacobian(fun: Callable[[np.ndarray], np.ndarray], theta: np.ndarray,
             f0: np.ndarray | None = None) -> np.ndarray:
    """Forward-difference Jacobian of a vector function, steps 1e-6 (1 + |theta_j|)."""
    f0 = fun(theta) if f0 is None else f0
    J = np.empty((len(f0), len(theta)))
    for j in range(len(theta)):
        h = 1e-6 * (1.0 + abs(theta[j]))
        th = theta.copy()
        th[j] += h
        J[:, j] = (fun(th) - f0) / h
    return J


def refine(build: Callable[[np.ndarray], object], theta0: np.ndarray,
           recordings: Sequence[Recording], *, x0: str = "periodic", weights=None,
           max_nfev: int | None = None, progress: Callable[[str], None] | None = None,
           cycles: Sequence[tuple[int, int] | None] | None = None,
           penalty: Callable[[np.ndarray], np.ndarray] | None = None,
           max_samples: int | None = 6000) -> RefineResult:
    """Output-error least squares of `build(theta)` on `recordings`.

    Parameters
    ----------
    build : theta -> model (RateIndependentModel or RateDependentModel); may
        raise ValueError for an invalid theta (treated as a failed simulation).
    theta0 : starting parameters.
    recordings : the data; all samples are used (trim beforehand if needed).
    x0 : "model", "fit" or "periodic" (see the module docstring).
    weights : per-recording scalars or per-sample arrays (default 1).
    max_nfev : cap on residual evaluations (default scipy's, 100 p).
    progress : called with a one-line status after the optimisation stages.
    cycles : for x0="periodic", the (s0, s1) sample indices of each recording's
        first settled cycle; by default found by `fitter.data.preparation`.
    penalty : optional theta -> extra residuals (e.g. a barrier that keeps the
        convergence condition satisfied); appended to the objective.
    max_samples : decimate longer recordings during the optimisation.
    """
    if x0 not in X0_MODES:
        raise ValueError(f"x0 must be one of {X0_MODES}, not {x0!r}")
    if not recordings:
        raise ValueError("refine needs at least one recording")
    theta0 = np.asarray(theta0, dtype=float)
    if cycles is None:
        cycles = [_first_cycle(rec) for rec in recordings] if x0 == "periodic" \
            else [None] * len(recordings)

    def objective(prob):
        def fun(theta):
            r, _, _ = _residuals(build, theta, prob, x0)
            return r if penalty is None else np.r_[r, penalty(theta)]
        return fun

    coarse = _problem(recordings, weights, cycles, max_samples)
    budget = None if max_nfev is None else (max_nfev * (len(theta0) + 1) if LSQ_METHOD == "lm" else max_nfev)
    sol = least_squares(objective(coarse), theta0, method=LSQ_METHOD, x_scale="jac", max_nfev=budget,
                        ftol=FTOL)
    if progress:
        progress(f"output-error refinement: cost {sol.cost:.4g} after {sol.nfev} evaluations")
    full = _problem(recordings, weights, cycles, None)
    r, model, info = _residuals(build, sol.x, full, x0)
    n_full = len(r)
    if sum(len(y) for y in coarse.y) < sum(len(y) for y in full.y):
        r_kept, _, _ = _residuals(build, sol.x, coarse, x0)
        J = jacobian(lambda th: _residuals(build, th, coarse, x0)[0], sol.x, r_kept)
        J_scale = n_full / len(r_kept)
    else:
        J = jacobian(lambda th: _residuals(build, th, full, x0)[0], sol.x, r * np.concatenate(
            [w[s:] for w, s in zip(full.w, [i[0] for i in info])]))
        J_scale = 1.0
    dof = max(n_full - len(sol.x), 1)
    sigma = float(np.sqrt(np.sum(r ** 2) / dof))
    cov = sigma ** 2 * np.linalg.pinv(J_scale * (J.T @ J))
    return RefineResult(theta=sol.x, model=model, residuals=[i[2] for i in info],
                        starts=[i[0] for i in info], x0s=[i[1] for i in info],
                        cost=float(0.5 * np.sum(r ** 2)), jac=J, cov=cov,
                        stderr=np.sqrt(np.clip(np.diag(cov), 0, None)), sigma=sigma,
                        nfev=int(sol.nfev), success=bool(sol.success), message=str(sol.message),
                        rho=[float(i[3]) for i in info])


def _first_cycle(rec: Recording) -> tuple[int, int]:
    """(s0, s1) of the first settled cycle, from `fitter.data.preparation`."""
    from fitter.data.preparation import prepare
    prep = prepare(rec)
    return first_settled_cycle(prep)


def first_settled_cycle(prep) -> tuple[int, int]:
    """First cycle that starts at or after the transient's end, in the original sample index."""
    cycles = [tuple(map(int, c)) for c in prep.cycles]
    if not cycles:
        raise ValueError(f"{prep.recording.name}: no complete input cycle to start from")
    return cycles[0]
