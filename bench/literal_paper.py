"""The paper's three examples by its literal procedures only: the peer `duhem reproduce-paper` is timed against.

    python bench/literal_paper.py        # prints the identified A_hat, B_hat and the run time

What a straightforward reference implementation of Oh & Bernstein (2007)'s examples computes, in one process:
Example 1 at q = 1 and 7 by Section III's constrained least squares (`identify_ri_loop`, ``method="paper"``,
cvxpy where the bound is active); Examples 2 (noise-free and the report's noisy seeds) and 3 by Section V's
literal estimator (DARMA least squares, the bilinear transform and eq (50)), with the sine-loop errors of the
noise-free and seed-0 models.  `duhem reproduce-paper` does all of this and more (the improved estimators, their
checks); issue 35 asks it to take no longer.  `bench/speed_summary.py` times both as fresh processes.
"""

from __future__ import annotations

import time

from fitter.core import limiting_loop
from fitter.identification.ri_loop import identify_ri_loop
from fitter.identification.rd_triangles import identify_rd_triangles
from fitter.paper import example1, example2, example3
from fitter.paper.report import DEFAULT_SEEDS


def run(seeds: int = DEFAULT_SEEDS) -> dict:
    """A_hat of each literal identification, by example."""
    grid, yr, yf, _ = limiting_loop(example1.true_model(), example1.U_MIN, example1.U_MAX, 1001)
    ex1 = {q: identify_ri_loop(grid, yr, yf, m=2, q=q, method="paper").model for q in (1.0, 7.0)}
    ex2 = [identify_rd_triangles(example2.records(example2.NOISE_PP, s), estimator="literal") for s in range(seeds)]
    clean2 = identify_rd_triangles(example2.records(0.0), estimator="literal")
    ex3 = identify_rd_triangles(example3.records(), estimator="literal", order=example3.ORDER)
    loops = [
        example3.loop_errors(example2.true_model(), clean2.model, example2.OMEGAS),
        example3.loop_errors(example2.true_model(), ex2[0].model, example2.OMEGAS),
        example3.loop_errors(example3.true_model(), ex3.model, example3.OMEGAS),
    ]
    return {
        "example1": {q: m.A_plus.tolist() for q, m in ex1.items()},
        "example2": [float(f.A_hat[0, 0]) for f in ex2],
        "example3": ex3.A_hat.tolist(),
        "loop_errors": loops,
    }


if __name__ == "__main__":
    t0 = time.perf_counter()
    out = run()
    print(f"Example 1 A+_hat at q = 1: {out['example1'][1.0]}; Example 3 A_hat: {out['example3']}")
    print(f"run time {time.perf_counter() - t0:.2f} s")
