"""Command-line plumbing shared by ``duhem`` (`fitter.cli`), ``build_fmu.py`` and the paper benchmark.

One toolkit, click, and one error contract: an error is the single line
``error: <message>`` on stderr with exit code 1 (`CliError`), a usage error
too (a bad option value, an unknown option, a missing argument: `usage_line`
names the command, the option and the value, and points to ``--help``).
Numeric options are `Number`: finite and range-checked.  `one_line_errors`
turns any exception of a command into a `CliError`: a `DuhemError` (the
package's errors), an `OSError`, or a `ValueError` or `RuntimeError` that
the package raised itself keeps its message; anything else (a bug, a
numerical library's failure such as a singular matrix) is labelled
``internal error``, with the project function it happened in; no traceback
unless ``DUHEM_DEBUG`` is set.
Numerical RuntimeWarnings (e.g. an overflow in a rejected trial step of an
optimiser) are hidden too: a command's own result says whether it
converged.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import math
import os
import re
import warnings
from pathlib import Path
from typing import Callable, Iterator, Sequence

import click
import numpy as np

from fitter.core.errors import DuhemError

_PROJECT = Path(__file__).resolve().parent
"""The package's folder: code below it is the project's own."""

__all__ = [
    "CliError",
    "DEFAULT_THRESHOLD",
    "EXIT_ERROR",
    "EXIT_VALIDATION_FAILED",
    "FilePath",
    "Number",
    "one_line_errors",
    "guarded",
    "GuardedGroup",
    "backend_option",
    "fmi_version_option",
    "ordered_pair",
    "run_command",
    "usage_line",
]

EXIT_ERROR = 1
EXIT_VALIDATION_FAILED = 3
"""Exit code of a validation whose NRMSE exceeds its threshold."""
DEFAULT_THRESHOLD = 0.05
"""Default `duhem validate` threshold on the NRMSE over all samples (5% of the output range)."""
_COMMAND_PATH = "fitter.cli_support.command_path"
"""`click.Context.meta` key: the subcommand `GuardedGroup` runs (for a usage error that has no context)."""


class CliError(click.ClickException):
    """An error reported as the single line ``error: <message>`` on stderr (exit code 1)."""

    exit_code = EXIT_ERROR

    def show(self, file=None) -> None:
        click.echo(f"error: {self.message}", err=True)


class FilePath(click.Path):
    """`click.Path` of a file (or, with `directory`, of a directory) whose refusals are one line
    ``error: <path>: <why>`` with exit code 1 (`CliError`), not click's three-line usage text.

    Refused: a directory given for a file, a file given for a directory, an existing path that is not
    readable.  A path that does not exist passes (the command says what is missing)."""

    def __init__(self, *, directory: bool = False, allow_dash: bool = False) -> None:
        super().__init__(file_okay=not directory, dir_okay=directory, allow_dash=allow_dash)

    def convert(self, value, param, ctx):
        path = os.fspath(value)
        if os.path.exists(path) and not (self.allow_dash and path == "-"):
            if not self.dir_okay and os.path.isdir(path):
                raise CliError(f"{path}: is a directory, not a file")
            if not self.file_okay and not os.path.isdir(path):
                raise CliError(f"{path}: is a file, not a directory")
            if not os.access(path, os.R_OK):
                raise CliError(f"{path}: cannot be read (permission denied)")
        return super().convert(value, param, ctx)


class Number(click.ParamType):
    """A finite number option (`kind` int or float) within [`low`, `high`] (`open_low`: above `low`); a refusal
    names the value and the range (`usage_line` adds the command and the option)."""

    def __init__(
        self, kind: type = float, *, low: float | None = None, high: float | None = None, open_low: bool = False
    ) -> None:
        self.kind, self.low, self.high, self.open_low = kind, low, high, open_low
        self.name = "integer" if kind is int else "number"
        bounds = ([f"{'>' if open_low else '>='} {low:g}"] if low is not None else []) + (
            [f"<= {high:g}"] if high is not None else []
        )
        self.rule = " ".join(["an integer" if kind is int else "a finite number", " and ".join(bounds)]).strip()

    def convert(self, value, param, ctx):
        try:
            number = self.kind(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not {self.rule}", param, ctx)
        if not (
            math.isfinite(number)
            and (self.low is None or number > self.low or (number == self.low and not self.open_low))
            and (self.high is None or number <= self.high)
        ):
            self.fail(f"{value} is out of range: give {self.rule}", param, ctx)
        return number


def ordered_pair(ctx: click.Context, param: click.Parameter, value: tuple | None) -> tuple | None:
    """Callback of a ``nargs=2`` `Number` option LO HI: refuses LO >= HI."""
    if value is not None and not value[0] < value[1]:
        raise click.BadParameter(f"{value[0]:g} {value[1]:g}: give LO < HI", ctx, param)
    return value


def usage_line(exc: click.UsageError) -> str:
    """A click usage error in one line: the command, the option and what is wrong with its value (or the
    unknown option, the missing argument), and where the options are listed."""
    ctx = exc.ctx or click.get_current_context(silent=True)
    command = (ctx.meta.get(_COMMAND_PATH) if exc.ctx is None else None) or ctx.command_path if ctx else "duhem"
    if isinstance(exc, click.BadParameter) and exc.param is not None and not isinstance(exc, click.MissingParameter):
        name = "/".join(exc.param.opts) if isinstance(exc.param, click.Option) else exc.param.human_readable_name
        text = f"{name}: {exc.message}"
    else:
        text = exc.format_message()
        text = text[0].lower() + text[1:] if text[:1].isupper() and not text[1:2].isupper() else text
    text = re.sub(r"\.\s*\(?Did you mean (.*?)\?\)?$", r" (did you mean \1?)", " ".join(text.split()))
    return f"{command}: {text.rstrip('.')}; see '{command} --help'"


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if isinstance(exc, OSError) and exc.filename:
        text = f"{exc.filename}: {exc.strerror or text}"
    return text or type(exc).__name__


_NUMERICAL = (ArithmeticError, np.linalg.LinAlgError)
"""Failures of a numerical library's computation: never a statement about the user's input."""


def _raised_in_project(exc: BaseException) -> bool:
    """Whether the innermost frame of `exc`'s traceback is the project's own code (not numpy's, scipy's ...)."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb is not None and Path(tb.tb_frame.f_code.co_filename).resolve().is_relative_to(_PROJECT)


def _about_the_input(exc: BaseException) -> bool:
    """Whether `exc` states something about the user's input or files: a `DuhemError` or an `OSError`, or a
    ValueError / RuntimeError that the project raised itself (not a numerical library's failure)."""
    if isinstance(exc, (DuhemError, OSError)):
        return True
    return isinstance(exc, (ValueError, RuntimeError)) and not isinstance(exc, _NUMERICAL) and _raised_in_project(exc)


def _internal_line(exc: BaseException) -> str:
    """An internal failure in one line: what was being done (the innermost project function on the traceback),
    the exception, and that it is the tool's failure, not a finding about the data."""
    where = None
    tb = exc.__traceback__
    while tb is not None:
        code = tb.tb_frame.f_code
        if Path(code.co_filename).resolve().is_relative_to(_PROJECT):
            module = tb.tb_frame.f_globals.get("__name__", "?")
            where = f"{module}.{code.co_name}"
        tb = tb.tb_next
    return (
        f"internal error{f' in {where}' if where else ''} ({type(exc).__name__}: {_one_line(exc)}): a failure of "
        "the tool's own computation, not a finding about your data; run again with DUHEM_DEBUG=1 for the "
        "traceback and report it"
    )


@contextlib.contextmanager
def one_line_errors() -> Iterator[None]:
    """Re-raise every exception of the block as a `CliError` (see the module docstring)."""
    debug = bool(os.environ.get("DUHEM_DEBUG"))
    try:
        with warnings.catch_warnings():
            if not debug:
                warnings.simplefilter("ignore", RuntimeWarning)
            yield
    except click.exceptions.NoArgsIsHelpError:
        raise
    except click.UsageError as exc:
        raise CliError(usage_line(exc)) from None
    except (click.ClickException, click.exceptions.Exit, click.Abort):
        raise
    except KeyboardInterrupt:
        raise CliError("interrupted") from None
    except Exception as exc:  # every failure becomes one line, never a traceback
        if debug:
            raise
        raise CliError(_one_line(exc) if _about_the_input(exc) else _internal_line(exc)) from None


def guarded(func: Callable) -> Callable:
    """Decorate a command callback to run under `one_line_errors`."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with one_line_errors():
            return func(*args, **kwargs)

    return wrapper


class GuardedGroup(click.Group):
    """A click group whose every subcommand, its options' parsing included, runs under `one_line_errors`.

    `lazy` names subcommands by ``"module:attribute"``, imported when the command runs or the help lists it
    (click's lazily loaded subcommands): ``duhem reproduce-paper`` does not import the diagnosis, the FMU host
    or Dask."""

    def __init__(self, *args, lazy: dict[str, str] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy = dict(lazy or {})

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *self.lazy})

    def get_command(self, ctx: click.Context, cmd_name: str):
        if cmd_name in self.lazy and cmd_name not in self.commands:
            module, attribute = self.lazy[cmd_name].split(":")
            self.add_command(getattr(importlib.import_module(module), attribute), cmd_name)
        return super().get_command(ctx, cmd_name)

    def make_context(self, info_name, args, parent=None, **extra) -> click.Context:
        with one_line_errors():
            return super().make_context(info_name, args, parent=parent, **extra)

    def resolve_command(self, ctx: click.Context, args: list[str]):
        name, command, rest = super().resolve_command(ctx, args)
        ctx.meta[_COMMAND_PATH] = f"{ctx.command_path} {name}"
        return name, command, rest

    def invoke(self, ctx: click.Context):
        """The subcommand, after the environment's settings are read (`fitter.workers.workers`: a bad
        ``DUHEM_WORKERS`` is one line here, not a failure of every fit's processes later)."""
        from fitter.workers import workers

        with one_line_errors():
            workers()
            return super().invoke(ctx)


def backend_option(func: Callable) -> Callable:
    """``--backend [native|python]`` (default native): the FMU backend."""
    return click.option(
        "--backend",
        type=click.Choice(["native", "python"]),
        default="native",
        show_default=True,
        help="native: C library for Linux, Windows and macOS, the simulator needs no Python "
        "(compiled with zig, package ziglang); python: pythonfmu, the simulator needs "
        "Python with numpy",
    )(func)


def fmi_version_option(func: Callable) -> Callable:
    """``--fmi-version [2|3]`` (default 2): the FMI version of the FMU (3 needs --backend native)."""
    return click.option(
        "--fmi-version",
        "fmi_version",
        type=click.Choice(["2", "3"]),
        default="2",
        show_default=True,
        callback=lambda ctx, param, value: int(value),
        help="FMI 2.0 or FMI 3.0 Co-Simulation (3.0 needs --backend native)",
    )(func)


def run_command(command: click.Command, argv: Sequence[str] | None, prog_name: str) -> int:
    """Run a click command as a function of its arguments (default ``sys.argv[1:]``).

    Returns the exit status: 0, the status the command exits with
    (``ctx.exit(n)``), or a `click.ClickException`'s exit code after showing
    it; a usage error is one line (`usage_line`), exit status 1.
    """
    try:
        status = command.main(args=None if argv is None else list(argv), prog_name=prog_name, standalone_mode=False)
    except click.UsageError as exc:
        exc = CliError(usage_line(exc))
        exc.show()
        return exc.exit_code
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    return status if isinstance(status, int) else 0
