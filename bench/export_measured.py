"""The exported FMU against the fit on every measured recording: the sweep behind tests/test_exported.py.

    python bench/export_measured.py [--json] [CASE ...]     # CASE: a name below, or a part of one

Cases: the demo (examples/demo.csv), every piezo recording ``../shared/data/piezo-pnzt/*_T*.csv``
(polarization against voltage) and the friction rig at 1 ... 7 bar (force F - p A against position, the
first 15 rows dropped), each fitted alone by `fit_recordings` (kind and order chosen by BIC).  The shared data
are read at run time and skipped when absent.  The test keeps the demo and one recording of each rig
(`test_exported_fmu_reproduces_the_fit_on_measured_recordings`); this script checks the same things on all
of them and prints one row per recording:

* ``model``: the kind and order chosen; ``converges``: condition (5) on the closed last cycle of the raw input;
* ``prepared`` / ``fit`` / ``fmu``: the optimiser's NRMSE on the prepared samples, the NRMSE the fit reports
  for the saved model (all raw samples, stored x0), and the native FMU's, driven by fmpy over all raw samples;
* ``|fmu-sim|``: the largest difference between the FMU's output and the kernel's, in output ranges
  (at most 2e-5); ``fmu~fit``: the FMU's NRMSE equals the fit's within 1e-4 (relative);
  ``within``: fmu <= max(1.5 x prepared, prepared + 1 %);
* ``rho``: condition (5) of every minor loop of a rate-independent model on its stored input range (< 1);
* ``excursion``: the summary's minor-loop excursion, recomputed (1e-12), and ``faithful`` matching it.

The exit status is 1 when any check fails on any recording.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fitter import build_fmu, fit_recordings, load_recording
from fitter.core.periodic import minor_loop_rho
from fitter.data.metrics import nrmse
from fitter.data.recordings import Recording
from fitter.fmu.host import simulate_fmu
from fitter.identification.exported import MINOR_LOOP_WARNING, minor_loop_excursion

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


def _piezo(name: str) -> list[Recording]:
    return [
        load_recording(
            DATA / "piezo-pnzt" / f"{name}.csv", time="time_s", input="voltage_V", output="polarization_uC_per_cm2"
        )
    ]


def _friction(bar: int) -> list[Recording]:
    """Friction force F - p A against position (bench/real_data.py), first 15 rows dropped."""
    with open(DATA / "friction-pneumatic" / f"Circle_{bar}bar.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))[15:]
    t, x, p, f = (np.array([float(r[k]) for r in rows]) for k in ("time_s", "position_mm", "pressure_bar", "force_N"))
    return [Recording(t, x, f - p * 1e5 * np.pi * 0.0125**2, name=f"{bar} bar")]


def cases() -> dict:
    """Every case present: name -> loader of its recordings."""
    out = {"demo": lambda: [load_recording(ROOT / "examples" / "demo.csv")]}
    if (DATA / "piezo-pnzt").is_dir():
        for path in sorted((DATA / "piezo-pnzt").glob("*_T*.csv")):
            out[path.stem] = lambda n=path.stem: _piezo(n)
    if (DATA / "friction-pneumatic").is_dir():
        for bar in range(1, 8):
            out[f"friction {bar} bar"] = lambda b=bar: _friction(b)
    return out


def run(case: str, load) -> dict:
    """Fit, export, drive the FMU over all raw samples; the figures and the checks of one case."""
    recs = load()
    t0 = time.process_time()
    fit = fit_recordings(recs)
    cpu = time.process_time() - t0
    checks = {
        "finite": all(math.isfinite(r["nrmse"]) for r in fit.summary["recordings"]),
        "converges": bool(fit.summary["convergence"]["satisfied"]),
    }
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        fmu = build_fmu(fit.model, Path(tmp) / "m.fmu", backend="native", allow_unstable=True)
        for rec, row in zip(recs, fit.summary["recordings"]):
            y_fmu = simulate_fmu(fmu, rec.t, rec.u)
            got = nrmse(rec.y, y_fmu)
            rows.append(
                {
                    "prepared": row["nrmse_prepared"],
                    "fit": row["nrmse"],
                    "fmu": got,
                    "fmu_sim": float(np.abs(y_fmu - fit.simulate(rec)).max() / np.ptp(rec.y)),
                }
            )
    checks["fmu_sim"] = all(r["fmu_sim"] <= 2e-5 for r in rows)
    checks["fmu_fit"] = all(abs(r["fmu"] - r["fit"]) <= 1e-4 * abs(r["fit"]) for r in rows)
    checks["within"] = all(r["fmu"] <= max(1.5 * r["prepared"], r["prepared"] + 0.01) for r in rows)
    rho = minor_loop_rho(fit.model, *fit.model.input_range) if fit.model.kind == "ri" else None
    checks["rho"] = rho is None or rho < 1
    minor = fit.summary["minor_loops"]
    checks["excursion"] = math.isclose(minor["excursion"], minor_loop_excursion(fit.model, recs), rel_tol=1e-12)
    checks["faithful"] = minor["faithful"] is (minor["excursion"] <= MINOR_LOOP_WARNING)
    return {
        "case": case,
        "model": f"{fit.summary['kind']}{fit.summary['order']}",
        "recordings": rows,
        "rho": rho,
        "excursion": minor["excursion"],
        "faithful": minor["faithful"],
        "checks": checks,
        "ok": all(checks.values()),
        "cpu_s": cpu,
    }


def line(r: dict) -> str:
    first = r["recordings"][0]
    failed = [k for k, ok in r["checks"].items() if not ok]
    rho = "-" if r["rho"] is None else f"{r['rho']:.3f}"
    return (
        f"{r['case']:34s} {r['model']:4s} prepared {first['prepared']:7.2%}  fit {first['fit']:7.2%}  "
        f"fmu {first['fmu']:7.2%}  |fmu-sim| {first['fmu_sim']:.1e}  rho {rho:5s}  excursion "
        f"{r['excursion']:.3g} ({'faithful' if r['faithful'] else 'not faithful'})  converges "
        f"{'yes' if r['checks']['converges'] else 'NO'}  {'ok' if r['ok'] else 'FAILED ' + ','.join(failed)}  "
        f"cpu {r['cpu_s']:.0f} s"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", help="only the cases whose name contains one of these (default: all)")
    ap.add_argument("--json", action="store_true", help="print the rows as JSON")
    args = ap.parse_args(argv)
    rows = []
    for case, load in cases().items():
        if args.cases and not any(part in case for part in args.cases):
            continue
        rows.append(run(case, load))
        if not args.json:
            print(line(rows[-1]), flush=True)
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        print(f"{sum(r['ok'] for r in rows)} of {len(rows)} recordings pass every check")
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
