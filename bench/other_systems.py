"""`duhem fit` on generated recordings of other hysteretic systems, beside the classical models, and what the saved
model does on inputs other than the fitted one.

    python bench/other_systems.py            # prints the table
    python bench/other_systems.py --json     # the same figures as JSON

Three systems, none of them a semilinear Duhem model, each one noisy recording (seeded) that starts from rest:

* ``b-h``: a ferromagnetic core, Jiles-Atherton (anhysteretic Langevin curve, pinning k, coupling alpha, reversible
  share c), H in A/m driven by a 50 Hz sine whose amplitude decays by 70 % over ten periods (nested minor loops),
  B in T, 20 kHz sampling;
* ``mr-damper``: a magnetorheological damper, Spencer's simple Bouc-Wen model F = c0 v + k0 x + alpha z, a 2 Hz
  10 mm displacement sine ramped in over 0.5 s, force in N, 1 kHz sampling;
* ``member``: a structural member under a quasi-static cyclic drift protocol of growing amplitude (5 to 30 mm),
  Bouc-Wen with post-yield stiffness ratio 0.1, shear in kN, 50 Hz sampling.

Per system: the Duhem fit's NRMSE (`duhem fit`, default options, all samples from the stored x0) and the classical
models' (`fitter.baselines.compare_baselines`, same recording, same measure), and the fit's own ``minor_loops``
check (`fitter.identification.exported.minor_loop_excursion`: the saved model driven by
`fitter.core.periodic.minor_loop_input` over its stored input range, 40 cycles of each of 8 sub-spans): the largest
output excursion beyond the recorded output range, in output ranges (0 = inside it); then the same fit with
faithful minor loops (`fit_recordings(faithful_minor_loops=True)`, `duhem fit --faithful-minor-loops`).  Before
condition (5) was required of every minor loop the B-H and damper fits reached 1.4e17 and 1.6e7 output ranges
there.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from real_data import excursion_text  # noqa: E402

from fitter.baselines import compare_baselines
from fitter.core.periodic import minor_loop_rho
from fitter.data.recordings import Recording
from fitter.identification.fit import fit_recordings


def _euler(rate, z0: float, steps: int, sub: int = 10) -> np.ndarray:
    """z_k of dz = rate(k, z) integrated with `sub` explicit substeps per sample (rate returns the increment of
    one whole sample at the substep's state)."""
    z = np.empty(steps)
    z[0] = z0
    for k in range(1, steps):
        zz = z[k - 1]
        for j in range(sub):
            zz += rate(k, zz, (j + 0.5) / sub) / sub
        z[k] = zz
    return z


def b_h(rng: np.random.Generator) -> Recording:
    """Jiles-Atherton B(H) (module docstring)."""
    ms, a, alpha, k, c, mu0 = 1.6e6, 1100.0, 1.6e-3, 400.0, 0.2, 4e-7 * np.pi
    t = np.arange(0, 0.2, 5e-5)
    h = 3000 * np.sin(2 * np.pi * 50 * t) * (1 - 0.7 * t / 0.2)

    def langevin(x):
        return ms * (1 / np.tanh(x / a) - a / x) if abs(x / a) > 1e-6 else ms * x / (3 * a)

    def rate(i, m, s):
        dh = h[i] - h[i - 1]
        he = h[i - 1] + s * dh + alpha * m
        man = langevin(he)
        slope = (langevin(he + 1e-3) - man) / 1e-3
        return ((1 - c) * (man - m) / ((np.sign(dh) or 1.0) * k - alpha * (man - m)) + c * slope) * dh

    b = mu0 * (h + _euler(rate, 0.0, len(t)))
    return Recording(t, h, b + 0.005 * rng.standard_normal(len(t)), name="b-h")


def mr_damper(rng: np.random.Generator) -> Recording:
    """Spencer's simple Bouc-Wen damper (module docstring)."""
    t = np.arange(0, 3, 1e-3)
    x = 10 * np.sin(2 * np.pi * 2 * t) * np.minimum(1, t / 0.5)
    v = np.gradient(x, t)
    c0, k0, al, gam, beta, amp = 20.0, 5.0, 400.0, 0.3, 0.3, 1.2

    def rate(i, z, s):
        vv = v[i - 1] + s * (v[i] - v[i - 1])
        return 1e-3 * (-gam * abs(vv) * z * abs(z) - beta * vv * z * z + amp * vv)

    f = c0 * v + k0 * x + al * _euler(rate, 0.0, len(t))
    return Recording(t, x, f + 20 * rng.standard_normal(len(t)), name="mr-damper")


def member(rng: np.random.Generator) -> Recording:
    """Bouc-Wen member under a growing cyclic drift (module docstring)."""
    t = np.arange(0, 120, 0.02)
    s = np.sin(2 * np.pi * t / 10)
    d = (5 + 25 * t / 120) * np.sign(s) * np.abs(s) ** 0.7

    def rate(i, z, _):
        dd = d[i] - d[i - 1]
        return dd - 0.05 * abs(dd) * abs(z) ** 0.5 * z - 0.05 * dd * abs(z) ** 1.5

    f = 2.0 * (0.1 * d + 0.9 * _euler(rate, 0.0, len(t)))
    return Recording(t, d, f + 0.3 * rng.standard_normal(len(t)), name="member")


SYSTEMS = {"b-h": b_h, "mr-damper": mr_damper, "member": member}


def system_part(name: str, seed: int) -> dict:
    rec = SYSTEMS[name](np.random.default_rng(seed))
    t0 = time.perf_counter()
    fit = fit_recordings([rec])
    seconds = time.perf_counter() - t0
    m = fit.model
    out = {
        "samples": len(rec),
        "model": f"{m.kind}{m.order}",
        "fit_seconds": seconds,
        "duhem": fit.summary["recordings"][0]["nrmse"],
        "minor_loop_excursion": fit.summary["minor_loops"]["excursion"],
        "minor_loop_rho": minor_loop_rho(m, *m.input_range) if m.kind == "ri" else None,
    }
    faithful = fit_recordings([rec], faithful_minor_loops=True)
    out["faithful"] = {
        "model": f"{faithful.model.kind}{faithful.model.order}",
        "duhem": faithful.summary["recordings"][0]["nrmse"],
        "minor_loop_excursion": faithful.summary["minor_loops"]["excursion"],
    }
    base = compare_baselines([rec], per_recording=False)
    out["baselines"] = {b: r["one_for_all"][rec.name] for b, r in base.items()}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print JSON instead of the table")
    args = ap.parse_args()
    res = {name: system_part(name, seed) for seed, name in enumerate(SYSTEMS)}
    if args.json:
        print(json.dumps(res, indent=2))
        return
    names = list(next(iter(res.values()))["baselines"])
    print(
        f"{'system':10s} {'model':6s} {'Duhem':>7s} "
        + " ".join(f"{n:>18s}" for n in names)
        + f" {'minor-loop rho':>15s} {'excursion':>10s} {'fit s':>6s}"
    )
    for name, r in res.items():
        rho = "-" if r["minor_loop_rho"] is None else f"{r['minor_loop_rho']:.3g}"
        print(
            f"{name:10s} {r['model']:6s} {r['duhem']:7.2%} "
            + " ".join(f"{r['baselines'][n]:18.2%}" for n in names)
            + f" {rho:>15s} {excursion_text(r['minor_loop_excursion']):>10s} {r['fit_seconds']:6.1f}"
        )
    print("\nwith --faithful-minor-loops (`fit_recordings(faithful_minor_loops=True)`):")
    for name, r in res.items():
        f = r["faithful"]
        print(f"{name:10s} {f['model']:6s} {f['duhem']:7.2%}  excursion {excursion_text(f['minor_loop_excursion'])}")
    print(
        "\nNRMSE = RMS error / output range over all samples; excursion = largest distance beyond the recorded "
        "output range on minor loops of every sub-span of the stored input range, in output ranges"
    )


if __name__ == "__main__":
    main()
