"""Limiting periodic input-output map (Theorem 1 of Oh & Bernstein 2007).

For a periodic input sampled over one period (u_N = u_0), one period of the
kernel is an affine map x_N = Phi x_0 + c of the initial state (every interval
flow is affine).  When rho(Phi) < 1 the iteration converges to the unique
periodic state x* = (I - Phi)^{-1} c, and the response from x* is the
limiting periodic map H_inf.  For the rate-independent model and an input with
one maximum and one minimum per period, Phi is similar to
e^{beta A+} e^{-beta A-} (beta = u_max - u_min), so rho(Phi) is the quantity
of condition (5).
"""

from __future__ import annotations

from collections import deque

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .errors import ConvergenceError, KernelError
from .kernel import Simulation, expm, flows, simulate, state_blocks

__all__ = [
    "ConvergenceError",
    "PeriodicResponse",
    "periodic_response",
    "convergence_rho",
    "minor_loop_rho",
    "minor_loop_outputs",
    "minor_loop_input",
    "limiting_loop",
    "affine_blocks",
    "affine_response",
    "period_map",
    "fixed_point",
]


def affine_blocks(model, t, u, cache: dict | None = None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """States as an affine function of the initial state, x_k = Phi_k x_0 + c_k, in consecutive pieces
    along the samples (`fitter.core.kernel.state_blocks`): (c (k, n), Phi (k, n, n)) per piece, c the states
    from x_0 = 0 and column j of Phi the states from x_0 = e_j minus c (every interval flow of the kernel is
    affine).  A caller that reduces the pieces as they come holds one piece at a time."""
    n = model.order
    for X in state_blocks(model, t, u, np.hstack([np.zeros((n, 1)), np.eye(n)]), cache):
        c = X[:, :, 0]
        yield c, X[:, :, 1:] - c[:, :, None]


def affine_response(model, t, u, cache: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """c (N, n) and Phi (N, n, n) of `affine_blocks` over all samples."""
    pieces = list(affine_blocks(model, t, u, cache))
    return np.concatenate([c for c, _ in pieces]), np.concatenate([Phi for _, Phi in pieces])


def period_map(model, t, u, cache: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, c) of the affine map x_N = Phi x_0 + c over the given samples (one period): the last
    state of `affine_blocks`, only the last piece kept."""
    ((c, Phi),) = deque(affine_blocks(model, t, u, cache), maxlen=1)
    return Phi[-1], c[-1]


def fixed_point(model, t, u, cache: dict | None = None) -> tuple[np.ndarray | None, float]:
    """Periodic state x* = (I - Phi)^{-1} c of the samples' period map and rho(Phi).

    x* is None when rho >= 1 (no fixed point to converge to) or the map overflows
    (rho = inf).  The samples are taken as they are: when u[-1] != u[0] the
    fixed point is the state the recorded cycle would return to.
    """
    return _settled(*period_map(model, t, u, cache))


def _settled(Phi: np.ndarray, c: np.ndarray) -> tuple[np.ndarray | None, float]:
    """(x*, rho) of the affine map x -> Phi x + c, as `fixed_point` returns them."""
    if not (np.all(np.isfinite(Phi)) and np.all(np.isfinite(c))):
        return None, np.inf
    rho = float(np.max(np.abs(np.linalg.eigvals(Phi))))
    if not rho < 1:
        return None, rho
    return np.linalg.solve(np.eye(len(c)) - Phi, c), rho


@dataclass
class PeriodicResponse:
    """The limiting periodic response over one period and the convergence quantity."""

    sim: Simulation
    rho: float
    x_periodic: np.ndarray


def periodic_response(model, t, u) -> PeriodicResponse:
    """Limiting periodic response for one period (t_0..t_N, u_N = u_0) of input.

    One pass of the kernel for a base model: the states are affine in the initial state,
    x_k = Phi_k x_0 + c_k (`affine_response`), so the periodic states are x_k = Phi_k x* + c_k with
    x* = (I - Phi_N)^{-1} c_N (the paper's reproduction spent half its identification time simulating
    again from x*); a model with effects is simulated again from x*.
    Raises `ConvergenceError` when the monodromy's spectral radius is >= 1.
    """
    u = np.asarray(u, dtype=float)
    if len(u) < 3:
        raise KernelError("one period needs at least 3 samples")
    if not np.isclose(u[-1], u[0], rtol=0, atol=1e-9 * max(1.0, np.ptp(u))):
        raise KernelError(f"input is not one period: u[0] = {u[0]} but u[-1] = {u[-1]}")
    cache = flows(model)
    if getattr(model, "effects", None):
        xs, rho = fixed_point(model, t, u, cache)
        return PeriodicResponse(
            sim=simulate(model, t, u, x0=_periodic(xs, rho), flow_cache=cache), rho=rho, x_periodic=xs
        )
    c, Phi = affine_response(model, t, u, cache)
    xs, rho = _settled(Phi[-1], c[-1])
    X = c + Phi @ _periodic(xs, rho)
    t = np.arange(len(u), dtype=float) if t is None else np.asarray(t, dtype=float)
    return PeriodicResponse(
        sim=Simulation(t=t, u=u, x=X, y=model.output(X, model.model_input(u))), rho=rho, x_periodic=xs
    )


def _periodic(xs: np.ndarray | None, rho: float) -> np.ndarray:
    """The periodic state `xs` of `fixed_point`, or `ConvergenceError` when there is none (rho >= 1)."""
    if xs is None:
        raise ConvergenceError(
            f"no limiting periodic map: spectral radius of the period map "
            f"is {rho:.6g} >= 1 (condition (5) of Theorem 1 fails)"
        )
    return xs


def _span_rho(model, b: float) -> float:
    """rho(e^{b A+} e^{-b A-}): the spectral radius of the period map of a loop of span b (inf on overflow)."""
    if model.kind != "ri":
        raise KernelError("condition (5) is for the rate-independent model")
    M = expm(b * model.A_plus) @ expm(-b * model.A_minus)
    if not np.all(np.isfinite(M)):
        return float("inf")
    return float(np.max(np.abs(np.linalg.eigvals(M))))


def convergence_rho(model, u_min: float, u_max: float) -> float:
    """rho(e^{beta A+} e^{-beta A-}), condition (5), for a rate-independent model."""
    return _span_rho(model, u_max - u_min)


MINOR_SPANS = 8
"""Sub-spans at which `minor_loop_outputs` and `minor_loop_input` place minor loops: b = beta k / MINOR_SPANS."""

RHO_SPANS = 256
"""Fewest sub-spans at which `minor_loop_rho` evaluates condition (5) (more for branches that oscillate fast)."""

_RHO_SPANS_MAX = 4096


def _rho_spans(model, beta: float) -> int:
    """Sub-spans for `minor_loop_rho`: `RHO_SPANS`, or eight per half-turn of the fastest oscillation
    (beta max |Im lambda(A+-)| / pi), at most 4096.  rho(e^{b A+} e^{-b A-}) is not monotone in b when a
    branch matrix has complex eigenvalues: on eight sub-spans a loop of a fifth of the span with radius 1.8
    went unseen (fits of piezo and B-H loops then diverged on minor loops inside their input range)."""
    with np.errstate(all="ignore"):
        turns = max(float(np.max(np.abs(np.linalg.eigvals(A).imag))) for A in (model.A_plus, model.A_minus))
    need = 8 * beta * turns / np.pi if np.isfinite(turns) else _RHO_SPANS_MAX
    return int(min(max(RHO_SPANS, np.ceil(need)), _RHO_SPANS_MAX))


def minor_loop_rho(model, u_min: float, u_max: float, spans: int | None = None) -> float:
    """Condition (5) for every minor loop, per full-span travel: max over b = beta k / spans (k = 1..spans,
    beta = u_max - u_min; `spans` by default `_rho_spans`) of rho(e^{b A+} e^{-b A-})^(beta / b).

    Condition (5) is stated for an input that sweeps the whole span [u_min, u_max] (Theorem 1).  An input that
    cycles between two interior levels b apart (a minor loop) has the period map e^{b A+} e^{-b A-}, whose
    spectral radius may exceed 1 although the full-span one does not: the state then grows from cycle to cycle
    and a simulation driven by any other input than the fitted one diverges.  Raised to beta / b, the radius
    is the contraction per travel of one full span, so a single limit applies to every sub-span; at b = beta
    it is condition (5) itself, and as b -> 0 it tends to e^{beta alpha(A+ - A-)}, alpha the spectral abscissa
    (the first-order term of the product).  The exponentials of the sub-spans are powers of those of the
    first, e^{k d A} = (e^{d A})^k (d = beta / spans).  inf when an exponential overflows."""
    if model.kind != "ri":
        raise KernelError("condition (5) is for the rate-independent model")
    beta = u_max - u_min
    spans = _rho_spans(model, beta) if spans is None else spans
    d = beta / spans
    steps = expm(np.stack([d * model.A_plus, -d * model.A_minus]))
    powers = np.empty((spans, *steps.shape))  # powers[k - 1] = (e^{k d A+}, e^{-k d A-}), one product per step
    with np.errstate(all="ignore"):
        power = np.stack([np.eye(len(steps[0]))] * 2)
        for k in range(spans):
            power = np.matmul(power, steps, out=powers[k])
        maps = powers[:, 0] @ powers[:, 1]
        if not np.all(np.isfinite(maps)):
            return float("inf")
        radii = np.max(np.abs(np.linalg.eigvals(maps)), axis=1)
        return float(np.max(radii ** (spans / np.arange(1, spans + 1))))


MINOR_CENTRES = 5
"""Centres at which `minor_loop_outputs` places each sub-span's loop, evenly from the lowest to the highest."""


def minor_loop_outputs(
    model, u_min: float, u_max: float, spans: int = MINOR_SPANS, centres: int = MINOR_CENTRES
) -> np.ndarray:
    """Outputs at the two turning points of every settled minor loop, shape (spans * centres, 2).

    A loop of span b = beta k / spans (k = 1..spans, beta = u_max - u_min) between u_lo and u_lo + b, with
    u_lo evenly placed on [u_min, u_max - b] (`centres` places; one for the full span), repeated, settles
    on the periodic state x* = (I - Phi)^{-1} c of its cycle u_lo -> u_lo + b -> u_lo (Phi, c: the affine
    period map, the falling branch's map after the rising one's); the outputs at u_lo (from x*) and at
    u_lo + b (after the rising branch) are the loop's turning points, y = C x + D u (a model without
    effects: effects are not run).  inf where a loop has no fixed point (its period map has radius >= 1)
    or overflows.  Rate-independent models (the time of a sample does not matter).  Each branch of a loop
    is the exact map of eqs (1)-(2) over its input travel (`_branch_maps`, all loops in one stacked
    exponential), with the kernel's hold of u at the edges of the model's ``input_range``."""
    if model.kind != "ri":
        raise KernelError("minor loops settle on a rate-independent model's own map")
    ends = []
    for k in range(1, spans + 1):
        b = (u_max - u_min) * k / spans
        ends += [(lo, lo + b) for lo in np.linspace(u_min, u_max - b, centres if k < spans else 1)]
    u = model.model_input(np.array(ends, dtype=float))
    n, eye = model.order, np.eye(model.order)
    with np.errstate(all="ignore"):
        R, gr, hr = _branch_maps(model.A_plus, model.B_plus, model.E_plus, u[:, 1] - u[:, 0])
        F, gf, hf = _branch_maps(model.A_minus, model.B_minus, model.E_minus, u[:, 0] - u[:, 1])
        top = gr * u[:, :1] + hr
        Phi = F @ R
        c = (F @ top[..., None])[..., 0] + gf * u[:, 1:] + hf
        finite = np.all(np.isfinite(Phi), axis=(1, 2)) & np.all(np.isfinite(c), axis=1)
        rho = np.full(len(u), np.inf)
        rho[finite] = np.max(np.abs(np.linalg.eigvals(Phi[finite])), axis=1)
        ok = rho < 1
        x = np.full((len(u), n), np.inf)
        x[ok] = np.linalg.solve(eye - Phi[ok], c[ok][..., None])[..., 0]
        x1 = (R @ x[..., None])[..., 0] + top
        y = np.stack([x @ model.C, x1 @ model.C], axis=1) + model.D * u
    y[~ok] = np.inf
    return np.where(np.isfinite(y), y, np.inf)


def _branch_maps(A: np.ndarray, B: np.ndarray, E: np.ndarray, du: np.ndarray) -> tuple[np.ndarray, ...]:
    """(Phi, g, h), stacked over the travels `du`, with x(u + du) = Phi x(u) + g u + h along one branch
    dx/du = A x + B u + E (eq. 1 with the branch's matrices), exact: the exponential of
    du [[A, B, E], [0, 0, 1], [0, 0, 0]] acting on (x, u, 1)."""
    n = len(B)
    M = np.zeros((n + 2, n + 2))
    M[:n, :n], M[:n, n], M[:n, n + 1], M[n, n + 1] = A, B, E, 1.0
    F = expm(du[:, None, None] * M)
    return F[:, :n, :n], F[:, :n, n], F[:, :n, n + 1]


def minor_loop_input(
    u_min: float, u_max: float, cycles: int = 40, points: int = 20, spans: int = MINOR_SPANS, start: float | None = None
) -> np.ndarray:
    """The sub-spans of `minor_loop_rho` as an input: from the middle of [u_min, u_max], `cycles` triangle
    cycles between two levels b apart around the middle, for b = beta k / spans, k = 1..spans in turn
    (`points` samples per leg).  A model whose `minor_loop_rho` is below 1 stays bounded on it.  `start`: the
    input at which the model's initial state holds (a fitted model's `first_input`); the input then begins
    there and goes straight to the middle (default: it begins at the middle)."""
    mid = 0.5 * (u_min + u_max)
    parts = [np.array([mid if start is None else start])]
    for k in range(1, spans + 1):
        b = (u_max - u_min) * k / spans
        leg = np.linspace(mid - b / 2, mid + b / 2, points + 1)
        parts.append(np.tile(np.r_[leg[:-1], leg[:0:-1]], cycles))
    if start is not None:
        parts.insert(1, np.array([mid]))
    return np.concatenate(parts)


def limiting_loop(model, u_min: float, u_max: float, points: int = 201):
    """Hysteresis map H_inf of a rate-independent model on a uniform grid.

    Returns (u_grid, y_rising, y_falling, rho); any input with one maximum and
    one minimum per period gives this loop (rate independence).
    """
    grid = np.linspace(u_min, u_max, points)
    u = np.r_[grid, grid[-2::-1]]
    t = np.arange(len(u), dtype=float)
    pr = periodic_response(model, t, u)
    y = pr.sim.y
    return grid, y[:points], y[points - 1 :][::-1], pr.rho
