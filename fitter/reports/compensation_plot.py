"""PNG of a feedforward compensation (``duhem compensate --plot``): the reference and the plant's output.

Top panel, against time: the reference y_ref, the plant's output without
compensation (the input a linear gain gives, u = (y_ref - y0) / gain) and
with the compensator's input (clamped samples marked).  Bottom panel: the
tracking error y - y_ref of both, with their RMS / range in the legend.  The
plant is the model the compensator inverts (`fitter.core.inverse`).  Both
panels are scaled to the reference and the compensated output (half their
span of margin): a linear-gain output far off that range runs off the panel
and the legend says so.  The PNG is written atomically
(`fitter.core.files.atomic_file`).
"""

from __future__ import annotations

import os

import numpy as np

from fitter.core.files import atomic_file
from fitter.reports import pyplot

__all__ = ["write_compensation_plot"]


def _nrmse(y: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.mean((y - ref) ** 2)) / (np.ptp(ref) or 1.0))


def write_compensation_plot(
    path: str | os.PathLike,
    t: np.ndarray,
    y_ref: np.ndarray,
    y_linear: np.ndarray,
    y_compensated: np.ndarray,
    clamped: np.ndarray,
    *,
    output_label: str = "y",
    title: str = "",
) -> None:
    """Write the PNG `path` (module docstring); `clamped` marks the samples the compensator clamped."""
    plt = pyplot()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8.0, 6.0), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    e_lin, e_comp = _nrmse(y_linear, y_ref), _nrmse(y_compensated, y_ref)
    top.plot(t, y_ref, "-", lw=2.2, color="0.6", label="reference y_ref")
    top.plot(t, y_linear, "-", lw=1.1, color="C1", label="plant, linear-gain input")
    top.plot(t, y_compensated, "--", lw=1.1, color="C0", label="plant, compensated input")
    if np.any(clamped):
        top.plot(
            t[clamped],
            y_compensated[clamped],
            "x",
            ms=4,
            color="C3",
            label=f"clamped ({int(np.count_nonzero(clamped))} samples)",
        )
    lo, hi = min(y_ref.min(), y_compensated.min()), max(y_ref.max(), y_compensated.max())
    margin = 0.5 * ((hi - lo) or 1.0)
    off = np.any((y_linear < lo - margin) | (y_linear > hi + margin))
    top.set_ylim(lo - margin, hi + margin)
    if off:
        top.plot([], [], " ", label="(the linear-gain output leaves the panel)")
    top.set_ylabel(output_label)
    top.legend(fontsize=8, loc="best")
    top.set_title(title or "feedforward hysteresis compensation", fontsize=10)
    bottom.plot(t, y_linear - y_ref, "-", lw=1.0, color="C1", label=f"linear gain: RMS/range {100 * e_lin:.2f}%")
    bottom.plot(t, y_compensated - y_ref, "-", lw=1.0, color="C0", label=f"compensated: RMS/range {100 * e_comp:.2g}%")
    bottom.axhline(0.0, color="0.5", lw=0.6)
    err = max(float(np.max(np.abs(y_compensated - y_ref))), 2 * margin)
    bottom.set_ylim(-err, err)
    bottom.set_xlabel("time")
    bottom.set_ylabel("tracking error")
    bottom.legend(fontsize=8, loc="best")
    fig.tight_layout()
    try:
        with atomic_file(path, suffix=".png") as tmp:
            fig.savefig(tmp, format="png", dpi=110)
    finally:
        plt.close(fig)
