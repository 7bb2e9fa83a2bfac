"""`duhem` on a corpus of public *measured* hysteresis recordings of many physical systems: crashes, FMU validation,
the extended model against the classical ones, per-file fits against the joint model.

    python bench/corpus.py --data DIR                  # every set whose raw files are under DIR
    python bench/corpus.py --data DIR --sets mr-damper,vhb-elastomer --json out.json
    python bench/corpus.py --sources                   # the sources, licences and how to fetch them

The sources (repository, commit, paths, licence, system, units, conversion) are in `bench/corpus_sources.py`; the raw
files are read at run time from ``DIR/<owner>+<name>/<path>`` (``git clone`` + ``git checkout COMMIT``, printed by
``--sources``) and never copied into this repository.  A set whose files are absent is skipped and said so.

Per set, as subprocesses of the console script (``--duhem``, default the ``duhem`` beside this interpreter), each
with a time limit, in a work directory (``--work``, default a temporary one; never inside the repository):

1. the converter writes ``time,u,y`` CSV files (one per recording);
2. ``duhem fit FILES -o m.json --fmu m.fmu --compare --json``: the joint model's NRMSE per file (all samples, stored
   x0; and from each file's own fitted x0), and the classical models' (Preisach, Prandtl-Ishlinskii, Bouc-Wen, their
   initial state fitted per recording);
3. ``duhem validate m.fmu FILES --json``: the FMU's NRMSE and pass (threshold 0.05), FMU against in-process;
4. ``duhem diagnose FILES --json d.json``: verdict, findings, base and extended NRMSE per file;
5. ``duhem fit FILE -o mi.json --json`` for each file alone: what one model per file reaches.

Flags: a crash (a non-zero exit other than validate's 3 for "over threshold", a time-out, a traceback, unreadable
JSON); a ``nothing_missing`` verdict while some per-file fit is at least 2x better than the joint base (the
diagnosis' base NRMSE of that file); an FMU written by ``fit --fmu`` that ``validate`` refuses, or whose NRMSE
differs from the fit's own figure for that file (more than 2 % relative), or that fails only the threshold (noted,
not a bug: the model is as inaccurate as the fit said).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from corpus_sources import NOT_USED, SOURCES, MissingData, Source  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
LIMITS = {"fit": 900, "validate": 300, "diagnose": 1200, "fit1": 600}


def run(cmd: list[str], limit: float, log: Path) -> dict:
    """Run one command; returns rc, seconds, stderr tail, timed_out, traceback."""
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=limit)
        rc, out, err, to = p.returncode, p.stdout, p.stderr, False
    except subprocess.TimeoutExpired as e:
        rc, to = None, True
        out = e.stdout.decode() if isinstance(e.stdout, bytes) else (e.stdout or "")
        err = e.stderr.decode() if isinstance(e.stderr, bytes) else (e.stderr or "")
    dt = time.perf_counter() - t0
    with log.open("a") as f:
        f.write(f"$ {shlex.join(cmd)}\n# rc={rc} timed_out={to} {dt:.1f}s\n--- stdout\n{out}\n--- stderr\n{err}\n\n")
    return {
        "cmd": shlex.join(cmd),
        "rc": rc,
        "seconds": round(dt, 1),
        "timed_out": to,
        "stdout": out,
        "stderr": err.strip()[-4000:],
        "traceback": "Traceback (most recent call last)" in err,
    }


def crash_of(step: str, r: dict, ok_codes=(0,)) -> dict | None:
    if r["timed_out"]:
        return {"step": step, "cmd": r["cmd"], "what": f"time-out after {r['seconds']} s", "stderr": r["stderr"]}
    if r["rc"] not in ok_codes or r["traceback"]:
        lines = r["stderr"].splitlines()
        refused = r["rc"] == 1 and not r["traceback"] and bool(lines) and lines[-1].startswith("error:")
        return {
            "step": step,
            "cmd": r["cmd"],
            "what": f"exit code {r['rc']}" + (" (refused: one-line error)" if refused else ""),
            "stderr": r["stderr"],
            "refused": refused,
        }
    return None


def write_csv(path: Path, t: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time", "u", "y"])
        for a, b, c in zip(t, u, y):
            w.writerow([repr(float(a)), repr(float(b)), repr(float(c))])


def _json(text: str) -> dict | None:
    try:
        return json.loads(text)
    except (json.JSONDecodeError, TypeError):
        return None


def bench_set(src: Source, data: Path, work: Path, duhem: str) -> dict:
    res: dict = {
        "set": src.name,
        "repo": src.repo,
        "commit": src.commit,
        "system": src.system,
        "u": src.u,
        "y": src.y,
        "licence": src.licence,
        "crashes": [],
        "flags": [],
        "files": {},
        "seconds": {},
    }
    try:
        recs = src.convert(src, data)
    except MissingData as e:
        res["skipped"] = f"raw file absent: {e}"
        return res
    d = work / src.name
    d.mkdir(parents=True, exist_ok=True)
    log = d / "commands.log"
    files = []
    for name, t, u, y in recs:
        ok = np.isfinite(t) & np.isfinite(u) & np.isfinite(y)
        p = d / f"{name}.csv"
        write_csv(p, t[ok], u[ok], y[ok])
        files.append(p)
        res["files"][name] = {"samples": int(ok.sum()), "dropped_non_finite": int((~ok).sum())}
    names = [p.stem for p in files]
    fs = [str(p) for p in files]

    # 1. the joint fit, FMU, classical models
    r = run(
        [duhem, "fit", *fs, "-o", str(d / "m.json"), "--fmu", str(d / "m.fmu"), "--compare", "--json"],
        LIMITS["fit"],
        log,
    )
    res["seconds"]["fit"] = r["seconds"]
    c = crash_of("fit --fmu --compare", r)
    fit = _json(r["stdout"]) if c is None else None
    if c is None and fit is None:
        c = {"step": "fit --fmu --compare", "cmd": r["cmd"], "what": "stdout is not JSON", "stderr": r["stderr"]}
    if c:
        res["crashes"].append(c)
    if fit:
        s = fit["summary"]
        res["model"] = f"{s.get('kind')}{s.get('order')}"
        res["budget_hit"] = bool((s.get("optimiser") or {}).get("budget_hit"))
        for rec in s.get("recordings", []):
            f = res["files"].setdefault(rec["recording"], {})
            f["fit"] = rec.get("nrmse")
            f["fit_own_x0"] = rec.get("nrmse_x0_fitted")
        comp = s.get("comparison") or {}
        for nm, b in (comp.get("baselines") or {}).items():
            for rec, v in ((b or {}).get("one_for_all") or {}).items():
                res["files"].setdefault(rec, {}).setdefault("classical", {})[nm] = v
        for rec, v in (comp.get("duhem") or {}).items():
            res["files"].setdefault(rec, {})["compare_duhem"] = v

    # 2. the FMU against the recordings
    if (d / "m.fmu").is_file() and fit:
        r = run([duhem, "validate", str(d / "m.fmu"), *fs, "--json"], LIMITS["validate"], log)
        res["seconds"]["validate"] = r["seconds"]
        c = crash_of("validate", r, ok_codes=(0, 3))
        val = _json(r["stdout"]) if c is None else None
        if c:
            res["crashes"].append(c)
            res["flags"].append(f"the FMU from fit --fmu is refused by validate ({c['what']}): {c['stderr'][-300:]}")
        for rec in (val or {}).get("recordings", []):
            f = res["files"].setdefault(rec["recording"], {})
            f["fmu"], f["fmu_pass"] = rec.get("nrmse"), rec.get("passed")
            f["fmu_vs_in_process"] = rec.get("fmu_vs_in_process_max_abs")
            fv = f.get("fit")
            if fv and f["fmu"] is not None and abs(f["fmu"] - fv) > 0.02 * fv:
                res["flags"].append(f"{rec['recording']}: FMU NRMSE {f['fmu']:.4g} differs from the fit's {fv:.4g}")
            elif f["fmu_pass"] is False:
                res["flags"].append(
                    f"{rec['recording']}: FMU fails validate's threshold only (NRMSE {f['fmu']:.4g}, "
                    "as the fit reported: an inaccurate model, not a broken FMU)"
                )
        if val and not val.get("passed"):  # the same FMU started from each file's own fitted state
            r = run([duhem, "validate", str(d / "m.fmu"), *fs, "--x0", "fitted", "--json"], LIMITS["validate"], log)
            c = crash_of("validate --x0 fitted", r, ok_codes=(0, 3))
            if c:
                res["crashes"].append(c)
            for rec in (_json(r["stdout"]) or {}).get("recordings", []) if c is None else []:
                f = res["files"].setdefault(rec["recording"], {})
                f["fmu_own_x0"], f["fmu_own_x0_pass"] = rec.get("nrmse"), rec.get("passed")
    elif fit:
        res["flags"].append("fit --fmu reported success but wrote no FMU")

    # 3. the diagnosis
    r = run([duhem, "diagnose", *fs, "--json", str(d / "d.json")], LIMITS["diagnose"], log)
    res["seconds"]["diagnose"] = r["seconds"]
    c = crash_of("diagnose", r)
    diag = None
    if c is None:
        try:
            diag = json.loads((d / "d.json").read_text())
        except (OSError, json.JSONDecodeError) as e:
            c = {"step": "diagnose", "cmd": r["cmd"], "what": f"no readable JSON: {e}", "stderr": r["stderr"]}
    if c:
        res["crashes"].append(c)
    if diag:
        res["verdict"] = diag.get("verdict")
        res["findings"] = [
            f"{x.get('effect')}{'(partial)' if x.get('partial') else ''}" for x in diag.get("findings") or []
        ]
        res["noise_rms"] = diag.get("noise_rms")
        res["diag_paragraph"] = (diag.get("summary") or "")[:1500]
        for key, col in (("baseline", "diag_base"), ("extended", "diag_ext")):
            for rec, v in ((diag.get(key) or {}).get("nrmse_per_recording") or {}).items():
                res["files"].setdefault(rec, {})[col] = v

    # 4. one model per file
    t1 = 0.0
    for p in files:
        r = run([duhem, "fit", str(p), "-o", str(d / f"single_{p.stem}.json"), "--json"], LIMITS["fit1"], log)
        t1 += r["seconds"]
        c = crash_of(f"fit {p.name} alone", r)
        one = _json(r["stdout"]) if c is None else None
        if c:
            res["crashes"].append(c)
        for rec in ((one or {}).get("summary") or {}).get("recordings", []):
            f = res["files"].setdefault(p.stem, {})
            f["single"] = rec.get("nrmse")
            f["single_model"] = f"{one['summary'].get('kind')}{one['summary'].get('order')}"
    res["seconds"]["single_fits"] = round(t1, 1)

    res["names"] = names
    derive_flags(res)
    return res


def derive_flags(res: dict) -> None:
    """The flags that compare figures across steps (also re-derived by --from-json)."""
    res["derived_flags"] = []
    for n in res.get("names", []):
        f = res["files"].get(n, {})
        base, one, ext = f.get("diag_base"), f.get("single"), f.get("diag_ext")
        if base and one and base >= 2 * one:
            f["base_over_single"] = base / one
            if res.get("verdict") == "nothing_missing":
                res["derived_flags"].append(
                    f"{n}: verdict nothing_missing but one model for this file alone reaches "
                    f"{one:.4g} against the joint base's {base:.4g} ({base / one:.1f}x)"
                )
            elif res.get("verdict") and ext and ext >= 0.8 * one:
                res["derived_flags"].append(
                    f"{n}: the diagnosis' base ({base:.4g}) is {base / one:.1f}x worse than `duhem fit` of this "
                    f"file alone ({one:.4g}), and its extended model ({ext:.4g}) is no better than that fit: the "
                    f"findings ({', '.join(res.get('findings') or []) or '-'}) make up for a weak base"
                )
        st, own = f.get("fit"), f.get("fit_own_x0")
        if st and own and st >= 5 * own:
            res["derived_flags"].append(
                f"{n}: the joint model from its stored x0 (what the FMU runs) gives {st:.4g}, from this file's own "
                f"fitted x0 {own:.4g} ({st / own:.0f}x): the stored state (fitted to the first recording's start) "
                "does not suit this one"
            )
        if one and own and one > 1.2 * own:
            res["derived_flags"].append(
                f"{n}: `duhem fit` of this file alone ({one:.4g}, {f.get('single_model')}) is worse than the joint "
                f"model on it ({own:.4g} from its own x0): the search for this file alone missed a better model"
            )
        cl = f.get("classical") or {}
        best = min(((v, k) for k, v in cl.items() if v is not None), default=None)
        if best:
            f["best_classical"] = f"{best[1]} {best[0]:.4g}"
            if ext is not None and ext > best[0]:
                f["classical_beats_extended"] = True


def fmt(v, w=".4g") -> str:
    return "-" if v is None else (f"{v:{w}}" if isinstance(v, (int, float)) else str(v))


def table(results: list[dict]) -> str:
    head = (
        "| set | file | n | joint fit (own x0) | FMU validate | diag base -> extended | best classical | "
        "file alone | model (alone) | verdict, findings | times fit/val/diag/alone [s] |"
    )
    lines = [head, "|" + "|".join(["---"] * 11) + "|"]
    for r in results:
        if r.get("skipped"):
            lines.append(f"| {r['set']} | skipped: {r['skipped']} |" + " |" * 9)
            continue
        first = True
        for n in r.get("names", []):
            f = r["files"].get(n, {})
            fmu = "-" if f.get("fmu") is None else f"{f['fmu']:.4g} {'pass' if f.get('fmu_pass') else 'FAIL'}"
            if f.get("fmu_own_x0") is not None:
                fmu += f" (own x0 {f['fmu_own_x0']:.4g} {'pass' if f.get('fmu_own_x0_pass') else 'FAIL'})"
            ext = f"{fmt(f.get('diag_base'))} -> {fmt(f.get('diag_ext'))}"
            setcols = ["", "", ""]
            if first:
                v = r.get("verdict") or "-"
                if r.get("findings"):
                    v += ": " + ", ".join(r["findings"])
                s = r["seconds"]
                setcols = [
                    r.get("model", "-") + (" (budget)" if r.get("budget_hit") else ""),
                    v,
                    "/".join(fmt(s.get(k), ".0f") for k in ("fit", "validate", "diagnose", "single_fits")),
                ]
            lines.append(
                f"| {r['set'] if first else ''} | {n} | {f.get('samples', '-')} | {fmt(f.get('fit'))} "
                f"({fmt(f.get('fit_own_x0'))}) | {fmu} | {ext} | {f.get('best_classical', '-')} | "
                f"{fmt(f.get('single'))} | {setcols[0]} ({f.get('single_model', '-')}) | {setcols[1]} | "
                f"{setcols[2]} |"
            )
            first = False
    out = ["\n".join(lines), ""]
    for r in results:
        for c in r.get("crashes", []):
            out.append(
                f"{'REFUSED' if c.get('refused') else 'CRASH'} {r['set']} [{c['step']}] {c['what']}\n"
                f"    $ {c['cmd']}\n    " + "\n    ".join(c["stderr"].splitlines()[-12:])
            )
        for fl in r.get("flags", []) + r.get("derived_flags", []):
            out.append(f"FLAG  {r['set']}: {fl}")
    return "\n".join(out)


def sources_text() -> str:
    out = []
    for s in SOURCES:
        out.append(
            f"{s.name}: {s.system}\n  repo {s.repo} @ {s.commit}\n  paths {', '.join(s.paths)}\n  licence "
            f"{s.licence}\n  u = {s.u}, y = {s.y}; {s.sampling}{'; time column built' if s.built_time else ''}"
            f"\n  {s.notes}\n  fetch: {s.fetch_lines()}"
        )
    out.append("looked at, not used: " + "; ".join(f"{a} ({b})" for a, b in NOT_USED))
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, help="folder holding <owner>+<name>/<path> of every source")
    ap.add_argument("--sets", default=None, help="comma-separated set names (default: all)")
    ap.add_argument("--json", type=Path, default=None, help="also write the results as JSON here")
    ap.add_argument("--work", type=Path, default=None, help="where the CSVs, models and logs go (default: a temp dir)")
    ap.add_argument("--duhem", default=str(Path(sys.executable).with_name("duhem")), help="the console script")
    ap.add_argument("--sources", action="store_true", help="print the sources and how to fetch them, and exit")
    ap.add_argument("--from-json", type=Path, default=None, help="print the table of an earlier --json, and exit")
    a = ap.parse_args()
    if a.sources:
        print(sources_text())
        return 0
    if a.from_json:
        results = json.loads(a.from_json.read_text())
        for r in results:
            if "derived_flags" not in r:  # a JSON from before derived_flags: its nothing_missing flags re-derived
                r["flags"] = [f for f in r.get("flags", []) if "verdict nothing_missing" not in f]
            derive_flags(r)
        print(table(results))
        return 0
    if a.data is None:
        ap.error("--data DIR is required (see --sources for what goes in it)")
    want = set(a.sets.split(",")) if a.sets else None
    unknown = (want or set()) - {s.name for s in SOURCES}
    if unknown:
        ap.error(f"--sets: unknown {sorted(unknown)}; known: {', '.join(s.name for s in SOURCES)}")
    work = a.work or Path(tempfile.mkdtemp(prefix="duhem-corpus-"))
    if REPO in work.resolve().parents or work.resolve() == REPO:
        ap.error("--work must be outside the repository (the data are never copied into it)")
    results = []
    t0 = time.perf_counter()
    for s in SOURCES:
        if want and s.name not in want:
            continue
        print(f"[{time.perf_counter() - t0:7.0f} s] {s.name} ...", file=sys.stderr, flush=True)
        results.append(bench_set(s, a.data, work, a.duhem))
        if a.json:  # after every set, so that a long run leaves what it has
            a.json.write_text(json.dumps(results, indent=1, default=str))
    print(table(results))
    print(
        f"\nwork directory: {work}; total {time.perf_counter() - t0:.0f} s; DUHEM_WORKERS="
        f"{os.environ.get('DUHEM_WORKERS', '(all cores)')}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
