"""The inverse model: the input u(t) that makes a model's output follow a reference y_ref(t).

A feedforward hysteresis compensator.  Put in front of the plant it inverts
(`simulate` of the same model, or the model's FMU), the cascade's output is
y_ref wherever some admissible input reaches it.

Method: exact inversion of the exact forward step
--------------------------------------------------
The compensator and the plant run the same kernel (`stepper.Stepper`, the
exact flow of `fitter.core.flow` and the effect chain of
`fitter.core.effects`).  At sample k+1 the compensator holds the plant's
state at sample k, (t_k, u_k, x_k, s_k) (s: the effect chain's state), and is
given y_ref(t_{k+1}).  The forward step with the input linear from u_k to u
over [t_k, t_{k+1}] gives the output f(u) at t_{k+1}; the compensator solves
f(u) = y_ref(t_{k+1}) for u and advances the state with that step.  So the
samples u_k it returns, fed to `simulate` (input piecewise linear between
samples), reproduce y_ref to the root finder's tolerance (about 1e-13 of the
input range in u), not to a discretisation error.

* Which root.  One rule: of the inputs that give y_ref, the one nearest the
  last input u_k is taken; so the held input u_k itself whenever it still
  gives y_ref.  The inverse is often not unique (the dead band of
  ``backlash``, a flat stretch, a fitted branch whose slope has the wrong
  sign for a while), and without the rule the root taken would depend on the
  order of the search: a host that reads u again at t_{k+1} before setting
  the new y_ref (fmusim: set y_ref(t_k), doStep, read u) got the other end of
  the dead band, u off by b, at hundreds of samples of the fitted demo
  model.  With it that read is continuous: for a rate-independent model the
  held input gives y(t_{k+1}) = y(t_k) = y_ref(t_k), so the u read is u_k.

  "Gives y_ref" means |y - y_ref| <= 1e-10 Y, Y the output scale |y(hi) -
  y(lo)| over the search range from the first interval step (kept in the
  state; at the first sample, t == t0, that sample's own span, which is the
  feedthrough's only).  Not a few eps of |y| (the test used to be 4 eps
  |y|): the forward step's rounding is relative to the terms it sums, not
  to their sum (a fitted state of 3e3 behind an output of 12; an output
  crossing 0, where 4 eps |y| is 0), and an accepted root keeps the
  residual of the root finder's input tolerance times the local slope (up
  to 2e-10 on the demo model, 200 times 4 eps |y|); the held input then
  failed the test and the search went on across the dead band.  1e-10 Y
  leaves a margin of 1e3 over the rounding seen and is still far below any
  tracking requirement.  Brent's method goes on below its input tolerance
  (to the input's resolution) while the residual is above half of that
  tolerance (a branch over 500 times steeper than Y / input span), so an
  exact sample's held input passes the test at the next time, the other
  half being left for the rounding.

  The search: moving u up from u_k follows the rising branch (rate
  independent: dy/du = C (A+ x + B+ u + E+) + D), moving it down the falling
  one.  The model's orientation o (+1 when its output rises with its input,
  as a piezo's polarization with the voltage; -1 when it falls) is found at
  the first interval step from the outputs at the two ends of the search
  range (or given).  The compensator first searches the side o sign(y_ref -
  y_held) (y_held: the output at t_{k+1} with the input held), the branch
  that moves y the way y_ref asks, for the root nearest u_k: it evaluates f
  at growing distances (factor 4, the first guess from the last step's
  slope) until f - y_ref changes sign, then Brent's method (inverse
  quadratic interpolation with bisection as the safeguard; standard library
  only) in that bracket.  Then it searches the other side, only up to the
  distance of that root: a strictly nearer root there is taken instead
  (the first side wins a tie); with no root on the first side the other
  side is searched over the whole range.  Where the inverse is unique this
  is the root the first side gives.  So a flat stretch (the dead band of
  ``backlash``, a rate with g(v) = 0) is crossed when y_ref turns, and a
  branch whose slope has the wrong sign for a while (a fitted loop whose
  output still rises after the input's reversal) is followed through its
  hump to the first crossing unless the other side reaches y_ref sooner:
  u jumps there, the output is exact.  "Nearest" is to the growing grid's
  resolution: two crossings inside one of its intervals are not seen.
* Search range.  u is searched in the model's ``input_range`` (beyond it the
  model holds its input at the edge, `models`), or in the range given to the
  compensator (an actuator's voltage limits); with neither, the compensator
  refuses to start (`InverseError`).
* Impossible references: clamp and report, never NaN.  When no input in the
  search range reaches y_ref (beyond the reachable output, a branch whose
  slope changes sign so that y_ref lies past its extremum, the first sample
  of a model whose output there does not depend on u), the compensator takes
  the evaluated input whose output is nearest to y_ref (at an interior
  extremum refined by golden-section search), so the output is clamped to
  the nearest reachable value; the sample is counted as clamped and its
  shortfall |y - y_ref| recorded (`Compensator.clamped`,
  `Compensator.max_shortfall`, `Compensation`).  u stays in the search
  range, so nothing grows without bound.  A step in y_ref is solved exactly
  when an admissible u reaches it in one interval, else clamped.
* Non-finite input: y_ref NaN or infinite is a `KernelError` naming the
  sample; time must increase strictly after the first sample.

The first sample
----------------
Like `simulate`, the plant's state at the first sample is ``x0`` (default
the model's) and the effect chain starts there at the effects' stored start,
else afresh.  A first call of
`Compensator.step` at t == t0 solves the output at that sample for u (only
the feedthrough D u and output effects such as creep depend on it; with
D = 0 and no such effect the output there is C x0 whatever u, and the
sample is clamped unless y_ref(t0) equals it; u then stays at u0).  u0
defaults to the model's first input (the input at which its x0 was fitted,
`first_input`), else the middle of the search range.

Effects
-------
The root finding runs on the full forward step, base model and effect
chain, so an effect is inverted exactly when it is part of the step:

* supported, device (``material``) effects: ``backlash`` (the play's dead
  band is crossed by the search: the play operator's inverse), ``rate_dependence``
  and a rate-dependent base (the step includes the time, the root is found
  for the interval's rate), ``creep``, ``relaxation``, ``switching`` (its switched output
  rises with the input in every step), ``viscous``, ``thermal_drift``,
  ``saturation`` (exact where the tanh is not flat; beyond y_c +- 1/beta the
  reference is unreachable and clamped);
* measurement (``measurement``) effects, ``sensor_lag`` and
  ``measurement_drift``, describe the measuring chain, not the actuator: a
  compensator that inverts them makes the *measured* signal follow y_ref
  (the device output then leads the lag, or drifts against the drift).  So
  they are refused unless the caller says what is wanted:
  ``measurement="drop"`` compensates the device output (the model without
  its measurement effects; the compensator's plant is then that model),
  ``measurement="invert"`` makes the measured output follow y_ref (exact
  too: the inverse of the lag's exact step is a stable recursion, which rings,
  decaying, after a step in y_ref).

State and stepping
------------------
`Compensator` is a stepper: ``step(t, y_ref) -> u`` per sample, and
`get_state` / `set_state` for the whole state as a tuple (the plant's
`Stepper` state at the last sample, the slope guess, the output scale and
the clamp counters),
so an FMU can wrap it as `fmu_src/duhem_slave.py` wraps `Stepper`.

This module needs only numpy: it is shipped inside the FMUs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .effects import REGISTRY
from .errors import DuhemError, KernelError
from .flow import check_finite, check_increasing
from .roots import brent
from .stepper import Stepper

__all__ = [
    "InverseError",
    "Compensator",
    "Compensation",
    "invert",
    "compensate",
    "linear_gain",
    "MEASUREMENT_CHOICES",
    "SUPPORTED_EFFECTS",
    "MEASUREMENT_EFFECTS",
]

MEASUREMENT_CHOICES = ("refuse", "drop", "invert")
"""What the compensator does with a model's measurement effects (module docstring)."""

MEASUREMENT_EFFECTS = tuple(name for name, spec in REGISTRY.items() if spec.origin == "measurement")
"""Effects of the measuring chain: refused unless ``measurement`` is "drop" or "invert"."""

SUPPORTED_EFFECTS = tuple(name for name, spec in REGISTRY.items() if spec.origin != "measurement")
"""Effects inverted as they stand (module docstring)."""

_EPS = np.finfo(float).eps
_YTOL = 1e-10
"""An input gives y_ref when |y - y_ref| <= _YTOL * (the output scale) (module docstring, "Which root")."""
_GROW = 4.0
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


class InverseError(DuhemError):
    """A model or request the compensator cannot serve (no search range, refused effects, bad arguments)."""


def _plant(model, measurement: str):
    """The model the compensator inverts, after the `measurement` choice (module docstring)."""
    if measurement not in MEASUREMENT_CHOICES:
        raise InverseError(f"measurement must be one of {', '.join(MEASUREMENT_CHOICES)}, got {measurement!r}")
    present = [e.effect for e in model.effects if e.effect in MEASUREMENT_EFFECTS]
    if not present or measurement == "invert":
        return model
    if measurement == "drop":
        return model.replace(effects=[e for e in model.effects if e.effect not in MEASUREMENT_EFFECTS])
    raise InverseError(
        f"the model has the measurement effect(s) {', '.join(present)}: they describe the sensor, not the "
        f"actuator, so say what to compensate: measurement='drop' (CLI --measurement drop) makes the device "
        f"output follow y_ref, measurement='invert' (--measurement invert) makes the measured output follow it"
    )


def _search_range(model, input_range) -> tuple[float, float]:
    rng = input_range if input_range is not None else model.input_range
    if rng is None:
        raise InverseError(
            "the compensator needs a finite input range to search: the model has no "
            "'input_range' (a fitted model has one); give input_range=(lo, hi) (CLI --input-range)"
        )
    try:
        lo, hi = (float(v) for v in rng)
    except (TypeError, ValueError):
        raise InverseError(f"input_range must be (lo, hi), two numbers, got {rng!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise InverseError(f"input_range ({lo}, {hi}) must be finite with lo < hi")
    return lo, hi


class Compensator:
    """Feedforward compensator of `model`: ``step(t, y_ref) -> u``, per sample (module docstring).

    Parameters
    ----------
    model : a `RateIndependentModel` or `RateDependentModel`, with effects or not
    t0 : time of the first sample (a first `step` at t0 solves that sample; see the module docstring)
    u0 : the plant's input before the first step (default: the model's `first_input`, the input at which its
        x0 was fitted, else the middle of the search range)
    x0 : the plant's state at the first sample (default: the model's x0)
    measurement : "refuse" (default), "drop" or "invert": what to do with the model's measurement effects
    input_range : (lo, hi), the inputs searched (default: the model's ``input_range``)
    orientation : +1 when the output rises with the input, -1 when it falls; None (default): found at the
        first step from the outputs at the two ends of the search range

    Raises
    ------
    InverseError
        No search range, or measurement effects with ``measurement="refuse"``.
    """

    def __init__(
        self,
        model,
        t0: float = 0.0,
        u0: float | None = None,
        x0=None,
        *,
        measurement: str = "refuse",
        input_range=None,
        orientation: float | None = None,
    ):
        if orientation not in (None, 1, -1):
            raise InverseError(f"orientation must be +1, -1 or None (automatic), got {orientation!r}")
        self._given_orientation = None if orientation is None else float(orientation)
        self.model = model
        self.plant = _plant(model, measurement)
        self.measurement = measurement
        self.input_range = _search_range(self.plant, input_range)
        lo, hi = self.input_range
        self._span = hi - lo
        self._xtol = 1e-13 * max(self._span, abs(lo), abs(hi))
        self._xfloor = _EPS * max(self._span, abs(lo), abs(hi))
        self._stepper = Stepper(self.plant)
        self.reset(t0, u0, x0)

    # ------------------------------------------------------------------ state
    def reset(self, t0: float = 0.0, u0: float | None = None, x0=None) -> None:
        """Back to time t0, the plant at input u0 with state x0 (defaults as in the constructor)."""
        lo, hi = self.input_range
        if u0 is None:
            u0 = self.model.first_input if self.model.first_input is not None else (lo + hi) / 2
        if not (math.isfinite(t0) and math.isfinite(u0)):
            raise KernelError(f"t0 = {t0} and u0 = {u0} must be finite")
        self._stepper.reset(float(t0), min(hi, max(lo, u0)), x0)
        self._anchor = self._stepper.get_state()
        self.started = False
        self.y = math.nan
        self.u = self._anchor[1]
        self.slope = math.nan
        self.scale = math.nan
        self.orientation = self._given_orientation
        self.samples = 0
        self.clamped = 0
        self.max_shortfall = 0.0
        self.last_clamped = False

    def get_state(self) -> tuple:
        """The whole state: (plant stepper state at the last sample, started, u, y, slope, scale, orientation,
        samples, clamped, max_shortfall, last_clamped); `set_state` restores exactly the same future."""
        a = self._anchor
        anchor = a[:2] + (np.array(a[2], dtype=float),) + a[3:]
        return (
            anchor,
            self.started,
            self.u,
            self.y,
            self.slope,
            self.scale,
            self.orientation,
            self.samples,
            self.clamped,
            self.max_shortfall,
            self.last_clamped,
        )

    def set_state(self, state: tuple) -> None:
        anchor, started, u, y, slope, scale, orientation, samples, clamped, shortfall, last = state
        self._stepper.set_state(anchor)
        self._anchor = self._stepper.get_state()
        self.started, self.u, self.y, self.slope = bool(started), float(u), float(y), float(slope)
        self.scale = float(scale)
        self.orientation = None if orientation is None else float(orientation)
        self.samples, self.clamped, self.max_shortfall = int(samples), int(clamped), float(shortfall)
        self.last_clamped = bool(last)

    # ------------------------------------------------------------------ stepping
    def _trial(self, t: float, u: float) -> float:
        """The plant's output at time t for the input linear from the anchor's to u (the anchor unchanged)."""
        a = self._anchor
        if t == a[0]:  # the first sample: re-anchor the input, the state does not move (`Stepper`)
            trial = (a[0], u, a[2], a[0], u) + a[5:]
        else:
            trial = a[:3] + (t, u) + a[5:]
        self._stepper.set_state(trial)
        return self._stepper.output()

    def step(self, t: float, y_ref: float) -> float:
        """The input u at time t that makes the plant's output y_ref there (clamped when none does).

        The first call may be at t0 (the first sample) or later; every later call needs a later t.
        Afterwards `y` is the plant's predicted output at t and `last_clamped` says whether it was clamped.
        """
        t, y_ref = float(t), float(y_ref)
        if not math.isfinite(y_ref):
            raise KernelError(f"reference y_ref = {y_ref} at t = {t:.6g} is not finite")
        if not math.isfinite(t):
            raise KernelError(f"time t = {t} is not finite")
        t_a = self._anchor[0]
        if t < t_a or (self.started and t == t_a):
            raise KernelError(f"time must increase: t = {t!r} after t = {t_a!r}")
        u, y, exact = self._solve(t, y_ref)
        self._commit(t, u)
        shortfall = abs(y - y_ref)
        self.u, self.y, self.samples, self.started = u, y, self.samples + 1, True
        self.last_clamped = not exact
        if not exact:
            self.clamped += 1
            self.max_shortfall = max(self.max_shortfall, shortfall)
        return u

    def _commit(self, t: float, u: float) -> None:
        self._trial(t, u)
        self._stepper.do_step(1.0)  # the current point becomes the anchor (the step size is overwritten later)
        self._anchor = self._stepper.get_state()

    def _solve(self, t: float, y_ref: float) -> tuple[float, float, bool]:
        """(u, y, exact) for one sample (module docstring, "Which root" and "clamp")."""
        lo, hi = self.input_range
        u_a = self._anchor[1]

        def f(u: float) -> float:
            return self._trial(t, u) - y_ref

        if t == self._anchor[0]:  # the first sample: its own span (feedthrough only), not kept
            scale = self._span_at(f)
        else:
            if math.isnan(self.scale):  # the first interval step: the output scale, and the orientation
                self._calibrate(f)
            scale = self.scale
        tol = _YTOL * scale
        r0 = f(u_a)
        if not math.isfinite(r0):
            raise KernelError(f"the model's output is not finite at t = {t:.6g} for the held input u = {u_a:.6g}")
        if abs(r0) <= tol:  # the held input still gives y_ref: kept
            return u_a, r0 + y_ref, True
        # first distance: the last step's slope predicts it, else a thousandth of the range
        guess = abs(r0 / self.slope) * 1.5 if self.slope and math.isfinite(self.slope) else 1e-3 * self._span
        guess = min(max(guess, 1e-12 * self._span), self._span)
        preferred = (self.orientation or 1.0) * (1.0 if r0 < 0 else -1.0)
        seen = [(u_a, r0)]
        found = None
        for s in (preferred, -preferred):
            reach = (hi - u_a) if s > 0 else (u_a - lo)
            if found is not None:  # the other side: only a strictly nearer root replaces it
                reach = min(reach, abs(found[0] - u_a))
            other = self._search(f, u_a, r0, s, reach, guess, seen, tol / 2)
            if other is not None and (found is None or abs(other[0] - u_a) < abs(found[0] - u_a)):
                found = other
        if found is not None:
            u, r = found
            if u != u_a:
                self.slope = (r - r0) / (u - u_a)
            return u, r + y_ref, True
        u, r = self._nearest(f, seen, r0)
        return u, r + y_ref, False

    def _span_at(self, f) -> float:
        """|y(hi) - y(lo)| for this sample (0 when not finite)."""
        lo, hi = self.input_range
        span = abs(f(hi) - f(lo))
        return span if math.isfinite(span) else 0.0

    def _calibrate(self, f) -> None:
        """At the first interval step: the output scale |y(hi) - y(lo)| and, unless given, the orientation (+1 when
        the output rises with the input over the search range, else -1), from the same two evaluations."""
        lo, hi = self.input_range
        r_hi, r_lo = f(hi), f(lo)
        finite = math.isfinite(r_hi) and math.isfinite(r_lo)
        self.scale = abs(r_hi - r_lo) if finite else 0.0
        if self.orientation is None:
            self.orientation = -1.0 if finite and r_hi < r_lo else 1.0

    def _search(self, f, u_a: float, r0: float, s: float, reach: float, d: float, seen: list, ftol: float):
        """The root of f nearest u_a on side s (distance up to `reach`): (u, f(u)), or None."""
        prev = (u_a, r0)
        while reach > 0:
            dist = min(d, reach)
            u = u_a + s * dist
            r = f(u)
            if not math.isfinite(r):  # the model overflows this far out: search no further on this side
                return None
            seen.append((u, r))
            if r == 0:
                return u, r
            if (r < 0) != (prev[1] < 0):
                return brent(f, prev[0], u, prev[1], r, self._xtol, ftol, self._xfloor)
            if dist >= reach:
                return None
            prev, d = (u, r), d * _GROW
        return None

    def _nearest(self, f, seen: list, r0: float) -> tuple[float, float]:
        """No root in the search range: the input whose output is nearest y_ref (module docstring)."""
        pts = sorted(seen)
        i = min(range(len(pts)), key=lambda k: abs(pts[k][1]))
        best = (abs(pts[i][1]), pts[i][0], pts[i][1])
        if 0 < i < len(pts) - 1:  # an interior extremum: golden-section search between the neighbours
            a, b = pts[i - 1][0], pts[i + 1][0]
            for _ in range(80):
                if abs(b - a) <= self._xtol:
                    break
                c, e = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
                rc, re_ = f(c), f(e)
                for u, r in ((c, rc), (e, re_)):
                    if math.isfinite(r) and abs(r) < best[0]:
                        best = (abs(r), u, r)
                if not abs(rc) > abs(re_):
                    b = e
                else:
                    a = c
        return best[1], best[2]

    def run(self, t, y_ref) -> "Compensation":
        """Step through the samples (t_k, y_ref_k) from the current state; returns the `Compensation`."""
        t = check_finite("t", t)
        y_ref = np.asarray(y_ref, dtype=float).ravel()
        if len(t) != len(y_ref):
            raise KernelError(f"t and y_ref differ in length ({len(t)} and {len(y_ref)})")
        bad = np.flatnonzero(~np.isfinite(y_ref))
        if bad.size:
            raise KernelError(
                f"y_ref[{bad[0]}] (sample {bad[0]}, t = {t[bad[0]]:.6g}) is {y_ref[bad[0]]} (NaN or infinite)"
            )
        check_increasing(t)
        u, y, clamped = np.empty(len(t)), np.empty(len(t)), np.zeros(len(t), dtype=bool)
        for k, (tk, yk) in enumerate(zip(t, y_ref)):
            u[k] = self.step(tk, yk)
            y[k], clamped[k] = self.y, self.last_clamped
        return Compensation(t=t, y_ref=y_ref, u=u, y=y, clamped=clamped, input_range=self.input_range)


@dataclass
class Compensation:
    """Result of `compensate`: per sample the input u, the plant's predicted output y and whether it was clamped."""

    t: np.ndarray
    y_ref: np.ndarray
    u: np.ndarray
    y: np.ndarray
    clamped: np.ndarray
    input_range: tuple[float, float]

    @property
    def n_clamped(self) -> int:
        return int(np.count_nonzero(self.clamped))

    @property
    def shortfall(self) -> np.ndarray:
        """|y - y_ref| at the clamped samples, 0 elsewhere."""
        return np.where(self.clamped, np.abs(self.y - self.y_ref), 0.0)

    @property
    def max_shortfall(self) -> float:
        return float(self.shortfall.max()) if len(self.t) else 0.0

    def tracking_error(self, exact_only: bool = False) -> float:
        """RMS(y - y_ref) / range(y_ref) (all samples, or the unclamped ones); 0 for a constant reference."""
        sel = ~self.clamped if exact_only else np.ones(len(self.t), dtype=bool)
        if not sel.any():
            return 0.0
        span = float(np.ptp(self.y_ref)) or 1.0
        return float(np.sqrt(np.mean((self.y[sel] - self.y_ref[sel]) ** 2)) / span)

    def summary(self) -> dict:
        k = int(np.argmax(self.shortfall)) if self.n_clamped else None
        return {
            "samples": len(self.t),
            "clamped": self.n_clamped,
            "max_shortfall": self.max_shortfall,
            "max_shortfall_time": None if k is None else float(self.t[k]),
            "first_clamped_time": float(self.t[np.argmax(self.clamped)]) if self.n_clamped else None,
            "tracking_error": self.tracking_error(),
            "input_range": list(self.input_range),
            "u_min": float(self.u.min()),
            "u_max": float(self.u.max()),
        }


def invert(model, **options) -> Compensator:
    """The compensator of `model` (`Compensator`; keyword options as its constructor's)."""
    return Compensator(model, **options)


def compensate(
    model,
    t,
    y_ref,
    *,
    u0: float | None = None,
    x0=None,
    measurement: str = "refuse",
    input_range=None,
    orientation: float | None = None,
) -> Compensation:
    """The input that makes `model` follow y_ref at the samples t (None: t_k = k); see the module docstring.

    The first sample is t[0] (the plant's state there is x0, as in `simulate`), so
    ``simulate(plant, t, result.u).y`` reproduces ``result.y``.

    Raises
    ------
    KernelError
        t or y_ref not finite (the message names the sample), of different lengths, time not increasing.
    InverseError
        See `Compensator`.
    """
    y_ref = np.asarray(y_ref, dtype=float).ravel()
    t = np.arange(len(y_ref), dtype=float) if t is None else check_finite("t", t)
    if len(y_ref) == 0:
        raise KernelError("empty reference")
    comp = Compensator(
        model, t0=float(t[0]), u0=u0, x0=x0, measurement=measurement, input_range=input_range, orientation=orientation
    )
    return comp.run(t, y_ref)


def linear_gain(u: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(y0, gain) of the linear calibration a compensation without a hysteresis model uses, u = (y_ref - y0) / gain.

    The straight line through the middle of the loop (u, y) with the slope of its extremes: gain = span(y) /
    span(u) (signed as the least-squares slope), y0 = mid(y) - gain mid(u), so that the full output span maps
    onto the full input span (a data sheet's "stroke per volt").
    """
    u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
    span_u, span_y = float(np.ptp(u)), float(np.ptp(y))
    if not (span_u > 0 and span_y > 0 and math.isfinite(span_u) and math.isfinite(span_y)):
        raise InverseError("no linear gain: the input or the output does not move")
    slope = float(np.mean((u - u.mean()) * (y - y.mean())))
    gain = math.copysign(span_y / span_u, slope)
    y0 = (float(y.max()) + float(y.min())) / 2 - gain * (float(u.max()) + float(u.min())) / 2
    return y0, gain
