"""`duhem simulate` and `duhem compensate`: a model (or its inverse) run on an input file."""

from __future__ import annotations

import contextlib
from pathlib import Path

import click
import numpy as np

from fitter.cli.common import (
    check_units,
    checked,
    emit_json,
    finite_output,
    is_zip,
    load_model_json,
    no_time_option,
    open_fmu,
    refuse_overwrite,
    time_column,
    use_unstable_option,
    warn_minor_loops,
)
from fitter.cli_support import CliError, FilePath, Number, ordered_pair
from fitter.core.files import atomic_file
from fitter.core.inverse import MEASUREMENT_CHOICES, Compensator, linear_gain
from fitter.core.kernel import simulate as simulate_model
from fitter.data.recordings import load_recording, save_columns
from fitter.fmu.host import simulate_fmu
from fitter.identification.exported import range_warnings
from fitter.progress import stderr_progress
from fitter.reports.compensation_plot import write_compensation_plot


@click.command()
@click.argument("model", type=FilePath())
@click.argument("input_csv", type=FilePath())
@click.option("-o", "--out", "out", required=True, type=FilePath(), help="CSV file to write (columns time,u,y)")
@click.option("--time", "time_col", default="time", show_default=True, metavar="COL", help="time column")
@no_time_option
@click.option("--input", "input_col", default="u", show_default=True, metavar="COL", help="input column")
@use_unstable_option
@click.option("--json", "as_json", is_flag=True, help="print a summary as JSON")
def simulate(model, input_csv, out, time_col, input_col, allow_unstable, as_json):
    """Simulate a model JSON (in-process kernel) or an FMU (fmpy) for a recorded input.

    The input is taken as piecewise linear between samples; the model starts
    from its stored initial state x0.  The output CSV has columns time,u,y.
    """
    refuse_overwrite([model, input_csv], out)
    rec = load_recording(input_csv, time_column(time_col), input_col, None)
    with stderr_progress("duhem simulate") as say, atomic_file(out, suffix=".csv") as tmp:
        say(f"simulating {len(rec)} samples", None)
        if is_zip(model):
            stored = open_fmu(model)
            check_units(stored, [rec], model)
            checked(stored, f"{model} (its resources/model.json)", allow_unstable, rec.u)
            y = simulate_fmu(model, rec.t, rec.u)
            engine = "fmu"
        else:
            stored = load_model_json(model)
            check_units(stored, [rec], model)
            checked(stored, model, allow_unstable, rec.u)
            y = simulate_model(stored, rec.t, rec.u).y
            engine = "in-process"
        finite_output(y, rec, "the simulated output")
        warnings = range_warnings(stored, rec.t, rec.u, y)
        save_columns(tmp, ["time", "u", "y"], [rec.t, rec.u, y])
    info = {
        "model": model,
        "input": input_csv,
        "out": out,
        "engine": engine,
        "samples": len(rec),
        "y_min": float(np.min(y)),
        "y_max": float(np.max(y)),
        "warnings": warnings,
    }
    for w in warnings:
        click.echo(f"warning: {input_csv}: {w}", err=True)
    if as_json:
        emit_json(info)
    else:
        click.echo(f"{len(rec)} samples simulated ({engine}) and written to {out}")


@click.command()
@click.argument("model", type=FilePath())
@click.argument("reference", type=FilePath())
@click.option(
    "-o", "--out", "out", required=True, type=FilePath(), help="CSV file to write (columns time,u,y_predicted)"
)
@click.option(
    "--plot", type=FilePath(), help="write a PNG: y_ref, the plant without compensation (linear gain) and with it"
)
@click.option("--time", "time_col", default="time", show_default=True, metavar="COL", help="time column")
@no_time_option
@click.option("--ref", "ref_col", default="y_ref", show_default=True, metavar="COL", help="reference column")
@click.option("--u0", type=Number(), help="the plant's input before the first sample (default: mid input range)")
@click.option(
    "--input-range",
    "input_range",
    type=Number(),
    nargs=2,
    metavar="LO HI",
    callback=ordered_pair,
    help="inputs the compensator may use (default: the model's input_range)",
)
@click.option(
    "--measurement",
    type=click.Choice(MEASUREMENT_CHOICES),
    default="refuse",
    show_default=True,
    help="a model with measurement effects (sensor_lag, measurement_drift): drop them (the device "
    "output follows y_ref) or invert them (the measured output follows y_ref)",
)
@use_unstable_option
@click.option("--json", "as_json", is_flag=True, help="print a summary as JSON")
def compensate(model, reference, out, plot, time_col, ref_col, u0, input_range, measurement, allow_unstable, as_json):
    """The input that makes a model's output follow a reference (the inverse model, a feedforward compensator).

    Exact wherever some input in the model's input range reaches y_ref (the
    compensator and the plant run the same kernel); elsewhere the output is
    clamped to the nearest reachable value and the clamped samples are
    reported.  The output CSV has columns time,u,y_predicted (the model's
    output for that input, from its stored x0).
    """
    refuse_overwrite([model, reference], out, plot)
    if plot and Path(plot).suffix.lower() != ".png":
        raise CliError(f"{plot}: the plot file name must end in .png")
    m = load_model_json(model)
    checked(m, model, allow_unstable, *([input_range] if input_range else []))
    rec = load_recording(reference, time_column(time_col), ref_col, None)
    comp = Compensator(m, t0=float(rec.t[0]), u0=u0, measurement=measurement, input_range=input_range)
    with stderr_progress("duhem compensate") as say, contextlib.ExitStack() as outputs:
        csv_tmp = outputs.enter_context(atomic_file(out, suffix=".csv"))
        plot_tmp = outputs.enter_context(atomic_file(plot, suffix=".png")) if plot else None
        say(f"compensating {len(rec)} samples", None)
        result = comp.run(rec.t, rec.u)
        save_columns(csv_tmp, ["time", "u", "y_predicted"], [result.t, result.u, result.y])
        info = {
            "model": model,
            "reference": reference,
            "out": out,
            "plot": plot,
            "measurement": measurement,
            **result.summary(),
        }
        if plot_tmp:
            say("plotting", None)
            y0, gain = linear_gain(result.u, result.y)
            lo, hi = result.input_range
            u_linear = np.clip((result.y_ref - y0) / gain, lo, hi)
            u_linear[0] = result.u[0]  # the plant starts where the compensated run starts
            y_linear = simulate_model(comp.plant, result.t, u_linear).y
            info["linear_gain"] = {
                "y0": y0,
                "gain": gain,
                "tracking_error": float(
                    np.sqrt(np.mean((y_linear - result.y_ref) ** 2)) / (np.ptp(result.y_ref) or 1.0)
                ),
            }
            write_compensation_plot(
                plot_tmp,
                result.t,
                result.y_ref,
                y_linear,
                result.y,
                result.clamped,
                output_label=_axis_name(m.signals.output),
                title=f"{Path(reference).name}: compensation of {Path(model).name}",
            )
    warn_minor_loops(m)
    lo, hi = result.input_range
    if u0 is not None and not lo <= u0 <= hi:
        click.echo(
            f"warning: --u0 {u0:g} is outside the input range [{lo:.6g}, {hi:.6g}]: the plant holds its "
            f"input at the nearest edge there",
            err=True,
        )
    if result.n_clamped:
        click.echo(
            f"warning: {reference}: {result.n_clamped} of {len(rec)} samples clamped (no input in "
            f"[{result.input_range[0]:.6g}, {result.input_range[1]:.6g}] reaches y_ref); largest shortfall "
            f"{result.max_shortfall:.4g} at t = {info['max_shortfall_time']:.6g}",
            err=True,
        )
    if as_json:
        emit_json(info)
    else:
        click.echo(
            f"{len(rec)} samples compensated and written to {out} ({result.n_clamped} clamped, tracking "
            f"error {100 * result.tracking_error():.3g}% of the reference range)"
        )


def _axis_name(signal) -> str:
    return f"{signal.name} [{signal.unit}]" if signal.unit else signal.name
