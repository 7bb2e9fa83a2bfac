"""Separate runs written by instruments of different gains and zeros: `duhem fit` finds each file's gain
(`fitter.identification.file_gains`) and every score applies it."""

from __future__ import annotations

import numpy as np
import pytest
from samples import ri_model, sampled_input

from fitter.core import simulate
from fitter.data.recordings import Recording
from fitter.identification.exported import calibrated, levelled
from fitter.identification.fit import fit_recordings


def _runs(gains, offsets, noise: float = 0.0) -> list[Recording]:
    """Three separate runs of the suite's order-1 device, each from its x0 on its own input (seeded), written
    as gain * y + offset, plus seeded noise of `noise` output units."""
    model, rng, out = ri_model(1), np.random.default_rng(11), []
    for i, (g, c) in enumerate(zip(gains, offsets)):
        t, u = sampled_input(300, seed=20 + i)
        y = g * simulate(model, t, u).y + c + noise * rng.standard_normal(len(t))
        out.append(Recording(t, u, y, name=f"run{i + 1}", source=f"run{i + 1}.csv"))
    return out


@pytest.fixture(scope="module")
def noisy_fit():
    recs = _runs([1.0, 0.6, 1.7], [0.0, 2.0, -1.5], noise=0.01)
    return recs, fit_recordings(recs, kind="ri")


def test_each_files_gain_is_found_and_every_score_applies_it(noisy_fit):
    """Noise 0.01 (about 0.1 % of the range): the gains within 1 % of the truth, each file's residual at the noise
    (1.2x), the summary's NRMSE that of `FitResult.simulate`; a recording in the model's frame (`levelled`) is
    the raw one less its reference, over its gain."""
    recs, res = noisy_fit
    gains = res.summary["gains"]["values"]
    assert abs(gains["run2"] / 0.6 - 1) < 0.01 and abs(gains["run3"] / 1.7 - 1) < 0.01
    for rec, row in zip(recs, res.summary["recordings"]):
        e = rec.y - res.simulate(rec)
        assert np.sqrt(np.mean(e**2)) < 1.2 * 0.01
        assert row["nrmse"] == pytest.approx(np.sqrt(np.mean(e**2)) / np.ptp(rec.y), rel=1e-6)
    model, rec = res.model, recs[2]
    y = simulate(model, rec.t, rec.u).y
    np.testing.assert_allclose(levelled(model, rec).y * gains["run3"] + model.fit_info["references"]["run3"], rec.y)
    np.testing.assert_allclose(calibrated(model, rec, y), res.simulate(rec))


def test_without_the_gains_the_same_files_are_missed(noisy_fit):
    """The control: the model of the gained fit with each file's reference alone (gains dropped) leaves more
    than 10x the noise on the files scaled by 0.6 and 1.7."""
    recs, res = noisy_fit
    info = {k: v for k, v in res.model.fit_info.items() if k != "gains"}
    model = res.model.replace(fit_info=info)
    for rec in recs[1:]:
        e = rec.y - simulate(model, rec.t, rec.u).y
        assert np.sqrt(np.mean((e - e.mean()) ** 2)) > 10 * 0.01


def test_the_diagnosis_takes_the_gains_off_and_finds_nothing_missing(noisy_fit):
    """Files that differ only by an instrument's gain and zero are a clean experiment: the diagnosis reports the
    gains as the files' (within 1 %) and finds nothing missing (it had refused them: 'the base model explains 0.415
    of the output's variance')."""
    from fitter.diagnosis import diagnose

    recs, _ = noisy_fit
    d = diagnose(recs)
    assert abs(d.file_gains["run2"] / 0.6 - 1) < 0.01 and abs(d.file_gains["run3"] / 1.7 - 1) < 0.01
    assert d.verdict == "nothing_missing" and d.findings == []
    assert "gain per file" in d.paragraph


def test_a_gain_that_a_flexible_model_mimics_is_found_by_the_lowest_order():
    """Two noise-free runs of a random first-order device from one start (the property draw of seed 12, 300
    samples), the second written at gain 0.904: a higher order fitted from each run's own start fits each run
    without a gain, and the regression on it shows none; the first-order candidate refined with and without the
    gain does, and the fit carries it to 1e-6."""
    from generality_draws import DrawSpec, build_draw

    draw = build_draw(DrawSpec(12, "ri", 1, "turning_points", 2, 300, 0.0, "calibrated"))
    assert abs(draw.gains[1] - 0.904) < 1e-3
    res = fit_recordings(draw.recordings)
    assert abs(res.summary["gains"]["values"]["file2"] / draw.gains[1] - 1) < 1e-6
