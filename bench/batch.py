"""Benchmark `duhem batch`: 32 generated devices on 1, 2 and all local Dask workers.

    python bench/batch.py                      # 32 devices, workers 1, 2 and os.cpu_count()
    python bench/batch.py --devices 8 --workers 1 2 --diagnose --keep DIR

Each device is one recording (600 samples, three triangle cycles of period 4 s) of a first-order
rate-independent base (`fitter.diagnosis.fitting.first_order_ri`) whose branch rates, gains and offsets
spread by +-25 % across the batch (seeded), every fourth device with one effect of
`fitter.core.effects.REGISTRY` at its `example` values (in turn backlash, creep, saturation, sensor_lag,
viscous, thermal_drift, rate_dependence, measurement_drift), plus output noise of 0.3 % of the range; the
CSVs are generated with the project's own simulator (`fitter.core.kernel.simulate`) under a temporary
directory.  Device 7 (no effect) gets branch rates 2.5 times the others' (the summary should flag it).

For each worker count: a fresh `distributed.LocalCluster` (processes, one thread each) is started and
warmed up (every worker imports the package), then `fitter.batch.run_batch` runs the whole manifest into a
fresh OUTDIR (nothing skipped): its wall time is the figure; the speed-up is T(1) / T(N), per worker
T(1) / (N T(N)).  Task wall time summed over the devices beside their CPU time summed (the worker and its C
compiler) shows contention: when other work shares the cores, the tasks of N workers each take longer in wall
time for the same CPU time.  Default options of `duhem batch` except ``--kind ri`` (each fit chooses its order by BIC;
native FMU, validation, report).  On a 2-core machine a speed-up of 2 is the limit, less when the machine
is shared.
"""

from __future__ import annotations

import argparse
import csv
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from fitter.batch import BatchOptions, run_batch
from fitter.core.effects import REGISTRY, Effect
from fitter.core.kernel import simulate
from fitter.diagnosis.fitting import first_order_ri

EFFECTS = (
    "backlash",
    "creep",
    "saturation",
    "sensor_lag",
    "viscous",
    "thermal_drift",
    "rate_dependence",
    "measurement_drift",
)
OUTLIER = 6


def generate(directory: Path, n: int, seed: int = 0) -> Path:
    """`n` device CSVs and their manifest under `directory`; returns the manifest."""
    rng = np.random.default_rng(seed)
    data = directory / "data"
    data.mkdir(parents=True, exist_ok=True)
    t = np.linspace(0.0, 12.0, 600)
    u = np.interp((t / 4.0) % 1.0, [0.0, 0.5, 1.0], [-1.0, 1.0, -1.0])
    rows = []
    for i in range(n):
        s = 1.0 + 0.25 * rng.uniform(-1, 1, 4)
        a = 3.0 * s[0] * (2.5 if i == OUTLIER else 1.0)
        base = first_order_ri(
            a_plus=-a,
            a_minus=a,
            b_plus=3.0 * s[1],
            b_minus=-3.0 * s[1],
            e_plus=-1.5 * s[2],
            e_minus=-1.5 * s[2],
            x0=-0.1 * s[3],
        )
        effect = EFFECTS[(i // 4) % len(EFFECTS)] if i % 4 == 3 else None
        model = base.replace(effects=[Effect(effect, dict(REGISTRY[effect].example))]) if effect else base
        y = simulate(model, t, u).y
        y = y + rng.normal(0.0, 0.003 * np.ptp(y), y.size)
        name = f"dev{i + 1:02d}"
        np.savetxt(
            data / f"{name}.csv",
            np.column_stack([t, u, y]),
            delimiter=",",
            header="time,u_V,y_um",
            comments="",
            fmt="%.12g",
        )
        rows.append({"device": name, "recordings": f"data/{name}.csv", "input": "u", "output": "y"})
    manifest = directory / "manifest.csv"
    with open(manifest, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["device", "recordings", "input", "output"])
        w.writerows([[r["device"], r["recordings"], r["input"], r["output"]] for r in rows])
    return manifest


def timed_run(manifest: Path, outdir: Path, workers: int, options: BatchOptions) -> tuple[float, float, object]:
    """(cluster start-up s, batch wall s, report) with a fresh LocalCluster of `workers` processes."""
    import distributed

    t0 = time.perf_counter()
    with (
        distributed.LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0"
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        client.wait_for_workers(workers)
        client.run(lambda: __import__("fitter.batch"))  # every worker imports the package once
        startup = time.perf_counter() - t0
        t1 = time.perf_counter()
        report = run_batch(manifest, outdir, options=options, client=client, progress=False)
        return startup, time.perf_counter() - t1, report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", type=int, default=32)
    ap.add_argument("--workers", type=int, nargs="+", help="worker counts (default: 1, 2 and os.cpu_count())")
    ap.add_argument("--diagnose", action="store_true", help="also diagnose every device (much slower)")
    ap.add_argument("--order", type=int, help="fit this order (default: chosen by BIC, as duhem batch)")
    ap.add_argument(
        "--keep", type=Path, help="write the manifest, data and outputs here (default: a temporary directory, removed)"
    )
    args = ap.parse_args()
    counts = args.workers or sorted({1, 2, os.cpu_count() or 1})
    options = BatchOptions(kind="ri", order=args.order, diagnose=args.diagnose)
    with tempfile.TemporaryDirectory(prefix="duhem-bench-batch-") as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        manifest = generate(root, args.devices)
        print(
            f"{args.devices} devices, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start; "
            f"options {options}"
        )
        results = {}
        for n in counts:
            startup, wall, report = timed_run(manifest, root / f"out-{n}-workers", n, options)
            busy = sum((report.entries[d].get("seconds") or 0.0) for d in report.devices)
            cpu = sum(((report.entries[d].get("row") or {}).get("cpu_seconds") or 0.0) for d in report.devices)
            results[n] = wall
            print(
                f"workers {n}: batch {wall:6.1f} s (cluster start-up {startup:4.1f} s), task wall time summed "
                f"{busy:6.1f} s, task CPU time summed {cpu:6.1f} s, {report.counts()}, outliers "
                f"{sorted(report.outliers)}, load average {os.getloadavg()[0]:.1f}",
                flush=True,
            )
        t1 = results.get(1)
        print("\n| workers | wall time (s) | speed-up | per worker |\n|---|---|---|---|")
        for n in counts:
            speed = t1 / results[n] if t1 else float("nan")
            print(f"| {n} | {results[n]:.1f} | {speed:.2f}x | {speed / n:.2f} |")
        if not args.workers:
            print(f"all local workers: os.cpu_count() = {os.cpu_count()} (the row of {os.cpu_count()} workers)")
        print(f"load average at the end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
