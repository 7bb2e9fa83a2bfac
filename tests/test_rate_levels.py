"""The input's rate levels (`fit_data.rate_levels`): one recording whose legs are driven at several speeds has
several levels, so that `duhem fit` tries rate-dependent candidates on it; one speed, one level."""

from __future__ import annotations

import numpy as np

from fitter.data.recordings import Recording
from fitter.identification.fit_data import leg_rates, rate_levels


def _legs(levels, speeds, per_leg: int = 60) -> Recording:
    """Straight legs between `levels`, leg k at `speeds[k]` (input units per second), `per_leg` samples each."""
    t, u = [0.0], [levels[0]]
    for a, b, v in zip(levels[:-1], levels[1:], speeds):
        dt = abs(b - a) / v
        t += list(t[-1] + np.linspace(0.0, dt, per_leg + 1)[1:])
        u += list(np.linspace(a, b, per_leg + 1)[1:])
    t, u = np.array(t), np.array(u)
    return Recording(t, u, np.tanh(u), "legs")


def test_legs_at_two_speeds_in_one_recording_are_two_rate_levels():
    levels = [-1.0, 1.0, -0.6, 0.8, -1.0, 0.5, -0.4]
    one = _legs(levels, [2.0] * 6)
    two = _legs(levels, [2.0, 2.0, 8.0, 8.0, 2.0, 8.0])
    assert np.allclose(leg_rates(one), 2.0) and len(leg_rates(one)) == 6
    assert sorted(np.round(leg_rates(two), 6)) == [2.0, 2.0, 2.0, 8.0, 8.0, 8.0]
    assert rate_levels([one]).levels == 1
    assert rate_levels([two]).levels == 2


def test_a_leg_shorter_than_a_tenth_of_the_range_is_not_a_rate():
    rec = _legs([-1.0, 1.0, 0.95, 1.0, -1.0], [2.0, 20.0, 20.0, 2.0])
    # the 0.05 reversal at the top is below the reversal threshold: two legs, the fast dip inside the second
    # (2 / (1 + 0.005) = 1.990 on average), not legs of their own at 20
    assert np.allclose(leg_rates(rec), [2.0, 2.0 / 1.005]) and rate_levels([rec]).levels == 1
