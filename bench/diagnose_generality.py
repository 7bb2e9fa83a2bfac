"""Generality sweep for `duhem diagnose`: experiments NOT made by the project's own effect code.

    python bench/diagnose_generality.py              # 2 seeds per case, 600 samples per recording
    python bench/diagnose_generality.py --quick      # 1 seed, 350 samples per recording
    python bench/diagnose_generality.py --json PATH  # also write the table as JSON
    python bench/diagnose_generality.py --clean 10   # only the clean controls: orders 1-3 x 10 seeds
    (--samples N: samples per recording; --only TEXT: only the cases whose name contains TEXT)

Every truth is generated here with numpy/scipy in its own functional form, on top of a Duhem base loop
simulated by `fitter.core.kernel.simulate` (the base alone: no `fitter.core.effects` code is used to
make any truth), then diagnosed by `fitter.diagnosis.diagnose` and scored.

Base loops (y range about 2 on u in [-1, 1])
--------------------------------------------
* ``ri1``: `first_order_ri(**TRUTH_BASE)`, dx = (A+- x + B+- u + E+-) du, y = x.
* ``ri2`` / ``ri3``: `fitter.diagnosis.synthetic.cell_base(2 or 3)`: one first-order cell per state,
  weakly coupled, the loop spanning 2, x0 on the settled loop.
Diagnosed as `duhem diagnose` does by default: the base order chosen by BIC (as `duhem fit` chooses it).

Input designs (recordings on one clock, 1 s gaps, the input linear across a gap)
--------------------------------------------------------------------------------
* ``trapezoids``: runs (period s, amplitude) (40, 1), (8, 1), (2, 1), (40, 1) (the last repeats the first),
  2 cycles each, holds of 10 % of the period at the tips (as `synthetic_experiment`'s DEFAULT_RUNS).
* ``triangles``: pure triangles, periods 30, 6, 1.5, 30 s, no holds.
* ``random``: 3 recordings, each piecewise linear between 8 random turning points (alternating
  direction, random amplitude 0.2-2 kept in [-1, 1], so minor loops), a random speed 0.2-2 /s per recording.
* ``two``: trapezoid runs (30, 1), (5, 1): two recordings, no repeat.
* ``synthetic``: `fitter.diagnosis.synthetic_experiment(None, seed=s, samples=N)` (the controls).

Effects (own forms; t0 = the first sample, D = the experiment's duration, dU_j = u_{j+1} - u_j on
interval j, v_j = dU_j / h_j; "du-convolution" with kernel G means
c(t_k) = sum_{j<k} v_j [G(t_k - t_j) - G(t_k - t_{j+1})], the exact integral of G'(t - s) du(s) for
u piecewise linear)
-------------------------------------------------------------------------------------------------------
* ``log_creep``: y += k * du-convolution with G(x) = (tau + x) ln(1 + x / tau) - x, i.e. the creep
  compliance J(t) = k ln(1 + t / tau) applied to every input increment (piezo logarithmic creep), tau = 0.5 s.
* ``sqrt_rate``: a first-order RI base integrated here (exact per interval for w linear) with its
  dynamics slowed by s(v) = 1 / (1 + alpha |v|^0.5): dx/dt = v s(v) (A+- x + B+- w + E+-), so the
  lag grows as |du/dt|^0.5 (the catalogue's is 1 / (1 + alpha |v|)).
* ``soft_backlash``: the base sees w = u - z, z the smooth play state, rising dz/du = 1 - (max(z, 0)/h)^2,
  falling dz/du = 1 - (max(-z, 0)/h)^2 (exact: z = h tanh(...) past the dead zone), z0 = -h:
  a play of width 2h with rounded corners.
* ``hard_clip``: y -> clip(y, min y + c, max y - c) (the catalogue's is tanh).
* ``two_pole_sensor``: the measured m obeys m'' + 2 zeta omega m' + omega^2 m = omega^2 y, zeta = 0.7,
  omega = 1 / tau, m(t0) = y(t0), m'(t0) = 0, y linear between samples (exact discretisation by the
  matrix exponential).
* ``linear_drift``: y += r (t - t0).
* ``quadratic_drift``: y += q ((t - t0) / D)^2.
* ``exp_drift``: y += d (1 - exp(-3 (t - t0) / D)).
* ``hum`` (outside the catalogue): y += A sin(2 pi f t + 0.7), f = 1 / (7 x the longest sample period)
  (a mains-like hum, unrelated to the input, resolved by every recording).
* ``delay`` (outside): y += c (u(t - L) - u(t)), L = 0.5 s, u(t) = u(t0) before t0 (the c u(t) part of
  c u(t - L) is absorbed exactly by the base's B, E, so only the memory part is added).
* ``fractional`` (outside): y += c D^0.5 u, the Caputo half-derivative: du-convolution with
  G(x) = x^0.5 / Gamma(1.5) (long memory between an elastic and a viscous term).

Size and noise: each effect alone is scaled (strength by bisection on max |y_with - y_without|) to a
size drawn per seed in [2 %, 3 %] of the base output range; white Gaussian noise of RMS size x range / 15.
Two effects are composed in physical order (input, rate, output, then the sensor / the drift), each
sized alone; clean cases get the noise of a 2.5 % effect.

Scoring
-------
* catalogue (one effect): PASS when the first finding is the expected effect.  An expected effect may
  name alternatives ("creep|relaxation" for the logarithmic creep: its compliance ln(1 + t / tau) is a
  continuous spectrum of exponential creeps, of which `relaxation`'s four log-spaced time constants are the
  discrete form and `creep` the one-term form; either is the right physics).
* two effects: PASS when both expected effects are among the findings (any order).
* outside the catalogue: PASS when the verdict is "unexplained", or when there are findings and the
  extended residual RMS stays above 1.5 x the true noise; FAIL otherwise (a catalogue effect claimed
  that brings the residual near the noise with the wrong physics, or "nothing_missing").
* clean: PASS when the verdict is "nothing_missing".

Clean controls (``--clean N``): effect-free data of the order-1, -2 and -3 bases, N seeds per order, the
design rotating with the seed over trapezoids, triangles, random reversals and two recordings; the
score is the number of "nothing_missing" verdicts per order.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.linalg import expm
from scipy.special import gamma

from fitter.core.kernel import simulate
from fitter.core.models import RateIndependentModel
from fitter.data.recordings import Recording
from fitter.diagnosis import diagnose, synthetic_experiment
from fitter.diagnosis.fitting import first_order_ri
from fitter.diagnosis.synthetic import TRUTH_BASE, cell_base

GAP = 1.0
SNR = 15.0


# ----------------------------------------------------------------------------------------------- designs
@dataclass
class Design:
    """An experiment's input on one clock: t, u joined; `parts` the (name, length) of each recording."""

    t: np.ndarray
    u: np.ndarray
    parts: list[tuple[str, int]]

    def recordings(self, y: np.ndarray) -> list[Recording]:
        recs, i = [], 0
        for name, n in self.parts:
            recs.append(Recording(self.t[i : i + n], self.u[i : i + n], y[i : i + n], name=name, source=f"{name}.csv"))
            i += n
        return recs


def _join(pieces: Sequence[tuple[str, np.ndarray, np.ndarray]]) -> Design:
    """Recordings (name, t from 0, u) laid one after the other on one clock, `GAP` s apart."""
    ts, us, parts, t0 = [], [], [], 0.0
    for name, t, u in pieces:
        ts.append(t0 + t)
        us.append(u)
        parts.append((name, len(t)))
        t0 = ts[-1][-1] + GAP
    return Design(np.concatenate(ts), np.concatenate(us), parts)


def _trapezoid(period: float, amp: float, samples: int, cycles: int, hold: float) -> tuple[np.ndarray, np.ndarray]:
    """`cycles` triangles -amp -> amp -> -amp with holds of fraction `hold` at the tips."""
    t = np.linspace(0.0, cycles * period, samples)
    ramp = (1 - 2 * hold) / 2
    knots = [0.0, hold / 2, hold / 2 + ramp, 1.5 * hold + ramp, 1.5 * hold + 2 * ramp, 1.0]
    return t, amp * np.interp((t / period) % 1.0, knots, [-1, -1, 1, 1, -1, -1])


def trapezoid_design(runs: Sequence[tuple[float, float]], samples: int, hold: float = 0.1) -> Design:
    pieces = []
    for j, (period, amp) in enumerate(runs):
        t, u = _trapezoid(period, amp, samples, 2, hold)
        repeat = "_repeat" if j and (period, amp) == tuple(runs[0]) else ""
        pieces.append((f"run{j + 1}_{1 / period:g}Hz{repeat}", t, u))
    return _join(pieces)


def random_design(rng: np.random.Generator, samples: int, recordings: int = 3, points: int = 8) -> Design:
    """Piecewise-linear input between random turning points (minor loops), a random speed per recording."""
    pieces, u_now = [], -1.0
    for j in range(recordings):
        knots, direction = [u_now], 1.0
        for _ in range(points):
            target = float(np.clip(knots[-1] + direction * rng.uniform(0.2, 2.0), -1.0, 1.0))
            if abs(target - knots[-1]) < 0.1:  # at an edge: go the other way
                direction = -direction
                target = float(np.clip(knots[-1] + direction * rng.uniform(0.2, 2.0), -1.0, 1.0))
            knots.append(target)
            direction = -direction
        speed = rng.uniform(0.2, 2.0)
        tk = np.r_[0.0, np.cumsum(np.abs(np.diff(knots)) / speed)]
        t = np.linspace(0.0, tk[-1], samples)
        pieces.append((f"random{j + 1}_{speed:.2f}per_s", t, np.interp(t, tk, knots)))
        u_now = knots[-1]
    return _join(pieces)


def make_design(kind: str, rng: np.random.Generator, samples: int) -> Design:
    if kind == "trapezoids":
        return trapezoid_design(((40.0, 1.0), (8.0, 1.0), (2.0, 1.0), (40.0, 1.0)), samples)
    if kind == "triangles":
        return trapezoid_design(((30.0, 1.0), (6.0, 1.0), (1.5, 1.0), (30.0, 1.0)), samples, hold=0.0)
    if kind == "random":
        return random_design(rng, samples)
    if kind == "two":
        return trapezoid_design(((30.0, 1.0), (5.0, 1.0)), samples)
    raise ValueError(kind)


# ------------------------------------------------------------------------------------------------- bases
def make_base(kind: str) -> RateIndependentModel:
    return first_order_ri(**TRUTH_BASE) if kind == "ri1" else cell_base(int(kind[-1]))


# ------------------------------------------------------------------------------------------ effect forms
def du_convolution(t: np.ndarray, u: np.ndarray, G: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """c(t_k) = sum_{j<k} v_j [G(t_k - t_j) - G(t_k - t_{j+1})] (u piecewise linear; G(0) = 0)."""
    v = np.diff(u) / np.diff(t)
    out = np.zeros(len(t))
    for k0 in range(1, len(t), 512):  # blocks of rows: bounded memory
        tk = t[k0 : k0 + 512, None]
        lo = np.clip(tk - t[None, :-1], 0.0, None)
        hi = np.clip(tk - t[None, 1:], 0.0, None)
        out[k0 : k0 + 512] = (G(lo) - G(hi)) @ v
    return out


def log_creep(t: np.ndarray, u: np.ndarray, tau: float = 0.5) -> np.ndarray:
    return du_convolution(t, u, lambda x: (tau + x) * np.log1p(x / tau) - x)


def half_derivative(t: np.ndarray, u: np.ndarray) -> np.ndarray:
    return du_convolution(t, u, lambda x: np.sqrt(x) / gamma(1.5))


def soft_play(u: np.ndarray, h: float) -> np.ndarray:
    """w = u - z, z the smooth play state (module docstring), exact per sample step."""
    z, w = -h, np.empty_like(u)
    w[0] = u[0] - z
    top = h * (1 - 1e-12)
    for k in range(1, len(u)):
        d = u[k] - u[k - 1]
        s = 1.0 if d >= 0 else -1.0  # mirror a fall onto a rise
        zs, ds = s * z, abs(d)
        if zs < 0:
            step = min(ds, -zs)
            zs, ds = zs + step, ds - step
        if ds > 0:
            zs = h * math.tanh(ds / h + math.atanh(min(zs, top) / h))
        z = s * zs
        w[k] = u[k] - z
    return w


def rate_slowed_first_order(model: RateIndependentModel, t: np.ndarray, w: np.ndarray, alpha: float) -> np.ndarray:
    """Output of a first-order RI model whose dynamics are slowed by s(v) = 1 / (1 + alpha |v|^0.5)."""
    ap, am = float(model.A_plus[0, 0]), float(model.A_minus[0, 0])
    bp, bm = float(model.B_plus[0]), float(model.B_minus[0])
    ep, em = float(model.E_plus[0]), float(model.E_minus[0])
    x = np.empty(len(w))
    x[0] = float(model.x0[0])
    dw = np.diff(w)
    s_all = 1.0 / (1.0 + alpha * np.sqrt(np.abs(dw / np.diff(t))))
    for k, d in enumerate(dw):
        if d == 0:
            x[k + 1] = x[k]
            continue
        a, b, e = (ap, bp, ep) if d > 0 else (am, bm, em)
        s = s_all[k]
        al = s * a  # dx/dw = al x + s (b w + e): exact for w linear
        p = -s * b / al
        q = (p - s * e) / al
        x[k + 1] = p * w[k + 1] + q + (x[k] - p * w[k] - q) * math.exp(al * d)
    return x * float(model.C[0]) + model.D * w


def two_pole(t: np.ndarray, y: np.ndarray, tau: float, zeta: float = 0.7) -> np.ndarray:
    """m'' + 2 zeta omega m' + omega^2 m = omega^2 y, y linear between samples, m(0) = y(0), m'(0) = 0."""
    om = 1.0 / tau
    M = np.zeros((4, 4))
    M[0, 1], M[1, 0], M[1, 1], M[1, 2], M[2, 3] = 1.0, -(om**2), -2 * zeta * om, om**2, 1.0
    h = np.diff(t)
    cache: dict[float, np.ndarray] = {}
    m, mdot, out = y[0], 0.0, np.empty(len(y))
    out[0] = m
    for k, hk in enumerate(h):
        key = float(f"{hk:.9g}")
        if key not in cache:
            cache[key] = expm(M * key)[:2]
        m, mdot = cache[key] @ np.array([m, mdot, y[k], (y[k + 1] - y[k]) / hk])
        out[k + 1] = m
    return out


# ------------------------------------------------------------------------------- effects as chain stages
@dataclass(frozen=True)
class Form:
    """An effect form: where it acts (`stage`) and what it does with strength s.

    stage "input": fn(t, u, s) -> w, the base's input; "rate": fn(model, t, w, s) -> y, the slowed base;
    "output": fn(t, u, y, s) -> y, applied in the case's order.
    """

    stage: str
    fn: Callable


def _hum(t, u, y, s):
    dt_max = max(np.median(np.diff(t[i : i + 50])) for i in range(0, len(t) - 50, 50))
    return y + s * np.sin(2 * np.pi * t / (7 * dt_max) + 0.7)


def _delay(t, u, y, s, lag: float = 0.5):
    return y + s * (np.interp(t - lag, t, u, left=u[0]) - u)


FORMS: dict[str, Form] = {
    "log_creep": Form("output", lambda t, u, y, s: y + s * log_creep(t, u)),
    "sqrt_rate": Form("rate", lambda model, t, w, s: rate_slowed_first_order(model, t, w, s)),
    "soft_backlash": Form("input", lambda t, u, s: soft_play(u, s)),
    "hard_clip": Form("output", lambda t, u, y, s: np.clip(y, y.min() + s, y.max() - s)),
    "two_pole_sensor": Form("output", lambda t, u, y, s: two_pole(t, y, s)),
    "linear_drift": Form("output", lambda t, u, y, s: y + s * (t - t[0])),
    "quadratic_drift": Form("output", lambda t, u, y, s: y + s * ((t - t[0]) / np.ptp(t)) ** 2),
    "exp_drift": Form("output", lambda t, u, y, s: y + s * (1 - np.exp(-3 * (t - t[0]) / np.ptp(t)))),
    "hum": Form("output", _hum),
    "delay": Form("output", _delay),
    "fractional": Form("output", lambda t, u, y, s: y + s * half_derivative(t, u)),
}


def truth_output(model, d: Design, effects: Sequence[tuple[str, float]]) -> np.ndarray:
    """The noise-free output: input effects, then the (possibly slowed) base, then output effects in order."""
    w = d.u
    for name, s in effects:
        if FORMS[name].stage == "input":
            w = FORMS[name].fn(d.t, w, s)
    rate = [(n, s) for n, s in effects if FORMS[n].stage == "rate"]
    y = FORMS[rate[0][0]].fn(model, d.t, w, rate[0][1]) if rate else simulate(model, d.t, w).y
    for name, s in effects:
        if FORMS[name].stage == "output":
            y = FORMS[name].fn(d.t, d.u, y, s)
    return y


def strength_for(model, d: Design, name: str, target: float, y0: np.ndarray) -> float:
    """Strength s with max |y_with - y0| = target (geometric bisection, deviation increasing in s)."""

    def dev(s: float) -> float:
        return float(np.max(np.abs(truth_output(model, d, [(name, s)]) - y0)))

    lo, hi = 1e-9, 1e-2
    while dev(hi) < target:
        lo, hi = hi, hi * 4
    while hi / lo > 1.002:
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if dev(mid) < target else (lo, mid)
    return hi


# ------------------------------------------------------------------------------------------------ cases
@dataclass(frozen=True)
class Case:
    name: str
    group: str  # "catalogue", "two", "outside", "clean"
    effects: tuple[str, ...] = ()  # keys of FORMS
    expected: tuple[str, ...] = ()  # registry effects to be found ("a|b": either)
    design: str = "trapezoids"
    base: str = "ri1"
    seeds: int = 2


CASES = (
    Case("log_creep", "catalogue", ("log_creep",), ("creep|relaxation",)),
    Case("sqrt_rate", "catalogue", ("sqrt_rate",), ("rate_dependence",)),
    Case("soft_backlash", "catalogue", ("soft_backlash",), ("backlash",)),
    Case("hard_clip", "catalogue", ("hard_clip",), ("saturation",)),
    Case("two_pole_sensor", "catalogue", ("two_pole_sensor",), ("sensor_lag",)),
    Case("linear_drift", "catalogue", ("linear_drift",), ("measurement_drift",)),
    Case("quadratic_drift", "catalogue", ("quadratic_drift",), ("measurement_drift",)),
    Case("exp_drift", "catalogue", ("exp_drift",), ("measurement_drift",)),
    Case("log_creep/ri2", "catalogue", ("log_creep",), ("creep|relaxation",), base="ri2", seeds=1),
    Case("linear_drift/ri3", "catalogue", ("linear_drift",), ("measurement_drift",), base="ri3", seeds=1),
    Case("creep+sensor", "two", ("log_creep", "two_pole_sensor"), ("creep|relaxation", "sensor_lag")),
    Case("backlash+drift", "two", ("soft_backlash", "linear_drift"), ("backlash", "measurement_drift")),
    Case("rate+saturation", "two", ("sqrt_rate", "hard_clip"), ("rate_dependence", "saturation")),
    Case("hum", "outside", ("hum",)),
    Case("delay", "outside", ("delay",)),
    Case("fractional", "outside", ("fractional",)),
    Case("clean/triangles", "clean", design="triangles"),
    Case("clean/random", "clean", design="random"),
    Case("clean/two_recordings", "clean", design="two"),
    Case("clean/ri3_auto", "clean", base="ri3", seeds=1),
    Case("clean/synthetic", "clean", design="synthetic"),
)


@dataclass
class Row:
    case: str
    group: str
    seed: int
    expected: str
    verdict: str = ""
    findings: list = field(default_factory=list)
    base_ratio: float = math.nan
    ext_ratio: float = math.nan
    seconds: float = 0.0
    ok: bool = False


def build_experiment(case: Case, seed: int, samples: int) -> tuple[list[Recording], float]:
    """The recordings of `case` for `seed` and the true noise RMS."""
    rng = np.random.default_rng(1000 + seed)
    size = rng.uniform(0.02, 0.03) if case.effects else 0.025
    if case.design == "synthetic":
        recs, truth = synthetic_experiment(None, seed=seed, samples=samples)
        return recs, truth["noise_rms"]
    d = make_design(case.design, rng, samples)
    model = make_base(case.base)
    y0 = simulate(model, d.t, d.u).y
    target = size * float(np.ptp(y0))
    effects = [(name, strength_for(model, d, name, target, y0)) for name in case.effects]
    y = truth_output(model, d, effects)
    sigma = target / SNR
    return d.recordings(y + rng.normal(0.0, sigma, len(y))), sigma


def score_row(case: Case, row: Row) -> bool:
    names = [f["effect"] for f in row.findings]
    if case.group == "catalogue":
        return bool(names) and names[0] in case.expected[0].split("|")
    if case.group == "two":
        return all(set(e.split("|")) & set(names) for e in case.expected)
    if case.group == "outside":
        return row.verdict == "unexplained" or (bool(names) and row.ext_ratio > 1.5)
    return row.verdict == "nothing_missing"


def run_case(case: Case, seed: int, samples: int) -> Row:
    recs, sigma = build_experiment(case, seed, samples)
    t0 = time.perf_counter()
    d = diagnose(recs)
    row = Row(
        case.name,
        case.group,
        seed,
        "+".join(case.expected) or ("unexplained|ext>1.5" if case.group == "outside" else "nothing_missing"),
        d.verdict,
        [
            {
                "effect": f["effect"],
                "p_value": f["p_value"],
                "parameters": f["parameters"],
                "explained_fraction": f["explained_fraction"],
                "consistent": (f.get("consistency") or {}).get("consistent", True),
            }
            for f in d.findings
        ],
        d.baseline["residual_rms"] / sigma,
        d.extended["residual_rms"] / sigma,
        time.perf_counter() - t0,
    )
    row.ok = score_row(case, row)
    return row


def line(row: Row) -> str:
    claimed = (
        ", ".join(
            f"{'' if f.get('consistent', True) else '~'}{f['effect']}"
            f"({100 * f['explained_fraction']:.0f}%; "
            + ", ".join(f"{k}={v:.3g}" for k, v in f["parameters"].items())
            + ")"
            for f in row.findings
        )
        or "-"
    )
    return (
        f"{'PASS' if row.ok else 'FAIL'}  {row.group:9s} {row.case:20s} s{row.seed} expected {row.expected:33s} "
        f"verdict {row.verdict:15s} base/noise {row.base_ratio:5.2f} ext/noise {row.ext_ratio:5.2f} "
        f"{row.seconds:4.1f} s  findings [{claimed}]"
    )


def summary(rows: Sequence[Row]) -> str:
    def frac(group: str | None) -> str:
        sel = [r for r in rows if group is None or r.group == group]
        return f"{sum(r.ok for r in sel)}/{len(sel)}"

    def flagged(group: str) -> str:
        sel = [r for r in rows if r.group == group and r.findings]
        return f"{sum(not r.findings[0].get('consistent', True) for r in sel)}/{len(sel)}"

    return (
        f"score: {frac(None)} cases right; catalogue-in-other-forms {frac('catalogue')}, "
        f"two-effects {frac('two')}, outside-catalogue {frac('outside')}, clean {frac('clean')}\n"
        f"first finding flagged '~' (one parameter set does not hold across the recordings: only approximate): "
        f"outside-catalogue {flagged('outside')}, catalogue-in-other-forms {flagged('catalogue')}, "
        f"two-effects {flagged('two')}"
    )


CLEAN_DESIGNS = ("trapezoids", "triangles", "random", "two")


def clean_controls(seeds: int, samples: int) -> list[Row]:
    """Effect-free experiments of the order-1/2/3 bases, the design rotating with the seed (docstring)."""
    rows = []
    for base in ("ri1", "ri2", "ri3"):
        for seed in range(seeds):
            design = CLEAN_DESIGNS[seed % len(CLEAN_DESIGNS)]
            rows.append(run_case(Case(f"clean/{base}/{design}", "clean", design=design, base=base), seed, samples))
            print(line(rows[-1]), flush=True)
    for base in ("ri1", "ri2", "ri3"):
        sel = [r for r in rows if r.case.startswith(f"clean/{base}/")]
        print(f"clean {base}: nothing_missing in {sum(r.ok for r in sel)}/{len(sel)}")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one seed per case, 350 samples per recording")
    ap.add_argument("--samples", type=int, default=None, help="samples per recording (default 600, quick 350)")
    ap.add_argument("--only", default=None, help="run only the cases whose name contains this")
    ap.add_argument("--json", type=str, default=None, help="write the table to this path")
    ap.add_argument(
        "--clean", type=int, default=None, metavar="N", help="run only the clean controls: orders 1-3, N seeds each"
    )
    args = ap.parse_args()
    samples = args.samples or (350 if args.quick else 600)
    rows, t_start = [], time.perf_counter()
    if args.clean:
        rows = clean_controls(args.clean, samples)
    for case in () if args.clean else CASES:
        if args.only and args.only not in case.name:
            continue
        for seed in range(1 if args.quick else case.seeds):
            rows.append(run_case(case, seed, samples))
            print(line(rows[-1]), flush=True)
    print(f"total {time.perf_counter() - t_start:.0f} s, {samples} samples per recording")
    print(summary(rows))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"samples": samples, "rows": [vars(r) for r in rows], "score": summary(rows)}, fh, indent=1)


if __name__ == "__main__":
    main()
