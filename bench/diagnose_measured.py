"""`duhem diagnose` on the measured recordings of ``../shared/data``, as their instruments wrote them.

    python bench/diagnose_measured.py                 # the piezo triangles (issue 34's first must-show)
    python bench/diagnose_measured.py --set creep     # the four creep trapezoids
    python bench/diagnose_measured.py --set friction  # the seven friction pressures
    python bench/diagnose_measured.py --set all --json PATH

Each set is diagnosed as a user runs it, with no option but the column names (the same call as
``duhem diagnose FILES --time ... --input ... --output ...``): the files are separate runs, each from
t = 0 with its own instrument zero, recognised as such by the diagnosis.  Beside it, in the same run, the
classical models fitted to each record alone (`fitter.baselines.compare_baselines`: Preisach and
Prandtl-Ishlinskii); the table prints per record the extended model's NRMSE (``extended.nrmse_per_recording``),
its held-out NRMSE (``extended.heldout_nrmse_per_recording``: the record predicted by the extended model
fitted without it), the best classical NRMSE and whether the extended model is at or below it, and per set
the findings (material and measurement apart), the verdict and the wall time.

The data are read at run time (no licence for the piezo set: never copied into the repository); a set whose
folder is absent is skipped with a message.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from fitter.baselines import compare_baselines
from fitter.data.recordings import load_recordings
from fitter.diagnosis import diagnose
from real_data import DATA, PIEZO  # the shared data's place and the piezo triangles (bench/real_data.py)

SETS = {
    "piezo": ("piezo-pnzt", list(PIEZO.values()), ("time_s", "voltage_V", "polarization_uC_per_cm2")),
    "creep": (
        "piezo-pnzt",
        [
            f"creep_T0{k}_trapezoid_1400V_{v}"
            for k, v in ((1, "1000V_60S"), (2, "1000V_60S"), (3, "1200V_105S"), (4, "1200V_1400S"))
        ],
        ("time_s", "voltage_V", "polarization_uC_per_cm2"),
    ),
    "friction": ("friction-pneumatic", [f"Circle_{p}bar" for p in range(1, 8)], ("time_s", "position_mm", "force_N")),
}
CLASSICAL = ("preisach", "prandtl_ishlinskii")


def run_set(name: str) -> dict | None:
    """Diagnose one set and fit the classical models per record: the figures of the module docstring."""
    folder, stems, (t_col, u_col, y_col) = SETS[name]
    paths = [DATA / folder / f"{stem}.csv" for stem in stems]
    if not all(p.exists() for p in paths):
        print(f"{name}: skipped, {DATA / folder} is absent", file=sys.stderr)
        return None
    recs = load_recordings([str(p) for p in paths], t_col, u_col, y_col)
    t0 = time.perf_counter()
    d = diagnose(recs)
    seconds = time.perf_counter() - t0
    classical = compare_baselines(recs, per_recording=True, names=CLASSICAL)
    rows = []
    for rec in recs:
        best_name = min(CLASSICAL, key=lambda c: classical[c]["per_recording"][rec.name])
        best = classical[best_name]["per_recording"][rec.name]
        ext = d.extended["nrmse_per_recording"][rec.name]
        held = (d.extended["heldout_nrmse_per_recording"] or {}).get(rec.name)
        rows.append(
            {
                "record": rec.name,
                "base": d.baseline["nrmse_per_recording"][rec.name],
                "extended": ext,
                "held_out": held,
                "best_classical": best,
                "classical_model": best_name,
                "at_or_below_classical": bool(ext <= best),
            }
        )
    return {
        "set": name,
        "seconds": seconds,
        "verdict": d.verdict,
        "separate": d.separate,
        "material_effects": d.extended["material_effects"],
        "measurement_effects": d.extended["measurement_effects"],
        "base_order": d.base_model.order,
        "noise_rms": d.noise_rms,
        "remainder_noise_ratio": d.extended["remainder"]["noise_ratio"],
        "records": rows,
    }


def _print(res: dict) -> None:
    print(
        f"\n{res['set']}: {res['seconds']:.0f} s wall, verdict {res['verdict']}, base order {res['base_order']}, "
        f"material {res['material_effects'] or '-'}, measurement {res['measurement_effects'] or '-'}, "
        f"remainder {res['remainder_noise_ratio']:.3g} x the noise"
    )
    print(f"{'record':34s} {'base':>7s} {'extended':>9s} {'held out':>9s} {'classical':>10s}  ok")
    for r in res["records"]:
        held = "-" if r["held_out"] is None else f"{100 * r['held_out']:.2f}%"
        print(
            f"{r['record']:34s} {100 * r['base']:6.2f}% {100 * r['extended']:8.2f}% {held:>9s} "
            f"{100 * r['best_classical']:9.2f}%  {'yes' if r['at_or_below_classical'] else 'NO'} "
            f"({r['classical_model']})"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=[*SETS, "all"], default="piezo")
    ap.add_argument("--json", type=Path, help="also write the results as JSON")
    args = ap.parse_args()
    results = [r for r in (run_set(n) for n in (SETS if args.set == "all" else [args.set])) if r is not None]
    for res in results:
        _print(res)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
