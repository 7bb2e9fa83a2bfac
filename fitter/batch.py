"""`duhem batch`: one validated model, FMU, report (and diagnosis) per device, on Dask.

Manifest
--------
A CSV file with one header line and one row per device:

``device`` (required)
    The device's name; it names the output directory ``OUTDIR/<device>/``, so it
    must be a safe directory name: letters, digits, ``-``, ``_`` and ``.``, not
    starting with ``.`` or ``-``, at most 100 characters, unique (also ignoring
    case), and not ``summary.csv``, ``summary.json`` or ``index.html``.
``recordings`` (required)
    The device's recording files, several separated by ``;`` (one experiment
    per file, e.g. one per rate, as ``duhem fit REC1.csv REC2.csv``).  A
    relative path is relative to the manifest's directory.
``time``, ``input``, ``output`` (optional)
    Column names or 0-based indices, as ``--time/--input/--output`` of
    ``duhem fit`` (defaults ``time``, ``u``, ``y``; an empty cell takes the
    default); ``time`` = ``none`` reads the file without a time column (the
    sample index is the time, ``--no-time``).
``input_unit``, ``output_unit`` (optional)
    Units of the input and output (e.g. ``V``, ``um``) when the column header
    does not carry one (a given unit replaces the header's); they go into the
    model and the FMU.

A bad manifest (a missing or unknown column, a missing recording file, an
empty or duplicate or unsafe device name) is a `BatchError` naming the
manifest, the row (as numbered in the file, header = line 1) and the value;
nothing is written.  A recording whose *content* is bad (non-numeric cell,
too few samples, ...) is not a manifest error: that device fails, and the
summary says why.

Per device (a task on a Dask worker, `process_device`)
------------------------------------------------------
fit (`fit_recordings`, ``kind``/``order``/``faithful_minor_loops``/``effects``/``held`` as ``duhem fit``)
-> ``model.json`` and ``fit.json`` (the fit summary); the FMU ``model.fmu`` (``backend``,
native by default); validation of the FMU against every recording with fmpy,
as ``duhem validate`` does (``validation.json``, ``validation.png``; NRMSE
over all samples against ``threshold``); the fit report ``report/``; with
``diagnose``, `fitter.diagnosis.diagnose` with the fitted model as its base
(``diagnosis.json``, ``diagnosis/``).  The worker reads no file and writes
none outside its own scratch directory: the client sends the recordings'
bytes and gets the output files back as bytes, so a cluster needs no shared
file system, and a worker that dies leaves nothing in OUTDIR.

The client writes each finished device as a whole: a temporary directory
beside ``OUTDIR/<device>`` renamed into place (`atomic_directory`), the last
file being ``done.json`` (status, the row of the summary, every output
file with its size, and the input hash).  The input hash is the SHA-256 of
the package version, `BATCH_FORMAT`, the options that change the outputs
(kind, order, backend, diagnose, threshold, faithful minor loops, effects, held parameters), the device's
column and unit choices, and each recording's name as written in the manifest and its bytes
(the recording's location on disk does not enter: a copied tree stays
current).  A re-run skips a device whose ``done.json`` has the same hash and
whose files are all present with their recorded sizes ("skipped: current").
A device that failed on its data (a `DuhemError`, ``ValueError``,
``OSError``) gets a directory with only ``done.json`` (status ``failed`` and
the one-line reason) and is skipped while its inputs stay the same
(``retry_failed`` runs it again).  A device whose worker died more often
than the scheduler allows (``distributed.scheduler.allowed-failures``,
default 3: the scheduler re-runs the task of a dead worker elsewhere), or
whose task raised an unexpected error ``RETRIES`` + 1 times, is reported as
failed in the summary and gets no directory, so the next run tries again.

Status: ``ok``; ``invalid`` (outputs written, but the FMU's NRMSE on some
recording exceeds the threshold, the exit-3 case of ``duhem validate``);
``failed`` (no outputs, the reason in the summary).

Summary (``OUTDIR/summary.csv``, ``summary.json``, ``index.html``)
---------------------------------------------------------------------
One row per device of the manifest: status and reason, what was done this
run (``action``), kind and order, the worst NRMSE of the FMU over the
device's recordings, the validation verdict, the fitted parameters with
their standard errors, the diagnosis verdict and the effects found, and
``outliers``.

Outlier rule (`flag_outliers`): the fitted parameters are those of the fit
summary (the canonical form of the model, fitted in units normalised by each
device's own input and output ranges: they describe the loop's shape, not
the sensor gain).  Devices are compared within a group of the same kind and
order with at least `MIN_GROUP` members; for each parameter, the robust
z-score is z = 0.6745 (p - median) / MAD (MAD = median absolute deviation
from the median; Iglewicz & Hoaglin), and a device is flagged for that
parameter when |z| > `OUTLIER_Z` (3.5).  A parameter whose MAD is 0 (all
devices but a few equal) uses 1.2533 x the mean absolute deviation instead;
when that is 0 too, nothing is flagged for it.  The canonical parameters are well determined at order 1;
at higher orders those of similar loops can differ by orders of magnitude (companion form), so a flag
there says that the models differ more than the devices need to (``--order`` puts a batch in one class).

Dask (`run_batch`)
------------------
A ``distributed.LocalCluster`` of ``workers`` processes with one thread
each (default: one per core), or an existing cluster (``scheduler`` address
or ``client``).  Tasks are submitted with ``retries=RETRIES`` and
collected as they finish; one device's failure never stops the batch.
Progress: a rich progress bar on stderr when it is a terminal, and the
dashboard link when there is one.  Devices that are current are never
submitted; when every device is current no cluster is started.  At the end,
leftover temporary entries in OUTDIR (``.tmp-*``, ``.old-*``: from a client
that was killed) are removed; one writer at a time may write into an OUTDIR
(`fitter.core.files.output_lock` of OUTDIR: a second batch, or a report
written there, waits a bounded time, then fails naming the first).
"""
from __future__ import annotations

import contextlib
import csv
import dataclasses
import hashlib
import html
import importlib.util
import io
import json
import math
import os
import re
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np

from fitter.core.effects import REGISTRY
from fitter.core.errors import DuhemError
from fitter.core.files import atomic_directory, atomic_file, json_text, jsonable, output_lock
from fitter.core.kernel import simulate as simulate_model
from fitter.core.models import Signal, save_model
from fitter.data.metrics import compare
from fitter.data.recordings import Recording, load_recordings
from fitter.diagnosis import diagnose
from fitter.fmu.build import build_fmu
from fitter.fmu.host import simulate_fmu
from fitter.fmu.model_description import package_version
from fitter.identification.effects_fit import check_held
from fitter.identification.exported import range_warnings
from fitter.identification.fit import fit_recordings
from fitter.reports.diagnosis_report import fill_diagnosis_report
from fitter.reports.fit_report import fill_fit_report
from fitter.reports.validation_plot import write_validation_plot

__all__ = ["BatchError", "BatchOptions", "DeviceSpec", "DeviceTask", "BatchReport", "read_manifest", "run_batch",
           "process_device", "flag_outliers", "input_hash", "BATCH_FORMAT", "OUTLIER_Z", "MIN_GROUP", "RETRIES",
           "DASK_MISSING"]

BATCH_FORMAT = 1
"""Version of the per-device outputs; part of the input hash (a change re-runs every device)."""
OUTLIER_Z = 3.5
"""A device is an outlier for a parameter when its robust z-score exceeds this (Iglewicz & Hoaglin)."""
MIN_GROUP = 4
"""Fewest devices of one kind and order among which outliers are looked for."""
RETRIES = 2
"""Dask ``retries=`` of a device task (an unexpected exception; a dead worker is the scheduler's affair)."""
DASK_MISSING = ("duhem batch needs dask.distributed, which is not installed: "
                "pip install 'semilinear-duhem[batch]' (or: pip install 'dask[distributed]')")

REQUIRED = ("device", "recordings")
OPTIONAL = ("time", "input", "output", "input_unit", "output_unit")
DEFAULT_COLUMNS = {"time": "time", "input": "u", "output": "y"}
RESERVED = {"summary.csv", "summary.json", "index.html"}
_SAFE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}$")
_KNOWN_ERRORS = (DuhemError, ValueError, OSError, ArithmeticError)


class BatchError(DuhemError):
    """A bad manifest or batch option; the message names the file, row and value."""


# --------------------------------------------------------------------------- manifest

@dataclass(frozen=True)
class DeviceSpec:
    """One row of the manifest: the device, its recording files and column choices."""

    name: str
    row: int
    recordings: tuple[str, ...]          # as written in the manifest
    paths: tuple[str, ...]               # resolved
    time: str | None = "time"
    input: str = "u"
    output: str = "y"
    input_unit: str | None = None
    output_unit: str | None = None

    def columns(self) -> dict:
        return {"time": self.time, "input": self.input, "output": self.output,
                "input_unit": self.input_unit, "output_unit": self.output_unit}


def read_manifest(path: str | os.PathLike) -> list[DeviceSpec]:
    """The devices of a manifest (module docstring); `BatchError` naming file, row and value."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise BatchError(f"{path}: no such manifest file") from None
    except IsADirectoryError:
        raise BatchError(f"{path}: is a directory, not a manifest file") from None
    except UnicodeDecodeError as exc:
        raise BatchError(f"{path}: not a UTF-8 text file ({exc.reason})") from None
    rows = [(i, r) for i, r in enumerate(csv.reader(io.StringIO(text)), start=1)
            if any(c.strip() for c in r)]
    if not rows:
        raise BatchError(f"{path}: empty manifest (expected a header line with columns "
                         f"{', '.join(REQUIRED)})")
    _, header = rows[0]
    header = [h.strip() for h in header]
    for h in header:
        if h not in REQUIRED + OPTIONAL:
            raise BatchError(f"{path}: line 1: unknown column {h!r} (allowed: {', '.join(REQUIRED + OPTIONAL)})")
    for h in REQUIRED:
        if h not in header:
            raise BatchError(f"{path}: line 1: no column {h!r} (columns: {', '.join(header)}; required: "
                             f"{', '.join(REQUIRED)})")
    dup = next((h for i, h in enumerate(header) if h in header[:i]), None)
    if dup:
        raise BatchError(f"{path}: line 1: column {dup!r} appears twice")
    if len(rows) == 1:
        raise BatchError(f"{path}: no devices (only a header line)")
    base = path.resolve().parent
    devices, seen = [], {}
    for line, cells in rows[1:]:
        if len(cells) > len(header):
            raise BatchError(f"{path}: line {line}: {len(cells)} cells but the header has {len(header)} columns")
        cell = {h: (cells[i].strip() if i < len(cells) else "") for i, h in enumerate(header)}
        name = cell["device"]
        where = f"{path}: line {line}"
        if not name:
            raise BatchError(f"{where}: empty device name")
        if not _SAFE.match(name) or name.lower() in RESERVED or name.endswith("."):
            raise BatchError(f"{where}: device name {name!r} is not a safe directory name (letters, digits, "
                             "'-', '_', '.', not starting with '.' or '-', at most 100 characters, not "
                             f"{', '.join(sorted(RESERVED))})")
        if name.lower() in seen:
            raise BatchError(f"{where}: device {name!r} appears twice (also on line {seen[name.lower()]})")
        seen[name.lower()] = line
        recs = tuple(p.strip() for p in cell["recordings"].split(";") if p.strip())
        if not recs:
            raise BatchError(f"{where}: device {name!r} has no recording files")
        paths = []
        for rec in recs:
            p = Path(rec) if Path(rec).is_absolute() else base / rec
            if not p.is_file():
                raise BatchError(f"{where}: device {name!r}: recording {rec!r}: "
                                 f"{'is a directory' if p.is_dir() else 'no such file'} ({p})")
            paths.append(str(p))
        if len(set(paths)) != len(paths):
            raise BatchError(f"{where}: device {name!r}: the same recording file is listed twice")
        cols = {k: cell.get(k) or DEFAULT_COLUMNS[k] for k in DEFAULT_COLUMNS}
        time_col = None if cols["time"].lower() == "none" else cols["time"]
        devices.append(DeviceSpec(name, line, recs, tuple(paths), time_col, cols["input"], cols["output"],
                                  cell.get("input_unit") or None, cell.get("output_unit") or None))
    return devices


# --------------------------------------------------------------------------- options and hash

@dataclass(frozen=True)
class BatchOptions:
    """What each device task does (every field enters the input hash)."""

    kind: str = "auto"
    order: int | None = None
    backend: str = "native"
    diagnose: bool = False
    threshold: float = 0.05
    faithful_minor_loops: bool = False
    effects: tuple[str, ...] = ()
    held: tuple[tuple[str, float], ...] = ()
    """Effect parameters held at known values, ("effect.parameter", value) pairs (``duhem fit --hold``)."""

    def __post_init__(self):
        object.__setattr__(self, "effects", tuple(self.effects))
        unknown = [e for e in self.effects if e not in REGISTRY]
        if unknown:
            raise BatchError(f"unknown effect {unknown[0]!r} (known: {', '.join(REGISTRY)})")
        try:
            held = check_held(dict(self.held), self.effects)
        except DuhemError as exc:
            raise BatchError(str(exc)) from None
        object.__setattr__(self, "held", tuple(sorted(held.items())))
        if self.kind not in ("auto", "ri", "rd"):
            raise BatchError(f"kind must be 'auto', 'ri' or 'rd', not {self.kind!r}")
        if self.backend not in ("native", "python"):
            raise BatchError(f"backend must be 'native' or 'python', not {self.backend!r}")
        if not self.threshold > 0:
            raise BatchError(f"the validation threshold must be positive, got {self.threshold}")


def input_hash(device: DeviceSpec, contents: Sequence[bytes], options: BatchOptions) -> str:
    """SHA-256 of everything a device's outputs depend on (module docstring)."""
    h = hashlib.sha256()
    head = {"package": package_version(), "format": BATCH_FORMAT, "options": dataclasses.asdict(options),
            "columns": device.columns(), "recordings": list(device.recordings)}
    h.update(json.dumps(head, sort_keys=True).encode())
    for data in contents:
        h.update(len(data).to_bytes(8, "little"))
        h.update(hashlib.sha256(data).digest())
    return h.hexdigest()


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
    """Per recording, what ``duhem validate`` reports: the FMU (fmpy) against the data, all samples."""
    rows, outputs = [], []
    for rec in recs:
        y = simulate_fmu(fmu, rec.t, rec.u)
        m = compare(rec, y)
        m.update(recording=rec.name, source=rec.source, passed=bool(m["nrmse"] <= threshold),
                 judged_on="all samples",
                 fmu_vs_in_process_max_abs=float(np.max(np.abs(y - simulate_model(model, rec.t, rec.u).y))),
                 warnings=range_warnings(model, rec.t, rec.u))
        rows.append(m)
        outputs.append(y)
    return rows, outputs


def _files(directory: Path) -> dict[str, bytes]:
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def _failed(task: DeviceTask, reason: str, seconds: float) -> dict:
    return {"device": task.device.name, "status": "failed", "reason": reason, "hash": task.hash,
            "seconds": seconds, "row": {}, "files": {}}


def _cpu() -> float:
    """CPU seconds of this process and its waited-for children (the C compiler)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if isinstance(exc, _KNOWN_ERRORS) else f"internal error ({type(exc).__name__}): {text}"


def process_device(task: DeviceTask) -> dict:
    """Fit, export, validate, report (and diagnose) one device; the outputs come back as bytes.

    Returns ``{"device", "status", "reason", "hash", "seconds", "row", "files"}``; a failure on the
    device's data (`DuhemError`, ValueError, OSError, ArithmeticError) is status ``failed`` with its
    one-line reason; any other exception propagates (Dask retries the task).
    """
    import warnings

    start, cpu0 = time.perf_counter(), _cpu()
    opts = task.options
    with tempfile.TemporaryDirectory(prefix="duhem-batch-", dir=_scratch_parent()) as tmp, \
            warnings.catch_warnings():
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
            result = fit_recordings(recs, kind=opts.kind, order=opts.order,
                                    faithful_minor_loops=opts.faithful_minor_loops, effects=opts.effects,
                                    held=dict(opts.held))
            lap("fit")
            model = result.model
            save_model(model, out / "model.json")
            (out / "fit.json").write_text(json_text(result.summary), encoding="utf-8")
            build_fmu(model, out / "model.fmu", backend=opts.backend)
            lap("fmu")
            rows, outputs = _validate(out / "model.fmu", recs, model, opts.threshold)
            (out / "validation.json").write_text(json_text({"threshold": opts.threshold, "recordings": rows}),
                                                 encoding="utf-8")
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
        except _KNOWN_ERRORS as exc:
            return _failed(task, _one_line(exc), time.perf_counter() - start)
        passed = all(r["passed"] for r in rows)
        worst = max(rows, key=lambda r: r["nrmse"])
        row = {"kind": model.kind, "order": model.order, "recordings": len(recs),
               "nrmse": worst["nrmse"], "nrmse_recording": worst["recording"], "validated": passed,
               "parameters": result.summary.get("parameters_normalised", {}),
               "convergence": bool((result.summary.get("convergence") or {}).get("satisfied")),
               "model_effects": [e.effect for e in model.effects],
               "diagnosis": None if diag is None else
               {"verdict": diag.verdict, "effects": [f["effect"] for f in diag.findings]},
               "timings": timings, "cpu_seconds": _cpu() - cpu0}
        reason = "" if passed else (f"validation: NRMSE {worst['nrmse']:.4g} of the FMU on {worst['recording']} "
                                    f"exceeds the threshold {opts.threshold:g}")
        return {"device": task.device.name, "status": "ok" if passed else "invalid", "reason": reason,
                "hash": task.hash, "seconds": time.perf_counter() - start, "row": jsonable(row),
                "files": _files(out)}


# --------------------------------------------------------------------------- outputs on the client

def _done_path(outdir: Path, name: str) -> Path:
    return outdir / name / "done.json"


def _current(outdir: Path, name: str, digest: str, retry_failed: bool) -> dict | None:
    """The device's ``done.json`` when its outputs are complete and its hash is `digest`; else None."""
    try:
        done = json.loads(_done_path(outdir, name).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(done, dict) or done.get("hash") != digest:
        return None
    if done.get("status") == "failed" and retry_failed:
        return None
    for rel, size in (done.get("files") or {}).items():
        p = outdir / name / rel
        if not p.is_file() or p.stat().st_size != size:
            return None
    return done


def _write_device(outdir: Path, result: dict) -> dict:
    """The device's directory, written whole (`atomic_directory`); returns its ``done.json`` content."""
    name = result["device"]
    done = {k: result[k] for k in ("device", "status", "reason", "hash", "seconds", "row")}
    done.update(files={rel: len(data) for rel, data in result["files"].items()}, package=package_version(),
                format=BATCH_FORMAT, written=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    with atomic_directory(outdir / name) as tmp:
        for rel, data in result["files"].items():
            p = tmp / rel
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)
        (tmp / "done.json").write_text(json_text(done), encoding="utf-8")
    return done


def _clean_leftovers(outdir: Path) -> list[str]:
    """Remove temporary entries a killed run left in OUTDIR (``.tmp-*``, ``.old-*``)."""
    removed = []
    for p in outdir.iterdir():
        if p.name.startswith((".tmp-", ".old-")):
            shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
            removed.append(p.name)
    return removed


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
        names = [k for k in rows[members[0]]["parameters"]
                 if all(k in rows[m]["parameters"] for m in members)]
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
                    flags.setdefault(m, []).append({"parameter": k, "value": float(v), "median": med,
                                                    "z": float(zi)})
    return flags


# --------------------------------------------------------------------------- summary

@dataclass
class BatchReport:
    """What a batch did: per device its ``done.json`` row, what happened this run, the outliers."""

    outdir: Path
    devices: list[str]
    entries: dict[str, dict]            # device -> status, reason, row, hash (done.json) or a failure
    actions: dict[str, str]             # device -> "done", "skipped: current", "failed", "lost"
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
        return jsonable({"outdir": self.outdir, "seconds": self.seconds, "dashboard": self.dashboard,
                         "counts": self.counts(), "outlier_rule": OUTLIER_RULE,
                         "devices": [self.summary_row(d) | {"parameters": (self.entries[d].get("row") or {})
                                                            .get("parameters", {})} for d in self.devices]})

    def summary_row(self, d: str) -> dict:
        e = self.entries[d]
        row = e.get("row") or {}
        diag = row.get("diagnosis")
        flags = self.outliers.get(d, [])
        return {"device": d, "status": e["status"], "reason": e.get("reason", ""), "action": self.actions[d],
                "kind": row.get("kind"), "order": row.get("order"), "nrmse": row.get("nrmse"),
                "nrmse_recording": row.get("nrmse_recording"), "validated": row.get("validated"),
                "convergence": row.get("convergence"),
                "diagnosis": None if diag is None else diag["verdict"],
                "effects": None if diag is None else ";".join(diag["effects"]),
                "model_effects": ";".join(row.get("model_effects", [])),
                "outliers": ";".join(f"{f['parameter']} (z {f['z']:+.1f})" for f in flags)}


OUTLIER_RULE = (f"robust z-score 0.6745 (p - median) / MAD of each fitted parameter (canonical form, units "
                f"normalised by the device's own input and output ranges) among the devices of the same kind and "
                f"order (at least {MIN_GROUP}); flagged when |z| > {OUTLIER_Z}")


def _param_names(report: BatchReport) -> list[str]:
    names: list[str] = []
    for d in report.devices:
        for k in ((report.entries[d].get("row") or {}).get("parameters") or {}):
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
    base = [c for c in report.summary_row(report.devices[0]) if c != "action"]     # what this run did: not kept
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
    head = ("<tr><th>device</th><th>status</th><th>kind</th><th>order</th><th>NRMSE (worst)</th>"
            "<th>validated</th><th>diagnosis</th><th>effects found</th><th>outliers</th>"
            + "".join(f"<th>{html.escape(k)}</th>" for k in params) + "<th>reason</th></tr>")
    body = []
    for d in report.devices:
        r = report.summary_row(d)
        e = report.entries[d]
        p = (e.get("row") or {}).get("parameters") or {}
        flagged = {f["parameter"] for f in report.outliers.get(d, [])}
        link = (f"<a href='{html.escape(d)}/report/index.html'>{html.escape(d)}</a>"
                if e["status"] != "failed" else html.escape(d))
        if e["status"] != "failed" and r["diagnosis"] is not None:
            diag = f"<a href='{html.escape(d)}/diagnosis/index.html'>{_h(r['diagnosis'])}</a>"
        else:
            diag = _h(r["diagnosis"] or "-")
        cells = [link, f"<span class='{e['status']}'>{_h(e['status'])}</span>", _h(r["kind"]), _h(r["order"]),
                 "" if r["nrmse"] is None else f"{100 * r['nrmse']:.3g} %", _h(r["validated"]), diag,
                 _h(r["effects"]), _h(r["outliers"])]
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
<table>{head}{''.join(body)}</table></body></html>"""


def _write_if_changed(path: Path, text: str) -> None:
    try:
        if path.read_text(encoding="utf-8") == text:
            return
    except OSError:
        pass
    with atomic_file(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _write_summary(report: BatchReport) -> None:
    _write_if_changed(report.outdir / "summary.csv", summary_csv(report))
    data = report.to_json()
    for k in ("seconds", "dashboard"):
        data.pop(k)
    data["devices"] = [{k: v for k, v in d.items() if k != "action"} for d in data["devices"]]
    _write_if_changed(report.outdir / "summary.json", json_text(data))
    _write_if_changed(report.outdir / "index.html", summary_html(report))


# --------------------------------------------------------------------------- Dask

def _require_dask():
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise BatchError(DASK_MISSING) from None
    return distributed


@contextlib.contextmanager
def _client(client, scheduler: str | None, workers: int | None) -> Iterator[tuple[object, str | None]]:
    """A ``distributed.Client``: the one given, one connected to `scheduler`, or a new LocalCluster's."""
    distributed = _require_dask()
    if client is not None:
        yield client, _dashboard(client)
        return
    if scheduler:
        try:
            c = distributed.Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise BatchError(f"cannot connect to the Dask scheduler {scheduler}: {_one_line(exc)}") from None
        with c:
            yield c, _dashboard(c)
        return
    n = workers or os.cpu_count() or 1
    with distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True) as cluster, \
            distributed.Client(cluster) as c:
        link = _dashboard(c)
        if link and importlib.util.find_spec("bokeh") is None:
            link += " (the local dashboard needs bokeh: pip install bokeh)"
        yield c, link


def _dashboard(client) -> str | None:
    try:
        services = client.scheduler_info().get("services", {})
    except Exception:   # noqa: BLE001 - an old or remote scheduler: no link
        return None
    return client.dashboard_link if "dashboard" in services else None


@contextlib.contextmanager
def _progress_bar(total: int, show: bool) -> Iterator[Callable[[str], None]]:
    from rich.console import Console

    console = Console(stderr=True)
    if not (show and console.is_terminal):
        yield lambda text: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console, transient=True) as bar:
        task = bar.add_task("duhem batch", total=total)

        def advance(text: str) -> None:
            bar.update(task, advance=1, description=f"duhem batch: {text}")

        yield advance


def run_batch(manifest: str | os.PathLike, outdir: str | os.PathLike, *, options: BatchOptions | None = None,
              workers: int | None = None, scheduler: str | None = None, client=None, retry_failed: bool = False,
              progress: bool = True, say: Callable[[str], None] | None = None) -> BatchReport:
    """Run the batch of `manifest` into `outdir` (module docstring); returns the `BatchReport`.

    `client`: an existing ``distributed.Client`` (tests, notebooks); else `scheduler` (an address) or a
    LocalCluster of `workers` processes.  `say(line)` receives the dashboard link.  Raises `BatchError` for
    a bad manifest or option (nothing written), or when dask is not installed.
    """
    started = time.perf_counter()
    options = options or BatchOptions()
    if workers is not None and workers < 1:
        raise BatchError(f"--workers must be at least 1, got {workers}")
    devices = read_manifest(manifest)
    if client is None:
        _require_dask()
    outdir = Path(outdir)
    if outdir.exists() and not outdir.is_dir():
        raise BatchError(f"{outdir}: exists and is not a directory")
    if not outdir.parent.resolve().is_dir():
        raise BatchError(f"{outdir}: directory {outdir.parent} does not exist")
    contents = {d.name: [Path(p).read_bytes() for p in d.paths] for d in devices}
    hashes = {d.name: input_hash(d, contents[d.name], options) for d in devices}
    outdir.mkdir(exist_ok=True)
    report = BatchReport(outdir, [d.name for d in devices], {}, {})
    with output_lock(outdir):
        _clean_leftovers(outdir)
        todo = []
        for d in devices:
            done = _current(outdir, d.name, hashes[d.name], retry_failed)
            if done is None:
                todo.append(d)
            else:
                report.entries[d.name] = done
                report.actions[d.name] = "skipped: current"
        if todo:
            _run(report, todo, contents, hashes, options, workers, scheduler, client, progress, say)
        _clean_leftovers(outdir)
        report.outliers = flag_outliers({d: report.entries[d].get("row") or {} for d in report.devices
                                         if report.entries[d]["status"] != "failed"})
        report.seconds = time.perf_counter() - started
        _write_summary(report)
    return report


def _run(report: BatchReport, todo: list[DeviceSpec], contents, hashes, options, workers, scheduler, client,
         progress: bool, say) -> None:
    distributed = _require_dask()
    with _client(client, scheduler, workers) as (c, dashboard):
        report.dashboard = dashboard
        if dashboard and say:
            say(f"dask dashboard: {dashboard}")
        futures = {}
        for d in todo:
            task = DeviceTask(d, contents[d.name], options, hashes[d.name])
            fut = c.submit(process_device, task, key=f"duhem-batch-{d.name}-{hashes[d.name][:16]}",
                           retries=RETRIES, pure=False)
            futures[fut] = d.name
        with _progress_bar(len(futures), progress) as advance:
            for fut in distributed.as_completed(list(futures)):
                name = futures[fut]
                try:
                    result = fut.result()
                except Exception as exc:   # noqa: BLE001 - a lost worker or an unexpected error: reported
                    report.entries[name] = {"status": "failed", "reason": _lost(exc), "row": {},
                                            "hash": hashes[name]}
                    report.actions[name] = "lost"
                    advance(f"{name} failed")
                    continue
                report.entries[name] = _write_device(report.outdir, result)
                report.actions[name] = "done" if result["status"] != "failed" else "failed"
                advance(f"{name} {result['status']}")


def _lost(exc: BaseException) -> str:
    """The summary's reason for a task that gave no result (nothing was written for it)."""
    if type(exc).__name__ == "KilledWorker":
        tries = exc.args[2] + 1 if len(exc.args) > 2 and isinstance(exc.args[2], int) else "several"
        return (f"the worker running it died on each of {tries} tries (killed, or out of memory?); "
                "nothing written, the next run tries again")
    return f"{_one_line(exc)} (after {RETRIES} retries; nothing written, the next run tries again)"
