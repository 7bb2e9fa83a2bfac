"""Simulators of the hysteresis zoo (`bench/zoo.py`): physics from other families than the semilinear Duhem model.

numpy only, independent of `fitter`. Every simulator takes a seeded generator and ``quick`` (shorter recordings) and
returns a list of `Rec` (time, input, output; written as CSV ``time,u,y``), each file starting at t = 0, its output
carrying seeded white noise of a fixed share (0.1-0.5 %) of its range and, where said, its own small offset (an
instrument's zero). The equations and references are in `bench/zoo.py`'s docstring; in short:

* `jiles_atherton`: B = mu0 (H_m + M), Jiles-Atherton M(H_m) with an eddy-current field, H = H_m + k_e dB/dt;
* `bouc_wen_pinching`: Baber-Noori pinching Bouc-Wen, y = a k u + (1 - a) k z;
* `preisach`: a discrete relay grid with a Gaussian weight, random turning points;
* `play`, `dead_zone`: k * play_w(u) and k * dz_w(u) under triangle and sine;
* `maxwell_slip`: N spring-slider elements, displacement in, force out;
* `input_lag`: a Bouc-Wen loop driven by the input through a first-order lag, three rates;
* `log_creep`: a Bouc-Wen loop plus logarithmic creep after every step of a staircase with holds;
* `pi_saturation`: Prandtl-Ishlinskii followed by a tanh saturation;
* `mr_damper`: Spencer's phenomenological MR damper model, velocity in, force out, three frequencies.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MU0 = 4e-7 * np.pi


@dataclass(frozen=True)
class Rec:
    """One recording: name (file stem), time, input and output samples."""

    name: str
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray

    def write(self, folder: Path) -> Path:
        """Write ``folder/<name>.csv`` with the header ``time,u,y`` and return its path."""
        path = folder / f"{self.name}.csv"
        data = np.column_stack([self.t, self.u, self.y])
        np.savetxt(path, data, delimiter=",", header="time,u,y", comments="", fmt="%.10g")
        return path


def finish(
    name: str, t: np.ndarray, u: np.ndarray, y: np.ndarray, rng: np.random.Generator, noise: float, offset: float = 0.0
) -> Rec:
    """Add an offset and white noise, both as shares of the output's range, and make a `Rec`."""
    span = float(np.ptp(y))
    return Rec(name, t, u, y + offset * span + noise * span * rng.standard_normal(len(y)))


# ----------------------------------------------------------------------------------------------------- waveforms
def triangle(t: np.ndarray, freq: float, amp: float) -> np.ndarray:
    """Triangle wave from 0, rising first, of amplitude `amp`."""
    return amp * (2 / np.pi) * np.arcsin(np.sin(2 * np.pi * freq * t))


def path_through(points: list[float], speed: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Time and input of a piecewise linear path through `points` at constant `speed`, sampled every `dt`."""
    knots = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(points)) / speed)])
    t = np.arange(0.0, knots[-1] + dt / 2, dt)
    return t, np.interp(t, knots, points)


def turning_points(rng: np.random.Generator, n: int, lo: float, hi: float, gap: float = 0.15) -> list[float]:
    """Random alternating turning points inside [lo, hi] after one saturating sweep lo -> hi (minor loops)."""
    pts, cur = [lo, hi], hi
    for i in range(n):
        cur = rng.uniform(lo, cur - gap) if i % 2 == 0 else rng.uniform(cur + gap, hi)
        pts.append(cur)
    return pts


def staircase(levels: list[float], hold: float, ramp: float, dt: float) -> tuple[np.ndarray, np.ndarray, list]:
    """Time, input and step list [(t_j, index of the level reached)] of steps between `levels`, each held `hold` s."""
    knots_t, knots_u, steps = [0.0], [levels[0]], []
    for j, level in enumerate(levels[1:], start=1):
        t0 = knots_t[-1] + hold
        knots_t += [t0, t0 + ramp]
        knots_u += [knots_u[-1], level]
        steps.append((t0, j))
    knots_t.append(knots_t[-1] + hold)
    knots_u.append(levels[-1])
    t = np.arange(0.0, knots_t[-1] + dt / 2, dt)
    return t, np.interp(t, knots_t, knots_u), steps


# ------------------------------------------------------------------------------------------------- operators
def integrate_ri(u: np.ndarray, dzdu: Callable[[float, float], float], sub: int = 20) -> np.ndarray:
    """z(u) of the rate-independent law dz = dzdu(z, sign du) du, explicit Euler with `sub` substeps a sample."""
    z = np.zeros(len(u))
    zz = 0.0
    for i in range(1, len(u)):
        du = (u[i] - u[i - 1]) / sub
        s = float(np.sign(du))
        for _ in range(sub):
            zz += dzdu(zz, s) * du
        z[i] = zz
    return z


def bouc_wen_rate(a: float = 1.0, beta: float = 0.5, gamma: float = 0.5, n: float = 1.0):
    """dz/du of Bouc-Wen (Wen 1976): A - |z|^n (beta sgn(du z) + gamma)."""
    return lambda z, s: a - abs(z) ** n * (beta * np.sign(s * z) + gamma)


def play(u: np.ndarray, w: float, z0: float = 0.0) -> np.ndarray:
    """Play (backlash) operator of half-width `w`: z = min(max(z, u - w), u + w)."""
    z = np.empty(len(u))
    zz = z0
    for i, ui in enumerate(u):
        zz = min(max(zz, ui - w), ui + w)
        z[i] = zz
    return z


def dead_zone(u: np.ndarray, w: float) -> np.ndarray:
    """Dead-zone operator: u - w above w, u + w below -w, 0 between (memoryless)."""
    return np.sign(u) * np.maximum(np.abs(u) - w, 0.0)


def langevin(x: float, a: float) -> float:
    """Langevin function coth(x / a) - a / x (series near 0)."""
    r = x / a
    return r / 3 - r**3 / 45 if abs(r) < 1e-4 else 1 / np.tanh(r) - 1 / r


# ------------------------------------------------------------------------------------------------- simulators
def _ja_step(hm: float, dhm: float, m: float, mirr: float, p: dict) -> tuple[float, float]:
    """One increment dhm of Jiles-Atherton: returns (M, M_irr) after it."""
    man = p["ms"] * langevin(hm + p["alpha"] * m, p["a"])
    d = np.sign(dhm) * (man - mirr)
    if d > 0:
        mirr += dhm * d / max(p["k"] - p["alpha"] * d, 0.1 * p["k"])
    man = p["ms"] * langevin(hm + dhm + p["alpha"] * m, p["a"])
    return p["c"] * man + (1 - p["c"]) * mirr, mirr


def ja_eddy_bh(t: np.ndarray, h: np.ndarray, ke: float, sub: int = 20) -> np.ndarray:
    """B(t) of Jiles-Atherton with an eddy-current field k_e dB/dt (semi-implicit in the lag of H_m behind H)."""
    p = {"ms": 1.6e6, "a": 1100.0, "k": 400.0, "alpha": 1.0e-3, "c": 0.2}
    hm = m = mirr = 0.0
    chi = p["c"] * p["ms"] / (3 * p["a"])
    b = np.zeros(len(t))
    for i in range(1, len(t)):
        dt = (t[i] - t[i - 1]) / sub
        for j in range(sub):
            hin = h[i - 1] + (j + 1) / sub * (h[i] - h[i - 1])
            tau = ke * MU0 * (1 + chi)
            dhm = (hin - hm) * dt / (tau + dt)
            m_new, mirr = _ja_step(hm, dhm, m, mirr, p)
            if abs(dhm) > 1e-9:
                chi = min(max((m_new - m) / dhm, 0.0), 1e5)
            m, hm = m_new, hm + dhm
        b[i] = MU0 * (hm + m)
    return b


def jiles_atherton(rng: np.random.Generator, quick: bool) -> list[Rec]:
    """B(H) of a laminated core at 5, 50 and 200 Hz (Jiles-Atherton with eddy currents), from the demagnetised state."""
    per = 120 if quick else 300
    out = []
    for f in (5.0, 50.0, 200.0):
        t = np.arange(0, 3 * per + 1) / (per * f)
        h = 5000.0 * np.sin(2 * np.pi * f * t)
        out.append(finish(f"ja_{f:g}Hz", t, h, ja_eddy_bh(t, h, ke=0.4), rng, 0.002))
    return out


def bwbn_rate(a=1.0, beta=0.5, gamma=0.5, n=2.0, zeta1=0.85, zeta2=0.2, q=0.15):
    """dz/du of the Baber-Noori pinched Bouc-Wen (no degradation): h(z) (A - |z|^n (beta sgn(du z) + gamma))."""
    zu = (a / (beta + gamma)) ** (1 / n)

    def rate(z: float, s: float) -> float:
        h = 1 - zeta1 * np.exp(-(((z * s - q * zu) / zeta2) ** 2))
        return h * (a - abs(z) ** n * (beta * np.sign(s * z) + gamma))

    return rate


def bouc_wen_pinching(rng: np.random.Generator, quick: bool) -> list[Rec]:
    """Pinched Bouc-Wen force of a displacement sine decaying from 4 (and one growing from 0.5) yield displacements."""
    per, cycles = (100, 5) if quick else (250, 8)
    t = np.arange(0, cycles * per + 1) / (per * 0.5)
    env = np.exp(-t / (cycles * 2 / np.log(4 / 0.4)))
    out = []
    for name, amp in (("bwbn_decaying", 4.0 * env), ("bwbn_growing", 4.0 * env[::-1] * 0.75)):
        u = amp * np.sin(2 * np.pi * 0.5 * t)
        y = 0.1 * u + 0.9 * integrate_ri(u, bwbn_rate())
        out.append(finish(name, t, u, y, rng, 0.003))
    return out


def preisach_relays(u: np.ndarray, n: int = 60, hc: float = 0.35, sc: float = 0.15, si: float = 0.25) -> np.ndarray:
    """Output of a Preisach grid of relays (alpha >= beta on [-1, 1]^2), Gaussian weight in coercivity and bias."""
    g = np.linspace(-1, 1, n)
    al, be = np.meshgrid(g, g, indexing="ij")
    keep = al >= be
    al, be = al[keep], be[keep]
    mu = np.exp(-(((al - be) / 2 - hc) ** 2) / (2 * sc**2) - ((al + be) / 2) ** 2 / (2 * si**2))
    mu /= mu.sum()
    r = -np.ones(len(al))
    y = np.empty(len(u))
    for i, ui in enumerate(u):
        r[al <= ui] = 1.0
        r[be >= ui] = -1.0
        y[i] = mu @ r
    return y


def preisach(rng: np.random.Generator, quick: bool) -> list[Rec]:
    """Preisach relay grid driven through random turning points (minor loops), two seeds."""
    dt = 0.02 if quick else 0.008
    out = []
    for j in range(2):
        pts = turning_points(rng, 8 if quick else 14, -1.2, 1.2)
        t, u = path_through(pts, speed=1.0, dt=dt)
        out.append(finish(f"preisach_{j + 1}", t, u, 5.0 * preisach_relays(u), rng, 0.002))
    return out


def _tri_and_sine(quick: bool) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """A triangle of amplitude 1 at 1 Hz and a sine of amplitude 0.6 at 0.5 Hz, from 0, three cycles each."""
    per = 100 if quick else 300
    t1 = np.arange(0, 3 * per + 1) / per
    t2 = np.arange(0, 3 * per + 1) / (per * 0.5)
    return [("triangle", t1, triangle(t1, 1.0, 1.0)), ("sine", t2, 0.6 * np.sin(2 * np.pi * 0.5 * t2))]


def play_gain(rng: np.random.Generator, quick: bool) -> list[Rec]:
    """y = 2 play_0.2(u): backlash feeding a linear gain."""
    return [finish(f"play_{n}", t, u, 2.0 * play(u, 0.2), rng, 0.002) for n, t, u in _tri_and_sine(quick)]


def dead_zone_gain(rng: np.random.Generator, quick: bool) -> list[Rec]:
    """y = 2 dz_0.2(u): a dead zone (memoryless), for what a hysteresis model makes of it."""
    return [finish(f"deadzone_{n}", t, u, 2.0 * dead_zone(u, 0.2), rng, 0.002) for n, t, u in _tri_and_sine(quick)]


def maxwell_force(u: np.ndarray, k: np.ndarray, fs: np.ndarray, k0: float) -> np.ndarray:
    """Force of N Maxwell-slip elements (spring k_i slipping at force f_i) beside a spring k0: sum k_i s_i + k0 u."""
    lim = fs / k
    s = np.zeros(len(k))
    f = np.empty(len(u))
    prev = u[0]
    for i, ui in enumerate(u):
        s = np.clip(s + ui - prev, -lim, lim)
        prev = ui
        f[i] = k @ s + k0 * ui
    return f


def maxwell_slip(rng: np.random.Generator, quick: bool) -> list[Rec]:
    """Maxwell-slip friction (8 elements) under displacement sines of 1 and 0.35 mm, each force with its own zero."""
    k = np.full(8, 2.0)
    fs = 2.0 * np.linspace(0.05, 0.8, 8)
    per = 100 if quick else 300
    out = []
    for name, amp, f, off in (("maxwell_1mm", 1.0, 1.0, 0.0), ("maxwell_0.35mm", 0.35, 2.0, 0.01)):
        t = np.arange(0, 3 * per + 1) / (per * f)
        u = amp * np.sin(2 * np.pi * f * t)
        out.append(finish(name, t, u, maxwell_force(u, k, fs, 0.5), rng, 0.002, off))
    return out


def first_order_lag(t: np.ndarray, u: np.ndarray, tau: float) -> np.ndarray:
    """tau du_f/dt = u - u_f, exact for an input linear between samples, from u_f = u[0]."""
    uf = np.empty(len(u))
    uf[0] = u[0]
    for i in range(1, len(u)):
        e = np.exp(-(t[i] - t[i - 1]) / tau)
        slope = (u[i] - u[i - 1]) / (t[i] - t[i - 1])
        uf[i] = u[i] - slope * tau + (uf[i - 1] - u[i - 1] + slope * tau) * e
    return uf


def input_lag(rng: np.random.Generator, quick: bool) -> list[Rec]:
    """Bouc-Wen loop seen through a first-order lag (tau = 10 ms) of its input, sines at 0.5, 3 and 12 Hz."""
    per = 100 if quick else 300
    out = []
    for f, off in ((0.5, 0.0), (3.0, 0.005), (12.0, -0.005)):
        t = np.arange(0, 3 * per + 1) / (per * f)
        u = np.sin(2 * np.pi * f * t)
        uf = first_order_lag(t, u, 0.01)
        y = 0.3 * uf + 0.7 * integrate_ri(3.0 * uf, bouc_wen_rate())
        out.append(finish(f"lag_{f:g}Hz", t, u, y, rng, 0.002, off))
    return out


def log_creep(rng: np.random.Generator, quick: bool) -> list[Rec]:
    """Staircases with holds: y = y_h(u) + gamma sum_j dy_j log10(1 + (t - t_j) / tau) (creep after step j)."""
    hold, dt = (2.0, 0.1) if quick else (5.0, 0.05)
    plans = {
        "creep_quarter": [0, 0.25, 0.5, 0.75, 1, 0.5, 0, -0.5, -1, -0.75, -0.5, -0.25, 0],
        "creep_half": [0, 0.5, 1, 0, -1, -0.5, 0, 0.5],
    }
    out = []
    for name, levels in plans.items():
        t, u, steps = staircase(levels, hold * (1 if name == "creep_quarter" else 1.6), 0.1, dt)
        yh = 0.3 * u + 0.7 * integrate_ri(3.0 * u, bouc_wen_rate())
        creep = np.zeros(len(t))
        for tj, _ in steps:
            after = t > tj + 0.1
            dy = np.interp(tj + 0.1, t, yh) - np.interp(tj, t, yh)
            creep[after] += 0.025 * dy * np.log10(1 + (t[after] - tj - 0.1) / 0.05)
        out.append(finish(name, t, u, yh + creep, rng, 0.002))
    return out


def prandtl_ishlinskii(u: np.ndarray, radii: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Prandtl-Ishlinskii: sum_i w_i play_{r_i}(u), every play starting at 0."""
    return sum(w * play(u, r) for w, r in zip(weights, radii))


def pi_saturation(rng: np.random.Generator, quick: bool) -> list[Rec]:
    """Prandtl-Ishlinskii (10 plays) followed by y = Ys tanh(PI / Ys): an amplitude-modulated sine and a triangle."""
    radii = np.linspace(0.0, 0.9, 10)
    weights = 0.4 * np.exp(-2 * radii)
    per = 100 if quick else 300
    t1 = np.arange(0, 4 * per + 1) / per
    u1 = np.sin(2 * np.pi * t1) * (1 - 0.5 * np.sin(np.pi * t1 / 4) ** 2)
    t2 = np.arange(0, 3 * per + 1) / (per * 0.5)
    u2 = triangle(t2, 0.5, 0.8)
    out = []
    for name, t, u in (("pisat_modulated", t1, u1), ("pisat_triangle", t2, u2)):
        p = prandtl_ishlinskii(u, radii, weights)
        out.append(finish(name, t, u, 0.8 * np.tanh(p / 0.8), rng, 0.002))
    return out


def spencer_force(t: np.ndarray, x: np.ndarray, v: np.ndarray, sub: int = 40) -> np.ndarray:
    """Force (N) of Spencer et al.'s (1997) MR damper model, x in cm, v in cm/s, parameters of their 0 V fit."""
    c0, k0, c1, k1, x0, al, ga, be, a = 21.0, 46.9, 283.0, 5.0, 14.3, 140.0, 363.0, 363.0, 301.0
    y = z = 0.0
    f = np.empty(len(t))
    for i in range(len(t)):
        dt = (t[i] - t[i - 1]) / sub if i else 0.0
        for j in range(sub if i else 1):
            w = (j + 1) / sub if i else 1.0
            xx = x[i - 1] + w * (x[i] - x[i - 1]) if i else x[0]
            vv = v[i - 1] + w * (v[i] - v[i - 1]) if i else v[0]
            ydot = (al * z + c0 * vv + k0 * (xx - y)) / (c0 + c1)
            dv = vv - ydot
            z += (-ga * abs(dv) * z * abs(z) - be * dv * z * z + a * dv) * dt
            y += ydot * dt
        f[i] = c1 * ydot + k1 * (x[i] - x0)
    return f


def mr_damper(rng: np.random.Generator, quick: bool) -> list[Rec]:
    """Spencer MR damper, displacement sines of 1.5 cm at 1, 2.5 and 4 Hz: input the velocity, output the force."""
    per = 150 if quick else 400
    out = []
    for f, off in ((1.0, 0.0), (2.5, 0.005), (4.0, -0.005)):
        t = np.arange(0, 3 * per + 1) / (per * f)
        x = 1.5 * np.sin(2 * np.pi * f * t)
        v = 1.5 * 2 * np.pi * f * np.cos(2 * np.pi * f * t)
        out.append(finish(f"mr_{f:g}Hz", t, v, spencer_force(t, x, v), rng, 0.002, off))
    return out


@dataclass(frozen=True)
class ZooSet:
    """A set of recordings: its simulator, a short statement of the physics and the catalogue effect nearest it."""

    name: str
    make: Callable[[np.random.Generator, bool], list[Rec]]
    physics: str
    nearest: str


SETS: dict[str, ZooSet] = {
    s.name: s
    for s in [
        ZooSet("jiles_atherton", jiles_atherton, "JA + eddy currents, 5/50/200 Hz", "rate_dependence"),
        ZooSet("bouc_wen_pinching", bouc_wen_pinching, "Baber-Noori pinched Bouc-Wen", "none (loop shape)"),
        ZooSet("preisach", preisach, "Preisach relay grid, random turning points", "none (RI, other class)"),
        ZooSet("play", play_gain, "play operator w=0.2, gain 2", "backlash"),
        ZooSet("dead_zone", dead_zone_gain, "dead zone w=0.2, gain 2 (memoryless)", "none (no hysteresis)"),
        ZooSet("maxwell_slip", maxwell_slip, "Maxwell-slip, 8 elements (+ zero offset)", "none (RI, PI class)"),
        ZooSet("input_lag", input_lag, "Bouc-Wen after input lag tau=10ms, 0.5/3/12 Hz", "sensor_lag (on the input)"),
        ZooSet("log_creep", log_creep, "Bouc-Wen + log10 creep after steps", "creep"),
        ZooSet("pi_saturation", pi_saturation, "Prandtl-Ishlinskii + tanh saturation", "saturation"),
        ZooSet("mr_damper", mr_damper, "Spencer MR damper, velocity in, 1/2.5/4 Hz", "viscous / rate_dependence"),
    ]
}


def make_set(name: str, quick: bool) -> list[Rec]:
    """The recordings of set `name`, from a generator seeded by the set's position (reproducible)."""
    seed = list(SETS).index(name) + 2024
    return SETS[name].make(np.random.default_rng(seed), quick)
