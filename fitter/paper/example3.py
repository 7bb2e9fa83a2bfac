"""Example 3 of Oh & Bernstein (2007): a second-order rate-dependent model, noise-free.

True model, eqs (54)-(55): A = [[0, 1], [-3, -1]], B = [1, 0]^T, C = [1, 1],
g(v) = (v/3 - 1)^3 + 1 for v >= 0 and 1 - e^v for v < 0.  Fourteen triangle
waves (20) with a_i = 0.25, 0.5, 0.75, 1, 1.5, ..., 6, b_i = -a_i,
T_a = T_b = 4/a_i; order n = 2.

Our choices (the paper states no sampling): delta = 0.05, one period of the
steady-state response per wave sampled from the wave's minimum at t = 0
(floor(T_i/delta) + 1 samples).  g_hat is compared with g / g(a_1),
g(a_1) = g(0.25) = 1 - (11/12)^3.  The identified and true models are compared
by their limiting periodic responses (Theorem 1, `periodic_response`) to
u = sin(w t), w in {0.5, 1, 2, 4, 6}, one period sampled at 2001 points (the
input is piecewise linear between them for both models): the error is
max |y_id - y_true| / (max y_true - min y_true).
"""

from __future__ import annotations

import numpy as np

from fitter.core import CallableRate, ConvergenceError, RateDependentModel, model_from_dict, periodic_response
from fitter.identification.rd_triangles import identify_each
from fitter.identification.triangle_waves import triangle_response

__all__ = [
    "PAPER",
    "SLOPES",
    "DELTA",
    "PERIODS",
    "ORDER",
    "OMEGAS",
    "g_true",
    "true_model",
    "records",
    "sine_period",
    "sine_loops",
    "loop_errors",
    "plot_loops",
    "run_example3",
    "plot_example3",
]

PAPER = {"note": "the paper shows Figs. 5-6 only (g_hat close to g/g(a_1), loops close); no numbers"}
SLOPES = np.r_[0.25, 0.5, 0.75, np.arange(1.0, 6.01, 0.5)]
DELTA = 0.05
PERIODS = 1
ORDER = 2
OMEGAS = (0.5, 1.0, 2.0, 4.0, 6.0)
SINE_POINTS = 2001


def g_true(v):
    """Eq (55)."""
    v = np.asarray(v, dtype=float)
    return np.where(v >= 0, (v / 3 - 1) ** 3 + 1, 1 - np.exp(np.minimum(v, 0.0)))


def true_model() -> RateDependentModel:
    """The paper's Example 3 model (54)-(55)."""
    return RateDependentModel(A=[[0.0, 1.0], [-3.0, -1.0]], B=[1.0, 0.0], C=[1.0, 1.0], g=CallableRate(g_true))


def records(delta: float = DELTA, periods: int = PERIODS) -> list:
    """The 14 noise-free steady-state triangle-wave records (t, u, y)."""
    model = true_model()
    return [triangle_response(model, a, -a, 4 / a, 4 / a, periods, delta) for a in SLOPES]


def sine_period(w: float, points: int = SINE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """One period of u = sin(w t) on `points` samples, u[-1] = u[0] exactly."""
    t = np.linspace(0.0, 2 * np.pi / w, points)
    u = np.sin(w * t)
    u[-1] = u[0]
    return t, u


def sine_loops(model: RateDependentModel, omegas) -> dict[str, np.ndarray]:
    """The model's limiting periodic outputs under sin(w t) (`sine_period`), per w (keys as `loop_errors`)."""
    return {f"{w:g}": periodic_response(model, *sine_period(w)).sim.y for w in omegas}


def loop_errors(true: RateDependentModel, model: RateDependentModel, omegas, reference: dict | None = None) -> dict:
    """max |y_model - y_true| / y_true-range of the limiting periodic responses to sin(w t), per w.

    None for a w at which the model has no limiting periodic response (rho >= 1).  `reference`: the true
    model's `sine_loops` at these w, when the caller has them.
    """
    reference = sine_loops(true, omegas) if reference is None else reference
    out = {}
    for w in omegas:
        yt = reference[f"{w:g}"]
        try:
            ym = periodic_response(model, *sine_period(w)).sim.y
        except ConvergenceError:
            out[f"{w:g}"] = None
            continue
        out[f"{w:g}"] = float(np.max(np.abs(ym - yt)) / np.ptp(yt))
    return out


def plot_loops(true: RateDependentModel, models: dict, omegas, path: str, title: str) -> None:
    """Input-output maps of the true (dashed) and identified models under sin(w t), one panel per w."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(omegas), figsize=(3.2 * len(omegas), 3.2), squeeze=False)
    styles = ("r-", "b:", "g-.")
    for ax, w in zip(axes[0], omegas):
        t, u = sine_period(w)
        ax.plot(u, periodic_response(true, t, u).sim.y, "k--", lw=2, label="true")
        for (name, m), style in zip(models.items(), styles):
            try:
                ax.plot(u, periodic_response(m, t, u).sim.y, style, lw=1, label=name)
            except ConvergenceError:
                ax.plot([], [], style, label=f"{name}: no limiting loop")
        ax.set_title(f"$\\omega$ = {w:g}", fontsize=9)
        ax.set_xlabel("u")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("y")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _linear_g_error(fit, true: RateDependentModel, w: float, reference: dict) -> float:
    """Loop error at w if g_hat were straight between g(0) = 0 and the slopes (not PCHIP)."""
    v, g = np.r_[fit.slopes, 0.0], np.r_[fit.g_hat, 0.0]
    order = np.argsort(v)
    lin = RateDependentModel(
        A=fit.A_hat, B=fit.B_hat, C=fit.C_hat, g=CallableRate(lambda s: np.interp(s, v[order], g[order]))
    )
    return loop_errors(true, lin, (w,), reference)[f"{w:g}"]


def run_example3() -> dict:
    """Identify Example 3 with both estimators; JSON-able figures.

    Per estimator: max |g_hat - g/g(a_1)| over the 28 slopes, A_hat, B_hat (true
    normalised canonical form: alpha = (g1, 3 g1^2), beta = (g1, -2 g1^2),
    g1 = g(a_1)), the sine-loop errors, and (for contrast) the w = 0.5 loop
    error with g_hat interpolated linearly instead of by PCHIP.
    """
    recs = records()
    true = true_model()
    reference = sine_loops(true, OMEGAS)
    g1 = float(g_true(SLOPES[0]))
    out = {
        "settings": {
            "slopes": SLOPES.tolist(),
            "delta": DELTA,
            "periods_per_record": PERIODS,
            "order": ORDER,
            "noise": "none",
            "omegas": list(OMEGAS),
            "sine_points": SINE_POINTS,
        },
        "paper": PAPER,
        "target": {"A_hat": [[-g1, 1.0], [-3 * g1**2, 0.0]], "B_hat": [g1, -2 * g1**2], "g_hat": "g / g(0.25)"},
        "estimators": {},
    }
    for est, fit in identify_each(recs, order=ORDER).items():
        err = np.abs(fit.g_hat - g_true(fit.slopes) / g1)
        out["estimators"][est] = {
            "max_abs_g_error": float(err.max()),
            "A_hat": fit.A_hat.tolist(),
            "B_hat": fit.B_hat.tolist(),
            "slopes": fit.slopes.tolist(),
            "g_hat": fit.g_hat.tolist(),
            "loop_rel_errors": loop_errors(true, fit.model, OMEGAS, reference),
            "loop_rel_error_w0.5_linear_g": _linear_g_error(fit, true, 0.5, reference),
            "rms_residual": fit.rms_residual,
            "model": fit.model.to_dict(),
        }
    return out


def plot_example3(result: dict, figures_dir: str) -> list[str]:
    """PNGs like the paper's Fig. 5 (g_hat vs g/g(a_1)) and Fig. 6 (sine loops)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from pathlib import Path

    est = result["estimators"]
    g1 = float(g_true(SLOPES[0]))
    fig, ax = plt.subplots(figsize=(6, 4))
    v = np.linspace(-6.3, 6.3, 501)
    ax.plot(v, g_true(v) / g1, "k--", label="g / g(0.25) (true, scaled)")
    for name, marker in (("improved", "o"), ("literal", "x")):
        ax.plot(est[name]["slopes"], est[name]["g_hat"], marker, ls="none", label=f"$\\hat g$ {name}")
    ax.set_xlabel("du/dt")
    ax.set_ylabel("g")
    ax.set_title(f"Example 3 (cf. Fig. 5b): pointwise $\\hat g$, noise-free, $\\delta$ = {DELTA}", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    p5 = str(Path(figures_dir) / "fig5_example3_g.png")
    fig.savefig(p5, dpi=110)
    plt.close(fig)
    p6 = str(Path(figures_dir) / "fig6_example3_loops.png")
    models = {name: model_from_dict(est[name]["model"]) for name in ("improved", "literal")}
    plot_loops(true_model(), models, OMEGAS, p6, "Example 3 (cf. Fig. 6), noise-free")
    return [p5, p6]
