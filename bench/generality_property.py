"""Property-based generality of `duhem fit` and `duhem diagnose` on random stable devices.

    python bench/generality_property.py                      # 40 draws from seed 0, 1e2-1e6 samples per file
    python bench/generality_property.py --draws 200 --seed 1000
    python bench/generality_property.py --max-samples 5000 --no-diagnose --json out/generality.json
    python bench/generality_property.py --only ri --draws 20  # rate-independent draws only
    python bench/generality_property.py --offsets calibrated --draws 6 --max-samples 1500  # a gain per file

Draw k is `tests/generality_draws.spec_from_seed(seed + k)`: a random stable device (rate-independent or
rate-dependent, order 1-4), a random input (turning points, sine, multisine, triangle train, steps with holds),
1-3 files of 1e2-1e6 samples (log-uniform; `--min-samples`, `--max-samples`), noise 0 or 0.1-1 % of the output
range, one output offset for all files, one per file, or one offset and one gain per file (`--offsets` runs only the
draws of one of these; the generators and the properties are described in
tests/generality_draws.py; tests/test_generality.py runs a fixed set of them in the test suite).  Per draw:

* ``fit``: `fit_recordings(recs)`, "ok" or the exception (type: message, and the innermost frame in `fitter`);
* ``ratio``: the residual RMS of every sample, from the saved model's own simulation (stored x0), over the
  bound (1.2 x the noise sigma; 1e-3 of the output range without noise): the property holds at <= 1;
* ``per file``: the ratio of each file alone (stored x0, plus the file's output reference where the fit found
  one: `FitResult.simulate`);
* ``own x0``: the same from each recording's own fitted start (the summary's ``nrmse_x0_fitted``): tells a
  model that misses the data from one whose stored start does not suit the other files;
* ``summary``: the summary's per-recording NRMSE agrees with that simulation (to 1e-6 relative);
* ``diagnosis`` (rate-independent draws: the base class of `duhem diagnose`; not with ``--no-diagnose``):
  the verdict and findings of `diagnose(recs)`; the property is "nothing_missing" without findings.

The pass rates are printed per property, and the residual's also for draws with one output offset for all files
and with one per file (each file's zero found by the fit: the summary's ``references``).  The target: the fit
never raises, the residual property on >= 95 % of the draws, the diagnosis clean on >= 95 % of the clean
draws.  Exit status 1 when a target is missed.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from generality_draws import OFFSETS, build_draw, check_diagnosis, check_fit, spec_from_seed  # noqa: E402

TARGET = 0.95


def _fmt(x, spec=".3g") -> str:
    return "-" if x is None else format(x, spec)


def _row(spec, fit, diag) -> str:
    off = {"per_file": "per-file", "calibrated": "gains"}.get(spec.offsets, "common")
    head = (
        f"{spec.seed:6d} {spec.kind}{spec.order} {spec.inputs:15s} {spec.files}x{spec.samples:<8d} "
        f"{100 * spec.noise:5.2f}% {off:8s}"
    )
    if fit.raised:
        body = f"RAISED {fit.error[:200]} [{fit.where}]"
    else:
        body = (
            f"{fit.chosen:4s} ratio {_fmt(fit.ratio, '8.3f')} {'ok  ' if fit.within_bound else 'FAIL'} "
            f"own x0 {_fmt(fit.own_x0_ratio, '8.3f')} summary {'ok' if fit.summary_agrees else 'DIFFERS'}"
        )
        if fit.per_file_ratio and len(fit.per_file_ratio) > 1:
            body += " per file " + "/".join(f"{r:.3g}" for r in fit.per_file_ratio)
    body += f" {fit.seconds:6.1f} s"
    if diag is not None:
        if diag.error:
            body += f" | diagnosis RAISED {diag.error[:160]} [{diag.where}]"
        else:
            names = ",".join(f["effect"] for f in diag.findings) or "-"
            body += (
                f" | {diag.verdict} [{names}] base {diag.base} base/noise {_fmt(diag.base_noise_ratio, '.2f')} "
                f"{diag.seconds:5.1f} s"
            )
    return f"{head} {body}"


def _rate(rows, pick, ok) -> str:
    sel = [r for r in rows if pick(r)]
    if not sel:
        return "0/0"
    good = sum(bool(ok(r)) for r in sel)
    return f"{good}/{len(sel)} ({100 * good / len(sel):.0f} %)"


def _share(rows, pick, ok) -> float:
    sel = [r for r in rows if pick(r)]
    return sum(bool(ok(r)) for r in sel) / len(sel) if sel else 1.0


def _common(r) -> bool:
    return r[0].offsets == "common"


def _fitted(r) -> bool:
    return not r[1].raised


def _diagnosed(r) -> bool:
    return r[2] is not None


_RATES = (
    ("fit never raises:", lambda r: True, _fitted),
    ("residual <= bound:", lambda r: True, lambda r: r[1].within_bound),
    ("  with noise:", lambda r: r[0].noise > 0, lambda r: r[1].within_bound),
    ("  noise-free:", lambda r: r[0].noise == 0, lambda r: r[1].within_bound),
    ("  one offset for all files:", _common, lambda r: r[1].within_bound),
    ("  an offset per file:", lambda r: r[0].offsets == "per_file", lambda r: r[1].within_bound),
    ("  a gain and an offset per file:", lambda r: r[0].offsets == "calibrated", lambda r: r[1].within_bound),
    ("  from each file's own x0 (not the property):", lambda r: True, lambda r: (r[1].own_x0_ratio or 2.0) <= 1),
    ("summary NRMSE = the simulation's:", _fitted, lambda r: r[1].summary_agrees),
    ("diagnosis nothing_missing, clean draws:", _diagnosed, lambda r: r[2].clean),
    ("  with noise:", lambda r: _diagnosed(r) and r[0].noise > 0, lambda r: r[2].clean),
    ("  noise-free:", lambda r: _diagnosed(r) and r[0].noise == 0, lambda r: r[2].clean),
)
"""(what, which draws, the property): the pass rates printed."""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=40, help="number of draws (default 40)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the first draw (draw k has seed + k)")
    ap.add_argument("--min-samples", type=int, default=100, help="fewest samples per file (default 100)")
    ap.add_argument("--max-samples", type=int, default=1_000_000, help="most samples per file (default 1e6)")
    ap.add_argument("--only", choices=("ri", "rd"), default=None, help="only draws of this kind")
    ap.add_argument("--offsets", choices=OFFSETS, default=None, help="only draws of these output offsets (and gains)")
    ap.add_argument("--no-diagnose", action="store_true", help="skip the diagnosis property")
    ap.add_argument("--json", type=str, default=None, help="write every draw's outcome to this file")
    args = ap.parse_args(argv)
    os.environ.setdefault("DUHEM_WORKERS", "1")
    rows, seed, t_start = [], args.seed, time.perf_counter()
    print("  seed dev input           files x n    noise offsets  fit / residual ratio ... | diagnosis", flush=True)
    while len(rows) < args.draws:
        spec = spec_from_seed(seed, args.min_samples, args.max_samples)
        seed += 1
        if (args.only and spec.kind != args.only) or (args.offsets and spec.offsets != args.offsets):
            continue
        draw = build_draw(spec)
        fit = check_fit(draw)
        diag = check_diagnosis(draw) if spec.kind == "ri" and not args.no_diagnose else None
        rows.append((spec, fit, diag))
        print(_row(spec, fit, diag), flush=True)
    print(f"\n{len(rows)} draws in {time.perf_counter() - t_start:.0f} s")
    for text, pick, ok in _RATES:
        if any(pick(r) for r in rows):
            print(f"{text:42s} {_rate(rows, pick, ok)}")
    if args.json:
        out = [
            {"spec": vars(s), "fit": f.to_dict(), "diagnosis": None if d is None else d.to_dict()} for s, f, d in rows
        ]
        Path(args.json).write_text(json.dumps(out, indent=1, default=float), encoding="utf-8")
    targets = [
        all(_fitted(r) for r in rows),
        _share(rows, lambda r: True, lambda r: r[1].within_bound) >= TARGET,
        _share(rows, _diagnosed, lambda r: r[2].clean) >= TARGET,
    ]
    return 0 if all(targets) else 1


if __name__ == "__main__":
    sys.exit(main())
