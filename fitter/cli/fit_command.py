"""`duhem fit`: recordings in, a model (and its FMU, report, comparison) out."""

from __future__ import annotations

import contextlib

import click

from fitter.baselines import comparison
from fitter.cli.common import (
    warning,
    allow_unstable_option,
    check_backend,
    check_fmu_name,
    column_options,
    effect_names,
    emit_json,
    fmt,
    fmt_list,
    held_values,
    python_host_note,
    refuse_overwrite,
    table,
    time_column,
    warn_minor_loops,
)
from fitter.cli_support import FilePath, Number, backend_option, fmi_version_option
from fitter.core.effects import REGISTRY
from fitter.core.files import atomic_directory, atomic_file, atomic_pair, jsonable
from fitter.core.models import save_model
from fitter.data.recordings import load_recordings
from fitter.fmu.build import build_fmu
from fitter.fmu.pair import recorded_fmu_digest, with_fmu_record
from fitter.identification.effects_fit import check_effects, check_held
from fitter.identification.explained import check_explained, explained_text, explained_variance
from fitter.identification import fit_summary
from fitter.identification.fit import ORDERS, fit_recordings
from fitter.progress import stderr_progress
from fitter.reports.fit_report import fill_fit_report


@click.command()
@click.argument("recordings", nargs=-1, required=True, type=FilePath())
@click.option(
    "--kind",
    type=click.Choice(["ri", "rd", "auto"]),
    default="auto",
    show_default=True,
    help="rate-independent (eqs 1-2), rate-dependent (eqs 18-19) or chosen by BIC",
)
@click.option("-o", "--out", "out", required=True, type=FilePath(), help="model JSON file to write")
@click.option("--fmu", type=FilePath(), help="also export the model as this FMU")
@backend_option
@fmi_version_option
@click.option("--report", type=FilePath(directory=True), help="write a fit report (HTML, PNG) here")
@click.option("--order", type=Number(int, low=1, high=max(ORDERS)), help="state dimension n (default: chosen by BIC)")
@click.option(
    "--q",
    type=Number(low=0, open_low=True),
    help="bound on sigma_max(A+-) of the Section III least squares, which gives one starting value of the "
    "rate-independent refinement (odd orders, periodic inputs; unused otherwise): the refined model is not bound "
    "by it, and another start may win",
)
@click.option(
    "--x0",
    "x0_policy",
    type=click.Choice(["fitted", "periodic"]),
    default="fitted",
    show_default=True,
    help="stored initial state at the first sample of the first recording: fitted to it (least "
    "squares), or leading onto the periodic response of its first cycle",
)
@click.option(
    "--faithful-minor-loops",
    "faithful",
    is_flag=True,
    help="keep every settled minor loop within half an output range of the recorded output "
    "(rate-independent candidates): the model stays near the data on loops smaller than the "
    "recorded ones, at a cost in accuracy where the recorded loop switches sharply",
)
@click.option(
    "--effects",
    "effects",
    callback=lambda ctx, param, value: effect_names(value),
    metavar="NAMES",
    help="effects of the catalogue (comma-separated, e.g. switching) fitted jointly with the base model: "
    f"physics you know the device has ({', '.join(REGISTRY)})",
)
@click.option(
    "--hold",
    "held",
    callback=lambda ctx, param, value: held_values(value),
    metavar="EFFECT.PARAM=VALUE",
    help="with --effects, effect parameters held at a value you know instead of fitted (comma-separated, "
    "e.g. measurement_drift.rate=0: each recording's output has its own reference, no drift)",
)
@allow_unstable_option
@click.option(
    "--allow-noise",
    is_flag=True,
    help="save the model even when it explains less than half of a recording's output variance "
    "(R^2 < 0.5: the output looks like noise, with no relation to the input)",
)
@column_options
@click.option(
    "--compare",
    is_flag=True,
    help="also fit the classical models (Preisach, Prandtl-Ishlinskii, Bouc-Wen) to the same recordings "
    "and show their NRMSE beside the Duhem model's (summary key 'comparison', and in the report)",
)
@click.option("--json", "as_json", is_flag=True, help="print the fit summary as JSON")
def fit(
    recordings,
    kind,
    out,
    fmu,
    backend,
    fmi_version,
    report,
    order,
    q,
    x0_policy,
    faithful,
    effects,
    held,
    allow_unstable,
    allow_noise,
    time_col,
    input_col,
    output_col,
    compare,
    as_json,
):
    """Fit a model to one or more recordings (one CSV file per experiment, e.g. per rate)."""
    if effects and x0_policy != "fitted":
        raise click.UsageError("--effects needs --x0 fitted (each effect's initial state is fitted per recording)")
    held = check_held(held, check_effects(effects))
    refuse_overwrite(recordings, out, fmu, report)
    check_fmu_name(fmu)
    if fmu:
        check_backend(backend, fmi_version)
    recs = load_recordings(list(recordings), time_column(time_col), input_col, output_col, warn=warning)
    with stderr_progress("duhem fit") as say, contextlib.ExitStack() as outputs:
        if fmu:
            model_tmp, fmu_tmp = outputs.enter_context(atomic_pair(out, fmu, recorded_fmu_digest))
        else:
            model_tmp, fmu_tmp = outputs.enter_context(atomic_file(out, suffix=".json")), None
        report_tmp = outputs.enter_context(atomic_directory(report)) if report else None
        say(f"fitting {len(recs)} recording(s)", None)
        result = fit_recordings(
            recs,
            kind=kind,
            order=order,
            q=q,
            x0=x0_policy,
            faithful_minor_loops=faithful,
            effects=effects,
            held=held,
            progress=say,
        )
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
            build_fmu(model, fmu_tmp, backend=backend, allow_unstable=allow_unstable, fmi_version=fmi_version)
            model = with_fmu_record(model, fmu, fmu_tmp, out)
        save_model(model, model_tmp)
    python_host_note(fmu, backend)
    if noise:
        click.echo(f"warning: {noise['source']}: {explained_text(noise)}; saved because of --allow-noise", err=True)
    summary = result.summary
    conv = summary.get("convergence") or {}
    if conv and not conv.get("satisfied"):
        click.echo(
            "warning: the convergence condition is violated: a wrong initial state need not die out; "
            "the FMU is exported only with --allow-unstable",
            err=True,
        )
    warn_minor_loops(result.model)
    misfit = summary.get("misfit") or {}
    if misfit and not misfit["followed"]:
        click.echo(f"warning: {fit_summary.misfit_text(misfit)}", err=True)
    if as_json:
        emit_json({"model": out, "fmu": fmu, "backend": backend if fmu else None, "report": report, "summary": summary})
        return
    click.echo(
        f"{result.model.kind} model of order {result.model.order} written to {out}"
        + (f", FMU {fmu} ({backend} backend)" if fmu else "")
        + (f", report in {report}" if report else "")
    )
    if summary.get("why"):
        click.echo(f"chosen: {summary['why']}")
    _budget_lines(summary)
    _file_property_lines(summary)
    effects = summary.get("effects") or {}
    held = effects.get("held") or {}
    for e in effects.get("fitted", []):
        free = [f"{k} = {fmt(v)}" for k, v in e["parameters"].items() if f"{e['effect']}.{k}" not in held]
        click.echo(f"effect {e['effect']} fitted with the base: " + (", ".join(free) or "none of its parameters"))
    if held:
        click.echo("held, not fitted: " + ", ".join(f"{k} = {fmt(v)}" for k, v in held.items()))
    if effects:
        settled = effects.get("settled") or []
        click.echo(
            "effects started settled on the closed loops " + ", ".join(settled)
            if settled
            else "effects started afresh (no recording is a closed loop)"
        )
    if conv:
        click.echo(
            f"convergence condition: {'satisfied' if conv.get('satisfied') else 'VIOLATED'} "
            f"({conv.get('quantity')} = {fmt(conv.get('value'))}, margin {fmt(conv.get('margin'))}; "
            f"spectral radius on the raw input {fmt_list(conv.get('rho_raw_input_per_recording'))})"
        )
    _minor_loop_lines(summary.get("minor_loops"))
    click.echo(f"NRMSE: {summary.get('nrmse_convention')}")
    recs = summary.get("recordings", [])
    rows = [
        [
            r.get("recording"),
            r.get("nrmse"),
            r.get("nrmse_x0_fitted"),
            r.get("nrmse_last_cycle"),
            r.get("max_error"),
            r.get("loop_area_error"),
            r.get("residual_rms"),
            r.get("noise_rms"),
        ]
        for r in recs
    ]
    table(
        "the saved model on each recording (from its stored x0, and from the recording's own fitted x0)",
        [
            "recording",
            "NRMSE (all samples)",
            "NRMSE own x0",
            "NRMSE last cycle",
            "max error",
            "loop area err",
            "residual RMS",
            "noise RMS",
        ],
        rows,
    )
    _own_start_note(recs)
    if "comparison" in summary:
        _comparison_tables(summary["comparison"])


_FILE_PROPERTIES = (
    (
        "references",
        "{:+.6g}",
        "output references (each file's zero relative to {first}'s, a property of the files, not of the device; "
        "every score adds them)",
    ),
    (
        "gains",
        "x{:.6g}",
        "output gains (each file's scale relative to {first}'s, a property of the files: an instrument's calibration "
        "or an operating condition, not the device; every score applies them)",
    ),
)
"""(summary key, value format, line) of what the fit found per file (`_file_property_lines`)."""


def _file_property_lines(summary: dict) -> None:
    """The output references and gains the fit found (the summary's ``references``, ``gains``), one line each."""
    for key, form, text in _FILE_PROPERTIES:
        found = summary.get(key)
        if found:
            values = ", ".join(f"{k} {form.format(v)}" for k, v in found["values"].items())
            click.echo(f"{text.format(first=found['relative_to'])}: {values}")


def _own_start_note(recs: list[dict]) -> None:
    """Where a recording is reproduced much better from its own start than from the stored x0, say how to
    run the FMU from there."""
    worse = [
        r["recording"]
        for r in recs
        if r.get("nrmse_x0_fitted") is not None
        and r.get("nrmse") is not None
        and r["nrmse"] > 1.5 * r["nrmse_x0_fitted"] + 1e-3
    ]
    if worse:
        click.echo(
            f"note: {', '.join(worse)} started from another state than the stored x0 (fitted to the first "
            "recording): each recording's own start is in the summary (recordings[].x0_fitted, "
            "recordings[].effect_start_fitted); `duhem validate --x0 fitted` sets the FMU's start "
            "parameters to it"
        )


def _minor_loop_lines(minor: dict | None) -> None:
    """The fit's `minor_loops` check in one line."""
    if not minor:
        return
    exc = minor.get("excursion")
    size = "overflows" if exc is None else f"leaves the recorded output range by {exc:.3g} output ranges"
    click.echo(f"minor loops inside the input range: the output {size} at most ({minor.get('input')})")


def _comparison_tables(comp: dict) -> None:
    """`duhem fit --compare`: the Duhem model beside each classical model, one row per recording."""
    names = list(comp["baselines"])
    recs = list(comp["duhem"])
    table(
        f"NRMSE beside the classical models, one parameter set for all recordings ({comp['measure']})",
        ["recording", "Duhem", *names],
        [[r, comp["duhem"][r], *[comp["baselines"][n]["one_for_all"][r] for n in names]] for r in recs],
    )
    if len(recs) > 1:
        table(
            "classical models fitted to each recording alone",
            ["recording", *names],
            [[r, *[comp["baselines"][n]["per_recording"][r] for n in names]] for r in recs],
        )


def _budget_lines(summary: dict) -> None:
    """A line per refinement that stopped at its evaluation budget before its tolerances were met (the
    summary's ``optimiser.budget_hit``): the fit is where the budget stopped it, which the scores show."""
    stages = (
        ("the chosen base", summary.get("optimiser")),
        ("the base with the effects", (summary.get("effects") or {}).get("optimiser")),
    )
    for what, opt in stages:
        if opt and opt.get("budget_hit"):
            click.echo(
                f"note: the refinement of {what} stopped at its evaluation budget ({opt['nfev']} in its last "
                "stage) before its tolerances were met; the scores below are where it stopped"
            )
