"""The JSON summary of `fitter.identification.fit.fit_recordings`: the saved model's score per recording,
its convergence (condition (5) / A Hurwitz, on every raw input), the effects fitted with it, its minor loops
off the recorded ones, and why this candidate was chosen.

Each part reads the candidate a fit chose (``param``, ``res``, ``bic``, ``start_info``) and the saved model in
physical units; none fits anything.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import numpy as np

from fitter.data.cycles import closed_loop
from fitter.data.metrics import compare
from fitter.identification.effects_fit import effects_bic
from fitter.identification.exported import MINOR_LOOP_WARNING, minor_loop_excursion, raw_input_rho, score
from fitter.identification.fit_data import FitData
from fitter.identification.refine import RefineResult

if TYPE_CHECKING:  # the fit's own classes, for the hints only (fit imports this module)
    from fitter.identification.fit import _Extended
    from fitter.identification.search import Candidate

__all__ = [
    "raw_range",
    "per_recording",
    "misfit",
    "misfit_text",
    "convergence",
    "optimiser",
    "effects_summary",
    "minor_loops",
    "why",
]


def raw_range(recordings) -> tuple[float, float]:
    """The recordings' input range in physical units."""
    return min(float(np.min(r.u)) for r in recordings), max(float(np.max(r.u)) for r in recordings)


def per_recording(model, res: RefineResult | None, data: FitData, recordings) -> list[dict]:
    """The saved model's score on each raw recording (`exported.score`), with the optimiser's own
    NRMSE on the prepared samples beside it (``nrmse_prepared``; None when effects were fitted after it on the
    raw recordings, `res` None)."""
    out = []
    for k, (m, rec, prep) in enumerate(zip(score(model, recordings), data.recs, data.preps)):
        prepared = None
        if res is not None:
            s, r = res.starts[k], res.residuals[k]
            prepared = compare(rec.slice(slice(s, None)), rec.y[s:] - r * data.scaling.y_s)["nrmse"]
        m.update(nrmse_prepared=prepared, transient_end=prep.transient_end)
        out.append(m)
    return out


def references(model, recordings) -> dict | None:
    """The summary's ``references``: the output reference the fit found for each recording but the first
    (``fit_info["references"]``, `fitter.identification.exported.file_references`), in the output's unit and in
    output ranges; None when the fit has none."""
    refs = model.fit_info.get("references") or {}
    if not refs:
        return None
    span = max(float(np.ptp(np.concatenate([r.y for r in recordings]))), 1e-300)
    return {
        "relative_to": recordings[0].name,
        "values": refs,
        "in_output_ranges": {k: v / span for k, v in refs.items()},
        "unit": recordings[0].output.unit,
        "why": "the recordings' outputs have different zeros (separate runs, each written by an instrument zeroed "
        "anew): each recording's output is compared with the model's plus its reference; the model is the first "
        "recording's, and an FMU runs it so (duhem validate adds the reference of a recording of the same name)",
    }


def gains(model, recordings) -> dict | None:
    """The summary's ``gains``: the output gain the fit found for each recording but the first
    (``fit_info["gains"]``, `fitter.identification.file_gains`); None when the fit has none."""
    found = model.fit_info.get("gains") or {}
    if not found:
        return None
    return {
        "relative_to": recordings[0].name,
        "values": found,
        "why": "the recordings' outputs have different gains (separate runs, each written by an instrument "
        "calibrated anew, or made under an operating condition that scales the output): each recording's output is "
        "compared with the model's times its gain plus its reference; the model is the first recording's, and an "
        "FMU runs it so (duhem validate applies the gain of a recording of the same name)",
    }


def misfit(scores: list[dict], limit: float, refined_further: bool, budget_hit: bool) -> dict:
    """The summary's ``misfit``: per recording, the saved model's residual RMS from the recording's own fitted start
    in times the output's white noise (`_own_start_ratio` of `per_recording`'s rows), the worst, and whether it is
    within `limit` (``followed``); when it is not, the likely causes, most likely first."""
    ratios = {m["recording"]: _own_start_ratio(m) for m in scores if m.get("residual_rms") is not None}
    known = [r for r in ratios.values() if r is not None]
    worst = max(known) if known else None
    out = {
        "ratio": worst,
        "per_recording": ratios,
        "limit": limit,
        "followed": worst is None or worst <= limit,
        "refined_further": refined_further,
    }
    if not out["followed"]:
        causes = ["the refinement stopped at its evaluation budget"] if budget_hit else []
        out["likely_causes"] = causes + [
            "physics the model class does not carry (a rate or time effect, a dead zone, a saturation, a drift, "
            "a gain or offset that differs between files): duhem diagnose names it",
            "a loop of another shape than a semilinear Duhem model draws: compare the classical models "
            "(duhem fit --compare)",
            "a start-up transient or a first sample far from the model's settled loop",
        ]
    return out


def _own_start_ratio(m: dict) -> float | None:
    """A recording's residual RMS from its own fitted start (``nrmse_x0_fitted`` times its output range: a model
    stores one start, and another recording's history or instrument zero is not a misfit) over its noise RMS."""
    if not m.get("noise_rms") or not m.get("nrmse"):
        return None
    own = m.get("nrmse_x0_fitted")
    residual = m["residual_rms"] * (min(own, m["nrmse"]) / m["nrmse"] if own is not None else 1.0)
    return residual / m["noise_rms"]


def misfit_text(m: dict) -> str:
    """One sentence for a ``misfit`` that was not followed."""
    return (
        f"the saved model leaves a residual {m['ratio']:.3g} times the output's noise (the limit is "
        f"{m['limit']:g}{', after refining it further' if m['refined_further'] else ''}): it does not follow the "
        "recordings; likely causes: " + "; ".join(m["likely_causes"])
    )


def convergence(best: Candidate, data: FitData, model, recordings, scores: list[dict], extended: bool = False) -> dict:
    """The condition with its fitting margin and on each raw input (physical model).  The structural quantities
    are the candidate's (normalised units) or, with effects fitted jointly (`extended`), the saved model's over
    the raw input range (invariant under the normalisation)."""
    param = best.param
    structural, lo, hi = (model, *raw_range(recordings)) if extended else (best.res.model, *data.input_range())
    val = param.convergence(structural, lo, hi)
    raw = raw_input_rho(model, recordings)
    ok = param.converges(val) and all(r is None or r < 1 for r in raw) and not any(m.get("diverged") for m in scores)
    out = {
        "satisfied": bool(ok),
        "quantity": param.QUANTITY,
        "value": val,
        "margin": param.LIMIT,
        "rho_raw_input_per_recording": raw,
        "rule": "the structural condition holds within its fitting margin and the period map of every raw "
        "recording's last full cycle has spectral radius < 1",
    }
    if param.kind == "ri":
        out["branch_amplification"] = float(np.exp(min(param.amplification(structural, lo, hi), 700.0)))
        out["amplification_margin"] = param.AMPLIFICATION
    if param.kind == "rd":
        lam = np.linalg.eigvals(structural.A)
        out["min_damping_ratio"] = float(np.min(-lam.real / np.abs(lam)))
        out["damping_margin"] = param.DAMPING
    return out


def optimiser(res) -> dict:
    """The summary's ``optimiser`` of a refinement (`RefineResult`): scipy's success, evaluations and message,
    and whether it stopped at its evaluation budget (``budget_hit``, `duhem fit` prints a note then)."""
    return {"success": res.success, "nfev": res.nfev, "message": res.message, "budget_hit": res.budget_hit}


def tried_entry(cand, res: RefineResult, fam, raced: bool, finished: bool) -> dict:
    """One entry of the summary's ``effects.tried``: a base candidate `cand` extended by the effects (`fam`) at
    the refinement `res` (the end of its screening, of its race, or finished)."""
    return {
        "base": f"{cand.param.kind}{cand.param.n}",
        "bic": effects_bic(cand.param.size, res, fam),
        "rss": res.rss,
        "samples": int(sum(len(r) for r in res.residuals)),
        "raced": raced,
        "finished": finished,
    }


def effects_summary(extended: _Extended, recordings) -> dict:
    """The summary's ``effects``: what was fitted with the base, on which base, every base tried, and the
    recordings whose effects started settled (closed loops)."""
    base = f"{extended.candidate.param.kind}{extended.candidate.param.n}"
    chosen = next(t for t in extended.tried if t["base"] == base)
    res, fam = extended.res, extended.param
    return {
        "fitted": [e.to_dict() for e in fam.effect_list(res.theta)],
        "base": base,
        "bic": chosen["bic"],
        "tried": extended.tried,
        "settled": [r.name for r in recordings if closed_loop(r)],
        "held": dict(fam.held),
        "parameters": {
            k: {"value": v, "stderr": e} for k, v, e in zip(fam.names(), res.theta.tolist(), res.stderr().tolist())
        },
        "optimiser": optimiser(res),
        "method": "the best rate-independent and rate-dependent candidates each screened with the effects, "
        "the screened starts of lowest BIC among both refined jointly by output error up to the end of their race "
        "('tried': 'raced'), the one of lower BIC then to convergence ('finished') on every raw sample "
        "(x0 fitted per recording; the effects of a "
        "recording that is a closed loop ('settled') start settled on it, of any other afresh; each "
        "recording's residuals divided by its own output range; rss weighted so); lowest BIC kept; "
        "the model stores the first recording's effect start; 'parameters' are the saved "
        "model's (physical units; the summary's parameters_normalised and optimiser are the base's "
        "before the joint refinement)",
    }


def minor_loops(model, recordings, constrained: bool) -> dict:
    """The saved model off its recorded loops (`minor_loop_excursion`), with the verdict `duhem fit` prints;
    `constrained`: the fit had the faithful-minor-loops barrier."""
    exc = minor_loop_excursion(model, recordings)
    return {
        "excursion": exc,
        "warning_above": MINOR_LOOP_WARNING,
        "faithful": bool(exc <= MINOR_LOOP_WARNING),
        "constrained": bool(constrained),
        "input": "40 triangle cycles of each of 8 sub-spans (1/8 to 8/8) of the model's input range around its "
        "middle, from the stored x0 at the first input, at the recordings' median rate; for a "
        "rate-independent model also the settled loops of 64 sub-spans at 5 places each",
        "quantity": "largest distance of the output beyond the recorded output range, in output ranges",
    }


def why(best: Candidate, cands, kind: str, levels: int, outside: Sequence[Candidate] = ()) -> str:
    ranked = sorted(cands, key=lambda c: c.bic)
    text = (
        f"lowest BIC ({best.bic:.1f}) among {len(cands)} candidate(s) "
        f"({', '.join(f'{c.param.kind}{c.param.n}: {c.bic:.1f}' for c in ranked)})"
    )
    if outside and best not in outside:
        text += (
            f" that end inside the fit's barrier (condition (5) margin, branch amplification / damping) "
            f"and converge on every raw input; "
            f"not eligible: {', '.join(f'{c.param.kind}{c.param.n}' for c in outside)}"
        )
    if kind != "auto":
        text = f"kind {kind!r} requested; order by " + text
    if levels < 2 and best.param.kind == "rd":
        text += "; note: a single input rate, so g is barely identifiable"
    if levels < 2 and kind == "auto":
        text += (
            "; rate-dependent candidates not tried: the recordings have a single input rate, "
            "from which rate dependence cannot be established (use --kind rd to force it)"
        )
    return text
