"""A zoo of hysteresis physics from other families than the semilinear Duhem model, run through `duhem` as a user would.

    python bench/zoo.py --quick                      # every set, short recordings (65 min on 2 busy cores)
    python bench/zoo.py                              # full-length recordings
    python bench/zoo.py --sets play,preisach --json  # two sets, the results as JSON on stdout
    python bench/zoo.py --out /tmp/zoo               # keep the recordings, models, FMUs and JSON here
    python bench/zoo.py --table /tmp/zoo/zoo.json    # print the table of a finished run again (runs nothing)

Per set the recordings (CSV ``time,u,y``, one file per rate or amplitude, each from t = 0, seeded output noise of
0.2-0.3 % of the range, some with their own small output offset) are written by `zoo_physics` (numpy only; no
`fitter` in the truth), then these commands run as subprocesses of the console script, each with a time limit:

    duhem fit FILES -o m.json --fmu m.fmu --compare --json   # joint fit, FMU, the classical models beside it
    duhem validate m.fmu FILES --json                        # the FMU fit wrote, in fmpy
    duhem diagnose FILES --json d.json                       # what the joint model misses
    duhem fit FILE -o f_i.json --json                        # per file (sets of several files)

The table gives per file: the joint fit's NRMSE (all samples, stored x0), the FMU's (validate) and whether it equals
the fit's, the diagnosis' base and extended model's NRMSE, the best classical model (Preisach, Prandtl-Ishlinskii,
Bouc-Wen, initial state fitted per recording) and the per-file fit; per set the model, the verdict and findings, the
time of each command and the flags: ``CRASH`` (traceback, internal error, signal, time-out or a non-zero exit
without the one-line error), ``REFUSED`` (a one-line error on these valid recordings), ``NOTHING_MISSING_2X``
(verdict ``nothing_missing`` while a per-file fit is at least 2x better than the joint base on some file),
``PER_FILE_WORSE`` (a fit of one file alone is 1.5x worse on it than the joint fit of all: a search that missed),
``FMU_MISMATCH`` (the FMU fit wrote does not validate: refused, or its NRMSE differs from the fit's) and
``FMU_THRESHOLD`` (validate exits 3: the NRMSE exceeds 0.05). A failed command is run again with
``DUHEM_DEBUG=1`` to record its traceback (``--no-debug-rerun`` skips that).

The simulators (`bench/zoo_physics.py`), with their references:

1. ``jiles_atherton``: Jiles-Atherton magnetisation (D. C. Jiles, D. L. Atherton, J. Magn. Magn. Mater. 61 (1986)
   48) with the classical eddy-current field of a thin lamination (D. C. Jiles, J. Appl. Phys. 76 (1994) 5849;
   H_eddy = sigma d^2 / 12 dB/dt): H = H_m + k_e dB/dt, M_an = M_s L((H_m + alpha M) / a),
   dM_irr/dH_m = (M_an - M_irr) / (k delta - alpha (M_an - M_irr)) (0 when delta (M_an - M_irr) < 0),
   M = c M_an + (1 - c) M_irr, B = mu0 (H_m + M); M_s 1.6e6 A/m, a 1100 A/m, k 400 A/m, alpha 1e-3, c 0.2,
   k_e 0.4 A s/(m T); H = 5000 sin(2 pi f t) A/m at 5, 50 and 200 Hz from the demagnetised state; output B in T.
2. ``bouc_wen_pinching``: Baber-Noori pinching (T. T. Baber, M. N. Noori, J. Vib. Acoust. 108 (1986) 411; Foliente,
   J. Struct. Eng. 121 (1995) 1013), no degradation: dz/du = h(z) (A - |z|^n (beta sgn(du z) + gamma)),
   h(z) = 1 - zeta1 exp(-(z sgn(du) - q z_u)^2 / zeta2^2), z_u = (A / (beta + gamma))^(1/n); A 1, beta = gamma 0.5,
   n 2, zeta1 0.85, zeta2 0.2, q 0.15; y = 0.1 u + 0.9 z; a 0.5 Hz sine decaying from 4 to 0.4, and one growing.
3. ``preisach``: a discrete Preisach model (F. Preisach, Z. Phys. 94 (1935) 277; I. D. Mayergoyz, Mathematical
   Models of Hysteresis, 1991): y = 5 sum mu(a, b) R_ab[u] over relays a >= b on a 60 x 60 grid of [-1, 1]^2,
   mu ~ exp(-((a - b)/2 - 0.35)^2 / (2 0.15^2) - ((a + b)/2)^2 / (2 0.25^2)); the input sweeps -1.2 -> 1.2, then
   through 8 (quick) or 14 random turning points at 1 unit/s (nested minor loops); two seeds.
4. ``play`` and ``dead_zone``: y = 2 P_w[u], the play z = min(max(z, u - w), u + w) (M. A. Krasnosel'skii,
   A. V. Pokrovskii, Systems with Hysteresis, 1989), w = 0.2, and y = 2 sgn(u) max(|u| - 0.2, 0) (memoryless); a
   1 Hz triangle of amplitude 1 and a 0.5 Hz sine of amplitude 0.6.
5. ``maxwell_slip``: generalized Maxwell-slip friction (Lampaert, Al-Bender, Swevers, 2003; Iwan, 1966) with
   displacement input: s_i <- clip(s_i + du, -f_i/k_i, f_i/k_i), F = sum k_i s_i + k_0 u, 8 elements k_i = 2,
   f_i = 2 linspace(0.05, 0.8), k_0 = 0.5; sines of 1 at 1 Hz and 0.35 at 2 Hz (offset 1 % of the range).
6. ``input_lag``: a Bouc-Wen loop (Y.-K. Wen, J. Eng. Mech. 102 (1976) 249) behind a first-order lag of the input
   (a sensor/driver lag): tau du_f/dt = u - u_f, tau = 10 ms, y = 0.3 u_f + 0.7 z, dz/dv = 1 - |z| (0.5 sgn(dv z)
   + 0.5), v = 3 u_f; unit sines at 0.5, 3 and 12 Hz (offsets 0, +0.5, -0.5 % of the range).
7. ``log_creep``: piezo creep after steps (H. Jung, D.-G. Gweon, Rev. Sci. Instrum. 71 (2000) 1896):
   y = y_h(u) + gamma sum_j dy_j log10(1 + (t - t_j) / tau), gamma 0.025, tau 0.05 s, dy_j the step of y_h over the
   0.1 s ramp of step j, y_h the Bouc-Wen loop of 6.; staircases of 0.25 and 0.5 steps held 5 and 8 s (quick 2, 3.2).
8. ``pi_saturation``: Prandtl-Ishlinskii followed by a saturation (K. Kuhnen, Eur. J. Control 9 (2003) 407):
   y = 0.8 tanh(sum w_i P_{r_i}[u] / 0.8), r_i = linspace(0, 0.9, 10), w_i = 0.4 exp(-2 r_i); an
   amplitude-modulated 1 Hz sine and a 0.5 Hz triangle of 0.8.
9. ``mr_damper``: Spencer's phenomenological MR damper (B. F. Spencer Jr. et al., J. Eng. Mech. 123 (1997) 230),
   dy/dt = (alpha z + c0 dx/dt + k0 (x - y)) / (c0 + c1), dz/dt = -gamma |dx/dt - dy/dt| z |z| - beta (dx/dt - dy/dt)
   z^2 + A (dx/dt - dy/dt), F = c1 dy/dt + k1 (x - x0), their 0 V parameters (N, cm, s); x = 1.5 sin(2 pi f t) cm
   at 1, 2.5 and 4 Hz; the input is the velocity dx/dt, the output the force (offsets 0, +0.5, -0.5 %).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from zoo_physics import SETS, make_set  # noqa: E402

THRESHOLD = 0.05  # duhem validate's default


@dataclass
class Run:
    """One finished (or timed-out) command."""

    cmd: list[str]
    rc: int | None
    seconds: float
    stdout: str
    stderr: str

    def problem(self, ok: tuple[int, ...] = (0,)) -> str | None:
        """None when the command ended as expected, else 'crash: ...' or 'refused: ...' with its message."""
        lines = [ln for ln in self.stderr.strip().splitlines() if ln.strip()]
        last = lines[-1] if lines else ""
        if self.rc is None:
            return "crash: time-out"
        if "Traceback" in self.stderr:
            return "crash: traceback: " + last
        if self.rc < 0:
            return f"crash: killed by signal {-self.rc}"
        if self.rc in ok:
            return None
        if last.startswith("error:") and "internal error" not in last:
            return "refused: " + last
        return f"crash: exit {self.rc}: " + (last or "(no message)")

    def record(self) -> dict:
        """The command, exit code, time and stderr (the last 40 lines) as JSON-ready values."""
        return {
            "cmd": " ".join(self.cmd),
            "rc": self.rc,
            "seconds": round(self.seconds, 1),
            "stderr": "\n".join(self.stderr.strip().splitlines()[-40:]),
        }


def duhem_exe() -> str:
    """The console script beside this interpreter, else the one on PATH."""
    here = Path(sys.executable).with_name("duhem")
    found = str(here) if here.exists() else shutil.which("duhem")
    if not found:
        raise SystemExit("duhem console script not found (run with the project's venv python)")
    return found


def run(args: list[str], timeout: float, env: dict | None = None) -> Run:
    """Run ``duhem ARGS`` with a time limit; a timed-out command is killed with its process group."""
    cmd = [duhem_exe(), *args]
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, **(env or {})},
        start_new_session=True,
    )
    try:
        out, err = proc.communicate(timeout=timeout)
        rc = proc.returncode
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)
        out, err = proc.communicate()
        rc = None
    return Run(cmd, rc, time.perf_counter() - t0, out, err)


def log(msg: str) -> None:
    """Progress on stderr."""
    print(msg, file=sys.stderr, flush=True)


def checked(args: list[str], opts: argparse.Namespace, ok: tuple[int, ...] = (0,)) -> tuple[Run, dict]:
    """Run a command; on a problem, run it again with DUHEM_DEBUG=1 to keep the traceback."""
    r = run(args, opts.timeout)
    rec = r.record()
    rec["problem"] = r.problem(ok)
    log(
        f"  {r.seconds:6.1f} s  rc={r.rc}  duhem {' '.join(Path(a).name if '/' in a else a for a in args)}"
        + (f"  [{rec['problem']}]" if rec["problem"] else "")
    )
    if rec["problem"] and r.rc is not None and not opts.no_debug_rerun:
        d = run(args, opts.timeout, {"DUHEM_DEBUG": "1"})
        rec["debug_stderr"] = "\n".join(d.stderr.strip().splitlines()[-60:])
    return r, rec


def load_json(text: str) -> dict | None:
    """JSON of a command's stdout, or None."""
    try:
        return json.loads(text)
    except (json.JSONDecodeError, TypeError):
        return None


def parse_fit(summary: dict) -> dict:
    """Model, per-file NRMSE and the best classical model per file from a fit summary."""
    per = {r["recording"]: r["nrmse"] for r in summary.get("recordings", [])}
    best: dict[str, tuple[str, float]] = {}
    for model, res in (summary.get("comparison") or {}).get("baselines", {}).items():
        for name, v in (res.get("one_for_all") or {}).items():
            if v is not None and (name not in best or v < best[name][1]):
                best[name] = (model, v)
    own = {r["recording"]: r.get("nrmse_x0_fitted") for r in summary.get("recordings", [])}
    return {
        "model": f"{summary.get('kind')}{summary.get('order')}",
        "nrmse": per,
        "nrmse_own_x0": own,
        "classical": best,
        "budget_hit": (summary.get("optimiser") or {}).get("budget_hit"),
    }


def parse_validate(data: dict) -> dict:
    """Per-file FMU NRMSE, pass and largest FMU-vs-kernel difference from `duhem validate --json`."""
    recs = data.get("recordings", [])
    return {
        "passed": data.get("passed"),
        "nrmse": {r["recording"]: r["nrmse"] for r in recs},
        "fmu_vs_kernel": max((r.get("fmu_vs_in_process_max_abs") or 0.0) for r in recs) if recs else None,
        "fmu_vs_kernel_of_limit": max(
            (r.get("fmu_vs_in_process_max_abs") or 0.0) / (r.get("fmu_vs_in_process_limit") or 1.0) for r in recs
        )
        if recs
        else None,
        "warnings": sorted({w for r in recs for w in r.get("warnings", [])}),
    }


def parse_diagnosis(d: dict) -> dict:
    """Verdict, findings, base and extended NRMSE per file and the remainder from a diagnosis JSON."""
    ext = d.get("extended") or {}
    rem = ext.get("remainder") or {}
    return {
        "verdict": d.get("verdict"),
        "findings": [
            f"{f['effect']}({f.get('origin')}{', partial' if f.get('partial') else ''}, "
            f"{f.get('explained_fraction', 0):.2f})"
            for f in d.get("findings", [])
        ],
        "base": (d.get("baseline") or {}).get("nrmse_per_recording", {}),
        "base_noise_ratio": (d.get("baseline") or {}).get("noise_ratio"),
        "extended": ext.get("nrmse_per_recording", {}),
        "ext_noise_ratio": ext.get("noise_ratio"),
        "base_order": (d.get("base_model") or {}).get("order"),
        "remainder": {k: rem.get(k) for k in ("structured", "explained", "lag1", "worst_recording")},
    }


def fit_step(files: list[str], folder: Path, opts) -> dict:
    """The joint fit with FMU and comparison."""
    r, rec = checked(
        ["fit", *files, "-o", str(folder / "m.json"), "--fmu", str(folder / "m.fmu"), "--compare", "--json"], opts
    )
    data = load_json(r.stdout) if r.rc == 0 else None
    rec.update(parse_fit(data["summary"]) if data else {})
    rec["fmu_written"] = (folder / "m.fmu").exists()
    return rec


def validate_step(files: list[str], folder: Path, opts) -> dict:
    """`duhem validate` of the FMU the fit wrote (exit 3 = over the threshold, not a failure of the command)."""
    r, rec = checked(["validate", str(folder / "m.fmu"), *files, "--json"], opts, ok=(0, 3))
    data = load_json(r.stdout)
    rec.update(parse_validate(data) if data else {})
    return rec


def diagnose_step(files: list[str], folder: Path, opts) -> dict:
    """`duhem diagnose` with its JSON written to a file."""
    out = folder / "d.json"
    r, rec = checked(["diagnose", *files, "--json", str(out)], opts)
    if r.rc == 0 and out.exists():
        rec.update(parse_diagnosis(json.loads(out.read_text())))
    return rec


def per_file_step(files: list[str], folder: Path, opts) -> list[dict]:
    """`duhem fit FILE` for every file of a set of several."""
    recs = []
    for i, f in enumerate(files):
        r, rec = checked(["fit", f, "-o", str(folder / f"f{i}.json"), "--json"], opts)
        data = load_json(r.stdout) if r.rc == 0 else None
        rec.update(parse_fit(data["summary"]) if data else {})
        recs.append(rec)
    return recs


def flags(res: dict) -> list[str]:
    """The flags of one set (module docstring)."""
    out = []
    steps = [("fit", res["fit"]), ("validate", res.get("validate") or {}), ("diagnose", res["diagnose"])]
    steps += [(f"per-file fit {i + 1}", p) for i, p in enumerate(res["per_file"])]
    for name, step in steps:
        p = step.get("problem") or ""
        if p.startswith("crash"):
            out.append(f"CRASH({name})")
        elif p.startswith("refused"):
            out.append(f"REFUSED({name})")
    if res["diagnose"].get("verdict") == "nothing_missing" and res["ratio_base_per_file"]:
        if max(res["ratio_base_per_file"].values()) >= 2:
            out.append("NOTHING_MISSING_2X")
    for i, name in enumerate(res["files"] if res["per_file"] else []):
        joint, pf = res["fit"].get("nrmse", {}).get(name), res["per_file"][i].get("nrmse", {}).get(name)
        if joint and pf and pf >= 1.5 * joint:
            out.append(f"PER_FILE_WORSE({name}: {pf / joint:.2g}x the joint fit)")
    out += fmu_flags(res)
    return out


def fmu_flags(res: dict) -> list[str]:
    """FMU_MISMATCH / FMU_THRESHOLD for the FMU that the joint fit wrote (none written is a mismatch too)."""
    fit, val = res["fit"], res.get("validate")
    if fit.get("rc") != 0:
        return []
    if not fit.get("fmu_written") or val is None:
        return ["FMU_MISMATCH(no FMU written)"]
    if (val.get("problem") or "").startswith(("crash", "refused")) or "nrmse" not in val:
        return ["FMU_MISMATCH(validate failed)"]
    out = []
    for name, v in fit.get("nrmse", {}).items():
        w = val["nrmse"].get(name)
        if w is None or abs(w - v) > 1e-6 + 1e-4 * abs(v):
            out.append(f"FMU_MISMATCH({name}: fit {v:.6g}, FMU {w})")
    if val.get("rc") == 3:
        out.append("FMU_THRESHOLD")
    return out


def run_set(name: str, root: Path, opts) -> dict:
    """Write one set's recordings and run every command on them."""
    folder = root / name
    folder.mkdir(parents=True, exist_ok=True)
    recs = make_set(name, opts.quick)
    files = [str(r.write(folder)) for r in recs]
    log(f"[{name}] {len(files)} file(s), {sum(len(r.t) for r in recs)} samples in all")
    res = {
        "set": name,
        "physics": SETS[name].physics,
        "nearest": SETS[name].nearest,
        "files": [r.name for r in recs],
        "samples": [len(r.t) for r in recs],
    }
    res["fit"] = fit_step(files, folder, opts)
    res["validate"] = validate_step(files, folder, opts) if res["fit"]["fmu_written"] else None
    res["diagnose"] = diagnose_step(files, folder, opts)
    res["per_file"] = per_file_step(files, folder, opts) if len(files) > 1 and not opts.no_per_file else []
    res["ratio_base_per_file"] = ratios(res)
    res["flags"] = flags(res)
    return res


def ratios(res: dict) -> dict:
    """Per file: the diagnosis' joint base NRMSE over the per-file fit's (falling back to the joint fit's)."""
    out = {}
    for i, name in enumerate(res["files"]):
        pf = res["per_file"][i].get("nrmse", {}).get(name) if res["per_file"] else None
        base = res["diagnose"].get("base", {}).get(name, res["fit"].get("nrmse", {}).get(name))
        if pf and base:
            out[name] = base / pf
    return out


# ------------------------------------------------------------------------------------------------------ table
def fmt(v: float | None, width: int = 8) -> str:
    """A number as %.4f (or 3 significant digits when large), '-' for none."""
    if v is None:
        return "-".rjust(width)
    return (f"{v:.4f}" if abs(v) < 10 else f"{v:.3g}").rjust(width)


def file_rows(res: dict) -> list[str]:
    """The table rows of one set's files."""
    rows = []
    fit, val, diag = res["fit"], res.get("validate") or {}, res["diagnose"]
    for i, name in enumerate(res["files"]):
        f = fit.get("nrmse", {}).get(name)
        w = val.get("nrmse", {}).get(name)
        same = "-" if f is None or w is None else ("=" if abs(w - f) <= 1e-6 + 1e-4 * abs(f) else "!=")
        cl = fit.get("classical", {}).get(name)
        pf = res["per_file"][i].get("nrmse", {}).get(name) if res["per_file"] else None
        rows.append(
            f"{(res['set'] if i == 0 else ''):18s} {name:17s} {res['samples'][i]:5d} {fmt(f)} {fmt(w)} {same:>2s} "
            f"{fmt(diag.get('base', {}).get(name))} {fmt(diag.get('extended', {}).get(name))} "
            f"{(cl[0][:9] if cl else '-'):>9s} {fmt(cl[1] if cl else None)} {fmt(pf)} "
            f"{fmt(res['ratio_base_per_file'].get(name), 6)}"
        )
    return rows


def set_lines(res: dict) -> list[str]:
    """The summary lines under one set's rows: model, verdict, findings, times, flags."""
    fit, diag = res["fit"], res["diagnose"]
    times = [f"fit {fit['seconds']:.0f}"]
    if res.get("validate"):
        times.append(f"validate {res['validate']['seconds']:.0f}")
    times.append(f"diagnose {diag['seconds']:.0f}")
    if res["per_file"]:
        times.append("per-file " + "+".join(f"{p['seconds']:.0f}" for p in res["per_file"]))
    pf_models = ",".join(p.get("model", "-") for p in res["per_file"])
    lines = [
        f"{'':18s} physics: {res['physics']} (nearest catalogue effect: {res['nearest']})",
        f"{'':18s} joint {fit.get('model', '-')}{' (budget hit)' if fit.get('budget_hit') else ''}"
        f"{'; per-file ' + pf_models if pf_models else ''}; diagnosis base order {diag.get('base_order', '-')}, "
        f"noise ratio {fmt(diag.get('base_noise_ratio'), 0)} -> {fmt(diag.get('ext_noise_ratio'), 0)}",
        f"{'':18s} verdict {diag.get('verdict', '-')}: {', '.join(diag.get('findings', [])) or 'no findings'}"
        f"; remainder {diag.get('remainder', {})}",
        f"{'':18s} seconds: {', '.join(times)}",
        *(f"{'':18s} joint fit {w}" for w in warnings(fit)),
        *(
            f"{'':18s} note: {n}: joint NRMSE {v:.4f} from the stored x0, {fit['nrmse_own_x0'][n]:.4f} from its own"
            for n, v in fit.get("nrmse", {}).items()
            if v > 2 * (fit.get("nrmse_own_x0", {}).get(n) or v)
        ),
        f"{'':18s} flags: {', '.join(res['flags']) or 'none'}",
    ]
    for step in [fit, res.get("validate") or {}, diag, *res["per_file"]]:
        if step.get("problem"):
            lines.append(f"{'':18s} !! {step['cmd']}\n{'':21s}{step['problem']}")
    return lines


def warnings(step: dict) -> list[str]:
    """The warning lines of a command's stderr, each cut after its first clause."""
    lines = [ln for ln in step.get("stderr", "").splitlines() if ln.startswith("warning:")]
    return [ln.split(":", 1)[0] + ":" + ln.split(":", 1)[1].split(";")[0][:110] for ln in lines]


def print_table(results: list[dict]) -> None:
    """The one table: a row per file, a block per set."""
    head = (
        f"{'set':18s} {'file':17s} {'N':>5s} {'joint':>8s} {'FMU':>8s} {'':2s} {'diag base':>8s} "
        f"{'extended':>8s} {'classical':>9s} {'NRMSE':>8s} {'per-file':>8s} {'b/pf':>6s}"
    )
    print(head)
    print("-" * len(head))
    for res in results:
        print("\n".join(file_rows(res) + set_lines(res)))
        print("-" * len(head))
    print(
        "NRMSE = RMS error / output range over all samples. joint: `duhem fit FILES` from the stored x0; FMU: "
        "`duhem validate` of its FMU (= the same to 1e-4 rel.); diag base / extended: `duhem diagnose` (x0 and "
        "reference fitted per file); classical: the best of --compare (one model for all, x0 per file); "
        "per-file: `duhem fit FILE`; b/pf: diag base / per-file."
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default=",".join(SETS), help=f"comma-separated, from: {', '.join(SETS)}")
    ap.add_argument("--quick", action="store_true", help="shorter recordings")
    ap.add_argument("--json", action="store_true", help="print the results as JSON instead of the table")
    ap.add_argument("--out", type=Path, help="folder for recordings, models, FMUs (default: a temporary one)")
    ap.add_argument("--timeout", type=float, default=600.0, help="time limit of each command, s")
    ap.add_argument("--no-per-file", action="store_true", help="skip the per-file fits")
    ap.add_argument("--no-debug-rerun", action="store_true", help="do not re-run failed commands with DUHEM_DEBUG=1")
    ap.add_argument("--table", type=Path, help="print the table of a saved zoo.json and exit (nothing is run)")
    opts = ap.parse_args()
    if opts.table:
        results = json.loads(opts.table.read_text())
        for res in results:  # the flags as this version of the runner sets them
            res["flags"] = flags(res)
        print(json.dumps(results, indent=1, default=str)) if opts.json else print_table(results)
        return
    names = [s.strip() for s in opts.sets.split(",") if s.strip()]
    unknown = [n for n in names if n not in SETS]
    if unknown:
        ap.error(f"unknown set(s) {', '.join(unknown)}; choose from {', '.join(SETS)}")
    root = opts.out or Path(tempfile.mkdtemp(prefix="duhem-zoo-"))
    root.mkdir(parents=True, exist_ok=True)
    log(f"writing to {root}")
    results = []
    for name in names:
        results.append(run_set(name, root, opts))
        (root / "zoo.json").write_text(json.dumps(results, indent=1, default=str))
    if opts.json:
        print(json.dumps(results, indent=1, default=str))
    else:
        print_table(results)


if __name__ == "__main__":
    main()
