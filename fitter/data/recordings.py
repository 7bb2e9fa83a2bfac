"""Recordings: one experiment's sampled input and output, loaded from CSV.

The file format, the choice of columns and the unit rule are `fitter.data.csv_table`'s.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from scipy.ndimage import median_filter

from fitter.data.csv_table import RecordingError, read_table, split_unit
from fitter.core.models import Signal

__all__ = [
    "Recording",
    "RecordingError",
    "SCALE_LIMIT",
    "check_samples",
    "check_scale",
    "load_recording",
    "load_recordings",
    "save_columns",
    "split_unit",
    "MIN_SAMPLES",
]

MIN_SAMPLES = 3
"""Fewest data rows `load_recording` accepts by default."""

_TIME_SCALE = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}


def check_samples(
    t,
    u,
    y=None,
    *,
    source: str,
    names: Sequence[str] = ("t", "u", "y"),
    rows: Sequence[int] | None = None,
    min_samples: int = 2,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Check the samples of one experiment; return t, u, y as float arrays (y None if not given).

    In this order: t, u (and y) are 1-D and of equal length; there are at
    least `min_samples` samples; every value is finite, except that y may
    be all NaN (no output recorded, e.g. an input to simulate); time
    increases strictly, ``t[k+1] > t[k]``.

    Parameters
    ----------
    t, u, y : the samples (y optional).
    source : what the samples are, first in every message (file or recording name).
    names : column names of t, u, y in the messages.
    rows : position of each sample in the messages: ``line rows[k]`` (e.g.
        the file's line numbers); by default ``row k`` (0-based).
    min_samples : fewest samples accepted.

    Raises
    ------
    RecordingError
        One line naming `source`, the column, the row (or line) and the value.
    """
    arrays = [np.asarray(a, dtype=float) for a in ((t, u) if y is None else (t, u, y))]
    if any(a.ndim != 1 for a in arrays) or len({a.size for a in arrays}) != 1:
        raise RecordingError(
            f"{source}: {', '.join(names[: len(arrays)])} must be 1-D arrays of equal "
            f"length (shapes {', '.join(str(a.shape) for a in arrays)})"
        )
    if arrays[0].size < min_samples:
        count = f"{arrays[0].size} data rows" if rows is not None else f"{arrays[0].size}"
        raise RecordingError(f"{source}: too few samples: {count}, at least {min_samples} needed")
    where = (lambda k: f"line {rows[k]}") if rows is not None else (lambda k: f"row {k}")
    for i, (name, a) in enumerate(zip(names, arrays)):
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size and not (i == 2 and np.isnan(a).all()):
            raise RecordingError(
                f"{source}: {where(bad[0])}, column {name!r}: value {float(a[bad[0]])!r} "
                f"is not finite (NaN or infinity)"
            )
    _check_increasing(arrays[0], source, names[0], where)
    return arrays[0], arrays[1], arrays[2] if y is not None else None


SCALE_LIMIT = 1e100
"""Largest magnitude, and inverse of the smallest nonzero span, of a column the identification accepts."""


def check_scale(recordings: Sequence["Recording"]) -> None:
    """Refuse columns whose scale makes the numerics meaningless (`RecordingError` naming file and column).

    A fitted model's parameters scale like 1/span(u), span(y)/span(u) and 1/span(t); with a column beyond
    `SCALE_LIMIT` in magnitude (or a span below 1/`SCALE_LIMIT`) they, or their products in the matrix
    exponentials, leave the range of double precision (about 1e-308 to 1e308) and the fit returns zeros or
    NaN.  The remedy is a change of unit, which the message names.
    """
    for rec in recordings:
        for name, values, unit in (
            ("time", rec.t, "s"),
            (rec.input.name, rec.u, rec.input.unit),
            (rec.output.name, rec.y, rec.output.unit),
        ):
            finite = values[np.isfinite(values)]
            if finite.size == 0:
                continue
            big, span = float(np.max(np.abs(finite))), float(np.ptp(finite))
            if big > SCALE_LIMIT or 0 < span < 1 / SCALE_LIMIT:
                what = f"values up to {big:.3g}" if big > SCALE_LIMIT else f"a span of only {span:.3g}"
                raise RecordingError(
                    f"{rec.label}: column {name!r}{f' ({unit})' if unit else ''} has {what}: beyond what the "
                    f"identification can represent in double precision (magnitudes up to {SCALE_LIMIT:.0e}, spans "
                    f"from {1 / SCALE_LIMIT:.0e}); rescale the column (another unit) so that its span is near 1"
                )


def _check_increasing(t: np.ndarray, source: str, name: str, where) -> None:
    """`RecordingError` at the first k with t[k] <= t[k-1]."""
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        k = int(back[0]) + 1
        raise RecordingError(
            f"{source}: {where(k)}, column {name!r}: time {float(t[k])!r} does not increase "
            f"({where(k - 1)} has {float(t[k - 1])!r})"
        )


@dataclass
class Recording:
    """One experiment: time t, input u, output y (equal-length float arrays).

    `name` is a short label (the file stem); `input` and `output` carry the
    column names and units; `source` is the file path (or "generated").
    The samples are checked at construction (`check_samples`: at least two,
    finite, time strictly increasing; y all NaN when no output was
    recorded); a bad sample is a `RecordingError` naming `label`, the
    column, the row and the value.
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    name: str = "recording"
    input: Signal = field(default_factory=lambda: Signal("u"))
    output: Signal = field(default_factory=lambda: Signal("y"))
    source: str = "generated"

    def __post_init__(self):
        self.t, self.u, self.y = check_samples(self.t, self.u, self.y, source=self.label)

    @property
    def label(self) -> str:
        """The file the recording came from, or its name when it was generated."""
        return self.source if self.source != "generated" else self.name

    def __len__(self) -> int:
        return len(self.t)

    def slice(self, s: slice, name: str | None = None) -> "Recording":
        """The samples `s` of this recording as a new `Recording` (times unchanged)."""
        return Recording(self.t[s], self.u[s], self.y[s], name or self.name, self.input, self.output, self.source)


SPIKE = 10.0
"""`spikes`: a sample this many times its column's central range from its neighbours is a glitch."""


def spikes(a: np.ndarray) -> np.ndarray:
    """Indices of the isolated glitches of a column: samples farther than `SPIKE` times the column's central range
    (the span of its 1-99 % quantiles) from the median of the five samples around them (a wrong row, such as
    1e6 in an input of +-1, which a fit would follow)."""
    a = np.asarray(a, dtype=float)
    if a.size < 5 or not np.all(np.isfinite(a)):
        return np.zeros(0, dtype=int)
    span = float(np.quantile(a, 0.99) - np.quantile(a, 0.01))
    if not span > 0:
        return np.zeros(0, dtype=int)
    return np.flatnonzero(np.abs(a - median_filter(a, size=5, mode="nearest")) > SPIKE * span)


def _spike_warning(path: str, column: str, a: np.ndarray, lines: Sequence[int]) -> str | None:
    """One line naming the first glitch (`spikes`) of a column: file, line, column, value, how many, the fix."""
    idx = spikes(a)
    if not idx.size:
        return None
    k = int(idx[0])
    return (
        f"{path}: line {lines[k]}, column {column!r}: value {float(a[k])!r} lies far outside the rest of the column "
        f"(more than {SPIKE:g} times its central range from its neighbours; {idx.size} such row(s)): a glitch? "
        "fix or remove the row(s): one wrong sample can spoil a fit"
    )


def load_recording(
    path: str | os.PathLike,
    time: str | int | None = "time",
    input: str | int = "u",
    output: str | int | None = "y",
    *,
    name: str | None = None,
    min_samples: int = MIN_SAMPLES,
    warn: Callable[[str], None] | None = None,
) -> Recording:
    """Load one experiment from a CSV file.

    Parameters
    ----------
    path : the CSV file (one header line).
    time, input, output : column names, base names or 0-based indices (see the
        module docstring).  ``time=None`` uses the sample index as time (enough
        for rate-independent models, whose response does not depend on time);
        ``output=None`` reads no output column (y is NaN), e.g. for an input
        to simulate.
    name : label of the recording; defaults to the file stem.
    min_samples : fewest data rows accepted.
    warn : called with one line per input or output column that holds glitches (`spikes`); default: none.

    Raises
    ------
    RecordingError
        Missing file, empty file, missing or ambiguous column, ragged row,
        non-numeric or non-finite cell, non-increasing time, too few samples.
        The message names the file, the column, the line (as numbered in the
        file, header = line 1) and the value.
    """
    path = str(path)
    table = read_table(path, {"time": time, "input": input, "output": output})
    values, numbers = table.columns()
    header, cols = table.header, table.cols
    n = len(numbers)
    t = values["time"] if "time" in values else np.arange(n, dtype=float)
    names = [header[cols["time"]] if "time" in cols else "sample index", header[cols["input"]]]
    check_samples(t, values["input"], source=path, names=names, rows=numbers, min_samples=min_samples)
    scale = _TIME_SCALE.get(split_unit(header[cols["time"]])[1], 1.0) if "time" in cols else 1.0
    if scale != 1.0:
        t = t * scale
    signals = {"output": Signal("y")}
    for role in ("input", "output"):
        if role in cols:
            base, unit = split_unit(header[cols[role]])
            signals[role] = Signal(base, unit, f"{role} column {header[cols[role]]!r} of {Path(path).name}")
    y = values["output"] if "output" in values else np.full(n, np.nan)
    for role in ("input", "output") if warn is not None else ():
        message = _spike_warning(path, header[cols[role]], values[role], numbers) if role in values else None
        if message is not None:
            warn(message)
    return Recording(
        t,
        values["input"],
        y,
        name=name or Path(path).stem,
        input=signals["input"],
        output=signals["output"],
        source=path,
    )


def load_recordings(
    paths: Sequence[str | os.PathLike],
    time: str | int | None = "time",
    input: str | int = "u",
    output: str | int = "y",
    *,
    min_samples: int = MIN_SAMPLES,
    warn: Callable[[str], None] | None = None,
) -> list[Recording]:
    """Load several experiments (one file each) with the same column choice (`warn`: `load_recording`'s).

    Raises `RecordingError` for the first bad file, and when the files' input
    or output columns carry different names or units (they must be the same
    experiment's signals).
    """
    if not paths:
        raise RecordingError("no recording files given")
    recs = [load_recording(p, time, input, output, min_samples=min_samples, warn=warn) for p in paths]
    first = recs[0]
    for r in recs[1:]:
        for role in ("input", "output"):
            a, b = getattr(first, role), getattr(r, role)
            if (a.name, a.unit) != (b.name, b.unit):
                raise RecordingError(
                    f"{r.source}: {role} column is {b.name!r} [{b.unit}] but {first.source} has {a.name!r} [{a.unit}]"
                )
    return recs


def save_columns(
    path: str | os.PathLike, names: Sequence[str], columns: Sequence[np.ndarray], block: int = 1 << 16
) -> None:
    """Write equal-length columns as a CSV file: the header line ``names`` joined by commas, then one row
    per sample, each value as ``%.17g`` (it reads back to the same float).

    The text is that of ``np.savetxt(path, np.column_stack(columns), delimiter=",", fmt="%.17g",
    header=",".join(names), comments="")``, formatted `block` rows at a time (no N x k copy).
    """
    row = ",".join(["%.17g"] * len(columns)) + "\n"
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(",".join(names) + "\n")
        for a in range(0, len(columns[0]), block):
            values = np.column_stack([c[a : a + block] for c in columns])
            fh.write(row * len(values) % tuple(values.ravel().tolist()))
