"""The model a fit writes, scored the way a user will run it.

The fit optimises on prepared recordings (start-up transient dropped, input
made monotone between reversals, normalised units).  What the user takes away
is the model JSON and the FMU, driven by the *raw* recording from the model's
stored initial state.  This module makes the two the same:

* **Initial state** (`initial_state`), the model's ``x0``, is the state at the
  first sample of the first recording:

  - ``"fitted"`` (default): x0 = argmin over all samples of the raw recording
    of ||y - yhat(x0)|| with the parameters fixed (linear least squares: the
    output is affine in x0, `fitted_initial_state`).  A model without effects,
    fitted to several recordings that start at the first one's input level
    (`start_groups`), takes the x0 that minimises the sum of
    squares over all of those recordings' samples (`shared_initial_state`)
    where that sum is at most `SHARED_START_RSS` times the sum of their RSS
    from each one's own start: the runs then start from one state (a device
    reset before each run); else they were made after other histories, and
    the first one's own start is stored.  (From another
    input level, "the same state" is not defined by the data: the coordinates
    x' = x + K u give the rate-independent class the same input-output map for
    every K, so a stored x0 suits only runs that start at one input.)
  - ``"periodic"``: the state at the first sample that leads onto the limiting
    periodic response (Theorem 1) of the recording's first full input cycle
    [s0, s1]: x(s0) = x* = (I - Phi)^-1 c, and x0 solves x(s0) = Phi_s0 x0 + c_s0
    by least squares (exact when s0 = 0).

* **Score** (`score`): every recording is simulated by the saved model from
  its stored x0 on the raw samples, and compared over all samples
  (``nrmse`` = RMS error / output range, the figure `duhem validate` reports),
  with the last full input cycle beside it (``nrmse_last_cycle``).  Beside it, each recording's own start
  state (``x0_fitted``: the "fitted" rule above applied to that recording; ``effect_start_fitted``: its
  effect chain's start, `own_start`, None where the chain starts afresh) and the NRMSE from it
  (``nrmse_x0_fitted``): one model for several recordings made after different histories starts each
  from a different state, and `duhem validate --x0 fitted` sets the FMU's x0 parameters to it.

* **Convergence on the raw input** (`raw_input_rho`): the spectral radius of the
  period map of each raw recording's last full cycle, closed back to its
  starting input (noise reversals included): the model converges on the
  user's input, repeated, when it is < 1.

* **Fitted range** (`fitted_range`): the input range and the 5-95 % range of
  |du/dt| over all recordings, so that `simulate` and `validate` can warn when
  an input leaves them.

* **Minor loops** (`minor_loop_excursion`): the saved model driven from its
  stored x0 by `fitter.core.periodic.minor_loop_input` (40 triangle cycles of
  each of 8 sub-spans of its input range, at the fitted data's median rate):
  how far its output leaves the recorded output range, in output ranges.
  Condition (5) on every minor loop makes such loops converge; it does not
  put them where the device's are (a semilinear model's small loops settle on
  a centre line that is affine in u), so the fit reports it and `duhem fit`
  warns when it exceeds `MINOR_LOOP_WARNING`.

* **Description** (`described`): the signals (names, units, descriptions) of
  the first recording, the default experiment of the longest one and the
  ``input_range`` below: what every saved model carries, fitted or diagnosed.

* **Extrapolation** (`input_range`): the model's ``input_range``, the fitted
  input range widened by `fitter.core.models.INPUT_MARGIN` of its span on each
  side; beyond it the model holds the input at the edge (the rule of
  `fitter.core.models`), so its output stays bounded whatever its branch
  matrices.  Rates need no such rule: g is held constant beyond its outermost
  node (`fitter.core.rates`).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fitter.core.effects import fresh_state, settled_state, stored_start, with_start
from fitter.core.errors import DuhemError, KernelError
from fitter.core.models import INPUT_MARGIN, Experiment, Signals
from fitter.core.kernel import flows, simulate
from fitter.core.periodic import fixed_point, minor_loop_input, minor_loop_outputs, period_map
from fitter.data.cycles import closed_last_cycle, closed_loop
from fitter.data.metrics import compare
from fitter.data.preparation import prepare
from fitter.data.recordings import Recording
from fitter.identification.fit_data import start_groups
from fitter.identification.output_error import fitted_initial_state, shared_initial_state

__all__ = [
    "X0_POLICIES",
    "NRMSE_CONVENTION",
    "initial_state",
    "calibrated",
    "file_gain",
    "file_reference",
    "file_references",
    "levelled",
    "own_start",
    "same_start",
    "SHARED_START_RSS",
    "started",
    "score",
    "raw_input_rho",
    "fitted_range",
    "minor_loop_excursion",
    "minor_loop_warning",
    "MINOR_LOOP_WARNING",
    "input_range",
    "range_warnings",
    "described",
]

X0_POLICIES = ("fitted", "periodic")
SHARED_START_RSS = 1.5
"""One x0 for several runs that start at one input level is stored where its RSS over them is at most this many
times that of each run from its own start (module docstring, ``"fitted"``)."""
NRMSE_CONVENTION = (
    "nrmse: RMS error / output range over all samples of the raw recording, the saved model "
    "simulated from its stored x0 (what `duhem validate` reports for its FMU); nrmse_last_cycle: "
    "the same over the last full input cycle"
)


def _periodic_x0(model, rec: Recording) -> np.ndarray:
    """x0 leading onto the periodic state of the first full cycle (module docstring)."""
    prep = prepare(rec, min_cycles=0, drop_transient=False)
    s0, s1 = prep.first_cycle()
    cache = flows(model)
    xs, rho = fixed_point(model, rec.t[s0 : s1 + 1], rec.u[s0 : s1 + 1], cache)
    if xs is None:
        raise DuhemError(
            f"{rec.name}: no periodic state (spectral radius of the cycle's map {rho:.4g} >= 1); "
            "use the fitted initial state"
        )
    if s0 == 0:
        return xs
    Phi, c = period_map(model, rec.t[: s0 + 1], rec.u[: s0 + 1], cache)
    x0, *_ = np.linalg.lstsq(Phi, xs - c, rcond=None)
    return x0


def initial_state(
    model, recordings: Sequence[Recording], policy: str = "fitted", references: bool = False
) -> np.ndarray:
    """The model's stored x0, the state at the first sample of the first recording, under `policy` (module
    docstring): the periodic start of the first recording, or the state fitted to the recordings that start
    where it starts (the first alone when it is the only one or the model has effects).  With `references`,
    every recording but the first has its own output reference, fitted with the state (`file_references`)."""
    if policy not in X0_POLICIES:
        raise DuhemError(f"x0 policy must be one of {X0_POLICIES}, not {policy!r}")
    rec = recordings[0]
    if policy == "periodic":
        with np.errstate(all="ignore"):
            return _periodic_x0(model, rec)
    start = own_start(model, rec)
    alike = same_start(recordings)
    if len(alike) > 1 and start is not None and not getattr(model, "effects", None):
        x0 = _shared_start(model, alike, references)
        if x0 is not None:
            return x0
    return np.array(model.x0, dtype=float) if start is None else start[0]


def _shared_start(model, alike: Sequence[Recording], references: bool = False) -> np.ndarray | None:
    """The x0 fitted to all of `alike` (`shared_initial_state`; with `references`, a reference for each but the
    first) when it is consistent with them: its RSS over their samples at most `SHARED_START_RSS` times the sum
    of each one's RSS from its own start (runs that did start from one state; else None: runs made after other
    histories, the first's own start is stored)."""
    refs = [references and i > 0 for i in range(len(alike))]
    with np.errstate(all="ignore"):
        try:
            x0, joint, _ = shared_initial_state(model, [(r.t, r.u, r.y) for r in alike], refs)
            starts = [fitted_initial_state(model, r.t, r.u, r.y, constant=ref) for r, ref in zip(alike, refs)]
        except (KernelError, np.linalg.LinAlgError):
            return None
    own = sum(float(np.sum((r.y - s[1]) ** 2)) for r, s in zip(alike, starts))
    return x0 if np.isfinite(joint) and np.isfinite(own) and joint <= SHARED_START_RSS * own else None


def file_reference(model, rec: Recording) -> float:
    """The output reference `duhem fit` fitted to the recording of this name (``fit_info["references"]``,
    `file_references`: the zero of the instrument that wrote it, relative to the first recording's, which is
    the model's own); 0 for any other recording.  The model's output plus it is what the recording is compared
    with."""
    refs = getattr(model, "fit_info", {}).get("references") or {}
    return float(refs.get(rec.name, 0.0))


def file_gain(model, rec: Recording) -> float:
    """The output gain `duhem fit` fitted to the recording of this name (``fit_info["gains"]``,
    `fitter.identification.file_gains`: the recording's output is g times the model's, the first recording's
    scale being the model's own); 1 for any other recording."""
    gains = getattr(model, "fit_info", {}).get("gains") or {}
    return float(gains.get(rec.name, 1.0))


def calibrated(model, rec: Recording, y_model: np.ndarray) -> np.ndarray:
    """The model's output `y_model` on `rec` as the recording's instrument writes it: g y + r, with the file's
    `file_gain` g and `file_reference` r (y itself for a recording the fit gave neither)."""
    return file_gain(model, rec) * y_model + file_reference(model, rec)


def levelled(model, rec: Recording) -> Recording:
    """`rec` in the model's own frame, (y - r) / g with its `file_reference` r and `file_gain` g: the recording as
    the model itself draws it (NRMSE, RMS over range, is the same in both frames)."""
    ref, gain = file_reference(model, rec), file_gain(model, rec)
    if ref == 0.0 and gain == 1.0:
        return rec
    return Recording(rec.t, rec.u, (rec.y - ref) / gain, rec.name, rec.input, rec.output, rec.source)


def file_references(model, recordings: Sequence[Recording]) -> dict[str, float]:
    """The output reference of every recording but the first, for the model with its stored x0 (recordings of
    several separate runs, each written by an instrument zeroed anew): the constant r_i = mean(y_i - yhat_i) that
    minimises ||y_i - yhat_i - r_i||, yhat_i the model's output from the stored x0, as the FMU runs it.  The first
    recording's reference is the model's own (0).  (Fitted together with each recording's own start instead, a
    model with a slow mode split state and reference arbitrarily: measured B-H loops at four frequencies got
    references of 4-12 output ranges, and 3.8-12.4 NRMSE from the stored x0, where these give 0.04-0.23.)
    Raises `KernelError` when a simulation overflows."""
    out = {}
    with np.errstate(all="ignore"):
        for rec in recordings[1:]:
            out[rec.name] = float(np.mean(rec.y - simulate(model, rec.t, rec.u).y))
    if not all(np.isfinite(v) for v in out.values()):
        raise KernelError("simulation overflowed")
    return out


def same_start(recordings: Sequence[Recording]) -> list[Recording]:
    """The recordings of the first one's start group (`fitter.identification.fit_data.start_groups`)."""
    groups = start_groups(recordings)
    return [r for r, g in zip(recordings, groups) if g == groups[0]]


def score(model, recordings: Sequence[Recording]) -> list[dict]:
    """`fitter.data.metrics.compare` of the saved model on each raw recording, from its stored x0 (the recording
    `levelled` by the reference the fit found for it), with the recording's own fitted start beside it
    (``x0_fitted``, ``effect_start_fitted``, ``nrmse_x0_fitted``; module docstring).

    A simulation that overflows scores None (and ``"diverged": True``).
    """
    out = []
    for rec in recordings:
        with np.errstate(all="ignore"):
            try:
                y_hat = simulate(model, rec.t, rec.u).y
            except KernelError:
                y_hat = np.full(len(rec.y), np.nan)
        if not np.all(np.isfinite(y_hat)):
            out.append({"recording": rec.name, "nrmse": None, "nrmse_last_cycle": None, "diverged": True})
            continue
        rec = levelled(model, rec)
        m = compare(rec, y_hat)
        m.update(recording=rec.name, diverged=False, **_own_start(model, rec))
        out.append(m)
    return out


def own_start(model, rec: Recording) -> tuple[np.ndarray, np.ndarray, tuple | None] | None:
    """(x0, output from it, effect chain state at the first sample): the state fitted to `rec` by least
    squares over all its samples (`fitted_initial_state`); None when that simulation overflows or gives a
    non-finite state or output.

    The effect chain: a model that stores its effects' start (`Effect.start`, fitted by `duhem fit
    --effects`) starts it as that fit did, settled on `rec` when `rec` is a closed loop
    (`fitter.data.cycles.closed_loop`, `fitter.core.effects.settled_state`), else afresh (the state given
    as numbers, `fresh_state`, so that an FMU can be set to it); any other model starts it afresh (state
    None).  An effect with a reference state (`EffectSpec.offset`) has it fitted with x0 (the state is then
    numbers for any model)."""
    stored = bool(getattr(model, "effects", None)) and stored_start(model) is not None
    with np.errstate(all="ignore"):
        try:
            fresh, fl, state = (with_start(model, None) if stored else model), flows(model), None
            if stored and closed_loop(rec):
                state = settled_state(fresh, rec.t, rec.u, model.x0, fl)
            x0, y_hat, state = fitted_initial_state(fresh, rec.t, rec.u, rec.y, fl, state)
            if stored and state is None:
                state = fresh_state(fresh, rec.t, rec.u, x0, fl)
        except (KernelError, np.linalg.LinAlgError):
            return None
    return (x0, y_hat, state) if np.all(np.isfinite(y_hat)) and np.all(np.isfinite(x0)) else None


def started(model, start: tuple) -> object:
    """`model` from an `own_start`: its x0 and, when the start has one, its effects' stored start."""
    model = model.replace(x0=start[0])
    return model if start[2] is None else with_start(model, start[2])


def _own_start(model, rec: Recording) -> dict:
    """``x0_fitted`` and ``effect_start_fitted`` (`own_start`) and ``nrmse_x0_fitted`` (the model's NRMSE from
    them); None for all when it has none."""
    start = own_start(model, rec)
    if start is None:
        return {"x0_fitted": None, "effect_start_fitted": None, "nrmse_x0_fitted": None}
    return {
        "x0_fitted": start[0].tolist(),
        "effect_start_fitted": None if start[2] is None else list(start[2]),
        "nrmse_x0_fitted": compare(rec, start[1])["nrmse"],
    }


def raw_input_rho(model, recordings: Sequence[Recording]) -> list[float | None]:
    """Spectral radius of the period map of each raw recording's last full cycle (None: no full cycle).

    A measured cycle rarely ends exactly at its starting input; the period map is that of the cycle
    *closed*: one more sample, one median sample period later, back at the starting input (the input
    that repeats the cycle).  An open cycle's map also contains the unclosed stretch of one branch,
    which can expand along a branch eigenvalue > 0 although the repeated input converges.
    """
    rhos = []
    for rec in recordings:
        try:
            _, t, u = closed_last_cycle(rec.t, rec.u)
        except DuhemError:
            rhos.append(None)
            continue
        with np.errstate(all="ignore"):
            try:
                rhos.append(fixed_point(model, t, u)[1])
            except (KernelError, np.linalg.LinAlgError):
                rhos.append(np.inf)
    return rhos


def _moving_rates(t: np.ndarray, u: np.ndarray) -> np.ndarray:
    """|du/dt| on the intervals where the input moves."""
    v = np.abs(np.diff(u) / np.diff(t))
    return v[v > 0]


def fitted_range(recordings: Sequence[Recording]) -> dict:
    """Input and output ranges over all recordings, and the range of |du/dt| they cover: from the lowest of their
    5 % percentiles to the highest of their 95 % percentiles (each recording's own 5-95 % range inside it, so
    that `range_warnings` is silent on a recording the model was fitted on)."""
    u = np.concatenate([r.u for r in recordings])
    y = np.concatenate([r.y for r in recordings])
    spans = [np.percentile(v, [5, 95]) for v in (_moving_rates(r.t, r.u) for r in recordings) if v.size]
    rates = [float(min(s[0] for s in spans)), float(max(s[1] for s in spans))] if spans else None
    return {"input": [float(u.min()), float(u.max())], "rate": rates, "output": [float(y.min()), float(y.max())]}


OUTPUT_WARNING = 10.0
"""Output ranges beyond the fitted output range (`fitted_range`) at which a simulated output is warned about
(`range_warnings`): no input inside the fitted range takes a model fitted there so far; an edited or corrupted
parameter (an effect's 1e90, say) does."""


MINOR_LOOP_WARNING = 1.0
"""`minor_loop_excursion` (in output ranges) beyond which `duhem fit` warns that the model is not a faithful
model of smaller loops than those it was fitted on."""


SETTLED_SPANS = 64
"""Sub-spans of the input range whose settled minor loops `minor_loop_excursion` adds (rate-independent)."""


def minor_loop_excursion(model, recordings: Sequence[Recording]) -> float:
    """Largest distance of `model`'s output beyond the recordings' output range on `minor_loop_input` of its
    input range (from its stored x0 at its first input) and, for a rate-independent model without effects, at
    the turning points of the settled minor loops of `SETTLED_SPANS` sub-spans at 5 places each
    (`fitter.core.periodic.minor_loop_outputs`: the fixed points of their period maps, where 40 cycles of a
    loop contracting by 0.99 per cycle are still on the way, and between the 8 sub-spans of the input, where
    a generated asymmetric Preisach loop's fit settled 45 ranges out on loops of 22-26 % of the range); in
    output ranges, inf when the output overflows.

    The input's time base gives it the median |du/dt| of the recordings (a rate-dependent model is driven
    at a rate it was fitted at; a rate-independent one does not depend on it)."""
    ys = np.concatenate([r.y for r in recordings])
    lo, hi = float(ys.min()), float(ys.max())
    settled = 0.0
    if model.kind == "ri" and not model.effects:
        with np.errstate(all="ignore"):
            try:
                turns = minor_loop_outputs(model, *model.input_range, spans=SETTLED_SPANS)
            except (KernelError, np.linalg.LinAlgError):
                return float("inf")
        if not np.all(np.isfinite(turns)):
            return float("inf")
        settled = max(0.0, lo - turns.min(), turns.max() - hi)
    u = minor_loop_input(*model.input_range, start=model.first_input)
    v = np.concatenate([_moving_rates(r.t, r.u) for r in recordings])
    rate = float(np.median(v)) if v.size else 1.0
    t = np.r_[0.0, np.cumsum(np.maximum(np.abs(np.diff(u)), 1e-6 * np.ptp(model.input_range)) / rate)]
    with np.errstate(all="ignore"):
        try:
            y = simulate(model, t, u).y
        except KernelError:
            return float("inf")
    if not np.all(np.isfinite(y)):
        return float("inf")
    return float(max(settled, lo - y.min(), y.max() - hi) / max(hi - lo, 1e-300))


def minor_loop_warning(model) -> str | None:
    """The sentence `duhem fit`, `duhem compensate` and `duhem export --inverse` print when the fit recorded
    (``fit_info["minor_loops"]``) that the model's minor loops leave the recorded range by more than
    `MINOR_LOOP_WARNING` output ranges; None otherwise, or when the model has no such record."""
    minor = model.fit_info.get("minor_loops") if isinstance(model.fit_info, dict) else None
    if not isinstance(minor, dict) or minor.get("faithful", True):
        return None
    exc = minor.get("excursion")
    size = "overflows" if exc is None else f"settles up to {exc:.3g} output ranges outside anything recorded"
    return (
        "on minor loops smaller than the recorded ones the model's output " + size + ": it reproduces "
        "the recorded loops, not necessarily smaller ones (a semilinear model's small loops settle on a "
        "centre line affine in u); its compensator inverts the model exactly but may ask for inputs far from "
        "the recorded path; check it on a recording with minor loops before using it there, or fit with "
        "--faithful-minor-loops (and --effects for physics such as switching that the faithful base then "
        "cannot follow)"
    )


def input_range(recordings: Sequence[Recording]) -> tuple[float, float]:
    """The model's ``input_range``: [min u - m span, max u + m span], m = `INPUT_MARGIN` (module docstring)."""
    lo, hi = fitted_range(recordings)["input"]
    slack = INPUT_MARGIN * (hi - lo) if hi > lo else max(abs(lo), 1.0)
    return lo - slack, hi + slack


def described(model, recordings: Sequence[Recording]):
    """`model` with the description of `recordings` (module docstring): the first recording's signals, the
    longest one's span and median step as the default experiment, and their `input_range`."""
    r0, longest = recordings[0], max(recordings, key=lambda rec: rec.t[-1] - rec.t[0])
    experiment = Experiment(
        start_time=float(longest.t[0]), stop_time=float(longest.t[-1]), step_size=float(np.median(np.diff(longest.t)))
    )
    return model.replace(
        signals=Signals(input=r0.input, output=r0.output), experiment=experiment, input_range=input_range(recordings)
    )


def range_warnings(model, t: np.ndarray, u: np.ndarray, y: np.ndarray | None = None) -> list[str]:
    """Sentences naming where an input leaves the model's fitted range (`fitted_range`, stored in
    ``fit_info``): its amplitude beyond `INPUT_MARGIN` of the fitted span (where the model's
    ``input_range`` holds the input), and for a rate-dependent model its rates (5-95 %) beyond a
    factor 1.5; and where the model's simulated output `y` (when given) leaves the fitted output range by more
    than `OUTPUT_WARNING` of its span.  Empty when inside, or when the model has no fitted range."""
    rng = model.fit_info.get("fitted_range") if isinstance(model.fit_info, dict) else None
    if not isinstance(rng, dict) or not rng.get("input"):
        return []
    out = []
    lo, hi = rng["input"]
    slack = INPUT_MARGIN * (hi - lo)
    if u.min() < lo - slack or u.max() > hi + slack:
        held = (
            f"beyond [{model.input_range[0]:.6g}, {model.input_range[1]:.6g}] the model holds the input at "
            "the edge, so its output stays at its value there"
            if model.input_range is not None
            else "outside it the model extrapolates (no input_range: unbounded)"
        )
        out.append(
            f"the input spans [{u.min():.6g}, {u.max():.6g}] but the model was fitted on [{lo:.6g}, {hi:.6g}]: {held}"
        )
    v = _moving_rates(t, u)
    if model.kind == "rd" and rng.get("rate") and v.size:
        v_lo, v_hi = np.percentile(v, [5, 95])
        f_lo, f_hi = rng["rate"]
        if v_hi > 1.5 * f_hi or v_lo < f_lo / 1.5:
            out.append(
                f"the input's rates |du/dt| span [{v_lo:.4g}, {v_hi:.4g}] (5-95 %) but the model was "
                f"fitted on [{f_lo:.4g}, {f_hi:.4g}]: its rate function g is extrapolated"
            )
    return out + _output_warning(rng.get("output"), y)


def _output_warning(fitted, y: np.ndarray | None) -> list[str]:
    """`range_warnings`' sentence on the simulated output `y` against the fitted output range."""
    if not fitted or y is None or not np.all(np.isfinite(y)):
        return []
    lo, hi = fitted
    span = max(hi - lo, 1e-300)
    beyond = max(lo - float(np.min(y)), float(np.max(y)) - hi, 0.0) / span
    if beyond <= OUTPUT_WARNING:
        return []
    return [
        f"the output reaches [{np.min(y):.6g}, {np.max(y):.6g}], {beyond:.3g} output ranges beyond the range the "
        f"model was fitted on, [{lo:.6g}, {hi:.6g}]: check the model's parameters (an edited value?)"
    ]
