"""The output-error problem on recordings.

A problem of `fitter.identification.refine.refine` (the one least-squares fitter): the residuals of a
model on recordings, with its initial states, effect starts, variable projection and decimation.

Problems
--------
A problem turns (param, theta) into a residual vector.  `Recordings` is the
general one (below); `fitter.identification.rd_triangles` defines the
periodic triangle-wave problem of Section V.  Samples of weight 0 are left out
of the objective (a mask), but their residuals are reported.

Initial state (``Recordings.x0``)
---------------------------------
The simulated state is affine in its initial value, x_k = Phi_k x_0 + c_k
(`fitter.core.periodic.affine_response`):

* ``"model"``: x_0 = build(theta).x0 for every recording (x0 may be part of
  theta, e.g. `StateSpace`), all samples fitted.
* ``"fit"``: x_0 of each recording is eliminated by linear least squares over
  all its samples: x_0 = argmin ||y - C Phi x_0 - C c - D u|| (Phi and c from
  one pass of the kernel with n + 1 initial states).
* ``"periodic"``: each recording is fitted from the start s0 of its first
  settled cycle (samples before s0 are dropped) from the fixed point of the
  cycle's affine map (Theorem 1, `fitter.core.periodic.fixed_point`); when
  rho >= 1 the model's x0 is used and ``RefineResult.rho`` says so.  Cycles
  come from `fitter.data.preparation` unless given.

A model's effect chain (`fitter.core.effects`) starts from the effects' stored
start, else afresh; with ``Recordings.settle`` from its state settled on each
recording (`fitter.core.effects.settled_state`), the effects' counterpart of
``"periodic"`` for recordings of one cycle each.

Variable projection (``Options.eliminate``)
-------------------------------------------
For a fixed A (and g), the states are linear in the forcing vectors B, E and
in x_0, and y = C x + D u is linear in D: with theta = (eta, theta_L), theta_L
the entries listed by `Parametrisation.linear_entries`,

    yhat_i = b_i(eta) + Psi_i(eta) theta_L + G_i(eta) x0_i,

where the columns of Psi are the responses to unit forcing vectors, b the
response to the remaining forcing and G the responses to unit initial states,
all from one pass of the kernel (`fitter.core.flow.integrate` takes several
initial states and forcings at once).  theta_L (shared by the recordings) and,
for ``"fit"``, each x0_i are the weighted linear least-squares solution; the
optimiser moves eta only (Golub & Pereyra's variable projection).  For
``"periodic"`` every column carries its own fixed point of the cycle map, so
the periodic state stays linear in theta_L.  A model whose effects are all
`additive` (its output the base's plus terms of the input and time alone) is
eliminated too, with ``"fit"``: the terms join b_i (the chain from its settled
state with ``settle``), and a recording whose effects carry the output's
reference (not the reference's owner) gets a column of ones for it, as
`fitted_initial_state` fits it.  Other effects may make the output nonlinear
in B or E: `WithEffects.linear_entries` is then empty.  The linear algebra is
in `fitter.identification.projection`.

Failure policy
--------------
A theta whose model cannot be built or simulated, or whose simulation leaves
1e6 output ranges, gives every residual of that recording the value
`FAIL` x (output range): a huge but finite cost, so the optimiser backs off.

Decimation
----------
Recordings longer than ``Options.max_samples`` (M) are decimated for the
optimisation: every turning point of the input (the last sample before its
direction changes; of an input that turns every few samples, a noisy one,
those of reversals above its noise: `fitter.identification.decimation`) is
kept, and every j-th sample, j = ceil(N / M); only the
every-j-th samples are scored (the turning points get weight 0).  Between
kept samples the input is monotone, so a rate-independent model's state at
the kept samples is exact (Proposition 1: its output depends on the path of
u only) at any length and for any number of reversals, and the scored
samples are spread evenly along the branches, as densely as in a short
recording.  (Keeping only each block's extremes loses the reversals inside a
block: a rate-independent model's state then follows another path than the
device's, and a long recording of many small loops was fitted 30x worse than
its first tenth.)  A rate-dependent model's state between kept samples is
integrated with the input interpolated linearly between them, an
approximation for the search only.  Final residuals are on all samples.
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from fitter.core.effects import fresh_state, offset_position, run_with_effects, settled_state, shifted, stored_start
from fitter.core.errors import DuhemError, KernelError
from fitter.core.kernel import flows, simulate
from fitter.core.periodic import affine_blocks, fixed_point
from fitter.core.scans import modal_pass
from fitter.data.preparation import prepare
from fitter.data.recordings import Recording
from fitter.identification.decimation import keep_indices
from fitter.identification.parametrisation import Parametrisation
from fitter.identification.projection import (
    LinearPart,
    lstsq_scaled,
    response_columns,
    response_columns_all,
    scaled,
    solve_shared,
    split_solution,
    with_reference,
)

__all__ = ["Recordings", "divided", "simulate_from", "fitted_initial_state", "shared_initial_state", "X0_MODES", "FAIL"]

X0_MODES = ("model", "fit", "periodic")
FAIL = 1e3
"""Residual, in output ranges, of a recording whose simulation fails."""


# ----------------------------------------------------------------------------- initial states
def fitted_initial_state(
    model,
    t,
    u,
    y,
    cache: dict | None = None,
    effect_state=None,
    reference: bool = True,
    constant: bool = False,
    memo: dict | None = None,
):
    """Initial state x_0 = argmin ||y - yhat(0) - G x_0|| over all samples, the output from it and the
    effect chain state it starts from (module docstring, ``"fit"``): yhat is affine in x_0, G its columns.
    A model with effects is simulated once per unit initial state (its output is y = C x + D w after its
    input stage, not D u), its chain from `effect_state` (default: `simulate`'s); once, with G the
    base's, when every effect is `additive`.  An effect state that is the output's reference
    (`fitter.core.effects.offset_position`: it adds its start to every sample) is fitted with x_0 when
    `reference`, a column of ones in G; the state returned then has it (numbers; else `effect_state` as
    given).  With `constant` (and `reference`), a model whose effects carry no reference gets one too: the
    column of ones is fitted and its value is part of yhat only (the instrument's zero of this recording,
    not a state of the model).  With additive effects, y(x_0) = yhat_base(x_0) + (the effects' terms): the two
    parts are kept in `memo` (a dict per recording, `_remembered`) and reused while their parameters repeat.
    Raises `KernelError` when the simulation overflows."""
    n = model.order
    if _all_additive(model):
        ybare, G = _remembered(
            memo, "base", _base_key(model), lambda: _affine_output(model.replace(effects=[]), t, u, cache)
        )
        base = ybare + _terms(model, t, u, effect_state, memo)
    elif getattr(model, "effects", None):
        ys = [
            simulate(model, t, u, x0=x, flow_cache=cache, effect_state=effect_state).y
            for x in np.hstack([np.zeros((n, 1)), np.eye(n)]).T
        ]
        base, G = ys[0], np.column_stack(ys[1:]) - ys[0][:, None]
    else:
        base, G = _affine_output(model, t, u, cache)
    position = offset_position(model) if reference and getattr(model, "effects", None) else None
    alone = reference and constant and position is None
    if position is not None or alone:
        G = np.column_stack([G, np.ones(len(base))])
    if not (np.all(np.isfinite(G)) and np.all(np.isfinite(base))):
        raise KernelError("simulation overflowed")
    z = lstsq_scaled(G, y - base)
    if alone:
        return z[:n], base + G @ z, effect_state
    if position is None:
        return z, base + G @ z, effect_state
    x0 = z[:n]
    start = effect_state if effect_state is not None else stored_start(model)
    start = fresh_state(model, t, u, x0, flows(model) if cache is None else cache) if start is None else start
    return x0, base + G @ z, shifted(start, position, float(z[n]))


def shared_initial_state(
    model, runs: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], references: Sequence[bool] | None = None
) -> tuple[np.ndarray, float, list[float]]:
    """One initial state for several runs (t, u, y) of a model without effects: x_0 = argmin sum over the runs
    and their samples of ||y - yhat(x_0) - r||^2, yhat = base + G x_0 on each (`_affine_output`, the runs
    stacked), r a constant of each run whose `references` entry is true (the zero of the instrument that wrote
    it; 0 for the others), fitted with x_0.  Returns x_0, that sum at the solution and the runs' r.  Raises
    `KernelError` when a simulation overflows."""
    cache = flows(model)
    parts = [_affine_output(model, t, u, cache) for t, u, _ in runs]
    refs = [bool(r) for r in (references or [False] * len(runs))]
    n, k = model.order, sum(refs)
    G = np.zeros((sum(len(y) for _, _, y in runs), n + k))
    at, col = 0, n
    for (_, g), ref in zip(parts, refs):
        G[at : at + len(g), :n] = g
        if ref:
            G[at : at + len(g), col] = 1.0
            col += 1
        at += len(g)
    r = np.concatenate([y - base for (base, _), (_, _, y) in zip(parts, runs)])
    if not (np.all(np.isfinite(G)) and np.all(np.isfinite(r))):
        raise KernelError("simulation overflowed")
    z = lstsq_scaled(G, r)
    offsets = iter(z[n:].tolist())
    return z[:n], float(np.sum((r - G @ z) ** 2)), [next(offsets) if ref else 0.0 for ref in refs]


def _affine_output(model, t, u, cache: dict | None) -> tuple[np.ndarray, np.ndarray]:
    """Output of a model without effects as an affine function of x_0: yhat = base + G x_0, with
    base_k = C c_k + D u_k and G_k = C Phi_k (`fitter.core.periodic.affine_blocks`, reduced to (N,) and
    (N, n) piece by piece)."""
    k = 0
    base, G = np.empty(len(u)), np.empty((len(u), model.order))
    for c, Phi in affine_blocks(model, t, u, cache):
        G[k : k + len(c)] = np.einsum("j,kjl->kl", model.C, Phi)
        base[k : k + len(c)] = c @ model.C
        k += len(c)
    base += model.D * model.model_input(np.asarray(u, dtype=float))
    return base, G


def _flows(model, memo: dict | None) -> dict:
    """The model's flows (`fitter.core.kernel.flows`), kept in `memo` under its base's parameters."""
    return flows(model) if memo is None else _remembered(memo, "flows", _base_key(model), lambda: flows(model))


def _settled(model, t, u, cache: dict, memo: dict | None):
    """`settled_state` of the model's chain on the recording; kept in `memo` when no effect follows the output
    (the settled state then depends on the effects alone)."""
    if memo is None or any(e.spec.follows_output for e in model.effects):
        return settled_state(model, t, u, model.x0, cache)
    return _remembered(memo, "settled", _effects_key(model, None), lambda: settled_state(model, t, u, model.x0, cache))


def _model_output(model, t, u, cache: dict, effect_state, memo: dict | None) -> np.ndarray:
    """The model's output from its own x0 (``"model"``): with additive effects, the base's output plus the
    effects' terms, each kept in `memo`."""
    if memo is None or not _all_additive(model):
        return simulate(model, t, u, flow_cache=cache, effect_state=effect_state).y
    key = (*_base_key(model), np.asarray(model.x0, dtype=float).tobytes())
    ybare = _remembered(
        memo, "base_from_x0", key, lambda: simulate(model.replace(effects=[]), t, u, flow_cache=cache).y
    )
    return ybare + _terms(model, t, u, effect_state, memo)


def _all_additive(model) -> bool:
    """Whether the model has effects and every one is additive (`EffectSpec.additive`)."""
    return bool(getattr(model, "effects", None)) and all(e.spec.additive for e in model.effects)


def _terms(model, t, u, effect_state, memo: dict | None) -> np.ndarray:
    """`_additive_terms`, kept in `memo` under the effects' parameters and start."""
    key = _effects_key(model, effect_state)
    return _remembered(memo, "effects", key, lambda: _additive_terms(model, t, u, effect_state))


def _additive_terms(model, t, u, effect_state) -> np.ndarray:
    """The sum of the terms a model's additive effects add to its output (`EffectSpec.additive`: driven by the
    input and time alone), from the chain state `effect_state` (None: the stored start, else afresh): the
    chain run without its base (`run_with_effects`, ``base=False``)."""
    w = model.model_input(np.asarray(u, dtype=float))
    return run_with_effects(model, t, w, np.zeros(model.order), {}, effect_state, base=False)[1]


MEMO_SIZE = 3
"""Parts kept per kind in a recording's memo: a finite-difference Jacobian moves one parameter at a time from
the point it differentiates at, so the base's part repeats over the effects' columns and the effects' part over
the base's columns, and the point itself is asked for again between them."""


def _remembered(memo: dict | None, kind: str, key: tuple, compute):
    """compute(), or its value kept in `memo` under (`kind`, `key`, the kernel's modal pass in effect) (the last
    `MEMO_SIZE` per kind).  The pass is part of the key because the compiled and the numpy pass round
    differently (`fitter.core.scans`): an effect fit's evaluations run compiled and its final residuals do not,
    and without it a value kept from an evaluation was reused there, so that the fit's last digits depended on
    which thetas this process had evaluated (on two processes, measured on the piezo triangles: 1e-9)."""
    if memo is None:
        return compute()
    key = (*key, modal_pass())
    kept = memo.setdefault(kind, {})
    if key not in kept:
        if len(kept) >= MEMO_SIZE:
            del kept[next(iter(kept))]
        kept[key] = compute()
        for a in kept[key] if isinstance(kept[key], tuple) else (kept[key],):
            if isinstance(a, np.ndarray):
                a.flags.writeable = False  # shared between evaluations: a caller may not change it
    return kept[key]


def _base_key(model) -> tuple:
    """What the simulation of a model's base (its effects left out) depends on besides (t, u, x_0): its class,
    its parameters but x0 (exact bytes), its rate function and input range."""
    arrays = b"".join(np.asarray(getattr(model, k), dtype=float).tobytes() for k in model.PARAMS if k != "x0")
    g = getattr(model, "g", None)
    return type(model).__name__, arrays, None if g is None else _exact(g.to_dict()), model.input_range


def _effects_key(model, effect_state) -> tuple:
    """What the effects' terms depend on besides (t, u): each effect's parameters and stored start, the chain
    state given, the input range."""
    return _exact([e.to_dict() for e in model.effects]), _exact(effect_state), model.input_range


def _exact(value) -> bytes:
    """A memo key part that determines `value` to the last bit (its pickle: every float and array entry exact;
    ``repr`` rounds an array to 8 digits and took 0.25 ms for a rate table, 3 % of piezo.best's time)."""
    return pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)


def simulate_from(
    model,
    t,
    u,
    y,
    mode: str,
    cycle: tuple[int, int] | None,
    settle: bool = False,
    reference: bool = True,
    constant: bool = False,
    memo: dict | None = None,
):
    """Simulate one recording under an initial-state mode (module docstring); with `settle`, a model's
    effect chain starts from its state settled on the recording (``Recordings.settle``); with `reference`
    (``"fit"`` only), the output's reference is fitted with x0 (`fitted_initial_state`; with `constant`
    also for a model whose effects carry none).  `memo`: the recording's memo of parts that repeat between
    evaluations (`_remembered`; None: none kept).

    Returns (start, x0, yhat, rho, effect state): yhat covers samples start..end; the effect chain's state at
    the first sample where it is not the model's own start (settled, or with a fitted reference,
    `fitted_initial_state`), else None.
    """
    cache = _flows(model, memo)
    state = _settled(model, t, u, cache, memo) if settle and getattr(model, "effects", None) else None
    if mode == "model":
        return 0, np.array(model.x0, dtype=float), _model_output(model, t, u, cache, state, memo), np.nan, state
    if mode == "fit":
        x0, yhat, state = fitted_initial_state(model, t, u, y, cache, state, reference, constant, memo)
        return 0, x0, yhat, np.nan, state
    if mode != "periodic":
        raise ValueError(f"x0 must be one of {X0_MODES}, not {mode!r}")
    s0, s1 = cycle
    x0, rho = fixed_point(model, t[s0 : s1 + 1], u[s0 : s1 + 1], cache)
    x0 = np.array(model.x0, dtype=float) if x0 is None else x0
    return s0, x0, simulate(model, t[s0:], u[s0:], x0=x0, flow_cache=cache).y, rho, None


# ----------------------------------------------------------------------------- the recordings problem
def _first_cycle(rec: Recording) -> tuple[int, int]:
    """(s0, s1) of the first settled cycle of `rec`, in its own sample index."""
    prep = prepare(rec, min_cycles=0)
    s0, s1 = prep.first_cycle()
    return s0 + prep.transient_end, s1 + prep.transient_end


@dataclass
class Recordings:
    """Recordings fitted by output error, with their initial-state mode, weights and cycles.

    weights: per-recording scalars or per-sample arrays (default 1; 0 = masked).
    cycles: for x0 = "periodic", the (s0, s1) sample indices of each recording's first settled cycle; by default
    `fitter.data.preparation.prepare(rec).first_cycle()` for "periodic".
    settle: per recording, whether a model's effect chain starts it from its state settled on it
    (`fitter.core.effects.settled_state`: the recording taken as one cycle of a periodic experiment, as
    ``"periodic"`` takes the base); default None (none): from the effects' stored start, else afresh.
    references: with ``"fit"``, every recording but the first (`_reference_owner`) has its own output
    reference (the zero of the instrument that wrote it, a constant added to its output) fitted with its x0
    even when no effect of the model carries one (`fitted_initial_state`'s ``constant``); default False.
    starts: with ``"fit"``, a group index per recording: the recordings of one group share one initial state,
    fitted by least squares over all their samples (`shared_initial_state`; runs of a device reset to one state
    that start at one input), for a model without effects; default None (each recording its own).

    With ``"fit"``, the output's reference of an effect that has one (`fitted_initial_state`) is fitted for
    every recording but the first, whose reference is the model's own: the base carries a constant output
    offset exactly (x -> x + delta with E -> E - A delta, for each branch's A and E), so a reference fitted on
    every recording would trade against the base's forcing along a flat direction of the fit; the others'
    are fitted relative to the first.
    """

    recordings: Sequence[Recording]
    x0: str = "periodic"
    weights: Sequence | None = None
    cycles: Sequence[tuple[int, int] | None] | None = None
    settle: Sequence[bool] | None = None
    references: bool = False
    starts: Sequence[int] | None = None

    def __post_init__(self):
        if self.x0 not in X0_MODES:
            raise ValueError(f"x0 must be one of {X0_MODES}, not {self.x0!r}")
        if not self.recordings:
            raise DuhemError("output-error fit needs at least one recording")
        if self.cycles is None:
            self.cycles = [_first_cycle(rec) if self.x0 == "periodic" else None for rec in self.recordings]
        w = [None] * len(self.recordings) if self.weights is None else self.weights
        self._w = [
            np.broadcast_to(1.0 if wi is None else np.asarray(wi, dtype=float), r.u.shape)
            for r, wi in zip(self.recordings, w)
        ]
        self.scale = max(float(np.ptp(np.concatenate([r.y for r in self.recordings]))), 1e-300)
        self._settle = [False] * len(self.recordings) if self.settle is None else [bool(s) for s in self.settle]
        self._memos = [{} for _ in self.recordings]

    def _kept(self, max_samples: int | None) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per recording, `keep_indices`; a recording whose effect chain starts settled on it keeps every
        sample (its settled state is that of the whole recording taken as one cycle)."""
        return [
            keep_indices(r.u, None if settle else max_samples, c)
            for r, c, settle in zip(self.recordings, self.cycles, self._settle)
        ]

    def decimated(self, max_samples: int | None) -> "Recordings":
        """The problem on the kept samples of `keep_indices` (self when nothing is dropped; `_kept`)."""
        kept = self._kept(max_samples)
        if all(len(k) == len(r.u) for (k, _), r in zip(kept, self.recordings)):
            return self
        keeps = [k for k, _ in kept]
        weights = [np.where(scored, w[k], 0.0) for w, (k, scored) in zip(self._w, kept)]
        recs = [
            Recording(r.t[k], r.u[k], r.y[k], r.name, r.input, r.output, r.source)
            for r, k in zip(self.recordings, keeps)
        ]
        cycles = [
            None if c is None else tuple(int(i) for i in np.searchsorted(k, c)) for c, k in zip(self.cycles, keeps)
        ]
        return Recordings(
            recs, self.x0, weights, cycles, settle=self._settle, references=self.references, starts=self.starts
        )

    def rows(self, max_samples: int | None) -> list[np.ndarray]:
        """Per recording, the indices of its samples that are the rows of ``decimated(max_samples).residuals``
        (and of a Jacobian `refine` takes on them): kept, scored, of positive weight, from the start."""
        out = []
        for w, cyc, (keep, scored) in zip(self._w, self.cycles, self._kept(max_samples)):
            start = int(np.searchsorted(keep, cyc[0])) if self.x0 == "periodic" and cyc is not None else 0
            out.append(keep[start:][(np.where(scored, w[keep], 0.0) > 0)[start:]])
        return out

    def residuals(self, param: Parametrisation, theta: np.ndarray):
        """Stacked weighted residuals sqrt(w) (y - yhat) of the unmasked samples, and per
        recording (start, x0, y - yhat from start, rho, effect state: `simulate_from`)."""
        try:
            model = param.build(theta)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError):
            model = None
        parts, info = [], []
        owner = self._reference_owner()
        gains = self._gains(model)
        frame = [divided(r, g) for r, g in zip(self.recordings, gains)]
        shared = self._shared_starts(model, frame)
        for i, (rec, w, cyc, settle) in enumerate(zip(frame, self._w, self.cycles, self._settle)):
            start = None if shared is None else shared.get(i)
            s, x0, r, rho, state = self._one(model, rec, cyc, settle, i != owner, self._memos[i], start)
            parts.append(_weighted(gains[i] * r, w[s:]))
            info.append((s, x0, gains[i] * r, rho, state))
        return (parts[0] if len(parts) == 1 else np.concatenate(parts)), model, info

    def projected(self, param: Parametrisation, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Variable projection (module docstring): the weighted residuals of `residuals` with the linear entries
        of theta (and x0 for ``"fit"``, and the output's references of a model whose additive effects carry one)
        at their weighted least-squares values, and theta with those values."""
        lin = param.linear_entries()
        try:
            model = param.build(theta)
            with np.errstate(all="ignore"):
                fl = flows(model)
                parts = self._linear_parts(model, lin, fl)
            parts = [scaled(p, g) for p, g in zip(parts, self._gains(model))]
            groups, refs = self._groups(model), self._reference_columns(model)
            solution = solve_shared(parts, [r.y for r in self.recordings], self._w, groups, refs)
        except (DuhemError, ValueError, np.linalg.LinAlgError, FloatingPointError):
            info = [self._one(None, rec, cyc) for rec, cyc in zip(self.recordings, self.cycles)]
            return np.concatenate([_weighted(i[2], w[i[0] :]) for i, w in zip(info, self._w)]), np.array(theta)
        theta_l, own = split_solution(parts, solution, groups, refs)
        if refs:
            parts = [with_reference(p) if r else p for p, r in zip(parts, refs)]
        theta = np.array(theta, dtype=float)
        theta[list(lin)] = theta_l
        weighted = [
            _weighted(rec.y[part.start :] - part.output(theta_l, z), w[part.start :])
            for rec, w, part, z in zip(self.recordings, self._w, parts, own)
        ]
        return np.concatenate(weighted), theta

    def _linear_parts(self, model, lin: dict[int, tuple[str, int]], fl: dict) -> list[LinearPart]:
        """Every recording's `LinearPart`: a model without effects, its columns on all recordings at once
        (`response_columns_all`); with effects, recording by recording (`_linear_part`).  `fl`: the model's
        flows, shared by the recordings."""
        if getattr(model, "effects", None):
            return [self._linear_part(model, lin, i, fl) for i in range(len(self.recordings))]
        recs = self.recordings
        return response_columns_all(model, lin, [r.t for r in recs], [r.u for r in recs], self.x0, self.cycles, fl)

    def _linear_part(self, model, lin: dict[int, tuple[str, int]], i: int, fl: dict) -> LinearPart:
        """Recording i's `LinearPart` for a model with effects, every one `additive` (``"fit"`` only): the base's
        columns (`response_columns`), the effects' terms added to its base (from the chain state settled on it
        with ``settle``) and, where one carries the output's reference and the recording is not the reference's
        owner, a column of ones (`fitted_initial_state`).  The base's columns are kept in the recording's
        memo under the base's parameters (the optimiser holds the linear entries of the theta it moves, so they
        repeat while only the effects' parameters move).  `fl`: the model's flows, shared by the recordings."""
        rec, memo = self.recordings[i], self._memos[i]
        if self.x0 != "fit" or not _all_additive(model):
            raise DuhemError("variable projection needs x0 'fit' and additive effects")
        w = model.model_input(np.asarray(rec.u, dtype=float))
        part = _remembered(
            memo,
            "columns",
            _base_key(model),
            lambda: response_columns(model.replace(effects=[]), lin, rec.t, w, "fit", None, fl),
        )
        state = _settled(model, rec.t, rec.u, fl, memo) if self._settle[i] else None
        terms = _terms(model, rec.t, rec.u, state, memo)
        own = part.Own
        if i != self._reference_owner() and (self.references or offset_position(model) is not None):
            own = np.column_stack([own, np.ones(len(terms))])
        return replace(part, base=part.base + terms, Own=own)

    def _groups(self, model) -> Sequence[int] | None:
        """The recordings' start groups (``starts``) where they apply: x0 ``"fit"``, a model without effects."""
        if self.starts is None or self.x0 != "fit" or model is None or getattr(model, "effects", None):
            return None
        return self.starts

    def _reference_columns(self, model) -> list[bool] | None:
        """Per recording, whether its output reference is a column of `solve_shared` (``references``, x0
        ``"fit"``, a model without effects; not the reference's owner); None: none is (a model with effects has
        its references among its own columns, `_linear_part`)."""
        if not self.references or self.x0 != "fit" or model is None or getattr(model, "effects", None):
            return None
        owner = self._reference_owner()
        return [i != owner for i in range(len(self.recordings))]

    def _gains(self, model) -> list[float]:
        """Per recording, the output gain of a model without effects that carries one for its name
        (``fit_info["gains"]``, `fitter.identification.file_gains`: its output is g times the model's); 1 for
        the others."""
        found = {} if model is None or getattr(model, "effects", None) else (model.fit_info.get("gains") or {})
        return [float(found.get(r.name, 1.0)) for r in self.recordings]

    def _shared_starts(self, model, recordings) -> dict[int, tuple[np.ndarray, float]] | None:
        """Per recording of a start group of more than one (`_groups`), its group's initial state and its own
        output reference (0 without ``references``): `shared_initial_state` over all the group's samples of
        `recordings` (the recordings in the model's frame), as `fitted_initial_state` fits one recording's."""
        groups = self._groups(model)
        if groups is None:
            return None
        refs = self._reference_columns(model) or [False] * len(groups)
        out = {}
        for g in set(groups):
            members = [i for i, k in enumerate(groups) if k == g]
            if len(members) > 1:
                runs = [(recordings[i].t, recordings[i].u, recordings[i].y) for i in members]
                try:
                    with np.errstate(all="ignore"):
                        x0, _, offsets = shared_initial_state(model, runs, [refs[i] for i in members])
                except (KernelError, np.linalg.LinAlgError):
                    continue
                out.update({i: (x0, r) for i, r in zip(members, offsets)})
        return out

    def _reference_owner(self) -> int:
        """The recording whose output reference is the model's own: the first with a sample of positive weight
        (a recording held out of the fit, all weights 0, has its reference fitted like the others', so that
        it is predicted as every recording is scored)."""
        return next((i for i, w in enumerate(self._w) if np.any(w > 0)), 0)

    def _one(self, model, rec: Recording, cyc, settle: bool = False, reference: bool = True, memo=None, shared=None):
        """(start, x0, residual from start, rho, effect state) of one recording (`simulate_from`); with `shared`
        (a shared start and the recording's reference, `_shared_starts`) simulated from it, the reference
        added; failures give `FAIL` residuals."""
        x0, offset = (None, 0.0) if shared is None else shared
        start = cyc[0] if (self.x0 == "periodic" and cyc is not None) else 0
        fail = FAIL * max(float(np.ptp(rec.y)), 1e-300)
        try:
            if model is None:
                raise KernelError("model could not be built")
            with np.errstate(all="ignore"):
                mode = self.x0 if x0 is None else "model"
                mod = model if x0 is None else model.replace(x0=x0)
                s, x0, yhat, rho, state = simulate_from(
                    mod, rec.t, rec.u, rec.y, mode, cyc, settle, reference, self.references, memo
                )
            r = rec.y[s:] - yhat - offset
            if not np.all(np.abs(r) < fail * 1e3):
                raise KernelError("simulation diverged")
            return s, x0, r, rho, state
        except (KernelError, ValueError, np.linalg.LinAlgError):
            return start, None, np.full(len(rec.y) - start, fail), np.nan, None


def divided(rec: Recording, gain: float) -> Recording:
    """`rec` in the model's frame: its output divided by its `gain` (itself for 1)."""
    return rec if gain == 1.0 else Recording(rec.t, rec.u, rec.y / gain, rec.name, rec.input, rec.output, rec.source)


def _weighted(r: np.ndarray, w: np.ndarray) -> np.ndarray:
    """sqrt(w) r on the samples of positive weight: r itself (no copy) when every weight is 1."""
    if np.all(w == 1.0):
        return r
    return (r * np.sqrt(w))[w > 0]
