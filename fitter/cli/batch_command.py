"""`duhem batch`: every device of a manifest, on Dask."""

from __future__ import annotations

from pathlib import Path

import click

from fitter.batch import BatchOptions, run_batch
from fitter.cli.common import check_backend, effect_names, emit_json, held_values, table
from fitter.cli_support import DEFAULT_THRESHOLD, CliError, FilePath, Number, backend_option
from fitter.identification.fit import ORDERS


@click.command()
@click.argument("manifest", type=FilePath())
@click.option(
    "-o",
    "--out",
    "outdir",
    required=True,
    type=FilePath(directory=True),
    help="output directory: OUTDIR/<device>/ per device, OUTDIR/summary.csv and OUTDIR/index.html",
)
@click.option(
    "--diagnose",
    "with_diagnosis",
    is_flag=True,
    help="also diagnose every device (its fitted model as the base): diagnosis.json and diagnosis/",
)
@click.option(
    "--scheduler",
    metavar="ADDRESS",
    help="use this running Dask scheduler (e.g. tcp://host:8786) instead of a local cluster",
)
@click.option(
    "--workers",
    type=Number(int, low=1),
    metavar="N",
    help="worker processes of the local cluster, one thread each (default: one per core)",
)
@backend_option
@click.option(
    "--kind",
    type=click.Choice(["ri", "rd", "auto"]),
    default="auto",
    show_default=True,
    help="model kind of every device's fit, as 'duhem fit --kind'",
)
@click.option(
    "--order", type=Number(int, low=1, high=max(ORDERS)), help="state dimension of every fit (default: chosen by BIC)"
)
@click.option(
    "--faithful-minor-loops",
    "faithful",
    is_flag=True,
    help="every fit keeps its settled minor loops near the data (as duhem fit --faithful-minor-loops)",
)
@click.option(
    "--effects",
    metavar="NAMES",
    callback=lambda ctx, param, value: effect_names(value),
    help="catalogue effects (comma-separated) fitted jointly with every device's base, as 'duhem fit --effects'",
)
@click.option(
    "--hold",
    "held",
    callback=lambda ctx, param, value: held_values(value),
    metavar="EFFECT.PARAM=VALUE",
    help="with --effects, effect parameters held at a known value in every fit, as 'duhem fit --hold'",
)
@click.option(
    "--threshold",
    type=Number(low=0, open_low=True),
    default=DEFAULT_THRESHOLD,
    show_default=True,
    help="validation: a device whose FMU has an NRMSE above this on a recording is 'invalid'",
)
@click.option(
    "--retry-failed",
    is_flag=True,
    help="run again the devices that failed on unchanged inputs (by default they are skipped)",
)
@click.option("--json", "as_json", is_flag=True, help="print what the batch did as JSON")
def batch(
    manifest,
    outdir,
    with_diagnosis,
    scheduler,
    workers,
    backend,
    kind,
    order,
    faithful,
    effects,
    held,
    threshold,
    retry_failed,
    as_json,
):
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
    options = BatchOptions(
        kind=kind,
        order=order,
        backend=backend,
        diagnose=with_diagnosis,
        threshold=threshold,
        faithful_minor_loops=faithful,
        effects=effects,
        held=tuple(held.items()),
    )
    check_backend(backend)
    report = run_batch(
        manifest,
        outdir,
        options=options,
        workers=workers,
        scheduler=scheduler,
        retry_failed=retry_failed,
        say=lambda line: click.echo(line, err=True),
    )
    if as_json:
        emit_json(report.to_json())
        return
    rows = [report.summary_row(d) for d in report.devices]
    table(
        f"duhem batch: {len(rows)} devices in {outdir} ({report.seconds:.1f} s)",
        ["device", "status", "this run", "model", "NRMSE", "effects found", "outliers", "reason"],
        [
            [
                r["device"],
                r["status"],
                r["action"],
                f"{r['kind']}{r['order']}" if r["kind"] else None,
                r["nrmse"],
                r["effects"],
                r["outliers"] or None,
                r["reason"] or None,
            ]
            for r in rows
        ],
    )
    counts = report.counts()
    click.echo(
        ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
        + f"; summary: {Path(outdir) / 'summary.csv'}, {Path(outdir) / 'index.html'}"
    )
