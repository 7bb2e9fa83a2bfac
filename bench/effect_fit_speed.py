"""Benchmark an effect fit: `duhem fit --effects switching` on two rates, with and without the recordings' memo,
on one process and on two.

    python bench/effect_fit_speed.py     # wall-time ratios: memo / no memo (one process), two processes / one

The experiment: an order-1 rate-independent base with one switching population (S 0.6, thresholds +0.55 /
-0.5, width 0.06) under a triangle of periods 2 s and 20 s (1.5 cycles from u = 0, 301 samples each), 0.2 %
noise (seeded), fitted as ``fit_recordings(recs, kind="ri", order=1, effects=["switching"])``: 8 screened
starts and two joint refinements of 18 free parameters, each Jacobian by forward differences.

The peer is the same fit in the same run with `fitter.identification.output_error._remembered` replaced by a
plain call (every evaluation simulates the base and the effects afresh, as before the memo).  Both fits must
end at the same NRMSE to 1e-6 (the memo changes residuals at the rounding level only); the script prints both
wall times, the ratio and the NRMSE per recording.  Then the memoised fit again with ``DUHEM_WORKERS=2`` (the
screened starts and the raced refinements on two forked processes, `fitter.workers`) against the one-process
run: the same NRMSE exactly, and the ratio of wall times.
"""

from __future__ import annotations

import os
import time

import numpy as np

from fitter.core.kernel import simulate
from fitter.data.recordings import Recording
from fitter.diagnosis.fitting import first_order_ri
from fitter.identification import output_error
from fitter.identification.fit import fit_recordings

SWITCHING = {"S1": 0.6, "u_up1": 0.55, "u_dn1": -0.5, "width1": 0.06, "q1": -1.0}


def recordings(seed: int = 4) -> list[Recording]:
    """The two rates of the module docstring."""
    truth = first_order_ri(-3.0, 3.0, 3.0, -3.0, -1.5, -1.5, -1 / 6)
    truth = truth.replace(effects=[{"effect": "switching", "parameters": SWITCHING}])
    rng, out = np.random.default_rng(seed), []
    for period in (2.0, 20.0):
        t = np.linspace(0.0, 1.5 * period, 301)
        u = np.interp((t / period + 0.25) % 1.0, [0.0, 0.5, 1.0], [-1.0, 1.0, -1.0])
        y = simulate(truth, t, u).y
        out.append(Recording(t, u, y + rng.normal(0.0, 0.002 * np.ptp(y), len(y)), name=f"T{period:g}"))
    return out


def timed_fit(recs: list[Recording]) -> tuple[float, list[float]]:
    """Wall seconds and NRMSE per recording of the switching fit."""
    t0 = time.perf_counter()
    fit = fit_recordings(recs, kind="ri", order=1, effects=["switching"])
    return time.perf_counter() - t0, [r["nrmse"] for r in fit.summary["recordings"]]


def main() -> None:
    recs = recordings()
    os.environ["DUHEM_WORKERS"] = "1"
    memo_s, memo_nrmse = timed_fit(recs)
    kept = output_error._remembered
    output_error._remembered = lambda memo, kind, key, compute: compute()
    try:
        plain_s, plain_nrmse = timed_fit(recs)
    finally:
        output_error._remembered = kept
    print(f"switching fit, 2 x 301 samples: memo {memo_s:.1f} s, without {plain_s:.1f} s, ratio {memo_s / plain_s:.2f}")
    print("NRMSE per recording: memo " + " ".join(f"{v:.4%}" for v in memo_nrmse))
    print("                  without " + " ".join(f"{v:.4%}" for v in plain_nrmse))
    assert max(abs(a - b) for a, b in zip(memo_nrmse, plain_nrmse)) < 1e-6, "the memo changed the fit"
    os.environ["DUHEM_WORKERS"] = "2"
    two_s, two_nrmse = timed_fit(recs)
    print(f"two processes {two_s:.1f} s, one {memo_s:.1f} s, ratio {two_s / memo_s:.2f}")
    assert two_nrmse == memo_nrmse, "two processes changed the fit"


if __name__ == "__main__":
    main()
