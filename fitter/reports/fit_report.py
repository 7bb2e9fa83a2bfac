"""HTML fit report: per-recording error figures and plots (matplotlib, Agg backend).

`write_fit_report(result, recordings, directory)` writes, for every recording,
the data and model loops (y against u) with the model's uncertainty band
(`FitResult.band`: y_hat -+ 2 sd, linearised propagation of the parameter
covariance), and the residual against the input and against time, plus an
`index.html` with the table of NRMSE, max error, loop-area error and residual
RMS against the estimated noise level, the convergence condition and the
preparation notes.  The report is written into a temporary directory beside
`directory` that then replaces it (`fitter.core.files.atomic_directory`), so a
reader never sees half a report; `fill_fit_report` writes the same files into
a directory the caller provides.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Sequence

import numpy as np

from fitter.core.files import atomic_directory
from fitter.data.metrics import compare
from fitter.data.recordings import Recording
from fitter.identification.fit_summary import misfit_text
from fitter.reports import pyplot

__all__ = ["write_fit_report", "fill_fit_report", "recording_metrics"]


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def recording_metrics(result, rec: Recording) -> tuple[dict, np.ndarray]:
    """`fitter.data.metrics.compare` of the saved model (from its stored x0) on all samples of `rec`:
    the figures of the fit summary and of `duhem validate`."""
    y_hat = result.simulate(rec)
    return compare(rec, y_hat), y_hat


def _loop_figure(rec: Recording, y_hat, lo, hi, path: Path) -> None:
    plt = pyplot()
    ok = np.isfinite(y_hat)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    ax.plot(rec.u, rec.y, ".", ms=2, color="0.5", label="data")
    ax.fill_between(rec.u[ok], lo[ok], hi[ok], color="C1", alpha=0.35, lw=0, label="model ±2 sd")
    ax.plot(rec.u[ok], y_hat[ok], "-", color="C0", lw=1, label="model")
    ax.set_xlabel(f"{rec.input.name} [{rec.input.unit}]" if rec.input.unit else rec.input.name)
    ax.set_ylabel(f"{rec.output.name} [{rec.output.unit}]" if rec.output.unit else rec.output.name)
    ax.set_title(f"{rec.name}: data and model loop")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _residual_figure(rec: Recording, y_hat, noise: float | None, path: Path) -> None:
    plt = pyplot()
    ok = np.isfinite(y_hat)
    r = rec.y[ok] - y_hat[ok]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.6))
    a1.plot(rec.u[ok], r, ".", ms=2)
    a1.set_xlabel(rec.input.name)
    a2.plot(rec.t[ok], r, "-", lw=0.7)
    a2.set_xlabel("time")
    for ax in (a1, a2):
        ax.set_ylabel(f"residual {rec.output.name}")
        if noise:
            ax.axhspan(-2 * noise, 2 * noise, color="C2", alpha=0.2, lw=0, label="±2 noise RMS")
        ax.axhline(0, color="k", lw=0.5)
    a1.legend(loc="best", fontsize=8)
    fig.suptitle(f"{rec.name}: residual vs input and vs time")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt(x, spec=".4g") -> str:
    return "–" if x is None else format(x, spec)


def _minor_loops(minor: dict | None) -> str:
    """The summary's `minor_loops` check as a paragraph (empty without it)."""
    if not minor:
        return ""
    exc = minor.get("excursion")
    size = "overflows" if exc is None else f"leaves the recorded output range by at most {exc:.3g} output ranges"
    verdict = (
        ""
        if minor.get("faithful")
        else " <b>The model reproduces the recorded loops, not necessarily "
        "smaller ones: check it on a recording with minor loops before using it there.</b>"
    )
    return f"<p>Minor loops inside the input range ({html.escape(minor['input'])}): the output {size}.{verdict}</p>"


def _misfit(m: dict | None) -> str:
    """The summary's ``misfit`` as a warning paragraph (empty when the model follows the recordings)."""
    if not m or m["followed"]:
        return ""
    return f"<p><b>Warning: {html.escape(misfit_text(m))}.</b></p>"


def _page(result, rows: list[tuple[str, dict, str, str]]) -> str:
    s = result.summary
    conv = s["convergence"]
    head = (
        "<tr><th>recording</th><th>samples used</th><th>NRMSE</th><th>NRMSE own x0</th><th>max error</th>"
        "<th>loop-area error</th><th>residual RMS</th><th>noise RMS</th><th>residual / noise</th></tr>"
    )
    own = {r["recording"]: r.get("nrmse_x0_fitted") for r in s.get("recordings", [])}
    body = []
    for name, m, _, _ in rows:
        ratio = m["residual_rms"] / m["noise_rms"] if m.get("noise_rms") else None
        body.append(
            f"<tr><td>{html.escape(name)}</td><td>{m['samples']}</td><td>{_fmt(m['nrmse'], '.3%')}</td>"
            f"<td>{_fmt(own.get(name), '.3%')}</td>"
            f"<td>{_fmt(m['max_error'])}</td>"
            f"<td>{_fmt(m['loop_area_error'], '.2%') if m['loop_area_error'] is not None else '–'}</td>"
            f"<td>{_fmt(m['residual_rms'])}</td><td>{_fmt(m['noise_rms'])}</td>"
            f"<td>{_fmt(ratio, '.2f')}</td></tr>"
        )
    figs = "".join(
        f"<h3>{html.escape(n)}</h3><img src='{a}' alt='loop {html.escape(n)}'>"
        f"<img src='{b}' alt='residual {html.escape(n)}'>"
        for n, _, a, b in rows
    )
    notes = "".join(
        f"<li><b>{html.escape(p['recording'])}</b>: {html.escape('; '.join(p['notes']))}</li>"
        for p in s.get("preparation", [])
    )
    params = "".join(
        f"<tr><td>{html.escape(k)}</td><td>{v['value']:.6g}</td><td>{_fmt(v['stderr'], '.3g')}</td></tr>"
        for k, v in s.get("parameters_normalised", {}).items()
    )
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>Fit report</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}img{{max-width:100%}}</style></head><body>
<h1>Semilinear Duhem fit report</h1>
<p>Model: <b>{"rate-dependent" if s["kind"] == "rd" else "rate-independent"}</b>, order {s["order"]}.
Chosen by: {html.escape(s["why"])}.</p>
<p>Convergence condition: <b>{"satisfied" if conv["satisfied"] else "NOT satisfied"}</b>
({html.escape(conv["quantity"])} = {_fmt(conv["value"])}).</p>
{_minor_loops(s.get("minor_loops"))}
{_misfit(s.get("misfit"))}
<h2>Errors per recording</h2><p>The saved model, simulated from its stored initial state over all samples
of each recording (what the FMU gives and what <code>duhem validate</code> reports).  NRMSE = RMS error /
output range; the last full input cycle beside it.  "NRMSE own x0": from the state fitted to that recording
(recordings made after different histories start from different states; <code>duhem validate --x0 fitted</code>
starts the FMU there).</p>
<table>{head}{"".join(body)}</table>
{_comparison_html(s.get("comparison"))}
<h2>Figures</h2>{figs}
<h2>Preparation</h2><ul>{notes}</ul>
<h2>Parameters (normalised units) and standard errors</h2><table><tr><th>name</th><th>value</th>
<th>stderr</th></tr>{params}</table></body></html>"""


def _comparison_html(comp: dict | None) -> str:
    """The `duhem fit --compare` table: the Duhem model beside the classical models."""
    if not comp:
        return ""
    names = list(comp["baselines"])
    several = any(comp["baselines"][n]["per_recording"] for n in names)
    head = "<tr><th>recording</th><th>Duhem</th>" + "".join(f"<th>{html.escape(n)}</th>" for n in names)
    head += "".join(f"<th>{html.escape(n)} (alone)</th>" for n in names) if several else ""
    rows = []
    for r, value in comp["duhem"].items():
        cells = [_fmt(value, ".3%")] + [_fmt(comp["baselines"][n]["one_for_all"][r], ".3%") for n in names]
        if several:
            cells += [_fmt(comp["baselines"][n]["per_recording"][r], ".3%") for n in names]
        rows.append(f"<tr><td>{html.escape(r)}</td>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    return (
        f"<h2>Beside the classical models</h2><p>NRMSE, {html.escape(comp['measure'])}; one parameter "
        f"set for all recordings{', and each classical model fitted to each recording alone' if several else ''}."
        f"</p><table>{head}</tr>{''.join(rows)}</table>"
    )


def write_fit_report(result, recordings: Sequence[Recording], directory) -> str:
    """Write the report for `result` on `recordings` as `directory` (created, or replaced
    as a whole; missing parents are created); returns the index.html path."""
    directory = Path(directory)
    directory.parent.mkdir(parents=True, exist_ok=True)
    with atomic_directory(directory) as tmp:
        fill_fit_report(result, recordings, tmp)
    return str(directory / "index.html")


def fill_fit_report(result, recordings: Sequence[Recording], directory: Path) -> None:
    """Write the report's files (``index.html``, one loop and one residual PNG per
    recording) into the existing directory `directory`."""
    rows = []
    for i, rec in enumerate(recordings):
        m, y_hat = recording_metrics(result, rec)
        lo, hi = result.band(rec)
        stem = f"{i:02d}_{_safe(rec.name)}"
        _loop_figure(rec, y_hat, lo, hi, directory / f"{stem}_loop.png")
        _residual_figure(rec, y_hat, m.get("noise_rms"), directory / f"{stem}_residual.png")
        rows.append((rec.name, m, f"{stem}_loop.png", f"{stem}_residual.png"))
    (directory / "index.html").write_text(_page(result, rows), encoding="utf-8")
