"""Forward selection refits jointly: a finding that took part of a later candidate's account gives it back.

Three separate runs of voltage-step (trapezoid) experiments, each file from t = 0 with its own instrument
zero: a first-order base with a relaxation spectrum (0.2-4 s), plus an output drift linear in time (an offset
current integrated by a charge amplifier, as the shared creep trapezoids carry) and white noise, both added
here with numpy.  The relaxation is found first and its slowest term takes part of the drift; refitted only
on top of it (the relaxation held), the drift leaves 3.6 times the noise; refitted jointly from its own
first-round fit (`fitter.diagnosis.fitting.joint_refit`), the extended model reaches the noise.
"""

from __future__ import annotations

import numpy as np

from fitter.core import simulate
from fitter.core.effects import Effect
from fitter.data.recordings import Recording
from fitter.diagnosis import diagnose
from fitter.diagnosis.fitting import first_order_ri

STEP = 0.02
"""Sample period [s]."""
DESIGNS = (((1.0, -1.0, 0.0, 0.7, 0.0), 4.0), ((1.0, -1.0, 0.0, 0.5, 0.0), 6.0), ((1.0, -1.0, 0.0, 0.8, 0.0), 3.0))
"""Per file: the hold levels (from 0, 50 ms ramps between them) and each hold's duration [s]."""
DRIFT = 0.01
"""The drift's rate in output ranges per second."""


def _trapezoid(levels: tuple[float, ...], hold: float) -> tuple[np.ndarray, np.ndarray]:
    knots_t, knots_u, t = [0.0], [0.0], 0.0
    for level in levels:
        knots_t += [t + 0.05, t + 0.05 + hold]
        knots_u += [level, level]
        t += 0.05 + hold
    ts = np.arange(0.0, t, STEP)
    return ts, np.interp(ts, knots_t, knots_u)


def _experiment(seed: int) -> tuple[list[Recording], float]:
    """The runs (references within 15 % of the range, noise 0.3 % of it) and the drift's rate [output/s]."""
    rng = np.random.default_rng(seed)
    relaxation = Effect("relaxation", {"k": 0.3, "w2": 1.0, "w3": 1.0, "w4": 1.0, "tau_min": 0.2, "tau_max": 4.0})
    model = first_order_ri(-3.0, 3.0, 1.0, 1.0, 0.0, 0.0, 0.0).replace(effects=[relaxation])
    clean = [(t, u, simulate(model, t, u).y) for t, u in (_trapezoid(*d) for d in DESIGNS)]
    span = float(np.ptp(np.concatenate([y for _, _, y in clean])))
    recs = [
        Recording(
            t,
            u,
            y + rng.uniform(-0.15, 0.15) * span + DRIFT * span * t + 0.003 * span * rng.standard_normal(len(t)),
            name=f"trapezoid{i}",
        )
        for i, (t, u, y) in enumerate(clean)
    ]
    return recs, DRIFT * span


def test_a_drift_taken_in_part_by_a_relaxation_found_first_is_given_back():
    recs, rate = _experiment(0)
    d = diagnose(recs, base_order=1, candidates=("relaxation", "measurement_drift", "creep", "viscous"))
    assert [(f["effect"], f["origin"]) for f in d.findings] == [
        ("relaxation", "material"),
        ("measurement_drift", "measurement"),
    ]
    assert d.extended["material_effects"] == ["relaxation"] and d.extended["measurement_effects"] == [
        "measurement_drift"
    ]
    drift = next(e for e in d.extended["effects"] if e["effect"] == "measurement_drift")
    assert abs(drift["parameters"]["rate"] / rate - 1) < 0.1
    assert d.extended["residual_rms"] < 1.2 * d.noise_rms  # the drift refitted on top of the relaxation: 3.6x
