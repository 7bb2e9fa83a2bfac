"""Co-simulation throughput of exported model FMUs, and of the in-process kernel.

For every FMU backend in `BACKENDS` (python, native FMI 2.0, native FMI 3.0),
and models of order 1-4 (rate independent and rate dependent):

* steps per second of the model FMU in fmpy's `FMU2Slave` loop, one step being
  ``setReal(u)``, ``getReal(y)``, ``doStep`` (the host of `fitter.fmu.host`);
  for FMI 3.0 fmpy's `FMU3Slave` with ``setFloat64``, ``getFloat64``, ``doStep``;
* the same for a trivial ``y = k u`` FMU built the same way, of the same FMI
  version (the per-step floor of host plus FMU wrapper), and the ratio model /
  trivial.
  Target: ratio >= 0.30 for the pythonfmu backend, order <= 4; >= 0.80 for the
  native (C) backend, FMI 2.0 and 3.0 (issue 35).

And samples per second of `fitter.core.simulate` on a 1e6-sample input
(target >= 1e6 for a rate-independent model of order <= 4).

Usage::

    python bench/fmu_throughput.py [--steps 20000] [--samples 1000000] [--repeats 5] [--json]
                                   [--backend python|native|native-fmi3 ...]

Every figure is the best of ``--repeats`` runs; the model and the trivial FMU
run alternately, so that load from other processes on a shared machine biases
the ratio as little as possible.

A backend is a `Backend(name, build_model, build_trivial, target)`; a native
backend is added by appending one to `BACKENDS`.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import build_fmu  # noqa: E402
from fitter.core import RateDependentModel, RateIndependentModel, TabulatedRate, simulate  # noqa: E402

KERNEL_TARGET = 1e6

GAIN_SLAVE = '''
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class GainSlave(Fmi2Slave):
    """y = k u, read directly (the same feedthrough as the model FMU)."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.modelName = "gain"
        self.u = 0.0
        self.k = 2.0
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("y", causality=Fmi2Causality.output,
                                    getter=lambda: self.k * self.u))
        self.register_variable(Real("k", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.fixed))

    def get_real(self, vrs):
        return [self.k * self.u if vr == 1 else (self.u if vr == 0 else self.k) for vr in vrs]

    def set_real(self, vrs, values):
        for vr, value in zip(vrs, values):
            if vr == 0:
                self.u = value
            else:
                self.k = value

    def do_step(self, current_time, step_size):
        return True
'''


def build_python_gain(out: Path) -> str:
    """The trivial y = k u FMU, built with pythonfmu like the model FMU."""
    from pythonfmu.builder import FmuBuilder

    with tempfile.TemporaryDirectory() as tmp:
        script = Path(tmp) / "gain_slave.py"
        script.write_text(GAIN_SLAVE, encoding="utf-8")
        saved = list(sys.path)
        try:
            built = FmuBuilder.build_FMU(script, dest=out)
        finally:
            sys.path[:] = saved
            sys.modules.pop("gain_slave", None)
    return str(built)


@dataclass
class Backend:
    name: str
    build_model: Callable[[object, Path], str]
    build_trivial: Callable[[Path], str]
    target: float


BACKENDS = [Backend("python", lambda m, p: build_fmu.build_fmu(m, p, backend="python"), build_python_gain, 0.30)]

# The native (C) backend: its trivial FMU is y = k u on the same C framework, compiled the
# same way (`fitter.fmu.native.build_gain_fmu`).  Target: ratio >= 0.80 (issue 35; 0.50 in issue 6).
from fitter.fmu.native import build_gain_fmu  # noqa: E402

BACKENDS.append(
    Backend("native", lambda m, p: build_fmu.build_fmu(m, p, backend="native"), lambda p: build_gain_fmu(p), 0.80)
)
# The same C model behind the FMI 3.0 framework, against the gain FMU of FMI 3.0 (issue 12).
BACKENDS.append(
    Backend(
        "native-fmi3",
        lambda m, p: build_fmu.build_fmu(m, p, backend="native", fmi_version=3),
        lambda p: build_gain_fmu(p, fmi_version=3),
        0.80,
    )
)


def stable_matrix(rng: np.random.Generator, n: int, decay: float) -> np.ndarray:
    """A random matrix with eigenvalues of real part <= -decay."""
    M = rng.standard_normal((n, n))
    return M - (np.max(np.linalg.eigvals(M).real) + decay) * np.eye(n)


def bench_model(kind: str, n: int) -> RateIndependentModel | RateDependentModel:
    rng = np.random.default_rng(100 * n + (kind == "rd"))
    C = rng.standard_normal(n)
    if kind == "ri":
        return RateIndependentModel(
            A_plus=stable_matrix(rng, n, 1.0),
            A_minus=-stable_matrix(rng, n, 1.0),
            B_plus=rng.standard_normal(n),
            B_minus=-rng.standard_normal(n),
            C=C,
            D=0.1,
        )
    nodes = np.geomspace(0.05, 10.0, 8)
    g = TabulatedRate(np.r_[-nodes[::-1], nodes], np.r_[-(nodes[::-1] ** 0.8), nodes**0.8])
    return RateDependentModel(A=stable_matrix(rng, n, 1.0), B=rng.standard_normal(n), C=C, g=g)


class LoopedFmu:
    """An initialised FMU2Slave (FMU3Slave) and the host loop: setReal(u) (setFloat64),
    getReal(y) (getFloat64), doStep."""

    def __init__(self, fmu_path: str):
        md = read_model_description(fmu_path)
        vr = {v.name: v.valueReference for v in md.modelVariables}
        self.unzipdir = extract(fmu_path)
        slave = FMU3Slave if md.fmiVersion == "3.0" else FMU2Slave
        self.fmu = slave(
            guid=md.guid,
            unzipDirectory=self.unzipdir,
            modelIdentifier=md.coSimulation.modelIdentifier,
            instanceName="bench",
        )
        self.fmu.instantiate()
        if slave is FMU3Slave:
            self.fmu.enterInitializationMode(startTime=0.0)
            self.set, self.get = self.fmu.setFloat64, self.fmu.getFloat64
        else:
            self.fmu.setupExperiment(startTime=0.0)
            self.fmu.enterInitializationMode()
            self.set, self.get = self.fmu.setReal, self.fmu.getReal
        self.fmu.exitInitializationMode()
        self.vu, self.vy = [vr["u"]], [vr["y"]]
        self.t = 0.0

    def steps_per_second(self, u: list[float], h: float) -> float:
        fmu, set_value, get_value, vu, vy, t = self.fmu, self.set, self.get, self.vu, self.vy, self.t
        start = time.perf_counter()
        for value in u:
            set_value(vu, [value])
            get_value(vy)
            fmu.doStep(t, h)
            t += h
        elapsed = time.perf_counter() - start
        self.t = t
        return len(u) / elapsed

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()
        shutil.rmtree(self.unzipdir, ignore_errors=True)


def paired_steps_per_second(model_fmu: str, trivial_fmu: str, steps: int, repeats: int) -> tuple[float, float]:
    """Best steps/s of the model and the trivial FMU, measured in alternating runs."""
    h = 0.01
    u = np.sin(2 * np.pi * 0.5 * h * np.arange(steps)).tolist()
    model, trivial = LoopedFmu(model_fmu), LoopedFmu(trivial_fmu)
    try:
        best_model = best_trivial = 0.0
        for _ in range(repeats):
            best_trivial = max(best_trivial, trivial.steps_per_second(u, h))
            best_model = max(best_model, model.steps_per_second(u, h))
    finally:
        model.close()
        trivial.close()
    return best_model, best_trivial


def kernel_samples_per_second(model, samples: int) -> float:
    t = np.arange(samples) * 1e-3
    u = np.sin(2 * np.pi * t) + 0.3 * np.sin(2 * np.pi * 3.7 * t)
    simulate(model, t[:1000], u[:1000])
    start = time.perf_counter()
    simulate(model, t, u)
    return samples / (time.perf_counter() - start)


def run(steps: int, samples: int, repeats: int, backends: list[str] | None = None) -> dict:
    """All figures; the trivial FMU is measured beside every model (shared, noisy machines)."""
    fmu_rows, kernel_rows = [], []
    with tempfile.TemporaryDirectory(prefix="duhem_bench_") as tmp:
        for backend in [b for b in BACKENDS if backends is None or b.name in backends]:
            gain = backend.build_trivial(Path(tmp) / f"gain_{backend.name}.fmu")
            for kind in ("ri", "rd"):
                for n in range(1, 5):
                    path = backend.build_model(bench_model(kind, n), Path(tmp) / f"{backend.name}_{kind}{n}.fmu")
                    rate, trivial = paired_steps_per_second(path, gain, steps, repeats)
                    fmu_rows.append(
                        {
                            "backend": backend.name,
                            "kind": kind,
                            "order": n,
                            "model_steps_per_s": rate,
                            "trivial_steps_per_s": trivial,
                            "ratio": rate / trivial,
                            "target": backend.target,
                            "meets_target": rate / trivial >= backend.target,
                        }
                    )
    for kind in ("ri", "rd"):
        for n in range(1, 5):
            rate = max(kernel_samples_per_second(bench_model(kind, n), samples) for _ in range(repeats))
            kernel_rows.append(
                {
                    "kind": kind,
                    "order": n,
                    "samples": samples,
                    "samples_per_s": rate,
                    "target": KERNEL_TARGET if kind == "ri" else None,
                    "meets_target": rate >= KERNEL_TARGET if kind == "ri" else None,
                }
            )
    return {"fmu": fmu_rows, "kernel": kernel_rows}


def print_table(result: dict) -> None:
    print(
        f"{'backend':11} {'kind':4} {'n':>2} {'model steps/s':>14} {'trivial steps/s':>16} {'ratio':>6} {'target':>6}"
    )
    for r in result["fmu"]:
        print(
            f"{r['backend']:11} {r['kind']:4} {r['order']:>2} {r['model_steps_per_s']:>14,.0f} "
            f"{r['trivial_steps_per_s']:>16,.0f} {r['ratio']:>6.2f} "
            f"{'ok' if r['meets_target'] else 'MISS':>6}"
        )
    print()
    print(f"{'kernel':8} {'kind':4} {'n':>2} {'samples/s':>14} {'target':>16}")
    for r in result["kernel"]:
        target = "-" if r["target"] is None else ("ok" if r["meets_target"] else "MISS")
        print(f"{'simulate':8} {r['kind']:4} {r['order']:>2} {r['samples_per_s']:>14,.0f} {target:>16}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=20000, help="co-simulation steps per run")
    parser.add_argument("--samples", type=int, default=1_000_000, help="kernel input length")
    parser.add_argument("--repeats", type=int, default=5, help="runs per figure (best is kept)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument(
        "--backend",
        dest="backends",
        action="append",
        choices=[b.name for b in BACKENDS],
        help="measure only this FMU backend (repeatable; default: all)",
    )
    args = parser.parse_args(argv)
    result = run(args.steps, args.samples, args.repeats, args.backends)
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print_table(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
