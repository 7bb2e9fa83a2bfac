"""Several runs of one device: one stored initial state for the runs that start at one input level, and the fit
from one shared start where the runs' own starts hide that one does not suit them all."""

from __future__ import annotations

import numpy as np

from fitter.core.kernel import simulate
from fitter.core.models import RateIndependentModel
from fitter.data.recordings import Recording
from fitter.identification.fit_data import start_groups
from fitter.identification.output_error import shared_initial_state
from fitter.identification.projection import LinearPart, solve_shared, split_solution

MODEL = RateIndependentModel(
    A_plus=[[-1.2, 0.4], [0.0, -3.0]],
    A_minus=[[1.0, 0.0], [0.3, 2.5]],
    B_plus=[0.5, 1.0],
    B_minus=[-0.4, 0.8],
    C=[1.0, 0.6],
    E_plus=[0.2, -0.1],
    E_minus=[0.1, 0.3],
    D=0.3,
    x0=[0.4, -0.7],
)


def _sine(amplitude: float, periods: float, n: int, start: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(t, u): a sine of `amplitude` about 0 from the phase where it passes `start` upward, n samples."""
    t = np.linspace(0.0, periods, n)
    phase = np.arcsin(start / amplitude)
    return t, amplitude * np.sin(2 * np.pi * t + phase)


def _recording(t, u, model=MODEL, name="r") -> Recording:
    return Recording(t, u, simulate(model, t, u).y, name)


def test_start_groups_gather_the_runs_that_start_at_one_input_level():
    runs = [_recording(*_sine(1.0, 2, 200, s)) for s in (0.0, 0.5, 0.01, 0.5 + 0.05)]
    # input range 2: the tolerance is 0.04; 0.01 joins 0.0, 0.55 is 0.05 from 0.5 and starts its own group
    assert start_groups(runs) == [0, 1, 0, 2]


def test_one_state_fitted_to_runs_from_one_start_is_exact():
    """Two runs of other amplitudes from the same state at one input: the shared least-squares start is that
    state (noise-free data: to rounding), though each run alone also fits it."""
    runs = [_recording(*_sine(a, p, n)) for a, p, n in ((1.0, 2, 300), (0.4, 3, 250))]
    x0, rss, _ = shared_initial_state(MODEL.replace(x0=[0.0, 0.0]), [(r.t, r.u, r.y) for r in runs])
    assert np.allclose(x0, MODEL.x0, atol=1e-9) and rss < 1e-18 * sum(len(r.y) for r in runs)


def test_grouped_own_unknowns_share_one_solution():
    """`solve_shared` with groups: parts of one group share their own unknowns; the solution is the stacked
    least squares with those columns added, and the split gives each part its group's values."""
    rng = np.random.default_rng(3)
    parts = [LinearPart(0, rng.normal(size=30), rng.normal(size=(30, 2)), rng.normal(size=(30, 3))) for _ in range(3)]
    theta, z_a, z_b = rng.normal(size=2), rng.normal(size=3), rng.normal(size=3)
    ys = [parts[0].output(theta, z_a), parts[1].output(theta, z_b), parts[2].output(theta, z_a)]
    weights = [np.ones(30)] * 3
    solution = solve_shared(parts, ys, weights, groups=[0, 1, 0])
    assert solution.shape == (2 + 3 + 3,)
    theta_l, own = split_solution(parts, solution, groups=[0, 1, 0])
    assert np.allclose(theta_l, theta) and np.allclose(own[0], z_a) and np.allclose(own[2], z_a)
    assert np.allclose(own[1], z_b)
    # without groups each part has its own unknowns (9 of them), and the same exact data are fitted exactly too
    alone = solve_shared(parts, ys, weights)
    assert alone.shape == (2 + 9,)
