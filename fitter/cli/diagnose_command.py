"""`duhem diagnose`: what the model misses, found, fitted and shown."""

from __future__ import annotations

import contextlib

import click

from fitter.cli.common import (
    warning,
    check_backend,
    check_fmu_name,
    column_options,
    effect_names,
    emit_json,
    load_model_json,
    python_host_note,
    refuse_overwrite,
    table,
    time_column,
)
from fitter.cli_support import CliError, FilePath, backend_option, fmi_version_option
from fitter.core.files import atomic_directory, atomic_file, json_text, jsonable
from fitter.data.recordings import load_recordings
from fitter.diagnosis import diagnose as run_diagnosis
from fitter.diagnosis.procedure import CANDIDATES
from fitter.fmu.build import build_fmu
from fitter.progress import stderr_progress
from fitter.reports.diagnosis_report import fill_diagnosis_report


@click.command()
@click.argument("recordings", nargs=-1, required=True, type=FilePath())
@click.option(
    "--model",
    "model_path",
    type=FilePath(),
    help="base model JSON (default: fit a rate-independent model of order --base-order)",
)
@click.option("--report", type=FilePath(directory=True), help="write the diagnosis report (HTML, PNG) here")
@click.option(
    "--json",
    "json_out",
    type=FilePath(allow_dash=True),
    help="write the diagnosis as JSON to this file ('-' for stdout)",
)
@click.option("--fmu", type=FilePath(), help="export the extended model as this FMU")
@backend_option
@fmi_version_option
@click.option(
    "--base-order",
    type=click.Choice(["auto", "1", "2", "3", "4"]),
    default="auto",
    show_default=True,
    help="without --model: order of the rate-independent base model (auto: the order 'duhem fit' "
    "chooses by BIC, so the base is adequate before effects are tested; 1: fitted here, fast; "
    "2-4: fitted by 'duhem fit --kind ri --order N' first; its A matrices are then held)",
)
@click.option(
    "--separate/--one-clock",
    "separate",
    default=None,
    help="force the reading of the files: separate runs, each simulated alone from the initial state "
    "fitted to it, as 'duhem fit' scores; or one clock running on from file to file (default: "
    "separate runs when a file starts at or before its predecessor ends, e.g. every file from t = 0)",
)
@click.option(
    "--candidates",
    callback=lambda ctx, param, value: effect_names(value),
    metavar="NAMES",
    help="the effects to test (comma-separated; default every effect searched for by default: "
    f"{', '.join(CANDIDATES)})",
)
@column_options
def diagnose(
    recordings,
    model_path,
    report,
    json_out,
    fmu,
    backend,
    fmi_version,
    base_order,
    separate,
    candidates,
    time_col,
    input_col,
    output_col,
):
    """Locate the model-data mismatch of one experiment, name the physics left out, model it.

    The recordings are one experiment in time order on one clock (e.g.
    several rates and a repeat of the first run), or separate runs, each
    on its own clock (recognised when a file starts at or before its
    predecessor ends; --separate / --one-clock force a reading).
    """
    refuse_overwrite([*recordings, model_path], report, json_out, fmu)
    check_fmu_name(fmu)
    if model_path and base_order != "auto":
        raise CliError("--base-order applies only without --model (the given model sets the base)")
    if fmu:
        check_backend(backend, fmi_version)
    base = load_model_json(model_path) if model_path else None
    recs = load_recordings(list(recordings), time_column(time_col), input_col, output_col, warn=warning)
    with contextlib.ExitStack() as outputs:
        json_tmp = (
            outputs.enter_context(atomic_file(json_out, suffix=".json")) if json_out and json_out != "-" else None
        )
        report_tmp = outputs.enter_context(atomic_directory(report)) if report else None
        fmu_tmp = outputs.enter_context(atomic_file(fmu, suffix=".fmu")) if fmu else None
        with stderr_progress("diagnosing", bar=True) as progress:
            result = run_diagnosis(
                recs,
                model=base,
                progress=progress,
                base_order=None if base_order == "auto" else int(base_order),
                separate=separate,
                candidates=candidates or CANDIDATES,
            )
        data = jsonable(result.to_json())
        if report_tmp:
            fill_diagnosis_report(result, recs, report_tmp)
        if fmu_tmp:
            build_fmu(result.extended_model, fmu_tmp, backend=backend, fmi_version=fmi_version)
        if json_tmp:
            json_tmp.write_text(json_text(data), encoding="utf-8")
    python_host_note(fmu, backend)
    if json_out == "-":
        emit_json(data)
        return
    click.echo(result.paragraph)
    _per_recording_table(data)
    findings = data.get("findings") or []
    if findings:
        table(
            "findings (most important first)",
            ["effect", "origin", "p-value", "explained fraction"],
            [[f.get("effect"), f.get("origin"), f.get("p_value"), f.get("explained_fraction")] for f in findings],
        )
        if result.verdict == "unexplained":
            click.echo(
                "unexplained: the findings explain part of the residual; what they leave is not the noise "
                "and no candidate effect explains it (the findings are partial: the nearest effects)"
            )
    elif result.verdict == "nothing_missing":
        click.echo("nothing missing: the residual is consistent with the noise level")
    else:
        click.echo("unexplained: the residual is above the noise but no candidate effect explains it")


def _per_recording_table(data: dict) -> None:
    """Per recording: NRMSE of the base and of the extended model, the extended model's held-out NRMSE (fitted
    without that recording) and, for separate runs, the output reference fitted to it (in the model's frame: the
    output divided by the file's gain, where the files' gains differ, ``file_gains``) and that gain."""
    base, ext = data["baseline"], data["extended"]
    held, refs = ext.get("heldout_nrmse_per_recording") or {}, ext.get("references") or {}
    gains = data.get("file_gains")
    rows = [
        [name, value, ext["nrmse_per_recording"].get(name), held.get(name), refs.get(name)]
        + ([gains.get(name, 1.0)] if gains else [])
        for name, value in base["nrmse_per_recording"].items()
    ]
    heads = ["recording", "base NRMSE", "extended NRMSE", "held out", "reference"] + (["gain"] if gains else [])
    table("per recording", heads, rows)
