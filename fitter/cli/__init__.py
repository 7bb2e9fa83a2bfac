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

from typing import Sequence

import click

from fitter.cli_support import DEFAULT_THRESHOLD, EXIT_ERROR, EXIT_VALIDATION_FAILED, CliError, GuardedGroup

COMMANDS = {
    "fit": "fitter.cli.fit_command:fit",
    "export": "fitter.cli.fmu_commands:export",
    "validate": "fitter.cli.fmu_commands:validate",
    "simulate": "fitter.cli.run_commands:simulate",
    "compensate": "fitter.cli.run_commands:compensate",
    "diagnose": "fitter.cli.diagnose_command:diagnose",
    "batch": "fitter.cli.batch_command:batch",
    "reproduce-paper": "fitter.paper.report:command",
}
"""The subcommands, each imported when it runs (`GuardedGroup`)."""


__all__ = ["main", "console", "CliError", "DEFAULT_THRESHOLD", "EXIT_ERROR", "EXIT_VALIDATION_FAILED"]


@click.group("duhem", cls=GuardedGroup, lazy=COMMANDS, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="semilinear-duhem")
def main() -> None:
    """Identify semilinear Duhem hysteresis models (Oh & Bernstein 2007) and export them as FMUs.

    Typical use: duhem fit rec.csv -o model.json --fmu model.fmu, then
    duhem validate model.fmu rec.csv.
    """


def console(argv: Sequence[str] | None = None) -> None:
    """The ``duhem`` executable: `main` on `argv` (default ``sys.argv[1:]``) in a process that ends after it.

    From its first fit on, its BLAS runs on one thread to the end (`fitter.workers.one_blas_thread_to_exit`):
    every fit does so within anyway, and a process that ends need not restore the count (a restore after a forked
    pool starts OpenBLAS's threads again only for them to spin while the process exits)."""
    from fitter.workers import one_blas_thread_to_exit

    one_blas_thread_to_exit()
    main(args=None if argv is None else list(argv), prog_name="duhem")
