"""`duhem batch` (fitter.batch): a manifest of devices, one task per device on a Dask LocalCluster.

Small generated devices (300 samples, first-order rate-independent fits) keep the module fast; one
LocalCluster of 2 worker processes serves the whole module, and the worker-kill test has its own.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from fitter.core.files import DIRECTORY_MARK
from click.testing import CliRunner

distributed = pytest.importorskip("distributed")

from fitter.batch import (  # noqa: E402
    BatchError,
    BatchOptions,
    DeviceTask,
    flag_outliers,
    input_hash,
    process_device,
    read_manifest,
    run_batch,
)
from fitter.cli import main  # noqa: E402
from fitter.core.kernel import simulate  # noqa: E402
from fitter.diagnosis.fitting import first_order_ri  # noqa: E402

OPTIONS = BatchOptions(kind="ri", order=1)
DEVICE_FILES = {
    "model.json",
    "fit.json",
    "model.fmu",
    "validation.json",
    "validation.png",
    "report/index.html",
    "done.json",
}


def device_csv(path: Path, a: float = 3.0, seed: int = 0, samples: int = 300) -> Path:
    """A first-order rate-independent device, branch rate `a` (A+ = -a, A- = a), on two triangle cycles."""
    m = first_order_ri(a_plus=-a, a_minus=a, b_plus=3.0, b_minus=-3.0, e_plus=-1.5, e_minus=-1.5, x0=-1 / 6)
    t = np.linspace(0.0, 4.0, samples)
    u = np.interp((t / 2.0) % 1.0, [0.0, 0.5, 1.0], [-1.0, 1.0, -1.0])
    y = simulate(m, t, u).y + np.random.default_rng(seed).normal(0.0, 0.003, samples)
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="time,u_V,y_um", comments="", fmt="%.12g")
    return path


def write_manifest(directory: Path, rows: list[dict], name: str = "manifest.csv") -> Path:
    path = directory / name
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return path


def make_batch(directory: Path, rates=(3.0, 3.1, 2.9, 3.05, 2.95), bad: bool = True) -> Path:
    """Devices dev1.. with branch rates `rates`, plus (bad) one whose recording has a non-numeric cell."""
    data = directory / "data"
    data.mkdir(parents=True)
    rows = []
    for i, a in enumerate(rates, start=1):
        device_csv(data / f"dev{i}.csv", a=a, seed=i)
        rows.append({"device": f"dev{i}", "recordings": f"data/dev{i}.csv", "input": "u", "output": "y"})
    if bad:
        (data / "broken.csv").write_text("time,u_V,y_um\n0,0,0\n1,oops,1\n2,1,2\n3,0,1\n")
        rows.append({"device": "broken", "recordings": "data/broken.csv", "input": "u", "output": "y"})
    return write_manifest(directory, rows)


def files_of(directory: Path) -> dict[str, float]:
    """Every file under `directory` with its mtime (ns)."""
    return {str(p.relative_to(directory)): p.stat().st_mtime_ns for p in sorted(directory.rglob("*")) if p.is_file()}


def no_temporaries(outdir: Path) -> bool:
    return not [p for p in outdir.rglob("*") if p.name.startswith((".tmp-", ".old-"))]


@pytest.fixture(scope="module")
def client():
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster,
        distributed.Client(cluster) as c,
    ):
        yield c


@pytest.fixture(scope="module")
def first_run(tmp_path_factory, client):
    """Four devices (dev4 with branch rates twice the others') and a bad one, run once."""
    root = tmp_path_factory.mktemp("batch")
    manifest = make_batch(root, rates=(3.0, 3.08, 2.93, 6.0))
    report = run_batch(manifest, root / "out", options=OPTIONS, client=client, progress=False)
    return root, manifest, report


def read_summary(outdir: Path) -> dict[str, dict]:
    with open(outdir / "summary.csv", newline="") as fh:
        return {r["device"]: r for r in csv.DictReader(fh)}


# --------------------------------------------------------------------------- (a) a batch with a bad device


def test_batch_completes_and_reports_the_bad_device(first_run):
    root, _, report = first_run
    out = root / "out"
    summary = read_summary(out)
    assert list(summary) == ["dev1", "dev2", "dev3", "dev4", "broken"]
    assert summary["broken"]["status"] == "failed"
    assert "line 3" in summary["broken"]["reason"] and "'oops'" in summary["broken"]["reason"]
    assert "data/broken.csv" in summary["broken"]["reason"]  # the manifest's name, not a scratch path
    for d in ("dev1", "dev2", "dev3", "dev4"):
        assert summary[d]["status"] == "ok", summary[d]
        assert summary[d]["kind"] == "ri" and summary[d]["order"] == "1"
        assert float(summary[d]["nrmse"]) < 0.01
        assert DEVICE_FILES <= set(files_of(out / d))
        done = json.loads((out / d / "done.json").read_text())
        assert done["status"] == "ok" and len(done["hash"]) == 64
        assert all((out / d / rel).stat().st_size == size for rel, size in done["files"].items())
        assert float(summary[d]["A_plus[0,0] stderr"]) > 0
    assert set(files_of(out / "broken")) == {"done.json", DIRECTORY_MARK}
    assert {"summary.csv", "summary.json", "index.html"} <= set(os.listdir(out))
    assert "broken" in (out / "index.html").read_text()
    assert report.actions == {**{f"dev{i}": "done" for i in range(1, 5)}, "broken": "failed"}
    assert no_temporaries(out)


def test_device_task_with_diagnosis(tmp_path):
    """The worker's function alone (no Dask): with diagnose (and the python backend, quicker to build), the
    diagnosis files and verdict come back."""
    manifest = make_batch(tmp_path, rates=(3.0,), bad=False)
    (d,) = read_manifest(manifest)
    data = [Path(p).read_bytes() for p in d.paths]
    options = BatchOptions(kind="ri", order=1, diagnose=True, backend="python")
    result = process_device(DeviceTask(d, data, options, input_hash(d, data, options)))
    assert result["status"] == "ok", result["reason"]
    assert {"diagnosis.json", "diagnosis/index.html"} | DEVICE_FILES - {"done.json"} <= set(result["files"])
    assert result["row"]["diagnosis"]["verdict"] in ("nothing_missing", "effects_found", "unexplained")
    assert set(result["row"]["timings"]) == {"fit", "fmu", "validation", "report", "diagnosis"}


def test_device_task_passes_faithful_minor_loops_to_the_fit(tmp_path):
    """The worker's function alone: with faithful_minor_loops the fit carries the barrier (its model file
    records it), without it not."""
    manifest = make_batch(tmp_path, rates=(3.0,), bad=False)
    (d,) = read_manifest(manifest)
    data = [Path(p).read_bytes() for p in d.paths]
    for faithful in (False, True):
        options = BatchOptions(kind="ri", order=2, backend="python", faithful_minor_loops=faithful)
        result = process_device(DeviceTask(d, data, options, input_hash(d, data, options)))
        assert result["status"] == "ok", result["reason"]
        model = json.loads(result["files"]["model.json"])
        assert model["fit_info"]["minor_loops"]["constrained"] is faithful


def test_device_task_fits_the_named_effects_with_the_base(tmp_path):
    """The worker's function alone: with effects=("creep",) the saved model carries creep, fitted jointly (the
    fit summary's effects), as duhem fit --effects does."""
    manifest = make_batch(tmp_path, rates=(3.0,), bad=False)
    (d,) = read_manifest(manifest)
    data = [Path(p).read_bytes() for p in d.paths]
    options = BatchOptions(kind="ri", order=1, backend="python", effects=("creep",), held=(("creep.tau", 7.5),))
    result = process_device(DeviceTask(d, data, options, input_hash(d, data, options)))
    assert result["status"] == "ok", result["reason"]
    (creep,) = json.loads(result["files"]["model.json"])["effects"]
    assert creep["effect"] == "creep" and creep["parameters"]["tau"] == 7.5
    fit = json.loads(result["files"]["fit.json"])
    assert [e["effect"] for e in fit["effects"]["fitted"]] == ["creep"]
    assert fit["effects"]["held"] == {"creep.tau": 7.5}
    assert input_hash(d, data, options) != input_hash(d, data, BatchOptions(kind="ri", order=1, backend="python"))
    assert input_hash(d, data, options) != input_hash(
        d, data, BatchOptions(kind="ri", order=1, backend="python", effects=("creep",))
    )


@pytest.mark.parametrize(
    "options, needle",
    [
        ({"effects": ("nope",)}, "unknown effect 'nope'"),
        ({"effects": ("creep",), "held": (("creep.tau", -1.0),)}, "held parameter 'creep.tau' = -1"),
        ({"held": (("creep.tau", 1.0),)}, "not one of the fitted effects"),
    ],
)
def test_batch_options_refuse_bad_effects(options, needle):
    with pytest.raises(BatchError, match=needle):
        BatchOptions(**options)


def test_batch_cli_names_a_bad_held_parameter(tmp_path):
    manifest = make_batch(tmp_path, rates=(3.0,), bad=False)
    result = CliRunner().invoke(
        main, ["batch", str(manifest), "-o", str(tmp_path / "out"), "--effects", "creep", "--hold", "creep.tau=-1"]
    )
    assert result.exit_code != 0 and "held parameter 'creep.tau' = -1 must be" in result.output
    assert not (tmp_path / "out").exists()


def test_batch_cli_names_an_unknown_effect(tmp_path):
    manifest = make_batch(tmp_path, rates=(3.0,), bad=False)
    result = CliRunner().invoke(main, ["batch", str(manifest), "-o", str(tmp_path / "out"), "--effects", "nope"])
    assert result.exit_code == 1 and result.stderr.startswith("error: duhem batch: --effects: unknown effect 'nope'")
    assert not (tmp_path / "out").exists()


def test_a_scheduler_where_nothing_listens_is_one_line(tmp_path):
    """A TCP address that takes no connection (a port nothing listens on) is refused by the probe, naming the
    address and what to do, before the Dask client's own 20 s handshake wait; nothing is written."""
    import socket

    with socket.socket() as s:  # a free port, closed again: nothing listens there
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    manifest = make_batch(tmp_path, rates=(3.0,), bad=False)
    address = f"tcp://127.0.0.1:{port}"
    result = CliRunner().invoke(main, ["batch", str(manifest), "-o", str(tmp_path / "out"), "--scheduler", address])
    assert result.exit_code == 1, result.output
    assert result.stderr.startswith(f"error: cannot connect to the Dask scheduler {address}: ")
    assert "leave out --scheduler" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_a_second_batch_into_the_same_outdir_fails_naming_the_first(tmp_path, holder):
    """The batch holds `output_lock(OUTDIR)`, the one lock of every output: a second writer gives one line naming
    OUTDIR and the holder's pid, exit 1, and writes nothing."""
    manifest = make_batch(tmp_path, rates=(3.0,), bad=False)
    out = tmp_path / "out"
    out.mkdir()
    pid = holder(out)
    result = CliRunner().invoke(main, ["batch", str(manifest), "-o", str(out)], env={"DUHEM_LOCK_WAIT": "0"})
    assert result.exit_code == 1 and result.stderr.startswith(
        f"error: {out}: another process is writing it (pid {pid}: "
    )
    assert len(result.stderr.splitlines()) == 1 and os.listdir(out) == []


# --------------------------------------------------------------------------- (e) outliers


def test_outlier_flagged(first_run):
    root, _, report = first_run
    summary = read_summary(root / "out")
    assert "A_plus[0,0]" in summary["dev4"]["outliers"]
    assert all(summary[d]["outliers"] == "" for d in ("dev1", "dev2", "dev3"))
    assert set(report.outliers) == {"dev4"}
    assert "class='outlier'" in (root / "out" / "index.html").read_text()


def test_outlier_rule():
    rows = {
        f"d{i}": {"kind": "ri", "order": 1, "parameters": {"a": {"value": v}, "b": {"value": 1.0}}}
        for i, v in enumerate([1.0, 1.02, 0.98, 1.01, 0.99, 1.6])
    }
    flags = flag_outliers(rows)
    assert list(flags) == ["d5"] and flags["d5"][0]["parameter"] == "a" and flags["d5"][0]["z"] > 3.5
    assert flag_outliers(dict(list(rows.items())[-3:])) == {}  # fewer than MIN_GROUP devices: no rule


# --------------------------------------------------------------------------- (b), (c) re-runs


def test_second_run_does_no_work(first_run, client, monkeypatch):
    root, manifest, _ = first_run
    out = root / "out"
    before = files_of(out)
    import fitter.batch.scheduling

    def refuse(*args, **kwargs):
        raise AssertionError("a current device was submitted")

    monkeypatch.setattr(fitter.batch.scheduling, "_run", refuse)  # no cluster, no task
    report = run_batch(manifest, out, options=OPTIONS, client=client, progress=False)
    assert set(report.actions.values()) == {"skipped: current"}
    assert files_of(out) == before  # no file written, not even the summary
    result = CliRunner().invoke(
        main, ["batch", str(manifest), "-o", str(out), "--kind", "ri", "--order", "1", "--json"]
    )  # the same options from the command line
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert [d["action"] for d in data["devices"]] == ["skipped: current"] * 5
    assert data["counts"] == {"ok": 4, "failed": 1} and data["dashboard"] is None
    assert files_of(out) == before


def test_changed_input_reruns_only_that_device(first_run, client, tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(first_run[0], root)  # a copied tree stays current
    out = root / "out"
    before = files_of(out)
    device_csv(root / "data" / "dev2.csv", a=3.08, seed=99)
    report = run_batch(root / "manifest.csv", out, options=OPTIONS, client=client, progress=False)
    assert report.actions == {
        **{f"dev{i}": "skipped: current" for i in (1, 3, 4)},
        "dev2": "done",
        "broken": "skipped: current",
    }
    after = files_of(out)
    changed = {k for k in before if before[k] != after.get(k)}
    assert changed and all(k.startswith("dev2/") or k in ("summary.csv", "summary.json", "index.html") for k in changed)
    assert no_temporaries(out)


def test_input_hash_covers_options_columns_and_contents(tmp_path):
    manifest = make_batch(tmp_path, rates=(3.0,), bad=False)
    (d,) = read_manifest(manifest)
    data = [Path(p).read_bytes() for p in d.paths]
    h = input_hash(d, data, OPTIONS)
    assert h == input_hash(d, [bytes(b) for b in data], BatchOptions(kind="ri", order=1))
    assert h != input_hash(d, data, BatchOptions(kind="ri", order=1, threshold=0.04))
    assert h != input_hash(d, data, BatchOptions(kind="ri", order=1, diagnose=True))
    assert h != input_hash(d, data, BatchOptions(kind="ri", order=1, faithful_minor_loops=True))
    assert h != input_hash(dataclasses.replace(d, input_unit="V"), data, OPTIONS)
    assert h != input_hash(d, [data[0] + b"\n"], OPTIONS)


# --------------------------------------------------------------------------- bad manifests, no dask


@pytest.mark.parametrize(
    "rows, needle",
    [
        ([{"device": "a", "recording": "data/dev1.csv"}], "unknown column 'recording'"),
        ([{"device": "a"}], "no column 'recordings'"),
        (
            [{"device": "a", "recordings": "data/missing.csv"}],
            "line 2: device 'a': recording 'data/missing.csv': no such file",
        ),
        (
            [{"device": "a", "recordings": "data/dev1.csv"}, {"device": "A", "recordings": "data/dev1.csv"}],
            "line 3: device 'A' appears twice (also on line 2)",
        ),
        ([{"device": "../x", "recordings": "data/dev1.csv"}], "line 2: device name '../x' is not a safe directory"),
        ([{"device": "index.html", "recordings": "data/dev1.csv"}], "device name 'index.html' is not a safe"),
    ],
)
def test_bad_manifest_is_one_line_and_writes_nothing(tmp_path, rows, needle):
    (tmp_path / "data").mkdir()
    device_csv(tmp_path / "data" / "dev1.csv")
    manifest = write_manifest(tmp_path, rows)
    before = set(os.listdir(tmp_path))
    result = CliRunner().invoke(main, ["batch", str(manifest), "-o", str(tmp_path / "out")])
    assert result.exit_code == 1, result.output
    assert needle in result.output and str(manifest) in result.output
    assert result.output.startswith("error: ") and result.output.count("\n") == 1
    assert set(os.listdir(tmp_path)) == before


def test_read_manifest_columns_and_units(tmp_path):
    (tmp_path / "data").mkdir()
    device_csv(tmp_path / "data" / "r1.csv")
    device_csv(tmp_path / "data" / "r2.csv")
    manifest = write_manifest(
        tmp_path,
        [
            {
                "device": "d",
                "recordings": "data/r1.csv; data/r2.csv",
                "time": "none",
                "input": "1",
                "output": "",
                "input_unit": "kV",
                "output_unit": "",
            }
        ],
    )
    (d,) = read_manifest(manifest)
    assert d.recordings == ("data/r1.csv", "data/r2.csv") and d.time is None and d.input == "1"
    assert d.output == "y" and d.input_unit == "kV" and d.output_unit is None


def test_without_dask_says_what_to_install(tmp_path, monkeypatch):
    manifest = make_batch(tmp_path, rates=(3.0,), bad=False)
    monkeypatch.setitem(__import__("sys").modules, "distributed", None)
    result = CliRunner().invoke(main, ["batch", str(manifest), "-o", str(tmp_path / "out")])
    assert result.exit_code == 1
    assert "pip install 'semilinear-duhem[batch]'" in result.output


# --------------------------------------------------------------------------- (d) a worker killed mid-batch


def test_worker_killed_during_batch(tmp_path, client):
    """SIGKILL a worker while it runs a device (the last test of the module: the shared cluster's nanny
    starts a new worker); the scheduler runs the task again, every device ends complete, nothing is left."""
    manifest = make_batch(tmp_path, rates=(3.0, 3.1), bad=False)
    out = tmp_path / "out"
    pids = client.run(os.getpid)
    result, killed = {}, {}
    thread = threading.Thread(
        target=lambda: result.update(report=run_batch(manifest, out, options=OPTIONS, client=client, progress=False))
    )
    thread.start()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not killed:
        busy = {w: [k for k in keys if str(k).startswith("duhem-batch-")] for w, keys in client.processing().items()}
        busy = {w: keys for w, keys in busy.items() if keys and w in pids}
        if busy:
            time.sleep(0.5)  # the task is under way: kill its worker
            worker, keys = next(iter(busy.items()))
            os.kill(pids[worker], signal.SIGKILL)
            killed[worker] = keys
        time.sleep(0.05)
    thread.join(180)
    assert killed, "no device task was seen running"
    assert not thread.is_alive()
    assert not set(killed) & set(client.run(os.getpid))  # that worker is gone
    report = result["report"]
    assert report.actions == {"dev1": "done", "dev2": "done"}
    assert all(report.entries[d]["status"] == "ok" for d in report.devices), report.entries
    for d in report.devices:
        assert DEVICE_FILES <= set(files_of(out / d))
        done = json.loads((out / d / "done.json").read_text())
        assert all((out / d / rel).stat().st_size == size for rel, size in done["files"].items())
    assert no_temporaries(out)
    assert set(os.listdir(out)) == {"dev1", "dev2", "summary.csv", "summary.json", "index.html"}


def test_device_task_refuses_an_output_that_is_noise(tmp_path):
    """The worker's function alone: a device whose output is seeded white noise beside its input is ``failed``
    with the fit's own reason (R^2 of the model below 0.5), and no model, FMU or report comes back; `duhem
    batch` used to save such a model and call the device "ok"."""
    manifest = make_batch(tmp_path, rates=(3.0,), bad=False)
    (d,) = read_manifest(manifest)
    t = np.linspace(0.0, 20.0, 801)
    noise = np.random.default_rng(9).standard_normal(len(t))
    noise[400] += 8.0  # one spike, as in the audit's file
    np.savetxt(d.paths[0], np.column_stack([t, np.sin(t), noise]), delimiter=",", header="time,u,y", comments="")
    data = [Path(p).read_bytes() for p in d.paths]
    options = BatchOptions(kind="auto", backend="python")
    result = process_device(DeviceTask(d, data, options, input_hash(d, data, options)))
    assert result["status"] == "failed"
    assert "of the output's variance" in result["reason"] and "no model written" in result["reason"]
    assert not {"model.json", "model.fmu"} & set(result.get("files") or {})
