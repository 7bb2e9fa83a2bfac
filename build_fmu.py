"""FMU generator script: a saved model JSON in, an FMI 2.0 Co-Simulation FMU out.

Usage::

    python build_fmu.py model.json -o model.fmu [--backend native|python] [--fmi-version 2|3] [--inverse]

prints the FMU's absolute path (exit status 0), or one line ``error: ...``
on stderr (exit status 1).  The default backend is ``native``: the FMU then
runs in simulators without Python.  ``--fmi-version 3`` (native backend only)
writes an FMI 3.0 Co-Simulation FMU; ``--inverse`` the model's compensator
(input y_ref, output u; ``duhem export --inverse``).  The generator is `fitter.fmu.build`;
``import build_fmu; build_fmu.build_fmu(model_or_json_path, out_path,
backend=...)`` is the same function (``duhem export`` is the same export with
the package's command line).
"""

from __future__ import annotations

import sys
from typing import Sequence

import click

from fitter.cli_support import FilePath, backend_option, fmi_version_option, guarded, run_command
from fitter.fmu.build import BACKENDS, FMI_VERSIONS, MODEL_IDENTIFIER, FmuBuildError, build_fmu

__all__ = ["build_fmu", "FmuBuildError", "MODEL_IDENTIFIER", "BACKENDS", "FMI_VERSIONS", "command", "main"]


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("model", type=FilePath())
@click.option("-o", "--output", required=True, type=FilePath(), help="FMU file to write")
@backend_option
@fmi_version_option
@click.option("--inverse", is_flag=True, help="export the model's compensator (input y_ref, output u)")
@guarded
def command(model: str, output: str, backend: str, fmi_version: int, inverse: bool) -> None:
    """Export a semilinear Duhem model JSON (duhem fit output) as an FMI 2.0 or 3.0 Co-Simulation FMU."""
    click.echo(build_fmu(model, output, backend=backend, fmi_version=fmi_version, inverse=inverse))


def main(argv: Sequence[str] | None = None) -> int:
    """`command` on `argv` (default ``sys.argv[1:]``); returns the exit status."""
    return run_command(command, argv, "build_fmu.py")


if __name__ == "__main__":
    sys.exit(main())
