"""`duhem export` and `duhem validate`: a model's FMU, and the FMU checked against recordings.

`duhem validate` checks that the FMU runs the model it carries (``resources/model.json``) before it judges the
fit: the binary's output agrees with the kernel's within the limit that follows the model's own amplification
of rounding (`fitter.core.checks.check_agreement`), the binary holds the model JSON's parameters
(`_check_binary_parameters`, read back through fmi2GetReal) and the modelDescription declares them as its start
values (`_check_start_values`: an importer applies them), both exactly.  The exact checks catch what the
outputs cannot show: a model that amplifies rounding by 1e10 has an agreement limit near 1e-4 of the output
range, which a change of D or x0 by 1e-6 of its value stays below.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import click
import numpy as np

from fitter.cli.common import (
    check_units,
    warning,
    allow_unstable_option,
    check_fmu_name,
    checked,
    column_options,
    emit_json,
    finite_output,
    load_model_json,
    open_fmu,
    platforms,
    python_host_note,
    refuse_overwrite,
    table,
    time_column,
    use_unstable_option,
    warn_minor_loops,
)
from fitter.cli_support import (
    DEFAULT_THRESHOLD,
    EXIT_VALIDATION_FAILED,
    CliError,
    FilePath,
    Number,
    backend_option,
    fmi_version_option,
)
from fitter.core.checks import agreement_limit, check_agreement, rounding_sensitivity, with_convergence
from fitter.core.files import atomic_file
from fitter.core.inverse import MEASUREMENT_CHOICES
from fitter.core.kernel import simulate as simulate_model
from fitter.data.metrics import compare
from fitter.data.recordings import load_recordings
from fitter.fmu.build import build_fmu
from fitter.fmu.host import collecting_callbacks, simulate_fmu
from fitter.fmu.toolchain import PLATFORMS, parse_platforms
from fitter.fmu.variables import model_variables, start_state_values
from fitter.identification.exported import file_gain, file_reference, levelled, own_start, range_warnings, started
from fitter.progress import stderr_progress
from fitter.reports.validation_plot import write_validation_plot


@click.command()
@click.argument("model", type=FilePath())
@click.option("-o", "--out", "out", required=True, type=FilePath(), help="FMU file to write")
@backend_option
@fmi_version_option
@allow_unstable_option
@click.option(
    "--inverse",
    is_flag=True,
    help="export the model's feedforward compensator instead (input y_ref, output u: the input that "
    "makes the model's output follow y_ref; see 'duhem compensate')",
)
@click.option(
    "--measurement",
    type=click.Choice(MEASUREMENT_CHOICES),
    default="refuse",
    show_default=True,
    help="with --inverse, a model with measurement effects (sensor_lag, measurement_drift): drop them "
    "(the device output follows y_ref) or invert them (the measured output follows y_ref)",
)
@click.option(
    "--platforms",
    default=None,
    metavar="LIST",
    callback=platforms,
    help=f"native backend: the binaries, a comma list of {', '.join(PLATFORMS)} (or linux, windows, "
    "darwin, host); default all (or $DUHEM_PLATFORMS), compiled with zig (package ziglang), no system "
    "compiler needed",
)
@click.option(
    "--cc",
    default=None,
    metavar="COMPILER",
    help="native backend: compile this machine's binary with this system C compiler instead of zig "
    "(the other platforms' still with zig)",
)
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
        raise CliError(
            "--platforms and --cc apply to the native backend (a python-backend FMU runs where its host's Python does)"
        )
    m = load_model_json(model)
    refuse_overwrite([model], out)
    check_fmu_name(out)
    m = with_convergence(m, checked(m, model, allow_unstable))
    what = "compensator " if inverse else ""
    with stderr_progress("duhem export") as say, atomic_file(out, suffix=".fmu") as tmp:
        say(f"building the {backend} FMI {fmi_version}.0 {what}FMU", None)
        native = {"platforms": platforms, "cc": cc} if backend == "native" else {}
        build_fmu(
            m,
            tmp,
            backend=backend,
            allow_unstable=allow_unstable,
            fmi_version=fmi_version,
            inverse=inverse,
            measurement=measurement,
            **native,
        )
    if as_json:
        emit_json(
            {
                "model": model,
                "fmu": out,
                "backend": backend,
                "fmi_version": f"{fmi_version}.0",
                "kind": m.kind,
                "order": m.order,
                "inverse": inverse,
                "platforms": list(platforms or parse_platforms(None)) if backend == "native" else None,
            }
        )
    else:
        click.echo(
            f"{m.kind} model of order {m.order} exported to {out} ({backend} backend, FMI {fmi_version}.0)"
            if not inverse
            else f"compensator of the {m.kind} model of order {m.order} exported to {out} (input y_ref, output "
            f"u; {backend} backend, FMI {fmi_version}.0)"
        )
    if inverse:
        warn_minor_loops(m)
    python_host_note(out, backend)


def _validation_row(rec, y_fmu: np.ndarray, model, threshold: float, x0_rule: str, fmu: str) -> dict:
    """`compare` of one recording, with the FMU vs in-process difference (`model` from the FMU's start), which
    must be within max(AGREEMENT, K s) of the output range R, s the model's rounding sensitivity on the
    recording (`fitter.core.checks.check_agreement`), and the verdict.  The row gives the difference in the
    output's unit, the limit (times R, same unit) and s."""
    y_model = simulate_model(model, rec.t, rec.u).y
    finite_output(y_fmu, rec, f"the output of {fmu}")
    scale = float(np.ptp(rec.y))
    s = rounding_sensitivity(model, rec.t, rec.u, scale, y_model)
    check_agreement(
        y_fmu,
        y_model,
        scale,
        f"{fmu}: its binary",
        "its resources/model.json (run by the in-process kernel)",
        rec.source,
        sensitivity=s,
    )
    m = compare(rec, y_fmu)
    m["fmu_vs_in_process_max_abs"] = float(np.max(np.abs(y_fmu - y_model)))
    m["fmu_vs_in_process_limit"] = agreement_limit(s) * (scale if scale > 0 else 1.0)
    m["rounding_sensitivity"] = s
    m["reference"], m["gain"] = file_reference(model, rec), file_gain(model, rec)
    m.update(
        recording=rec.name,
        source=rec.source,
        passed=bool(m["nrmse"] <= threshold),
        judged_on="all samples",
        x0=x0_rule,
        x0_value=np.asarray(model.x0, dtype=float).tolist(),
        warnings=range_warnings(model, rec.t, rec.u, y_fmu),
    )
    return m


def _expected_starts(model) -> dict:
    """{name: (value reference, start)} of the FMU variables that hold the model JSON's numbers (the parameters,
    order and kind: `fitter.fmu.variables.model_variables` with a path into the JSON)."""
    return {v.name: (v.value_reference, v.start) for v in model_variables(model) if v.path}


def _same_start(text: str | None, value) -> bool:
    """Whether a modelDescription start attribute `text` is `value` (a number compared exactly as a double)."""
    if text is None or isinstance(value, str):
        return text == value
    try:
        return float(text) == float(value)
    except ValueError:
        return False


def _check_start_values(fmu: str, model) -> None:
    """CliError (one line) when a variable of the FMU's modelDescription.xml that holds a number of its
    resources/model.json is missing or declares another value reference or start value: an importer starts
    the FMU from those start values, so an edited description runs another model there."""
    from fmpy import read_model_description

    declared = {v.name: v for v in read_model_description(fmu).modelVariables}
    bad = []
    for name, (vr, start) in _expected_starts(model).items():
        v = declared.get(name)
        if v is None or v.valueReference != vr or not _same_start(v.start, start):
            got = "is missing" if v is None else f"has value reference {v.valueReference}, start {v.start}"
            bad.append(f"{name} {got} where its resources/model.json gives value reference {vr}, start {start!r}")
    if bad:
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        raise CliError(
            f"{fmu}: its modelDescription.xml and its resources/model.json disagree: {bad[0]}{more}; one of them "
            "was altered after export: export the FMU again from the model JSON (duhem export)"
        )


def _binary_reals(fmu: str, refs: list[int]) -> list[float]:
    """The values the FMI 2.0 binary of `fmu` holds for the Real variables `refs`, read (fmi2GetReal) in
    initialization mode of a fresh instance with no value set."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(fmu)
    unzipdir = extract(fmu)
    slave = FMU2Slave(
        guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier, instanceName="duhem"
    )
    log: list[str] = []
    callbacks = collecting_callbacks(log)
    try:
        slave.instantiate(callbacks=callbacks, loggingOn=True)
        try:
            slave.setupExperiment(startTime=0.0)
            slave.enterInitializationMode()
            return list(slave.getReal(refs))
        finally:
            slave.freeInstance()
    except Exception as exc:  # fmpy raises FMICallException
        raise CliError(f"{fmu}: its binary's parameters cannot be read: {exc} {'; '.join(log[-3:])}".strip()) from None
    finally:
        shutil.rmtree(unzipdir, ignore_errors=True)


def _check_binary_parameters(fmu: str, model) -> None:
    """CliError (one line) when the FMU's binary holds a real parameter other than its resources/model.json's
    (compared exactly: both are the exported doubles).  Run after the FMU has been simulated (which names a
    binary that cannot run): it catches the changes the outputs cannot show within the agreement limit."""
    reals = {n: (vr, s) for n, (vr, s) in _expected_starts(model).items() if not isinstance(s, (str, int))}
    held = dict(zip(reals, _binary_reals(fmu, [vr for vr, _ in reals.values()])))
    bad = [
        f"{n} = {held[n]!r} where its resources/model.json gives {s!r}" for n, (_, s) in reals.items() if held[n] != s
    ]
    if bad:
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        raise CliError(
            f"{fmu}: its binary and its resources/model.json disagree: the binary holds {bad[0]}{more}; one of "
            "them was altered after export: export the FMU again from the model JSON (duhem export)"
        )


def _validation_start(model, rec, x0_rule: str):
    """The model as the FMU starts for `rec`: its stored x0, or (``"fitted"``) the state fitted to `rec`
    (`fitter.identification.exported.own_start`), which the FMU gets through its x0 parameters (and, for
    effects fitted with a settled start, its ``<effect>.start.<state>`` parameters).
    CliError naming the recording when that fit overflows (no silent fall-back to the stored x0)."""
    if x0_rule == "stored":
        return model
    start = own_start(model, rec)
    if start is None:
        raise CliError(
            f"{rec.source}: no start state could be fitted to this recording (the simulation "
            "overflowed); validate it from the stored x0 (--x0 stored)"
        )
    return started(model, start)


def _judged(row: dict) -> float:
    return row["nrmse"]


@click.command()
@click.argument("fmu", type=FilePath())
@click.argument("recordings", nargs=-1, required=True, type=FilePath())
@click.option(
    "--threshold",
    type=Number(low=0, open_low=True),
    default=DEFAULT_THRESHOLD,
    show_default=True,
    help="fail (exit code 3) when the NRMSE over all samples of a recording exceeds this",
)
@click.option("--plot", type=FilePath(), help="write a PNG overlay of the loops")
@click.option(
    "--x0",
    "x0_rule",
    type=click.Choice(["stored", "fitted"]),
    default="stored",
    show_default=True,
    help="the FMU's start state: as stored, or fitted to each recording (set through the FMU's x0 "
    "parameters; the figure `duhem fit` reports as 'NRMSE own x0')",
)
@use_unstable_option
@column_options
@click.option("--json", "as_json", is_flag=True, help="print the comparison as JSON")
def validate(fmu, recordings, threshold, plot, x0_rule, allow_unstable, time_col, input_col, output_col, as_json):
    """Drive an FMU with recorded inputs (fmpy) and compare its closed curves with the data.

    Per recording: NRMSE (RMS error / output range) over all samples, the
    FMU started from its stored x0 (the figure `duhem fit` reports, and the
    one judged) or, with ``--x0 fitted``, from the state fitted to that
    recording (one model for recordings made after different histories),
    NRMSE and max error over the last full input cycle, the
    loop-area error, and the largest difference between the FMU and the
    in-process simulation of the model stored in the FMU.  A recording of
    the name of one that `duhem fit` fitted with an output reference and gain
    of its own (files whose outputs have different zeros or gains) is compared
    in the model's frame: its output less that reference, divided by that gain
    (``reference`` and ``gain`` in the JSON; the NRMSE is the same in both frames).

    The FMU must run the model it carries (exit code 1 otherwise): its
    binary's output within max(1e-6, 100 s) of the output range of the
    kernel's, s the model's own amplification of rounding measured on the
    recording (the kernel against itself on its other algorithm and with its
    parameters moved by a few units in the last place), and its binary's
    parameters and its modelDescription's start values equal to its
    resources/model.json's, exactly.
    """
    refuse_overwrite([fmu, *recordings], plot)
    if plot and Path(plot).suffix.lower() != ".png":
        raise CliError(f"{plot}: the plot file name must end in .png")
    model = open_fmu(fmu)
    recs = load_recordings(list(recordings), time_column(time_col), input_col, output_col, warn=warning)
    check_units(model, recs, fmu)
    checked(model, f"{fmu} (its resources/model.json)", allow_unstable, *[rec.u for rec in recs])
    recs = [levelled(model, rec) for rec in recs]  # the reference `duhem fit` found for a recording of its name
    rows, outputs = [], []
    with stderr_progress("duhem validate") as say:
        for rec in recs:
            say(f"simulating {rec.name} in the FMU ({len(rec)} samples)", None)
            started = _validation_start(model, rec, x0_rule)
            start = None if x0_rule == "stored" else start_state_values(started)
            outputs.append(simulate_fmu(fmu, rec.t, rec.u, start=start))
            rows.append(_validation_row(rec, outputs[-1], started, threshold, x0_rule, fmu))
        _check_binary_parameters(fmu, model)
        _check_start_values(fmu, model)
        if plot:
            say("plotting", None)
            write_validation_plot(plot, recs, outputs, [_judged(r) for r in rows])
    passed = all(r["passed"] for r in rows)
    if as_json:
        emit_json({"fmu": fmu, "threshold": threshold, "passed": passed, "plot": plot, "recordings": rows})
    else:
        table(
            f"validation of {fmu} (threshold NRMSE {threshold:g} over all samples; "
            f"{'stored x0' if x0_rule == 'stored' else 'x0 fitted to each recording'})",
            [
                "recording",
                "NRMSE all",
                "NRMSE last cycle",
                "max err last cycle",
                "loop area err",
                "FMU vs in-process",
                "pass",
            ],
            [
                [
                    r["recording"],
                    r["nrmse"],
                    r["nrmse_last_cycle"],
                    r["max_error_last_cycle"],
                    r["loop_area_error"],
                    r["fmu_vs_in_process_max_abs"],
                    "yes" if r["passed"] else "NO",
                ]
                for r in rows
            ],
        )
    refs = [
        f"{r['recording']} {r['reference']:+.6g}" + (f" x{r['gain']:.6g}" if r["gain"] != 1.0 else "")
        for r in rows
        if r["reference"] != 0.0 or r["gain"] != 1.0
    ]
    if refs and not as_json:
        click.echo(
            "compared with the FMU's output times the gain and plus the output reference `duhem fit` found for the "
            "recording of that name (its instrument's zero and gain relative to the model's): " + ", ".join(refs)
        )
    for r in rows:
        for w in r["warnings"]:
            click.echo(f"warning: {r['source']}: {w}", err=True)
    if not passed:
        worst = max(rows, key=_judged)
        click.echo(
            f"error: {worst['source']}: NRMSE {_judged(worst):.4g} over {worst['judged_on']} "
            f"exceeds the threshold {threshold:g}",
            err=True,
        )
        sys.exit(EXIT_VALIDATION_FAILED)
