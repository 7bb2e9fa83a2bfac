"""One experiment: recordings joined on one clock, checked before a diagnosis.

One experiment is a list of recordings whose time is the experiment clock: it
runs on from file to file (gaps allowed).  The recordings are simulated as one
signal: the input is piecewise linear between all samples, including across a
gap (the straight line from the last sample of one file to the first of the
next), so model states, creep and the input travel of a thermal drift carry
over from file to file.

Or (``separate``) a list of separate runs, each on its own clock (every file
may start at t = 0, as a tester that writes one file per measurement does;
recognised by default when a file starts at or before its predecessor ends,
`own_clocks`):
each recording is simulated alone, from the initial state that fits it best
(least squares over all its samples, the fit's and the baselines' policy,
`fitter.identification.output_error.fitted_initial_state`), and every effect
state restarts at its own start (a creep at equilibrium with the first input,
a drift at 0).  `runs` gives the slices that are simulated as one signal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fitter.core.effects import EffectContext
from fitter.core.errors import DuhemError
from fitter.data.cycles import count_reversals, find_reversals, single_loop
from fitter.data.recordings import Recording, check_scale

__all__ = ["DiagnoseError", "JoinedExperiment", "MIN_SAMPLES", "join_recordings", "chain_recordings", "own_clocks"]

MIN_SAMPLES = 100
"""Fewest samples a diagnosis takes in all: the base's seven parameters and an effect's few keep about ten samples
per parameter (a random clean order-1 device of 197 samples was diagnosed "nothing_missing" at 0.84 times the
noise once 200 were no longer asked for)."""


class DiagnoseError(DuhemError):
    """Input that cannot be diagnosed (named file, column, row, value)."""


@dataclass
class JoinedExperiment:
    """The recordings of one experiment, concatenated on the experiment clock."""

    recordings: list
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    index: np.ndarray  # recording number of each sample
    bounds: list  # [start, stop) of each recording in the arrays
    separate: bool = False  # each recording its own run (module docstring)

    def part(self, i: int) -> slice:
        """The samples of recording `i` in the joined arrays."""
        return slice(*self.bounds[i])

    def runs(self) -> list[slice]:
        """The slices simulated as one signal: the whole experiment, or each recording when `separate`."""
        return [self.part(i) for i in range(len(self.recordings))] if self.separate else [slice(0, len(self.t))]

    def min_dt(self) -> float:
        """The shortest of the recordings' median sample periods."""
        return float(min(np.median(np.diff(r.t)) for r in self.recordings))

    def effect_context(self, y_mean: float) -> EffectContext:
        """The experiment's `EffectContext`, `y_mean` the mean output of the model an effect would extend.

        v95 is the 95th percentile of |du/dt| over all intervals of the runs (1.0 when it is 0); the duration is
        the longest run's.
        """
        return EffectContext.of([(self.t[s], self.u[s], self.y[s]) for s in self.runs()], y_mean, self.min_dt())


def own_clocks(recordings: Sequence[Recording]) -> tuple[Recording, Recording] | None:
    """The first pair (a, b) of consecutive recordings where b starts at or before a ends (b.t[0] <= a.t[-1]):
    files each on their own clock, as a tester writes one file per measurement (every file from t = 0);
    None when time runs on from file to file (one clock)."""
    recs = list(recordings)
    return next(((a, b) for a, b in zip(recs[:-1], recs[1:]) if b.t[0] <= a.t[-1]), None)


def join_recordings(recordings: Sequence[Recording], separate: bool | None = None) -> JoinedExperiment:
    """Check the recordings of one experiment and join them on its clock (`separate`: as separate runs,
    module docstring).

    `separate` None (default) reads the files as they were written: separate runs when a file starts
    at or before its predecessor ends (`own_clocks`), else one clock; True or False forces a reading.

    Raises
    ------
    DiagnoseError : no recordings, different columns, a non-finite output, time not running on from
        file to file with `separate` False, fewer than `MIN_SAMPLES` samples, an input reversing fewer
        than twice.
    """
    recs = list(recordings)
    if not recs:
        raise DiagnoseError("no recordings given")
    _check_columns(recs)
    for r in recs:
        _check_output(r)
    check_scale(recs)
    overlap = own_clocks(recs)
    if separate is None:
        separate = overlap is not None
    if overlap is not None and not separate:
        a, b = overlap
        raise DiagnoseError(
            f"{b.source}: starts at t = {b.t[0]} before {a.source} ends (t = {a.t[-1]}); "
            "the recordings of one experiment on one clock must run on from file to file "
            "(shift the time of later files, or leave out --one-clock: files each on their own "
            "clock are diagnosed as separate runs)"
        )
    n = sum(len(r.t) for r in recs)
    if n < MIN_SAMPLES:
        raise DiagnoseError(
            f"{n} samples in all ({', '.join(r.source for r in recs)}): too short to "
            f"diagnose (at least {MIN_SAMPLES} needed)"
        )
    u = np.concatenate([r.u for r in recs])
    if count_reversals(u) < 2 and not any(
        single_loop(r.u, find_reversals(r.u)) for r in recs
    ):  # one closed loop from one tip to the other and back is a loop too
        raise DiagnoseError(
            f"the input ({recs[0].input.name}) reverses fewer than twice over the experiment "
            f"({', '.join(r.source for r in recs)}): no hysteresis loop to diagnose"
        )
    stops = np.cumsum([len(r.t) for r in recs])
    bounds = [(int(s - len(r.t)), int(s)) for s, r in zip(stops, recs)]
    return JoinedExperiment(
        recs,
        np.concatenate([r.t for r in recs]),
        u,
        np.concatenate([r.y for r in recs]),
        np.concatenate([np.full(len(r.t), i) for i, r in enumerate(recs)]),
        bounds,
        separate,
    )


def chain_recordings(recordings: Sequence[Recording], relative_output: bool = False) -> list[Recording]:
    """Recordings that each start their own clock (every file at t = 0), put back to back on one clock.

    Recording i + 1 starts one sample period (its median) after recording i ends: t_i+1 <- t_i+1 - t_i+1[0]
    + t_i[-1] + dt.  With `relative_output` (an output measured from an arbitrary zero in every file, as the
    charge a ferroelectric tester integrates and re-references per table) each later output is shifted to
    start where the previous one ended: y_i+1 <- y_i+1 - y_i+1[0] + y_i[-1].  The input is linear across the
    joint, as in every experiment (module docstring).
    """
    out: list[Recording] = []
    for r in recordings:
        t, y = r.t - r.t[0], r.y
        if out:
            t = t + out[-1].t[-1] + float(np.median(np.diff(r.t)))
            if relative_output:
                y = y - y[0] + out[-1].y[-1]
        out.append(Recording(t, r.u, y, name=r.name, input=r.input, output=r.output, source=r.source))
    return out


def _check_columns(recs: list[Recording]) -> None:
    first = recs[0]
    for r in recs[1:]:
        if (r.input.name, r.output.name) != (first.input.name, first.output.name):
            raise DiagnoseError(
                f"{r.source}: columns ({r.input.name}, {r.output.name}) differ from "
                f"{first.source}: ({first.input.name}, {first.output.name}); one experiment "
                "needs the same input and output in every recording"
            )


def _check_output(r: Recording) -> None:
    """A diagnosis needs the output everywhere (`Recording` checks time and input at construction)."""
    bad = np.flatnonzero(~np.isfinite(r.y))
    if bad.size:
        raise DiagnoseError(
            f"{r.source}: column {r.output.name or 'y'}, row {bad[0]}: value {r.y[bad[0]]} is not finite"
        )
