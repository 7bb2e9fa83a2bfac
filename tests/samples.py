"""The suite's reference models, inputs and noisy recordings (test modules import them: ``from samples import
ri_model``; pytest puts tests/ on sys.path).

The models are semilinear Duhem models (Oh & Bernstein 2007):
rate independent, dx = (A+ x + B+ u + E+) du+ + (A- x + B- u + E-) du- with
du+ = max(du, 0), du- = min(du, 0); rate dependent,
dx/dt = g(du/dt) (A x + B u + E); both with y = C x + D u.
"""

from __future__ import annotations

import numpy as np

from fitter.core import Experiment, RateDependentModel, RateIndependentModel, Signal, Signals, TabulatedRate, simulate
from fitter.data.recordings import Recording
from fitter.paper import example3


def ri_model(order: int, effects=()) -> RateIndependentModel:
    """The suite's rate-independent model of `order` (1, 2 or 3), with `effects`.

    order 1: one state, E and D, x0 = 2 far from the loop (fits recover it);
    order 2: two coupled states and D, x0 off the loop (fit-and-export);
    order 3: a fitted model's full parameter set (E, D, x0) with named signals
    and a default experiment (the FMU tests and the backend contract).
    """
    if order == 1:
        return RateIndependentModel(
            A_plus=[[-3.0]],
            A_minus=[[2.0]],
            B_plus=[3.0],
            B_minus=[2.0],
            C=[4.0],
            E_plus=[1.0],
            E_minus=[-1.0],
            D=0.5,
            x0=[2.0],
            effects=list(effects),
        )
    if order == 2:
        return RateIndependentModel(
            A_plus=[[-3.0, 1.0], [0.0, -1.5]],
            A_minus=[[2.5, 0.0], [1.0, 1.2]],
            B_plus=[2.0, 1.0],
            B_minus=[1.5, 1.2],
            C=[1.0, 0.5],
            D=0.2,
            x0=[0.4, -0.3],
            effects=list(effects),
        )
    if order == 3:
        return RateIndependentModel(
            A_plus=[[-2.0, 1.0, 0.0], [-1.0, -2.0, 0.5], [0.0, -0.5, -1.0]],
            A_minus=[[-1.5, -1.0, 0.2], [1.0, -1.5, 0.0], [0.0, 0.3, -2.0]],
            B_plus=[1.0, 0.5, -0.2],
            B_minus=[0.8, -0.4, 0.3],
            E_plus=[0.1, 0.0, -0.05],
            E_minus=[-0.1, 0.02, 0.0],
            C=[1.0, -0.5, 0.25],
            D=0.4,
            x0=[0.2, -0.1, 0.05],
            signals=Signals(Signal("V_in", "V", "piezo drive voltage"), Signal("disp", "um", "stage displacement")),
            experiment=Experiment(0.0, 12.0, 0.01),
            effects=list(effects),
        )
    raise ValueError(f"no reference rate-independent model of order {order}")


def rd_model(order: int, effects=()) -> RateDependentModel:
    """The suite's rate-dependent model of `order` (1 or 2), g tabulated, with `effects`.

    order 1: g(v) = v / (1 + v/2) for v >= 0, mirrored (g(-v) = g(v)), on
    +-logspace(-3, 3, 121); E, D, x0 = 1.5.
    order 2: the paper's Example 3 (eqs 54-55) with g tabulated on
    +-geomspace(0.05, 6, 10) (20 nodes), plus E, D and x0.
    """
    if order == 1:
        v = np.logspace(-3, 3, 121)
        g = v / (1 + v / 2)
        return RateDependentModel(
            A=[[-1.0]],
            B=[1.0],
            C=[3.0],
            E=[0.2],
            D=0.3,
            g=TabulatedRate(np.r_[-v[::-1], v], np.r_[g[::-1], g]),
            x0=[1.5],
            effects=list(effects),
        )
    if order == 2:
        nodes = np.geomspace(0.05, 6.0, 10)
        g = TabulatedRate.from_function(example3.g_true, np.r_[-nodes[::-1], nodes])
        return example3.true_model().replace(g=g, E=[0.1, -0.05], D=0.05, x0=[0.1, -0.2], effects=list(effects))
    raise ValueError(f"no reference rate-dependent model of order {order}")


def sampled_input(n: int = 400, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """n irregular samples (periods uniform in [0.01, 0.06]) of
    u = 1.4 sin(1.7 t) + 0.5 sin(4.3 t + 0.3): reversals, and a held stretch
    (du = 0) over samples n/4 .. n/4 + n/20."""
    rng = np.random.default_rng(seed)
    t = np.r_[0.0, np.cumsum(rng.uniform(0.01, 0.06, n - 1))]
    u = 1.4 * np.sin(1.7 * t) + 0.5 * np.sin(4.3 * t + 0.3)
    u[n // 4 : n // 4 + n // 20] = u[n // 4]
    return t, u


def sine_input(
    omega: float, periods: int, per_period: int, offset: float = 0.0, amplitude: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """u = offset + amplitude sin(omega t), `per_period` samples a period, t in [0, periods 2 pi / omega]."""
    t = np.linspace(0, periods * 2 * np.pi / omega, periods * per_period + 1)
    return t, offset + amplitude * np.sin(omega * t)


def noisy_recording(model, t, u, *, noise: float, seed, relative: bool = True, name: str = "recording") -> Recording:
    """The model's simulated response plus seeded Gaussian output noise.

    y = simulate(model, t, u).y + s z with z ~ N(0, 1) drawn from
    ``np.random.default_rng(seed)`` (`seed` may be a Generator, to draw several
    recordings from one stream) and s = noise * ptp(y) when `relative`, else
    s = noise.
    """
    rng = np.random.default_rng(seed)
    y = simulate(model, t, u).y
    scale = noise * np.ptp(y) if relative else noise
    return Recording(t, u, y + scale * rng.standard_normal(len(y)), name=name)
