"""Example 2 of Oh & Bernstein (2007): rate-dependent identification with noise.

True model, eqs (18)-(19) and (51)-(52): A = -1, B = 1, C = 1,
g(v) = |v| for |v| <= 1, 1 beyond.  Twelve triangle waves (20) with
a_i = 0.25, 0.5, ..., 3, b_i = -a_i, T_a = T_b = 4/a_i (u between -2 and 2),
sampled with delta = 0.13; uniform output noise of peak-to-peak 0.1.

Our choices (the paper leaves them open): each record is one period of the
steady-state response (the paper's l_i measurements with delta = T/l), sampled
from the wave's minimum at t = 0, so a record has floor(T_i/delta) + 1 samples;
noise seeds 0..seeds-1 (numpy default_rng).  Since g(a_1) = g(0.25) = 0.25 the
identified model is A_hat = g(a_1) A = -0.25, B_hat = 0.25, g_hat = 4 g.
"""

from __future__ import annotations

from concurrent.futures import Executor, ProcessPoolExecutor
from typing import Iterator, Sequence

import numpy as np

from fitter.core import CallableRate, RateDependentModel, model_from_dict
from fitter.identification.rd_triangles import ESTIMATORS, identify_each
from fitter.identification.triangle_waves import triangle_response
from fitter.paper.example3 import loop_errors, plot_loops, sine_loops

__all__ = [
    "PAPER",
    "SLOPES",
    "DELTA",
    "NOISE_PP",
    "PERIODS",
    "OMEGAS",
    "g_true",
    "true_model",
    "records",
    "seed_runs",
    "noise_free_run",
    "run_example2",
    "plot_example2",
]

PAPER = {
    "A_hat": -0.2501,
    "B_hat": 0.25,
    "C_hat": 1.0,
    "note": "g_hat shown only in Fig. 3 (close to 4 g); one noisy run, seed and record length unstated",
}
SLOPES = 0.25 * np.arange(1, 13)
DELTA = 0.13
NOISE_PP = 0.1
PERIODS = 1
OMEGAS = (0.5, 1.0, 2.0, 4.0, 6.0)
SCALE = 4.0  # 1 / g(a_1)


def g_true(v):
    """Eq (52): g(v) = |v| for |v| <= 1, else 1."""
    return np.minimum(np.abs(np.asarray(v, dtype=float)), 1.0)


def true_model() -> RateDependentModel:
    """The paper's Example 2 model (51)-(52)."""
    return RateDependentModel(A=[[-1.0]], B=[1.0], C=[1.0], g=CallableRate(g_true))


def records(noise_pp: float = NOISE_PP, seed: int | None = None, periods: int = PERIODS) -> list:
    """The 12 steady-state triangle-wave records (t, u, y); noise from default_rng(seed)."""
    rng = np.random.default_rng(seed) if noise_pp > 0 else None
    model = true_model()
    return [triangle_response(model, a, -a, 4 / a, 4 / a, periods, DELTA, noise_pp, rng) for a in SLOPES]


def _summary(fit) -> dict:
    """A_hat, B_hat and the relative errors of g_hat against 4 g at all 24 slopes (both signs)."""
    target = SCALE * g_true(fit.slopes)
    rel = np.abs(fit.g_hat - target) / target
    return {
        "A_hat": float(fit.A_hat[0, 0]),
        "B_hat": float(fit.B_hat[0]),
        "worst_rel_g_error": float(rel.max()),
        "slopes": fit.slopes.tolist(),
        "g_hat": fit.g_hat.tolist(),
        "g_hat_over_4g": (fit.g_hat / target).tolist(),
        "rms_residual": fit.rms_residual,
    }


def _seed_run(seed: int) -> dict:
    """Both estimators' summaries and models on the noisy records of `seed`; seed 0's also with their sine-loop
    errors (the report's "seed0" entries), in the process that fitted them."""
    fits = identify_each(records(NOISE_PP, seed))
    out = {est: {**_summary(fit), "model": fit.model.to_dict()} for est, fit in fits.items()}
    if seed == 0:
        true = true_model()
        reference = sine_loops(true, OMEGAS)
        for est, fit in fits.items():
            out[est]["loop_rel_errors"] = loop_errors(true, fit.model, OMEGAS, reference)
    return out


def _median(runs: list[dict], est: str, key: str) -> float:
    return float(np.median([r[est][key] for r in runs]))


def seed_runs(seeds: int, pool: Executor | None = None) -> Iterator[dict]:
    """`_seed_run` of seeds 0..seeds-1, submitted to `pool` at once when one is given (so that the caller can
    do other work while they run), else run one by one as the iterator is consumed."""
    if seeds < 1:
        raise ValueError(f"seeds must be >= 1, got {seeds}")
    return pool.map(_seed_run, range(seeds)) if pool is not None else map(_seed_run, range(seeds))


def noise_free_run() -> dict:
    """Both estimators on the noise-free records: per estimator the summary, the model and its sine-loop
    errors (the "noise_free" entries of `run_example2`)."""
    true = true_model()
    reference = sine_loops(true, OMEGAS)
    return {
        est: {
            **_summary(fit),
            "model": fit.model.to_dict(),
            "loop_rel_errors": loop_errors(true, fit.model, OMEGAS, reference),
        }
        for est, fit in identify_each(records(0.0)).items()
    }


def run_example2(
    seeds: int = 20, workers: int = 2, runs: Sequence[dict] | None = None, noise_free: dict | None = None
) -> dict:
    """Noise-free and noisy (seeds 0..seeds-1) identification with both estimators.

    JSON-able: per estimator the noise-free summary, the per-seed A_hat, B_hat,
    worst relative g error, their medians over the seeds, and the sine-loop
    errors (max |y_id - y_true| / y-range, limiting periodic responses) of the
    noise-free and the seed-0 models.  Seeds run in `workers` processes, unless
    `runs` gives their results (`seed_runs`, started by the caller); `noise_free` is
    `noise_free_run()` when the caller ran it elsewhere.
    """
    if runs is None:
        if workers > 1 and seeds > 1:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                runs = list(seed_runs(seeds, pool))
        else:
            runs = list(seed_runs(seeds))
    seeds = len(runs)
    noise_free = noise_free_run() if noise_free is None else noise_free
    out = {
        "settings": {
            "slopes": SLOPES.tolist(),
            "delta": DELTA,
            "noise_pp": NOISE_PP,
            "periods_per_record": PERIODS,
            "seeds": seeds,
            "omegas": list(OMEGAS),
        },
        "paper": PAPER,
        "target": {"A_hat": -0.25, "B_hat": 0.25, "g_hat": "4 g"},
        "estimators": {},
    }
    for est in ESTIMATORS:
        out["estimators"][est] = {
            "noise_free": noise_free[est],
            "noisy": {
                "median_A_hat": _median(runs, est, "A_hat"),
                "median_B_hat": _median(runs, est, "B_hat"),
                "median_worst_rel_g_error": _median(runs, est, "worst_rel_g_error"),
                "per_seed": [{k: r[est][k] for k in ("A_hat", "B_hat", "worst_rel_g_error")} for r in runs],
                "seed0": runs[0][est],
            },
        }
    return out


def plot_example2(result: dict, figures_dir: str) -> list[str]:
    """PNGs like the paper's Fig. 3 (g_hat vs 4 g, seed 0) and Fig. 4 (sine loops)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from pathlib import Path

    est = result["estimators"]
    fig, ax = plt.subplots(figsize=(6, 4))
    v = np.linspace(-3.2, 3.2, 401)
    ax.plot(v, SCALE * g_true(v), "k--", label="4 g (true, scaled)")
    for name, marker in (("improved", "o"), ("literal", "x")):
        s = est[name]["noisy"]["seed0"]
        ax.plot(s["slopes"], s["g_hat"], marker, ls="none", label=f"$\\hat g$ {name} (noise seed 0)")
    ax.set_xlabel("du/dt")
    ax.set_ylabel("g")
    ax.set_title("Example 2 (cf. Fig. 3b): pointwise $\\hat g$, $\\delta$ = 0.13, noise 0.1 p-p", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    p3 = str(Path(figures_dir) / "fig3_example2_g.png")
    fig.savefig(p3, dpi=110)
    plt.close(fig)
    p4 = str(Path(figures_dir) / "fig4_example2_loops.png")
    models = {name: model_from_dict(est[name]["noisy"]["seed0"]["model"]) for name in ("improved", "literal")}
    plot_loops(true_model(), models, OMEGAS, p4, "Example 2 (cf. Fig. 4), noise seed 0")
    return [p3, p4]
