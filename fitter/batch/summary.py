"""Outliers across devices (`flag_outliers`) and the batch summary: CSV, JSON and HTML (`BatchReport`)."""

from __future__ import annotations

import csv
import html
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fitter.batch.config import MIN_GROUP, OUTLIER_Z
from fitter.core.files import atomic_file, json_text, jsonable

# --------------------------------------------------------------------------- outliers


def _robust_z(values: np.ndarray) -> np.ndarray | None:
    med = np.median(values)
    dev = np.abs(values - med)
    mad = np.median(dev)
    if mad > 0:
        return 0.6745 * (values - med) / mad
    mean_ad = np.mean(dev)
    if mean_ad > 0:
        return (values - med) / (1.2533 * mean_ad)
    return None


def flag_outliers(rows: dict[str, dict], *, z_limit: float = OUTLIER_Z, min_group: int = MIN_GROUP) -> dict:
    """``{device: [{"parameter", "value", "median", "z"}, ...]}`` for the devices outside the batch's spread.

    `rows` maps a device to its summary row (``kind``, ``order``, ``parameters``: name -> {"value", ...});
    the rule is in the module docstring.
    """
    groups: dict[tuple, list[str]] = {}
    for name, row in rows.items():
        if row and row.get("parameters"):
            groups.setdefault((row["kind"], row["order"]), []).append(name)
    flags: dict[str, list] = {}
    for members in groups.values():
        if len(members) < min_group:
            continue
        names = [k for k in rows[members[0]]["parameters"] if all(k in rows[m]["parameters"] for m in members)]
        for k in names:
            vals = np.array([rows[m]["parameters"][k]["value"] for m in members], dtype=float)
            if not np.all(np.isfinite(vals)):
                continue
            z = _robust_z(vals)
            if z is None:
                continue
            med = float(np.median(vals))
            for m, v, zi in zip(members, vals, z):
                if abs(zi) > z_limit:
                    flags.setdefault(m, []).append({"parameter": k, "value": float(v), "median": med, "z": float(zi)})
    return flags


# --------------------------------------------------------------------------- summary


@dataclass
class BatchReport:
    """What a batch did: per device its ``done.json`` row, what happened this run, the outliers."""

    outdir: Path
    devices: list[str]
    entries: dict[str, dict]  # device -> status, reason, row, hash (done.json) or a failure
    actions: dict[str, str]  # device -> "done", "skipped: current", "failed", "lost"
    outliers: dict[str, list] = field(default_factory=dict)
    dashboard: str | None = None
    seconds: float = 0.0

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for d in self.devices:
            s = self.entries[d]["status"]
            out[s] = out.get(s, 0) + 1
        return out

    def to_json(self) -> dict:
        return jsonable(
            {
                "outdir": self.outdir,
                "seconds": self.seconds,
                "dashboard": self.dashboard,
                "counts": self.counts(),
                "outlier_rule": OUTLIER_RULE,
                "devices": [
                    self.summary_row(d) | {"parameters": (self.entries[d].get("row") or {}).get("parameters", {})}
                    for d in self.devices
                ],
            }
        )

    def summary_row(self, d: str) -> dict:
        e = self.entries[d]
        row = e.get("row") or {}
        diag = row.get("diagnosis")
        flags = self.outliers.get(d, [])
        return {
            "device": d,
            "status": e["status"],
            "reason": e.get("reason", ""),
            "action": self.actions[d],
            "kind": row.get("kind"),
            "order": row.get("order"),
            "nrmse": row.get("nrmse"),
            "nrmse_recording": row.get("nrmse_recording"),
            "validated": row.get("validated"),
            "convergence": row.get("convergence"),
            "diagnosis": None if diag is None else diag["verdict"],
            "effects": None if diag is None else ";".join(diag["effects"]),
            "model_effects": ";".join(row.get("model_effects", [])),
            "outliers": ";".join(f"{f['parameter']} (z {f['z']:+.1f})" for f in flags),
        }


OUTLIER_RULE = (
    f"robust z-score 0.6745 (p - median) / MAD of each fitted parameter (canonical form, units "
    f"normalised by the device's own input and output ranges) among the devices of the same kind and "
    f"order (at least {MIN_GROUP}); flagged when |z| > {OUTLIER_Z}"
)


def _param_names(report: BatchReport) -> list[str]:
    names: list[str] = []
    for d in report.devices:
        for k in (report.entries[d].get("row") or {}).get("parameters") or {}:
            if k not in names:
                names.append(k)
    return names


def _csv_value(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.6g}"
    return str(v)


def summary_csv(report: BatchReport) -> str:
    """``summary.csv``: one row per device, the parameters and their standard errors last."""
    params = _param_names(report)
    base = [c for c in report.summary_row(report.devices[0]) if c != "action"]  # what this run did: not kept
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(base + [c for k in params for c in (k, f"{k} stderr")])
    for d in report.devices:
        r = report.summary_row(d)
        p = (report.entries[d].get("row") or {}).get("parameters") or {}
        pairs = [(p[k]["value"], p[k]["stderr"]) if k in p else (None, None) for k in params]
        w.writerow([_csv_value(r[c]) for c in base] + [_csv_value(x) for pair in pairs for x in pair])
    return buf.getvalue()


def _h(v) -> str:
    return html.escape(_csv_value(v))


def summary_html(report: BatchReport) -> str:
    """``index.html``: the summary table with links to each device's report, the outliers marked."""
    params = _param_names(report)
    head = (
        "<tr><th>device</th><th>status</th><th>kind</th><th>order</th><th>NRMSE (worst)</th>"
        "<th>validated</th><th>diagnosis</th><th>effects found</th><th>outliers</th>"
        + "".join(f"<th>{html.escape(k)}</th>" for k in params)
        + "<th>reason</th></tr>"
    )
    body = []
    for d in report.devices:
        r = report.summary_row(d)
        e = report.entries[d]
        p = (e.get("row") or {}).get("parameters") or {}
        flagged = {f["parameter"] for f in report.outliers.get(d, [])}
        link = (
            f"<a href='{html.escape(d)}/report/index.html'>{html.escape(d)}</a>"
            if e["status"] != "failed"
            else html.escape(d)
        )
        if e["status"] != "failed" and r["diagnosis"] is not None:
            diag = f"<a href='{html.escape(d)}/diagnosis/index.html'>{_h(r['diagnosis'])}</a>"
        else:
            diag = _h(r["diagnosis"] or "-")
        cells = [
            link,
            f"<span class='{e['status']}'>{_h(e['status'])}</span>",
            _h(r["kind"]),
            _h(r["order"]),
            "" if r["nrmse"] is None else f"{100 * r['nrmse']:.3g} %",
            _h(r["validated"]),
            diag,
            _h(r["effects"]),
            _h(r["outliers"]),
        ]
        for k in params:
            if k in p:
                cls = " class='outlier'" if k in flagged else ""
                se = p[k].get("stderr")
                cells.append(f"<span{cls}>{p[k]['value']:.4g}" + ("" if se is None else f" ± {se:.2g}") + "</span>")
            else:
                cells.append("")
        cells.append(_h(r["reason"]))
        body.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    counts = ", ".join(f"{n} {s}" for s, n in sorted(report.counts().items()))
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>duhem batch</title>
<style>body{{font-family:sans-serif;margin:1em}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 6px;text-align:right}}td:first-child{{text-align:left}}
.failed{{color:#b00;font-weight:bold}}.invalid{{color:#b60;font-weight:bold}}.ok{{color:#070}}
.outlier{{background:#fd8;font-weight:bold}}</style></head><body>
<h1>duhem batch: {len(report.devices)} devices</h1>
<p>{html.escape(counts)}. NRMSE: the FMU (fmpy) against the data, RMS error / output range over all samples,
the worst recording of the device. Parameters: the fit's canonical parameters ± standard error.
Outliers: {html.escape(OUTLIER_RULE)}. Machine-readable: <a href="summary.csv">summary.csv</a>,
<a href="summary.json">summary.json</a>.</p>
<table>{head}{"".join(body)}</table></body></html>"""


def _write_if_changed(path: Path, text: str) -> None:
    try:
        if path.read_text(encoding="utf-8") == text:
            return
    except OSError:
        pass
    with atomic_file(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_summary(report: BatchReport) -> None:
    _write_if_changed(report.outdir / "summary.csv", summary_csv(report))
    data = report.to_json()
    for k in ("seconds", "dashboard"):
        data.pop(k)
    data["devices"] = [{k: v for k, v in d.items() if k != "action"} for d in data["devices"]]
    _write_if_changed(report.outdir / "summary.json", json_text(data))
    _write_if_changed(report.outdir / "index.html", summary_html(report))
