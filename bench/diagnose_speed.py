"""Benchmark `duhem diagnose`: wall time of one 7-recording x 3000-sample experiment, and the sweep.

    python bench/diagnose_speed.py                 # timing (target: under 2 minutes)
    python bench/diagnose_speed.py --sweep 5       # success rates over 7 effects x 5 seeds + 5 clean

The experiments come from `fitter.diagnose.synthetic_experiment` (the project's
own simulator; effect max 2% of the output range, noise 1/15 of that).  The
sweep counts: the right effect first, "nothing missing" on clean data, and the
extended model's residual RMS within 20% of the true noise when right.
"""
from __future__ import annotations

import argparse
import time

from fitter.core.effects import EFFECTS
from fitter.diagnose import diagnose, rich_progress, synthetic_experiment

RUNS7 = ((50.0, 1.0), (20.0, 1.0), (10.0, 1.0), (5.0, 1.0), (2.0, 1.0), (10.0, 0.6), (50.0, 1.0))


def timing(effect: str) -> None:
    recordings, truth = synthetic_experiment(effect, seed=1, samples=3000, runs=RUNS7)
    n = sum(len(r.t) for r in recordings)
    t0 = time.perf_counter()
    with rich_progress(f"diagnosing {len(recordings)} recordings") as progress:
        d = diagnose(recordings, progress=progress)
    elapsed = time.perf_counter() - t0
    print(f"diagnose: {len(recordings)} recordings, {n} samples, concealed {effect}: {elapsed:.1f} s "
          f"(target < 120 s); findings {[f['effect'] for f in d.findings]}; residual RMS "
          f"{d.baseline['residual_rms']:.4g} -> {d.extended['residual_rms']:.4g} (true noise {truth['noise_rms']:.4g})")


def sweep(seeds: int, samples: int) -> None:
    right = total = clean_ok = clean = near_noise = 0
    for effect in list(EFFECTS) + [None]:
        for seed in range(seeds):
            recordings, truth = synthetic_experiment(effect, seed=100 + seed, samples=samples)
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
    print(f"right effect first: {right}/{total} ({100 * right / total:.0f}%); nothing missing on clean: "
          f"{clean_ok}/{clean} ({100 * clean_ok / clean:.0f}%); extended residual within 20% of the noise when "
          f"right: {near_noise}/{right}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effect", default="rate_dependence", choices=list(EFFECTS))
    ap.add_argument("--sweep", type=int, default=0, help="seeds per effect for the success-rate sweep")
    ap.add_argument("--samples", type=int, default=1000, help="samples per recording in the sweep")
    args = ap.parse_args()
    if args.sweep:
        sweep(args.sweep, args.samples)
    else:
        timing(args.effect)


if __name__ == "__main__":
    main()
