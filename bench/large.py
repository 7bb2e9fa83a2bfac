"""Time and peak memory of `duhem simulate`, `validate` and `fit` on large recordings.

    python bench/large.py                          # 1e5, 1e6 and 2e6 samples
    python bench/large.py --sizes 100000 1000000   # chosen sizes
    python bench/large.py --skip-fit               # simulate and validate only

Each size gets a generated CSV (time,u,y: a first-order rate-independent model,
`fitter.diagnosis.synthetic.cell_base(1)`, driven by a sine of 20 periods with
a slow amplitude sweep, output noise 1 % of the range), written with numpy to a
temporary folder.  Each command runs as its own process (the console script
``duhem``, as a user runs it); the figures are its wall time and its peak
resident memory (``ru_maxrss`` of the finished child), beside the CSV's size.
`simulate` runs the generating model; `fit` runs with ``--kind ri --order 1``;
`validate` drives the native FMU that the fit wrote.  About 105 MB of each peak is
the interpreter and its libraries (numpy, scipy, click, fmpy), the whole figure at
1e5 samples; the rest grows with the samples.  Figures depend on the machine's
load: run it on a quiet one.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fitter.core import save_model
from fitter.core.kernel import simulate
from fitter.diagnosis.synthetic import cell_base

DUHEM = [sys.executable, "-c", "import sys; from fitter.cli import console; sys.argv[0] = 'duhem'; console()"]


def make_csv(path: Path, n: int, seed: int = 0) -> None:
    """`n` samples of the generated recording (module docstring)."""
    t = np.linspace(0.0, 200.0, n)
    u = (0.6 + 0.4 * np.sin(2 * np.pi * t / 200.0)) * np.sin(2 * np.pi * t / 10.0)
    y = simulate(cell_base(1), t, u).y
    y = y + 0.01 * np.ptp(y) * np.random.default_rng(seed).standard_normal(n)
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="time,u,y", comments="", fmt="%.10g")


def run(args: list[str]) -> tuple[float, float, int]:
    """Wall seconds, peak RSS (MB) and exit code of `duhem args` in a child process (run from a fresh
    parent, `_isolated`: ``RUSAGE_CHILDREN`` reports the largest child so far)."""
    start = time.perf_counter()
    code = subprocess.run(DUHEM + args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
    seconds = time.perf_counter() - start
    return seconds, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0, code


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000, 2_000_000])
    ap.add_argument("--skip-fit", action="store_true", help="only simulate (validate needs the fit's FMU)")
    args = ap.parse_args()
    print(f"{'samples':>9} {'CSV MB':>7}  {'command':9} {'seconds':>8} {'peak MB':>8} {'x CSV':>6}  exit")
    for n in sorted(args.sizes):
        with tempfile.TemporaryDirectory(prefix="duhem-large-") as tmp:
            d = Path(tmp)
            csv = d / "rec.csv"
            make_csv(csv, n)
            mb = csv.stat().st_size / 1e6
            save_model(cell_base(1), d / "truth.json")
            steps = [("simulate", ["simulate", str(d / "truth.json"), str(csv), "-o", str(d / "out.csv")])]
            if not args.skip_fit:
                steps += [
                    (
                        "fit",
                        [
                            "fit",
                            str(csv),
                            "-o",
                            str(d / "m.json"),
                            "--fmu",
                            str(d / "m.fmu"),
                            "--kind",
                            "ri",
                            "--order",
                            "1",
                        ],
                    ),
                    ("validate", ["validate", str(d / "m.fmu"), str(csv)]),
                ]
            for name, cmd in steps:
                seconds, peak, code = _isolated(cmd)
                print(f"{n:9d} {mb:7.1f}  {name:9s} {seconds:8.1f} {peak:8.0f} {peak / mb:6.1f}  {code}", flush=True)


def _isolated(cmd: list[str]) -> tuple[float, float, int]:
    """`run(cmd)` in a fresh Python process, so the peak is this command's alone."""
    code = "import json, sys; sys.path.insert(0, %r); import large; print(json.dumps(large.run(%r)))" % (
        str(Path(__file__).parent),
        cmd,
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    seconds, peak, rc = json.loads(out.strip().splitlines()[-1])
    return seconds, peak, rc


if __name__ == "__main__":
    main()
