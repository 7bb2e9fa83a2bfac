"""The one simulation kernel: `simulate` a semilinear Duhem model for sampled input.

The input is piecewise linear between the samples (t_k, u_k).  The base model
is moved from sample to sample by the exact flow of eq (K) of `fitter.core.flow`
(no time stepping: the state is exact at every sample); a model with effects
runs the effect chain of `fitter.core.effects` instead, which builds on the
same flow.  The numerics of `fitter.core.flow` are re-exported here, so
``fitter.core.kernel`` stays the one place to import them from.

This module needs only numpy: it is shipped inside the FMUs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .effects import run_with_effects
from .errors import KernelError
from .flow import (
    AffineFlow,
    check_finite,
    check_increasing,
    expm,
    flows,
    integrate,
    integrate_blocks,
    integrate_runs,
    interval_coefficients,
    one_interval,
    phi1,
    phi2,
)

__all__ = [  # the simulation, then the flows and checks of `fitter.core.flow` it re-exports
    "simulate",
    "state_response",
    "state_responses",
    "state_blocks",
    "Simulation",
    "flows",
    "AffineFlow",
    "integrate",
    "integrate_blocks",
    "interval_coefficients",
    "one_interval",
    "expm",
    "phi1",
    "phi2",
    "check_finite",
    "check_increasing",
    "KernelError",
]


@dataclass
class Simulation:
    """Result of `simulate`: samples t, u; states x (N, n) and outputs y at each sample."""

    t: np.ndarray
    u: np.ndarray
    x: np.ndarray
    y: np.ndarray


def simulate(model, t, u, x0=None, flow_cache: dict | None = None, effect_state=None) -> Simulation:
    """Simulate a semilinear Duhem model for the sampled input (t_k, u_k).

    The input is piecewise linear between samples; the state is exact at every
    sample (no time stepping).  The rate-independent result does not depend
    on t (None: t_k = k).  `x0` defaults to the model's x0; y_k = C x_k + D u_k.
    A model with a non-empty ``effects`` list runs the effect chain of
    `fitter.core.effects` (then y is the chain's measured output), from the
    chain state `effect_state` at the first sample (default: the effects'
    stored start, else afresh; `effects.run_with_effects`).  A model
    with an ``input_range`` acts on u held at its edges (`model.model_input`,
    the extrapolation rule of `fitter.core.models`); the returned u is the
    input as given.

    Raises
    ------
    KernelError
        t or u not finite, of different lengths or empty; time not strictly
        increasing where the model needs time (rate-dependent, timed effects).
    """
    u = check_finite("u", u)
    t = check_finite("t", t) if t is not None else np.arange(len(u), dtype=float)
    if len(t) != len(u):
        raise KernelError(f"t and u differ in length ({len(t)} and {len(u)})")
    if len(u) == 0:
        raise KernelError("empty input")
    x0 = model.x0 if x0 is None else np.asarray(x0, dtype=float)
    fl = flow_cache if flow_cache is not None else flows(model)
    w = model.model_input(u)
    if getattr(model, "effects", None):
        X, y, _ = run_with_effects(model, t, w, x0, fl, effect_state)
        return Simulation(t=t, u=u, x=X, y=y)
    branch, p, r, S = interval_coefficients(model, t, w)
    X = integrate(fl, x0, branch, p, r, S)
    y = model.output(X, w)
    return Simulation(t=t, u=u, x=X, y=y)


def state_response(model, t, u, X0, flow_cache: dict | None = None, forcing: dict | None = None) -> np.ndarray:
    """States (N, n, m) of `simulate` from each of the m initial states in the columns of X0 (n, m).

    A base model runs all columns in one pass of the kernel (`flow.integrate`
    takes a matrix of initial states and, optionally, per-column forcings
    {branch: (B, E)} that replace the model's own); a model with effects runs
    the effect chain once per column (forcings are then refused).  The states
    come from `state_blocks`.
    """
    out = None
    k = 0
    for X in state_blocks(model, t, u, X0, flow_cache, forcing):
        if out is None:
            out = np.empty((1 + max(len(u) - 1, 0),) + X.shape[1:])  # x_0 and one state per interval
        out[k : k + len(X)] = X
        k += len(X)
    return out


def state_blocks(model, t, u, X0, flow_cache: dict | None = None, forcing: dict | None = None) -> Iterator[np.ndarray]:
    """The states of `state_response` in consecutive pieces along the samples ((k, n, m) arrays, the
    first starting with x_0), so that a caller reducing them as they come (an output, the last state)
    holds one piece at a time (`flow.integrate_blocks`; a model with effects gives one piece)."""
    X0 = np.asarray(X0, dtype=float)
    fl = flow_cache if flow_cache is not None else flows(model)
    if getattr(model, "effects", None):
        if forcing is not None:
            raise KernelError("per-column forcings need a model without effects")
        yield np.stack([simulate(model, t, u, x0=x, flow_cache=fl).x for x in X0.T], axis=2)
        return
    pieces = integrate_blocks(fl, X0, *_intervals(model, t, u), forcing)
    first = next(pieces, np.empty((0,) + X0.shape))
    yield np.concatenate([X0[None], first])
    yield from pieces


def state_responses(
    model, ts, us, X0, flow_cache: dict | None = None, forcing: dict | None = None, outputs: bool = False
) -> list[np.ndarray]:
    """`state_response` of a base model (no effects) on several recordings (t_i, u_i) from the same X0: the
    same numbers, with the recordings' intervals in one call of the compiled scan where it is in effect
    (`flow.integrate_runs`), else recording by recording (`flow.integrate_blocks`).  `outputs`: C x (the
    model's C; without D u) per sample instead of the states, (N,) or (N, m): inside the compiled scan from the
    modal states directly (n products an interval instead of n^2; for C = e1 the states' first entries)."""
    X0 = np.asarray(X0, dtype=float)
    fl = flow_cache if flow_cache is not None else flows(model)
    if getattr(model, "effects", None):
        states = [state_response(model, t, u, X0, fl, forcing) for t, u in zip(ts, us)]
        return [np.einsum("i,ki...->k...", model.C, X) for X in states] if outputs else states
    C = np.asarray(model.C, dtype=float)
    runs = [_intervals(model, t, u) for t, u in zip(ts, us)]
    together = integrate_runs(fl, X0, runs, forcing, C if outputs else None)
    if together is not None:
        pieces = [[X] for X in together]
    else:
        pieces = [list(integrate_blocks(fl, X0, *run, forcing)) for run in runs]
        pieces = [[np.einsum("i,ki...->k...", C, X) for X in run] for run in pieces] if outputs else pieces
    first = np.einsum("i,i...->...", C, X0) if outputs else X0
    out = []
    for run in pieces:
        full = np.empty((1 + sum(len(X) for X in run),) + first.shape)  # x_0 and one state per interval
        full[0], k = first, 1
        for X in run:
            full[k : k + len(X)] = X
            k += len(X)
        out.append(full)
    return out


def _intervals(model, t, u) -> tuple[np.ndarray, ...]:
    """(branch, p, r, S) of `interval_coefficients` for a recording, t and u checked finite and of one length (t
    None: the sample index)."""
    u = check_finite("u", u)
    t = check_finite("t", t) if t is not None else np.arange(len(u), dtype=float)
    if len(t) != len(u):
        raise KernelError(f"t and u differ in length ({len(t)} and {len(u)})")
    return interval_coefficients(model, t, model.model_input(u))
