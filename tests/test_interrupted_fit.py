"""`duhem fit -o m.json --fmu m.fmu` killed with SIGKILL at many points (issue 15): whatever the moment, the next
reader of m.json finds the old pair or the new one, never a model beside an FMU of another fit, and the next run
leaves no temporary behind.

The kill points: by a hook in the writer (`fitter.core.files.PUBLISH_HOOK`) just before the FMU is renamed into
place and just before the JSON is (between the two renames), and at several moments of a run by the clock.
"""

import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from samples import noisy_recording, ri_model, sine_input
from fitter.core import load_model
from fitter.core.files import file_digest
from fitter.fmu.pair import check_fmu_pair

DRIVER = """
import os, signal, sys
from pathlib import Path
import fitter.core.files as files
kill_before = sys.argv.pop(1)
def hook(target):
    if Path(target).name == kill_before:
        os.kill(os.getpid(), signal.SIGKILL)
files.PUBLISH_HOOK = hook
sys.argv[0] = "duhem"
from fitter.cli import main
main()
"""


def _csv(path: Path, amplitude: float, seed: int) -> Path:
    t, u = sine_input(1.0, 3, 80, amplitude=amplitude)
    rec = noisy_recording(ri_model(1), t, u, noise=0.01, seed=seed)
    np.savetxt(path, np.column_stack([rec.t, rec.u, rec.y]), delimiter=",", header="time,u,y", comments="")
    return path


def _fit(tmp: Path, data: Path, kill_before: str = "-", after: float | None = None) -> int:
    """Run the fit in a subprocess; SIGKILL it before renaming `kill_before`, or `after` seconds."""
    args = [
        sys.executable,
        "-c",
        DRIVER,
        kill_before,
        "fit",
        str(data),
        "-o",
        str(tmp / "m.json"),
        "--fmu",
        str(tmp / "m.fmu"),
        "--kind",
        "ri",
        "--order",
        "1",
    ]
    proc = subprocess.Popen(
        args,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1])},
    )
    if after is not None:
        time.sleep(after)
        proc.send_signal(signal.SIGKILL)
    return proc.wait(timeout=300)


def _pair(tmp: Path) -> str:
    """Read the pair as every command does (recovery first); the model digest both agree on."""
    model = load_model(tmp / "m.json")
    assert check_fmu_pair(tmp / "m.json", model) is None
    assert file_digest(tmp / "m.fmu") == model.fit_info["fmu"]["sha256"]
    with zipfile.ZipFile(tmp / "m.fmu") as z:
        in_fmu = json.loads(z.read("resources/model.json"))
    mine = model.to_dict()
    del mine["fit_info"]["fmu"]
    assert in_fmu["parameters"] == mine["parameters"]
    return json.dumps(mine["parameters"], sort_keys=True)


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    """The old pair (data A: its files' bytes) and the new pair (data B) as complete runs write them."""
    tmp = tmp_path_factory.mktemp("pairs")
    a, b = _csv(tmp / "a.csv", 1.0, 1), _csv(tmp / "b.csv", 0.6, 2)
    assert _fit(tmp, a) == 0
    old = {name: (tmp / name).read_bytes() for name in ("m.json", "m.fmu")}
    start = time.perf_counter()
    assert _fit(tmp, b) == 0
    return {"old": old, "new": _pair(tmp), "seconds": time.perf_counter() - start, "b": b}


def _old_pair(tmp: Path, pairs) -> str:
    for name, data in pairs["old"].items():
        (tmp / name).write_bytes(data)
    return _pair(tmp)


@pytest.mark.parametrize("point", ["m.fmu", "m.json"])
def test_a_fit_killed_at_either_rename_leaves_the_old_pair_and_the_next_run_cleans_up(tmp_path, pairs, point):
    old = _old_pair(tmp_path, pairs)
    assert _fit(tmp_path, pairs["b"], kill_before=point) == -signal.SIGKILL
    assert len(list(tmp_path.glob(".*"))) >= 1  # the killed run left its temporaries
    assert _pair(tmp_path) == old  # killed before the JSON's rename: the old pair stands
    assert _fit(tmp_path, pairs["b"]) == 0  # the next run on the same outputs completes and cleans up
    assert _pair(tmp_path) == pairs["new"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.fmu", "m.json"]


@pytest.mark.parametrize("fraction", [0.5, 0.8, 0.95])
def test_a_fit_killed_by_the_clock_leaves_the_old_pair_or_the_new_one(tmp_path, pairs, fraction):
    old = _old_pair(tmp_path, pairs)
    _fit(tmp_path, pairs["b"], after=fraction * pairs["seconds"])
    assert _pair(tmp_path) in (old, pairs["new"])
