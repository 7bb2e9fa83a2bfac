"""Benchmark `duhem diagnose`: wall time of one 7-recording x 3000-sample experiment, and the sweep.

    python bench/diagnose_speed.py                 # timing (target: under 2 minutes)
    python bench/diagnose_speed.py --sweep 5       # success rates over 7 effects x 5 seeds + 5 clean
    python bench/diagnose_speed.py --piezo DIR     # diagnose the measured piezo data, reports in DIR
    python bench/diagnose_speed.py --piezo DIR --base-order 1   # ... with a fixed base order (default auto)

The experiments come from `fitter.diagnosis.synthetic_experiment` (the project's
own simulator; timing: effect max 2% of the output range, noise 1/15 of that;
sweep: per seed a different base loop, effect size 1.5-2.5% of the range and
noise 1/10-1/20 of it, `_varied`).  The
sweep counts: the right effect first, "nothing missing" on clean data, and the
extended model's residual RMS within 20% of the true noise when right.

``--piezo`` reads ``<repo>/../shared/data/piezo-pnzt`` at run time (skipped when
absent; the data are not redistributable) and diagnoses two experiments,
voltage -> polarization, as measured (the output is not corrected):
(a) the 1400 V triangles at 0.1, 0.01 and 1 Hz (slow_T01, T02, T06);
(b) the trapezoid runs creep_T01-T03, whose polarization carries the offset
current of the shared data's README (a drift of about -0.3 uC/cm2/s): the
diagnosis is to find it as a measurement drift.  The voltage inside each hold
(`fitter.data.preparation.find_holds`) is set to the hold's median: the
+-0.2 V measurement noise of a held voltage would otherwise reverse the
rate-independent model's branch at almost every sample (slow, and not
physics).  aixPlorer re-references P in every table and the sample rests at
0 V between tables, so the files are joined back to back on one clock (each
file's time runs on from the previous one's last sample by one sample
period) and each file's P is shifted to start where the previous one ended
(only differences of P are physical).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from fitter.core.effects import REGISTRY
from fitter.diagnosis import chain_recordings, diagnose, rich_progress, synthetic_experiment
from fitter.reports.diagnosis_report import write_diagnosis_report
from fitter.data.preparation import find_holds
from fitter.data.recordings import Recording, load_recording

PIEZO = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "piezo-pnzt"
TRIANGLES = (
    "slow_T01_triangle_1400V_0.1Hz.csv",
    "slow_T02_triangle_1400V_0.01Hz.csv",
    "slow_T06_triangle_1400V_1Hz.csv",
)
TRAPEZOIDS = (
    "creep_T01_trapezoid_1400V_1000V_60S.csv",
    "creep_T02_trapezoid_1400V_1000V_60S.csv",
    "creep_T03_trapezoid_1400V_1200V_105S.csv",
)

RUNS7 = ((50.0, 1.0), (20.0, 1.0), (10.0, 1.0), (5.0, 1.0), (2.0, 1.0), (10.0, 0.6), (50.0, 1.0))


def timing(effect: str) -> None:
    recordings, truth = synthetic_experiment(effect, seed=1, samples=3000, runs=RUNS7)
    n = sum(len(r.t) for r in recordings)
    t0 = time.perf_counter()
    with rich_progress(f"diagnosing {len(recordings)} recordings") as progress:
        d = diagnose(recordings, progress=progress)
    elapsed = time.perf_counter() - t0
    print(
        f"diagnose: {len(recordings)} recordings, {n} samples, concealed {effect}: {elapsed:.1f} s "
        f"(target < 120 s); findings {[f['effect'] for f in d.findings]}; residual RMS "
        f"{d.baseline['residual_rms']:.4g} -> {d.extended['residual_rms']:.4g} (true noise {truth['noise_rms']:.4g})"
    )


def _varied(seed: int) -> dict:
    """Per-seed variety: base loop shape, noise (effect 10-20 x noise), effect size 1.5-2.5% of the range."""
    rng = np.random.default_rng(seed)
    a, e = rng.uniform(2.0, 6.0), rng.uniform(0.3, 0.7)
    base = dict(a_plus=-a, a_minus=a, b_plus=a, b_minus=-a, e_plus=-a * e, e_minus=-a * e, x0=0.0)
    return {"base": base, "snr": rng.uniform(10.0, 20.0), "size": rng.uniform(0.015, 0.025)}


def sweep(seeds: int, samples: int) -> None:
    right = total = clean_ok = clean = near_noise = 0
    for effect in list(REGISTRY) + [None]:
        for seed in range(seeds):
            recordings, truth = synthetic_experiment(effect, seed=100 + seed, samples=samples, **_varied(seed))
            d = diagnose(recordings)
            found = [f["effect"] for f in d.findings]
            ratio = d.extended["residual_rms"] / truth["noise_rms"]
            if effect is None:
                clean += 1
                clean_ok += not found
            else:
                total += 1
                ok = bool(found) and found[0] == effect
                right += ok
                near_noise += ok and ratio <= 1.2
            print(f"  {effect or 'clean':16s} seed {seed}: found {found}, extended/noise {ratio:.3f}", flush=True)
    print(
        f"right effect first: {right}/{total} ({100 * right / total:.0f}%); nothing missing on clean: "
        f"{clean_ok}/{clean} ({100 * clean_ok / clean:.0f}%); extended residual within 20% of the noise when "
        f"right: {near_noise}/{right}"
    )


def piezo_experiment(files, clean_holds: bool) -> list[Recording]:
    """The piezo files as one experiment (see the module docstring; `chain_recordings`)."""
    recs = []
    for f in files:
        rec = load_recording(PIEZO / f, time="time_s", input="voltage_V", output="polarization_uC_per_cm2")
        u = rec.u.copy()
        if clean_holds:
            for a, b in find_holds(rec.t, u):
                u[a:b] = np.median(u[a:b])
        recs.append(
            Recording(
                rec.t,
                u,
                rec.y,
                name=Path(f).stem.split("_")[1] + "_" + "_".join(Path(f).stem.split("_")[2:4]),
                input=rec.input,
                output=rec.output,
                source=str(PIEZO / f),
            )
        )
    return chain_recordings(recs, relative_output=True)


def piezo(out: Path, base_order: int | None) -> None:
    if not PIEZO.exists():
        print(f"skipped: {PIEZO} is absent")
        return
    for label, files, holds in (("triangles", TRIANGLES, False), ("trapezoids", TRAPEZOIDS, True)):
        recordings = piezo_experiment(files, holds)
        t0 = time.perf_counter()
        with rich_progress(f"piezo {label}") as progress:
            d = diagnose(recordings, progress=progress, base_order=base_order)
        write_diagnosis_report(d, recordings, out / label)
        print(f"\n== piezo {label} ({time.perf_counter() - t0:.1f} s): {', '.join(r.name for r in recordings)}")
        print(f"verdict: {d.verdict}; findings: {[f['effect'] for f in d.findings]}")
        print(d.paragraph)
        for c in d.candidates:
            print(
                f"  {c['rank']}. {c['effect']:16s} residual {c['residual_rms']:.4g}  explains "
                f"{100 * c['explained_fraction']:5.1f}%  p = {c['p_value']:.2g}  n_eff = {c['n_eff']:.0f}  "
                f"{c['parameters']}"
            )
        for label, part in (("before:", d.baseline), ("after: ", d.extended)):
            percent = {k: round(100 * v, 2) for k, v in part["nrmse_per_recording"].items()}
            print(f"  NRMSE per recording {label}", percent)
        print("  hold-out:", d.validation)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effect", default="rate_dependence", choices=list(REGISTRY))
    ap.add_argument("--sweep", type=int, default=0, help="seeds per effect for the success-rate sweep")
    ap.add_argument("--samples", type=int, default=1000, help="samples per recording in the sweep")
    ap.add_argument("--piezo", type=Path, default=None, help="diagnose the piezo data; reports in this folder")
    ap.add_argument(
        "--base-order",
        default="auto",
        help="piezo: base model order ('auto': as `duhem diagnose` by default; 1-4: fixed)",
    )
    args = ap.parse_args()
    if args.piezo:
        piezo(args.piezo, None if args.base_order == "auto" else int(args.base_order))
    elif args.sweep:
        sweep(args.sweep, args.samples)
    else:
        timing(args.effect)


if __name__ == "__main__":
    main()
