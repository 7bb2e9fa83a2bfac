"""Fitting the measured recordings of ``../shared/data``, and the speed of a 1e5-sample fit.

    python bench/real_data.py            # prints the tables
    python bench/real_data.py --json     # the same figures as JSON
    python bench/real_data.py --report DIR   # also writes HTML fit reports (piezo, friction)

Piezo (``piezo-pnzt/slow_T06/T01/T02``: 1400 V triangles at 1, 0.1, 0.01 Hz;
voltage_V -> polarization_uC_per_cm2):

(a) one rate-independent model per rate (`fit_recordings(kind="ri")` on that rate);
(b) one rate-dependent model fitted on all three rates (`kind="rd"`), beside the
    best single rate-independent model fitted on all three (`kind="ri"`);
(c) a rate-dependent model fitted on two rates, predicting the third (all three
    hold-outs).

Beside the classical models (``piezo.best``, ``piezo.baselines``,
``friction.baselines``; `fitter.baselines`): every model scored the same way,
RMS error / output range over all samples with its initial state fitted per
recording (what `duhem validate --x0 fitted` gives for the exported FMU; from the stored x0, fitted to the
first recording, in ``fit_stored_x0``).  ``piezo.best`` is the single model for all three rates that `duhem fit`
(``--kind auto``), `duhem diagnose --separate` (the fit as its base) or
`duhem fit --effects switching,measurement_drift --hold measurement_drift.rate=0` (the physics a user names for a
ferroelectric and what they know of the instrument, `PIEZO_EFFECTS`, `PIEZO_HELD`) give, the lowest mean NRMSE of the
three, with the same structure refitted on two rates predicting the third (``holdout``; the predicted record's initial
state fitted to it, as for every score here: the base's x0 and, with `measurement_drift`, the output's
reference d_0).

"fit" NRMSE is the fit's own (the saved model from its stored x0, all samples);
"pred" NRMSE is `FitResult.predict`: the model started from the periodic
state of the recording's first cycle, nothing fitted to that recording.
NRMSE = RMS error / output range of the recording.

Friction (``friction-pneumatic/Circle_{1..7}bar``): position_mm -> friction
force F - p A (A = pi 0.0125^2 m^2, p in Pa), first 15 rows dropped as in the
authors' notebook: one first-order rate-independent model per
pressure (a rectangular Coulomb loop is one relaxation per branch), and one
first-order rate-independent model across all seven pressures (the pressure dependence of
the friction level is then not modelled: it shows as a per-file offset and
scale error).

Timing: `fit_recordings` on one generated recording of 1e5 samples (sine, 20
periods, start-up transient, 1% output noise): rate-independent order 1 and 2
on data of a first-order rate-independent model, rate-dependent order 1 on data
of a first-order rate-dependent model.

The data are read at run time from ``<repo>/../shared/data`` (no licence for the
piezo set: never copied into the repository); each part is skipped with a
message when its folder is absent.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

import numpy as np

from fitter.baselines import compare_baselines, duhem_nrmse
from fitter.diagnosis import diagnose
from fitter.core import RateDependentModel, RateIndependentModel, TabulatedRate, simulate
from fitter.core.models import Signal
from fitter.identification.exported import score
from fitter.identification.fit import fit_recordings
from fitter.data.metrics import compare
from fitter.data.recordings import Recording

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
PIEZO = {
    "1 Hz": "slow_T06_triangle_1400V_1Hz",
    "0.1 Hz": "slow_T01_triangle_1400V_0.1Hz",
    "0.01 Hz": "slow_T02_triangle_1400V_0.01Hz",
}
AREA = np.pi * 0.0125**2
PIEZO_EFFECTS = ("switching", "measurement_drift")
"""What a user fitting a ferroelectric names (`duhem fit --effects switching,measurement_drift`): its domains
switch over in time beyond a coercive voltage (`duhem diagnose` ranks switching first on the three triangles
but, with about a dozen effective samples in three single loops, cannot call it significant), and P is a
charge integrated by the instrument, whose reference is its own in each record (the data README: aixPlorer
centres each triangle; only differences of P are physical)."""
PIEZO_HELD = {"measurement_drift.rate": 0.0}
"""What the user knows of the instrument (`duhem fit --hold`): the triangles have no holds, so an offset
current cannot be told from real non-closure (the data README); each record keeps its reference, no drift."""


def _columns(path: Path, names: list[str]) -> list[np.ndarray]:
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return [np.array([float(r[n]) for r in rows]) for n in names]


def piezo_recordings(data: Path | None = None) -> dict[str, Recording]:
    """The three 1400 V triangles, read from `data` (default `DATA`)."""
    out = {}
    for label, stem in PIEZO.items():
        t, u, y = _columns(
            (data or DATA) / "piezo-pnzt" / f"{stem}.csv", ["time_s", "voltage_V", "polarization_uC_per_cm2"]
        )
        out[label] = Recording(
            t, u, y, name=label, input=Signal("voltage", "V"), output=Signal("polarization", "uC/cm2"), source=stem
        )
    return out


def friction_recordings() -> dict[str, Recording]:
    out = {}
    for bar in range(1, 8):
        path = DATA / "friction-pneumatic" / f"Circle_{bar}bar.csv"
        t, x, p, f = (a[15:] for a in _columns(path, ["time_s", "position_mm", "pressure_bar", "force_N"]))
        out[f"{bar} bar"] = Recording(
            t,
            x,
            f - p * 1e5 * AREA,
            name=f"{bar} bar",
            input=Signal("position", "mm"),
            output=Signal("friction_force", "N"),
            source=path.name,
        )
    return out


def stack() -> dict[str, str]:
    """Versions of the numerical stack: the fits' local minima depend on rounding, so the figures are
    stated with the versions that printed them (the piezo one-for-all fit moved between two stacks
    before its rate-dependent starts were each refined in full)."""
    import platform

    import scipy

    return {"python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__}


def excursion_text(value: float | None) -> str:
    """A fit summary's ``minor_loops.excursion`` in output ranges, as the benches print it (None: the output
    overflowed)."""
    return "overflow" if value is None else f"{value:.3g}"


def _log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def _pred(result, rec: Recording) -> float:
    y = result.predict(rec)
    ok = np.isfinite(y)
    first = int(np.argmax(ok))
    return compare(rec.slice(slice(first, None)), y[first:])["nrmse"]


def _fit_nrmse(result) -> list[float]:
    return [r["nrmse"] for r in result.summary["recordings"]]


def _model_tag(result) -> str:
    s = result.summary
    return f"{s['kind']}{s['order']}"


def piezo_part(report: Path | None) -> dict:
    recs = piezo_recordings()
    labels = list(recs)
    out = {"per_rate_ri": {}, "joint_ri": {}, "joint_rd": {}, "holdout_rd": {}}
    for lab in labels:
        _log(f"piezo: rate-independent fit on {lab}")
        r = fit_recordings([recs[lab]], kind="ri")
        out["per_rate_ri"][lab] = {"model": _model_tag(r), "fit": _fit_nrmse(r)[0], "pred": _pred(r, recs[lab])}
    for key, kind in (("joint_ri", "ri"), ("joint_rd", "rd")):
        _log(f"piezo: {kind} fit on all three rates")
        t0 = time.perf_counter()
        r = fit_recordings([recs[k] for k in labels], kind=kind)
        out[key] = {
            "model": _model_tag(r),
            "seconds": time.perf_counter() - t0,
            "fit": dict(zip(labels, _fit_nrmse(r))),
            "pred": {k: _pred(r, recs[k]) for k in labels},
            "convergence": r.summary["convergence"],
        }
        if report is not None:
            from fitter.reports.fit_report import write_fit_report

            write_fit_report(r, [recs[k] for k in labels], report / f"piezo_{kind}")
    for held in labels:
        _log(f"piezo: rd fit without {held}")
        train = [recs[k] for k in labels if k != held]
        r = fit_recordings(train, kind="rd")
        out["holdout_rd"][held] = {
            "model": _model_tag(r),
            "pred": _pred(r, recs[held]),
            "fit_on": [k for k in labels if k != held],
        }
    out["rd_beats_ri_on_each_rate"] = all(out["joint_rd"]["fit"][k] < out["joint_ri"]["fit"][k] for k in labels)
    out["best"] = _best(recs, labels)
    _log("piezo: classical baselines")
    out["baselines"] = _baselines(recs)
    return out


def _baselines(recs: dict[str, Recording]) -> dict:
    """Each classical model per recording and one for all (`fitter.baselines.compare_baselines`)."""
    res = compare_baselines(list(recs.values()))
    return {
        name: {
            "per_recording": dict(zip(recs, b["per_recording"].values())),
            "one_for_all": dict(zip(recs, b["one_for_all"].values())),
        }
        for name, b in res.items()
    }


def _scores(model, recs: dict[str, Recording], labels: list[str]) -> dict[str, float]:
    """NRMSE with x0 fitted per recording: what `duhem validate --x0 fitted` gives for the exported FMU."""
    return {k: duhem_nrmse(model, recs[k]) for k in labels}


def _stored_scores(model, recs: dict[str, Recording], labels: list[str]) -> dict[str, float]:
    """NRMSE from the model's stored x0 (fitted to the first recording): what `duhem validate` gives
    (`exported.score`)."""
    return {k: m["nrmse"] for k, m in zip(labels, score(model, [recs[k] for k in labels]))}


def _diagnosed(model, recs: list[Recording], **options):
    """`duhem diagnose --separate` of the recordings (separate files, each from its own start, scored as the
    fit scores them) with `model` as the base: (its extended model, the diagnosis)."""
    d = diagnose(recs, model=model, separate=True, **options)
    return d.extended_model, d


def _best(recs: dict[str, Recording], labels: list[str]) -> dict:
    """The best single Duhem model (one parameter set) for all rates, scored as the baselines are (x0 fitted per
    recording, all samples): of `duhem fit` (``--kind auto``), `duhem diagnose` with that fit as its base (its
    base refined on the records, with the effects it found) and `duhem fit --effects` (`PIEZO_EFFECTS`,
    `PIEZO_HELD`), the lowest mean NRMSE.  ``candidates`` lists all three.  The held-out rates: the same pipeline
    on two rates (the fit of the same kind and order, with the same effects named and held; when the diagnosis' model
    was picked, the diagnosis restricted to its effects), predicting the third."""
    _log("piezo: best single model: duhem fit on all three rates")
    t0 = time.perf_counter()
    r = fit_recordings([recs[k] for k in labels])
    fitted = _scores(r.model, recs, labels)
    _log("piezo: best single model: duhem diagnose with that fit as its base")
    ext, d = _diagnosed(r.model, [recs[k] for k in labels])
    diagnosed = _scores(ext, recs, labels)
    _log(f"piezo: best single model: duhem fit --effects {','.join(PIEZO_EFFECTS)} --hold {PIEZO_HELD}")
    e = fit_recordings([recs[k] for k in labels], effects=PIEZO_EFFECTS, held=PIEZO_HELD)
    cands = {
        "fit": {
            "model": _model_tag(r),
            "effects": [],
            "fit": fitted,
            "fit_stored_x0": _stored_scores(r.model, recs, labels),
        },
        "fit+diagnose": {
            "model": _model_tag(r),
            "effects": [e.effect for e in ext.effects],
            "verdict": d.verdict,
            "fit": diagnosed,
            "fit_stored_x0": _stored_scores(ext, recs, labels),
        },
        "fit --effects": {
            "model": _model_tag(e),
            "effects": list(PIEZO_EFFECTS),
            "held": PIEZO_HELD,
            "fit": _scores(e.model, recs, labels),
            "fit_stored_x0": _stored_scores(e.model, recs, labels),
        },
    }
    pick = min(cands, key=lambda c: np.mean(list(cands[c]["fit"].values())))
    out = dict(cands[pick], source=pick, seconds=time.perf_counter() - t0, candidates=cands, holdout={})
    for held in labels:
        _log(f"piezo: best structure without {held}")
        train = [recs[k] for k in labels if k != held]
        chosen = e.model if pick == "fit --effects" else r.model
        named = pick == "fit --effects"
        h = fit_recordings(
            train,
            kind=chosen.kind,
            order=chosen.order,
            effects=PIEZO_EFFECTS if named else (),
            held=PIEZO_HELD if named else None,
        ).model
        if pick == "fit+diagnose":
            h, _ = _diagnosed(h, train, candidates=out["effects"], alpha=1.0, max_findings=len(out["effects"]))
        out["holdout"][held] = duhem_nrmse(h, recs[held])
    return out


def friction_part(report: Path | None) -> dict:
    recs = friction_recordings()
    out = {"per_pressure_ri": {}, "joint_ri": {}}
    for lab, rec in recs.items():
        _log(f"friction: rate-independent fit at {lab}")
        r = fit_recordings([rec], kind="ri", order=1)
        out["per_pressure_ri"][lab] = {"model": _model_tag(r), "fit": _fit_nrmse(r)[0], "pred": _pred(r, rec)}
    _log("friction: one rate-independent model across pressures")
    t0 = time.perf_counter()
    r = fit_recordings(list(recs.values()), kind="ri", order=1)
    out["joint_ri"] = {
        "model": _model_tag(r),
        "seconds": time.perf_counter() - t0,
        "fit": dict(zip(recs, _fit_nrmse(r))),
        "pred": {k: _pred(r, v) for k, v in recs.items()},
    }
    out["per_pressure_auto"] = {}
    for lab, rec in recs.items():
        _log(f"friction: duhem fit (auto order) at {lab}")
        a = fit_recordings([rec])
        out["per_pressure_auto"][lab] = {"model": _model_tag(a), "fit": duhem_nrmse(a.model, rec)}
    _log("friction: classical baselines")
    out["baselines"] = _baselines(recs)
    if report is not None:
        from fitter.reports.fit_report import write_fit_report

        write_fit_report(r, list(recs.values()), report / "friction_joint_ri")
    return out


def _generated(model, n: int = 100_000) -> Recording:
    t = np.linspace(0, 20 * 2 * np.pi, n)
    u = 1 + 2 * np.sin(t)
    y = simulate(model, t, u).y
    y = y + 0.01 * np.ptp(y) * np.random.default_rng(0).standard_normal(len(y))
    return Recording(t, u, y, name="generated 1e5")


def timing_part() -> dict:
    ri = RateIndependentModel(
        A_plus=[[-3.0]],
        A_minus=[[2.0]],
        B_plus=[3.0],
        B_minus=[2.0],
        C=[4.0],
        E_plus=[1.0],
        E_minus=[-1.0],
        D=0.5,
        x0=[2.0],
    )
    v = np.logspace(-3, 3, 121)
    g = v / (1 + v / 2)
    rd = RateDependentModel(
        A=[[-1.0]], B=[1.0], C=[3.0], E=[0.2], D=0.3, x0=[1.5], g=TabulatedRate(np.r_[-v[::-1], v], np.r_[g[::-1], g])
    )
    out = {}
    for kind, order, true in (("ri", 1, ri), ("ri", 2, ri), ("rd", 1, rd)):
        rec = _generated(true)
        _log(f"timing: {kind}{order} on 1e5 samples")
        t0 = time.perf_counter()
        r = fit_recordings([rec], kind=kind, order=order)
        out[f"{kind}{order}"] = {
            "seconds": time.perf_counter() - t0,
            "nrmse": _fit_nrmse(r)[0],
            "true_model": true.kind,
        }
    return out


def _print(res: dict) -> None:
    p = res.get("piezo")
    if p is None:
        print("piezo: skipped (../shared/data/piezo-pnzt is absent)")
    else:
        labels = list(PIEZO)
        print("Piezo 1400 V triangles, voltage -> polarization: NRMSE per recording (fit / pred)")
        print(f"{'model':42s}" + "".join(f"{lab:>18s}" for lab in labels))
        row = "".join(f"{p['per_rate_ri'][k]['fit']:8.2%} /{p['per_rate_ri'][k]['pred']:7.2%}  " for k in labels)
        print(f"{'(a) RI per rate (' + ','.join(p['per_rate_ri'][k]['model'] for k in labels) + ')':42s}{row}")
        for key, name in (("joint_ri", "RI joint on all three"), ("joint_rd", "(b) RD joint on all three")):
            d = p[key]
            row = "".join(f"{d['fit'][k]:8.2%} /{d['pred'][k]:7.2%}  " for k in labels)
            tag = f"{name} ({d['model']}, {d['seconds']:.0f} s)"
            print(f"{tag:42s}{row}")
        row = "".join(f"{'':9s} {p['holdout_rd'][k]['pred']:7.2%}  " for k in labels)
        models = ",".join(p["holdout_rd"][k]["model"] for k in labels)
        print(f"{'(c) RD on the other two, predicting (' + models + ')':42s}{row}")
        print(
            f"RD joint below RI joint on each rate (fit NRMSE): {p['rd_beats_ri_on_each_rate']}; "
            f"RD convergence: {p['joint_rd']['convergence']['satisfied']} "
            f"(max Re eig A = {p['joint_rd']['convergence']['value']:.3g}); RI condition (5) rho = "
            f"{p['joint_ri']['convergence']['value']:.3g}"
        )
    f = res.get("friction")
    if f is None:
        print("friction: skipped (../shared/data/friction-pneumatic is absent)")
    else:
        print("\nFriction (Circle bore), position -> F - pA: NRMSE per recording (fit / pred)")
        print(f"{'pressure':10s}{'RI per pressure':>26s}{'one RI across pressures':>30s}")
        for k in f["per_pressure_ri"]:
            a, j = f["per_pressure_ri"][k], f["joint_ri"]
            print(
                f"{k:10s}{a['model']:>6s} {a['fit']:8.2%} /{a['pred']:7.2%}   "
                f"{j['model']:>8s} {j['fit'][k]:8.2%} /{j['pred'][k]:7.2%}"
            )
    _print_baselines(res)
    print("\nFit of one generated 1e5-sample recording (sine, transient, 1% noise):")
    for k, v in res["timing"].items():
        print(
            f"  {k} fit on data from a true {v['true_model']}1 model: {v['seconds']:.2f} s "
            f"(target < 10 s), NRMSE {v['nrmse']:.2%}"
        )


def _print_baselines(res: dict) -> None:
    """Side by side: the Duhem fit and each classical model, NRMSE with x0 fitted per recording."""
    p, f = res.get("piezo"), res.get("friction")
    if p is not None:
        b = p["best"]
        print("\nPiezo beside the classical models (NRMSE, all samples, initial state fitted per recording)")
        print(f"{'model':44s}" + "".join(f"{k:>10s}" for k in b["fit"]))
        for src, c in b["candidates"].items():
            label = f"Duhem, one {c['model']}{'+' + '+'.join(c['effects']) if c['effects'] else ''} ({src})"
            print(f"{label:44s}" + "".join(f"{v:10.2%}" for v in c["fit"].values()))
            print(
                f"{'  from the stored x0 (duhem validate)':44s}"
                + "".join(f"{v:10.2%}" for v in c["fit_stored_x0"].values())
            )
        print(f"  best: {b['source']} ({b['seconds']:.0f} s)")
        print(
            f"{'  same structure, rate held out (prediction)':44s}"
            + "".join(f"{v:10.2%}" for v in b["holdout"].values())
        )
        for name, v in p["baselines"].items():
            print(f"{name + ', one per record':44s}" + "".join(f"{x:10.2%}" for x in v["per_recording"].values()))
            print(f"{name + ', one for all three':44s}" + "".join(f"{x:10.2%}" for x in v["one_for_all"].values()))
    if f is not None:
        print("\nFriction beside the classical models (one model per pressure, NRMSE as above)")
        labels = list(f["per_pressure_auto"])
        print(f"{'model':30s}" + "".join(f"{k:>9s}" for k in labels))
        print(f"{'Duhem (duhem fit, auto)':30s}" + "".join(f"{f['per_pressure_auto'][k]['fit']:9.2%}" for k in labels))
        for name, v in f["baselines"].items():
            print(f"{name:30s}" + "".join(f"{v['per_recording'][k]:9.2%}" for k in labels))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print JSON instead of tables")
    ap.add_argument("--report", type=Path, default=None, help="write HTML fit reports into this folder")
    args = ap.parse_args()
    t0 = time.perf_counter()
    res = {
        "piezo": piezo_part(args.report) if (DATA / "piezo-pnzt").is_dir() else None,
        "friction": friction_part(args.report) if (DATA / "friction-pneumatic").is_dir() else None,
        "timing": timing_part(),
    }
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
