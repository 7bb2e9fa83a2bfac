"""What every `duhem` command shares: defaults, console output, model and FMU files, column options."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Callable

import click
import numpy as np

from fitter.cli_support import CliError
from fitter.core.checks import check_model
from fitter.core.effects import REGISTRY
from fitter.core.files import json_text
from fitter.core.models import load_model
from fitter.fmu.build import PYTHON_HOST_NEEDS
from fitter.fmu.host import check_fmu_file
from fitter.fmu.native import check_toolchain
from fitter.fmu.pair import check_fmu_pair
from fitter.fmu.toolchain import parse_platforms
from fitter.identification.exported import minor_loop_warning


# --------------------------------------------------------------------------- console output


def emit_json(data) -> None:
    click.echo(json_text(data))


def table(title: str, columns: list[str], rows: list[list]) -> None:
    """Print a table that cuts no column name and no value: into a file or a pipe its lines are as long as it
    needs; in a narrower terminal the names wrap, the values keep their width (a terminal narrower than the
    values alone gets the needed width and wraps its lines)."""
    from rich.console import Console
    from rich.table import Table

    cells = [[fmt(v) for v in row] for row in rows]
    table = Table(title=title)
    for i, c in enumerate(columns):
        table.add_column(
            c,
            justify="left" if i == 0 else "right",
            overflow="fold",
            min_width=max((len(row[i]) for row in cells), default=1),
        )
    for row in cells:
        table.add_row(*row)
    console = Console(file=sys.stdout, soft_wrap=True)
    need = console.measure(table, options=console.options.update(max_width=10_000))
    console.width = max(console.width, need.minimum if console.is_terminal else need.maximum)
    console.print(table)


def fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, (float, np.floating)):
        return f"{v:.4g}"
    return str(v)


def fmt_list(values) -> str:
    return ", ".join(fmt(v) for v in values or []) or "-"


# --------------------------------------------------------------------------- model files and names


def is_zip(path: str) -> bool:
    try:
        with open(path, "rb") as fh:
            return fh.read(4) == b"PK\x03\x04"
    except FileNotFoundError:
        raise CliError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise CliError(f"{path}: is a directory") from None


def load_model_json(path: str):
    """A model from a JSON file written by `duhem fit`; an FMU or a CSV is a clear error."""
    if is_zip(path):
        raise CliError(
            f"{path}: is an FMU or zip archive, not a model JSON file (give the JSON written by 'duhem fit')"
        )
    if Path(path).suffix.lower() == ".fmu":
        raise CliError(f"{path}: not an FMU (not a zip archive: damaged or unfinished), nor a model JSON file")
    model = load_model(path)
    note = check_fmu_pair(path, model)
    if note:
        click.echo(f"note: {note}", err=True)
    return model


def open_fmu(path: str):
    """The model in an FMU argument, every part checked (`check_fmu_file`), after the hint that a model JSON
    is exported first."""
    if not is_zip(path):
        raise CliError(f"{path}: not an FMU (not a zip archive); for a model JSON use 'duhem export' first")
    return check_fmu_file(path)


def refuse_overwrite(inputs, *outputs) -> None:
    """A one-line error, before anything is written, when an output path is one of the command's inputs
    (the same file by its real path: a link, a hard link or another spelling counts) or a directory that holds
    one (a report directory is replaced as a whole), or when two outputs are one path or one lies inside
    another (a report directory)."""
    _distinct_outputs([o for o in outputs if o and o != "-"])
    known = {os.path.realpath(str(p)): str(p) for p in inputs if p}
    for out in outputs:
        if not out or out == "-":
            continue
        real = os.path.realpath(str(out))
        same = next((p for r, p in known.items() if r == real or _same_file(str(out), p)), None)
        inside = next((p for r, p in known.items() if r.startswith(real + os.sep)), None)
        if same is not None or inside is not None:
            what = (
                f"is one of this command's inputs ({same})"
                if same is not None
                else f"is a directory that holds this command's input {inside} (it would be replaced as a whole)"
            )
            raise CliError(f"{out}: {what}; write the output to another path (the input is left untouched)")


def _distinct_outputs(outputs: list) -> None:
    """`refuse_overwrite`'s check among the outputs: no two at one real path, none inside another."""
    real = [os.path.realpath(str(o)) for o in outputs]
    for i, a in enumerate(real):
        for j, b in enumerate(real):
            if i == j:
                continue
            if a == b and i < j:
                raise CliError(
                    f"{outputs[j]}: given for two outputs ({outputs[i]} and {outputs[j]}); give each its own path"
                )
            if b.startswith(a + os.sep):
                raise CliError(
                    f"{outputs[j]}: is inside the directory {outputs[i]}, which is written as a whole; write it "
                    "outside that directory"
                )


def _same_file(a: str, b: str) -> bool:
    """Whether two existing paths are one file (`os.path.samefile`: hard links too)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_fmu_name(path: str | None) -> None:
    if path and Path(path).suffix.lower() != ".fmu":
        raise CliError(f"{path}: an FMU file name must end in .fmu")


def check_backend(backend: str, fmi_version: int = 2) -> None:
    """Fail before any long work when the native backend has no compiler (zig; message names --backend python),
    or FMI 3.0 is asked of another backend."""
    if fmi_version == 3 and backend != "native":
        raise CliError("FMI 3.0 export needs --backend native")
    if backend == "native":
        check_toolchain()


def platforms(ctx: click.Context, param: click.Parameter, value: str | None) -> tuple[str, ...] | None:
    try:
        return None if value is None else parse_platforms(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None


# --------------------------------------------------------------------------- shared options


def _no_time(ctx: click.Context, param: click.Parameter, value: bool) -> None:
    ctx.meta["no_time"] = value


def time_column(time_col: str) -> str | None:
    """The --time column, or None (sample index as time) under --no-time."""
    return None if click.get_current_context().meta.get("no_time") else time_col


def no_time_option(func: Callable) -> Callable:
    """``--no-time``: the file has no time column (`time_column` then gives None)."""
    return click.option(
        "--no-time",
        is_flag=True,
        expose_value=False,
        callback=_no_time,
        help="the file has no time column: use the sample index as time (rate-independent "
        "models only depend on the input's path)",
    )(func)


def column_options(func: Callable) -> Callable:
    func = no_time_option(func)
    for name, default, role in (("output", "y", "output"), ("input", "u", "input"), ("time", "time", "time")):
        func = click.option(
            f"--{name}",
            f"{name}_col",
            default=default,
            show_default=True,
            metavar="COL",
            help=f"{role} column: header name, name without unit suffix, or 0-based index",
        )(func)
    return func


def allow_unstable_option(func: Callable) -> Callable:
    return click.option(
        "--allow-unstable",
        is_flag=True,
        help="export even when the fit recorded a violated convergence condition (the FMU's description then says so)",
    )(func)


def use_unstable_option(func: Callable) -> Callable:
    return click.option(
        "--allow-unstable",
        is_flag=True,
        help="use the model even when its convergence condition, checked from its parameters, "
        "is violated (a warning says so; a non-finite output is still refused)",
    )(func)


def checked(model, source: str, allow_unstable: bool, *inputs):
    """`fitter.core.checks.check_model` of a model about to be used, on the range of `inputs` (the inputs it is
    run with, for a model without input_range); under --allow-unstable a violated condition is one warning."""
    values = [np.ravel(np.asarray(u, dtype=float)) for u in inputs]
    span = (float(min(v.min() for v in values)), float(max(v.max() for v in values))) if values else None
    conv = check_model(model, source, span=span, allow_unstable=allow_unstable)
    if not conv.satisfied:
        click.echo(
            f"warning: {source}: the convergence condition is violated ({conv.text()}); used anyway (--allow-unstable)",
            err=True,
        )
    return conv


def effect_names(value: str | None) -> tuple[str, ...]:
    """The names of ``--effects`` (comma-separated), each a key of the effect registry."""
    names = tuple(n.strip() for n in (value or "").split(",") if n.strip())
    unknown = [n for n in names if n not in REGISTRY]
    if unknown:
        raise click.BadParameter(f"unknown effect {unknown[0]!r} (known: {', '.join(REGISTRY)})")
    return names


def held_values(value: str | None) -> dict[str, float]:
    """``--hold``: comma-separated EFFECT.PARAM=VALUE pairs (checked against ``--effects`` by `check_held`)."""
    out = {}
    for item in (n.strip() for n in (value or "").split(",") if n.strip()):
        key, _, number = item.partition("=")
        try:
            out[key.strip()] = float(number)
        except ValueError:
            raise click.BadParameter(f"{item!r} is not EFFECT.PARAM=VALUE with VALUE a number") from None
    return out


def check_units(model, recs, what: str) -> None:
    """One line when a recording's input or output column names a unit (its header, ``u_kV``) other than the one
    the model was fitted in (its signals'); nothing when either is not named."""
    for rec in recs:
        for role in ("input", "output"):
            mine, theirs = getattr(model.signals, role).unit, getattr(rec, role).unit
            if mine and theirs and mine != theirs:
                raise CliError(
                    f"{rec.source}: the {role} column {getattr(rec, role).name!r} is in {theirs} but {what} was "
                    f"fitted in {mine}: convert the column to {mine} (a model's parameters hold its units)"
                )


def warning(text: str) -> None:
    """One line ``warning: text`` on stderr."""
    click.echo(f"warning: {text}", err=True)


def warn_minor_loops(model) -> None:
    """`minor_loop_warning` on stderr, when the model's fit recorded unfaithful minor loops."""
    text = minor_loop_warning(model)
    if text:
        click.echo(f"warning: {text}", err=True)


def python_host_note(fmu: str | None, backend: str) -> None:
    """One line on stderr when a python-backend FMU was written: what a host needs to run it."""
    if fmu and backend == "python":
        click.echo(PYTHON_HOST_NEEDS, err=True)


def finite_output(y: np.ndarray, rec, what: str) -> None:
    """A one-line error naming the recording's first data row where `y` (`what`) is not finite."""
    bad = np.flatnonzero(~np.isfinite(y))
    if bad.size:
        raise CliError(
            f"{rec.source}: data row {bad[0] + 1} (t = {rec.t[bad[0]]:.6g}): {what} is {y[bad[0]]} "
            "(the model overflows on this input); nothing written"
        )
