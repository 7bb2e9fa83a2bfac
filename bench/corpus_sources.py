"""The sources of `bench/corpus.py`: public *measured* hysteresis recordings on GitHub, where each lives, under which
licence, and how its raw files become `time,u,y` CSV files.

Nothing here is copied into this repository: the raw files are read at run time from ``--data DIR``, which holds the
fetched repositories' files at their own paths, ``DIR/<owner>+<name>/<path>``.  To get them::

    git clone https://github.com/<owner>/<name> DIR/<owner>+<name>
    git -C DIR/<owner>+<name> checkout <commit>

(`python bench/corpus.py --sources` prints these two lines for every source.)  A source without a licence file at
its commit is "all rights reserved": it may be fetched by the user and read at run time, never redistributed.

Each converter returns ``[(recording name, t, u, y)]`` in the source's own units (listed in `SOURCES`) and raises
`MissingData` when a raw file is absent.  Where a file has no time column a uniform one is built and the source says
so (`built_time`); a rate-independent fit depends only on the input's path, but rate-dependent candidates and the
diagnosis' rate and creep tests then see an invented clock.  Long records are decimated (every k-th sample, after
the source's own anti-aliasing) so that the whole bench stays near an hour on two cores; the factor is in `notes`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np


class MissingData(Exception):
    """A raw file of a source is not under --data DIR."""


@dataclass(frozen=True)
class Source:
    name: str  # the set's name in the table and for --sets
    repo: str  # owner/name on GitHub
    commit: str  # the commit the paths and the licence were read at
    paths: tuple[str, ...]  # raw files inside the repository
    licence: str  # the LICENSE file at that commit, or "none (all rights reserved)"
    system: str  # what was measured
    u: str  # input, with unit
    y: str  # output, with unit
    sampling: str
    convert: Callable[[Path], list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]] = field(repr=False)
    built_time: bool = False
    notes: str = ""

    @property
    def local(self) -> str:
        return self.repo.replace("/", "+")

    def raw(self, data: Path, path: str) -> Path:
        p = data / self.local / path
        if not p.is_file():
            raise MissingData(f"{p} (from {self.repo}@{self.commit[:10]}:{path})")
        return p

    def fetch_lines(self) -> str:
        d = f"DIR/{self.local}"
        return f"git clone https://github.com/{self.repo} {d} && git -C {d} checkout {self.commit}"


# ---------------------------------------------------------------- helpers


def _lines(p: Path, encoding: str = "utf-8") -> list[str]:
    """Lines of a text file whatever its line ends (CR alone included)."""
    return [s for s in re.split(r"\r\n|\r|\n", p.read_bytes().decode(encoding, errors="replace")) if s.strip()]


def _table(p: Path, sep: str | None, skip: int = 0, cols: int | None = None) -> np.ndarray:
    rows = []
    for s in _lines(p)[skip:]:
        cells = [c.strip().strip('"') for c in (s.split(sep) if sep else s.split())]
        if cols is not None:
            cells = cells[:cols]
        try:
            rows.append([float(c) if c != "" else np.nan for c in cells])
        except ValueError:
            continue  # a header or unit line
    width = max(len(r) for r in rows)
    return np.array([r + [np.nan] * (width - len(r)) for r in rows], dtype=float)


def _uniform_time(n: int, dt: float = 1.0) -> np.ndarray:
    return np.arange(n, dtype=float) * dt


# ---------------------------------------------------------------- converters


def _piezo_sindy(src: Source, data: Path):
    # columns: (empty index), time [s], displacement [um], voltage [V]; 5 kHz, 10 s; a 1 Hz 150 V sine after a rest
    a = _table(src.raw(data, src.paths[0]), ",")
    t, y, u = a[:, 1], a[:, 2], a[:, 3]
    k = 5  # 5 kHz -> 1 kHz: 1000 samples a cycle
    return [("piezo_150V_1Hz", t[::k], u[::k], y[::k])]


def _ferrite_no27(src: Source, data: Path):
    # columns: H [A/m], B [T]; 999 samples of one period of a sinusoidal B (B-controlled measurement: B is the input);
    # no time column: one period is taken as 10 s, as the source's own script does (t = linspace(0, 10, 1000))
    a = _table(src.raw(data, src.paths[0]), None)
    n = len(a)
    return [("no27_B_sine", np.linspace(0.0, 10.0, n), a[:, 1], a[:, 0])]


def _mr_damper(src: Source, data: Path):
    # columns "t","A","D","Y","fs","V","F": time [s], actuator acceleration, damper displacement [cm], voltage to the
    # damper's current driver [V] (random, 0-2.25 V: a second input the single-input model does not see), sampling
    # rate, velocity [cm/s], force [N]; fs = 3004.8 Hz, 100 Hz anti-aliasing filters
    out = []
    for path, name in zip(src.paths, ("ranran_50", "ransim_u")):
        a = _table(src.raw(data, path), ",", skip=1)
        k = 3  # 3 kHz -> 1 kHz (the channels are filtered at 100 Hz)
        out.append((name, a[::k, 0], a[::k, 2], a[::k, 6]))
    return out


def _vhb4910(src: Source, data: Path):
    # two header lines in GBK (time, displacement, force / (s),(mm),(N)), quoted numbers; 50 Hz; one loading-unloading
    # to stretch 2 (80 mm) at 0.08, 0.24 and 0.40 cm/s, and a repeat of the middle rate
    out = []
    for path in src.paths:
        a = _table(src.raw(data, path), ",", skip=2)
        out.append((Path(path).stem, a[:, 0], a[:, 1], a[:, 2]))
    return out


def _microwire_bh(src: Source, data: Path):
    # two columns, no header: pickup-coil voltage (proportional to dB/dt) and the excitation field's sinusoid (H, in
    # oscilloscope volts); the source's BH.py integrates the first (trapezoid, with an offset correction).  Here: the
    # pickup's mean over the whole periods the file holds (2 or 3 of the nominal frequency) is removed, it is
    # integrated (trapezoid), and the linear drift a residual offset leaves is removed so that B returns to its start
    # after those periods, centred on 0 over them; B in V*s (unscaled).  dt from the repository's README, the
    # frequency from the file name.
    dts = {"50kHz": 5e-8, "100kHz": 2e-8, "200kHz": 1e-8, "250kHz": 1e-8}
    out = []
    for path in src.paths:
        stem = Path(path).stem
        a = _table(src.raw(data, path), ",")
        n, dt = len(a), dts[stem]
        t = _uniform_time(n, dt)
        m = int(int(n * dt * float(stem[:-3]) * 1e3) / (float(stem[:-3]) * 1e3 * dt))  # samples in whole periods
        e = a[:, 0] - np.mean(a[:m, 0])
        b = np.concatenate([[0.0], np.cumsum(0.5 * (e[1:] + e[:-1]) * dt)])
        b -= b[m - 1] * np.arange(n) / (m - 1)
        b -= np.mean(b[:m])  # the integration constant is unknown: a symmetric drive gives a loop centred on 0
        out.append((f"wire_{stem}", t, a[:, 1], b))
    return out


def _rc_column(src: Source, data: Path):
    # MATLAB v5 file, variable data_exp (481 x 2): lateral displacement [m], lateral load [g] (the source's axis
    # labels); a quasi-static cyclic test, no time: one sample a second is built
    from scipy.io import loadmat

    a = np.asarray(loadmat(str(src.raw(data, src.paths[0])))["data_exp"], dtype=float)
    return [("gill_park_priestley_col1", _uniform_time(len(a)), a[:, 0], a[:, 1])]


def _timber_wall(src: Source, data: Path):
    # two columns, no header: top displacement [m], base shear [N] (the source's example divides by 1000 for kN);
    # a quasi-static cyclic protocol to 4 % drift, 9281 samples, no time: one sample a second is built
    a = _table(src.raw(data, src.paths[0]), ",")
    return [("ganey_TS1", _uniform_time(len(a)), a[:, 0], a[:, 1] / 1000.0)]


def _sma_wire(src: Source, data: Path):
    # tab-separated, CR line ends, no header: a flag (0 / 1e-5 alternating), length-sensor signal [V, raw], water
    # temperature near the wire's front and end [degC]; 10 samples a second (the source's scripts: t = 0.1 s a row).
    # The wire (NiTi, with a return spring) is heated and cooled by the water: input = mean water temperature
    out = []
    for path in src.paths:
        a = _table(src.raw(data, path), "\t", cols=4)
        a = a[np.all(np.isfinite(a), axis=1)]
        out.append((Path(path).stem, _uniform_time(len(a), 0.1), 0.5 * (a[:, 2] + a[:, 3]), a[:, 1]))
    return out


# ---------------------------------------------------------------- the table

NONE = "none (all rights reserved: fetch at run time only)"

SOURCES: list[Source] = [
    Source(
        "piezo-stack",
        "chandratue/SmartHysteresis",
        "e7672dabcabbc75341e9ea965d073f68b27e5cda",
        ("Data/hysteresis_v_150_1hz.csv",),
        NONE + "; an MIT LICENSE exists only on an unrelated root commit a09eb32, not in HEAD's history",
        "piezoelectric actuator (Chandra et al., 'Discovering sparse hysteresis models for smart materials', 2023)",
        "voltage [V]",
        "displacement [um]",
        "5 kHz, 10 s (decimated x5 to 1 kHz)",
        _piezo_sindy,
        notes="1 Hz, 150 V sine after ~3.5 s at 0 V; a single file",
    ),
    Source(
        "steel-no27",
        "chandratue/SmartHysteresis",
        "e7672dabcabbc75341e9ea965d073f68b27e5cda",
        ("Data/mag10.txt",),
        NONE,
        "non-oriented electrical steel NO27, B-controlled loop (same paper, 'Exp8_NO27')",
        "flux density B [T]",
        "field H [A/m]",
        "999 samples of one period, no time column",
        _ferrite_no27,
        built_time=True,
        notes="one period taken as 10 s (as the source's script); one 0.2 T loop",
    ),
    Source(
        "mr-damper",
        "Abhay3757/PSO-Optimized-Dual-Attention-LSTM-for-MR-Damper-Force-Prediction",
        "92619e4cfab281450627c7e6a6198113196e41a1",
        ("Dataset/ranran_50_converted.csv", "Dataset/ransim_u_converted.csv"),
        NONE + "; the data are S. Dyke's NEES-2012-1158 (DesignSafe, doi:10.4231/D3V11VM6X), converted by the repo",
        "magnetorheological damper (Dyke, 1996 prototype), hydraulic actuator, random displacement and voltage",
        "displacement [cm]",
        "force [N]",
        "3004.8 Hz (decimated x3 to ~1 kHz), 24.6 s and 20 s",
        _mr_damper,
        notes="the damper voltage is random too (a second input, not modelled); the README calls 'ransim' a "
        "'simulation' file but its channels are recorded ones; ranran_50_u (60 s) is over the 4 MiB snapshot limit",
    ),
    Source(
        "vhb-elastomer",
        "Chongran-Zhao/VHB4910_data",
        "a23efd8c4f8abaa907c4d613db6e74ca6b0321c5",
        tuple(
            f"uniaxial-loading-unloading/original_data/{f}.csv"
            for f in ("0d01_2d0", "0d03_2d0_1", "0d05_2d0", "0d03_2d0_2")
        ),
        NONE,
        "VHB 4910 acrylic elastomer strip, uniaxial loading-unloading to stretch 2 at three rates",
        "displacement [mm]",
        "force [N]",
        "50 Hz; 0.01, 0.03, 0.05 1/s stretch rates + a repeat",
        _vhb4910,
        notes="one loading-unloading per file (a single half loop each way); each file starts at rest from 0",
    ),
    Source(
        "microwire-bh",
        "DYK-Team/Digital_BH-loop_algorithm",
        "d570f56bcdd6661fa845a4161e04306ef9ed7afc",
        tuple(f"Experimental data/{f}.csv" for f in ("50kHz", "100kHz", "200kHz", "250kHz")),
        NONE,
        "amorphous magnetic microwire, B-H loop by pickup coil (MISiS), sinusoidal field at 50-250 kHz",
        "field H [oscilloscope V]",
        "integrated pickup B [V s]",
        "1200 samples at 50/20/10/10 ns (2.4-3 periods)",
        _microwire_bh,
        notes="B = integral of the pickup voltage (dB/dt), mean and linear drift removed",
    ),
    Source(
        "rc-column",
        "sebin-oh/Bouc-Wen-class-model",
        "22520ede17e2b8e93a68f5105d90a78a375538b6",
        ("Example/experimental data.mat",),
        "GPL-3.0 (LICENSE at that commit)",
        "reinforced-concrete column, cyclic lateral test (Gill, Park & Priestley 1979, via the PEER structural "
        "performance database)",
        "lateral displacement [m]",
        "lateral load [g]",
        "481 samples, no time column",
        _rc_column,
        built_time=True,
        notes="quasi-static: 1 sample/s built; growing cycles with stiffness and strength degradation, pinching",
    ),
    Source(
        "timber-wall",
        "cslotboom/hysteresis",
        "585ca4527358ce1fdd002636662baee415ea5a6f",
        ("examples/02 Basic Usage/2.2 Hysteresis with Noisey Data/TS1_Experiment_Shear.csv",),
        "Apache-2.0 (LICENSE at that commit)",
        "timber (CLT) shear wall, quasi-static cyclic test TS1 (R. Ganey, 2015 thesis, U. Washington)",
        "top displacement [m]",
        "base shear [kN]",
        "9281 samples, no time column",
        _timber_wall,
        built_time=True,
        notes="quasi-static: 1 sample/s built; noisy, pinched loops of growing amplitude to 4 % drift",
    ),
    Source(
        "sma-wire",
        "spikelucky/master_thesis_matlab",
        "7cfa310686931927c369b2e17e7c6c78b0f2e03d",
        tuple(f"hyd_stp_{i}.txt" for i in (1, 2, 3, 4)),
        NONE,
        "NiTi shape-memory wire with a return spring, heated and cooled by water steps (master thesis)",
        "water temperature [degC]",
        "wire length sensor [V]",
        "10 Hz (per the source's scripts), 3-7 min each",
        _sma_wire,
        notes="the hyd_hys_* files (slow loops) are over the 4 MiB snapshot limit; the steps are used",
    ),
]

# Looked at and not benchmarked (kept here so that the next person does not look again):
NOT_USED = [
    ("nonlinearbenchmark.org Bouc-Wen (BoucWenData.mat in pyvib examples)", "simulated, not measured"),
    (
        "PrincetonUniversity/magnet",
        "MagNet's measured B/H waveforms are hosted outside GitHub; the repository has "
        "scripts, one parameter CSV and tutorial outputs only",
    ),
    ("otvam/large_signal_ferrite_apec24", "MagNet-derived permeability tables (MIT), not time series"),
    (
        "AleksandrVakulenko/PMN-PT-2023-processing-proj",
        "ferroelectric P-E loops: the loop files are not committed (misc data/*.mat are truncated stubs)",
    ),
    ("chandratue/SmartHysteresis Data/data_file_Loops.txt", "the same NO27 loop as a HystLab export with a fit"),
    ("HaammiiD/Genetic-Algorithm-System-Identification", "SMA morphing-wing loop: ~150 points typed into DataE.m"),
    ("cslotboom/hysteresis BackboneData.csv, 'Damper - Chan and Albermani.csv'", "digitised from figures"),
    ("EvaZillen/3D-printed-pneumatic-actuator, mavasbel/matlab-preisach-model", "already in shared/data"),
]
