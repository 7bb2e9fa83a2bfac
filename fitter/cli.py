"""The `duhem` command line: fit, export, validate, simulate, compensate, diagnose, batch, reproduce-paper.

Conventions shared by every command
-----------------------------------
* ``--json`` prints one JSON document on stdout (``diagnose --json OUT.json``
  writes it to a file, ``-`` for stdout); without it a short human-readable
  summary goes to stdout.  Progress goes to stderr (rich; silent when stderr
  is not a terminal: `fitter.progress.stderr_progress`).
* An error is one line on stderr, ``error: <file>: <what>``, and exit code 1
  (also a path that is a directory where a file is expected, or the reverse,
  or unreadable: `fitter.cli_support.FilePath`; a broken FMU names its broken
  part: `fitter.fmu.host.check_fmu_file`; a command-line usage error, every
  numeric option range-checked: `fitter.cli_support.usage_line`); a
  validation whose NRMSE exceeds the threshold is exit code 3.  No
  traceback is shown (set ``DUHEM_DEBUG=1`` to see one), nor the optimisers' numerical warnings
  (`fitter.cli_support.one_line_errors`).
* Every output file is written under a temporary name in its directory and
  renamed into place when the whole command succeeds, so a failure never
  leaves a partial file; it gets the usual mode (0o666 & ~umask).  A report
  directory is written in full beside its target and then replaces it
  (`fitter.core.files`).  One writer per output: a second command writing
  the same path waits (``DUHEM_LOCK_WAIT`` s, default 10), then fails
  naming the first (`fitter.core.files.output_lock`).
* FMUs are built with the ``native`` backend by default (a C library: the
  simulator needs no Python); ``--backend python`` builds a pythonfmu FMU
  (no C compiler needed at export, but the simulator must provide Python
  with numpy).
"""
from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path
from typing import Callable

import click
import numpy as np

from fitter.baselines import comparison
from fitter.batch import BatchOptions, run_batch
from fitter.cli_support import (EXIT_ERROR, CliError, FilePath, GuardedGroup, Number, backend_option,
                                fmi_version_option, ordered_pair)
from fitter.core.checks import check_agreement, check_model, with_convergence
from fitter.core.effects import REGISTRY
from fitter.core.files import atomic_directory, atomic_file, atomic_pair, json_text, jsonable
from fitter.core.inverse import MEASUREMENT_CHOICES, Compensator, linear_gain
from fitter.core.kernel import simulate as simulate_model
from fitter.core.models import load_model, save_model
from fitter.data.metrics import compare
from fitter.data.recordings import load_recording, load_recordings, save_columns
from fitter.diagnosis import diagnose as run_diagnosis
from fitter.diagnosis.procedure import CANDIDATES
from fitter.fmu.build import PYTHON_HOST_NEEDS, build_fmu
from fitter.fmu.host import check_fmu_file, simulate_fmu
from fitter.fmu.variables import start_state_values
from fitter.fmu.native import check_toolchain
from fitter.fmu.pair import check_fmu_pair, recorded_fmu_digest, with_fmu_record
from fitter.fmu.toolchain import PLATFORMS, parse_platforms
from fitter.identification.exported import minor_loop_warning, own_start, range_warnings, started
from fitter.identification.effects_fit import check_effects, check_held
from fitter.identification.explained import check_explained, explained_text, explained_variance
from fitter.identification.fit import ORDERS, fit_recordings
from fitter.paper.report import command as reproduce_paper
from fitter.progress import stderr_progress
from fitter.reports.compensation_plot import write_compensation_plot
from fitter.reports.diagnosis_report import fill_diagnosis_report
from fitter.reports.fit_report import fill_fit_report
from fitter.reports.validation_plot import write_validation_plot

__all__ = ["main", "CliError", "DEFAULT_THRESHOLD", "EXIT_ERROR", "EXIT_VALIDATION_FAILED"]

DEFAULT_THRESHOLD = 0.05
"""Default `duhem validate` threshold on the NRMSE over all samples (5% of the output range)."""
EXIT_VALIDATION_FAILED = 3


# --------------------------------------------------------------------------- console output

def _emit_json(data) -> None:
    click.echo(json_text(data))


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


def _fmt_list(values) -> str:
    return ", ".join(_fmt(v) for v in values or []) or "-"


# --------------------------------------------------------------------------- model files and names

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
    if Path(path).suffix.lower() == ".fmu":
        raise CliError(f"{path}: not an FMU (not a zip archive: damaged or unfinished), nor a model JSON file")
    model = load_model(path)
    note = check_fmu_pair(path, model)
    if note:
        click.echo(f"note: {note}", err=True)
    return model


def _open_fmu(path: str):
    """The model in an FMU argument, every part checked (`check_fmu_file`), after the hint that a model JSON
    is exported first."""
    if not _is_zip(path):
        raise CliError(f"{path}: not an FMU (not a zip archive); for a model JSON use 'duhem export' first")
    return check_fmu_file(path)


def _refuse_overwrite(inputs, *outputs) -> None:
    """A one-line error, before anything is written, when an output path is one of the command's inputs
    (the same file by its real path: a link, a hard link or another spelling counts) or a directory that holds
    one (a report directory is replaced as a whole)."""
    known = {os.path.realpath(str(p)): str(p) for p in inputs if p}
    for out in outputs:
        if not out or out == "-":
            continue
        real = os.path.realpath(str(out))
        same = next((p for r, p in known.items() if r == real or _same_file(str(out), p)), None)
        inside = next((p for r, p in known.items() if r.startswith(real + os.sep)), None)
        if same is not None or inside is not None:
            what = f"is one of this command's inputs ({same})" if same is not None else \
                f"is a directory that holds this command's input {inside} (it would be replaced as a whole)"
            raise CliError(f"{out}: {what}; write the output to another path (the input is left untouched)")


def _same_file(a: str, b: str) -> bool:
    """Whether two existing paths are one file (`os.path.samefile`: hard links too)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _check_fmu_name(path: str | None) -> None:
    if path and Path(path).suffix.lower() != ".fmu":
        raise CliError(f"{path}: an FMU file name must end in .fmu")


def _check_backend(backend: str) -> None:
    """Fail before any long work when the native backend has no compiler (zig; message names --backend python)."""
    if backend == "native":
        check_toolchain()


def _platforms(ctx: click.Context, param: click.Parameter, value: str | None) -> tuple[str, ...] | None:
    try:
        return None if value is None else parse_platforms(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None


# --------------------------------------------------------------------------- shared options

def _no_time(ctx: click.Context, param: click.Parameter, value: bool) -> None:
    ctx.meta["no_time"] = value


def _time_column(time_col: str) -> str | None:
    """The --time column, or None (sample index as time) under --no-time."""
    return None if click.get_current_context().meta.get("no_time") else time_col


def _column_options(func: Callable) -> Callable:
    func = click.option("--no-time", is_flag=True, expose_value=False, callback=_no_time,
                        help="the file has no time column: use the sample index as time (rate-independent "
                             "models only depend on the input's path)")(func)
    for name, default, role in (("output", "y", "output"), ("input", "u", "input"),
                                ("time", "time", "time")):
        func = click.option(f"--{name}", f"{name}_col", default=default, show_default=True, metavar="COL",
                            help=f"{role} column: header name, name without unit suffix, or 0-based index")(func)
    return func


def _allow_unstable_option(func: Callable) -> Callable:
    return click.option("--allow-unstable", is_flag=True,
                        help="export even when the fit recorded a violated convergence condition "
                             "(the FMU's description then says so)")(func)


def _use_unstable_option(func: Callable) -> Callable:
    return click.option("--allow-unstable", is_flag=True,
                        help="use the model even when its convergence condition, checked from its parameters, "
                             "is violated (a warning says so; a non-finite output is still refused)")(func)


def _checked(model, source: str, allow_unstable: bool, *inputs):
    """`fitter.core.checks.check_model` of a model about to be used, on the range of `inputs` (the inputs it is
    run with, for a model without input_range); under --allow-unstable a violated condition is one warning."""
    values = [np.ravel(np.asarray(u, dtype=float)) for u in inputs]
    span = (float(min(v.min() for v in values)), float(max(v.max() for v in values))) if values else None
    conv = check_model(model, source, span=span, allow_unstable=allow_unstable)
    if not conv.satisfied:
        click.echo(f"warning: {source}: the convergence condition is violated ({conv.text()}); used anyway "
                   "(--allow-unstable)", err=True)
    return conv


# --------------------------------------------------------------------------- commands

@click.group("duhem", cls=GuardedGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="semilinear-duhem")
def main() -> None:
    """Identify semilinear Duhem hysteresis models (Oh & Bernstein 2007) and export them as FMUs.

    Typical use: duhem fit rec.csv -o model.json --fmu model.fmu, then
    duhem validate model.fmu rec.csv.
    """


main.add_command(reproduce_paper)


@main.command()
@click.argument("recordings", nargs=-1, required=True, type=FilePath())
@click.option("--kind", type=click.Choice(["ri", "rd", "auto"]), default="auto", show_default=True,
              help="rate-independent (eqs 1-2), rate-dependent (eqs 18-19) or chosen by BIC")
@click.option("-o", "--out", "out", required=True, type=FilePath(),
              help="model JSON file to write")
@click.option("--fmu", type=FilePath(), help="also export the model as this FMU")
@backend_option
@click.option("--report", type=FilePath(directory=True), help="write a fit report (HTML, PNG) here")
@click.option("--order", type=Number(int, low=1, high=max(ORDERS)), help="state dimension n (default: chosen by BIC)")
@click.option("--q", type=Number(low=0, open_low=True), help="bound on sigma_max(A+-) of the Section III least squares")
@click.option("--x0", "x0_policy", type=click.Choice(["fitted", "periodic"]), default="fitted", show_default=True,
              help="stored initial state at the first sample of the first recording: fitted to it (least "
                   "squares), or leading onto the periodic response of its first cycle")
@click.option("--faithful-minor-loops", "faithful", is_flag=True,
              help="keep every settled minor loop within half an output range of the recorded output "
                   "(rate-independent candidates): the model stays near the data on loops smaller than the "
                   "recorded ones, at a cost in accuracy where the recorded loop switches sharply")
@click.option("--effects", "effects", callback=lambda ctx, param, value: _effect_names(value), metavar="NAMES",
              help="effects of the catalogue (comma-separated, e.g. switching) fitted jointly with the base model: "
                   f"physics you know the device has ({', '.join(REGISTRY)})")
@click.option("--hold", "held", callback=lambda ctx, param, value: _held_values(value), metavar="EFFECT.PARAM=VALUE",
              help="with --effects, effect parameters held at a value you know instead of fitted (comma-separated, "
                   "e.g. measurement_drift.rate=0: each recording's output has its own reference, no drift)")
@_allow_unstable_option
@click.option("--allow-noise", is_flag=True,
              help="save the model even when it explains less than half of a recording's output variance "
                   "(R^2 < 0.5: the output looks like noise, with no relation to the input)")
@_column_options
@click.option("--compare", is_flag=True,
              help="also fit the classical models (Preisach, Prandtl-Ishlinskii, Bouc-Wen) to the same recordings "
                   "and show their NRMSE beside the Duhem model's (summary key 'comparison', and in the report)")
@click.option("--json", "as_json", is_flag=True, help="print the fit summary as JSON")
def fit(recordings, kind, out, fmu, backend, report, order, q, x0_policy, faithful, effects, held, allow_unstable,
        allow_noise, time_col, input_col, output_col, compare, as_json):
    """Fit a model to one or more recordings (one CSV file per experiment, e.g. per rate)."""
    if effects and x0_policy != "fitted":
        raise click.UsageError("--effects needs --x0 fitted (each effect's initial state is fitted per recording)")
    held = check_held(held, check_effects(effects))
    _refuse_overwrite(recordings, out, fmu, report)
    _check_fmu_name(fmu)
    if fmu:
        _check_backend(backend)
    recs = load_recordings(list(recordings), _time_column(time_col), input_col, output_col)
    with stderr_progress("duhem fit") as say, contextlib.ExitStack() as outputs:
        if fmu:
            model_tmp, fmu_tmp = outputs.enter_context(atomic_pair(out, fmu, recorded_fmu_digest))
        else:
            model_tmp, fmu_tmp = outputs.enter_context(atomic_file(out, suffix=".json")), None
        report_tmp = outputs.enter_context(atomic_directory(report)) if report else None
        say(f"fitting {len(recs)} recording(s)", None)
        result = fit_recordings(recs, kind=kind, order=order, q=q, x0=x0_policy, faithful_minor_loops=faithful,
                                effects=effects, held=held, progress=say)
        if compare:
            say("fitting the classical models (Preisach, Prandtl-Ishlinskii, Bouc-Wen)", None)
            result.summary["comparison"] = jsonable(comparison(result.model, recs))
        explained = explained_variance(result.model, recs)
        result.summary["explained"] = jsonable(explained)
        noise = check_explained(explained, allow_noise=allow_noise)
        model = result.model
        if report_tmp:
            say("writing the fit report", None)
            fill_fit_report(result, recs, report_tmp)
        if fmu_tmp:
            say(f"building the {backend} FMU", None)
            build_fmu(model, fmu_tmp, backend=backend, allow_unstable=allow_unstable)
            model = with_fmu_record(model, fmu, fmu_tmp, out)
        save_model(model, model_tmp)
    _python_host_note(fmu, backend)
    if noise:
        click.echo(f"warning: {noise['source']}: {explained_text(noise)}; saved because of --allow-noise", err=True)
    summary = result.summary
    conv = summary.get("convergence") or {}
    if conv and not conv.get("satisfied"):
        click.echo("warning: the convergence condition is violated: a wrong initial state need not die out; "
                   "the FMU is exported only with --allow-unstable", err=True)
    _warn_minor_loops(result.model)
    if as_json:
        _emit_json({"model": out, "fmu": fmu, "backend": backend if fmu else None, "report": report,
                    "summary": summary})
        return
    click.echo(f"{result.model.kind} model of order {result.model.order} written to {out}"
               + (f", FMU {fmu} ({backend} backend)" if fmu else "") + (f", report in {report}" if report else ""))
    if summary.get("why"):
        click.echo(f"chosen: {summary['why']}")
    effects = summary.get("effects") or {}
    held = effects.get("held") or {}
    for e in effects.get("fitted", []):
        free = [f"{k} = {_fmt(v)}" for k, v in e["parameters"].items() if f"{e['effect']}.{k}" not in held]
        click.echo(f"effect {e['effect']} fitted with the base: " + (", ".join(free) or "none of its parameters"))
    if held:
        click.echo("held, not fitted: " + ", ".join(f"{k} = {_fmt(v)}" for k, v in held.items()))
    if effects:
        settled = effects.get("settled") or []
        click.echo("effects started settled on the closed loops " + ", ".join(settled) if settled else
                   "effects started afresh (no recording is a closed loop)")
    if conv:
        click.echo(f"convergence condition: {'satisfied' if conv.get('satisfied') else 'VIOLATED'} "
                   f"({conv.get('quantity')} = {_fmt(conv.get('value'))}, margin {_fmt(conv.get('margin'))}; "
                   f"spectral radius on the raw input {_fmt_list(conv.get('rho_raw_input_per_recording'))})")
    _minor_loop_lines(summary.get("minor_loops"))
    click.echo(f"NRMSE: {summary.get('nrmse_convention')}")
    recs = summary.get("recordings", [])
    rows = [[r.get("recording"), r.get("nrmse"), r.get("nrmse_x0_fitted"), r.get("nrmse_last_cycle"),
             r.get("max_error"), r.get("loop_area_error"), r.get("residual_rms"), r.get("noise_rms")] for r in recs]
    _table("the saved model on each recording (from its stored x0, and from the recording's own fitted x0)",
           ["recording", "NRMSE (all samples)", "NRMSE own x0", "NRMSE last cycle", "max error", "loop area err",
            "residual RMS", "noise RMS"], rows)
    _own_start_note(recs)
    if "comparison" in summary:
        _comparison_tables(summary["comparison"])


def _own_start_note(recs: list[dict]) -> None:
    """Where a recording is reproduced much better from its own start than from the stored x0, say how to
    run the FMU from there."""
    worse = [r["recording"] for r in recs if r.get("nrmse_x0_fitted") is not None and r.get("nrmse") is not None
             and r["nrmse"] > 1.5 * r["nrmse_x0_fitted"] + 1e-3]
    if worse:
        click.echo(f"note: {', '.join(worse)} started from another state than the stored x0 (fitted to the first "
                   "recording): each recording's own start is in the summary (recordings[].x0_fitted, "
                   "recordings[].effect_start_fitted); `duhem validate --x0 fitted` sets the FMU's start "
                   "parameters to it")


def _effect_names(value: str | None) -> tuple[str, ...]:
    """The names of ``--effects`` (comma-separated), each a key of the effect registry."""
    names = tuple(n.strip() for n in (value or "").split(",") if n.strip())
    unknown = [n for n in names if n not in REGISTRY]
    if unknown:
        raise click.BadParameter(f"unknown effect {unknown[0]!r} (known: {', '.join(REGISTRY)})")
    return names


def _held_values(value: str | None) -> dict[str, float]:
    """``--hold``: comma-separated EFFECT.PARAM=VALUE pairs (checked against ``--effects`` by `check_held`)."""
    out = {}
    for item in (n.strip() for n in (value or "").split(",") if n.strip()):
        key, _, number = item.partition("=")
        try:
            out[key.strip()] = float(number)
        except ValueError:
            raise click.BadParameter(f"{item!r} is not EFFECT.PARAM=VALUE with VALUE a number") from None
    return out


def _minor_loop_lines(minor: dict | None) -> None:
    """The fit's `minor_loops` check in one line."""
    if not minor:
        return
    exc = minor.get("excursion")
    size = "overflows" if exc is None else f"leaves the recorded output range by {exc:.3g} output ranges"
    click.echo(f"minor loops inside the input range: the output {size} at most ({minor.get('input')})")


def _warn_minor_loops(model) -> None:
    """`minor_loop_warning` on stderr, when the model's fit recorded unfaithful minor loops."""
    text = minor_loop_warning(model)
    if text:
        click.echo(f"warning: {text}", err=True)


def _comparison_tables(comp: dict) -> None:
    """`duhem fit --compare`: the Duhem model beside each classical model, one row per recording."""
    names = list(comp["baselines"])
    recs = list(comp["duhem"])
    _table(f"NRMSE beside the classical models, one parameter set for all recordings ({comp['measure']})",
           ["recording", "Duhem", *names],
           [[r, comp["duhem"][r], *[comp["baselines"][n]["one_for_all"][r] for n in names]] for r in recs])
    if len(recs) > 1:
        _table("classical models fitted to each recording alone", ["recording", *names],
               [[r, *[comp["baselines"][n]["per_recording"][r] for n in names]] for r in recs])


@main.command()
@click.argument("model", type=FilePath())
@click.option("-o", "--out", "out", required=True, type=FilePath(), help="FMU file to write")
@backend_option
@fmi_version_option
@_allow_unstable_option
@click.option("--inverse", is_flag=True,
              help="export the model's feedforward compensator instead (input y_ref, output u: the input that "
                   "makes the model's output follow y_ref; see 'duhem compensate')")
@click.option("--measurement", type=click.Choice(MEASUREMENT_CHOICES), default="refuse", show_default=True,
              help="with --inverse, a model with measurement effects (sensor_lag, measurement_drift): drop them "
                   "(the device output follows y_ref) or invert them (the measured output follows y_ref)")
@click.option("--platforms", default=None, metavar="LIST", callback=_platforms,
              help=f"native backend: the binaries, a comma list of {', '.join(PLATFORMS)} (or linux, windows, "
                   "darwin, host); default all, compiled with zig (package ziglang), no system compiler needed")
@click.option("--cc", default=None, metavar="COMPILER",
              help="native backend: compile this machine's binary with this system C compiler instead of zig "
                   "(the other platforms' still with zig)")
@click.option("--json", "as_json", is_flag=True, help="print the result as JSON")
def export(model, out, backend, fmi_version, allow_unstable, inverse, measurement, platforms, cc, as_json):
    """Export a model JSON as an FMI 2.0 (or, --fmi-version 3, FMI 3.0) Co-Simulation FMU.

    With --inverse the FMU is the model's compensator: at each communication
    point it reads the reference y_ref(t_k) and outputs the input u(t_k) that
    makes the model's output equal y_ref(t_k) (exact inverse of the model's
    step, searched in the model's input_range; clamped to the nearest reachable
    output where none reaches it), to be connected in front of the model's FMU.
    """
    if fmi_version == 3 and backend != "native":
        raise CliError("FMI 3.0 export needs --backend native")
    if measurement != "refuse" and not inverse:
        raise CliError("--measurement applies to the compensator: add --inverse")
    if backend != "native" and (platforms or cc):
        raise CliError("--platforms and --cc apply to the native backend (a python-backend FMU runs where "
                       "its host's Python does)")
    m = _load_model_json(model)
    _refuse_overwrite([model], out)
    _check_fmu_name(out)
    m = with_convergence(m, _checked(m, model, allow_unstable))
    what = "compensator " if inverse else ""
    with stderr_progress("duhem export") as say, atomic_file(out, suffix=".fmu") as tmp:
        say(f"building the {backend} FMI {fmi_version}.0 {what}FMU", None)
        native = {"platforms": platforms, "cc": cc} if backend == "native" else {}
        build_fmu(m, tmp, backend=backend, allow_unstable=allow_unstable, fmi_version=fmi_version,
                  inverse=inverse, measurement=measurement, **native)
    if as_json:
        _emit_json({"model": model, "fmu": out, "backend": backend, "fmi_version": f"{fmi_version}.0",
                    "kind": m.kind, "order": m.order, "inverse": inverse,
                    "platforms": list(platforms or PLATFORMS) if backend == "native" else None})
    else:
        click.echo(f"{m.kind} model of order {m.order} exported to {out} ({backend} backend, "
                   f"FMI {fmi_version}.0)" if not inverse else
                   f"compensator of the {m.kind} model of order {m.order} exported to {out} (input y_ref, output "
                   f"u; {backend} backend, FMI {fmi_version}.0)")
    if inverse:
        _warn_minor_loops(m)
    _python_host_note(out, backend)


def _python_host_note(fmu: str | None, backend: str) -> None:
    """One line on stderr when a python-backend FMU was written: what a host needs to run it."""
    if fmu and backend == "python":
        click.echo(PYTHON_HOST_NEEDS, err=True)


def _validation_row(rec, y_fmu: np.ndarray, model, threshold: float, x0_rule: str, fmu: str) -> dict:
    """`compare` of one recording, with the FMU vs in-process difference (`model` from the FMU's start), which
    must be within `fitter.core.checks.AGREEMENT` of the output range, and the verdict."""
    y_model = simulate_model(model, rec.t, rec.u).y
    _finite_output(y_fmu, rec, f"the output of {fmu}")
    check_agreement(y_fmu, y_model, float(np.ptp(rec.y)), f"{fmu}: its binary", "its resources/model.json (run "
                    "by the in-process kernel)", rec.source)
    m = compare(rec, y_fmu)
    m["fmu_vs_in_process_max_abs"] = float(np.max(np.abs(y_fmu - y_model)))
    m.update(recording=rec.name, source=rec.source, passed=bool(m["nrmse"] <= threshold), judged_on="all samples",
             x0=x0_rule, x0_value=np.asarray(model.x0, dtype=float).tolist(),
             warnings=range_warnings(model, rec.t, rec.u))
    return m


def _finite_output(y: np.ndarray, rec, what: str) -> None:
    """A one-line error naming the recording's first data row where `y` (`what`) is not finite."""
    bad = np.flatnonzero(~np.isfinite(y))
    if bad.size:
        raise CliError(f"{rec.source}: data row {bad[0] + 1} (t = {rec.t[bad[0]]:.6g}): {what} is {y[bad[0]]} "
                       "(the model overflows on this input); nothing written")


def _validation_start(model, rec, x0_rule: str):
    """The model as the FMU starts for `rec`: its stored x0, or (``"fitted"``) the state fitted to `rec`
    (`fitter.identification.exported.own_start`), which the FMU gets through its x0 parameters (and, for
    effects fitted with a settled start, its ``<effect>.start.<state>`` parameters).
    CliError naming the recording when that fit overflows (no silent fall-back to the stored x0)."""
    if x0_rule == "stored":
        return model
    start = own_start(model, rec)
    if start is None:
        raise CliError(f"{rec.source}: no start state could be fitted to this recording (the simulation "
                       "overflowed); validate it from the stored x0 (--x0 stored)")
    return started(model, start)


def _judged(row: dict) -> float:
    return row["nrmse"]


@main.command()
@click.argument("fmu", type=FilePath())
@click.argument("recordings", nargs=-1, required=True, type=FilePath())
@click.option("--threshold", type=Number(low=0, open_low=True), default=DEFAULT_THRESHOLD, show_default=True,
              help="fail (exit code 3) when the NRMSE over all samples of a recording exceeds this")
@click.option("--plot", type=FilePath(), help="write a PNG overlay of the loops")
@click.option("--x0", "x0_rule", type=click.Choice(["stored", "fitted"]), default="stored", show_default=True,
              help="the FMU's start state: as stored, or fitted to each recording (set through the FMU's x0 "
                   "parameters; the figure `duhem fit` reports as 'NRMSE own x0')")
@_use_unstable_option
@_column_options
@click.option("--json", "as_json", is_flag=True, help="print the comparison as JSON")
def validate(fmu, recordings, threshold, plot, x0_rule, allow_unstable, time_col, input_col, output_col, as_json):
    """Drive an FMU with recorded inputs (fmpy) and compare its closed curves with the data.

    Per recording: NRMSE (RMS error / output range) over all samples, the
    FMU started from its stored x0 (the figure `duhem fit` reports, and the
    one judged) or, with ``--x0 fitted``, from the state fitted to that
    recording (one model for recordings made after different histories),
    NRMSE and max error over the last full input cycle, the
    loop-area error, and the largest difference between the FMU and the
    in-process simulation of the model stored in the FMU.
    """
    _refuse_overwrite([fmu, *recordings], plot)
    if plot and Path(plot).suffix.lower() != ".png":
        raise CliError(f"{plot}: the plot file name must end in .png")
    model = _open_fmu(fmu)
    recs = load_recordings(list(recordings), _time_column(time_col), input_col, output_col)
    _checked(model, f"{fmu} (its resources/model.json)", allow_unstable, *[rec.u for rec in recs])
    rows, outputs = [], []
    with stderr_progress("duhem validate") as say:
        for rec in recs:
            say(f"simulating {rec.name} in the FMU ({len(rec)} samples)", None)
            started = _validation_start(model, rec, x0_rule)
            start = None if x0_rule == "stored" else start_state_values(started)
            outputs.append(simulate_fmu(fmu, rec.t, rec.u, start=start))
            rows.append(_validation_row(rec, outputs[-1], started, threshold, x0_rule, fmu))
        if plot:
            say("plotting", None)
            write_validation_plot(plot, recs, outputs, [_judged(r) for r in rows])
    passed = all(r["passed"] for r in rows)
    if as_json:
        _emit_json({"fmu": fmu, "threshold": threshold, "passed": passed, "plot": plot, "recordings": rows})
    else:
        _table(f"validation of {fmu} (threshold NRMSE {threshold:g} over all samples; "
               f"{'stored x0' if x0_rule == 'stored' else 'x0 fitted to each recording'})",
               ["recording", "NRMSE all", "NRMSE last cycle", "max err last cycle", "loop area err",
                "FMU vs in-process", "pass"],
               [[r["recording"], r["nrmse"], r["nrmse_last_cycle"], r["max_error_last_cycle"],
                 r["loop_area_error"], r["fmu_vs_in_process_max_abs"], "yes" if r["passed"] else "NO"]
                for r in rows])
    for r in rows:
        for w in r["warnings"]:
            click.echo(f"warning: {r['source']}: {w}", err=True)
    if not passed:
        worst = max(rows, key=_judged)
        click.echo(f"error: {worst['source']}: NRMSE {_judged(worst):.4g} over {worst['judged_on']} "
                   f"exceeds the threshold {threshold:g}", err=True)
        sys.exit(EXIT_VALIDATION_FAILED)


@main.command()
@click.argument("model", type=FilePath())
@click.argument("input_csv", type=FilePath())
@click.option("-o", "--out", "out", required=True, type=FilePath(),
              help="CSV file to write (columns time,u,y)")
@click.option("--time", "time_col", default="time", show_default=True, metavar="COL", help="time column")
@click.option("--input", "input_col", default="u", show_default=True, metavar="COL", help="input column")
@_use_unstable_option
@click.option("--json", "as_json", is_flag=True, help="print a summary as JSON")
def simulate(model, input_csv, out, time_col, input_col, allow_unstable, as_json):
    """Simulate a model JSON (in-process kernel) or an FMU (fmpy) for a recorded input.

    The input is taken as piecewise linear between samples; the model starts
    from its stored initial state x0.  The output CSV has columns time,u,y.
    """
    _refuse_overwrite([model, input_csv], out)
    rec = load_recording(input_csv, time_col, input_col, None)
    with stderr_progress("duhem simulate") as say, atomic_file(out, suffix=".csv") as tmp:
        say(f"simulating {len(rec)} samples", None)
        if _is_zip(model):
            stored = _open_fmu(model)
            _checked(stored, f"{model} (its resources/model.json)", allow_unstable, rec.u)
            y = simulate_fmu(model, rec.t, rec.u)
            engine = "fmu"
        else:
            stored = _load_model_json(model)
            _checked(stored, model, allow_unstable, rec.u)
            y = simulate_model(stored, rec.t, rec.u).y
            engine = "in-process"
        _finite_output(y, rec, "the simulated output")
        warnings = range_warnings(stored, rec.t, rec.u)
        save_columns(tmp, ["time", "u", "y"], [rec.t, rec.u, y])
    info = {"model": model, "input": input_csv, "out": out, "engine": engine, "samples": len(rec),
            "y_min": float(np.min(y)), "y_max": float(np.max(y)), "warnings": warnings}
    for w in warnings:
        click.echo(f"warning: {input_csv}: {w}", err=True)
    if as_json:
        _emit_json(info)
    else:
        click.echo(f"{len(rec)} samples simulated ({engine}) and written to {out}")


@main.command()
@click.argument("model", type=FilePath())
@click.argument("reference", type=FilePath())
@click.option("-o", "--out", "out", required=True, type=FilePath(),
              help="CSV file to write (columns time,u,y_predicted)")
@click.option("--plot", type=FilePath(),
              help="write a PNG: y_ref, the plant without compensation (linear gain) and with it")
@click.option("--time", "time_col", default="time", show_default=True, metavar="COL", help="time column")
@click.option("--ref", "ref_col", default="y_ref", show_default=True, metavar="COL", help="reference column")
@click.option("--u0", type=Number(), help="the plant's input before the first sample (default: mid input range)")
@click.option("--input-range", "input_range", type=Number(), nargs=2, metavar="LO HI", callback=ordered_pair,
              help="inputs the compensator may use (default: the model's input_range)")
@click.option("--measurement", type=click.Choice(MEASUREMENT_CHOICES), default="refuse", show_default=True,
              help="a model with measurement effects (sensor_lag, measurement_drift): drop them (the device "
                   "output follows y_ref) or invert them (the measured output follows y_ref)")
@_use_unstable_option
@click.option("--json", "as_json", is_flag=True, help="print a summary as JSON")
def compensate(model, reference, out, plot, time_col, ref_col, u0, input_range, measurement, allow_unstable,
               as_json):
    """The input that makes a model's output follow a reference (the inverse model, a feedforward compensator).

    Exact wherever some input in the model's input range reaches y_ref (the
    compensator and the plant run the same kernel); elsewhere the output is
    clamped to the nearest reachable value and the clamped samples are
    reported.  The output CSV has columns time,u,y_predicted (the model's
    output for that input, from its stored x0).
    """
    _refuse_overwrite([model, reference], out, plot)
    if plot and Path(plot).suffix.lower() != ".png":
        raise CliError(f"{plot}: the plot file name must end in .png")
    m = _load_model_json(model)
    _checked(m, model, allow_unstable, *([input_range] if input_range else []))
    rec = load_recording(reference, time_col, ref_col, None)
    comp = Compensator(m, t0=float(rec.t[0]), u0=u0, measurement=measurement, input_range=input_range)
    with stderr_progress("duhem compensate") as say, contextlib.ExitStack() as outputs:
        csv_tmp = outputs.enter_context(atomic_file(out, suffix=".csv"))
        plot_tmp = outputs.enter_context(atomic_file(plot, suffix=".png")) if plot else None
        say(f"compensating {len(rec)} samples", None)
        result = comp.run(rec.t, rec.u)
        save_columns(csv_tmp, ["time", "u", "y_predicted"], [result.t, result.u, result.y])
        info = {"model": model, "reference": reference, "out": out, "plot": plot, "measurement": measurement,
                **result.summary()}
        if plot_tmp:
            say("plotting", None)
            y0, gain = linear_gain(result.u, result.y)
            lo, hi = result.input_range
            u_linear = np.clip((result.y_ref - y0) / gain, lo, hi)
            u_linear[0] = result.u[0]       # the plant starts where the compensated run starts
            y_linear = simulate_model(comp.plant, result.t, u_linear).y
            info["linear_gain"] = {"y0": y0, "gain": gain,
                                   "tracking_error": float(np.sqrt(np.mean((y_linear - result.y_ref) ** 2))
                                                           / (np.ptp(result.y_ref) or 1.0))}
            write_compensation_plot(plot_tmp, result.t, result.y_ref, y_linear, result.y, result.clamped,
                                    output_label=_axis_name(m.signals.output),
                                    title=f"{Path(reference).name}: compensation of {Path(model).name}")
    _warn_minor_loops(m)
    lo, hi = result.input_range
    if u0 is not None and not lo <= u0 <= hi:
        click.echo(f"warning: --u0 {u0:g} is outside the input range [{lo:.6g}, {hi:.6g}]: the plant holds its "
                   f"input at the nearest edge there", err=True)
    if result.n_clamped:
        click.echo(f"warning: {reference}: {result.n_clamped} of {len(rec)} samples clamped (no input in "
                   f"[{result.input_range[0]:.6g}, {result.input_range[1]:.6g}] reaches y_ref); largest shortfall "
                   f"{result.max_shortfall:.4g} at t = {info['max_shortfall_time']:.6g}", err=True)
    if as_json:
        _emit_json(info)
    else:
        click.echo(f"{len(rec)} samples compensated and written to {out} ({result.n_clamped} clamped, tracking "
                   f"error {100 * result.tracking_error():.3g}% of the reference range)")


def _axis_name(signal) -> str:
    return f"{signal.name} [{signal.unit}]" if signal.unit else signal.name


@main.command()
@click.argument("recordings", nargs=-1, required=True, type=FilePath())
@click.option("--model", "model_path", type=FilePath(),
              help="base model JSON (default: fit a rate-independent model of order --base-order)")
@click.option("--report", type=FilePath(directory=True), help="write the diagnosis report (HTML, PNG) here")
@click.option("--json", "json_out", type=FilePath(allow_dash=True),
              help="write the diagnosis as JSON to this file ('-' for stdout)")
@click.option("--fmu", type=FilePath(), help="export the extended model as this FMU")
@backend_option
@click.option("--base-order", type=click.Choice(["auto", "1", "2", "3", "4"]), default="auto", show_default=True,
              help="without --model: order of the rate-independent base model (auto: the order 'duhem fit' "
                   "chooses by BIC, so the base is adequate before effects are tested; 1: fitted here, fast; "
                   "2-4: fitted by 'duhem fit --kind ri --order N' first; its A matrices are then held)")
@click.option("--separate/--one-clock", "separate", default=None,
              help="force the reading of the files: separate runs, each simulated alone from the initial state "
                   "fitted to it, as 'duhem fit' scores; or one clock running on from file to file (default: "
                   "separate runs when a file starts at or before its predecessor ends, e.g. every file from t = 0)")
@click.option("--candidates", callback=lambda ctx, param, value: _effect_names(value), metavar="NAMES",
              help="the effects to test (comma-separated; default every effect searched for by default: "
                   f"{', '.join(CANDIDATES)})")
@_column_options
def diagnose(recordings, model_path, report, json_out, fmu, backend, base_order, separate, candidates, time_col,
             input_col, output_col):
    """Locate the model-data mismatch of one experiment, name the physics left out, model it.

    The recordings are one experiment in time order on one clock (e.g.
    several rates and a repeat of the first run), or separate runs, each
    on its own clock (recognised when a file starts at or before its
    predecessor ends; --separate / --one-clock force a reading).
    """
    _refuse_overwrite([*recordings, model_path], report, json_out, fmu)
    _check_fmu_name(fmu)
    if model_path and base_order != "auto":
        raise CliError("--base-order applies only without --model (the given model sets the base)")
    if fmu:
        _check_backend(backend)
    base = _load_model_json(model_path) if model_path else None
    recs = load_recordings(list(recordings), _time_column(time_col), input_col, output_col)
    with contextlib.ExitStack() as outputs:
        json_tmp = outputs.enter_context(atomic_file(json_out, suffix=".json")) \
            if json_out and json_out != "-" else None
        report_tmp = outputs.enter_context(atomic_directory(report)) if report else None
        fmu_tmp = outputs.enter_context(atomic_file(fmu, suffix=".fmu")) if fmu else None
        with stderr_progress("diagnosing", bar=True) as progress:
            result = run_diagnosis(recs, model=base, progress=progress,
                                   base_order=None if base_order == "auto" else int(base_order),
                                   separate=separate, candidates=candidates or CANDIDATES)
        data = jsonable(result.to_json())
        if report_tmp:
            fill_diagnosis_report(result, recs, report_tmp)
        if fmu_tmp:
            build_fmu(result.extended_model, fmu_tmp, backend=backend)
        if json_tmp:
            json_tmp.write_text(json_text(data), encoding="utf-8")
    _python_host_note(fmu, backend)
    if json_out == "-":
        _emit_json(data)
        return
    click.echo(result.paragraph)
    _per_recording_table(data)
    findings = data.get("findings") or []
    if findings:
        _table("findings (most important first)", ["effect", "origin", "p-value", "explained fraction"],
               [[f.get("effect"), f.get("origin"), f.get("p_value"), f.get("explained_fraction")] for f in findings])
        if result.verdict == "unexplained":
            click.echo("unexplained: the findings explain part of the residual; what they leave is not the noise "
                       "and no candidate effect explains it (the findings are partial: the nearest effects)")
    elif result.verdict == "nothing_missing":
        click.echo("nothing missing: the residual is consistent with the noise level")
    else:
        click.echo("unexplained: the residual is above the noise but no candidate effect explains it")


def _per_recording_table(data: dict) -> None:
    """Per recording: NRMSE of the base and of the extended model, the extended model's held-out NRMSE (fitted
    without that recording) and, for separate runs, the output reference fitted to it."""
    base, ext = data["baseline"], data["extended"]
    held, refs = ext.get("heldout_nrmse_per_recording") or {}, ext.get("references") or {}
    _table("per recording", ["recording", "base NRMSE", "extended NRMSE", "held out", "reference"],
           [[name, value, ext["nrmse_per_recording"].get(name), held.get(name), refs.get(name)]
            for name, value in base["nrmse_per_recording"].items()])


@main.command()
@click.argument("manifest", type=FilePath())
@click.option("-o", "--out", "outdir", required=True, type=FilePath(directory=True),
              help="output directory: OUTDIR/<device>/ per device, OUTDIR/summary.csv and OUTDIR/index.html")
@click.option("--diagnose", "with_diagnosis", is_flag=True,
              help="also diagnose every device (its fitted model as the base): diagnosis.json and diagnosis/")
@click.option("--scheduler", metavar="ADDRESS",
              help="use this running Dask scheduler (e.g. tcp://host:8786) instead of a local cluster")
@click.option("--workers", type=Number(int, low=1), metavar="N",
              help="worker processes of the local cluster, one thread each (default: one per core)")
@backend_option
@click.option("--kind", type=click.Choice(["ri", "rd", "auto"]), default="auto", show_default=True,
              help="model kind of every device's fit, as 'duhem fit --kind'")
@click.option("--order", type=Number(int, low=1, high=max(ORDERS)),
              help="state dimension of every fit (default: chosen by BIC)")
@click.option("--faithful-minor-loops", "faithful", is_flag=True,
              help="every fit keeps its settled minor loops near the data (as duhem fit --faithful-minor-loops)")
@click.option("--effects", metavar="NAMES", callback=lambda ctx, param, value: _effect_names(value),
              help="catalogue effects (comma-separated) fitted jointly with every device's base, as "
                   "'duhem fit --effects'")
@click.option("--hold", "held", callback=lambda ctx, param, value: _held_values(value), metavar="EFFECT.PARAM=VALUE",
              help="with --effects, effect parameters held at a known value in every fit, as 'duhem fit --hold'")
@click.option("--threshold", type=Number(low=0, open_low=True), default=DEFAULT_THRESHOLD, show_default=True,
              help="validation: a device whose FMU has an NRMSE above this on a recording is 'invalid'")
@click.option("--retry-failed", is_flag=True,
              help="run again the devices that failed on unchanged inputs (by default they are skipped)")
@click.option("--json", "as_json", is_flag=True, help="print what the batch did as JSON")
def batch(manifest, outdir, with_diagnosis, scheduler, workers, backend, kind, order, faithful, effects, held,
          threshold, retry_failed, as_json):
    """Fit, export, validate, report (and diagnose) every device of a manifest, on Dask.

    MANIFEST is a CSV file: columns device, recordings (files separated by
    ';', relative to the manifest), optional time, input, output (column
    choices) and input_unit, output_unit.  A re-run skips the devices whose
    outputs are complete and current; one bad device is reported in the
    summary and does not stop the batch.  Exit code 0 when the batch ran to
    its end, whatever the devices' status (see the summary); 1 for a bad
    manifest or option.
    """
    if scheduler and workers is not None:
        raise CliError("--workers applies to the local cluster only (not with --scheduler)")
    options = BatchOptions(kind=kind, order=order, backend=backend, diagnose=with_diagnosis, threshold=threshold,
                           faithful_minor_loops=faithful, effects=effects, held=tuple(held.items()))
    _check_backend(backend)
    report = run_batch(manifest, outdir, options=options, workers=workers, scheduler=scheduler,
                       retry_failed=retry_failed, say=lambda line: click.echo(line, err=True))
    if as_json:
        _emit_json(report.to_json())
        return
    rows = [report.summary_row(d) for d in report.devices]
    _table(f"duhem batch: {len(rows)} devices in {outdir} ({report.seconds:.1f} s)",
           ["device", "status", "this run", "model", "NRMSE", "effects found", "outliers", "reason"],
           [[r["device"], r["status"], r["action"], f"{r['kind']}{r['order']}" if r["kind"] else None,
             r["nrmse"], r["effects"], r["outliers"] or None, r["reason"] or None] for r in rows])
    counts = report.counts()
    click.echo(", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
               + f"; summary: {Path(outdir) / 'summary.csv'}, {Path(outdir) / 'index.html'}")
