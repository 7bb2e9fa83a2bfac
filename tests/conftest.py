"""The suite's fixtures and environment (the reference models, inputs and noisy recordings are in `samples`).

Test modules request the session fixture `fmu_cache`,
which builds each (model, backend) FMU once per session, and `holder`, another process holding an
output's lock (`fitter.core.files.output_lock`).  The diagnosis' fits run in the test's own process
(``DUHEM_WORKERS=1``, `fitter.workers`); one test runs it on two processes and compares.
The modules of the longest tests (whole diagnoses and fits, 10-50 s each) are collected first
(`pytest_collection_modifyitems`), so that pytest-xdist's two workers end on short tests, not one on a long test
while the other waits; the eight longest are marked ``slow`` (`SLOW`), which `make test` leaves out and
`make test-slow` runs.
Native FMUs carry this machine's binary alone (``DUHEM_PLATFORMS=host``, `fitter.fmu.toolchain.PLATFORMS_ENV`)
unless a test asks for others: `tests/test_platforms.py` builds and checks every platform's.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from fmu_host import FmuCache

os.environ.setdefault("DUHEM_WORKERS", "1")  # the suite runs on pytest-xdist's workers already (one per core)
os.environ.setdefault("DUHEM_PLATFORMS", "host")  # native FMUs: this machine's binary; tests/test_platforms.py: all


LONG_MODULES = ("test_diagnose.py", "test_diagnose_joint.py", "test_generality.py", "test_file_gains.py")
"""The modules whose tests take longest (module docstring)."""


SLOW = (
    "test_diagnose_joint.py::test_a_drift_taken_in_part_by_a_relaxation_found_first_is_given_back",
    "test_diagnose.py::test_concealed_effect_is_the_first_finding[saturation]",
    "test_diagnose.py::test_default_base_on_clean_data_of_any_order_has_nothing_missing[3]",
    "test_diagnose.py::test_a_drift_on_an_order_three_base_is_not_hidden_behind_saturation",
    "test_diagnose.py::test_clean_bouc_wen_loops_are_explained",
    "test_generality.py::test_fit_on_a_fixed_draw[ri2-sine-2files-b]",
    "test_generality.py::test_diagnosis_on_a_clean_draw[ri4-multisine]",
    "test_exported.py::test_exported_fmu_reproduces_the_fit_on_measured_recordings[creep_T04_trapezoid_1400V_1200V_1400S]",
)
"""The longest tests (30-55 s each on two busy cores: whole diagnoses and fits), marked ``slow``: `make test` (the
CI's command, which must end within 10 minutes on a fresh clone) leaves them out, `make test-slow` runs them."""


def pytest_collection_modifyitems(items: list) -> None:
    """The tests of `LONG_MODULES` first, every module's order kept, and the `SLOW` ones marked (module docstring)."""
    items.sort(key=lambda item: item.path.name not in LONG_MODULES)
    for item in items:
        if f"{item.path.name}::{item.name}" in SLOW:
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session")
def fmu_cache(tmp_path_factory) -> FmuCache:
    """Every FMU the session needs, built once per (backend, model)."""
    return FmuCache(tmp_path_factory.mktemp("fmus"))


_HOLD = """import sys
from fitter.core.files import output_lock
with output_lock(sys.argv[1]):
    print("held", flush=True)
    sys.stdin.read()
"""


@pytest.fixture
def holder():
    """hold(path) -> pid: another process holds `output_lock(path)` until the test ends."""
    procs = []

    def hold(path: Path) -> int:
        proc = subprocess.Popen(
            [sys.executable, "-c", _HOLD, str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        procs.append(proc)
        assert proc.stdout.readline() == "held\n"
        return proc.pid

    yield hold
    for proc in procs:
        proc.communicate("")
