"""A model's effects (`Effect`), their states at the first sample, and the run of the chain
(`run_with_effects`; the `fitter.core.effects` docstring).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import EffectError, KernelError
from ..flow import check_increasing, integrate, interval_coefficients
from .catalogue import REGISTRY
from .spec import Chain, EffectSpec, EffectState


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
            self.parameters = {
                **{par.name: par.default for par in spec.parameters if par.default is not None},
                **self.parameters,
            }
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
            raise EffectError(
                f"each effect must be {{'effect': name, 'parameters': {{...}}}} (and optionally "
                f"'start': {{...}}), got {item!r}"
            )
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
    """`model` with its effects' stored start set to the chain state `state` (None: afresh); `model` itself when
    its effects already start afresh and `state` is None (models are immutable)."""
    if state is None and all(e.start is None for e in model.effects):
        return model
    parts = _split_state(_present(model), state) if state is not None else {}
    return model.replace(
        effects=[
            Effect(
                e.effect, dict(e.parameters), dict(zip(e.spec.state, parts[e.effect])) if state is not None else None
            )
            for e in model.effects
        ]
    )


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
    """The chain state at the first sample when the chain starts afresh there (the base at `x0`, integrated only
    when an effect `follows_output`): the afresh start as numbers, which a model can store (`with_start`)."""
    fresh = with_start(model, None)
    base = any(spec.follows_output for spec, _ in _present(fresh))
    return run_with_effects(fresh, t[:1], model.model_input(u[:1]), x0, fl, base=base)[2]


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
    settled = _settled_in_closed_form(present, t, w)
    if settled is None:
        base, state = any(spec.follows_output for spec, _ in present), None
        for _ in range(SETTLE_RUNS):
            state = run_with_effects(fresh, t, w, x0, fl, state, base=base)[2]
        if all(spec.steady for spec, _ in present):
            return state
        settled = _split_state(present, state)
    if all(spec.steady for spec, _ in present):
        return tuple(v for spec, _ in present for v in settled[spec.name])
    first = _afresh(present) or _split_state(present, fresh_state(fresh, t, u, x0, fl))
    return tuple(v for spec, _ in present for v in (settled if spec.steady else first)[spec.name])


def _afresh(present: list) -> dict[str, tuple] | None:
    """Each effect's afresh start that is not `steady`, from its own `EffectSpec.afresh`, or None unless every
    such effect has one (then the chain is run on the first sample instead: the same numbers, measured at 7 % of
    piezo.best's time)."""
    out = {spec.name: spec.afresh(params) for spec, params in present if not spec.steady}
    return None if any(v is None for v in out.values()) else out


def _settled_in_closed_form(present: list, t: np.ndarray, w: np.ndarray) -> dict[str, tuple | None] | None:
    """Each steady effect's settled state from its own `EffectSpec.settle` (the others' None), or None unless
    every steady effect has one."""
    if any(spec.timed for spec, _ in present):
        check_increasing(t)
    chain, out = Chain(t=t, u=w, h=np.diff(t), w=w), {}
    for spec, params in present:
        out[spec.name] = spec.settle(params, chain, SETTLE_RUNS) if spec.steady else None
        if spec.steady and out[spec.name] is None:
            return None
    return out


def _split_state(present: list, state0: EffectState | None) -> dict[str, tuple | None]:
    """Each present effect's part of the chain state `state0` (None: all start afresh)."""
    if state0 is None:
        return {spec.name: None for spec, _ in present}
    need = sum(len(spec.state) for spec, _ in present)
    if len(state0) != need:
        raise KernelError(f"effect state has {len(state0)} values, the model's effects have {need}")
    out, i = {}, 0
    for spec, _ in present:
        out[spec.name] = tuple(state0[i : i + len(spec.state)])
        i += len(spec.state)
    return out


def run_with_effects(
    model, t: np.ndarray, u: np.ndarray, x0: np.ndarray, fl: dict, state0: EffectState | None = None, base: bool = True
):
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
    chain.y = model.output(X, chain.w) if base else np.zeros(len(t))
    _run_stage("output", present, chain, starts, ends)
    end = tuple(value for spec, _ in present for value in ends[spec.name])
    return X, chain.y, end


def _run_stage(stage: str, present: list, chain: Chain, starts: dict, ends: dict) -> None:
    for spec, params in present:
        if spec.stage == stage:
            ends[spec.name] = spec.apply(params, chain, starts[spec.name])
