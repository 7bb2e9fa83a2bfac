"""The `duhem` command line: fit, export, validate, simulate, diagnose, reproduce-paper.

Conventions shared by every command
-----------------------------------
* ``--json`` prints one JSON document on stdout (``diagnose --json OUT.json``
  writes it to a file, ``-`` for stdout); without it a short human-readable
  summary goes to stdout.  Progress goes to stderr (rich; silent when stderr
  is not a terminal).
* An error is one line on stderr, ``error: <file>: <what>``, and exit code 1;
  a command-line usage error is exit code 2 (click); a validation whose NRMSE
  exceeds the threshold is exit code 3.  No traceback is shown (set
  ``DUHEM_DEBUG=1`` to see one).  Numerical warnings of the optimisers
  (e.g. an overflow in a rejected trial step) are not shown either: the
  command's own result says whether the fit converged.
* Every output file is written under a temporary name in its directory and
  renamed into place, so a failure never leaves a partial file; it gets the
  usual mode (0o666 & ~umask), not the 0600 of `tempfile.mkstemp`.  Report
  directories are filled from a temporary directory, file by file.
* FMUs are built with the ``native`` backend by default (a C library: the
  simulator needs no Python); ``--backend python`` builds a pythonfmu FMU
  (no C compiler needed at export, but the simulator must provide Python
  with numpy).
"""
from __future__ import annotations

import contextlib
import functools
import json
import os
import shutil
import sys
import tempfile
import warnings
import zipfile
from pathlib import Path
from typing import Callable, Iterator

import click
import numpy as np

from fitter.core.models import ModelFileError, load_model, model_from_dict
from fitter.data.recordings import Recording, load_recording, load_recordings

__all__ = ["main", "CliError", "DEFAULT_THRESHOLD", "EXIT_ERROR", "EXIT_VALIDATION_FAILED"]

DEFAULT_THRESHOLD = 0.05
"""Default `duhem validate` threshold on the NRMSE over the last full cycle (5% of the output range)."""
EXIT_ERROR = 1
EXIT_VALIDATION_FAILED = 3


class CliError(click.ClickException):
    """An error reported as the single line ``error: <message>`` on stderr."""

    exit_code = EXIT_ERROR

    def show(self, file=None) -> None:
        click.echo(f"error: {self.message}", err=True)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if isinstance(exc, (FileNotFoundError, PermissionError, IsADirectoryError)) and exc.filename:
        text = f"{exc.filename}: {exc.strerror or text}"
    return text or type(exc).__name__


def _guarded(func: Callable) -> Callable:
    """Turn every exception of a command into a `CliError` (one line, exit code 1); hide RuntimeWarnings."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            with warnings.catch_warnings():
                if not os.environ.get("DUHEM_DEBUG"):
                    warnings.simplefilter("ignore", RuntimeWarning)
                return func(*args, **kwargs)
        except (click.ClickException, click.exceptions.Exit, click.Abort):
            raise
        except KeyboardInterrupt:
            raise CliError("interrupted") from None
        except Exception as exc:  # every failure becomes one line, never a traceback
            if os.environ.get("DUHEM_DEBUG"):
                raise
            known = isinstance(exc, (ValueError, OSError, RuntimeError))
            raise CliError(_one_line(exc) if known else
                           f"internal error ({type(exc).__name__}): {_one_line(exc)}") from None
    return wrapper


# --------------------------------------------------------------------------- output helpers

def _emit_json(data) -> None:
    click.echo(json.dumps(data, indent=2, allow_nan=False, default=_json_default))


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def _clean_json(obj):
    """Replace NaN/inf floats by None so the output is strict JSON."""
    if isinstance(obj, dict):
        return {k: _clean_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean_json(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    return obj


@contextlib.contextmanager
def _atomic_path(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """A temporary path beside `path`, renamed to `path` when the block succeeds, removed otherwise."""
    target = Path(path)
    if not target.parent.resolve().is_dir():
        raise CliError(f"{path}: directory {target.parent} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=suffix or target.suffix, dir=target.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _umask() -> int:
    """The process's file-creation mask (read by setting it and restoring it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _write_json(path: Path, data) -> None:
    path.write_text(json.dumps(_clean_json(data), indent=2, default=_json_default), encoding="utf-8")


@contextlib.contextmanager
def _report_directory(directory: str | os.PathLike) -> Iterator[Path]:
    """A temporary directory whose files are moved into `directory` when the block succeeds."""
    target = Path(directory)
    parent = target.resolve().parent
    if not parent.is_dir():
        raise CliError(f"{directory}: directory {parent} does not exist")
    if target.exists() and not target.is_dir():
        raise CliError(f"{directory}: exists and is not a directory")
    tmp = Path(tempfile.mkdtemp(prefix=".tmp-report-", dir=parent))
    try:
        yield tmp
        target.mkdir(exist_ok=True)
        for item in sorted(tmp.rglob("*")):
            dest = target / item.relative_to(tmp)
            if item.is_dir():
                dest.mkdir(exist_ok=True)
            else:
                os.replace(item, dest)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def _progress(enabled: bool = True) -> Iterator[Callable[[str], None]]:
    """A one-line rich status on stderr; yields a callback taking a message."""
    from rich.console import Console

    console = Console(stderr=True)
    if not (enabled and console.is_terminal):
        yield lambda message: None
        return
    with console.status("working") as status:
        yield lambda message: status.update(str(message))


def _table(title: str, columns: list[str], rows: list[list]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=title)
    for c in columns:
        table.add_column(c, justify="left" if c == columns[0] else "right")
    for row in rows:
        table.add_row(*[_fmt(v) for v in row])
    Console(file=sys.stdout, soft_wrap=True).print(table)


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, (float, np.floating)):
        return f"{v:.4g}"
    return str(v)


# --------------------------------------------------------------------------- model files

def _is_zip(path: str) -> bool:
    try:
        with open(path, "rb") as fh:
            return fh.read(4) == b"PK\x03\x04"
    except FileNotFoundError:
        raise CliError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise CliError(f"{path}: is a directory") from None


def _load_model_json(path: str):
    """A model from a JSON file written by `duhem fit`; an FMU or a CSV is a clear error."""
    if _is_zip(path):
        raise CliError(f"{path}: is an FMU or zip archive, not a model JSON file "
                       f"(give the JSON written by 'duhem fit')")
    try:
        return load_model(path)
    except ModelFileError as exc:
        raise CliError(f"{exc} (expected the model JSON written by 'duhem fit')") from None


def _check_fmu(path: str) -> None:
    if not _is_zip(path):
        raise CliError(f"{path}: not an FMU (an FMU is a zip archive; for a model JSON use "
                       f"'duhem export' first)")
    try:
        with zipfile.ZipFile(path) as z:
            if "modelDescription.xml" not in z.namelist():
                raise CliError(f"{path}: zip archive without modelDescription.xml, not an FMU")
    except zipfile.BadZipFile:
        raise CliError(f"{path}: damaged zip archive, not a valid FMU") from None


def _model_in_fmu(path: str):
    """The model stored in the FMU's ``resources/model.json`` (None when there is none)."""
    with zipfile.ZipFile(path) as z:
        if "resources/model.json" not in z.namelist():
            return None
        data = json.loads(z.read("resources/model.json").decode("utf-8"))
    return model_from_dict(data, source=f"{path}!resources/model.json")


# --------------------------------------------------------------------------- shared options

def _column_options(func: Callable) -> Callable:
    for name, default, role in (("output", "y", "output"), ("input", "u", "input"),
                                ("time", "time", "time")):
        func = click.option(f"--{name}", f"{name}_col", default=default, show_default=True, metavar="COL",
                            help=f"{role} column: header name, name without unit suffix, or 0-based index")(func)
    return func


def _backend_option(func: Callable) -> Callable:
    return click.option("--backend", type=click.Choice(["native", "python"]), default="native",
                        show_default=True,
                        help="native: C library, the simulator needs no Python (needs a C compiler "
                             "now); python: pythonfmu, the simulator needs Python with numpy")(func)


def _check_fmu_name(path: str | None) -> None:
    if path and Path(path).suffix.lower() != ".fmu":
        raise CliError(f"{path}: an FMU file name must end in .fmu")


def _check_backend(backend: str) -> None:
    """Fail before any long work when the native backend has no C compiler (message names --backend python)."""
    if backend == "native":
        from fitter.fmu.native import find_c_compiler
        find_c_compiler()


def _build_fmu(model, path: str | os.PathLike, backend: str) -> None:
    """`build_fmu.build_fmu` (imported late: it imports pythonfmu)."""
    from build_fmu import build_fmu

    build_fmu(model, path, backend=backend)


def _load(paths, time_col, input_col, output_col) -> list[Recording]:
    return load_recordings(list(paths), time_col, input_col, output_col)


# --------------------------------------------------------------------------- commands

@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="semilinear-duhem")
def main() -> None:
    """Identify semilinear Duhem hysteresis models (Oh & Bernstein 2007) and export them as FMUs.

    Typical use: duhem fit rec.csv -o model.json --fmu model.fmu, then
    duhem validate model.fmu rec.csv.
    """


@main.command()
@click.argument("recordings", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--kind", type=click.Choice(["ri", "rd", "auto"]), default="auto", show_default=True,
              help="rate-independent (eqs 1-2), rate-dependent (eqs 18-19) or chosen by BIC")
@click.option("-o", "--out", "out", required=True, type=click.Path(dir_okay=False),
              help="model JSON file to write")
@click.option("--fmu", type=click.Path(dir_okay=False), help="also export the model as this FMU")
@_backend_option
@click.option("--report", type=click.Path(file_okay=False), help="write a fit report (HTML, PNG) here")
@click.option("--order", type=int, help="state dimension n (default: chosen by BIC)")
@click.option("--q", type=float, help="bound on sigma_max(A+-) of the Section III least squares")
@_column_options
@click.option("--json", "as_json", is_flag=True, help="print the fit summary as JSON")
@_guarded
def fit(recordings, kind, out, fmu, backend, report, order, q, time_col, input_col, output_col, as_json):
    """Fit a model to one or more recordings (one CSV file per experiment, e.g. per rate)."""
    from fitter.core.models import save_model
    from fitter.identification.fit import fit_recordings

    _check_fmu_name(fmu)
    if fmu:
        _check_backend(backend)
    recs = _load(recordings, time_col, input_col, output_col)
    with _progress() as say, contextlib.ExitStack() as outputs:
        model_tmp = outputs.enter_context(_atomic_path(out, ".json"))
        report_tmp = outputs.enter_context(_report_directory(report)) if report else None
        fmu_tmp = outputs.enter_context(_atomic_path(fmu, ".fmu")) if fmu else None
        say(f"fitting {len(recs)} recording(s)")
        result = fit_recordings(recs, kind=kind, order=order, q=q, progress=say)
        save_model(result.model, model_tmp)
        if report_tmp:
            say("writing the fit report")
            from fitter.reports.fit_report import write_fit_report
            write_fit_report(result, recs, report_tmp)
        if fmu_tmp:
            say(f"building the {backend} FMU")
            _build_fmu(result.model, fmu_tmp, backend)
    summary = result.summary
    if as_json:
        _emit_json(_clean_json({"model": out, "fmu": fmu, "backend": backend if fmu else None,
                                "report": report, "summary": summary}))
        return
    click.echo(f"{result.model.kind} model of order {result.model.order} written to {out}"
               + (f", FMU {fmu} ({backend} backend)" if fmu else "") + (f", report in {report}" if report else ""))
    if summary.get("why"):
        click.echo(f"chosen: {summary['why']}")
    conv = summary.get("convergence") or {}
    if conv:
        click.echo(f"convergence condition: {'satisfied' if conv.get('satisfied') else 'VIOLATED'} "
                   f"({conv.get('quantity')} = {_fmt(conv.get('value'))})")
    rows = [[r.get("recording"), r.get("nrmse"), r.get("nrmse_last_cycle"), r.get("max_error"),
             r.get("loop_area_error"), r.get("residual_rms"), r.get("noise_rms")]
            for r in summary.get("recordings", [])]
    _table("fit per recording", ["recording", "NRMSE", "NRMSE last cycle", "max error", "loop area err",
                                 "residual RMS", "noise RMS"], rows)


@main.command()
@click.argument("model", type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out", required=True, type=click.Path(dir_okay=False), help="FMU file to write")
@_backend_option
@click.option("--json", "as_json", is_flag=True, help="print the result as JSON")
@_guarded
def export(model, out, backend, as_json):
    """Export a model JSON as an FMI 2.0 Co-Simulation FMU."""
    m = _load_model_json(model)
    _check_fmu_name(out)
    with _progress() as say, _atomic_path(out, ".fmu") as tmp:
        say(f"building the {backend} FMU")
        _build_fmu(m, tmp, backend)
    if as_json:
        _emit_json({"model": model, "fmu": out, "backend": backend, "kind": m.kind, "order": m.order})
    else:
        click.echo(f"{m.kind} model of order {m.order} exported to {out} ({backend} backend)")


@main.command()
@click.argument("fmu", type=click.Path(dir_okay=False))
@click.argument("recordings", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--threshold", type=float, default=DEFAULT_THRESHOLD, show_default=True,
              help="fail (exit code 3) when the NRMSE over a recording's last full cycle exceeds this")
@click.option("--plot", type=click.Path(dir_okay=False), help="write a PNG overlay of the loops")
@_column_options
@click.option("--json", "as_json", is_flag=True, help="print the comparison as JSON")
@_guarded
def validate(fmu, recordings, threshold, plot, time_col, input_col, output_col, as_json):
    """Drive an FMU with recorded inputs (fmpy) and compare its closed curves with the data.

    Per recording: NRMSE and max error over the last full input cycle and
    overall, the loop-area error, and the largest difference between the
    FMU and the in-process simulation of the model stored in the FMU.
    """
    from fitter.core import simulate
    from fitter.fmu.host import simulate_fmu
    from fitter.data.metrics import compare, last_full_cycle

    if not threshold > 0:
        raise CliError(f"--threshold must be positive, got {threshold}")
    if plot and Path(plot).suffix.lower() != ".png":
        raise CliError(f"{plot}: the plot file name must end in .png")
    _check_fmu(fmu)
    recs = _load(recordings, time_col, input_col, output_col)
    model = _model_in_fmu(fmu)
    rows, outputs = [], []
    with _progress() as say:
        for rec in recs:
            say(f"simulating {rec.name} in the FMU ({len(rec)} samples)")
            y_fmu = simulate_fmu(fmu, rec.t, rec.u)
            m = compare(rec, y_fmu)
            if model is not None:
                y_in = simulate(model, rec.t, rec.u).y
                m["fmu_vs_in_process_max_abs"] = float(np.max(np.abs(y_fmu - y_in)))
            else:
                m["fmu_vs_in_process_max_abs"] = None
            key = m["nrmse_last_cycle"] if m["nrmse_last_cycle"] is not None else m["nrmse"]
            m.update(recording=rec.name, source=rec.source, passed=bool(key <= threshold),
                     judged_on="last full cycle" if m["nrmse_last_cycle"] is not None else "all samples")
            rows.append(m)
            outputs.append(y_fmu)
        if plot:
            say("plotting")
            _plot_loops(plot, recs, outputs, rows, last_full_cycle)
    passed = all(r["passed"] for r in rows)
    result = {"fmu": fmu, "threshold": threshold, "passed": passed, "plot": plot, "recordings": rows}
    if as_json:
        _emit_json(_clean_json(result))
    else:
        _table(f"validation of {fmu} (threshold NRMSE {threshold:g} over the last full cycle)",
               ["recording", "NRMSE last cycle", "max err last cycle", "NRMSE all", "loop area err",
                "FMU vs in-process", "pass"],
               [[r["recording"], r["nrmse_last_cycle"], r["max_error_last_cycle"], r["nrmse"],
                 r["loop_area_error"], r["fmu_vs_in_process_max_abs"], "yes" if r["passed"] else "NO"]
                for r in rows])
    if not passed:
        worst = max(rows, key=lambda r: r["nrmse_last_cycle"] if r["nrmse_last_cycle"] is not None
                    else r["nrmse"])
        value = worst["nrmse_last_cycle"] if worst["nrmse_last_cycle"] is not None else worst["nrmse"]
        click.echo(f"error: {worst['source']}: NRMSE {value:.4g} over the {worst['judged_on']} exceeds "
                   f"the threshold {threshold:g}", err=True)
        sys.exit(EXIT_VALIDATION_FAILED)


def _plot_loops(path: str, recs: list[Recording], outputs: list[np.ndarray], rows: list[dict],
                last_full_cycle) -> None:
    """PNG: per recording, the data (all samples, light) and the FMU's loop over the last full cycle."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(recs)
    cols = min(n, 3)
    rows_n = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows_n, cols, figsize=(4.6 * cols, 3.8 * rows_n), squeeze=False)
    for ax, rec, y_fmu, row in zip(axes.flat, recs, outputs, rows):
        try:
            s = last_full_cycle(rec.u)
        except ValueError:
            s = slice(0, len(rec))
        ax.plot(rec.u, rec.y, ".", ms=2, color="0.75", label="data (all)")
        ax.plot(rec.u[s], rec.y[s], ".", ms=3, color="C0", label="data (last cycle)")
        ax.plot(rec.u[s], y_fmu[s], "-", lw=1.4, color="C3", label="FMU")
        key = row["nrmse_last_cycle"] if row["nrmse_last_cycle"] is not None else row["nrmse"]
        ax.set_title(f"{rec.name}: NRMSE {100 * key:.2f}%", fontsize=9)
        ax.set_xlabel(f"{rec.input.name} [{rec.input.unit}]" if rec.input.unit else rec.input.name)
        ax.set_ylabel(f"{rec.output.name} [{rec.output.unit}]" if rec.output.unit else rec.output.name)
        ax.legend(fontsize=7, loc="best")
    for ax in list(axes.flat)[n:]:
        ax.set_visible(False)
    fig.tight_layout()
    with _atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


@main.command()
@click.argument("model", type=click.Path(dir_okay=False))
@click.argument("input_csv", type=click.Path(dir_okay=False))
@click.option("-o", "--out", "out", required=True, type=click.Path(dir_okay=False),
              help="CSV file to write (columns time,u,y)")
@click.option("--time", "time_col", default="time", show_default=True, metavar="COL", help="time column")
@click.option("--input", "input_col", default="u", show_default=True, metavar="COL", help="input column")
@click.option("--json", "as_json", is_flag=True, help="print a summary as JSON")
@_guarded
def simulate(model, input_csv, out, time_col, input_col, as_json):
    """Simulate a model JSON (in-process kernel) or an FMU (fmpy) for a recorded input.

    The input is taken as piecewise linear between samples; the model starts
    from its stored initial state x0.  The output CSV has columns time,u,y.
    """
    rec = load_recording(input_csv, time_col, input_col, None)
    with _progress() as say, _atomic_path(out, ".csv") as tmp:
        say(f"simulating {len(rec)} samples")
        if _is_zip(model):
            from fitter.fmu.host import simulate_fmu
            _check_fmu(model)
            y = simulate_fmu(model, rec.t, rec.u)
            engine = "fmu"
        else:
            from fitter.core import simulate as run
            y = run(_load_model_json(model), rec.t, rec.u).y
            engine = "in-process"
        np.savetxt(tmp, np.column_stack([rec.t, rec.u, y]), delimiter=",", fmt="%.17g",
                   header="time,u,y", comments="")
    info = {"model": model, "input": input_csv, "out": out, "engine": engine, "samples": len(rec),
            "y_min": float(np.min(y)), "y_max": float(np.max(y))}
    if as_json:
        _emit_json(info)
    else:
        click.echo(f"{len(rec)} samples simulated ({engine}) and written to {out}")


@main.command()
@click.argument("recordings", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--model", "model_path", type=click.Path(dir_okay=False),
              help="base model JSON (default: fit a rate-independent model of order --base-order)")
@click.option("--report", type=click.Path(file_okay=False), help="write the diagnosis report (HTML, PNG) here")
@click.option("--json", "json_out", type=click.Path(dir_okay=False, allow_dash=True),
              help="write the diagnosis as JSON to this file ('-' for stdout)")
@click.option("--fmu", type=click.Path(dir_okay=False), help="export the extended model as this FMU")
@_backend_option
@click.option("--base-order", type=click.IntRange(1, 3), default=1, show_default=True, metavar="N",
              help="without --model: order of the rate-independent base model (1: fitted here, fast; "
                   "2-3: fitted by 'duhem fit --kind ri --order N' first, slower)")
@_column_options
@_guarded
def diagnose(recordings, model_path, report, json_out, fmu, backend, base_order, time_col, input_col,
             output_col):
    """Locate the model-data mismatch of one experiment, name the physics left out, model it.

    The recordings are one experiment in time order on one clock (e.g.
    several rates and a repeat of the first run).
    """
    from fitter.diagnosis.diagnose import diagnose as run_diagnosis, rich_progress

    _check_fmu_name(fmu)
    if model_path and base_order != 1:
        raise CliError("--base-order applies only without --model (the given model sets the base)")
    if fmu:
        _check_backend(backend)
    base = _load_model_json(model_path) if model_path else None
    recs = _load(recordings, time_col, input_col, output_col)
    with contextlib.ExitStack() as outputs:
        json_tmp = outputs.enter_context(_atomic_path(json_out, ".json")) \
            if json_out and json_out != "-" else None
        report_tmp = outputs.enter_context(_report_directory(report)) if report else None
        fmu_tmp = outputs.enter_context(_atomic_path(fmu, ".fmu")) if fmu else None
        if _stderr_is_terminal():
            with rich_progress("diagnosing") as progress:
                result = run_diagnosis(recs, model=base, progress=progress, base_order=base_order)
        else:
            result = run_diagnosis(recs, model=base, base_order=base_order)
        data = _clean_json(result.to_json())
        if report_tmp:
            from fitter.reports.diagnosis_report import write_diagnosis_report
            write_diagnosis_report(result, recs, report_tmp)
        if fmu_tmp:
            _build_fmu(result.extended_model, fmu_tmp, backend)
        if json_tmp:
            _write_json(json_tmp, data)
    if json_out == "-":
        _emit_json(data)
        return
    click.echo(result.paragraph)
    findings = data.get("findings") or []
    if findings:
        _table("findings (most important first)", ["effect", "p-value", "explained fraction"],
               [[f.get("effect"), f.get("p_value"), f.get("explained_fraction")] for f in findings])
    elif result.verdict == "nothing_missing":
        click.echo("nothing missing: the residual is consistent with the noise level")
    else:
        click.echo("unexplained: the residual is above the noise but no candidate effect explains it")


def _stderr_is_terminal() -> bool:
    from rich.console import Console
    return Console(stderr=True).is_terminal


@main.command("reproduce-paper")
@click.option("--json", "as_json", is_flag=True, help="print the figures as JSON")
@click.option("--figures", type=click.Path(file_okay=False), help="save PNG figures like the paper's here")
@click.option("--seeds", type=click.IntRange(min=1), help="number of noise seeds for Example 2")
@_guarded
def reproduce_paper(as_json, figures, seeds):
    """Reproduce Examples 1-3 of Oh & Bernstein (2007): our figures beside the paper's."""
    from fitter.paper.report import main as paper_main

    argv = (["--json"] if as_json else []) + (["--figures", figures] if figures else []) \
        + (["--seeds", str(seeds)] if seeds else [])
    code = paper_main(argv)
    if code:
        sys.exit(code)
