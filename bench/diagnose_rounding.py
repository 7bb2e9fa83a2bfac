"""Does `duhem diagnose` rest on rounding?  A measured set diagnosed as recorded and with its outputs perturbed.

    python bench/diagnose_rounding.py [--set piezo] [--seeds 1 2] [--scale 1e-12]

Each perturbed run multiplies every recorded output sample by (1 + scale z), z seeded standard normal: at 1e-12,
far below any instrument's last digit and near the rounding of the fits' own arithmetic.  A diagnosis whose account
(verdict, base order, material and measurement findings) changes under it rests on rounding, not on the data;
its held-out NRMSE per record shows how far the refits' end points move.  The sets and their columns are those of
`bench/diagnose_measured.py` (read at run time from ``../shared/data``, skipped when absent).  About 4-6 minutes
per run for the piezo set on two cores.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from diagnose_measured import DATA, SETS
from fitter.data.recordings import Recording, load_recordings
from fitter.diagnosis import diagnose


def perturbed(recs: list[Recording], seed: int | None, scale: float) -> list[Recording]:
    """The recordings with y (1 + scale z), z ~ N(0, 1) seeded; as recorded for seed None."""
    if seed is None:
        return recs
    rng = np.random.default_rng(seed)
    return [
        Recording(r.t, r.u, r.y * (1.0 + scale * rng.standard_normal(len(r.y))), r.name, r.input, r.output, r.source)
        for r in recs
    ]


def account(recs: list[Recording]) -> dict:
    """The diagnosis' account and held-out NRMSE per record, with its wall time."""
    t0 = time.perf_counter()
    d = diagnose(recs)
    return {
        "seconds": time.perf_counter() - t0,
        "account": (
            d.verdict,
            d.base_model.order,
            tuple(d.extended["material_effects"]),
            tuple(d.extended["measurement_effects"]),
        ),
        "held_out": d.extended["heldout_nrmse_per_recording"] or {},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=list(SETS), default="piezo")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--scale", type=float, default=1e-12)
    args = ap.parse_args()
    folder, stems, columns = SETS[args.set]
    paths = [DATA / folder / f"{stem}.csv" for stem in stems]
    if not all(p.exists() for p in paths):
        print(f"{args.set}: skipped, {DATA / folder} is absent", file=sys.stderr)
        return
    recs = load_recordings([str(p) for p in paths], *columns)
    accounts = []
    for seed in [None, *args.seeds]:
        run = account(perturbed(recs, seed, args.scale))
        accounts.append(run["account"])
        verdict, order, material, measurement = run["account"]
        held = " / ".join(f"{100 * v:.2f}%" for v in run["held_out"].values()) or "-"
        label = "as recorded" if seed is None else f"seed {seed}"
        print(
            f"{label:12s} {run['seconds']:5.0f} s  verdict {verdict}, order {order}, material {list(material)}, "
            f"measurement {list(measurement)}, held out {held}",
            flush=True,
        )
    same = all(a == accounts[0] for a in accounts)
    print(f"the account is {'the same in every run' if same else 'NOT the same in every run'}")


if __name__ == "__main__":
    main()
