"""HTML + PNG report of a `fitter.diagnosis.Diagnosis`.

`write_diagnosis_report(diagnosis, recordings, directory)` writes

* ``residual_map.png``: the base model's residual against the input (one
  colour per recording) and against the experiment clock, with the noise band
  +-2 sigma; where the mismatch lives;
* ``loops.png``: per recording, the data loop with the base and the extended
  model's loops (before / after), and the residuals before / after vs time;
* ``nrmse.png``: NRMSE per recording before and after;
* ``index.html``: the plain-language paragraph, the findings and candidate
  table, the mismatch location tables, the figures.

Everything is written into a temporary directory beside `directory`, which
then replaces `directory` (`fitter.core.files.atomic_directory`), so a reader
never sees a half-written report; `fill_diagnosis_report` writes the same files
into a directory the caller provides.
"""

from __future__ import annotations

import html
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from fitter.core.files import atomic_directory

__all__ = ["write_diagnosis_report", "fill_diagnosis_report"]


def _split(diagnosis, recordings) -> list[tuple[np.ndarray, np.ndarray]]:
    out, i = [], 0
    for r in recordings:
        n = len(r.t)
        out.append((diagnosis.baseline_output[i : i + n], diagnosis.extended_output[i : i + n]))
        i += n
    return out


def _residual_map(diagnosis, recordings, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.5))
    s = diagnosis.noise_rms
    for r, (yb, _) in zip(recordings, _split(diagnosis, recordings)):
        a1.plot(r.u, r.y - yb, ".", ms=1.5, label=r.name)
        a2.plot(r.t, r.y - yb, ".", ms=1.5)
    for ax in (a1, a2):
        ax.axhspan(-2 * s, 2 * s, color="0.85", zorder=0, label="±2σ noise" if ax is a1 else None)
        ax.set_ylabel(f"residual {recordings[0].output.name} (data - base model)")
    a1.set_xlabel(f"input {recordings[0].input.name}")
    a2.set_xlabel("experiment time")
    a1.legend(markerscale=6, fontsize=7)
    a1.set_title("base-model residual vs input")
    a2.set_title("base-model residual vs time")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _loops(diagnosis, recordings, path: Path) -> None:
    import matplotlib.pyplot as plt

    n = len(recordings)
    fig, axes = plt.subplots(2, n, figsize=(3.2 * n, 6), squeeze=False)
    for j, (r, (yb, ye)) in enumerate(zip(recordings, _split(diagnosis, recordings))):
        ax = axes[0, j]
        ax.plot(r.u, r.y, color="0.6", lw=0.8, label="data")
        ax.plot(r.u, yb, color="tab:red", lw=0.9, label="before (base)")
        ax.plot(r.u, ye, color="tab:blue", lw=0.9, ls="--", label="after (extended)")
        ax.set_title(r.name, fontsize=8)
        ax.set_xlabel(r.input.name)
        bx = axes[1, j]
        bx.plot(r.t, r.y - yb, color="tab:red", lw=0.6, label="before")
        bx.plot(r.t, r.y - ye, color="tab:blue", lw=0.6, label="after")
        bx.set_xlabel("time")
    axes[0, 0].legend(fontsize=7)
    axes[1, 0].legend(fontsize=7)
    axes[0, 0].set_ylabel(recordings[0].output.name)
    axes[1, 0].set_ylabel("residual")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _nrmse(diagnosis, path: Path) -> None:
    import matplotlib.pyplot as plt

    names = list(diagnosis.baseline["nrmse_per_recording"])
    before = [100 * diagnosis.baseline["nrmse_per_recording"][k] for k in names]
    after = [100 * diagnosis.extended["nrmse_per_recording"][k] for k in names]
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(1.2 * len(names) + 3, 3.5))
    ax.bar(x - 0.2, before, 0.4, label="before", color="tab:red")
    ax.bar(x + 0.2, after, 0.4, label="after", color="tab:blue")
    ax.set_xticks(x, names, rotation=30, ha="right", fontsize=7)
    ax.set_ylabel("NRMSE (%)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _table(rows: list[dict], keys: Sequence[str]) -> str:
    def fmt(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        if isinstance(v, dict):
            return ", ".join(f"{k} = {fmt(x)}" for k, x in v.items())
        return html.escape(str(v))

    head = "".join(f"<th>{html.escape(k)}</th>" for k in keys)
    body = "".join("<tr>" + "".join(f"<td>{fmt(r.get(k))}</td>" for k in keys) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _html(diagnosis) -> str:
    d = diagnosis.to_json()
    m = d["mismatch"]
    findings = (
        _table(
            d["findings"], ["effect", "origin", "p_value", "parameters", "stderr", "explained_fraction", "residual_rms"]
        )
        if d["findings"]
        else "<p>Nothing missing.</p>"
    )
    parts = [
        "<!doctype html><meta charset='utf-8'><title>duhem diagnose</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}td,th{border:1px solid #ccc;"
        "padding:2px 6px;font-size:13px}table{border-collapse:collapse}</style>",
        "<h1>Diagnosis</h1>",
        f"<p><b>Verdict: {html.escape(d['verdict'].replace('_', ' '))}.</b> {html.escape(d['summary'])}</p>",
        f"<p>Noise level (from the data): {d['noise_rms']:.4g}; base residual RMS "
        f"{d['baseline']['residual_rms']:.4g}; extended residual RMS {d['extended']['residual_rms']:.4g}.</p>",
        _remainder_html(d["extended"].get("remainder")),
        "<h2>Findings</h2>",
        findings,
        "<h2>All candidates (first round)</h2>",
        _table(
            d["candidates"],
            ["rank", "effect", "residual_rms", "explained_fraction", "p_value", "n_eff", "significant", "parameters"],
        ),
        "<h2>Where the mismatch is</h2>",
        "<img src='residual_map.png'>",
        _table(
            m["per_recording"], ["name", "t_start", "rate", "amplitude", "residual_rms", "noise_ratio", "residual_mean"]
        ),
        _table([{"branch": k, "residual_rms": v} for k, v in m["per_branch"].items()], ["branch", "residual_rms"]),
        _table(m["per_input_range"], ["u_from", "u_to", "residual_rms"]),
        _table([{"trend": k, "correlation": v} for k, v in m["growth"].items()], ["trend", "correlation"]),
        "<h2>Before and after</h2>",
        "<img src='loops.png' style='max-width:100%'>",
        "<img src='nrmse.png'>",
    ]
    if d["validation"]:
        parts += [
            "<h2>Hold-out check</h2>",
            _table(
                [{"model": k, "held-out residual RMS": v} for k, v in d["validation"].items() if k != "held_out"],
                ["model", "held-out residual RMS"],
            ),
            f"<p>Held out: {html.escape(d['validation']['held_out'])}.</p>",
        ]
    return "\n".join(parts)


def write_diagnosis_report(diagnosis, recordings, directory: str | os.PathLike) -> Path:
    """Write the report (PNGs + ``index.html``) as `directory` (created, or replaced as a
    whole; missing parents are created); returns its absolute path."""
    target = Path(directory).resolve()
    target.parent.mkdir(parents=True, exist_ok=True)
    with atomic_directory(target) as tmp:
        fill_diagnosis_report(diagnosis, recordings, tmp)
    return target


def fill_diagnosis_report(diagnosis, recordings, directory: Path) -> None:
    """Write the report's files into the existing directory `directory`."""
    import matplotlib

    matplotlib.use("Agg")
    _residual_map(diagnosis, recordings, directory / "residual_map.png")
    _loops(diagnosis, recordings, directory / "loops.png")
    _nrmse(diagnosis, directory / "nrmse.png")
    (directory / "index.html").write_text(_html(diagnosis), encoding="utf-8")


def _remainder_html(rem: dict | None) -> str:
    """One line on the residual the extended model leaves (`procedure._remainder`)."""
    if not rem:
        return ""
    state = "explained (the noise)" if rem["explained"] else "not explained"
    lo, hi = rem["worst_input_range"]
    return (
        f"<p>Remainder: {state}; lag-1 autocorrelation {rem['lag1']:.3f} (p = {rem['p_value']:.2g}, white noise "
        f"0 &plusmn; {1 / max(rem['pairs'], 1) ** 0.5:.2g}); largest in "
        f"{html.escape(str(rem['worst_recording']))}, {html.escape(str(rem['worst_branch']))} branch, inputs "
        f"{lo:.3g} to {hi:.3g}.</p>"
    )
