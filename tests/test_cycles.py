"""Reversals and cycles (`fitter.data.cycles`) and the first settled cycle of a prepared recording."""

import numpy as np
import pytest

from fitter.core import RateIndependentModel, simulate
from fitter.data.cycles import (
    PreparationError,
    closing_period,
    count_reversals,
    cycle_reversals,
    find_reversals,
    last_full_cycle,
    period_cycle,
    split_cycles,
)
from fitter.data.metrics import compare
from fitter.data.preparation import prepare
from fitter.data.recordings import Recording
from fitter.diagnosis import synthetic_experiment


def wiggle():
    """Up 0 -> 1, back by 0.07 (5.8% of the range 1.2), up to 1.2, down to 0."""
    return np.r_[np.linspace(0, 1, 50), np.linspace(1, 0.93, 5), np.linspace(0.93, 1.2, 20), np.linspace(1.2, 0, 60)]


def test_threshold_policy_and_the_ten_percent_counter():
    u = wiggle()
    # default threshold max(5% of range, 6 noise) = 0.06 < 0.07: the wiggle is a minor loop
    assert list(find_reversals(u)) == [49, 54, 74]
    assert count_reversals(u) == 3
    # reversals larger than 10% of the range only
    assert count_reversals(u, threshold=0.1 * np.ptp(u)) == 1
    assert count_reversals(np.ones(20)) == 0 and count_reversals([0.0, 1.0]) == 0


def test_ten_percent_counter_on_the_diagnosis_experiments():
    """4 runs of 2 trapezoidal triangles each from -1: 3 reversals per run, 15 over the joined runs."""
    for effect, seed in ((None, 0), ("creep", 0), ("backlash", 1)):
        recs, _ = synthetic_experiment(effect, seed=seed, samples=300)
        u = np.concatenate([r.u for r in recs])
        assert count_reversals(u, threshold=0.1 * np.ptp(u)) == 15
        assert [count_reversals(r.u, threshold=0.1 * np.ptp(r.u)) for r in recs] == [3, 3, 3, 3]


def test_last_full_cycle_ends_at_the_last_reversal_whatever_its_kind():
    t = np.linspace(0, 6.5 * np.pi, 651)
    u = np.cos(t + 0.3)  # first reversal a minimum, six in all
    assert list(find_reversals(u)) == [90, 190, 290, 390, 490, 590]
    assert cycle_reversals(u) == [(90, 190, 290), (290, 390, 490)]  # min -> max -> min
    assert split_cycles(u) == [slice(90, 291), slice(290, 491)]
    assert last_full_cycle(u) == slice(390, 591)  # max -> min -> max
    with pytest.raises(PreparationError, match="reverses 1 time"):
        last_full_cycle(u[:150])


def test_one_period_and_one_closing_period():
    t = np.linspace(0, 2 * np.pi, 400)
    r = find_reversals(np.sin(t))
    assert period_cycle(np.sin(t), r) == slice(0, 400) == closing_period(np.sin(t), r)
    # ends 0.1 short of its start (5% of the range): not a period, but a closing period
    t = np.linspace(0, 2 * np.pi - 0.1, 400)
    r = find_reversals(np.sin(t))
    assert list(r) == [101, 304]
    assert period_cycle(np.sin(t), r) is None and split_cycles(np.sin(t)) == []
    assert closing_period(np.sin(t), r) == slice(0, 400)
    # ends falling: not closing
    t = np.linspace(0, 2.5 * np.pi, 400)
    assert closing_period(np.sin(t), find_reversals(np.sin(t))) is None


def first_order():
    return RateIndependentModel(
        A_plus=[[-0.4]], A_minus=[[0.4]], B_plus=[0], B_minus=[0], E_plus=[0.4], E_minus=[0.4], C=[1], D=0.5, x0=[1.5]
    )


def test_first_cycle_is_the_first_settled_cycle():
    t = np.linspace(0, 10 * 2 * np.pi, 6000)
    u = np.sin(t)
    rec = Recording(t, u, simulate(first_order(), t, u).y)
    p = prepare(rec, min_cycles=0)
    cycles = split_cycles(rec)
    # the transient shrinks by exp(-1.6) per cycle: the 4th full cycle is the first settled one
    assert p.transient_end == cycles[3].start
    s0, s1 = p.first_cycle()
    assert (s0 + p.transient_end, s1 + p.transient_end) == (cycles[3].start, cycles[3].stop - 1)
    assert s1 - s0 == 600 and u[p.transient_end + s0] == pytest.approx(u[p.transient_end + s1], abs=1e-5)


def test_first_cycle_of_a_closing_period_and_too_few_cycles():
    t = np.linspace(0, 2 * np.pi - 0.1, 400)
    assert prepare(Recording(t, np.sin(t), np.cos(t)), min_cycles=0).first_cycle() == (0, 399)
    t = np.linspace(0, 1.5 * np.pi, 300)
    p = prepare(Recording(t, np.sin(t), np.cos(t), name="short"), min_cycles=0)
    with pytest.raises(PreparationError, match=r"^short: too few cycles: no full input cycle \(1 reversals\)"):
        p.first_cycle()


def test_compare_judges_the_last_full_cycle():
    t = np.linspace(0, 6.5 * np.pi, 651)
    u = np.cos(t + 0.3)
    y = np.sin(t)
    y_hat = y + np.where(np.arange(651) >= 390, 0.01, 1.0)  # wrong before the last full cycle only
    c = compare(Recording(t, u, y), y_hat)
    assert c["last_cycle"] == [390, 591]
    assert c["max_error_last_cycle"] == pytest.approx(0.01)
    assert c["max_error"] == pytest.approx(1.0)


def test_closed_loop_needs_input_and_output_back_where_they_started():
    """One period from u = 0 rising back to u = 0 rising, its output back too: a closed loop; the same input
    with an output that drifts away by 20 % of its range, half a period more, or a monotone ramp: not."""
    from fitter.data.cycles import closed_loop
    from fitter.data.recordings import Recording

    t = np.linspace(0.0, 1.0, 401)
    u = np.interp(t, [0.0, 0.25, 0.75, 1.0], [0.0, 1.0, -1.0, 0.0])
    loop = np.tanh(3 * u) + 0.3 * np.sin(2 * np.pi * t)
    assert closed_loop(Recording(t, u, loop))
    assert not closed_loop(Recording(t, u, loop + 0.2 * np.ptp(loop) * t))
    longer = np.linspace(0.0, 1.5, 601)
    u_long = np.interp(longer % 1.0, [0.0, 0.25, 0.75, 1.0], [0.0, 1.0, -1.0, 0.0])
    assert not closed_loop(Recording(longer, u_long, np.tanh(3 * u_long)))
    assert not closed_loop(Recording(t, t, t))
