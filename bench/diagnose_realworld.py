"""Real-world tier for `duhem diagnose`: physics as laboratories record it, NOT the catalogue's formulas.

    python bench/diagnose_realworld.py              # 2 seeds per effect case, 4 per control, 400 samples per file
    python bench/diagnose_realworld.py --quick      # 1 seed per case, 300 samples per file
    python bench/diagnose_realworld.py --seeds 10 --only control     # 10 seeds of every control
    (--json PATH: also write the table as JSON; --samples N: samples per file; --only TEXT: the cases whose
    name contains TEXT)

Every truth is simulated here with numpy/scipy from its own physics (no `fitter` code makes any truth:
`fitter` is called only to diagnose, `fitter.diagnosis.diagnose(recordings)` with its defaults, and its
`Recording` holds the files).  The catalogue's exact forms (`fitter.core.effects`) are avoided on purpose:
the diagnosis must name the right physics when the data only resemble its catalogue, and claim nothing
when there is nothing to claim.

The recordings, as instruments write them
-----------------------------------------
* Each case is 3-4 separate files (`Recording(t, u, y, name=...)`), each on its own clock from t = 0,
  recorded one after another, each at its own rate and amplitude (its "design": a list of (waveform,
  period, amplitude, cycles)).  Diagnosed without any option: the files are recognised as separate runs
  because every one starts at t = 0.
* Waveforms, all starting at u = 0 going up (as a tester starts a loop at zero): ``triangle``
  0 -> A -> -A -> 0; ``trapezoid`` the same with holds of 20 % of the period at each tip (ramp up 15 %,
  hold 20 %, ramp down 30 %, hold 20 %, ramp up 15 %); ``sine`` A sin(2 pi t / T).  m samples per
  cycle (m a multiple of 20, so that every corner of a waveform is a sample), `cycles` cycles per file.
* Each file is preceded by one unrecorded pre-cycle of its own waveform (the instrument's poling /
  conditioning cycle; the material's state at t = 0 is where that cycle leaves it) unless said otherwise.
* The instrument: Y = range of the noise-free outputs over all files of the case; each file gets its own
  reference (the instrument's zero: a constant offset drawn uniformly in +-15 % of Y) and white Gaussian
  noise of RMS 0.3 % of Y.  Everything is seeded (`numpy.random.default_rng((crc32(case), seed))`); the
  material's parameters are drawn per seed in the ranges below.

Notation: u the input, y the material's output, s = sign(du/dt) the branch, N(z) the standard normal
quantile nodes z_j = Phi^-1((j - 1/2)/J).  "Effect size" (column ``eff%``) is max |y - y_twin| / Y, y_twin
the same truth without the effect (left out for the switching kinetics, which are the whole loop).

Effect cases
------------
``ferro_kai``: ferroelectric switching with nucleation kinetics (Kolmogorov-Avrami-Ishibashi with Merz's
  law and a distribution of activation fields, as in the nucleation-limited-switching picture).  Input E
  (kV/cm, amplitude 60), output P (uC/cm2).  J = 24 domain populations j with activation fields
  Ea_j = Ea exp(sigma z_j) (lognormal, sigma in [0.15, 0.3]); each switched fraction s_j in [-1, 1] obeys
  KAI kinetics in the time-varying field: when E turns to sign g, s_ref = s_j and
  Theta_j = integral since then of r_j(E) dt, r_j = exp(-Ea_j / |E|) / tau0 (Merz), and
  s_j = g - (g - s_ref) exp(-Theta_j^n), Avrami index n in [1.5, 2.5], tau0 in [3e-5, 3e-4] s, Ea set so
  that the coercive field at 1 Hz is 0.5 x 60 kV/cm (Ec(f) ~ Ea / ln(1 / (4 f tau0)): it grows with the
  rate, logarithmically).  P = Ps mean_j s_j + eps E (Ps in [20, 30], eps E up to 10 % of Ps), s_j = -1
  (poled) before the pre-cycle.  Exact per sample interval (E linear; Theta by 8-point Gauss-Legendre,
  the interval split where E crosses 0).  Files: triangles of period 100, 10, 1 s at 60 kV/cm and 10 s at
  48 kV/cm (2 cycles).
  Right: ``switching`` (the catalogue's form of the same physics: populations driven by exponential rates
  in the field, with a spread of thresholds) or ``rate_dependence`` (a loop whose width grows with the
  rate: the catalogue's rate-dependent hysteresis; the kinetics' macroscopic signature).  NOT relaxation
  or creep: those are linear memories of the input, while switching is the nonlinear, thresholded
  reversal of the polarisation; naming them is the failure the issue reports.  ``saturation`` is
  tolerated as a second material finding (the switched polarisation does saturate at +-Ps).

``eddy_bh``: B-H loops of a conducting soft-magnetic lamination with classical eddy-current loss.  Input
  the applied field Ha (A/m, sinusoidal, as a magnetising current), output B (T).  The applied field is
  shared between the rate-independent hysteresis and the eddy field: Ha = Hh + k_e dB/dt (k_e = sigma
  d^2 / 12 of a lamination of thickness d), B = mu_rev Hh + Js m, and the irreversible magnetisation m
  approaches the branch curve of its direction, m_s(Hh) = tanh((Hh - s Hc) / a), only towards it
  (dm/dHh = lam max(s (m_s - m), 0), s = sign dHh/dt, the Jiles-Atherton rule that keeps dB/dH >= 0 on
  minor loops).  So dHh/dt = (Ha - Hh) / (k_e mu_d), mu_d = mu_rev + Js lam max(s (m_s - m), 0), a stiff
  ODE solved by scipy (Radau).  Hc in [15, 25], a in [10, 20], lam = 2/a, Js in [1.2, 1.6] T, mu_rev
  = 0.05 Js / 100 (per A/m), k_e such that the eddy time constant on the steep part of the loop,
  k_e Js lam, is 2-5 % of the 200 Hz period.  Files: sines of 10, 50, 200 Hz at
  100 A/m and 50 Hz at 40 A/m (minor loops), 2 cycles.  Twin: k_e -> 0 (the quasi-static loop).
  Right: ``viscous`` (to first order the eddy field makes B(Ha) = B_h(Ha - k_e dB/dt) ~ B_h(Ha) -
  k_e mu_d^2 dHa/dt: an output term proportional to the input rate, here with a state-dependent gain) or
  ``rate_dependence`` (the loop widens with frequency: the classical loss per cycle grows as f).  NOT
  relaxation/creep, NOT a sensor lag (the eddy currents are the material's, not the instrument's).
  ``saturation`` is tolerated as a second material finding: the material does saturate (tanh branches).

``damper_bw``: a magnetorheological damper (Spencer's phenomenological model without its filter).  Input
  the displacement x (mm, sines), output the force F (N) = c dx/dt + k x + alpha z, Bouc-Wen
  dz/dx = (1 - (beta s sign(z) + gamma) |z|^n) / x_y (s = sign dx/dt), n = 2, beta in [0.55, 0.85],
  gamma = 1 - beta, yield displacement x_y in [0.5, 1.5] mm, alpha in [300, 500] N, k in [2, 6] N/mm;
  c (N s/mm) such that c max|dx/dt| is 20-35 % of alpha at the fastest file.  Files: sines of period 4,
  1, 0.5 s at 10, 10, 5 mm and 0.25 s at 5 mm, 2 cycles.  Twin: c = 0 (that is the ``control_bouc_wen``
  truth).  Right: ``viscous`` only (the force c dx/dt is a viscous term exactly; a creep with a negative
  gain and a short time constant, the failure the issue reports, is that term in disguise).

``creep_drift``: a piezo stack under trapezoidal voltage with two-time-constant creep and a slow drift of
  the charge amplifier's zero.  Input u (V, amplitude 100), output displacement (um) = Bouc-Wen (n = 1,
  y = d33 u + alpha z, dz/du = (1 - (beta s sign(z) + gamma)|z|) / u_y, d33 = 0.1 um/V, beta in
  [0.55, 0.85], gamma = 1 - beta, u_y in [10, 25] V; the hysteresis alpha z spans 12 % of the stroke)
  + c1 + c2, each creep a Kelvin-Voigt element dc_i/dt = (k_i u - c_i) / tau_i, tau1 in [1, 3] s,
  tau2 in [25, 80] s, k1 + k2 such that the creep is 6-10 % of the stroke (k2 / k1 in [0.5, 2]),
  plus a drift of the reading d(t) = r T_d (1 - exp(-t / T_d)) from each file's start (the amplifier's
  offset current, settling with T_d in [400, 900] s), r such that the drift over the longest file is
  2-4 % of the stroke.  Two exponentials are neither the catalogue's one-term creep nor its four
  log-spaced relaxation times; the drift is curved, not linear.  Files: trapezoids (holds 20 %) of period
  20, 60, 200 s at 100 V and 60 s at 60 V, 2 cycles.  Twin: no creep, no drift.
  Right: a material ``creep`` or ``relaxation`` (both are the linear viscoelastic memory, one or four
  exponentials) AND ``measurement_drift`` among the measurement findings (the drift is the instrument's,
  not the material's; naming it thermal_drift or a material creep alone is wrong).

``heating``: self-heating of a ferroelectric cycled at several rates.  Input E (kV/cm, triangles),
  output P = g(theta) Ps m + eps E, m the rate-independent branch loop of ``eddy_bh``
  (dm/dE = lam max(s (tanh((E - s Ec)/a) - m), 0)); the heat released is the pinning loss,
  proportional to |dm| (Jiles-Atherton: the loop area is 4 Ec Ps per cycle), and the sample cools to the
  bath: d theta/dt = eta |dm/dt| - theta / tau_th (theta = T rise / Curie distance), the spontaneous
  polarisation falls as g = sqrt(1 - theta) (Landau).  Each file starts cool (theta = 0 at the start of its
  pre-cycle: the sample rests between files).  tau_th in [5, 15] s, eta such that theta reaches 0.2-0.3
  at the end of the fastest file.  Files: triangles of period 0.5, 5, 50 s at 60 kV/cm and 5 s at 45
  kV/cm, 4 cycles each: a fast file heats (no time to cool), a slow one does not, so the gain loss is
  neither a function of the input travel alone nor linear in it.  Twin: eta = 0.
  Right: ``thermal_drift`` (the catalogue's self-heating: a gain changing with the input travel), or an
  honest "unexplained" with no material claim.  Any other material claim is wrong (``saturation`` is
  tolerated beside thermal_drift, as for every saturating loop here).

``degradation``: ferroelectric fatigue: the switchable polarisation falls with the number of switching
  cycles N (domain-wall pinning), P = (1 - f ln(1 + N / N0)) Ps m + eps E, m the branch loop as in
  ``heating``, N = integral of |dm| / 4 counted from the first pre-cycle and carried from file to file
  (the files are recorded one after another on the same sample: each starts more fatigued than the
  last).  f in [0.04, 0.07], N0 in [0.5, 2].  Files: triangles of period 2, 0.5, 10, 2 s at 60, 60, 60,
  48 kV/cm, 4, 4, 3, 4 cycles.  Twin: f = 0.
  Right: ``thermal_drift`` (the catalogue's only gain loss with cycling, a loop shrinking with the
  input travel; its name says self-heating, its form is fatigue's too) or an honest "unexplained" with
  no material claim.

Effect-free controls (references per file and noise only)
--------------------------------------------------------
``control_duhem1`` / ``2`` / ``3``: semilinear Duhem models of order n, dx/dt = du+/dt (A+ x + B+ u + E+)
  + du-/dt (A- x + B- u + E-), y = C x, integrated here exactly per sample interval (u linear on it:
  the augmented matrix exponential of [[A_s, B_s, E_s], [0, 0, 1], [0, 0, 0]] over du, s the branch).
  the input in V (amplitude U = 50): A+ = -diag(a) + K (a_i log-uniform in [1.5, 12] / U, K
  off-diagonal, uniform in +-0.25 min a), A- = diag(a') - K' (a' = a x U[0.7, 1.4], K' likewise),
  B+ = a b, B- = -a' b, E+ = -a e, E- = -a' e (b in [0.6, 1.4], e in [0.2, 0.6] x U), C positive
  random, scaled so that the loop of amplitude U spans 10, x0 = 0 before the pre-cycle.  Files:
  triangles of period 40, 8, 2, 8 s at 50, 35, 50, 42 V, 2 cycles.
``control_bouc_wen``: the ``damper_bw`` truth with c = 0 and n drawn in [1.2, 3] (rate-independent).
``control_preisach``: a Preisach model: a grid of 120 x 120 thresholds alpha > beta on [-1.2, 1.2] x
  the amplitude, relays +-1 switching up at u >= alpha and down at u <= beta (all down before the
  pre-cycle), weights w(alpha, beta) = Gaussian in the interaction field (alpha + beta)/2 (sd in [0.1,
  0.25]) times a lognormal in the coercive field (alpha - beta)/2 (median in [0.25, 0.5], log-sd in
  [0.3, 0.6]), y = sum w R + c u (reversible part c u 10-25 % of the output), the input in V
  (amplitude 10).  Files: triangles of period 10, 10, 1, 10 s at 10, 7, 10, 5 V (nested minor loops,
  where Preisach's wiping-out differs from a Duhem model), 2 cycles.
  Right for every control: no material finding (verdict "nothing_missing", or any verdict whose findings
  are only measurement effects).  A material finding on a control is always wrong.

Scoring (column ``right?``)
---------------------------
An effect case is right when (a) at least one material finding is in its accepted set, every material
finding is in the accepted set or its tolerated set, and every required measurement effect is among the
measurement findings; or (b) for ``heating`` and ``degradation`` only, there is no material finding and the
verdict is "unexplained".  "nothing_missing" on an effect case is wrong (every effect is far above the
noise).  Measurement findings are otherwise not scored (references are the instrument's, so is a drift).
A control is right when there is no material finding.  The score is right/total, effect cases and controls
apart, and the controls' rate: "no material finding in X % of control seeds".
"""

from __future__ import annotations

import argparse
import json
import math
import time
import zlib
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from scipy.stats import norm

from fitter.data.recordings import Recording
from fitter.diagnosis import diagnose

REF_SPAN = 0.15  # references uniform in +-15 % of the output range
NOISE = 0.003  # white noise RMS, fraction of the output range
GL_X, GL_W = np.polynomial.legendre.leggauss(8)


# ----------------------------------------------------------------------------------------------- waveforms
@dataclass(frozen=True)
class Wave:
    """One file's input: `kind` triangle / trapezoid / sine, from u = 0 going up."""

    kind: str
    period: float
    amp: float
    cycles: int

    def knots(self) -> tuple[np.ndarray, np.ndarray]:
        """Phase knots and values of a triangle / trapezoid cycle."""
        if self.kind == "triangle":
            return np.array([0.0, 0.25, 0.75, 1.0]), np.array([0.0, 1.0, -1.0, 0.0])
        return np.array([0.0, 0.15, 0.35, 0.65, 0.85, 1.0]), np.array([0.0, 1.0, 1.0, -1.0, -1.0, 0.0])

    def u(self, t: np.ndarray) -> np.ndarray:
        if self.kind == "sine":
            return self.amp * np.sin(2 * np.pi * t / self.period)
        ph, val = self.knots()
        return self.amp * np.interp(np.mod(t / self.period, 1.0), ph, val)

    def du(self, t: float) -> float:
        """du/dt at t (inside a segment: the caller keeps t off the corners)."""
        if self.kind == "sine":
            return self.amp * 2 * np.pi / self.period * math.cos(2 * np.pi * t / self.period)
        ph, val = self.knots()
        p = (t / self.period) % 1.0
        i = min(int(np.searchsorted(ph, p, side="right")) - 1, len(ph) - 2)
        return self.amp * (val[i + 1] - val[i]) / ((ph[i + 1] - ph[i]) * self.period)

    def corners(self, t0: float, t1: float) -> np.ndarray:
        """Times in [t0, t1] where du/dt jumps, with t0 and t1 (a sine: 8 pieces per period)."""
        ph = np.linspace(0, 1, 9) if self.kind == "sine" else self.knots()[0]
        c0, c1 = math.floor(t0 / self.period), math.ceil(t1 / self.period)
        ts = np.array([(c + p) * self.period for c in range(c0, c1 + 1) for p in ph])
        return np.unique(np.r_[t0, ts[(ts > t0) & (ts < t1)], t1])

    def grid(self, samples: int, pre: int = 1) -> tuple[np.ndarray, int]:
        """The sample times from -pre periods (the pre-cycle) and the index of t = 0."""
        m = max(20, 20 * round((samples - 1) / self.cycles / 20))
        t = np.arange(-pre * m, self.cycles * m + 1) * (self.period / m)
        return t, pre * m


def ode_path(
    rhs: Callable,
    wave: Wave,
    t: np.ndarray,
    x0: Sequence[float],
    method: str = "LSODA",
    rtol: float = 1e-8,
    atol: float = 1e-10,
) -> np.ndarray:
    """States at the samples t of dx/dt = rhs(t, x, u, du/dt), u the analytic wave (piece by piece between
    its corners, so that no solver step crosses a jump of du/dt)."""
    x = np.asarray(x0, float)
    out = np.empty((len(t), len(x)))
    out[0] = x
    cs = wave.corners(t[0], t[-1])
    for a, b in zip(cs[:-1], cs[1:]):
        mid = 0.5 * (a + b)
        inside = (t > a) & (t <= b)
        v = None if wave.kind == "sine" else wave.du(mid)

        def f(tt, xx, v=v):
            return rhs(tt, xx, float(wave.u(tt)), wave.du(tt) if v is None else v)

        sol = solve_ivp(
            f,
            (a, b),
            x,
            method=method,
            rtol=rtol,
            atol=atol,
            t_eval=t[inside] if inside.any() else None,
            dense_output=False,
        )
        if not sol.success:
            raise RuntimeError(sol.message)
        x = sol.y[:, -1]
        if inside.any():
            out[inside] = sol.y.T
            if t[inside][-1] < b:  # t_eval ended before b: go on to b
                x = solve_ivp(f, (t[inside][-1], b), x, method=method, rtol=rtol, atol=atol).y[:, -1]
    return out


def path_in_u(slope: Callable, u: np.ndarray, x0: Sequence[float]) -> np.ndarray:
    """States at the samples of a rate-independent dx/du = slope(u, x, s), s = sign du, monotone run by
    monotone run (scipy RK45 in u)."""
    x = np.asarray(x0, float)
    out = np.empty((len(u), len(x)))
    out[0] = x
    k = 0
    while k < len(u) - 1:
        d = np.sign(u[k + 1] - u[k])
        j = k + 1
        while j < len(u) - 1 and np.sign(u[j + 1] - u[j]) == d:
            j += 1
        if d == 0:
            out[k + 1 : j + 1] = x
        else:
            sol = solve_ivp(
                lambda uu, xx, d=d: slope(uu, xx, d), (u[k], u[j]), x, t_eval=u[k + 1 : j + 1], rtol=1e-9, atol=1e-11
            )
            out[k + 1 : j + 1] = sol.y.T
            x = sol.y[:, -1]
        k = j
    return out


# --------------------------------------------------------------------------------------- material models
def branch_slope(Hc: float, a: float, lam: float) -> Callable:
    """dm/du of the rate-independent branch loop (module docstring, ``eddy_bh``)."""

    def slope(u, m, s):
        return lam * max(s * (math.tanh((u - s * Hc) / a) - m), 0.0)

    return slope


def kai(t: np.ndarray, E: np.ndarray, Ea: np.ndarray, tau0: float, n: float) -> np.ndarray:
    """Mean switched fraction of the KAI populations (module docstring, ``ferro_kai``), from s = -1."""
    s = -np.ones(len(Ea))
    ref, theta, g = s.copy(), np.zeros(len(Ea)), -1.0
    out = np.empty(len(t))
    out[0] = s.mean()
    for k in range(len(t) - 1):
        pieces = [(t[k], t[k + 1], E[k], E[k + 1])]
        if E[k] * E[k + 1] < 0:  # split where E crosses 0
            tz = t[k] + (t[k + 1] - t[k]) * E[k] / (E[k] - E[k + 1])
            pieces = [(t[k], tz, E[k], 0.0), (tz, t[k + 1], 0.0, E[k + 1])]
        for ta, tb, ea, eb in pieces:
            em = 0.5 * (ea + eb)
            if em == 0.0:
                continue
            gi = 1.0 if em > 0 else -1.0
            if gi != g:  # the field turned: a new KAI transformation
                g, ref, theta = gi, s.copy(), np.zeros(len(Ea))
            e_nodes = np.abs(0.5 * (ea + eb) + 0.5 * (eb - ea) * GL_X)
            with np.errstate(divide="ignore", over="ignore"):
                rates = np.exp(-Ea[:, None] / np.maximum(e_nodes[None, :], 1e-300)) / tau0
            theta = theta + 0.5 * (tb - ta) * rates @ GL_W
            s = g - (g - ref) * np.exp(-(theta**n))
        out[k + 1] = s.mean()
    return out


def duhem_exact(model: dict, u: np.ndarray) -> np.ndarray:
    """y = C x of the semilinear Duhem model, exact per sample interval (augmented matrix exponential)."""
    n = len(model["C"])
    mats = {}
    for s in (1, -1):
        M = np.zeros((n + 2, n + 2))
        M[:n, :n], M[:n, n], M[:n, n + 1] = model["A"][s], model["B"][s], model["E"][s]
        M[n, n + 1] = 1.0
        mats[s] = M
    cache: dict[tuple, np.ndarray] = {}
    x = np.asarray(model["x0"], float)
    y = np.empty(len(u))
    y[0] = model["C"] @ x
    for k in range(len(u) - 1):
        d = u[k + 1] - u[k]
        if d != 0:
            s = 1 if d > 0 else -1
            key = (s, round(d, 12))
            if key not in cache:
                cache[key] = expm(mats[s] * d)
            x = (cache[key] @ np.r_[x, u[k], 1.0])[:n]
        y[k + 1] = model["C"] @ x
    return y


def bouc_wen(x: np.ndarray, n: float, beta: float, gamma: float, x_y: float, z0: float = 0.0) -> np.ndarray:
    """z of dz/dx = (1 - (beta s sign(z) + gamma) |z|^n) / x_y (rate-independent)."""

    def slope(xx, z, s):
        zz = z[0]
        return [(1.0 - (beta * s * math.copysign(1.0, zz) + gamma) * abs(zz) ** n) / x_y]

    return path_in_u(slope, x, [z0])[:, 0]


def preisach(u: np.ndarray, alpha: np.ndarray, beta: np.ndarray, w: np.ndarray) -> np.ndarray:
    """sum w R of relays (up at u >= alpha, down at u <= beta), all down at the start."""
    R = -np.ones(len(w))
    out = np.empty(len(u))
    for k, uk in enumerate(u):
        R[uk >= alpha] = 1.0
        R[uk <= beta] = -1.0
        out[k] = w @ R
    return out


# ------------------------------------------------------------------------------------------------- cases
FileTruth = tuple  # (name, t from 0, u, y, y_twin or None)


def _files(design: Sequence[Wave], samples: int, one: Callable) -> list[FileTruth]:
    """Run `one(wave, t_full, u_full, i) -> (y_full, twin_full or None)` per file; keep t >= 0."""
    out = []
    for i, w in enumerate(design):
        t, k0 = w.grid(samples)
        u = w.u(t)
        u[k0] = 0.0
        y, twin = one(w, t, u, i)
        name = f"{w.kind}_{w.period:g}s_{w.amp:g}"
        out.append((f"f{i + 1}_{name}", t[k0:] - t[k0], u[k0:], y[k0:], None if twin is None else twin[k0:]))
    return out


def case_ferro_kai(rng, samples):
    E0 = 60.0
    tau0 = math.exp(rng.uniform(math.log(3e-5), math.log(3e-4)))
    sigma, n = rng.uniform(0.15, 0.3), rng.uniform(1.5, 2.5)
    Ea = 0.5 * E0 * math.log(1.0 / (4 * 1.0 * tau0))
    Eas = Ea * np.exp(sigma * norm.ppf((np.arange(24) + 0.5) / 24))
    Ps, eps = rng.uniform(20, 30), 0.0
    eps = rng.uniform(0.03, 0.1) * Ps / E0
    design = [
        Wave("triangle", 100.0, E0, 2),
        Wave("triangle", 10.0, E0, 2),
        Wave("triangle", 1.0, E0, 2),
        Wave("triangle", 10.0, 0.8 * E0, 2),
    ]
    return _files(design, samples, lambda w, t, u, i: (Ps * kai(t, u, Eas, tau0, n) + eps * u, None))


def case_eddy_bh(rng, samples):
    Hc, a, Js = rng.uniform(15, 25), rng.uniform(10, 20), rng.uniform(1.2, 1.6)
    lam, mu_rev = 2.0 / a, 0.05 * Js / 100.0
    slope = branch_slope(Hc, a, lam)
    # eddy time constant k_e mu_d: mu_d ~ Js lam on the steep part; a few % of a 200 Hz period there
    k_e = rng.uniform(0.02, 0.05) * (1 / 200.0) / (Js * lam)

    def rhs(tt, xx, Ha, dHa):
        Hh, m = xx
        s = 1.0 if Ha >= Hh else -1.0
        g = lam * max(s * (math.tanh((Hh - s * Hc) / a) - m), 0.0)  # |dm/dHh| on branch s
        dHh = (Ha - Hh) / (k_e * (mu_rev + Js * g))
        return [dHh, g * abs(dHh) * s]

    def one(w, t, u, i):
        m0 = -1.0
        x = ode_path(rhs, w, t, [u[0], m0], method="Radau", rtol=1e-7, atol=1e-9)
        B = mu_rev * x[:, 0] + Js * x[:, 1]
        mq = path_in_u(lambda uu, mm, s: [slope(uu, mm[0], s)], u, [m0])[:, 0]
        return B, mu_rev * u + Js * mq

    design = [
        Wave("sine", 0.1, 100.0, 2),
        Wave("sine", 0.02, 100.0, 2),
        Wave("sine", 0.005, 100.0, 2),
        Wave("sine", 0.02, 40.0, 2),
    ]
    return _files(design, samples, one)


def _bw_params(rng, n=None):
    return dict(
        n=2.0 if n is None else n,
        beta=rng.uniform(0.55, 0.85),
        x_y=rng.uniform(0.5, 1.5),
        alpha=rng.uniform(300, 500),
        k=rng.uniform(2, 6),
    )


DAMPER_DESIGN = (
    Wave("sine", 4.0, 10.0, 2),
    Wave("sine", 1.0, 10.0, 2),
    Wave("sine", 0.5, 5.0, 2),
    Wave("sine", 0.25, 5.0, 2),
)


def _damper(rng, samples, viscous: bool, n=None):
    p = _bw_params(rng, n)
    vmax = max(2 * np.pi * w.amp / w.period for w in DAMPER_DESIGN)
    c = rng.uniform(0.2, 0.35) * p["alpha"] / vmax if viscous else 0.0

    def one(w, t, u, i):
        z = bouc_wen(u, p["n"], p["beta"], 1.0 - p["beta"], p["x_y"])
        F0 = p["k"] * u + p["alpha"] * z
        v = np.array([w.du(tt) for tt in t])
        return F0 + c * v, (F0 if viscous else None)

    return _files(DAMPER_DESIGN, samples, one)


def case_damper_bw(rng, samples):
    return _damper(rng, samples, True)


def case_creep_drift(rng, samples):
    U = 100.0
    d33, n_bw = 0.1, 1.0  # um / V: stroke ~ 20 um
    beta, u_y = rng.uniform(0.55, 0.85), rng.uniform(10, 25)
    alpha = 0.12 * 2 * d33 * U / 2  # hysteresis ~ 12 % of the stroke
    tau1, tau2 = rng.uniform(1, 3), rng.uniform(25, 80)
    ratio = rng.uniform(0.5, 2.0)
    k_tot = rng.uniform(0.06, 0.10) * 2 * d33 * U / (2 * U)  # creep 6-10 % of the stroke
    k1, k2 = k_tot / (1 + ratio), k_tot * ratio / (1 + ratio)
    T_d = rng.uniform(400, 900)
    design = [
        Wave("trapezoid", 20.0, U, 2),
        Wave("trapezoid", 60.0, U, 2),
        Wave("trapezoid", 200.0, U, 2),
        Wave("trapezoid", 60.0, 0.6 * U, 2),
    ]
    longest = max(w.period * w.cycles for w in design)
    r = rng.uniform(0.02, 0.04) * 2 * d33 * U / (T_d * (1 - math.exp(-longest / T_d)))

    def one(w, t, u, i):
        z = bouc_wen(u, n_bw, beta, 1.0 - beta, u_y, z0=-0.5)
        base = d33 * u + alpha * z
        c = ode_path(
            lambda tt, cc, uu, du: [(k1 * uu - cc[0]) / tau1, (k2 * uu - cc[1]) / tau2], w, t, [k1 * u[0], k2 * u[0]]
        )
        drift = np.where(t >= 0, r * T_d * (1 - np.exp(-np.maximum(t, 0) / T_d)), 0.0)
        return base + c.sum(axis=1) + drift, base

    return _files(design, samples, one)


def _branch_params(rng):
    E0 = 60.0
    return E0, rng.uniform(0.35, 0.55) * E0, rng.uniform(0.12, 0.2) * E0, rng.uniform(20, 30)


def case_heating(rng, samples):
    E0, Ec, a, Ps = _branch_params(rng)
    lam = 2.0 / a
    eps = rng.uniform(0.03, 0.1) * Ps / E0
    tau_th = rng.uniform(5, 15)
    design = [
        Wave("triangle", 0.5, E0, 4),
        Wave("triangle", 5.0, E0, 4),
        Wave("triangle", 50.0, E0, 4),
        Wave("triangle", 5.0, 0.75 * E0, 4),
    ]
    fast = design[0]
    # theta at the end of the fastest file ~ eta * total |dm| (no time to cool): |dm| ~ 4 per cycle
    eta = rng.uniform(0.2, 0.3) / (4 * (fast.cycles + 1))

    def rhs_for(eta_):
        def rhs(tt, xx, uu, du):
            m, th = xx
            s = 1.0 if du > 0 else -1.0
            g = lam * max(s * (math.tanh((uu - s * Ec) / a) - m), 0.0)
            dm = g * abs(du) * s
            return [dm, eta_ * abs(dm) - th / tau_th]

        return rhs

    def one(w, t, u, i):
        x = ode_path(rhs_for(eta), w, t, [-1.0, 0.0])
        y = np.sqrt(np.clip(1 - x[:, 1], 0, None)) * Ps * x[:, 0] + eps * u
        return y, Ps * x[:, 0] + eps * u

    return _files(design, samples, one)


def case_degradation(rng, samples):
    E0, Ec, a, Ps = _branch_params(rng)
    lam = 2.0 / a
    eps = rng.uniform(0.03, 0.1) * Ps / E0
    f, N0 = rng.uniform(0.04, 0.07), rng.uniform(0.5, 2.0)
    design = [
        Wave("triangle", 2.0, E0, 4),
        Wave("triangle", 0.5, E0, 4),
        Wave("triangle", 10.0, E0, 3),
        Wave("triangle", 2.0, 0.8 * E0, 4),
    ]
    state = {"m": -1.0, "N": 0.0}

    def rhs(tt, xx, uu, du):
        m, N = xx
        s = 1.0 if du > 0 else -1.0
        g = lam * max(s * (math.tanh((uu - s * Ec) / a) - m), 0.0)
        return [g * abs(du) * s, g * abs(du) / 4.0]

    def one(w, t, u, i):
        x = ode_path(rhs, w, t, [state["m"], state["N"]])
        state["m"], state["N"] = float(x[-1, 0]), float(x[-1, 1])
        keep = 1 - f * np.log1p(x[:, 1] / N0)
        return keep * Ps * x[:, 0] + eps * u, Ps * x[:, 0] + eps * u

    return _files(design, samples, one)


def _duhem_model(rng, order: int) -> dict:
    U = 50.0
    a = np.exp(rng.uniform(math.log(1.5), math.log(12.0), order)) / U
    a_m = a * rng.uniform(0.7, 1.4, order)
    K = rng.uniform(-0.25, 0.25, (order, order)) * a.min()
    np.fill_diagonal(K, 0.0)
    Kp = rng.uniform(-0.25, 0.25, (order, order)) * a_m.min()
    np.fill_diagonal(Kp, 0.0)
    b = rng.uniform(0.6, 1.4, order)
    e = rng.uniform(0.2, 0.6, order) * U
    model = {
        "A": {1: -np.diag(a) + K, -1: np.diag(a_m) - Kp},
        "B": {1: a * b, -1: -a_m * b},
        "E": {1: -a * e, -1: -a_m * e},
        "C": rng.uniform(0.3, 1.0, order),
        "x0": np.zeros(order),
    }
    for s in (1, -1):
        assert np.all(s * np.linalg.eigvals(model["A"][s]).real < 0), "a branch that does not converge"
    warm = U * np.r_[np.linspace(0, 1, 200), np.linspace(1, -1, 400)[1:], np.linspace(-1, 0, 200)[1:]]
    y = duhem_exact(model, warm)
    model["C"] = model["C"] * 10.0 / np.ptp(y)
    return model


def _control_duhem(order: int):
    def case(rng, samples):
        model = _duhem_model(rng, order)
        design = [
            Wave("triangle", 40.0, 50.0, 2),
            Wave("triangle", 8.0, 35.0, 2),
            Wave("triangle", 2.0, 50.0, 2),
            Wave("triangle", 8.0, 42.0, 2),
        ]
        return _files(design, samples, lambda w, t, u, i: (duhem_exact(model, u), None))

    return case


def case_control_bouc_wen(rng, samples):
    return _damper(rng, samples, False, n=rng.uniform(1.2, 3.0))


def case_control_preisach(rng, samples):
    U, G = 10.0, 120
    levels = np.linspace(-1.2, 1.2, G) * U
    A, Bt = np.meshgrid(levels, levels, indexing="ij")
    keep = A > Bt
    alpha, beta = A[keep], Bt[keep]
    sd_i = rng.uniform(0.1, 0.25) * U
    hc, sd_c = rng.uniform(0.25, 0.5) * U, rng.uniform(0.3, 0.6)
    hcs = (alpha - beta) / 2
    w = np.exp(-0.5 * (((alpha + beta) / 2) / sd_i) ** 2) * np.exp(-0.5 * (np.log(hcs / hc) / sd_c) ** 2) / hcs
    w = w / w.sum()  # the relays span 2
    frac = rng.uniform(0.1, 0.25)  # share of the reversible part in the output
    c = frac / (1 - frac) / U
    design = [
        Wave("triangle", 10.0, U, 2),
        Wave("triangle", 10.0, 0.7 * U, 2),
        Wave("triangle", 1.0, U, 2),
        Wave("triangle", 10.0, 0.5 * U, 2),
    ]
    return _files(design, samples, lambda wv, t, u, i: (preisach(u, alpha, beta, w) + c * u, None))


@dataclass(frozen=True)
class Case:
    name: str
    make: Callable
    control: bool = False
    accepted: frozenset = frozenset()  # material effects that name the physics
    tolerated: frozenset = frozenset()  # material effects also true of the truth (never alone)
    required_measurement: frozenset = frozenset()
    unexplained_ok: bool = False  # an honest "unexplained" without material claims is right
    seeds: int = 2

    def expected(self) -> str:
        if self.control:
            return "no material"
        s = "|".join(sorted(self.accepted))
        if self.tolerated:
            s += f" (+{'|'.join(sorted(self.tolerated))})"
        if self.required_measurement:
            s += " & meas " + "|".join(sorted(self.required_measurement))
        if self.unexplained_ok:
            s += " or unexplained"
        return s


F = frozenset
CASES = (
    Case("ferro_kai", case_ferro_kai, accepted=F({"switching", "rate_dependence"}), tolerated=F({"saturation"})),
    Case("eddy_bh", case_eddy_bh, accepted=F({"viscous", "rate_dependence"}), tolerated=F({"saturation"})),
    Case("damper_bw", case_damper_bw, accepted=F({"viscous"})),
    Case(
        "creep_drift",
        case_creep_drift,
        accepted=F({"creep", "relaxation"}),
        required_measurement=F({"measurement_drift"}),
    ),
    Case("heating", case_heating, accepted=F({"thermal_drift"}), tolerated=F({"saturation"}), unexplained_ok=True),
    Case(
        "degradation", case_degradation, accepted=F({"thermal_drift"}), tolerated=F({"saturation"}), unexplained_ok=True
    ),
    Case("control_duhem1", _control_duhem(1), control=True, seeds=4),
    Case("control_duhem2", _control_duhem(2), control=True, seeds=4),
    Case("control_duhem3", _control_duhem(3), control=True, seeds=4),
    Case("control_bouc_wen", case_control_bouc_wen, control=True, seeds=4),
    Case("control_preisach", case_control_preisach, control=True, seeds=4),
)


# ----------------------------------------------------------------------------------------------- running
def build(case: Case, seed: int, samples: int) -> tuple[list[Recording], dict]:
    """The case's files as an instrument writes them, and what is true about them."""
    rng = np.random.default_rng((zlib.crc32(case.name.encode()), seed))
    files = case.make(rng, samples)
    Y = float(np.ptp(np.concatenate([f[3] for f in files])))
    recs, refs = [], []
    for name, t, u, y, _ in files:
        ref = rng.uniform(-REF_SPAN, REF_SPAN) * Y
        refs.append(ref)
        recs.append(Recording(t, u, y + ref + rng.normal(0.0, NOISE * Y, len(y)), name=name, source=f"{name}.csv"))
    twins = [f for f in files if f[4] is not None]
    size = max(float(np.max(np.abs(f[3] - f[4]))) for f in twins) / Y if twins else math.nan
    return recs, {"range": Y, "noise_rms": NOISE * Y, "references": refs, "effect_size": size}


@dataclass
class Row:
    case: str
    seed: int
    control: bool
    expected: str
    material: list = field(default_factory=list)
    measurement: list = field(default_factory=list)
    verdict: str = ""
    nrmse_per_recording: list = field(default_factory=list)
    base_ratio: float = math.nan
    ext_ratio: float = math.nan
    effect_size: float = math.nan
    seconds: float = 0.0
    right: bool = False
    error: str = ""


def score(case: Case, row: Row) -> bool:
    material = set(row.material)
    if row.error:
        return False
    if case.control:
        return not material
    if not material:
        return case.unexplained_ok and row.verdict == "unexplained"
    return (
        bool(material & case.accepted)
        and material <= (case.accepted | case.tolerated)
        and case.required_measurement <= set(row.measurement)
    )


def run(case: Case, seed: int, samples: int) -> Row:
    recs, truth = build(case, seed, samples)
    row = Row(case.name, seed, case.control, case.expected(), effect_size=truth["effect_size"])
    t0 = time.perf_counter()
    try:
        d = diagnose(recs).to_json()
    except Exception as exc:  # a refusal is a wrong answer, shown as such
        row.error, row.verdict = f"{type(exc).__name__}: {exc}"[:200], "error"
    else:
        findings = d["findings"]
        row.material = [f["effect"] for f in findings if f.get("origin") == "material"]
        row.measurement = [f["effect"] for f in findings if f.get("origin") == "measurement"]
        row.verdict = d["verdict"]
        row.nrmse_per_recording = list(d["extended"].get("nrmse_per_recording") or [])
        row.base_ratio = d["baseline"]["residual_rms"] / truth["noise_rms"]
        row.ext_ratio = d["extended"]["residual_rms"] / truth["noise_rms"]
    row.seconds = time.perf_counter() - t0
    row.right = score(case, row)
    return row


HEADER = (
    f"{'case':17s} {'seed':>4s}  {'expected':44s} {'found material':26s} {'found measurement':20s} "
    f"{'verdict':15s} {'right?':6s} {'eff%':>5s} {'base/n':>6s} {'ext/n':>6s} {'seconds':>7s}"
)


def line(r: Row) -> str:
    return (
        f"{r.case:17s} {r.seed:4d}  {r.expected:44s} {','.join(r.material) or '-':26s} "
        f"{','.join(r.measurement) or '-':20s} {r.verdict:15s} {'yes' if r.right else 'NO':6s} "
        f"{'-' if math.isnan(r.effect_size) else f'{100 * r.effect_size:.1f}':>5s} {r.base_ratio:6.2f} "
        f"{r.ext_ratio:6.2f} {r.seconds:7.1f}" + (f"  [{r.error}]" if r.error else "")
    )


def summary(rows: Sequence[Row]) -> str:
    eff = [r for r in rows if not r.control]
    ctl = [r for r in rows if r.control]
    pct = f"{100 * sum(r.right for r in ctl) / len(ctl):.0f} %" if ctl else "-"
    nm = sum(r.verdict == "nothing_missing" for r in ctl)
    return (
        f"score: {sum(r.right for r in rows)}/{len(rows)} right; "
        f"effect cases {sum(r.right for r in eff)}/{len(eff)}, "
        f"controls {sum(r.right for r in ctl)}/{len(ctl)}\n"
        f"controls: no material finding in {pct} of control seeds ({nm}/{len(ctl)} say nothing_missing)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one seed per case, 300 samples per file")
    ap.add_argument(
        "--seeds", type=int, default=None, help="seeds per case (default: 2 per effect case, 4 per control)"
    )
    ap.add_argument("--samples", type=int, default=None, help="samples per file (default 400, quick 300)")
    ap.add_argument("--only", default=None, help="run only the cases whose name contains this")
    ap.add_argument("--json", default=None, help="write the table to this path")
    args = ap.parse_args()
    samples = args.samples or (300 if args.quick else 400)
    rows, t_start = [], time.perf_counter()
    print(HEADER, flush=True)
    for case in CASES:
        if args.only and args.only not in case.name:
            continue
        for seed in range(args.seeds or (1 if args.quick else case.seeds)):
            rows.append(run(case, seed, samples))
            print(line(rows[-1]), flush=True)
            if args.json:
                _write(args.json, samples, rows)
    print(f"total {time.perf_counter() - t_start:.0f} s, about {samples} samples per file")
    print(summary(rows))
    if args.json:
        _write(args.json, samples, rows)


def _write(path: str, samples: int, rows: Sequence[Row]) -> None:
    with open(path, "w") as fh:
        json.dump(
            {"samples": samples, "rows": [vars(r) for r in rows], "score": summary(rows)}, fh, indent=1, default=float
        )


if __name__ == "__main__":
    main()
