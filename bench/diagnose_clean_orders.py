"""`duhem diagnose` on effect-free two-rate triangles of order-1/2/3 bases: nothing is missing.

    python bench/diagnose_clean_orders.py              # orders 1, 2, 3, each with its seed (= the order)
    python bench/diagnose_clean_orders.py --seeds 5    # orders 1, 2, 3 x seeds 1..5
    python bench/diagnose_clean_orders.py --orders 2   # only order 2

The sweep behind tests/test_diagnose.py::test_default_base_on_clean_data_of_any_order_has_nothing_missing
(the test keeps orders 1 and 3: the first-order base adequate, and a higher order needed; order 2 takes the
second path too).  Data: `fitter.diagnosis.synthetic.cell_base(order)` driven by two triangle runs on one
clock (periods 20 s and 4 s, 300 samples each, the second starting where the first ends), seeded Gaussian
output noise 0.5 % of the output range, as the test makes them.  Diagnosed with the defaults (the base order
chosen by BIC, competing with the first-order base's best effect).  A row passes when the verdict is
"nothing_missing" with no finding, the base's residual RMS is within 1.2 x the noise floor, and for orders 2
and 3 the base is of order > 1.  The exit status is 1 when a row fails.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from fitter.core import simulate
from fitter.data.recordings import Recording
from fitter.diagnosis import diagnose
from fitter.diagnosis.synthetic import cell_base


def two_rate_triangles(model, seed: int, noise: float = 0.005) -> list[Recording]:
    """Two triangle runs of `model` (tests/test_diagnose.py `_two_rate_triangles`, tests/samples.py
    `noisy_recording` with relative noise)."""
    t = np.r_[np.linspace(0, 40, 300), 40.5 + np.linspace(0, 8, 300)]
    period = np.where(t < 40.25, 20.0, 4.0)
    u = 1 - 4 * np.abs(((t - np.where(t < 40.25, 0, 40.5)) / period) % 1 - 0.5)
    y = simulate(model, t, u).y
    y = y + noise * np.ptp(y) * np.random.default_rng(seed).standard_normal(len(y))
    return [Recording(t[:300], u[:300], y[:300], name="slow"), Recording(t[300:], u[300:], y[300:], name="fast")]


def run(order: int, seed: int) -> bool:
    t0 = time.perf_counter()
    d = diagnose(two_rate_triangles(cell_base(order), seed=seed))
    ratio = d.baseline["residual_rms"] / d.noise_rms
    ok = d.verdict == "nothing_missing" and d.findings == [] and ratio <= 1.2 and (order == 1 or d.base_model.order > 1)
    print(
        f"{'PASS' if ok else 'FAIL'}  order {order} seed {seed}: verdict {d.verdict:15s} findings "
        f"{[f['effect'] for f in d.findings]}  base order {d.base_model.order}  base/noise {ratio:.3f}  "
        f"{time.perf_counter() - t0:.0f} s",
        flush=True,
    )
    return ok


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=0, help="seeds 1..N per order (default: the order's own seed)")
    ap.add_argument("--orders", type=int, nargs="*", default=[1, 2, 3], choices=[1, 2, 3])
    args = ap.parse_args(argv)
    results = [
        run(order, seed) for order in args.orders for seed in (range(1, args.seeds + 1) if args.seeds else (order,))
    ]
    print(f"{sum(results)} of {len(results)} clean experiments: nothing missing")
    return 0 if all(results) else 1


if __name__ == "__main__":
    sys.exit(main())
