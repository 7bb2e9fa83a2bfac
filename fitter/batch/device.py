"""The per-device work a worker runs: load, fit, export, validate, report, diagnose (`process_device`)."""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fitter.batch.config import KNOWN_ERRORS
from fitter.batch.manifest import BatchOptions, DeviceSpec
from fitter.core.errors import DuhemError
from fitter.core.files import json_text, jsonable
from fitter.core.kernel import simulate as simulate_model
from fitter.core.models import Signal, save_model
from fitter.data.metrics import compare
from fitter.data.recordings import Recording, load_recordings
from fitter.diagnosis import diagnose
from fitter.fmu.build import build_fmu
from fitter.fmu.host import simulate_fmu
from fitter.identification.exported import levelled, range_warnings
from fitter.identification.explained import check_explained, explained_variance
from fitter.identification.fit import fit_recordings
from fitter.reports.diagnosis_report import fill_diagnosis_report
from fitter.reports.fit_report import fill_fit_report
from fitter.reports.validation_plot import write_validation_plot

# --------------------------------------------------------------------------- the device task


@dataclass
class DeviceTask:
    """What a worker gets: the device, its recordings' bytes, the options."""

    device: DeviceSpec
    contents: list[bytes]
    options: BatchOptions
    hash: str


def _scratch_parent() -> str | None:
    """The Dask worker's local directory (cleaned by Dask when a worker dies), else the system default."""
    try:
        from distributed import get_worker

        return get_worker().local_directory
    except (ImportError, ValueError):
        return None


def _load(task: DeviceTask, scratch: Path) -> list[Recording]:
    """The device's recordings, read from their bytes written into `scratch` (messages name the originals)."""
    d = task.device
    local = []
    for i, (shown, data) in enumerate(zip(d.recordings, task.contents)):
        p = scratch / "in" / str(i) / Path(shown).name
        p.parent.mkdir(parents=True)
        p.write_bytes(data)
        local.append(str(p))
    try:
        recs = load_recordings(local, d.time, d.input, d.output)
    except DuhemError as exc:
        text = str(exc)
        for lp, shown in zip(local, d.recordings):
            text = text.replace(lp, shown)
        raise type(exc)(text) from None
    out = []
    for r, shown in zip(recs, d.recordings):
        inp = Signal(r.input.name, d.input_unit, r.input.description) if d.input_unit else r.input
        outp = Signal(r.output.name, d.output_unit, r.output.description) if d.output_unit else r.output
        out.append(Recording(r.t, r.u, r.y, r.name, inp, outp, shown))
    return out


def _validate(fmu: Path, recs: list[Recording], model, threshold: float) -> tuple[list[dict], list[np.ndarray]]:
    """Per recording, what ``duhem validate`` reports: the FMU (fmpy) against the data `levelled` by the output
    reference the fit found for it, all samples."""
    rows, outputs = [], []
    for rec in [levelled(model, r) for r in recs]:
        y = simulate_fmu(fmu, rec.t, rec.u)
        m = compare(rec, y)
        m.update(
            recording=rec.name,
            source=rec.source,
            passed=bool(m["nrmse"] <= threshold),
            judged_on="all samples",
            fmu_vs_in_process_max_abs=float(np.max(np.abs(y - simulate_model(model, rec.t, rec.u).y))),
            warnings=range_warnings(model, rec.t, rec.u, y),
        )
        rows.append(m)
        outputs.append(y)
    return rows, outputs


def _files(directory: Path) -> dict[str, bytes]:
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def _failed(task: DeviceTask, reason: str, seconds: float) -> dict:
    return {
        "device": task.device.name,
        "status": "failed",
        "reason": reason,
        "hash": task.hash,
        "seconds": seconds,
        "row": {},
        "files": {},
    }


def _cpu() -> float:
    """CPU seconds of this process and its waited-for children (the C compiler)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if isinstance(exc, KNOWN_ERRORS) else f"internal error ({type(exc).__name__}): {text}"


def process_device(task: DeviceTask) -> dict:
    """Fit, export, validate, report (and diagnose) one device; the outputs come back as bytes.

    Returns ``{"device", "status", "reason", "hash", "seconds", "row", "files"}``; a failure on the
    device's data (`DuhemError`, ValueError, OSError, ArithmeticError) is status ``failed`` with its
    one-line reason; any other exception propagates (Dask retries the task).
    """
    import warnings

    start, cpu0 = time.perf_counter(), _cpu()
    opts = task.options
    with tempfile.TemporaryDirectory(prefix="duhem-batch-", dir=_scratch_parent()) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        scratch = Path(tmp)
        out = scratch / "out"
        out.mkdir()
        timings: dict[str, float] = {}
        mark = [time.perf_counter()]

        def lap(step: str) -> None:
            now = time.perf_counter()
            timings[step] = now - mark[0]
            mark[0] = now

        try:
            recs = _load(task, scratch)
            result = fit_recordings(
                recs,
                kind=opts.kind,
                order=opts.order,
                faithful_minor_loops=opts.faithful_minor_loops,
                effects=opts.effects,
                held=dict(opts.held),
            )
            lap("fit")
            model = result.model
            result.summary["explained"] = jsonable(explained := explained_variance(model, recs))
            check_explained(explained)  # as `duhem fit`: a model of noise is refused, not saved
            save_model(model, out / "model.json")
            (out / "fit.json").write_text(json_text(result.summary), encoding="utf-8")
            build_fmu(model, out / "model.fmu", backend=opts.backend)
            lap("fmu")
            rows, outputs = _validate(out / "model.fmu", recs, model, opts.threshold)
            (out / "validation.json").write_text(
                json_text({"threshold": opts.threshold, "recordings": rows}), encoding="utf-8"
            )
            write_validation_plot(out / "validation.png", recs, outputs, [r["nrmse"] for r in rows])
            lap("validation")
            (out / "report").mkdir()
            fill_fit_report(result, recs, out / "report")
            lap("report")
            diag = None
            if opts.diagnose:
                diag = diagnose(recs, model=model)
                (out / "diagnosis.json").write_text(json_text(diag.to_json()), encoding="utf-8")
                (out / "diagnosis").mkdir()
                fill_diagnosis_report(diag, recs, out / "diagnosis")
                lap("diagnosis")
        except KNOWN_ERRORS as exc:
            return _failed(task, one_line(exc), time.perf_counter() - start)
        passed = all(r["passed"] for r in rows)
        worst = max(rows, key=lambda r: r["nrmse"])
        row = {
            "kind": model.kind,
            "order": model.order,
            "recordings": len(recs),
            "nrmse": worst["nrmse"],
            "nrmse_recording": worst["recording"],
            "validated": passed,
            "parameters": result.summary.get("parameters_normalised", {}),
            "convergence": bool((result.summary.get("convergence") or {}).get("satisfied")),
            "model_effects": [e.effect for e in model.effects],
            "diagnosis": None
            if diag is None
            else {"verdict": diag.verdict, "effects": [f["effect"] for f in diag.findings]},
            "timings": timings,
            "cpu_seconds": _cpu() - cpu0,
        }
        reason = (
            ""
            if passed
            else (
                f"validation: NRMSE {worst['nrmse']:.4g} of the FMU on {worst['recording']} "
                f"exceeds the threshold {opts.threshold:g}"
            )
        )
        return {
            "device": task.device.name,
            "status": "ok" if passed else "invalid",
            "reason": reason,
            "hash": task.hash,
            "seconds": time.perf_counter() - start,
            "row": jsonable(row),
            "files": _files(out),
        }
