"""Generality properties of `duhem fit` and `duhem diagnose` on a fixed set of random stable devices.

The draws and the properties are `generality_draws`' (its docstring): a random stable semilinear Duhem device
(rate-independent or rate-dependent, order 1-4), a random input, one or several files, noise 0 or 0.1-1 % of
the output range, an output offset for all files or one per file.  Here a fixed set, small enough for the suite
(at most 5e3 samples in all per draw; the whole file about 60 s on two cores); `bench/generality_property.py`
runs a larger one (1e2-1e6 samples per file) and prints the pass rates.

* `test_generated_devices_are_stable_and_deterministic` (hypothesis, derandomized): the generator's own
  promises, on 40 specs: the truth meets the convergence condition the fit enforces (condition (5) on every
  minor loop of the stored input range below 0.9, or A Hurwitz with damping >= 0.3 and g >= 0), each file
  reverses and starts at the draw's start level, the draw is the same when built twice, the noise has the drawn level.
* `test_fit_on_a_fixed_draw` (one per draw of `FIT_DRAWS`): `fit_recordings` returns; the saved model's
  residual RMS over every sample (its own simulation from the stored x0) is within 1.2 x the true noise
  sigma (noise-free: 1e-3 of the output range); the summary's per-recording NRMSE is that simulation's.
* `test_diagnosis_on_a_clean_draw` (one per draw of `DIAGNOSIS_DRAWS`): a clean rate-independent device
  (no effect) is diagnosed "nothing_missing" with no finding.

Each draw here failed once (a local minimum of the generic starts, one stored x0 for runs that start alike, legs
at two speeds, a general input judged unsettled, a small second reversal, per-file offsets) and passes now; a draw that
fails is marked ``xfail(strict=True)`` with what it shows, so that the property is not weakened and the mark goes
when the code is fixed.  `bench/generality_property.py` prints the pass rates over many more draws.
"""

from __future__ import annotations

import numpy as np
import pytest
from generality_draws import (
    NOISE_RANGE,
    DrawSpec,
    build_draw,
    check_diagnosis,
    check_fit,
    draw_specs,
)
from hypothesis import HealthCheck, Phase, given, settings

from fitter.core.checks import convergence
from fitter.core.periodic import minor_loop_rho

CI_MAX_SAMPLES = 5000


FIT_DRAWS = [
    pytest.param(DrawSpec(301, "ri", 2, "sine", 2, 300, 0.002), id="ri2-sine-2files"),
    pytest.param(DrawSpec(302, "ri", 2, "turning_points", 1, 400, 0.003), id="ri2-turning-points-b"),
    pytest.param(DrawSpec(300, "ri", 2, "sine", 2, 300, 0.002), id="ri2-sine-2files-b"),
    pytest.param(DrawSpec(300, "rd", 1, "sine", 2, 300, 0.002), id="rd1-sine-2files-b"),
    pytest.param(DrawSpec(3, "ri", 1, "turning_points", 3, 250, 0.004, "per_file"), id="ri1-per-file-offsets"),
]
"""The fit's fixed draws, one per failure mode once seen (at most 800 samples in all per draw; the rest of the space,
the slower orders among it, is `bench/generality_property.py`'s): one stored x0 for two runs from one start, a
generic start's local minimum, a shared-start search, legs at two speeds (rate-dependent), files whose outputs have
different zeros (three runs from one start: 42x the bound without output references)."""

DIAGNOSIS_DRAWS = [
    pytest.param(DrawSpec(400, "ri", 1, "triangles", 2, 300, 0.005, "per_file"), id="ri1-triangles-per-file-offsets"),
    pytest.param(DrawSpec(400, "ri", 4, "multisine", 1, 400, 0.004), id="ri4-multisine"),
    pytest.param(DrawSpec(401, "ri", 2, "turning_points", 1, 400, 0.0), id="ri2-turning-points-small-second-reversal"),
]
"""The diagnosis' fixed clean draws (rate-independent: the diagnosis' base class)."""


@settings(
    max_examples=40,
    derandomize=True,
    deadline=None,
    database=None,
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=[HealthCheck.too_slow],
)
@given(draw_specs(max_samples=800))
def test_generated_devices_are_stable_and_deterministic(spec):
    draw = build_draw(spec)
    truth = draw.truth
    if spec.kind == "ri":
        assert minor_loop_rho(truth, -1.1, 1.1) <= 0.9
    else:
        lam = np.linalg.eigvals(truth.A)
        assert np.max(lam.real) < 0 and np.min(-lam.real / np.abs(lam)) >= 0.3
        assert np.min(truth.g.g) >= 0
    assert convergence(truth, (-1.1, 1.1)).satisfied
    assert len(draw.recordings) == spec.files and len(draw.recordings[0].t) == spec.samples
    assert len({float(rec.u[0]) for rec in draw.recordings}) == 1, "every file starts at one input level"
    for rec in draw.recordings:
        d = np.sign(np.diff(rec.u))
        d = d[d != 0]
        assert np.count_nonzero(d[1:] != d[:-1]) >= 2, "every file reverses at least twice"
        assert rec.t[0] == 0.0 and np.all(np.diff(rec.t) > 0)
    again = build_draw(spec)
    for a, b in zip(draw.recordings, again.recordings):
        assert np.array_equal(a.u, b.u) and np.array_equal(a.y, b.y)
    noise = np.concatenate([r.y - c for r, c in zip(draw.recordings, draw.clean)])
    if spec.noise == 0:
        assert np.all(noise == 0)
    else:
        assert NOISE_RANGE[0] <= spec.noise <= NOISE_RANGE[1]
        # the sample standard deviation of >= 100 normal draws is within 35 % of sigma (4.9 of its errors)
        assert abs(np.std(noise) / draw.sigma - 1) < 0.35
    offsets = {round(o / draw.output_range, 12) for o in draw.offsets}
    assert len(offsets) == (1 if spec.offsets == "common" else spec.files)


@pytest.mark.parametrize("spec", FIT_DRAWS)
def test_fit_on_a_fixed_draw(spec):
    assert spec.samples * spec.files <= CI_MAX_SAMPLES
    out = check_fit(build_draw(spec))
    assert not out.raised, f"{spec.label}: fit_recordings raised {out.error} at {out.where}"
    assert out.summary_agrees, f"{spec.label}: summary NRMSE and the saved model's differ by {out.nrmse_mismatch}"
    assert out.within_bound, (
        f"{spec.label}: residual RMS {out.residual_rms:.4g} is {out.ratio:.3f} x the bound {out.bound:.4g} "
        f"(noise ratio {out.noise_ratio}, chosen {out.chosen}; from each file's own x0: {out.own_x0_ratio:.3f})"
    )
    if spec.offsets != "calibrated":  # files of one gain: none found (`fitter.identification.file_gains`)
        assert out.gains is None, f"{spec.label}: gains {out.gains} found where the files have one"


@pytest.mark.parametrize("spec", DIAGNOSIS_DRAWS)
def test_diagnosis_on_a_clean_draw(spec):
    out = check_diagnosis(build_draw(spec))
    assert out.error is None, f"{spec.label}: diagnose raised {out.error} at {out.where}"
    assert out.verdict == "nothing_missing" and out.findings == [], (
        f"{spec.label}: verdict {out.verdict}, findings {out.findings}, base {out.base}, "
        f"base/noise {out.base_noise_ratio:.3f}"
    )
