"""The verdict in prose: the paragraph of a `Diagnosis` and the winner-versus-runner-up comparison."""

from __future__ import annotations

from fitter.core.effects import REGISTRY
from fitter.diagnosis.result import Diagnosis
from fitter.diagnosis.statistics import NOISE_MARGIN

__all__ = ["comparison_text", "summary_paragraph"]


def _noise_parts(noise: dict | None) -> str:
    """ ", the output's x and the input's noise carried through the model y" when the input's part counts
    (over 10 % of the output's), else ""."""
    if noise and noise.get("capped_from") is not None:
        return (
            f" (the residual of a model fitted to each recording alone: the estimate from the output's and the "
            f"input's noise, {noise['capped_from']:.3g}, exceeds what such a model leaves)"
        )
    if not noise or noise["through_input"] <= 0.1 * noise["output"]:
        return ""
    return (
        f" (the output's noise {noise['output']:.3g} and the input's noise carried through the model "
        f"{noise['through_input']:.3g})"
    )


def summary_paragraph(d: Diagnosis) -> str:
    """The diagnosis in one paragraph: the base residual against the noise, where it lies, what was found."""
    b, e = d.baseline, d.extended
    m = d.mismatch
    text = (
        "The files are read as separate runs, each on its own clock and each simulated from its own initial state. "
        if d.separate and len(d.mismatch.get("per_recording", [])) > 1
        else ""
    )
    text += (
        f"The base model leaves a residual of {b['residual_rms']:.3g} RMS against a noise level of "
        f"{d.noise_rms:.3g} estimated from the data{_noise_parts(d.noise)} "
        f"({_times(b['residual_rms'], d.noise_rms)}); "
        f"the largest mismatch is in {m['worst_recording']}."
    )
    g = m["growth"]
    trends = [
        f"{'increases' if v > 0 else 'decreases'} with {k.split('_')[1]} (r = {v:.2f})"
        for k, v in g.items()
        if v is not None and abs(v) >= 0.7
    ]
    if trends and b["residual_rms"] > NOISE_MARGIN * d.noise_rms:
        text += " Across recordings it " + ", ".join(trends) + "."
    rep = m.get("repeat")
    if rep:
        text += (
            f" The repeated run {rep['repeat']} differs from {rep['original']} by {rep['data_difference_rms']:.3g}"
            f" RMS (noise alone: {rep['expected_from_noise']:.3g})."
        )
    text += _gains_text(d.file_gains)
    text += _gap_text(d.file_gap)
    if not d.findings and d.verdict == "nothing_missing":
        return text + " No candidate effect explains a significant part of it: nothing is missing."
    if not d.findings and d.file_gap and d.file_gap["gap"]:
        return text + (
            " No candidate effect of the catalogue explains that difference: what is missing is physics that "
            "differs between the recordings (rate, amplitude or a condition of each file) outside the catalogue."
        )
    if not d.findings:
        best = d.candidates[0] if d.candidates else None
        more = (
            (
                f" (the best, {best['effect']}, explains {100 * best['explained_fraction']:.0f}%, "
                f"p = {best['p_value']:.2g} with an effective sample size of {best['n_eff']:.0f})"
            )
            if best
            else ""
        )
        return text + (
            " The residual is above the noise, but no candidate effect explains a significant part of "
            f"it{more}: what is missing is not in the catalogue (or the base model is too simple)."
        )
    for f in d.findings:
        params = ", ".join(f"{k} = {v:.3g} ± {f['stderr'][k]:.2g}" for k, v in f["parameters"].items())
        gain = f"removes {100 * f['explained_fraction']:.0f}% of the residual ({_p_text(f['p_value'])})"
        if f.get("origin") == "measurement" and f.get("partial"):
            text += (
                f" The nearest measurement effect is {REGISTRY[f['effect']].description}: modelled as "
                f"{f['effect']} ({params}) it {gain}, but the extended model does not reach the noise, so the "
                "recording need not carry it (reported apart from the material's physics)."
            )
        elif f.get("origin") == "measurement":
            text += (
                f" The recording carries {REGISTRY[f['effect']].description}; modelled as "
                f"{f['effect']} ({params}) it {gain}. This is reported apart from the material's physics."
            )
        elif f.get("origin") == "loop_shape":
            text += (
                f" The loop's shape differs from the base model's: {f['effect'].replace('_', ' ')} ({params}) "
                f"{gain}, but the extended model does not reach the noise, and a hysteresis of another class "
                "than the base's (a Bouc-Wen or a Preisach loop) draws such shapes too: this is the loop's "
                f"shape, not claimed as the material's {f['effect'].replace('_', ' ')}."
            )
        else:
            text += f" The model had no {f['effect'].replace('_', ' ')}; adding it ({params}) {gain}."
        text += _consistency_text(f)
    if d.comparison:
        text += " " + d.comparison + "."
    text += (
        f" The extended model leaves {e['residual_rms']:.3g} RMS ({_times(e['residual_rms'], d.noise_rms)}); "
        f"NRMSE {100 * b['nrmse']:.2f}% -> {100 * e['nrmse']:.2f}%."
    )
    if d.verdict == "unexplained":
        text += " " + _remainder_text(e["remainder"], len(d.findings))
    return text


def _gains_text(gains: dict | None) -> str:
    """The recordings' output gains taken off before the diagnosis (`fitter.diagnosis.calibration`): "" without."""
    if not gains:
        return ""
    values = ", ".join(f"{k} x{v:.3g}" for k, v in gains.items())
    return (
        f" The recordings' outputs differ by a gain per file ({values}, relative to the first recording): a "
        "property of each file (an instrument's calibration, or an operating condition that scales the output), "
        "not of the device; each output was divided by its gain before the diagnosis."
    )


def _gap_text(gap: dict | None) -> str:
    """What the base refitted on each recording alone says (`fitter.diagnosis.file_gap`): "" without a gap."""
    if not gap or not gap["gap"]:
        return ""
    text = (
        f" One model across the recordings leaves {gap['joint_rms']:.3g} RMS where the same model fitted to each "
        f"recording alone leaves {gap['per_file_rms']:.3g} ({gap['ratio']:.1f} times less): the recordings differ "
        "by something the model does not carry, which is a finding, not noise."
    )
    if gap["gain_explains"]:
        gains = ", ".join(f"{k} {v:.3g}" for k, v in gap["gains"].items())
        text += (
            f" A gain and an offset per file take it to {gap['gain_rms']:.3g} RMS (gains {gains}): the files differ "
            "by their instrument's calibration or an operating condition of each (a property of the file, like its "
            "reference), not by the material's physics."
        )
    return text


def _remainder_text(rem: dict, n_findings: int) -> str:
    """Why a diagnosis with findings is "unexplained": the remainder is not noise, and where it lives."""
    if rem["structured"]:
        why = (
            f"its neighbouring samples correlate (lag-1 autocorrelation {rem['lag1']:.2f}, "
            f"{_p_text(rem['p_value'])}; white noise gives 0 ± {1 / max(rem['pairs'], 1) ** 0.5:.2g}): "
            f"a structured part of about {100 * rem['lag1']:.0f}% of it"
        )
    else:
        why = f"it stays above {NOISE_MARGIN:g} times the noise"
    lo, hi = rem["worst_input_range"]
    effects = (
        "the finding is partial: the nearest effect"
        if n_findings == 1
        else "the findings are partial: the nearest effects"
    )
    return (
        f"Unexplained: the residual left is not the noise, {why} that no effect of the catalogue explains "
        f"(largest in {rem['worst_recording']}, on the {rem['worst_branch']} branch, for inputs "
        f"{lo:.3g} to {hi:.3g}). So {effects} of the catalogue, not necessarily the physics; what is "
        "missing is another functional form, an effect outside the catalogue, or a base model too simple."
    )


def comparison_text(winner: dict, runner: dict | None, hold_out: dict, noise: float, worst: str) -> str:
    """Why the winner wins: residuals, explained fractions, hold-out errors, where the runner-up errs more.

    Parameters
    ----------
    winner, runner : the first finding and the runner-up candidate (None: no runner-up).
    hold_out : `validation` of the diagnosis: "held_out" (recording name), "base", the winner's and the
        runner-up's RMS error on it, "confirmed".
    worst : where the runner-up's extra error is largest (`locate.where_differs`).
    """
    win = winner["effect"]
    text = f"{win} leaves a residual of {winner['residual_rms']:.3g} (noise {noise:.3g})"
    if runner is None:
        return text
    other, held = runner["effect"], hold_out["held_out"]
    text += (
        f"; the runner-up {other} leaves {runner['residual_rms']:.3g}"
        f" (explains {100 * runner['explained_fraction']:.0f}% against "
        f"{100 * winner['explained_fraction']:.0f}%)"
    )
    resp = runner.get("response")
    if resp and not resp["follows_input"]:
        text += (
            f"; but that {other} does not follow the input (its gain on the input's response is "
            f"{resp['gain_response']:.3g} against k = {runner['parameters']['k']:.3g} once its start "
            f"transient is free, {_p_text(resp['p_value'])}): what it fits is its start, a change in time, "
            "so it is not a finding"
        )
    text += (
        f". Refitted without {held}, {win} predicts it with a residual of {hold_out[win]:.3g}, "
        f"{other} with {hold_out[other]:.3g}, the base model with {hold_out['base']:.3g}"
    )
    text += f". The runner-up's extra error is largest {worst}"
    if not hold_out["confirmed"]:
        text += (
            f". Caution: on the held-out run {win} does not predict better than "
            f"{'the base model' if hold_out[win] >= hold_out['base'] else other}, so the hold-out "
            "check does not confirm it"
        )
    return text


def _consistency_text(f: dict) -> str:
    """A sentence when the finding's parameters differ between the recordings (`consistency`)."""
    c = f.get("consistency")
    if not c or c["consistent"]:
        return ""
    per = "; ".join(
        f"{rec}: " + ", ".join(f"{k} = {v:.3g}" for k, v in vals.items()) for rec, vals in c["per_recording"].items()
    )
    return (
        f" But one parameter set does not hold across the recordings ({per}; separate parameters would remove "
        f"a further {100 * c['gain']:.0f}% of the residual, {_p_text(c['p_value'])}): the data follow "
        f"{f['effect']} only approximately, so it is the nearest effect of the catalogue, not necessarily the "
        "physics (another functional form, or an effect outside the catalogue)."
    )


def _p_text(p: float) -> str:
    return "p < 1e-300" if p == 0 else f"p = {p:.2g}"


def _times(value: float, noise: float) -> str:
    if noise <= 0:
        return "no noise level"
    ratio = value / noise
    if ratio > 100:
        return "over 100 times the noise: a systematic misfit"
    return f"{ratio:.2f} times the noise"
