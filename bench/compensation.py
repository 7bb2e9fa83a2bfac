"""Feedforward hysteresis compensation on the shared piezo triangles: the inverse Duhem model beside a
linear gain and a Prandtl-Ishlinskii inverse.

    python bench/compensation.py                  # prints the table
    python bench/compensation.py --json           # the same figures as JSON
    python bench/compensation.py --data DIR       # the shared data elsewhere (default <repo>/../shared/data)

Per record (``piezo-pnzt/slow_T06/T01/T02``: 1400 V triangles at 1, 0.1, 0.01 Hz; voltage_V ->
polarization_uC_per_cm2), as ``bench/real_data.py`` (a) fits them: a rate-independent Duhem model fitted to that
record alone (`fit_recordings(kind="ri")`, order by BIC), the same fit at orders 1-3, the BIC fit with
faithful minor loops (`faithful_minor_loops=True`: its settled small loops near the data), and that fit with the
switching effect (`FITS`: `duhem fit --faithful-minor-loops --effects switching`).  Then one model for
the three rates, as `duhem fit` gives it on the three files (`fit_recordings`, kind and order by BIC; a
rate-dependent model), as `duhem fit --effects switching` gives it (`JOINT_EFFECTS`: the material
effect of the piezo.best of ``bench/real_data.py``), and that piezo.best itself (`JOINTS`: `duhem fit --effects
switching,measurement_drift --hold measurement_drift.rate=0`, compensated with ``measurement="invert"``), each
beside one Prandtl-Ishlinskii model fitted to the three; each record's plant starts from the state fitted to
that record (`own_start`).

The plant is the fitted Duhem model, started as the record starts (its stored x0 at the record's first voltage).
The reference: that first output, then a triangle in the output between 10 % and 90 % of the measured range
(starting at its low end, two cycles of the record's period, the record's sample period).  Three inputs:

(a) compensated: `fitter.core.inverse.compensate` of the model (the exact inverse; clamped samples counted);
(b) linear gain: u = (y_ref - y0) / gain, the measured loop's output span over its input span through its middle
    (`fitter.core.inverse.linear_gain`), held within the measured input range;
(c) Prandtl-Ishlinskii inverse: `fitter.baselines.PrandtlIshlinskii(deadband=False, invertible=True)` fitted to
    the same record (24 plays, weights >= 0, linear term >= 5 % of the mean slope so that it is invertible),
    its analytic inverse (`PrandtlIshlinskii.invert`) applied to y_ref.

Every input starts at the record's first voltage (the plant's rest point).  Tracking error = RMS(y - y_ref) /
range(y_ref) over all samples after the first, for the Duhem plant, and (robustness to model error) for the
Prandtl-Ishlinskii model as the plant.  And on the record itself, where no model extrapolates: the input each
inverse gives for the measured output, against the measured input (RMS / range of the input).

The data have no licence: read at run time, never copied; the bench is skipped with a message when absent.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_data import DATA, PIEZO_EFFECTS, PIEZO_HELD, excursion_text, piezo_recordings, stack  # noqa: E402

from fitter.baselines import PrandtlIshlinskii  # noqa: E402
from fitter.core import compensate, simulate  # noqa: E402
from fitter.core.inverse import linear_gain  # noqa: E402
from fitter.data.metrics import compare  # noqa: E402
from fitter.data.recordings import Recording  # noqa: E402
from fitter.identification.exported import own_start, started  # noqa: E402
from fitter.identification.fit import fit_recordings  # noqa: E402

JOINT_EFFECTS = ("switching",)
"""The material physics named for the second one-for-all model (of `bench/real_data.py`'s ``PIEZO_EFFECTS``,
its piezo.best, the material's)."""
JOINTS = (
    ("one_for_all", (), {}, "refuse"),
    ("one_for_all_effects", JOINT_EFFECTS, {}, "refuse"),
    ("one_for_all_best", PIEZO_EFFECTS, PIEZO_HELD, "invert"),
)
"""The one-for-all models: (key, effects, held effect parameters, the compensator's ``measurement`` choice).
The last is `bench/real_data.py`'s piezo.best (ri3 + switching + measurement_drift, rate held at 0): its
measurement effect is each record's output reference, so the compensator inverts it (``measurement="invert"``:
the measured output, in the record's own zero, follows y_ref)."""
FITS = (
    (None, False, ()),
    (1, False, ()),
    (2, False, ()),
    (3, False, ()),
    (None, True, ()),
    (None, True, JOINT_EFFECTS),
)
"""Duhem fits per record, (order, faithful minor loops, effects): order None = chosen by BIC (as
bench/real_data.py), then fixed orders, then the BIC order with `fit_recordings(faithful_minor_loops=True)`,
and that with the material effect (`duhem fit --faithful-minor-loops --effects switching`: the barrier on the
base's minor loops, the switching carrying the sharp switching)."""
RULES = {(True, False): "BIC", (False, False): "fix", (True, True): "BIC+f"}
"""Short names of the fits in the table (order by BIC?, faithful?); +f: faithful minor loops (the model's name
carries its effects)."""


def _log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def reference(rec: Recording, y_start: float, cycles: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """(t, y_ref): y_start, then a triangle over 10-90 % of the measured output range from its low end."""
    lo, hi = float(rec.y.min()), float(rec.y.max())
    a, b = lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo)
    per = len(rec) - 1
    dt = float(np.median(np.diff(rec.t)))
    n = cycles * per + 1
    phase = np.arange(n) / per
    tri = a + (b - a) * (1 - np.abs((phase % 1.0) * 2 - 1))
    t = rec.t[0] + dt * np.arange(n + 1)
    return t, np.r_[y_start, tri]


def _error(y: np.ndarray, y_ref: np.ndarray) -> float:
    return float(np.sqrt(np.mean((y[1:] - y_ref[1:]) ** 2)) / np.ptp(y_ref[1:]))


def _pi_output(pi: PrandtlIshlinskii, t: np.ndarray, u: np.ndarray) -> np.ndarray:
    return pi.predict(Recording(t, u, np.full(len(t), np.nan)))


def _rows(model, rec: Recording, pi: PrandtlIshlinskii, y0: float, gain: float, measurement: str = "refuse") -> dict:
    """Tracking of the 10-90 % reference with `model` as the plant (x0 as stored: the record's start), and
    the input each inverse gives for the measured output; `measurement`: `compensate`'s choice for a model with
    measurement effects (the tracking is of `simulate`'s output, the measured one, either way here since
    "invert" is the only choice used with such a model)."""
    u0 = float(rec.u[0])
    t, y_ref = reference(rec, float(simulate(model, rec.t[:1], rec.u[:1]).y[0]))
    t1 = time.perf_counter()
    comp = compensate(model, t, y_ref, u0=u0, measurement=measurement)
    comp_seconds = time.perf_counter() - t1
    inputs = {
        "compensated": comp.u,
        "linear gain": np.r_[u0, np.clip((y_ref[1:] - y0) / gain, rec.u.min(), rec.u.max())],
        "PI inverse": np.r_[u0, pi.invert(y_ref[1:])],
    }
    duhem = {k: _error(simulate(model, t, u).y, y_ref) for k, u in inputs.items()}
    on_pi = {k: _error(_pi_output(pi, t, u), y_ref) for k, u in inputs.items()}
    # on the record itself: the input each inverse gives for the measured output, against the measured input
    back = compensate(model, rec.t, rec.y, u0=u0, measurement=measurement)
    recovered = {"compensated": back.u, "linear gain": (rec.y - y0) / gain, "PI inverse": pi.invert(rec.y)}
    on_record = {k: float(np.sqrt(np.mean((u - rec.u) ** 2)) / np.ptp(rec.u)) for k, u in recovered.items()}
    return {
        "samples": len(t),
        "clamped": comp.n_clamped,
        "max_shortfall": comp.max_shortfall,
        "compensation_seconds": comp_seconds,
        "plant_duhem": duhem,
        "plant_pi": on_pi,
        "record_input_error": on_record,
        "record_clamped": back.n_clamped,
        "record_samples": len(rec),
        "u_range": [float(comp.u.min()), float(comp.u.max())],
    }


def record_part(rec: Recording) -> dict:
    _log(f"{rec.name}: Prandtl-Ishlinskii fit")
    pi = PrandtlIshlinskii(deadband=False, invertible=True).fit(rec)
    y0, gain = linear_gain(rec.u, rec.y)
    out = {"linear_gain": {"y0": y0, "gain": gain}, "pi_nrmse": pi.score(rec)["nrmse"], "models": []}
    for order, faithful, effects in FITS:
        _log(
            f"{rec.name}: Duhem fit, order {'by BIC' if order is None else order}"
            + (", faithful minor loops" if faithful else "")
            + (f", effects {','.join(effects)}" if effects else "")
        )
        t0 = time.perf_counter()
        fit = fit_recordings([rec], kind="ri", order=order, faithful_minor_loops=faithful, effects=effects)
        out["models"].append(
            {
                "model": "+".join([f"ri{fit.model.order}", *(e.effect for e in fit.model.effects)]),
                "order_rule": RULES[order is None, faithful],
                "minor_loop_excursion": fit.summary["minor_loops"]["excursion"],
                "fit_nrmse": fit.summary["recordings"][0]["nrmse"],
                "fit_seconds": time.perf_counter() - t0,
                **_rows(fit.model, rec, pi, y0, gain),
            }
        )
    return out


def joint_part(
    recs: dict[str, Recording], effects: tuple[str, ...] = (), held: dict | None = None, measurement: str = "refuse"
) -> dict:
    """One Duhem model for the three rates (`duhem fit` on all three, kind and order by BIC, with `effects`
    and `held` as `duhem fit --effects --hold`) and one Prandtl-Ishlinskii model for the three, each record's
    plant started from the state fitted to that record (`own_start`: x0, and the effects' start with the output
    reference, as `bench/real_data.py` scores it: `duhem validate --x0 fitted`)."""
    _log(f"all rates: Duhem fit (auto{', effects ' + ','.join(effects) if effects else ''}) and Prandtl-Ishlinskii fit")
    t0 = time.perf_counter()
    fit = fit_recordings(list(recs.values()), effects=effects, held=held)
    seconds = time.perf_counter() - t0
    pi = PrandtlIshlinskii(deadband=False, invertible=True).fit(list(recs.values()))
    tag = "+".join([f"{fit.model.kind}{fit.model.order}", *(e.effect for e in fit.model.effects)])
    out = {"model": tag, "fit_seconds": seconds, "records": {}}
    for label, rec in recs.items():
        start = own_start(fit.model, rec)
        y0, gain = linear_gain(rec.u, rec.y)
        out["records"][label] = {
            "fit_nrmse": compare(rec, start[1])["nrmse"],
            "pi_nrmse": pi.score(rec)["nrmse"],
            **_rows(started(fit.model, start), rec, pi, y0, gain, measurement),
        }
    return out


def _print(res: dict) -> None:
    print("Tracking a triangle over 10-90 % of the measured output range, two periods: RMS(y - y_ref) / range")
    print("plant = the fitted Duhem model (columns 4-6) or the fitted Prandtl-Ishlinskii model (columns 7-9)\n")
    head = (
        f"{'record':8s} {'model':24s} {'clamped':>9s} | {'comp.':>9s} {'linear':>8s} {'PI inv.':>8s} | "
        f"{'comp.':>8s} {'linear':>8s} {'PI inv.':>8s}"
    )
    print(head)
    print("-" * len(head))
    for rec, part in res["records"].items():
        for m in part["models"]:
            d, p = m["plant_duhem"], m["plant_pi"]
            tag = f"{m['model']} ({m['order_rule']})"
            print(
                f"{rec:8s} {tag:24s} {m['clamped']:4d}/{m['samples']:<4d} | {d['compensated']:9.2e} "
                f"{d['linear gain']:8.1%} {d['PI inverse']:8.1%} | {p['compensated']:8.1%} "
                f"{p['linear gain']:8.1%} {p['PI inverse']:8.2e}"
            )
    print(
        "\nOn the record itself (no extrapolation): the input each inverse gives for the measured output, "
        "RMS(u - u_measured) / range(u)"
    )
    print(f"{'record':8s} {'model':24s} {'clamped':>9s} | {'comp.':>8s} {'linear':>8s} {'PI inv.':>8s}")
    for rec, part in res["records"].items():
        for m in part["models"]:
            e = m["record_input_error"]
            tag = f"{m['model']} ({m['order_rule']})"
            print(
                f"{rec:8s} {tag:24s} {m['record_clamped']:4d}/{m['record_samples']:<4d} | {e['compensated']:8.2%} "
                f"{e['linear gain']:8.2%} {e['PI inverse']:8.2%}"
            )
    for key, effects, held, _ in JOINTS:
        j = res[key]
        how = (
            "`duhem fit"
            + (f" --effects {','.join(effects)}" if effects else "")
            + "".join(f" --hold {k}={v:g}" for k, v in held.items())
            + "`"
        )
        print(
            f"\nOne model for the three rates ({j['model']} by {how}, one Prandtl-Ishlinskii model), each "
            "record's plant from the state fitted to it:"
        )
        print(
            f"{'record':8s} {'fit':>6s} {'clamped':>9s} | {'comp.':>9s} {'linear':>8s} {'PI inv.':>8s} | "
            f"{'on the record: comp.':>20s} {'linear':>8s} {'PI inv.':>8s}"
        )
        for rec, m in j["records"].items():
            d, e = m["plant_duhem"], m["record_input_error"]
            print(
                f"{rec:8s} {m['fit_nrmse']:6.2%} {m['clamped']:4d}/{m['samples']:<4d} | {d['compensated']:9.2e} "
                f"{d['linear gain']:8.1%} {d['PI inverse']:8.1%} | {e['compensated']:20.2%} "
                f"{e['linear gain']:8.2%} {e['PI inverse']:8.2%}"
            )
    print(
        "\nfit NRMSE of each Duhem model on its record [its summary's minor-loop excursion, output ranges], and "
        "of the Prandtl-Ishlinskii model:"
    )
    for rec, part in res["records"].items():
        fits = ", ".join(
            f"{m['model']} ({m['order_rule']}) {m['fit_nrmse']:.2%} [minor loops "
            f"{excursion_text(m['minor_loop_excursion'])}]"
            for m in part["models"]
        )
        print(f"  {rec}: {fits}; PI {part['pi_nrmse']:.2%}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print JSON instead of the table")
    ap.add_argument("--data", type=Path, default=DATA, help=f"the shared data folder (default {DATA})")
    args = ap.parse_args()
    if not (args.data / "piezo-pnzt").is_dir():
        print(f"compensation bench: skipped ({args.data / 'piezo-pnzt'} is absent)")
        return
    t0 = time.perf_counter()
    recs = piezo_recordings(args.data)
    res = {key: joint_part(recs, effects, held, measurement) for key, effects, held, measurement in JOINTS}
    res["records"] = {label: record_part(rec) for label, rec in recs.items()}
    res["total_seconds"] = time.perf_counter() - t0
    res["stack"] = stack()
    if args.json:
        print(json.dumps(res, indent=2, default=float))
    else:
        _print(res)
        versions = ", ".join(f"{k} {v}" for k, v in res["stack"].items())
        print(f"\ntotal run time {res['total_seconds']:.0f} s; {versions}")


if __name__ == "__main__":
    main()
