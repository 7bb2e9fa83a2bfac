"""Running the manifest on Dask (`run_batch`): what is done already, the client, retries, the devices'
outputs written on the client.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import shutil
import time
from pathlib import Path
from typing import Callable, Iterator

from fitter.batch.config import BATCH_FORMAT, DASK_MISSING, RETRIES, BatchError
from fitter.batch.device import DeviceTask, one_line, process_device
from fitter.batch.manifest import BatchOptions, DeviceSpec, input_hash, read_manifest
from fitter.batch.summary import BatchReport, flag_outliers, write_summary
from fitter.core.files import atomic_directory, json_text, output_lock
from fitter.fmu.model_description import package_version

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
    done.update(
        files={rel: len(data) for rel, data in result["files"].items()},
        package=package_version(),
        format=BATCH_FORMAT,
        written=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    )
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


# --------------------------------------------------------------------------- Dask


def _require_dask():
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise BatchError(DASK_MISSING) from None
    return distributed


SCHEDULER_PROBE = 3.0
"""Seconds a TCP connection to a ``tcp://`` scheduler address may take before the batch gives up on it (the
Dask client itself waits 20 s for its handshake: an address where nothing listens took 21 s to fail)."""


def _reachable(scheduler: str) -> None:
    """`BatchError` (one line) when the ``tcp://host:port`` of `scheduler` takes no TCP connection within
    `SCHEDULER_PROBE` seconds (refused at once where nothing listens); other protocols are left to the client."""
    import socket
    from urllib.parse import urlsplit

    address = urlsplit(scheduler if "://" in scheduler else f"tcp://{scheduler}")
    if address.scheme != "tcp" or not address.hostname:
        return
    try:
        port = address.port or 8786
        socket.create_connection((address.hostname, port), timeout=SCHEDULER_PROBE).close()
    except (OSError, ValueError) as exc:
        raise BatchError(
            f"cannot connect to the Dask scheduler {scheduler}: {one_line(exc) or type(exc).__name__}; start it "
            "(dask scheduler) or check the address, or leave out --scheduler to run on a local cluster"
        ) from None


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
            raise BatchError(f"cannot connect to the Dask scheduler {scheduler}: {one_line(exc)}") from None
        with c:
            yield c, _dashboard(c)
        return
    n = workers or os.cpu_count() or 1
    with (
        distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True) as cluster,
        distributed.Client(cluster) as c,
    ):
        link = _dashboard(c)
        if link and importlib.util.find_spec("bokeh") is None:
            link += " (the local dashboard needs bokeh: pip install bokeh)"
        yield c, link


def _dashboard(client) -> str | None:
    try:
        services = client.scheduler_info().get("services", {})
    except Exception:  # noqa: BLE001 - an old or remote scheduler: no link
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

    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task("duhem batch", total=total)

        def advance(text: str) -> None:
            bar.update(task, advance=1, description=f"duhem batch: {text}")

        yield advance


def run_batch(
    manifest: str | os.PathLike,
    outdir: str | os.PathLike,
    *,
    options: BatchOptions | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    client=None,
    retry_failed: bool = False,
    progress: bool = True,
    say: Callable[[str], None] | None = None,
) -> BatchReport:
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
        if scheduler:
            _reachable(scheduler)  # before anything is written
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
        report.outliers = flag_outliers(
            {d: report.entries[d].get("row") or {} for d in report.devices if report.entries[d]["status"] != "failed"}
        )
        report.seconds = time.perf_counter() - started
        write_summary(report)
    return report


def _run(
    report: BatchReport,
    todo: list[DeviceSpec],
    contents,
    hashes,
    options,
    workers,
    scheduler,
    client,
    progress: bool,
    say,
) -> None:
    distributed = _require_dask()
    with _client(client, scheduler, workers) as (c, dashboard):
        report.dashboard = dashboard
        if dashboard and say:
            say(f"dask dashboard: {dashboard}")
        futures = {}
        for d in todo:
            task = DeviceTask(d, contents[d.name], options, hashes[d.name])
            fut = c.submit(
                process_device, task, key=f"duhem-batch-{d.name}-{hashes[d.name][:16]}", retries=RETRIES, pure=False
            )
            futures[fut] = d.name
        with _progress_bar(len(futures), progress) as advance:
            for fut in distributed.as_completed(list(futures)):
                name = futures[fut]
                try:
                    result = fut.result()
                except Exception as exc:  # noqa: BLE001 - a lost worker or an unexpected error: reported
                    report.entries[name] = {"status": "failed", "reason": _lost(exc), "row": {}, "hash": hashes[name]}
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
        return (
            f"the worker running it died on each of {tries} tries (killed, or out of memory?); "
            "nothing written, the next run tries again"
        )
    return f"{one_line(exc)} (after {RETRIES} retries; nothing written, the next run tries again)"
