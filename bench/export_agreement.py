"""Does the exported FMU reproduce what `fit` reported?  On the demo and the shared measured recordings.

    python bench/export_agreement.py [--json] [CASE ...]

Per recording: `fit_recordings` (kind auto), then the native FMU of the saved model driven by fmpy over all
samples of the raw recording from its stored x0.  Printed: the model chosen, the optimiser's NRMSE on the
prepared samples (``prepared``), the NRMSE the fit reports for the saved model (``fit``), the FMU's
(``fmu``), whether fmu <= max(1.5 x prepared, prepared + 1 %), the input dead band, the convergence
verdict and the CPU seconds of the fit.  Cases: demo, piezo triangles at 1 / 0.1 / 0.01 Hz (voltage ->
polarization), friction at 1 / 4 / 7 bar (position -> force); the shared data are read from
``../shared/data`` at run time and skipped when absent.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from fitter import build_fmu, fit_recordings, load_recording
from fitter.data.metrics import nrmse
from fitter.fmu.host import simulate_fmu

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
PIEZO = {
    "piezo 1 Hz": "slow_T06_triangle_1400V_1Hz",
    "piezo 0.1 Hz": "slow_T01_triangle_1400V_0.1Hz",
    "piezo 0.01 Hz": "slow_T02_triangle_1400V_0.01Hz",
}


def _cases() -> dict:
    cases = {"demo": lambda: load_recording(ROOT / "examples" / "demo.csv")}
    if (DATA / "piezo-pnzt").is_dir():
        for label, name in PIEZO.items():
            cases[label] = lambda n=name: load_recording(
                DATA / "piezo-pnzt" / f"{n}.csv", time="time_s", input="voltage_V", output="polarization_uC_per_cm2"
            )
    if (DATA / "friction-pneumatic").is_dir():
        for p in (1, 4, 7):
            cases[f"friction {p} bar"] = lambda p=p: load_recording(
                DATA / "friction-pneumatic" / f"Circle_{p}bar.csv", time="time_s", input="position_mm", output="force_N"
            )
    return cases


def run(case: str, load) -> dict:
    rec = load()
    t0 = time.process_time()
    fit = fit_recordings([rec])
    cpu = time.process_time() - t0
    row = fit.summary["recordings"][0]
    with tempfile.TemporaryDirectory() as tmp:
        fmu = build_fmu(fit.model, Path(tmp) / "m.fmu", backend="native", allow_unstable=True)
        got = nrmse(rec.y, simulate_fmu(fmu, rec.t, rec.u))
    prepared = row["nrmse_prepared"]
    return {
        "case": case,
        "model": f"{fit.summary['kind']}{fit.summary['order']}",
        "prepared": prepared,
        "fit": row["nrmse"],
        "fmu": got,
        "within": bool(got <= max(1.5 * prepared, prepared + 0.01)),
        "deadband": fit.summary["input_deadband"],
        "converges": fit.summary["convergence"]["satisfied"],
        "cpu_s": cpu,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", help="subset of the cases (default: all present)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = []
    for case, load in _cases().items():
        if args.cases and case not in args.cases:
            continue
        rows.append(run(case, load))
        if not args.json:
            r = rows[-1]
            print(
                f"{case:16s} {r['model']:4s} prepared {r['prepared']:7.2%}  fit {r['fit']:7.2%}  "
                f"fmu {r['fmu']:7.2%}  within {'yes' if r['within'] else 'NO ':3s}  dead band "
                f"{r['deadband']:.3g}  converges {r['converges']}  cpu {r['cpu_s']:.0f} s",
                flush=True,
            )
    if args.json:
        print(json.dumps(rows, indent=2))
    return 0 if all(r["within"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
