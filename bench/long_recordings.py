"""Does a longer recording give a worse model?  `duhem fit` on a whole long file against its first tenth.

The device: a rate-independent Duhem model of order 2 (`fitter.diagnosis.synthetic.cell_base(2)`) driven
at 50 Hz through straight runs between uniformly random turning points in [-1, 1] (minor loops of every size),
each run 10 to 190 samples long (uniform: 100 on average, so a 1e6-sample file turns about 6700 times, more
than the search's scored samples), output noise 0.2 % of the output range (Gaussian, seeded).  For each size N
this writes the whole file and its first N/10 samples as CSV files, runs ``duhem fit FILE -o MODEL.json`` on
each in its own process (the console script, as a user runs it), and simulates both models on the whole file
from their stored x0 (`fitter.core.simulate`).  It prints, per size:

* each model's NRMSE on the whole file, and the ratio whole / tenth (target <= 1.05);
* the kind and order each fit chose;
* each fit's wall time and peak resident memory, and the whole fit's time as a ratio to the tenth's, measured in
  the same run (targets at 1e6 samples: <= 120 s and <= 400 MB; at 2e6: <= 240 s).

Usage::

    python bench/long_recordings.py [--sizes 1000000 2000000] [--json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fitter.core import load_model, simulate  # noqa: E402
from fitter.diagnosis.synthetic import cell_base  # noqa: E402
from large import DUHEM  # noqa: E402  (the console script as a process, as a user runs it)

RUN_SAMPLES = (10, 190)
RATE = 50.0
NOISE = 0.002


def recording(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, u, y) of the device (module docstring), `n` samples."""
    rng = np.random.default_rng(seed)
    knots = np.r_[0, np.cumsum(rng.integers(*RUN_SAMPLES, n // RUN_SAMPLES[0]))]
    knots = np.r_[knots[knots < n - 1], n - 1]
    u = np.interp(np.arange(n), knots, rng.uniform(-1.0, 1.0, len(knots)))
    t = np.arange(n) / RATE
    y = simulate(cell_base(2), t, u).y
    return t, u, y + NOISE * np.ptp(y) * rng.standard_normal(n)


def write_csv(path: Path, t: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="time,u,y", comments="", fmt="%.10g")


def timed_fit(csv: Path, out: Path) -> tuple[float, float]:
    """Wall seconds and peak RSS (MB) of ``duhem fit csv -o out`` in a child process; raises on failure."""
    code = (
        "import resource, subprocess, sys, time; t0 = time.perf_counter(); "
        f"rc = subprocess.run({DUHEM!r} + ['fit', {str(csv)!r}, '-o', {str(out)!r}], "
        "stdout=subprocess.DEVNULL).returncode; "
        "print(time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, rc)"
    )
    seconds, mb, rc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.split()
    if int(rc) != 0:
        raise RuntimeError(f"duhem fit {csv} failed (exit {rc})")
    return float(seconds), float(mb)


def nrmse(model_path: Path, t: np.ndarray, u: np.ndarray, y: np.ndarray) -> tuple[float, str]:
    """NRMSE of the saved model on (t, u, y) from its stored x0, and its kind and order."""
    model = load_model(model_path)
    e = simulate(model, t, u).y - y
    return float(np.sqrt(np.mean(e**2)) / np.ptp(y)), f"{model.kind}{model.order}"


def measure(n: int, folder: Path) -> dict:
    t, u, y = recording(n)
    head = n // 10
    write_csv(folder / "whole.csv", t, u, y)
    write_csv(folder / "tenth.csv", t[:head], u[:head], y[:head])
    row = {"samples": n}
    for part in ("tenth", "whole"):
        seconds, mb = timed_fit(folder / f"{part}.csv", folder / f"{part}.json")
        score, structure = nrmse(folder / f"{part}.json", t, u, y)
        row[part] = {"nrmse": score, "model": structure, "seconds": seconds, "peak_mb": mb}
    row["score_ratio"] = row["whole"]["nrmse"] / row["tenth"]["nrmse"]
    row["time_ratio"] = row["whole"]["seconds"] / row["tenth"]["seconds"]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1_000_000, 2_000_000])
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    args = parser.parse_args()
    rows = []
    for n in args.sizes:
        with tempfile.TemporaryDirectory() as tmp:
            rows.append(measure(n, Path(tmp)))
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    print(f"{'samples':>9s} {'fit on':>6s} {'model':>5s} {'NRMSE on whole':>15s} {'wall [s]':>9s} {'peak [MB]':>10s}")
    for r in rows:
        for part in ("tenth", "whole"):
            p = r[part]
            print(
                f"{r['samples']:9d} {part:>6s} {p['model']:>5s} {100 * p['nrmse']:14.4f}% {p['seconds']:9.1f} "
                f"{p['peak_mb']:10.0f}"
            )
        print(f"{'':9s} whole / tenth: score {r['score_ratio']:.3f} (target <= 1.05), time {r['time_ratio']:.2f}")


if __name__ == "__main__":
    main()
