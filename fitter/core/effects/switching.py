"""The `switching` effect (step 6 of the chain, the `fitter.core.effects` docstring): two populations of shares
that switch over in time beyond their thresholds, each share's state solved exactly interval by interval as the
first-order linear recurrence s_{k+1} = e^{-T_k} s_k + (1 - e^{-T_k}) s_eq,k (`switching_rates`,
`switching_states`), and a run's affine map for the settled start (`switching_period_map`).

The input is linear between samples; the switching integrals over an interval are exact for that input
(`_log_exprel`).  A population's run (its rates, period map and states) is kept for the runs asked last
(`_RUNS`): every number is what computing it again gives, to the last digit.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from statistics import NormalDist

import numpy as np

from ..recurrence import linear_recurrence
from .spec import INF, Chain, EffectContext, EffectSpec, ParameterSpec


def _log_exprel(d: np.ndarray) -> np.ndarray:
    """log((e^d - 1) / d), elementwise without overflow (its limit 0 at d = 0)."""
    d = np.asarray(d, dtype=float)
    out = d / 2
    pos, neg = d > 1e-12, d < -1e-12
    out[pos] = d[pos] + np.log(-np.expm1(-d[pos])) - np.log(d[pos])
    out[neg] = np.log(-np.expm1(d[neg])) - np.log(-d[neg])
    return out


_MAX_EXPONENT = 700.0
"""Switching integrals I+- are capped at e^700: beyond, e^{-I} is 0 in double precision anyway."""

_MAX_DECAY = 40.0
"""Their sum I+ + I- is capped at 40: e^{-40} = 4e-18 of |s - s_eq| <= 2 S is below the rounding of S, and the
cap keeps the recurrence's chunks (`linear_recurrence`) long over fully switched intervals."""


def switching_rates(u: np.ndarray, h: np.ndarray, S: float, u_up, u_dn, width: float) -> tuple[np.ndarray, ...]:
    """Per interval (N - 1, m) and share: the decay exponent T = min(I+ + I-, `_MAX_DECAY`) and the switched
    output s_eq it decays to (module docstring, step 6): s_{k+1} = e^{-T_k} s_k + (1 - e^{-T_k}) s_eq,k.

    log I+ = P_k - u_up / width and log I- = Q_k + u_dn / width, P and Q per interval; s_eq = S tanh((log I+ -
    log I-) / 2) and I+ + I- = max(I+, I-) (1 + e^{-|log I+ - log I-|}) depend on the share only through
    u_up + u_dn, computed once per interval (shape (N - 1, 1)) when every share has the same sum (thresholds
    spread symmetrically, `_shares`)."""
    run = _run(u, h, S, u_up, u_dn, width)
    return run.total, run.target


@dataclass
class _Run:
    """One population's switching over one run of samples (`_run`): its rates (`switching_rates`), and, once
    asked, its period map (`switching_period_map`) and its states from each start asked (`switching_states`),
    all read-only."""

    total: np.ndarray
    target: np.ndarray
    period: tuple[np.ndarray, np.ndarray] | None = None
    states: dict[bytes, np.ndarray] = field(default_factory=dict)


_RUNS: OrderedDict[tuple, _Run] = OrderedDict()
_RUNS_KEPT = 32
"""Populations' runs kept, the least recently asked dropped first.  A settled start (`Switching.settle`) and the
run from it (`Switching.apply`) ask for the same rates; a forward-difference Jacobian moves one parameter at a
time, so each of its evaluations asks again for the unmoved population's runs on every recording (measured on
the piezo triangles' effect screening: 8.6 s -> 6.5 s, the same costs to the last digit)."""
_RUNS_SIZE = 2**15
"""Only runs of at most this many values (intervals x shares, 256 kB an array) are kept: a long recording's are
computed again rather than held."""
_STATES_KEPT = 2
"""States kept per run: from the start afresh and from the settled one."""
_LOCK = threading.Lock()
"""Guards `_RUNS` and the runs' kept values: a simulator may step several FMU instances on threads."""


def _run(u: np.ndarray, h: np.ndarray, S: float, u_up, u_dn, width: float) -> _Run:
    """The `_Run` of a population with thresholds `u_up`, `u_dn` (arrays (m,) or scalars) over samples `u`
    with steps `h`: from `_RUNS` when asked before (keyed by the values' bytes and the caps)."""
    up, dn = np.atleast_1d(np.asarray(u_up, dtype=float)), np.atleast_1d(np.asarray(u_dn, dtype=float))
    key = (u.tobytes(), h.tobytes(), float(S), up.tobytes(), dn.tobytes(), float(width), _MAX_EXPONENT, _MAX_DECAY)
    with _LOCK:
        run = _RUNS.get(key)
        if run is not None:
            _RUNS.move_to_end(key)
            return run
    run = _Run(*_switching_rates(u, h, S, up, dn, width))
    if len(u) * len(up) <= _RUNS_SIZE:
        with _LOCK:
            _RUNS[key] = run
            while len(_RUNS) > _RUNS_KEPT:
                _RUNS.popitem(last=False)
    return run


def _switching_rates(u, h, S: float, up: np.ndarray, dn: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """`switching_rates` computed (read-only arrays)."""
    ua, d = u[:-1, None], (np.diff(u) / width)[:, None]
    log_h = np.log(h)[:, None]
    P = log_h + ua / width + _log_exprel(d)
    Q = log_h - ua / width + _log_exprel(-d)
    sums = up + dn
    gap = (P - Q) - (sums[:1] if np.all(sums == sums[0]) else sums) / width
    big = np.maximum(P - up / width, Q + dn / width)
    total = np.minimum(np.exp(np.minimum(big, _MAX_EXPONENT)) * (1.0 + np.exp(-np.abs(gap))), _MAX_DECAY)
    target = S * np.tanh(gap / 2)
    total.flags.writeable = target.flags.writeable = False
    return total, target


def switching_states(u: np.ndarray, h: np.ndarray, S: float, u_up, u_dn, width: float, s0) -> np.ndarray:
    """Samples (N, m) of m shares' switched outputs s (module docstring, step 6): thresholds `u_up`, `u_dn`
    and starts `s0` of shape (m,) (or scalars: m = 1).  Read-only (kept with the run, `_run`)."""
    run = _run(u, h, S, u_up, u_dn, width)
    total, target = run.total, run.target
    start = np.broadcast_to(np.asarray(s0, dtype=float), total.shape[1:])
    key = start.tobytes()
    with _LOCK:
        out = run.states.get(key)
    if out is None:
        out = np.empty((len(u), total.shape[1]))
        out[0] = start
        if len(h):
            out[1:] = linear_recurrence(start, -total, np.exp(-total), -np.expm1(-total) * target)
        out.flags.writeable = False
        with _LOCK:
            while len(run.states) >= _STATES_KEPT:
                del run.states[next(iter(run.states))]
            run.states[key] = out
    return out


def switching_period_map(total: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The run of `switching_rates`' intervals as the affine map s_N = P s_0 + c of each share:
    P = e^{-sum T}, c = sum_k e^{-(T_{k+1} + ... + T_{N-1})} (1 - e^{-T_k}) s_eq,k (every exponent <= 0)."""
    after = np.cumsum(total[::-1], axis=0)[::-1] - total
    c = np.sum(np.exp(-after) * -np.expm1(-total) * target, axis=0)
    return np.exp(-np.sum(total, axis=0)), c


def _period_map(run: _Run) -> tuple[np.ndarray, np.ndarray]:
    """`switching_period_map` of a run, kept with it (read-only)."""
    if run.period is None:
        P, c = switching_period_map(run.total, run.target)
        P.flags.writeable = c.flags.writeable = False
        run.period = (P, c)
    return run.period


SWITCHING_POPULATIONS = 2
"""Number of populations of the `switching` effect."""

SWITCHING_NODES = 16
"""Equal shares of each `switching` population (module docstring, step 6)."""

SWITCHING_NODES_Z = tuple(NormalDist().inv_cdf((j + 0.5) / SWITCHING_NODES) for j in range(SWITCHING_NODES))
"""Their threshold offsets in units of the spread: the normal quantiles Phi^-1((j + 1/2) / N), j = 0..N-1."""


def _population_parameters(i: int) -> tuple[ParameterSpec, ...]:
    """Population i's parameters of `switching`: S, u_up, u_dn, width, q, required for population 1 and
    refinements for the others (their defaults switch nothing: S = 0); every spread a refinement (default 0)."""
    more = i > 1

    def spec(name: str, lower: float, upper: float, default: float, **kw) -> ParameterSpec:
        return ParameterSpec(f"{name}{i}", lower, upper, default=default if more else None, refinement=more, **kw)

    return (
        spec("S", 0.0, INF, 0.0),
        spec("u_up", -INF, INF, 0.0),
        spec("u_dn", -INF, INF, 0.0),
        spec("width", 0.0, INF, 1.0, strict=True, log=True),
        spec("q", -1.0, 1.0, 0.0),
        ParameterSpec(f"spread{i}", 0.0, INF, log=True, default=0.0, refinement=True),
    )


def _shares(p: dict[str, float], i: int, start: np.ndarray) -> tuple:
    """Population i's amplitude S and its shares' thresholds u_up, u_dn and starts (each of
    `SWITCHING_NODES`), or one share standing for all when they are alike (no spread, one start)."""
    S, shift = p[f"S{i}"], p[f"spread{i}"] * np.array(SWITCHING_NODES_Z)
    up, dn = p[f"u_up{i}"] + shift, p[f"u_dn{i}"] - shift
    if not shift.any() and np.all(start == start[0]):
        return S, up[:1], dn[:1], start[:1]
    return S, up, dn, start


class Switching(EffectSpec):
    """Step 6 of the chain: y += sum_i mean_j s_ij, two populations of `SWITCHING_NODES` shares
    ds_ij/dt = k+_ij(u) (S_i - s_ij) - k-_ij(u) (S_i + s_ij), thresholds spread by spread_i z_j."""

    name = "switching"
    description = (
        "field-activated switching: beyond a threshold input the output switches over in time, at a "
        "rate growing exponentially with the input (a ferroelectric's domains, Merz's law), so it goes "
        "on after the input turns and a slower loop switches more"
    )
    stage = "output"
    additive = True
    timed = True
    parameters = tuple(par for i in range(1, SWITCHING_POPULATIONS + 1) for par in _population_parameters(i))
    state = tuple(f"s{i}_{j}" for i in range(1, SWITCHING_POPULATIONS + 1) for j in range(1, SWITCHING_NODES + 1))
    example = {
        "S1": 0.3,
        "u_up1": 0.5,
        "u_dn1": -0.5,
        "width1": 0.1,
        "q1": -1.0,
        "spread1": 0.0,
        "S2": 0.0,
        "u_up2": 0.8,
        "u_dn2": -0.8,
        "width2": 0.05,
        "q2": -1.0,
        "spread2": 0.0,
    }
    strength = "S1"
    reverses = True
    """With one threshold just beyond the input's tips and the other out of reach it switches slowly at every
    tip, one way: a drift in time, which the generality sweep's quadratic and exponential output drifts were
    named as before `duhem diagnose` asked for the swing both ways (`fitter.diagnosis.statistics.reversal_report`,
    from the extreme starts of `extremes`)."""

    def extremes(self, p: dict[str, float]) -> tuple[dict[str, float], dict[str, float]]:
        """Every population started switched down (q_i = -1), and switched up (q_i = +1)."""
        qs = [f"q{i}" for i in range(1, SWITCHING_POPULATIONS + 1)]
        return {**p, **dict.fromkeys(qs, -1.0)}, {**p, **dict.fromkeys(qs, 1.0)}

    def c_constants(self) -> dict[str, int | float | tuple[float, ...]]:
        """Populations, shares, their threshold offsets and the caps of the switching integrals."""
        return {
            "POPULATIONS": SWITCHING_POPULATIONS,
            "NODES": SWITCHING_NODES,
            "NODES_Z": SWITCHING_NODES_Z,
            "MAX_EXPONENT": _MAX_EXPONENT,
            "MAX_DECAY": _MAX_DECAY,
        }

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        ends = []
        for i in range(1, SWITCHING_POPULATIONS + 1):
            nodes = slice((i - 1) * SWITCHING_NODES, i * SWITCHING_NODES)
            start = np.full(SWITCHING_NODES, p[f"q{i}"] * p[f"S{i}"]) if s0 is None else np.array(s0[nodes])
            S, up, dn, start = _shares(p, i, start)
            s = switching_states(chain.u, chain.h, S, up, dn, p[f"width{i}"], start)
            s = np.broadcast_to(s, (len(s), SWITCHING_NODES))
            for j in range(SWITCHING_NODES):
                chain.y = chain.y + s[:, j] / SWITCHING_NODES
            ends += s[-1].tolist()
        return tuple(ends)

    def settle(self, p: dict[str, float], chain: Chain, runs: int) -> tuple:
        """`runs` runs from afresh by each share's affine map over the run (`switching_period_map`): the
        switching rates are computed once and no share is stepped from sample to sample."""
        ends = []
        for i in range(1, SWITCHING_POPULATIONS + 1):
            S, up, dn, s = _shares(p, i, np.full(SWITCHING_NODES, p[f"q{i}"] * p[f"S{i}"]))
            if len(chain.h):
                P, c = _period_map(_run(chain.u, chain.h, S, up, dn, p[f"width{i}"]))
                for _ in range(runs):
                    s = P * s + c
            ends += np.broadcast_to(s, SWITCHING_NODES).tolist()
        return tuple(ends)

    def bounds(self, ctx: EffectContext) -> dict[str, tuple[float, float]]:
        """Thresholds within two input ranges of the middle (a threshold is where switching takes one time
        unit; at a time scale far from it the loop switches well inside), widths and spreads from 1e-3 to 1
        input range."""
        out = super().bounds(ctx)
        span = max(ctx.u_span, 1e-300)
        for i in range(1, SWITCHING_POPULATIONS + 1):
            out[f"u_up{i}"] = out[f"u_dn{i}"] = (ctx.u_mid - 2 * span, ctx.u_mid + 2 * span)
            out[f"width{i}"] = out[f"spread{i}"] = (1e-3 * span, span)
        return out

    @staticmethod
    def _population(ctx: EffectContext, i: int, width: float, time: float) -> dict[str, float]:
        """Population i switching a third of the output range from the negative state, of width `width` input
        ranges, its thresholds where switching takes `time` durations at 0.35 input ranges from the middle,
        spread by 5 % of the input range."""
        w = width * ctx.u_span
        shift = w * math.log(max(time * ctx.duration, 1e-300))
        return {
            f"S{i}": (ctx.y_max - ctx.y_min) / 3,
            f"u_up{i}": ctx.u_mid + 0.35 * ctx.u_span + shift,
            f"u_dn{i}": ctx.u_mid - 0.35 * ctx.u_span - shift,
            f"width{i}": w,
            f"q{i}": -0.8,
            f"spread{i}": 0.05 * ctx.u_span,
        }

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        """Population 1 of widths 3 % and 8 % of the input range, switching at its thresholds in a hundredth
        or a tenth of the duration; population 2 at either width, in a hundredth."""
        return [
            {**self._population(ctx, 1, w1, f1), **self._population(ctx, 2, w2, 0.01)}
            for w1 in (0.03, 0.08)
            for f1 in (0.01, 0.1)
            for w2 in (0.03, 0.08)
        ]

    def null(self, ctx: EffectContext) -> dict[str, float]:
        """S1 = S2 = 0: nothing switches."""
        out = {}
        for i in range(1, SWITCHING_POPULATIONS + 1):
            out.update(self._population(ctx, i, 0.05, 0.1), **{f"S{i}": 0.0, f"q{i}": 0.0})
        return out
