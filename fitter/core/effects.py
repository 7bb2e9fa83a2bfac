"""Effect extensions of the semilinear Duhem models (what `duhem diagnose` adds).

An effect is a small, exactly discretised extension with its own parameters,
stored in the model JSON as ``"effects": [{"effect": name, "parameters": {...}}]``
(absent = none).  `kernel.simulate` and `stepper.Stepper` both run the chain
below through `run_with_effects`, so FMUs run it unchanged.

`REGISTRY` is the one list of effects: an `EffectSpec` per effect, in chain
order, that declares its parameters (`ParameterSpec`: allowed range, log
scale), whether it needs time and whether the native C FMU implements it,
applies itself in the chain (`EffectSpec.apply`), and gives the diagnosis its
fitting bounds, starting values and vanishing point (`bounds`, `starts`,
`null`, from an `EffectContext`).  Model validation, the diagnosis, the native
FMU generator and the tests all read it (docs/developer.md, "Adding an effect").

Input semantics are the kernel's: the input u is piecewise linear between the
samples t_0 < t_1 < ... (for a rate-independent model without time, t_k = k).
On interval k (from sample k to k+1): h_k = t_{k+1} - t_k, du_k = u_{k+1} - u_k,
v_k = du_k / h_k (constant on the interval).

The chain, always applied in this order whatever the order of the list:

1. ``backlash`` {b >= 0}: the base model sees the play operator's output
   w_k = min(u_k + b/2, max(u_k - b/2, w_{k-1})), w_0 = u_0, taken piecewise
   linear between samples (exact for a rate-independent base, whose state
   depends only on the path of w; for a rate-dependent base this is the
   specified discretisation).
2. ``rate_dependence`` {alpha >= 0}: the base dynamics are slowed by
   s(v) = 1 / (1 + alpha |v|), v the rate of the base input w on the
   interval: rate-independent base, dx/dt = v s(|v|) (A± x + B± w + E±) (the
   paper's g(du/dt) of eq (18), on top of eqs (1)-(2)); rate-dependent base,
   g(v) becomes g(v) s(v).  Exact, since v is constant per interval: in the
   kernel's interval coefficients (p, r, S) of (K), S -> S s and r -> r / s.
3. Base output y_b = C x + D w.
4. ``creep`` {k, tau > 0}: an extra state dc/dt = (k u - c) / tau, c_0 = k u_0,
   y += c.  Exact for u linear on the interval:
   c_{k+1} = a c_k + k [du_k (1 - q) + (1 - a) u_k], a = e^{-h/tau},
   q = (1 - a) / (h / tau).
5. ``relaxation`` {k, w2, w3, w4 >= 0, tau_min > 0, tau_max > 0}: a spectrum
   of creeps, four states dc_i/dt = (k_i u - c_i) / tau_i, c_i(t_0) = k_i u_0,
   y += sum_i c_i, with k_i = k w_i / (w_1 + ... + w_4), w_1 = 1 (k is the
   relaxed gain, sum k_i; every share w_i / sum w in [0, 1], so the creep
   function sum_i k_i (1 - e^{-t/tau_i}) is monotone, as for a passive
   material) and the tau_i log-spaced from tau_min to tau_max (tau_i = tau_min
   (tau_max / tau_min)^((i - 1) / 3)); each state exact as in 4 (a discrete
   relaxation spectrum, the Prony series of linear viscoelasticity and of
   dielectric relaxation; a long tau_i also takes a leakage current, whose
   charge grows as the integral of u).
6. ``switching`` {S_i >= 0, u_up_i, u_dn_i, width_i > 0, q_i in [-1, 1],
   spread_i >= 0, i = 1, 2}: field-activated switching (nucleation-limited
   switching of a ferroelectric, the thermally activated flips of domains in
   a magnet) of two populations of domains, each with a Gaussian spread of
   coercive inputs (the distribution of domains' switching fields): population
   i is `SWITCHING_NODES` equal shares j, at the normal quantiles z_j =
   Phi^-1((j - 1/2) / N) (`SWITCHING_NODES_Z`), each a switched output
   s_ij in [-S_i, S_i], y += sum_i mean_j s_ij, driven up while u is above
   u_up_i + spread_i z_j and down while it is below u_dn_i - spread_i z_j
   (a share that switches up late switches down late: its loop is wider) at
   rates that grow exponentially with the distance (Merz's law, linearised
   at the threshold)::

       ds/dt = k+(u) (S - s) - k-(u) (S + s),
       k+(u) = e^{(u - u_up)/width},  k-(u) = e^{(u_dn - u)/width}

   per unit of time (the recording's: u_up is the input at which switching up
   takes one time unit, as a coercive field is quoted at a time scale; a
   separate time constant would only shift both thresholds by width ln tau).
   spread_i = 0 (the default of a model saved without it) gives one threshold
   pair per population.  Population 1 with spread 0 is the effect's basic
   form, which `duhem diagnose` tests; population 2 and the spreads are its
   refinements (`ParameterSpec.refinement`; population 2's defaults S_2 = 0
   switch nothing).  s_ij,0 = q_i S_i (the switched fraction the
   experiment starts from).  Unlike the Duhem base, whose state moves only
   while u moves, s moves at a held input (the output keeps rising after the
   input has turned at a tip) and the switched amount depends on the time
   spent beyond a threshold, so a slower loop switches more, and the spread
   of thresholds makes that growth gradual over decades of rate.  Per
   interval, with I+- = integral of k+- dt (closed form for u linear:
   I+ = h e^{(u_k - u_up)/width} (e^d - 1)/d, d = du_k/width; I- likewise):
   s_{k+1} = s_eq + (s_k - s_eq) e^{-(I+ + I-)},
   s_eq = S (I+ - I-)/(I+ + I-) = S tanh((ln I+ - ln I-)/2).  Exact whenever
   one of k+- is negligible on the interval; otherwise s_eq is a weighted
   mean target, with an error of the order of e^{-(u_up - u_dn)/width}
   (1e-8 of S at 20 widths apart; the loops the effect is for are hundreds).
7. ``viscous`` {c}: y += c v, v the rate of u on the interval that ends at the
   sample (0 at the first sample).
8. ``thermal_drift`` {kappa}: y *= 1 - kappa W, W_k = sum_{j<k} |du_j| the
   input travel since the start of the experiment (W_0 = 0).
9. ``saturation`` {y_c, beta >= 0}: y -> y_c + tanh(beta (y - y_c)) / beta
   (beta = 0: unchanged; y_s = 1/beta is the saturation half-range).
10. ``sensor_lag`` {tau >= 0}: the measured output m obeys dm/dt = (y - m)/tau
   with y (the output of steps 3-9) taken linear between samples, m_0 = y_0:
   m_{k+1} = a m_k + dy_k (1 - q) + (1 - a) y_k with a, q as in 4 (tau = 0:
   m = y).  Its state at a sample is (m, y), y the value the next interval
   starts its line from (an output effect such as viscous makes y_k depend
   on the interval); a run of one sample leaves it unchanged.
11. ``measurement_drift`` {rate}: y += d, d_k = d_0 + rate (t_k - t_0), a drift
   of the measured output linear in time (an offset current integrated by a
   charge amplifier, a sensor zero that wanders); d_0 = 0 afresh.  Exact.  d_0
   is the reading's reference (the amplifier's integration constant, the zero
   an instrument gives each record): an initial state fitted to a recording
   (``x0="fit"``) fits d_0 with the base's x_0 (`EffectSpec.offset`).

Each effect says where it comes from (`EffectSpec.origin`): ``material`` (the
physics of the device: steps 1-9) or ``measurement`` (the measuring chain:
sensor_lag, measurement_drift); the diagnosis reports the two apart.

Each step acts in one stage of the chain (`EffectSpec.stage`): ``input``
(the base model's input w, step 1), ``rate`` (the coefficients r, S of (K),
step 2) or ``output`` (the output y, steps 4-11).  The chain's state at a
sample, `EffectState`, is the tuple of the present effects' state variables
(`EffectSpec.state`) in chain order: backlash (w, the play output), creep (c), relaxation (c1..c4), switching
(s1_1..s2_16), thermal_drift (W, the travel), sensor_lag (m, the measured output, and y, the
output before the lag), measurement_drift (d, the drift).

Start of the chain.  A simulation from the first sample starts each effect
afresh (the starts listed with each step) unless the model's effects carry a
stored start (`Effect.start`, the state at the first sample of the recording
the model was fitted on, like the base's x0; all of a model's effects or
none).  `settled_state` is the state a recording of one repeated cycle
starts from: the end state after running its input `SETTLE_RUNS` times
(each run from the previous run's end) for the effects whose state settles
(`EffectSpec.steady`), the afresh start for a drift; a fit uses it for a
recording that is a closed loop.  This module needs only
numpy: it is shipped inside the FMUs.
"""
from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from statistics import NormalDist

import numpy as np

from .errors import EffectError, KernelError
from .flow import check_increasing, integrate, interval_coefficients, linear_recurrence

__all__ = ["play_operator", "REGISTRY", "STAGES", "ORIGINS", "EffectSpec", "ParameterSpec", "EffectContext", "Chain",
           "EffectError", "Effect", "EffectState", "effects_from_list", "run_with_effects", "relaxation_taus",
           "switching_states", "SWITCHING_POPULATIONS", "SWITCHING_NODES",
           "SWITCHING_NODES_Z", "stored_start", "settled_state", "fresh_state", "with_start", "SETTLE_RUNS",
           "offset_position", "shifted"]

EffectState = tuple
"""State of the effect chain at one sample: a tuple of floats (module docstring)."""

STAGES = ("input", "rate", "output")
"""The chain's stages in the order they run (module docstring)."""

ORIGINS = ("material", "measurement")
"""Where an effect comes from: the device's physics or the measuring chain (module docstring)."""

_INF = math.inf


@dataclass(frozen=True)
class ParameterSpec:
    """One effect parameter: allowed range lower <= value <= upper (lower < value when `strict`).

    `log`: a time constant, fitted on a log scale (its fitting bounds are
    relative to the sample period and the duration, see `EffectSpec.bounds`).
    `default`: the value a model file that omits the parameter gets (a parameter added to an effect after
    models were saved; its default gives the effect as it was); None: the parameter is required.
    `refinement`: a parameter that refines the effect's basic form (which it has at `default`).  `duhem
    diagnose` tests the basic form, holding it at `default`; a fit that names the effect (`duhem fit
    --effects`) fits it too (`fitter.identification.parametrisation.WithEffects`).
    """

    name: str
    lower: float
    upper: float
    strict: bool = False
    log: bool = False
    default: float | None = None
    refinement: bool = False

    def allows(self, value: float) -> bool:
        """Whether `value` is finite and in the allowed range."""
        return (math.isfinite(value) and value >= self.lower and value <= self.upper
                and not (self.strict and value <= self.lower))

    def rule(self) -> str:
        """The allowed range in words: "positive", ">= 0", "finite", "> 0 and <= 1", ..."""
        if self.lower == 0 and self.upper == math.inf:
            return "positive" if self.strict else ">= 0"
        low = f"{'>' if self.strict else '>='} {self.lower:g}" if self.lower > -math.inf else ""
        high = f"<= {self.upper:g}" if self.upper < math.inf else ""
        return " and ".join(part for part in (low, high) if part) or "finite"


@dataclass(frozen=True)
class EffectContext:
    """What an effect's fitting bounds, starts and null depend on (one experiment).

    dt_min : shortest median sample period of the recordings
    duration : time span of the experiment
    u_span : input range, max u - min u
    y_min, y_max : output range
    y_mean : mean of the fitted base model's output
    v95 : 95th percentile of |du/dt| (1.0 when that is 0)
    u_mid : middle of the input range, (max u + min u) / 2
    """

    dt_min: float
    duration: float
    u_span: float
    y_min: float
    y_max: float
    y_mean: float
    v95: float
    u_mid: float = 0.0

    @classmethod
    def of(cls, runs: list[tuple[np.ndarray, np.ndarray, np.ndarray]], y_mean: float,
           dt_min: float | None = None) -> "EffectContext":
        """The context of an experiment given as runs (t, u, y), each simulated as one signal: v95 over the
        intervals of every run, the duration the longest run's, `dt_min` (default) the shortest median sample
        period of the runs."""
        rates = np.concatenate([np.diff(u) / np.diff(t) for t, u, _ in runs])
        u = np.concatenate([u for _, u, _ in runs])
        y = np.concatenate([y for _, _, y in runs])
        return cls(dt_min=float(min(np.median(np.diff(t)) for t, _, _ in runs)) if dt_min is None else dt_min,
                   duration=max(float(np.ptp(t)) for t, _, _ in runs), u_span=float(np.ptp(u)),
                   y_min=float(y.min()), y_max=float(y.max()), y_mean=y_mean,
                   v95=float(np.percentile(np.abs(rates), 95)) or 1.0, u_mid=float(u.max() + u.min()) / 2)


@dataclass
class Chain:
    """The samples on their way through the chain (module docstring's notation).

    t, u : the samples; h = diff(t)
    w : the base model's input (the ``input`` stage may change it; else u)
    r, S : per-interval coefficients of the kernel's eq (K) for w (the ``rate`` stage may rescale them)
    y : the output (the ``output`` stage transforms it)
    """

    t: np.ndarray
    u: np.ndarray
    h: np.ndarray
    w: np.ndarray
    r: np.ndarray | None = None
    S: np.ndarray | None = None
    y: np.ndarray | None = None


class EffectSpec(ABC):
    """One effect: what it is, its parameters, how it runs in the chain and how it is fitted.

    Attributes
    ----------
    name : the key in `REGISTRY` and in the model JSON
    description : one line in physical words
    stage : the chain stage it acts in, one of `STAGES`
    timed : needs strictly increasing time (it depends on du/dt or on elapsed time)
    native : the native C FMU implements it (a C function ``effect_<name>`` in duhem_model.c)
    parameters : its parameters, in the order of the model JSON and of the C parameter block
    state : names of its state variables, carried from sample to sample (may be empty)
    example : typical parameter values at which the effect is clearly visible on an input of
        unit amplitude and unit rate (the tests run every effect there; synthetic experiments
        conceal it at these values with `strength` scaled)
    strength : the parameter that sets the effect's size (default: the first one)
    origin : "material" (the device's physics) or "measurement" (the measuring chain), one of `ORIGINS`
    steady : its state settles on a repeated input (a steady cycle, `settled_state`); False for a state that
        accumulates (a drift in time or in travel), which a settled start leaves afresh
    follows_output : its state depends on the output y before it (not on the input and time alone)
    additive : an output effect that adds a term driven by the input and time alone (not by y), so the output
        stays affine in the base's x0 with the base's own coefficients (`fitted_initial_state` uses it)
    offset : the name of a state whose start is added to the output at every sample and does nothing else
        (a reference, `offset_position`): an initial state fitted to a recording fits it with the base's x0
        (`fitter.identification.output_error.fitted_initial_state`); None for every other effect
    searched : `duhem diagnose` tests it by default (`fitter.diagnosis.procedure.CANDIDATES`); an effect that
        can stand in for other physics is tested only when named (``--candidates``) or fitted when named
        (``duhem fit --effects``)
    """

    name: str
    description: str
    stage: str
    timed: bool
    native: bool = True
    parameters: tuple[ParameterSpec, ...]
    state: tuple[str, ...] = ()
    example: dict[str, float]
    strength: str | None = None
    origin: str = "material"
    additive: bool = False
    steady: bool = True
    follows_output: bool = False
    offset: str | None = None
    searched: bool = True

    @property
    def strength_parameter(self) -> str:
        """Name of the parameter that sets the effect's size (`strength`, else the first parameter)."""
        return self.strength or self.parameters[0].name

    @abstractmethod
    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        """Apply the effect with parameters `p` to `chain` in place; return its state at the last sample.

        `s0` is its state at the first sample (`state` values), None to start afresh.
        """

    def bounds(self, ctx: EffectContext) -> dict[str, tuple[float, float]]:
        """Fitting bounds in physical units.

        The allowed range; a `log` parameter (a time constant) within
        [0.05 dt_min, max(duration, 10 dt_min)]: a time constant longer than the experiment cannot be told
        apart from an integrator (a ramp in time), which is a different physics (`measurement_drift`).
        """
        out = {}
        for par in self.parameters:
            if par.log:
                out[par.name] = (ctx.dt_min * 0.05, max(ctx.duration, 10 * ctx.dt_min))
            else:
                out[par.name] = (par.lower, par.upper)
        return out

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        """Starting values in physical units (several for a nonlinear effect); default: the null."""
        return [self.null(ctx)]

    def memory_taus(self, p: dict[str, float]) -> list[float] | None:
        """For an effect whose output is a linear memory of the input started at equilibrium (k times a unit
        response, whose free response from another start is a sum of e^{-(t - t0)/tau_i}): its time
        constants tau_i; None (the default) for every other effect."""
        return None

    def null(self, ctx: EffectContext) -> dict[str, float]:
        """Parameter values at which the effect (almost) vanishes (the nested model); default all 0."""
        return {par.name: 0.0 for par in self.parameters}


def _first_order(m0: float, target: np.ndarray, h: np.ndarray, tau: float) -> np.ndarray:
    """Exact samples of dm/dt = (z(t) - m)/tau, z linear between the samples `target`."""
    x = h / tau
    a = np.exp(-x)
    one_minus_a = -np.expm1(-x)
    q = np.where(x > 0, one_minus_a / np.where(x > 0, x, 1.0), 1.0)
    f = np.diff(target) * (1.0 - q) + one_minus_a * target[:-1]
    out = np.empty_like(target)
    out[0] = m0
    if len(h):
        W = linear_recurrence(np.array([m0]), (-x)[:, None].astype(complex), a[:, None].astype(complex),
                              f[:, None].astype(complex))
        out[1:] = W[:, 0].real
    return out


def play_operator(u: np.ndarray, b: float, w0: float) -> np.ndarray:
    """Play operator of width b, vectorised over monotone runs of u.

    Within a run where u does not fall, w_k = max(w_start, u_k - b/2); where
    it does not rise, w_k = min(w_start, u_k + b/2); equal to the recursion
    of the module docstring.
    """
    h = b / 2
    w = np.empty_like(u)
    w[0] = min(u[0] + h, max(u[0] - h, w0))
    du = np.diff(u)
    sgn = np.sign(du)
    idx = np.where(sgn != 0, np.arange(len(du)), 0)
    np.maximum.accumulate(idx, out=idx)
    sgn = np.where(sgn[idx] == 0, 1.0, sgn[idx])
    cuts = np.r_[0, np.flatnonzero(np.diff(sgn)) + 1, len(du)]
    for s0, s1 in zip(cuts[:-1], cuts[1:]):
        seg = u[s0 + 1:s1 + 1]
        if s1 == s0:
            continue
        if sgn[s0] > 0:
            w[s0 + 1:s1 + 1] = np.maximum(w[s0], seg - h)
        else:
            w[s0 + 1:s1 + 1] = np.minimum(w[s0], seg + h)
    return w


def _taus(ctx: EffectContext) -> np.ndarray:
    """Starting time constants: geomspace(3 dt_min, max(duration / 10, 10 dt_min), 4)."""
    return np.geomspace(3 * ctx.dt_min, max(ctx.duration / 10, 10 * ctx.dt_min), 4)


class Backlash(EffectSpec):
    """Step 1 of the chain (module docstring): the play operator on the base input."""

    name = "backlash"
    description = "mechanical play: the input must travel b across a dead band before the output follows"
    stage = "input"
    timed = False
    parameters = (ParameterSpec("b", 0.0, _INF),)
    state = ("w",)
    example = {"b": 0.1}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        chain.w = play_operator(chain.u, p["b"], chain.u[0] if s0 is None else s0[0])
        return (float(chain.w[-1]),)

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        return [{"b": 0.01 * ctx.u_span}, {"b": 0.05 * ctx.u_span}]


class RateDependence(EffectSpec):
    """Step 2 of the chain: the base dynamics slowed by 1 / (1 + alpha |dw/dt|)."""

    name = "rate_dependence"
    description = "rate-dependent lag: the faster the input moves, the less the loop keeps up"
    stage = "rate"
    timed = True
    parameters = (ParameterSpec("alpha", 0.0, _INF),)
    example = {"alpha": 0.3}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        s = 1.0 / (1.0 + p["alpha"] * np.abs(np.diff(chain.w) / chain.h))
        chain.r, chain.S = chain.r / s, chain.S * s
        return ()

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        return [{"alpha": 0.05 / ctx.v95}, {"alpha": 0.5 / ctx.v95}]


class Creep(EffectSpec):
    """Step 4 of the chain: y += c, dc/dt = (k u - c) / tau."""

    name = "creep"
    description = "creep of the material: a slow first-order approach of the output after input changes"
    stage = "output"
    additive = True
    timed = True
    parameters = (ParameterSpec("k", -_INF, _INF), ParameterSpec("tau", 0.0, _INF, strict=True, log=True))
    state = ("c",)
    example = {"k": 0.05, "tau": 3.0}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        k = p["k"]
        c = _first_order(k * chain.u[0] if s0 is None else s0[0], k * chain.u, chain.h, p["tau"])
        chain.y = chain.y + c
        return (float(c[-1]),)

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        return [{"k": 0.0, "tau": float(tau)} for tau in _taus(ctx)]

    def memory_taus(self, p: dict[str, float]) -> list[float]:
        return [p["tau"]]

    def null(self, ctx: EffectContext) -> dict[str, float]:
        return {"k": 0.0, "tau": 10 * ctx.dt_min}


RELAXATION_TERMS = 4
"""Number of time constants of the `relaxation` spectrum."""


def relaxation_taus(tau_min: float, tau_max: float, m: int = RELAXATION_TERMS) -> np.ndarray:
    """tau_i = tau_min (tau_max / tau_min)^(i / (m - 1)), i = 0..m-1: log-spaced from tau_min to tau_max."""
    return tau_min * (tau_max / tau_min) ** (np.arange(m) / (m - 1))


class Relaxation(EffectSpec):
    """Step 5 of the chain: y += sum_i c_i, dc_i/dt = (k_i u - c_i) / tau_i, tau_i log-spaced (a Prony series)."""

    name = "relaxation"
    description = ("a relaxation spectrum of the material: the output follows input changes through several time "
                   "constants (dielectric or viscoelastic relaxation; the longest also takes a leakage current)")
    stage = "output"
    additive = True
    timed = True
    parameters = (ParameterSpec("k", -_INF, _INF),) + tuple(
        ParameterSpec(f"w{i}", 0.0, _INF) for i in range(2, RELAXATION_TERMS + 1)) + (
        ParameterSpec("tau_min", 0.0, _INF, strict=True, log=True),
        ParameterSpec("tau_max", 0.0, _INF, strict=True, log=True))
    state = tuple(f"c{i + 1}" for i in range(RELAXATION_TERMS))
    example = {"k": 0.08, "w2": 1.0, "w3": 1.0, "w4": 1.0, "tau_min": 0.3, "tau_max": 30.0}

    @staticmethod
    def gains(p: dict[str, float]) -> list[float]:
        """k_i = k w_i / (w_1 + ... + w_m), w_1 = 1."""
        w = [1.0] + [p[f"w{i}"] for i in range(2, RELAXATION_TERMS + 1)]
        total = sum(w)
        return [p["k"] * wi / total for wi in w]

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        ends = []
        for i, (k, tau) in enumerate(zip(self.gains(p), relaxation_taus(p["tau_min"], p["tau_max"]))):
            c = _first_order(k * chain.u[0] if s0 is None else s0[i], k * chain.u, chain.h, float(tau))
            chain.y = chain.y + c
            ends.append(float(c[-1]))
        return tuple(ends)

    def bounds(self, ctx: EffectContext) -> dict[str, tuple[float, float]]:
        """The default bounds, but tau_max up to 10 durations: a time constant beyond the experiment turns its
        state into the integral of u (a leakage current), not a drift in time, so it stays this effect's."""
        out = super().bounds(ctx)
        out["tau_max"] = (out["tau_max"][0], 10 * out["tau_max"][1])
        return out

    def memory_taus(self, p: dict[str, float]) -> list[float]:
        return [float(tau) for tau in relaxation_taus(p["tau_min"], p["tau_max"])]

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        """The null spectrum (3 samples to the duration), and one from a thousandth to a third of the duration."""
        null = self.null(ctx)
        return [null, dict(null, tau_min=null["tau_max"] / 1000, tau_max=null["tau_max"] / 3)]

    def null(self, ctx: EffectContext) -> dict[str, float]:
        """k = 0, equal shares, tau from 3 samples to the duration (at least 30 samples)."""
        return dict({"k": 0.0, **{f"w{i}": 1.0 for i in range(2, RELAXATION_TERMS + 1)}}, tau_min=3 * ctx.dt_min,
                    tau_max=max(ctx.duration, 30 * ctx.dt_min))


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


def switching_states(u: np.ndarray, h: np.ndarray, S: float, u_up, u_dn, width: float, s0) -> np.ndarray:
    """Samples (N, m) of m shares' switched outputs s (module docstring, step 6): thresholds `u_up`, `u_dn`
    and starts `s0` of shape (m,) (or scalars: m = 1)."""
    up, dn = np.atleast_1d(np.asarray(u_up, dtype=float)), np.atleast_1d(np.asarray(u_dn, dtype=float))
    start = np.broadcast_to(np.asarray(s0, dtype=float), up.shape)
    ua, d = u[:-1, None], (np.diff(u) / width)[:, None]
    log_h = np.log(h)[:, None]
    lp = log_h + (ua - up) / width + _log_exprel(d)
    lm = log_h + (dn - ua) / width + _log_exprel(-d)
    big = np.maximum(lp, lm)
    total = np.minimum(np.exp(np.minimum(big, _MAX_EXPONENT)) * (1.0 + np.exp(np.minimum(lp, lm) - big)), _MAX_DECAY)
    target = S * np.tanh((lp - lm) / 2)
    out = np.empty((len(u), len(up)))
    out[0] = start
    if len(h):
        W = linear_recurrence(start, (-total).astype(complex), np.exp(-total).astype(complex),
                              (-np.expm1(-total) * target).astype(complex))
        out[1:] = W.real
    return out


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

    return (spec("S", 0.0, _INF, 0.0), spec("u_up", -_INF, _INF, 0.0), spec("u_dn", -_INF, _INF, 0.0),
            spec("width", 0.0, _INF, 1.0, strict=True, log=True), spec("q", -1.0, 1.0, 0.0),
            ParameterSpec(f"spread{i}", 0.0, _INF, log=True, default=0.0, refinement=True))


class Switching(EffectSpec):
    """Step 6 of the chain: y += sum_i mean_j s_ij, two populations of `SWITCHING_NODES` shares
    ds_ij/dt = k+_ij(u) (S_i - s_ij) - k-_ij(u) (S_i + s_ij), thresholds spread by spread_i z_j."""

    name = "switching"
    description = ("field-activated switching: beyond a threshold input the output switches over in time, at a "
                   "rate growing exponentially with the input (a ferroelectric's domains, Merz's law), so it goes "
                   "on after the input turns and a slower loop switches more")
    stage = "output"
    additive = True
    timed = True
    parameters = tuple(par for i in range(1, SWITCHING_POPULATIONS + 1) for par in _population_parameters(i))
    state = tuple(f"s{i}_{j}" for i in range(1, SWITCHING_POPULATIONS + 1) for j in range(1, SWITCHING_NODES + 1))
    example = {"S1": 0.3, "u_up1": 0.5, "u_dn1": -0.5, "width1": 0.1, "q1": -1.0, "spread1": 0.0,
               "S2": 0.0, "u_up2": 0.8, "u_dn2": -0.8, "width2": 0.05, "q2": -1.0, "spread2": 0.0}
    strength = "S1"
    searched = False
    """Not tested by `duhem diagnose` unless named: with its thresholds just beyond the input's tips it switches
    slowly at every tip, a drift in time, and was named for quadratic and exponential output drifts
    (`bench/diagnose_generality.py`)."""

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        ends = []
        for i in range(1, SWITCHING_POPULATIONS + 1):
            S, shift = p[f"S{i}"], p[f"spread{i}"] * np.array(SWITCHING_NODES_Z)
            nodes = slice((i - 1) * SWITCHING_NODES, i * SWITCHING_NODES)
            start = np.full(SWITCHING_NODES, p[f"q{i}"] * S) if s0 is None else np.array(s0[nodes])
            if not shift.any() and np.all(start == start[0]):
                s = np.repeat(switching_states(chain.u, chain.h, S, p[f"u_up{i}"], p[f"u_dn{i}"], p[f"width{i}"],
                                               start[:1]), SWITCHING_NODES, axis=1)
            else:
                s = switching_states(chain.u, chain.h, S, p[f"u_up{i}"] + shift, p[f"u_dn{i}"] - shift,
                                     p[f"width{i}"], start)
            for j in range(SWITCHING_NODES):
                chain.y = chain.y + s[:, j] / SWITCHING_NODES
            ends += s[-1].tolist()
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
        return {f"S{i}": (ctx.y_max - ctx.y_min) / 3, f"u_up{i}": ctx.u_mid + 0.35 * ctx.u_span + shift,
                f"u_dn{i}": ctx.u_mid - 0.35 * ctx.u_span - shift, f"width{i}": w, f"q{i}": -0.8,
                f"spread{i}": 0.05 * ctx.u_span}

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        """Population 1 of widths 3 % and 8 % of the input range, switching at its thresholds in a hundredth
        or a tenth of the duration; population 2 at either width, in a hundredth."""
        return [{**self._population(ctx, 1, w1, f1), **self._population(ctx, 2, w2, 0.01)}
                for w1 in (0.03, 0.08) for f1 in (0.01, 0.1) for w2 in (0.03, 0.08)]

    def null(self, ctx: EffectContext) -> dict[str, float]:
        """S1 = S2 = 0: nothing switches."""
        out = {}
        for i in range(1, SWITCHING_POPULATIONS + 1):
            out.update(self._population(ctx, i, 0.05, 0.1), **{f"S{i}": 0.0, f"q{i}": 0.0})
        return out

class Viscous(EffectSpec):
    """Step 7 of the chain: y += c du/dt."""

    name = "viscous"
    description = "viscous damping: an output offset proportional to the input rate"
    stage = "output"
    additive = True
    timed = True
    parameters = (ParameterSpec("c", -_INF, _INF),)
    example = {"c": 0.02}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        chain.y = chain.y + p["c"] * np.r_[0.0, np.diff(chain.u) / chain.h]
        return ()


class ThermalDrift(EffectSpec):
    """Step 8 of the chain: y *= 1 - kappa W, W the input travel."""

    name = "thermal_drift"
    description = "thermal drift: the gain changes in proportion to the input travel (self-heating)"
    stage = "output"
    steady = False
    timed = False
    parameters = (ParameterSpec("kappa", -_INF, _INF),)
    state = ("W",)
    example = {"kappa": 0.01}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        W = (0.0 if s0 is None else s0[0]) + np.r_[0.0, np.cumsum(np.abs(np.diff(chain.u)))]
        chain.y = chain.y * (1.0 - p["kappa"] * W)
        return (float(W[-1]),)


class Saturation(EffectSpec):
    """Step 9 of the chain: y -> y_c + tanh(beta (y - y_c)) / beta."""

    name = "saturation"
    description = "saturation: the output flattens smoothly (tanh) away from a centre y_c"
    stage = "output"
    timed = False
    parameters = (ParameterSpec("y_c", -_INF, _INF), ParameterSpec("beta", 0.0, _INF))
    example = {"y_c": 0.0, "beta": 0.4}
    strength = "beta"

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        yc, beta = p["y_c"], p["beta"]
        if beta > 0:
            chain.y = yc + np.tanh(beta * (chain.y - yc)) / beta
        return ()

    def bounds(self, ctx: EffectContext) -> dict[str, tuple[float, float]]:
        return {**super().bounds(ctx), "y_c": (ctx.y_min, ctx.y_max)}

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        half = max(ctx.y_max - ctx.y_min, 1e-300) / 2
        return [{"y_c": ctx.y_mean, "beta": 0.5 / half}, {"y_c": ctx.y_mean, "beta": 1.5 / half}]

    def null(self, ctx: EffectContext) -> dict[str, float]:
        return {"y_c": ctx.y_mean, "beta": 0.0}


class SensorLag(EffectSpec):
    """Step 10 of the chain: the measured output m, dm/dt = (y - m) / tau."""

    name = "sensor_lag"
    description = "sensor lag: the measurement follows the output as a first-order low-pass"
    origin = "measurement"
    stage = "output"
    follows_output = True
    timed = True
    parameters = (ParameterSpec("tau", 0.0, _INF, log=True),)
    state = ("m", "y")
    example = {"tau": 0.05}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        target, tau = chain.y, p["tau"]
        y_last = float(target[-1]) if s0 is None or len(target) > 1 else s0[1]
        if tau > 0:
            if s0 is not None:
                target = target.copy()
                target[0] = s0[1]
            chain.y = _first_order(target[0] if s0 is None else s0[0], target, chain.h, tau)
        return (float(chain.y[-1]), y_last)

    def starts(self, ctx: EffectContext) -> list[dict[str, float]]:
        return [{"tau": float(tau)} for tau in _taus(ctx)[:3]]

    def null(self, ctx: EffectContext) -> dict[str, float]:
        return {"tau": math.exp(math.log(0.05 * ctx.dt_min) + 1e-6)}


class MeasurementDrift(EffectSpec):
    """Step 11 of the chain: y += rate (t - t_0), a measurement drift linear in time."""

    name = "measurement_drift"
    description = ("a measurement drift of the output, linear in time (an offset current integrated by the "
                   "charge amplifier, a wandering sensor zero): a property of the measurement, not of the material")
    origin = "measurement"
    stage = "output"
    steady = False
    additive = True
    offset = "d"
    timed = True
    parameters = (ParameterSpec("rate", -_INF, _INF),)
    state = ("d",)
    example = {"rate": 0.01}

    def apply(self, p: dict[str, float], chain: Chain, s0: tuple | None) -> tuple:
        d = (0.0 if s0 is None else s0[0]) + p["rate"] * (chain.t - chain.t[0])
        chain.y = chain.y + d
        return (float(d[-1]),)


REGISTRY: dict[str, EffectSpec] = {spec.name: spec for spec in (
    Backlash(), RateDependence(), Creep(), Relaxation(), Switching(), Viscous(), ThermalDrift(), Saturation(),
    SensorLag(), MeasurementDrift())}
"""Effect name -> `EffectSpec`, in chain order."""


@dataclass
class Effect:
    """One effect of a model: its name (a key of `REGISTRY`), its parameters and, optionally, its state at the
    first sample (`start`: state name -> value, the names of `EffectSpec.state`; None: afresh)."""

    effect: str
    parameters: dict = field(default_factory=dict)
    start: dict | None = None

    def __post_init__(self):
        spec = REGISTRY.get(self.effect)
        if spec is None:
            raise EffectError(f"unknown effect {self.effect!r} (known: {', '.join(REGISTRY)})")
        names = [par.name for par in spec.parameters]
        if isinstance(self.parameters, dict):
            self.parameters = {**{par.name: par.default for par in spec.parameters
                                  if par.default is not None}, **self.parameters}
        if not isinstance(self.parameters, dict) or set(self.parameters) != set(names):
            got = sorted(self.parameters) if isinstance(self.parameters, dict) else self.parameters
            raise EffectError(f"effect {self.effect!r}: parameters must be {sorted(names)}, got {got}")
        clean = {}
        for par in spec.parameters:
            try:
                value = float(self.parameters[par.name])
            except (TypeError, ValueError):
                raise EffectError(f"effect {self.effect!r}: parameter {par.name} is not a number") from None
            if not par.allows(value):
                raise EffectError(f"effect {self.effect!r}: parameter {par.name} = {value} must be {par.rule()}")
            clean[par.name] = value
        self.parameters = clean
        if self.start is not None:
            self.start = self._clean_start(spec)

    def _clean_start(self, spec: EffectSpec) -> dict[str, float]:
        """`start` checked: a dict of exactly the effect's state names to finite numbers."""
        if not isinstance(self.start, dict) or set(self.start) != set(spec.state):
            got = sorted(self.start) if isinstance(self.start, dict) else self.start
            raise EffectError(f"effect {self.effect!r}: start must give the state {list(spec.state)}, got {got}")
        clean = {}
        for name in spec.state:
            try:
                value = float(self.start[name])
            except (TypeError, ValueError):
                raise EffectError(f"effect {self.effect!r}: start {name} is not a number") from None
            if not math.isfinite(value):
                raise EffectError(f"effect {self.effect!r}: start {name} = {value} must be finite")
            clean[name] = value
        return clean

    @property
    def spec(self) -> EffectSpec:
        return REGISTRY[self.effect]

    def to_dict(self) -> dict:
        out = {"effect": self.effect, "parameters": dict(self.parameters)}
        if self.start is not None:
            out["start"] = dict(self.start)
        return out


def effects_from_list(items) -> list[Effect]:
    """Validate a list of `Effect` or ``{"effect", "parameters"}`` dicts (each name at most once)."""
    if items is None:
        return []
    if not isinstance(items, (list, tuple)):
        raise EffectError(f"expected a list of effects, got {type(items).__name__}")
    out = []
    for item in items:
        if isinstance(item, Effect):
            out.append(Effect(item.effect, dict(item.parameters), None if item.start is None else dict(item.start)))
        elif isinstance(item, dict) and {"effect", "parameters"} <= set(item) <= {"effect", "parameters", "start"}:
            out.append(Effect(item["effect"], item["parameters"], item.get("start")))
        else:
            raise EffectError(f"each effect must be {{'effect': name, 'parameters': {{...}}}} (and optionally "
                              f"'start': {{...}}), got {item!r}")
    names = [e.effect for e in out]
    dup = [n for n in set(names) if names.count(n) > 1]
    if dup:
        raise EffectError(f"effect {dup[0]!r} is listed more than once")
    started = [e.start is not None for e in out if e.spec.state]
    if any(started) and not all(started):
        raise EffectError("a start is given for some effects with a state but not for all (all or none)")
    return out


def _present(model) -> list[tuple[EffectSpec, dict]]:
    """The model's effects as (spec, parameters), in chain order."""
    given = {e.effect: e.parameters for e in model.effects}
    return [(spec, given[name]) for name, spec in REGISTRY.items() if name in given]


def stored_start(model) -> EffectState | None:
    """The chain state at the first sample stored with the model's effects (`Effect.start`), None when they
    start afresh."""
    starts = {e.effect: e.start for e in model.effects}
    if all(starts[spec.name] is None for spec, _ in _present(model) if spec.state):
        return None
    return tuple(starts[spec.name][name] for spec, _ in _present(model) for name in spec.state)


def with_start(model, state: EffectState | None):
    """`model` with its effects' stored start set to the chain state `state` (None: afresh)."""
    parts = _split_state(_present(model), state) if state is not None else {}
    return model.replace(effects=[
        Effect(e.effect, dict(e.parameters),
               dict(zip(e.spec.state, parts[e.effect])) if state is not None else None) for e in model.effects])


def offset_position(model) -> int | None:
    """Position in the chain state (`EffectState`) of the state whose start is added to the output at every
    sample (`EffectSpec.offset`); None when no effect of `model` has one."""
    i = 0
    for spec, _ in _present(model):
        if spec.offset is not None:
            return i + spec.state.index(spec.offset)
        i += len(spec.state)
    return None


def shifted(state: EffectState, position: int, by: float) -> EffectState:
    """The chain state `state` with its value at `position` raised by `by`."""
    return tuple(float(v) + (by if i == position else 0.0) for i, v in enumerate(state))


def fresh_state(model, t: np.ndarray, u: np.ndarray, x0: np.ndarray, fl: dict) -> EffectState:
    """The chain state at the first sample when the chain starts afresh there (the base at `x0`): the
    afresh start as numbers, which a model can store (`with_start`)."""
    return run_with_effects(with_start(model, None), t[:1], model.model_input(u[:1]), x0, fl)[2]


SETTLE_RUNS = 2
"""Runs of a recording's own input that settle the chain state it starts from (`settled_state`)."""


def settled_state(model, t: np.ndarray, u: np.ndarray, x0: np.ndarray, fl: dict) -> EffectState:
    """The chain state a recording of one repeated cycle starts from (module docstring): the state at the
    end of `SETTLE_RUNS` runs of the samples (t, u) (u as the model acts on it, `model_input`), each from the
    previous run's end, the first afresh (whatever the model's stored start), for every `steady` effect; the
    afresh start for the others (a drift starts at its origin).  The base runs from `x0` each time when an
    effect `follows_output`; otherwise the states are driven by the input and time alone and the base is not
    integrated."""
    fresh, w = with_start(model, None), model.model_input(u)
    present = _present(fresh)
    base = any(spec.follows_output for spec, _ in present)
    state = None
    for _ in range(SETTLE_RUNS):
        state = run_with_effects(fresh, t, w, x0, fl, state, base=base)[2]
    if all(spec.steady for spec, _ in present):
        return state
    settled, first = _split_state(present, state), _split_state(present, fresh_state(fresh, t, u, x0, fl))
    return tuple(v for spec, _ in present for v in (settled if spec.steady else first)[spec.name])


def _split_state(present: list, state0: EffectState | None) -> dict[str, tuple | None]:
    """Each present effect's part of the chain state `state0` (None: all start afresh)."""
    if state0 is None:
        return {spec.name: None for spec, _ in present}
    need = sum(len(spec.state) for spec, _ in present)
    if len(state0) != need:
        raise KernelError(f"effect state has {len(state0)} values, the model's effects have {need}")
    out, i = {}, 0
    for spec, _ in present:
        out[spec.name] = tuple(state0[i:i + len(spec.state)])
        i += len(spec.state)
    return out


def run_with_effects(model, t: np.ndarray, u: np.ndarray, x0: np.ndarray, fl: dict,
                     state0: EffectState | None = None, base: bool = True):
    """Simulate `model` with its effects over the samples (t, u).

    The stages run in the order of `STAGES`, the effects of each stage in
    `REGISTRY` order: input effects set the base input w; the kernel's
    interval coefficients of w are rescaled by the rate effects; the base
    model is integrated and y = C x + D w transformed by the output effects.

    Parameters
    ----------
    model : model with a non-empty ``effects`` list
    t, u : finite sample arrays (t strictly increasing where a timed effect is present)
    x0 : base state at the first sample
    fl : the model's flows (`flow.flows`)
    state0 : effect state at the first sample (as returned in `end`); None: the model's stored start
        (`stored_start`), else afresh (w_0 = u_0, c_0 = k u_0, W_0 = 0, m_0 = y_0).
    base : False: the base is not integrated (the output stage starts from y = 0; X is None), for the end
        state of effects none of which `follows_output`.

    Returns
    -------
    X : (N, n) base states, y : (N,) measured outputs, end : `EffectState` at the last sample.
    """
    present = _present(model)
    if any(spec.timed for spec, _ in present):
        check_increasing(t)
    starts = _split_state(present, stored_start(model) if state0 is None else state0)
    chain = Chain(t=t, u=u, h=np.diff(t), w=u)
    ends: dict[str, tuple] = {}
    _run_stage("input", present, chain, starts, ends)
    branch, p, chain.r, chain.S = interval_coefficients(model, t, chain.w)
    _run_stage("rate", present, chain, starts, ends)
    X = integrate(fl, x0, branch, p, chain.r, chain.S) if base else None
    chain.y = X @ model.C + model.D * chain.w if base else np.zeros(len(t))
    _run_stage("output", present, chain, starts, ends)
    end = tuple(value for spec, _ in present for value in ends[spec.name])
    return X, chain.y, end


def _run_stage(stage: str, present: list, chain: Chain, starts: dict, ends: dict) -> None:
    for spec, params in present:
        if spec.stage == stage:
            ends[spec.name] = spec.apply(params, chain, starts[spec.name])
