"""Issue 35's speed figures in one table, each as a ratio to its peer measured in the same run.

    python bench/speed_summary.py [--out out/bench/speed.md] [--skip-long] [--steps 20000] [--interactive]

Rows (each runs the other benches' own code, nothing is re-implemented here):

* **piezo, one model for the three triangle rates** with switching and a reference per record
  (`bench/real_data.py`'s piezo.best step, ``fit_recordings(..., effects=PIEZO_EFFECTS, held=PIEZO_HELD)``),
  wall time against the three classical models fitted to each record alone on the same records (Preisach,
  Prandtl-Ishlinskii, Bouc-Wen: `fitter.baselines`, the sum of their fits' times); target 30 s.  Skipped when
  ``../shared/data`` is absent.
* **answers in seconds** (issue 71): ``duhem fit examples/demo.csv`` as a fresh process (start-up and imports
  included), wall time against the Preisach model fitted to the same file (`fitter.baselines`); target 3 s or 10x
  the Preisach fit, whichever is larger.  ``duhem diagnose`` of the three piezo triangles as a fresh process against
  the three classical models fitted per record; target 60 s (skipped when ``../shared/data`` is absent).
* **the piezo base search on two processes** against the same on one (``fit_recordings`` without effects, orders
  1-4 of both kinds: the Jacobians' columns on the cores, `fitter.workers.evaluation_map`); the bench stops
  unless both give the same theta to the last digit.  Skipped when ``../shared/data`` is absent.
* **an effect fit on two processes** against the same fit on one (`bench/effect_fit_speed.py`'s experiment,
  ``DUHEM_WORKERS`` 2 and 1).
* **the native FMU** (FMI 2.0) of orders 1-4, rate independent, steps per second in fmpy's loop against the
  trivial ``y = k u`` FMU (`bench/fmu_throughput.py`, alternating runs, best of 5); target >= 0.8.
* **a long recording** (1e6 samples, `bench/long_recordings.py`): ``duhem fit`` on the whole file against the
  same on its first tenth, wall time and the NRMSE on the whole file; targets: score ratio <= 1.05, whole fit
  <= 120 s and <= 400 MB (``--skip-long`` leaves it out: about a minute and a 40 MB file).
* **the paper's reproduction** (`bench/reproduce_paper.py`: Examples 1-3 with the improved and the literal
  estimators, 20 noise seeds) against the paper's literal procedures alone (`bench/literal_paper.py`), each as a
  fresh process, alternating, median of 9 (the two are close, and one run's noise is a tenth); target <= 1.
  Beside it the improved estimator's identification time of Examples 2 and 3 against the paper-literal
  estimator's on the same records (`fitter.identification.rd_triangles`).

The table goes to stdout and, with ``--out``, to a Markdown file (``make bench`` writes ``out/bench/speed.md``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT.parent))
sys.path.insert(0, str(ROOT))

import effect_fit_speed  # noqa: E402
import fmu_throughput  # noqa: E402
import long_recordings  # noqa: E402
import real_data  # noqa: E402

from fitter.baselines import BASELINES  # noqa: E402
from fitter.data.recordings import load_recording  # noqa: E402
from fitter.identification.fit import fit_recordings  # noqa: E402
from fitter.identification.rd_triangles import identify_rd_triangles  # noqa: E402
from fitter.paper import example2, example3  # noqa: E402

Row = tuple[str, float, str, float, str]
"""(figure, seconds or rate, peer, the peer's, target): the ratio is the first over the second."""


def _timed(function, *args, **kwargs) -> float:
    """Wall seconds of function(*args, **kwargs)."""
    t0 = time.perf_counter()
    function(*args, **kwargs)
    return time.perf_counter() - t0


def piezo_rows() -> list[Row]:
    """piezo.best's fit against the classical models fitted per record (empty without the shared data)."""
    if not real_data.DATA.is_dir():
        return []
    recs = real_data.piezo_recordings()
    best = _timed(
        lambda: fit_recordings(list(recs.values()), effects=real_data.PIEZO_EFFECTS, held=real_data.PIEZO_HELD)
    )
    classical = sum(_timed(cls().fit, [rec]) for cls in BASELINES.values() for rec in recs.values())
    return [("piezo.best fit [s]", best, "Preisach + PI + Bouc-Wen per record [s]", classical, "<= 30 s")]


def _command_seconds(*args: str) -> float:
    """Wall seconds of ``duhem ARGS`` as a fresh process (start-up and imports included); its output discarded."""
    duhem = Path(sys.executable).with_name("duhem")
    t0 = time.perf_counter()
    subprocess.run([str(duhem), *args], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def interactive_rows() -> list[Row]:
    """Issue 71's interactive figures: the demo's fit against a Preisach fit of the same file, the piezo diagnosis
    against the classical models per record (that row only with the shared data)."""
    demo = ROOT.parent / "examples" / "demo.csv"
    preisach = _timed(BASELINES["preisach"]().fit, [load_recording(demo)])
    with tempfile.TemporaryDirectory() as tmp:
        fit = _command_seconds("fit", str(demo), "-o", str(Path(tmp) / "demo.json"))
        rows = [("duhem fit demo.csv, a process [s]", fit, "Preisach fit [s]", preisach, "<= max(3 s, 10x)")]
        if real_data.DATA.is_dir():
            recs = real_data.piezo_recordings()
            classical = sum(_timed(cls().fit, [rec]) for cls in BASELINES.values() for rec in recs.values())
            files = [str(real_data.DATA / "piezo-pnzt" / f"{stem}.csv") for stem in real_data.PIEZO.values()]
            columns = ["--time", "time_s", "--input", "voltage_V", "--output", "polarization_uC_per_cm2"]
            diagnose = _command_seconds("diagnose", *files, *columns, "--json", str(Path(tmp) / "d.json"))
            rows.append(
                ("duhem diagnose, piezo, a process [s]", diagnose, "classical per record [s]", classical, "<= 60 s")
            )
    return rows


def base_search_rows() -> list[Row]:
    """The piezo base search (``fit_recordings`` of the three rates, orders 1-4 of both kinds, no effects) on two
    processes against one: the Jacobians' columns on the cores (`fitter.workers.evaluation_map`); raises unless
    both give the same theta to the last digit (empty without the shared data)."""
    if not real_data.DATA.is_dir():
        return []
    recs, seconds, thetas = list(real_data.piezo_recordings().values()), {}, {}
    for n in ("1", "2"):
        os.environ["DUHEM_WORKERS"] = n
        t0 = time.perf_counter()
        thetas[n] = fit_recordings(recs).theta.tobytes()
        seconds[n] = time.perf_counter() - t0
    os.environ.pop("DUHEM_WORKERS")
    if thetas["1"] != thetas["2"]:
        raise RuntimeError("the piezo base search differs on two processes from one")
    return [("piezo base search, two processes [s]", seconds["2"], "one process [s]", seconds["1"], "< 1")]


def effect_fit_rows() -> list[Row]:
    """The switching fit of `effect_fit_speed` on two processes against one."""
    recs, seconds = effect_fit_speed.recordings(), {}
    for n in ("1", "2"):
        os.environ["DUHEM_WORKERS"] = n
        seconds[n] = effect_fit_speed.timed_fit(recs)[0]
    os.environ.pop("DUHEM_WORKERS")
    return [("effect fit, two processes [s]", seconds["2"], "one process [s]", seconds["1"], "< 1")]


def fmu_rows(steps: int) -> list[Row]:
    """Native FMI 2.0 FMUs of orders 1-4 against the trivial FMU, steps per second."""
    native = next(b for b in fmu_throughput.BACKENDS if b.name == "native")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        trivial = native.build_trivial(Path(tmp) / "trivial.fmu")
        for n in (1, 2, 3, 4):
            path = native.build_model(fmu_throughput.bench_model("ri", n), Path(tmp) / f"ri{n}.fmu")
            model, peer = fmu_throughput.paired_steps_per_second(path, trivial, steps, 5)
            rows.append((f"native FMU ri{n} [steps/s]", model, "trivial FMU [steps/s]", peer, ">= 0.8"))
    return rows


def long_rows() -> list[Row]:
    """The 1e6-sample fit on the whole file against its first tenth."""
    with tempfile.TemporaryDirectory() as tmp:
        r = long_recordings.measure(1_000_000, Path(tmp))
    whole, tenth = r["whole"], r["tenth"]
    return [
        ("1e6 samples: fit on the whole [s]", whole["seconds"], "on the first tenth [s]", tenth["seconds"], "<= 120 s"),
        ("  its NRMSE on the whole file", whole["nrmse"], "the tenth's model's", tenth["nrmse"], "<= 1.05"),
        ("  its peak memory [MB]", whole["peak_mb"], "the tenth's fit's [MB]", tenth["peak_mb"], "<= 400 MB"),
    ]


def _process_seconds(script: str) -> float:
    """Wall seconds of ``python bench/<script>`` as a fresh process (start-up and imports included)."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, str(ROOT / script)], check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def paper_rows(runs: int = 9) -> list[Row]:
    """`duhem reproduce-paper` against the paper's literal procedures (`bench/literal_paper.py`), each a fresh
    process, alternating, median of `runs`; and Examples 2 and 3 identified by the improved and by the
    literal estimator."""
    whole = {script: [] for script in ("reproduce_paper.py", "literal_paper.py")}
    for _ in range(runs):
        for script in whole:
            whole[script].append(_process_seconds(script))
    cases = ((example2.records(example2.NOISE_PP, 0), {}), (example3.records(), {"order": example3.ORDER}))
    seconds = {
        est: sum(_timed(identify_rd_triangles, recs, estimator=est, **kw) for recs, kw in cases)
        for est in ("improved", "literal")
    }
    reproduce, literal = (float(np.median(v)) for v in whole.values())
    return [
        ("paper reproduction, a process [s]", reproduce, "literal procedures, a process [s]", literal, "<= 1"),
        ("paper Ex. 2-3, improved estimator [s]", seconds["improved"], "literal [s]", seconds["literal"], "-"),
    ]


def table(rows: list[Row]) -> str:
    """The rows as a Markdown table with the ratio column."""
    lines = ["| figure | value | peer | peer's | ratio | target |", "|---|---|---|---|---|---|"]
    for figure, value, peer, other, target in rows:
        lines.append(f"| {figure} | {value:.4g} | {peer} | {other:.4g} | {value / other:.3g} | {target} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="also write the table to this Markdown file")
    parser.add_argument("--skip-long", action="store_true", help="leave out the 1e6-sample recording")
    parser.add_argument("--steps", type=int, default=20000, help="co-simulation steps per FMU run")
    parser.add_argument("--interactive", action="store_true", help="only the rows of answers in seconds (issue 71)")
    args = parser.parse_args()
    rows = interactive_rows()
    if not args.interactive:
        rows += piezo_rows() + base_search_rows() + effect_fit_rows() + fmu_rows(args.steps)
        rows += ([] if args.skip_long else long_rows()) + paper_rows()
    text = table(rows)
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
