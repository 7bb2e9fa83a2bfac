"""Generate the shipped demo recording `examples/demo.csv` and its ground truth `demo_truth.json`.

The recording is a simulated piezo stack actuator: drive voltage u (V) to
displacement y (um), a rate-independent semilinear Duhem model of order 2
(eqs (1)-(2) of Oh & Bernstein 2007), simulated by the project's own kernel
(`fitter.core.simulate`).

Model (diagonal: two hysteretic states; while u rises each relaxes toward
2 um, while u falls toward 0, at rates a_i per volt of input travel)::

    rising  u:  dx_i/du = -a_i (x_i - 2)        (A+ = -diag(a), E+ = 2 a)
    falling u:  dx_i/du = +a_i x_i              (A- = +diag(a), E- = 0)
    y = c . x + d u

with a = (0.06, 0.02) 1/V, c = (0.9, 1.4), d = 0.085 um/V.
Condition (5): rho(e^{beta A+} e^{-beta A-}) = e^{-2 * 0.02 * beta} < 1.

Input: 6 periods at 1 Hz of a sine-ish drive from 0 V to 100 V (a sine with a
5% third harmonic), 400 samples per period; the actuator starts from x = (1, 1) um
(a remanent state left by earlier use), not
from its periodic state, so the first cycles hold a start-up transient.
Measurement: seeded white noise, 0.05 V on u and 0.015 um on y (about 0.15%
of the output range), y rounded to 1 nm (quantisation).

Run from the repository root: ``python examples/make_demo.py``.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from fitter.core import RateIndependentModel, Signal, Signals, save_model, simulate
from fitter.core.models import Experiment

HERE = Path(__file__).resolve().parent
SEED = 20070501
PERIODS, SAMPLES_PER_PERIOD, FREQ = 6, 400, 1.0


def truth() -> RateIndependentModel:
    a = np.array([0.06, 0.02])
    return RateIndependentModel(
        A_plus=-np.diag(a),
        A_minus=np.diag(a),
        B_plus=[0, 0],
        B_minus=[0, 0],
        E_plus=2 * a,
        E_minus=[0, 0],
        C=[0.9, 1.4],
        D=0.085,
        x0=[1.0, 1.0],
        signals=Signals(Signal("u", "V", "drive voltage"), Signal("y", "um", "displacement")),
        experiment=Experiment(0.0, PERIODS / FREQ, 1.0 / (FREQ * SAMPLES_PER_PERIOD)),
        fit_info={"source": "ground truth of examples/demo.csv (examples/make_demo.py)"},
    )


def drive(t: np.ndarray) -> np.ndarray:
    """0..100 V: 50 - 50 (cos w t + 0.05 cos 3 w t) / 1.05, starting at 0 V."""
    w = 2 * np.pi * FREQ
    return 50.0 - 50.0 * (np.cos(w * t) + 0.05 * np.cos(3 * w * t)) / 1.05


def _atomic_text(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=path.parent)
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        fh.write(text)
    os.chmod(tmp, 0o644)
    os.replace(tmp, path)


def main() -> None:
    rng = np.random.default_rng(SEED)
    n = PERIODS * SAMPLES_PER_PERIOD + 1
    t = np.arange(n) / (FREQ * SAMPLES_PER_PERIOD)
    u = drive(t)
    model = truth()
    y = simulate(model, t, u).y
    u_meas = u + 0.05 * rng.standard_normal(n)
    y_meas = np.round(y + 0.015 * rng.standard_normal(n), 3)
    lines = ["time_s,u_V,y_um"] + [f"{a:.6f},{b:.4f},{c:.3f}" for a, b, c in zip(t, u_meas, y_meas)]
    _atomic_text(HERE / "demo.csv", "\n".join(lines) + "\n")
    save_model(model, HERE / "demo_truth.json")
    os.chmod(HERE / "demo_truth.json", 0o644)
    print(f"wrote {HERE / 'demo.csv'} ({n} samples) and {HERE / 'demo_truth.json'}")


if __name__ == "__main__":
    main()
