"""PNG of an FMU validation (``duhem validate --plot``): data and FMU loops, one panel per recording.

Each panel shows the recorded loop (all samples, light grey), the samples of
the last full input cycle (`fitter.data.cycles.last_full_cycle`; all samples
when there is none) and the FMU's output over that cycle, titled with the
NRMSE the validation judged.  The PNG is written atomically
(`fitter.core.files.atomic_file`).
"""

from __future__ import annotations

import os
from typing import Sequence

import numpy as np

from fitter.core.files import atomic_file
from fitter.data.cycles import PreparationError, last_full_cycle
from fitter.data.recordings import Recording
from fitter.reports import pyplot

__all__ = ["write_validation_plot"]


def _axis_label(signal) -> str:
    return f"{signal.name} [{signal.unit}]" if signal.unit else signal.name


def _panel(ax, rec: Recording, y_fmu: np.ndarray, nrmse: float) -> None:
    try:
        s = last_full_cycle(rec.u)
    except PreparationError:
        s = slice(0, len(rec))
    ax.plot(rec.u, rec.y, ".", ms=2, color="0.75", label="data (all)")
    ax.plot(rec.u[s], rec.y[s], ".", ms=3, color="C0", label="data (last cycle)")
    ax.plot(rec.u[s], y_fmu[s], "-", lw=1.4, color="C3", label="FMU")
    ax.set_title(f"{rec.name}: NRMSE {100 * nrmse:.2f}%", fontsize=9)
    ax.set_xlabel(_axis_label(rec.input))
    ax.set_ylabel(_axis_label(rec.output))
    ax.legend(fontsize=7, loc="best")


def write_validation_plot(
    path: str | os.PathLike, recordings: Sequence[Recording], outputs: Sequence[np.ndarray], nrmses: Sequence[float]
) -> None:
    """Write the PNG `path`: per recording, its data and the FMU output `outputs[i]` over the
    last full cycle, titled with `nrmses[i]` (a fraction, shown in percent); up to 3 panels a row."""
    plt = pyplot()
    n = len(recordings)
    cols = min(n, 3)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.8 * rows), squeeze=False)
    for ax, rec, y_fmu, value in zip(axes.flat, recordings, outputs, nrmses):
        _panel(ax, rec, y_fmu, value)
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    fig.tight_layout()
    try:
        with atomic_file(path, suffix=".png") as tmp:
            fig.savefig(tmp, format="png", dpi=110)
    finally:
        plt.close(fig)
