"""Several runs of one device: their initial states and output references, judged on the raw recordings.

`fitter.identification.fit` fits several recordings each from its own initial state (x0 "fit") and then asks
three questions of its best candidate, all answered here on the raw samples (what the saved model is scored on,
`fitter.identification.exported.score`):

* which initial-state mode fits single cycles that do not close better (`raw_bic`: BIC on every raw sample, each
  recording from its own fitted start);
* whether the one x0 stored for runs that start alike suits them (`alike`, `apart`, `start_rss`: its RSS over
  them against that of each one from its own start, `SHARED_START_RSS`);
* whether the recordings' outputs have different zeros (`zeros_apart`: separate runs, an instrument zeroed anew
  for each), which the fit then carries as an output reference per recording (`referenced`).

`base_model` is a candidate in physical units as saved; `stored_with` the same with its stored x0 and references.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fitter.core.effects import Effect
from fitter.core.errors import KernelError
from fitter.identification.exported import (
    SHARED_START_RSS,
    described,
    file_references,
    initial_state,
    same_start,
    score,
)
from fitter.identification.fit_data import FitData
from fitter.identification.output_error import Recordings
from fitter.identification.parametrisation import Physical
from fitter.identification.search import Candidate

__all__ = ["alike", "apart", "base_model", "raw_bic", "referenced", "start_rss", "stored_with", "zeros_apart"]


def base_model(cand: Candidate, data: FitData, recordings):
    """The candidate in physical units with the preparation's dead band, signals, experiment and input range."""
    bare = Physical(cand.param, data.scaling).build(cand.res.theta)
    if data.deadband > 0:
        bare = bare.replace(effects=[Effect("backlash", {"b": data.deadband})])
    return described(bare, recordings)


def raw_bic(cand: Candidate, data: FitData, recordings) -> float:
    """N ln(RSS / N) + p ln N of the candidate's physical model on every raw sample, each recording from its own
    fitted initial state (`exported.score`'s ``nrmse_x0_fitted``): the score on which fits of the two initial-state
    modes are compared; inf when one diverges."""
    rss = _rss(score(base_model(cand, data, recordings), recordings), recordings, "nrmse_x0_fitted")
    n = sum(len(r.y) for r in recordings)
    return float(n * np.log(max(rss, 1e-300) / n) + cand.param.size * np.log(n))


def _rss(rows: Sequence[dict], recordings, key: str) -> float:
    """Sum of squared residuals over the recordings' samples from `exported.score`'s rows' NRMSE `key` (RMS over
    output range); inf when a row has none (a simulation diverged)."""
    if any(m.get(key) is None for m in rows):
        return float("inf")
    return float(sum((m[key] * np.ptp(r.y)) ** 2 * len(r.y) for m, r in zip(rows, recordings)))


def start_rss(cand: Candidate, data: FitData, recordings) -> tuple[float, float]:
    """(RSS from the stored x0, RSS from each recording's own start) of the candidate's physical model over the
    raw samples of the recordings that start where the first starts (`exported.same_start`: those the stored x0
    is for); (inf, inf) when one diverges."""
    alike = same_start(recordings)
    rows = score(_stored(cand, data, recordings), alike)
    stored, own = _rss(rows, alike, "nrmse"), _rss(rows, alike, "nrmse_x0_fitted")
    return (stored, own) if np.isfinite(stored) and np.isfinite(own) else (float("inf"), float("inf"))


def zeros_apart(cand: Candidate, data: FitData, recordings, groups: Sequence[int] | None = None) -> bool:
    """Whether recordings fitted from fitted initial states (x0 "fit"; several, of distinct names) have outputs of
    different zeros: an output reference fitted for each recording but the first (`Recordings`' ``references``)
    lowers the candidate's RSS on the N prepared samples, each recording from its own initial state, below
    1 / `SHARED_START_RSS` of it; with `groups`, one initial state per start group (`start_groups`), by more than
    BIC allows for R - 1 parameters: N ln(RSS / RSS_ref) > (R - 1) ln N (each RSS at least N (1e-9)^2, rounding in
    normalised units).  From their own starts a misfit of the model between files is also lowered by a constant
    per file (an order-4 fit of three runs of one zero passed BIC's test there and kept references of 1 % of the
    range); under one start the offsets a slowly forgetting state hid are plain.  Separate
    runs, each written by an instrument zeroed anew: `fit_recordings` then searches with the references and keeps
    them by its own test.  The groups matter for a model whose state forgets slowly: from its own start each
    recording carries its offset in its initial state, which one state stored for runs that start alike cannot
    (a random order-1 device of two noise-free runs: the order-4 fit from own starts left 1.4 times the RSS
    without references as with them, under one start; its shared search with references fitted them to 1e-13)."""
    names = [r.name for r in recordings]
    if data.x0_mode != "fit" or data.references or len(names) < 2 or len(set(names)) < len(names):
        return False
    rss = []
    for refs in (False, True):
        problem = Recordings(data.norm, x0="fit", cycles=data.cycles, starts=groups, references=refs)
        with np.errstate(all="ignore"):
            r = problem.residuals(cand.param, cand.res.theta)[0]
        rss.append(float(r @ r))
    n = len(r)
    without, with_refs = (x + n * 1e-18 for x in rss)
    if groups is None:
        return bool(np.isfinite(with_refs) and SHARED_START_RSS * with_refs < without)
    return bool(np.isfinite(with_refs) and n * np.log(without / with_refs) > (len(names) - 1) * np.log(n))


def alike(data: FitData, recordings) -> bool:
    """Whether the recordings were fitted each from its own initial state and several start where the first starts
    (the case `apart` judges)."""
    return data.x0_mode == "fit" and data.starts is None and len(same_start(recordings)) >= 2


def apart(cand: Candidate, data: FitData, recordings) -> bool:
    """Whether recordings fitted each from its own initial state, several of which start where the first starts
    (`alike`), are missed from the one x0 stored for them: its RSS over them above `SHARED_START_RSS` times that
    from each one's own start (`start_rss`)."""
    if not alike(data, recordings):
        return False
    stored, own = start_rss(cand, data, recordings)
    return np.isfinite(stored) and stored > SHARED_START_RSS * own


def _stored(cand: Candidate, data: FitData, recordings):
    """The candidate's physical model with its stored x0 (`exported.initial_state`, "fitted") and, with
    references, the recordings' (`exported.file_references`)."""
    model = base_model(cand, data, recordings)
    return stored_with(model, data, recordings, "fitted")


def stored_with(model, data: FitData, recordings, policy: str):
    """`model` with its stored x0 under `policy` (`exported.initial_state`) and the recordings' references
    (`referenced`)."""
    return referenced(model.replace(x0=initial_state(model, recordings, policy, data.references)), data, recordings)


def referenced(model, data: FitData, recordings):
    """`model` (its stored x0 set) with, where the fit has references, the recordings' in its ``fit_info``
    (`exported.file_references`; an overflow leaves them out)."""
    if not data.references:
        return model
    try:
        refs = file_references(model, recordings)
    except KernelError:
        return model
    return model.replace(fit_info=dict(model.fit_info, references=refs))
