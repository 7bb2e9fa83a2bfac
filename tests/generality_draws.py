"""Random draws for the generality properties of `duhem fit` and `duhem diagnose` (tests/test_generality.py,
bench/generality_property.py).

A draw is a random *stable* semilinear Duhem device (Oh & Bernstein 2007: rate-independent eqs (1)-(2) or
rate-dependent eqs (18)-(19), order 1-4), driven by a random input, recorded in one or several files with noise
and an output offset per file.  A `DrawSpec` names a draw (its seed and its structural choices); `build_draw`
makes it, deterministically, from the spec alone (numpy's PCG64 streams seeded by (seed, purpose)).  The
generators come in two forms: `draw_specs`, a hypothesis strategy, and `spec_from_seed`, a plain seeded function
(the bench's).  `check_fit` and `check_diagnosis` run the properties on a draw and return what happened, an
exception included (never raised): the tests assert on the outcome, the bench tabulates it.

The device, in normalised units (input s in [-1, 1])
----------------------------------------------------
* rate-independent: A+ = T (-S+ + W+) T^-1 and A- = T (S- - W-) T^-1, S+- symmetric positive definite
  (eigenvalues log-uniform in [0.5, 8] per unit of s), W+- skew (a rotation part), T a random well-conditioned
  change of coordinates (singular values in [1, 3]).  In the norm |T^-1 x| both branches contract (the rising
  flow e^{b A+} and the falling flow e^{-b A-} for every travel b > 0), so the period map of every loop, of any
  span and place, contracts: rho(e^{b A+} e^{-b A-}) < 1 for every b (condition (5) of Theorem 1 on every minor
  loop, which the fit enforces with the margin 0.99, `fitter.core.periodic.minor_loop_rho`), and a branch
  amplifies a state error by at most cond(T) <= 3 (the fit's bound is 1e6).  Both are checked numerically
  (`_check_ri`: minor-loop radius <= 0.9 on the stored input range, the span widened by 5 % each side).
* rate-dependent: A = T (-S + W) T^-1, Hurwitz with every mode's damping ratio -Re(l)/|l| >= 0.3 (the fit
  admits >= 0.1, `RDCanonical.DAMPING`); g(v) = k_sign |v|^p, p in [0.5, 0.8] or [1.25, 1.6] (g(1) = 1, k- in
  [0.6, 1.6]), tabulated (`TabulatedRate`, PCHIP) on +-logspace(-4, 4, 161): g >= 0 and A Hurwitz is the
  convergence condition of the rate-dependent model (`fitter.core.checks`).  |v|^p is a straight line in
  log-rate, which the fit's rate function g(v) = |v| exp(c [v < 0] + h(ln |v| / v_ref)) draws exactly between
  its knots.
* B+-, E+- (or B, E), C, D: standard normal draws (D, E halved); x0 the state after two settled cycles
  -1 -> 1 -> -1 from 0, plus a random kick of 30 % of its size (a start-up transient).

The physical units: u = c + a s (a log-uniform in [1e-2, 1e2], c / a uniform in [-3, 3]),
y = y_s (C x + D s) + offset (y_s log-uniform in [1e-2, 1e2]).  An affine change of the input's and of the output's
unit maps the model class onto itself (the rate-dependent g on v / a; the constant y_s D c / a and the offset
are carried by E, since the state can take any constant output shift: x -> x + d, E -> E - A d), so every
draw's truth is a model of the class, but for the offsets of ``offsets="per_file"`` (below).

Inputs (per file, in s; every file reverses at least twice; the samples are uniform in time)
------------------------------------------------------------------------------------------
Every file starts at one start level s0 (uniform in [-0.8, 0.8], one per draw) from the device's x0: a device
reset before each run.  Its first n // 50 samples (at least 3) ramp from s0 to where the family's input begins,
at that input's mean rate; the family's input follows.  The common start level matters: in the rate-independent
class the coordinates x' = x + K u (B+- -> B+- - A+- K, E+- -> E+- + K, D -> D - C K) give the same input-output
map for any K, so "the same state" at two different inputs is not identified from data, and a stored x0 could not
be the start of a file that begins at another input (measured: fits of the truth's order then missed such files
by 2-20 x the noise while fitting them within it from their own start).
* ``turning_points``: 3-12 legs between random levels (alternating, legs >= 0.15), one leg reaching -1 and
  one +1; each leg at its own speed, log-uniform over a factor 30 (minor loops, and many rates).
* ``sine``: s = A sin(2 pi f t + phi) + m, 1.5-8 periods, A in [0.4, 1], |m| <= 1 - A.
* ``multisine``: 2-4 sines at distinct harmonics 1-7 of f, random amplitudes and phases, scaled into [-1, 1],
  1-4 fundamental periods (minor loops).
* ``triangles``: a train of 2-8 triangles, each from its own low (in [-1, -0.15]) to its own high (in
  [0.15, 1]), -1 and +1 both reached, the triangles' speeds from one or two levels (a factor 2-10 apart).
* ``steps``: a staircase: 4-12 levels, alternately up and down (steps >= 0.15), each reached over one sample
  interval and held for a random share of the samples (a hold moves nothing in the rate-independent model;
  in the rate-dependent one, g(0) = 0).
The time scale is drawn per file so that the typical normalised rate |ds/dt| is log-uniform in [0.1, 10] (the
rate-dependent truths then show their rate dependence across files and within them).

Files, noise, offsets
---------------------
Each file is a separate run from t = 0 (its own clock) of the device from its x0, `samples` x U(0.6, 1) samples
(at least 100).  ``noise``: the standard deviation of white Gaussian output noise as a fraction of the output
range (the range of the noise-free device output y_s (C x + D s) over all files, offsets excluded); 0, or in
[1e-3, 1e-2].  ``offsets="common"``: every file has the same output offset (drawn as N(0, 3) output ranges);
``"per_file"`` (two or more files): each file's offset differs from the first's by U(-0.5, 0.5) output ranges,
an instrument zeroed anew for each run; ``"calibrated"``: the same, and each file's output also scaled by a gain
(the first's 1, the others' log-uniform in [0.5, 2]), an instrument calibrated anew.  All are models of the class:
`duhem fit` fits an output reference per file where the files' zeros differ (the summary's ``references``) and a
gain per file where their scales differ (``gains``), which `FitResult.simulate` applies.

Properties (`check_fit`, `check_diagnosis`)
-------------------------------------------
* `fit_recordings(recs)` returns (any exception is a failure, kept with its type, message and the innermost
  frame inside `fitter`).
* The residual RMS over every sample of every file, from the saved model's own simulation (`FitResult.simulate`,
  its stored x0), is at most `RESIDUAL_FACTOR` = 1.2 x the true noise standard deviation sigma; for a noise-free
  draw at most `NOISELESS_FLOOR` = 1e-3 of the output range.  Why 1e-3: the least noisy draws (noise 1e-3 of the
  range) must reach 1.2e-3 of the range, of which the noise takes 1e-3 and the fit's own error at most
  sqrt(1.2^2 - 1) = 0.66e-3; a fit that cannot bring noise-free data of its own class to 1e-3 of the range could not
  meet the bound of those draws either.  It is far above the floating-point level (the kernel is exact to about
  1e-12 of the range), so it does not depend on any library's last digits.
* The summary's per-recording NRMSE is that same simulation's (RMS error / the recording's output range, within
  1e-6 relative, or 1e-15 absolute below an NRMSE of 1e-9): the number `duhem fit` prints is the saved model's.
* `diagnose(recs)` on a clean rate-independent draw (no effect: the device is a model of the diagnosis' base
  class, the rate-independent one) says "nothing_missing" with no finding.  Rate-dependent draws are not clean
  for it: their rate dependence is an effect its rate-independent base lacks (``rate_dependence``).
"""

from __future__ import annotations

import time
import traceback
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from fitter.core import RateDependentModel, RateIndependentModel, TabulatedRate, simulate
from fitter.data.recordings import Recording

KINDS = ("ri", "rd")
ORDERS = (1, 2, 3, 4)
INPUTS = ("turning_points", "sine", "multisine", "triangles", "steps")
OFFSETS = ("common", "per_file", "calibrated")
GAIN_RANGE = (0.5, 2.0)
MIN_SAMPLES = 100
NOISE_RANGE = (1e-3, 1e-2)
"""Nonzero noise levels (sigma / output range) are drawn log-uniform in this range (module docstring)."""
RESIDUAL_FACTOR = 1.2
NOISELESS_FLOOR = 1e-3
"""Residual bound of a noise-free draw, as a fraction of the output range (module docstring)."""
NRMSE_AGREEMENT = 1e-6
"""Relative agreement of the summary's per-recording NRMSE with the saved model's simulation, of NRMSEs above
`NRMSE_ROUNDING`; below it, absolute (a noise-free draw fitted to 1e-12 of the range: its residual is rounding,
whose relative size is not a property of the code)."""
NRMSE_ROUNDING = 1e-9

_PURPOSE = {"model": 1, "input": 2, "noise": 3, "offsets": 4, "scales": 5, "lengths": 6, "start": 7}
LEAD_IN = 50
"""A file's first n // LEAD_IN samples (at least 3) are its lead-in from the common start level (module docstring)."""


# ------------------------------------------------------------------------------------------------ the spec
@dataclass(frozen=True)
class DrawSpec:
    """A draw: its seed (every number of it) and structural choices (module docstring)."""

    seed: int
    kind: str = "ri"
    order: int = 1
    inputs: str = "sine"
    files: int = 1
    samples: int = 1000
    noise: float = 0.005
    offsets: str = "common"

    def __post_init__(self):
        if self.kind not in KINDS or self.order not in ORDERS or self.inputs not in INPUTS:
            raise ValueError(f"not a draw: {self}")
        if self.offsets not in OFFSETS or (self.offsets != "common" and self.files < 2):
            raise ValueError(f"offsets {self.offsets!r} with {self.files} file(s)")
        if self.samples < MIN_SAMPLES or self.files < 1:
            raise ValueError(f"at least one file of {MIN_SAMPLES} samples: {self}")
        if not (self.noise == 0 or NOISE_RANGE[0] <= self.noise <= NOISE_RANGE[1]):
            raise ValueError(f"noise {self.noise} is neither 0 nor in {NOISE_RANGE}")

    @property
    def label(self) -> str:
        off = {"common": "", "per_file": "/per-file-offsets", "calibrated": "/per-file-offsets-and-gains"}[self.offsets]
        return (
            f"{self.kind}{self.order}/{self.inputs}/{self.files}x{self.samples}/noise{self.noise:.4f}{off}/s{self.seed}"
        )


def spec_from_seed(seed: int, min_samples: int = MIN_SAMPLES, max_samples: int = 5000) -> DrawSpec:
    """A random `DrawSpec` from `seed` (numpy only): kind, order, input, 1-3 files, samples per file log-uniform
    in [min_samples, max_samples], noise 0 (one draw in five) or log-uniform in `NOISE_RANGE`, offsets per file
    in half of the draws with several files, and in half of those a gain per file too."""
    rng = np.random.default_rng([seed, 0])
    files = int(rng.integers(1, 4))
    samples = int(round(np.exp(rng.uniform(np.log(min_samples), np.log(max_samples)))))
    noise = 0.0 if rng.random() < 0.2 else float(np.exp(rng.uniform(*np.log(NOISE_RANGE))))
    spec = DrawSpec(
        seed=seed,
        kind=str(rng.choice(KINDS)),
        order=int(rng.integers(1, 5)),
        inputs=str(rng.choice(INPUTS)),
        files=files,
        samples=max(MIN_SAMPLES, samples),
        noise=round(noise, 5),
        offsets="per_file" if files > 1 and rng.random() < 0.5 else "common",
    )
    if spec.offsets == "per_file" and rng.random() < 0.5:  # drawn last: the other choices stay those of the seed
        spec = replace(spec, offsets="calibrated")
    return spec


def draw_specs(
    max_samples: int = 5000,
    kinds=KINDS,
    orders=ORDERS,
    inputs=INPUTS,
    max_files: int = 3,
    per_file_offsets: bool = True,
):
    """The hypothesis strategy of `DrawSpec`s (the same space as `spec_from_seed`, narrowed by the arguments)."""
    from hypothesis import strategies as st

    @st.composite
    def spec(draw):
        files = draw(st.integers(1, max_files))
        offsets = draw(st.sampled_from(OFFSETS)) if per_file_offsets and files > 1 else "common"
        noise = draw(st.one_of(st.just(0.0), st.floats(*NOISE_RANGE).map(lambda x: round(x, 5))))
        return DrawSpec(
            seed=draw(st.integers(0, 2**31 - 1)),
            kind=draw(st.sampled_from(kinds)),
            order=draw(st.sampled_from(orders)),
            inputs=draw(st.sampled_from(inputs)),
            files=files,
            samples=draw(st.integers(MIN_SAMPLES, max_samples)),
            noise=noise,
            offsets=offsets,
        )

    return spec()


def _rng(spec: DrawSpec, purpose: str) -> np.random.Generator:
    return np.random.default_rng([spec.seed, _PURPOSE[purpose]])


# ---------------------------------------------------------------------------------------------- the device
def _coordinates(rng: np.random.Generator, n: int) -> np.ndarray:
    """T = Q1 diag(s) Q2, singular values in [1, 3]: cond(T) <= 3."""
    q1, _ = np.linalg.qr(rng.standard_normal((n, n)))
    q2, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return q1 @ np.diag(rng.uniform(1.0, 3.0, n)) @ q2


def _dissipative(rng: np.random.Generator, n: int, rotation: float) -> np.ndarray:
    """-S + W: S symmetric positive definite (eigenvalues log-uniform in [0.5, 8]), W skew of size `rotation`."""
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    S = q @ np.diag(np.exp(rng.uniform(np.log(0.5), np.log(8.0), n))) @ q.T
    K = rng.standard_normal((n, n))
    return -S + rotation * (K - K.T) / 2


def _warm_x0(model, rng: np.random.Generator):
    """The state after two cycles -1 -> 1 -> -1 from 0 (on the settled loop at s = -1), kicked by 30 % of its
    size in a random direction."""
    cycle = np.r_[np.linspace(-1, 1, 201), np.linspace(1, -1, 201)[1:]]
    s = np.r_[cycle, cycle[1:]]
    t = np.linspace(0.0, 8.0, len(s))  # |ds/dt| = 1: the rate-dependent model at g(1) = 1
    x = simulate(model.replace(x0=np.zeros(model.order)), t, s).x[-1]
    kick = rng.standard_normal(model.order)
    kick *= 0.3 * max(float(np.linalg.norm(x)), 0.1) / max(float(np.linalg.norm(kick)), 1e-12)
    return model.replace(x0=x + kick)


def random_ri(rng: np.random.Generator, n: int) -> RateIndependentModel:
    """A random rate-independent device of order n whose loops all converge (module docstring), normalised
    input s in [-1, 1]."""
    while True:
        T = _coordinates(rng, n)
        Ti = np.linalg.inv(T)
        a_plus = T @ _dissipative(rng, n, rng.uniform(0.0, 4.0)) @ Ti
        a_minus = -(T @ _dissipative(rng, n, rng.uniform(0.0, 4.0)) @ Ti)
        model = RateIndependentModel(
            A_plus=a_plus,
            A_minus=a_minus,
            B_plus=rng.standard_normal(n) * 2.0,
            B_minus=rng.standard_normal(n) * 2.0,
            E_plus=rng.standard_normal(n),
            E_minus=rng.standard_normal(n),
            C=rng.standard_normal(n),
            D=0.5 * rng.standard_normal(),
        )
        if _check_ri(model):
            return _warm_x0(model, rng)


def _check_ri(model: RateIndependentModel) -> bool:
    """Condition (5) on every minor loop of the stored input range with a margin (radius <= 0.9), and a
    branch amplification below 10 (the fit's limits: 0.99 and 1e6)."""
    from fitter.core.periodic import minor_loop_rho
    from fitter.core.kernel import expm

    rho = minor_loop_rho(model, -1.1, 1.1)
    amp = max(np.linalg.norm(expm(b * model.A_plus), 2) for b in (0.5, 1.0, 2.2))
    amp = max(amp, max(np.linalg.norm(expm(-b * model.A_minus), 2) for b in (0.5, 1.0, 2.2)))
    return bool(rho <= 0.9 and amp < 10.0)


RATE_NODES = np.logspace(-4, 4, 161)


def random_rd(rng: np.random.Generator, n: int) -> RateDependentModel:
    """A random rate-dependent device of order n (module docstring): A Hurwitz with damping ratio >= 0.3,
    g(v) = k_sign |v|^p tabulated."""
    while True:
        T = _coordinates(rng, n)
        A = T @ _dissipative(rng, n, rng.uniform(0.0, 3.0)) @ np.linalg.inv(T)
        lam = np.linalg.eigvals(A)
        if np.max(lam.real) < 0 and np.min(-lam.real / np.abs(lam)) >= 0.3:
            break
    p = rng.uniform(0.5, 0.8) if rng.random() < 0.5 else rng.uniform(1.25, 1.6)
    k_minus = rng.uniform(0.6, 1.6)
    v = np.r_[-RATE_NODES[::-1], RATE_NODES]
    g = np.abs(v) ** p * np.where(v < 0, k_minus, 1.0)
    model = RateDependentModel(
        A=A,
        B=rng.standard_normal(n) * 2.0,
        E=rng.standard_normal(n),
        C=rng.standard_normal(n),
        D=0.5 * rng.standard_normal(),
        g=TabulatedRate(v, g),
    )
    return _warm_x0(model, rng)


# ---------------------------------------------------------------------------------------------- the inputs
def _legs_to_samples(levels: np.ndarray, durations: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Piecewise-linear input through `levels` (the legs taking `durations`), sampled at n uniform times."""
    tk = np.r_[0.0, np.cumsum(durations)]
    t = np.linspace(0.0, tk[-1], n)
    return t, np.interp(t, tk, levels)


def _alternating_levels(rng: np.random.Generator, count: int, min_step: float = 0.15) -> np.ndarray:
    """`count` levels in [-1, 1], alternately up and down, each step >= min_step, -1 and +1 both reached."""
    levels = [rng.uniform(-1.0, 1.0)]
    up = rng.random() < 0.5
    for _ in range(count - 1):
        lo, hi = (levels[-1] + min_step, 1.0) if up else (-1.0, levels[-1] - min_step)
        if hi - lo < 1e-9:  # at an edge: turn
            up = not up
            lo, hi = (levels[-1] + min_step, 1.0) if up else (-1.0, levels[-1] - min_step)
        levels.append(rng.uniform(lo, hi))
        up = not up
    levels = np.array(levels)
    i_max, i_min = int(np.argmax(levels)), int(np.argmin(levels))
    levels[i_max], levels[i_min] = 1.0, -1.0
    return levels


def _reversals(s: np.ndarray) -> int:
    d = np.sign(np.diff(s))
    d = d[d != 0]
    return int(np.count_nonzero(d[1:] != d[:-1]))


def random_input(rng: np.random.Generator, inputs: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(t, s): n samples of the input family `inputs` (module docstring), normalised (s in [-1, 1]) at a
    typical rate log-uniform in [0.1, 10]."""
    rate = float(np.exp(rng.uniform(np.log(0.1), np.log(10.0))))
    if inputs == "turning_points":
        levels = _alternating_levels(rng, int(rng.integers(4, 13)))
        speeds = rate * np.exp(rng.uniform(-np.log(30) / 2, np.log(30) / 2, len(levels) - 1))
        return _legs_to_samples(levels, np.abs(np.diff(levels)) / speeds, n)
    if inputs == "sine":
        periods, amp = rng.uniform(1.5, 8.0), rng.uniform(0.4, 1.0)
        mid = rng.uniform(-(1 - amp), 1 - amp)
        f = rate / (4 * amp)  # mean |ds/dt| of A sin(2 pi f t) is 4 A f
        t = np.linspace(0.0, periods / f, n)
        return t, mid + amp * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    if inputs == "multisine":
        k = rng.choice(np.arange(1, 8), size=int(rng.integers(2, 5)), replace=False)
        amps, phases = rng.uniform(0.2, 1.0, len(k)), rng.uniform(0, 2 * np.pi, len(k))
        periods = rng.uniform(1.0, 4.0)
        grid = np.linspace(0.0, periods, n)  # in fundamental periods
        s = np.sum(amps[:, None] * np.sin(2 * np.pi * k[:, None] * grid[None] + phases[:, None]), axis=0)
        s = 2 * (s - s.min()) / np.ptp(s) - 1
        mean_rate = np.mean(np.abs(np.diff(s))) * (n - 1) / periods  # per fundamental period
        return grid * mean_rate / rate, s
    if inputs == "triangles":
        count = int(rng.integers(2, 9))
        lows, highs = rng.uniform(-1.0, -0.15, count + 1), rng.uniform(0.15, 1.0, count)
        lows[int(rng.integers(count + 1))], highs[int(rng.integers(count))] = -1.0, 1.0
        levels = np.r_[np.ravel(np.column_stack([lows[:-1], highs])), lows[-1]]
        ratio = rng.uniform(2.0, 10.0) if rng.random() < 0.5 else 1.0
        speed = np.repeat(np.where(rng.random(count) < 0.5, rate, rate * ratio), 2)
        return _legs_to_samples(levels, np.abs(np.diff(levels)) / speed, n)
    if inputs == "steps":
        levels = _alternating_levels(rng, int(rng.integers(4, 13)))
        holds = rng.dirichlet(np.ones(len(levels)))
        counts = np.maximum(2, np.floor(holds * (n - len(levels))).astype(int))
        counts[-1] += n - int(np.sum(counts))
        if counts[-1] < 2:
            counts = np.maximum(2, counts - 1)
            counts[int(np.argmax(counts))] += n - int(np.sum(counts))
        s = np.repeat(levels, counts)
        dt = float(np.mean(np.abs(np.diff(levels)))) / rate / max(float(np.mean(counts)), 1.0)
        return np.arange(n) * dt, s
    raise ValueError(f"unknown input family {inputs!r}")


# ------------------------------------------------------------------------------------------------- the draw
@dataclass
class Draw:
    """A built draw: the truth (normalised units), the recordings (physical units) and the noise."""

    spec: DrawSpec
    truth: object
    recordings: list[Recording]
    clean: list[np.ndarray]
    sigma: float
    output_range: float
    offsets: list[float]
    units: dict = field(default_factory=dict)
    gains: list = field(default_factory=list)
    """Each file's output gain (the first's 1; "calibrated" draws only differ from 1)."""

    @property
    def bound(self) -> float:
        """The residual bound of the fit property (module docstring), in output units."""
        return RESIDUAL_FACTOR * self.sigma if self.sigma > 0 else NOISELESS_FLOOR * self.output_range


def _lead_in(t: np.ndarray, s: np.ndarray, s0: float, k: int) -> tuple[np.ndarray, np.ndarray]:
    """k samples ramping from the start level s0 towards s[0] at the input's mean rate (k sample periods at
    least), then (t, s): every file starts at s0."""
    dt = float(np.median(np.diff(t)))
    rate = float(np.mean(np.abs(np.diff(s)) / np.diff(t)))
    lead = max(k * dt, abs(s[0] - s0) / max(rate, 1e-12))
    return np.r_[np.linspace(0.0, lead, k + 1)[:-1], lead + t], np.r_[np.linspace(s0, s[0], k + 1)[:-1], s]


def build_draw(spec: DrawSpec) -> Draw:
    """The draw of `spec` (module docstring), deterministic in `spec`."""
    model_rng = _rng(spec, "model")
    truth = random_ri(model_rng, spec.order) if spec.kind == "ri" else random_rd(model_rng, spec.order)
    scales = _rng(spec, "scales")
    a = float(np.exp(scales.uniform(np.log(1e-2), np.log(1e2))))
    c = a * scales.uniform(-3.0, 3.0)
    y_s = float(np.exp(scales.uniform(np.log(1e-2), np.log(1e2))))
    lengths = _rng(spec, "lengths")
    sizes = [max(MIN_SAMPLES, int(round(spec.samples * lengths.uniform(0.6, 1.0)))) for _ in range(spec.files)]
    sizes[0] = spec.samples
    input_rng = _rng(spec, "input")
    s0 = float(_rng(spec, "start").uniform(-0.8, 0.8))
    runs = []
    for n in sizes:
        k = max(3, n // LEAD_IN)
        for _ in range(20):
            t, s = _lead_in(*random_input(input_rng, spec.inputs, n - k), s0, k)
            if _reversals(s) >= 2:
                break
        else:
            raise ValueError(f"{spec.label}: no input with two reversals in 20 tries")
        runs.append((t, s, y_s * simulate(truth, t, s).y))
    output_range = float(np.ptp(np.concatenate([y for _, _, y in runs])))
    sigma = spec.noise * output_range
    off_rng = _rng(spec, "offsets")
    base = float(off_rng.normal(0.0, 3.0)) * output_range
    offsets = [base] * spec.files
    if spec.offsets != "common":
        offsets = [base] + [base + float(off_rng.uniform(-0.5, 0.5)) * output_range for _ in range(spec.files - 1)]
    gains = [1.0] * spec.files
    if spec.offsets == "calibrated":
        gains[1:] = np.exp(off_rng.uniform(*np.log(GAIN_RANGE), spec.files - 1)).tolist()
    noise_rng = _rng(spec, "noise")
    recs, clean = [], []
    for i, ((t, s, y), off, gain) in enumerate(zip(runs, offsets, gains)):
        y_clean = gain * y + off
        y_meas = y_clean + sigma * noise_rng.standard_normal(len(y))
        name = f"file{i + 1}"
        recs.append(Recording(t, c + a * s, y_meas, name=name, source=f"{name}.csv"))
        clean.append(y_clean)
    units = {"u_scale": a, "u_centre": c, "y_scale": y_s}
    return Draw(spec, truth, recs, clean, sigma, output_range, offsets, units, gains)


# ----------------------------------------------------------------------------------------------- properties
def _where(exc: BaseException) -> str:
    """The innermost traceback frame inside the package `fitter` (else the innermost), as path:line in func."""
    frames = traceback.extract_tb(exc.__traceback__)
    inside = [f for f in frames if "/fitter/" in f.filename.replace("\\", "/")]
    f = (inside or frames)[-1]
    path = f.filename.replace("\\", "/")
    path = path[path.rfind("/fitter/") + 1 :] if "/fitter/" in path else path
    return f"{path}:{f.lineno} in {f.name}"


@dataclass
class FitOutcome:
    """What `check_fit` saw: the exception (type: message, where) or the chosen model and its residual."""

    label: str
    seconds: float
    error: str | None = None
    where: str | None = None
    chosen: str | None = None
    residual_rms: float | None = None
    bound: float | None = None
    ratio: float | None = None
    """residual_rms / bound: the property holds when <= 1."""
    noise_ratio: float | None = None
    """residual_rms / sigma (None for a noise-free draw)."""
    nrmse_mismatch: float | None = None
    """Largest relative difference between the summary's per-recording NRMSE and the simulation's."""
    own_x0_ratio: float | None = None
    """The residual from each recording's own fitted start (the summary's ``nrmse_x0_fitted``) over the bound."""
    per_file_ratio: list | None = None
    gains: dict | None = None  # the output gains the fit found (the summary's ``gains``), None: none
    """Each file's residual RMS (stored x0) over the bound."""
    cpu_seconds: float | None = None

    @property
    def raised(self) -> bool:
        return self.error is not None

    @property
    def within_bound(self) -> bool:
        return self.ratio is not None and self.ratio <= 1.0

    @property
    def summary_agrees(self) -> bool:
        return self.nrmse_mismatch is not None and self.nrmse_mismatch <= NRMSE_AGREEMENT

    def to_dict(self) -> dict:
        return asdict(self)


def check_fit(draw: Draw, **fit_kwargs) -> FitOutcome:
    """`fit_recordings(draw.recordings)` and the fit properties (module docstring); never raises."""
    from fitter.identification.fit import fit_recordings

    t0, c0 = time.perf_counter(), time.process_time()
    try:
        res = fit_recordings(draw.recordings, **fit_kwargs)
        sims = [res.simulate(rec) for rec in draw.recordings]
    except Exception as exc:  # noqa: BLE001 - any exception is the finding
        return FitOutcome(
            draw.spec.label, time.perf_counter() - t0, error=f"{type(exc).__name__}: {exc}", where=_where(exc)
        )
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    resid = np.concatenate([rec.y - y for rec, y in zip(draw.recordings, sims)])
    rms = float(np.sqrt(np.mean(resid**2))) if np.all(np.isfinite(resid)) else float("inf")
    mismatch = 0.0
    own = []
    for rec, y, score in zip(draw.recordings, sims, res.summary["recordings"]):
        mine = float(np.sqrt(np.mean((rec.y - y) ** 2)) / np.ptp(rec.y))
        theirs = score.get("nrmse")
        mismatch = max(mismatch, float("inf") if theirs is None else abs(theirs - mine) / max(mine, NRMSE_ROUNDING))
        own_nrmse = score.get("nrmse_x0_fitted")
        own.append(np.inf if own_nrmse is None else own_nrmse * np.ptp(rec.y))
    n = np.array([len(r.y) for r in draw.recordings])
    own_rms = float(np.sqrt(np.sum(n * np.square(own)) / np.sum(n)))
    return FitOutcome(
        draw.spec.label,
        seconds,
        chosen=f"{res.summary['kind']}{res.summary['order']}",
        residual_rms=rms,
        bound=draw.bound,
        ratio=rms / draw.bound,
        noise_ratio=rms / draw.sigma if draw.sigma > 0 else None,
        nrmse_mismatch=mismatch,
        own_x0_ratio=own_rms / draw.bound,
        per_file_ratio=[float(np.sqrt(np.mean((r.y - y) ** 2))) / draw.bound for r, y in zip(draw.recordings, sims)],
        gains=(res.summary.get("gains") or {}).get("values"),
        cpu_seconds=cpu,
    )


@dataclass
class DiagnosisOutcome:
    """What `check_diagnosis` saw: the exception, or the verdict, the findings and the residual / noise."""

    label: str
    seconds: float
    error: str | None = None
    where: str | None = None
    verdict: str | None = None
    findings: list = field(default_factory=list)
    base: str | None = None
    base_noise_ratio: float | None = None
    """The base model's residual RMS over the diagnosis' own noise estimate."""
    noise_estimate_ratio: float | None = None
    """The diagnosis' noise estimate over the true sigma (None for a noise-free draw)."""
    cpu_seconds: float | None = None

    @property
    def clean(self) -> bool:
        return self.error is None and self.verdict == "nothing_missing" and not self.findings

    def to_dict(self) -> dict:
        return asdict(self)


def check_diagnosis(draw: Draw) -> DiagnosisOutcome:
    """`fitter.diagnosis.diagnose(draw.recordings)` (what `duhem diagnose` runs, defaults); never raises."""
    from fitter.diagnosis import diagnose

    t0, c0 = time.perf_counter(), time.process_time()
    try:
        d = diagnose(draw.recordings)
    except Exception as exc:  # noqa: BLE001 - any exception is the finding
        return DiagnosisOutcome(
            draw.spec.label, time.perf_counter() - t0, error=f"{type(exc).__name__}: {exc}", where=_where(exc)
        )
    return DiagnosisOutcome(
        draw.spec.label,
        time.perf_counter() - t0,
        verdict=d.verdict,
        findings=[
            {
                "effect": f["effect"],
                "p_value": f["p_value"],
                "explained_fraction": f["explained_fraction"],
                "parameters": f["parameters"],
            }
            for f in d.findings
        ],
        base=f"{d.base_model.kind}{d.base_model.order}",
        base_noise_ratio=d.baseline["residual_rms"] / d.noise_rms if d.noise_rms else float("inf"),
        noise_estimate_ratio=d.noise_rms / draw.sigma if draw.sigma > 0 else None,
        cpu_seconds=time.process_time() - c0,
    )
