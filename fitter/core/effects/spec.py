"""The parts every effect is built from: `ParameterSpec`, `EffectContext`, the `Chain` of signals and the
`EffectSpec` base class (the math of the chain: the `fitter.core.effects` docstring).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

EffectState = tuple
"""State of the effect chain at one sample: a tuple of floats (module docstring)."""

STAGES = ("input", "rate", "output")
"""The chain's stages in the order they run (module docstring)."""

ORIGINS = ("material", "measurement")
"""Where an effect comes from: the device's physics or the measuring chain (module docstring)."""

INF = math.inf


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
        return (
            math.isfinite(value)
            and value >= self.lower
            and value <= self.upper
            and not (self.strict and value <= self.lower)
        )

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
    def of(
        cls, runs: list[tuple[np.ndarray, np.ndarray, np.ndarray]], y_mean: float, dt_min: float | None = None
    ) -> "EffectContext":
        """The context of an experiment given as runs (t, u, y), each simulated as one signal: v95 over the
        intervals of every run, the duration the longest run's, `dt_min` (default) the shortest median sample
        period of the runs."""
        rates = np.concatenate([np.diff(u) / np.diff(t) for t, u, _ in runs])
        u = np.concatenate([u for _, u, _ in runs])
        y = np.concatenate([y for _, _, y in runs])
        return cls(
            dt_min=float(min(np.median(np.diff(t)) for t, _, _ in runs)) if dt_min is None else dt_min,
            duration=max(float(np.ptp(t)) for t, _, _ in runs),
            u_span=float(np.ptp(u)),
            y_min=float(y.min()),
            y_max=float(y.max()),
            y_mean=y_mean,
            v95=float(np.percentile(np.abs(rates), 95)) or 1.0,
            u_mid=float(u.max() + u.min()) / 2,
        )


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
    reverses : its output is a state the input drives both ways (domains switching back and forth):
        `duhem diagnose` takes it only when the input drives its fitted state both ways, up from its lowest
        start and down from its highest (`extremes`, `fitter.diagnosis.statistics.reversal_report`), since a
        one-way swing is a drift in time
    loop_shape : a rate-independent change of the loop's shape (a dead band, a flattening): a hysteresis of
        another class than the base's (a Bouc-Wen or Preisach loop) draws such shapes too, so `duhem diagnose`
        claims it as the material's only when the extended model reaches the noise (a partial finding of it
        is reported as the loop's shape, `fitter.diagnosis.procedure`)
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
    reverses: bool = False
    loop_shape: bool = False
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

    def settle(self, p: dict[str, float], chain: Chain, runs: int) -> tuple | None:
        """Its state after `runs` runs of the chain's samples, the first from afresh and each from the previous
        run's end (`settled_state`), computed without running them; None (the default): run them.

        Only for a `steady` effect whose state is driven by the chain's t, u and h alone (not by w, r, S or y).
        """
        return None

    def afresh(self, p: dict[str, float]) -> tuple | None:
        """Its state at the first sample when it starts afresh, where that does not depend on the chain's signals
        (a drift's origin), as `apply` gives it; None (the default): `settled_state` runs the chain on the first
        sample for it (`fresh_state`).  Only for an effect that is not `steady` (a steady one settles)."""
        return None

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

    def extremes(self, p: dict[str, float]) -> tuple[dict[str, float], dict[str, float]]:
        """For a reversing effect (`reverses`): `p` with its state started at its lowest, and at its highest
        (`fitter.diagnosis.statistics.reversal_report` drives it up from the one and down from the other)."""
        raise NotImplementedError(f"{self.name} does not reverse: it has no extreme states")

    def c_constants(self) -> dict[str, int | float | tuple[float, ...]]:
        """Fixed numbers of the effect's C twin (``effect_<name>`` in duhem_model.c), written into the native FMU's
        generated header as ``DUHEM_<NAME>_<KEY>`` (a tuple as a C initializer list), so that the C reads the
        numbers this class computes with; default none."""
        return {}

    def null(self, ctx: EffectContext) -> dict[str, float]:
        """Parameter values at which the effect (almost) vanishes (the nested model); default all 0."""
        return {par.name: 0.0 for par in self.parameters}
