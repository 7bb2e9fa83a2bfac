"""Preparation (reversals, cycles, settling, drift, holds, resampling) and metric definitions."""

import json
from pathlib import Path

import numpy as np
import pytest

from fitter.core import RateIndependentModel, simulate
from fitter.data.cycles import PreparationError, find_reversals, last_full_cycle, split_cycles
from fitter.data.metrics import compare, loop_area, max_error, nrmse
from fitter.data.noise import noise_rms
from fitter.data.preparation import branch_on_grid, find_holds, prepare, resample_time, settled_start
from fitter.data.recordings import Recording, load_recording

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def duhem_first_order(a=0.4, x0=1.5):
    """dx/du = a (1 - x) rising, a (1 + x) falling: loops in [-1, 1]; a transient from x0 that
    shrinks by exp(-2 a beta) per cycle of input range beta."""
    return RateIndependentModel(
        A_plus=[[-a]], A_minus=[[a]], B_plus=[0], B_minus=[0], E_plus=[a], E_minus=[a], C=[1], D=0.5, x0=[x0]
    )


def sine_recording(periods=10, n=6000, noise=0.0, u_noise=0.0, quantum=0.0, seed=0, drift=0.0):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, periods * 2 * np.pi, n)
    u = np.sin(t)
    y = simulate(duhem_first_order(), t, u).y + noise * rng.standard_normal(n) + drift * t / (2 * np.pi)
    um = u + u_noise * rng.standard_normal(n)
    if quantum:
        um = quantum * np.round(um / quantum)
    return Recording(t, um, y), u


def true_extremes(t):
    """Indices of sin(t) extremes (t = pi/2 + k pi) inside the record."""
    k = np.arange(0, int(np.floor(t[-1] / np.pi - 0.5)) + 1)
    return np.array([np.argmin(np.abs(t - (np.pi / 2 + j * np.pi))) for j in k])


@pytest.mark.parametrize("u_noise,quantum", [(0.0, 0.0), (0.01, 0.0), (0.0, 0.02), (0.02, 0.01)])
def test_reversals_under_noise_and_quantisation(u_noise, quantum):
    rec, _ = sine_recording(u_noise=u_noise, quantum=quantum, seed=3)
    r = find_reversals(rec.u)
    truth = true_extremes(rec.t)
    assert len(r) == len(truth) == 20
    # within the samples where sin is within noise + quantum of its peak
    tol = 1 + int(np.ceil(np.sqrt(2 * (4 * u_noise + quantum)) / (2 * np.pi / 600)))
    assert np.max(np.abs(r - truth)) <= tol
    assert np.all(np.diff(np.sign(np.diff(rec.u[r]))) != 0)  # alternating max / min


def test_reversal_threshold_ignores_small_wiggles():
    u = np.r_[np.linspace(0, 1, 50), np.linspace(1, 0.97, 5), np.linspace(0.97, 1.2, 20), np.linspace(1.2, 0, 60)]
    assert list(find_reversals(u)) == [74]
    assert list(find_reversals(u, threshold=0.01)) == [49, 54, 74]


def test_split_cycles_full_cycles_only():
    rec, _ = sine_recording(periods=3, n=1800)
    cycles = split_cycles(rec)
    assert len(cycles) == 2
    for s in cycles:
        u = rec.u[s]
        assert u[0] == pytest.approx(u[-1], abs=1e-4) and np.ptp(u) == pytest.approx(2, abs=1e-4)


def test_settled_start_on_generated_transient():
    # the transient shrinks by exp(-1.6) = 0.2 per cycle: 0.19, 0.038, 0.0076, 0.0015 (RMS cycle
    # differences); tolerance 0.002 * range(y) = 0.0054 -> the first settled cycle is the 4th
    rec, _ = sine_recording()
    cycles = split_cycles(rec)
    assert settled_start(rec) == cycles[3].start
    p = prepare(rec)
    assert p.transient_end == cycles[3].start
    assert p.recording.t[0] == rec.t[cycles[3].start]
    assert len(p.cycles) == len(cycles) - 3
    assert p.cycle_difference[0] == pytest.approx(0.187, rel=0.02)
    # the kept cycles repeat each other: first and last kept cycle agree at matched samples
    a, b = p.cycles[0], p.cycles[-1]
    n = min(a.stop - a.start, b.stop - b.start)
    y = p.recording.y
    assert np.max(np.abs(y[a.start : a.start + n] - y[b.start : b.start + n])) < 0.01


def test_settled_start_without_transient_keeps_first_cycle():
    rec, _ = sine_recording()
    # the state after 10 periods is the periodic state (to 0.2^10) at the record's start phase
    x_periodic = simulate(duhem_first_order(), rec.t, rec.u).x[-1]
    steady = Recording(rec.t, rec.u, simulate(duhem_first_order(), rec.t, rec.u, x0=x_periodic).y)
    assert prepare(steady).transient_end == split_cycles(steady)[0].start


def test_drift_is_reported_and_not_taken_for_a_transient():
    rec, _ = sine_recording(noise=0.001, drift=0.01, seed=5)
    p = prepare(rec)
    assert p.drift_per_cycle == pytest.approx(0.01, rel=0.05)
    assert p.transient_end == split_cycles(rec)[3].start
    assert any("do not close" in n for n in p.notes)
    json.dumps(p.to_dict())


def test_too_few_cycles():
    t = np.linspace(0, 1, 100)
    rec = Recording(t, t, t**2, name="ramp")
    with pytest.raises(PreparationError, match="ramp: too few cycles: the input has 0 full cycle"):
        prepare(rec)


def test_holds_found_in_trapezoid():
    seg = [np.linspace(-1, 1, 100), np.full(80, 1.0), np.linspace(1, -1, 100), np.full(60, -1.0)]
    u = np.tile(np.concatenate(seg), 3) + 0.001 * np.random.default_rng(2).standard_normal(1020)
    holds = find_holds(np.arange(u.size), u, min_samples=20)
    assert len(holds) == 6
    lengths = [b - a for a, b in holds]
    assert all(78 <= n <= 84 for n in lengths[0::2]) and all(58 <= n <= 64 for n in lengths[1::2])


def test_branch_on_grid_accuracy():
    u = np.linspace(-1, 1, 400)
    y = np.tanh(2 * u)
    grid = np.linspace(-0.9, 0.9, 37)
    # linear interpolation error <= h^2/8 max|y''| with h = 2/399, |y''| <= 8 * 0.77
    assert np.max(np.abs(branch_on_grid(u, y, grid) - np.tanh(2 * grid))) < (2 / 399) ** 2 / 8 * 6.2
    # noisy, quantised input: sorting and averaging equal inputs keeps it close
    rng = np.random.default_rng(4)
    uq = np.round(u + 0.002 * rng.standard_normal(u.size), 2)
    err = branch_on_grid(uq, y, grid) - np.tanh(2 * grid)
    assert np.max(np.abs(err)) < 0.03
    with pytest.raises(PreparationError, match="leaves the branch's input range"):
        branch_on_grid(u, y, [0.0, 1.5])


def test_resample_time_uniform():
    t = np.cumsum(np.r_[0, np.full(50, 0.01), np.full(50, 0.03)])
    rec = Recording(t, 2 * t, t**2)
    r = resample_time(rec, 0.005)
    assert np.allclose(np.diff(r.t), 0.005) and r.t[-1] == pytest.approx(t[-1])
    np.testing.assert_allclose(r.u, 2 * r.t, atol=1e-12)
    assert np.max(np.abs(r.y - r.t**2)) <= 0.03**2 / 4 + 1e-12


def test_nrmse_and_max_error_definitions():
    y = np.array([0.0, 1.0, 2.0, 4.0])
    e = np.array([0.1, -0.1, 0.1, -0.1])
    assert nrmse(y, y + e) == pytest.approx(0.1 / 4)
    assert max_error(y, y + np.array([0, 0.3, -0.5, 0])) == pytest.approx(0.5)


def test_loop_area_of_circle_and_orientation():
    th = np.linspace(0, 2 * np.pi, 2001)[:-1]
    assert loop_area(2 + 3 * np.cos(th), 3 * np.sin(th)) == pytest.approx(np.pi * 9, rel=1e-4)
    assert loop_area(np.cos(th), -np.sin(th)) == pytest.approx(-np.pi, rel=1e-4)
    # hysteresis loop: rising branch below the falling one -> positive
    u = np.r_[np.linspace(-1, 1, 101), np.linspace(1, -1, 101)]
    y = np.r_[np.linspace(-1, 1, 101) - 0.2, np.linspace(1, -1, 101) + 0.2]
    assert loop_area(u, y) == pytest.approx(0.8, rel=1e-12)


@pytest.mark.parametrize("sigma", [0.001, 0.01])
def test_noise_rms_estimate(sigma):
    rng = np.random.default_rng(7)
    t = np.linspace(0, 20, 4000)
    y = np.sin(t) + np.abs(np.sin(0.5 * t)) + sigma * rng.standard_normal(t.size)
    assert noise_rms(y) == pytest.approx(sigma, rel=0.1)


def test_last_full_cycle_and_compare():
    rec, _ = sine_recording(noise=0.002, seed=8)
    s = last_full_cycle(rec.u)
    assert s == split_cycles(rec)[-1] or s.stop > split_cycles(rec)[-1].stop
    assert s.stop - s.start == pytest.approx(601, abs=2)
    y_hat = simulate(duhem_first_order(), rec.t, rec.u).y
    c = compare(rec, y_hat)
    assert c["residual_rms"] == pytest.approx(0.002, rel=0.1)
    assert c["noise_rms"] == pytest.approx(0.002, rel=0.15)
    assert c["nrmse"] == pytest.approx(0.002 / np.ptp(rec.y), rel=0.1)
    assert abs(c["loop_area_error"]) < 0.01
    json.dumps(c)


@pytest.mark.skipif(not (DATA / "piezo-pnzt").exists(), reason="shared piezo data absent")
def test_piezo_triangle_prepares():
    rec = load_recording(DATA / "piezo-pnzt" / "slow_T01_triangle_1400V_0.1Hz.csv", "time", "voltage", "polarization")
    p = prepare(rec)
    # one period from +79 V up to 1467 V, down to -1322 V and back to +72 V: two reversals,
    # and the whole record is the one full cycle
    assert len(find_reversals(rec.u)) == 2
    assert [(s.start, s.stop) for s in p.cycles] == [(0, len(rec))] and p.transient_end == 0
    assert last_full_cycle(rec.u) == slice(0, len(rec))
