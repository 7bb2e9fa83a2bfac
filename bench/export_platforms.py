"""Size and export time of native FMUs with every platform's binaries, against this machine's binary alone.

For each kind of native FMU (the model in FMI 2.0 and 3.0, the compensator in
FMI 2.0) this exports the same fitted model twice per repeat, alternating:

* ``all``: Linux, Windows and macOS (x86_64 and arm64) binaries, cross-compiled
  with zig (`fitter.fmu.toolchain`), the default of ``duhem export``;
* ``host``: this machine's binary alone (``--platforms host``), the peer.

and prints the best time of each, their ratio, and the FMU sizes.  The zig cache
is warmed by one untimed export of each kind first (a cold cache costs about
1.5 minutes once per machine, for mingw-w64's C runtime); the figures are those
of a user's second and later exports.

Usage::

    python bench/export_platforms.py [--repeats 3] [--json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fitter.core import load_model  # noqa: E402
from fitter.fmu.native import build_native_compensator, build_native_fmu  # noqa: E402

KINDS = {
    "model, FMI 2.0": (build_native_fmu, 2),
    "model, FMI 3.0": (build_native_fmu, 3),
    "compensator, FMI 2.0": (build_native_compensator, 2),
}


def demo_model():
    """The shipped demo's true model (an order-2 rate-independent model), given the demo's input range
    (the compensator needs a finite one)."""
    model = load_model(ROOT / "examples" / "demo_truth.json")
    return model if model.input_range is not None else dataclasses.replace(model, input_range=(-1.0, 1.0))


def timed_export(build, model, out: Path, fmi_version: int, platforms: str | None) -> float:
    """Seconds taken by one export."""
    start = time.perf_counter()
    build(model, out, fmi_version=fmi_version, platforms=platforms)
    return time.perf_counter() - start


def measure(repeats: int) -> list[dict]:
    """One row per kind: best seconds and FMU bytes for all platforms and for this machine's binary."""
    model = demo_model()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind, (build, version) in KINDS.items():
            paths = {sel: Path(tmp) / f"{sel}-{version}-{build.__name__}.fmu" for sel in ("all", "host")}
            timed_export(build, model, paths["all"], version, None)  # warms zig's cache
            best = {"all": float("inf"), "host": float("inf")}
            for _ in range(repeats):
                for sel in ("all", "host"):
                    t = timed_export(build, model, paths[sel], version, None if sel == "all" else "host")
                    best[sel] = min(best[sel], t)
            rows.append(
                {
                    "kind": kind,
                    "seconds_all": best["all"],
                    "seconds_host": best["host"],
                    "time_ratio": best["all"] / best["host"],
                    "bytes_all": paths["all"].stat().st_size,
                    "bytes_host": paths["host"].stat().st_size,
                }
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    args = parser.parse_args()
    rows = measure(args.repeats)
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    print(f"{'FMU':22s} {'all [s]':>8s} {'host [s]':>9s} {'ratio':>6s} {'all [kB]':>9s} {'host [kB]':>10s}")
    for r in rows:
        print(
            f"{r['kind']:22s} {r['seconds_all']:8.2f} {r['seconds_host']:9.2f} {r['time_ratio']:6.2f} "
            f"{r['bytes_all'] / 1e3:9.0f} {r['bytes_host'] / 1e3:10.0f}"
        )


if __name__ == "__main__":
    main()
