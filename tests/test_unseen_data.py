"""Recordings the project's own benches do not resemble: many small loops past the decimation budget, noisy
inputs, inputs of few samples per cycle, starts that cannot be put in canonical form, numerical failures, and
experiments whose files differ by a gain."""

from __future__ import annotations

from types import SimpleNamespace

import click
import numpy as np
import pytest

from fitter.core.kernel import simulate
from fitter.core.models import RateIndependentModel
from fitter.data.noise import local_noise_rms, noise_rms
from fitter.data.recordings import Recording
from fitter.diagnosis.synthetic import cell_base


def _random_turns(n: int, runs: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(t, u): straight runs of random lengths between uniformly random turning points in [-1, 1]."""
    rng = np.random.default_rng(seed)
    lengths = rng.integers(3, 2 * n // runs, runs)
    knots = np.r_[0, np.cumsum(lengths)]
    knots = knots[knots < n]
    u = np.interp(np.arange(n), knots, rng.uniform(-1.0, 1.0, len(knots)))
    return np.arange(n) / 50.0, u


def test_decimation_keeps_every_turning_point_beyond_the_budget():
    """More turning points than scored samples (4000 against 1000): every one is kept, so the true model on the
    kept samples alone gives its output there exactly (Proposition 1); only the every-j-th samples are scored.
    Keeping each block's extremes instead dropped the reversals inside a block."""
    from fitter.identification.decimation import keep_indices, turning_points

    t, u = _random_turns(40_000, 6000, seed=1)
    turns = turning_points(u)
    keep, scored = keep_indices(u, 1000, None)
    assert len(turns) > 3000 and np.isin(turns, keep).all()
    assert np.array_equal(keep[scored][:-1], np.arange(0, 40_000, 40))
    truth = cell_base(2)
    full = simulate(truth, t, u).y[keep]
    np.testing.assert_allclose(simulate(truth, t[keep], u[keep]).y, full, rtol=0, atol=1e-12)


def test_noise_reversals_are_not_kept_but_the_drives_are():
    """Input noise of RMS 0.004 on a drive of 200 reversals: the threshold at `REVERSAL_NOISE` times the noise
    keeps about one point per turning point of the drive, near it, and drops the thousands of noise reversals."""
    from fitter.identification.decimation import REVERSAL_NOISE, significant_turns, turning_points

    t, u0 = _random_turns(20_000, 200, seed=2)
    u = u0 + 0.004 * np.random.default_rng(3).standard_normal(len(u0))
    drive = turning_points(u0)
    kept = significant_turns(u, REVERSAL_NOISE * noise_rms(u))
    assert len(turning_points(u)) > 20 * len(drive)
    assert 0.8 * len(drive) <= len(kept) <= 1.2 * len(drive)
    nearest = np.min(np.abs(kept[:, None] - drive[None, :]), axis=0)
    assert np.median(nearest) <= 20
    assert np.array_equal(significant_turns(u0, 0.0), drive)


def test_noise_of_an_input_with_few_samples_per_cycle():
    """A sine of 10 samples per period with white noise 1e-3: the local quadratic fit reads its curvature as
    noise (about 0.1), the spectral floor gives the noise; on a smooth ramp with noise both agree and the local
    one is kept."""
    rng = np.random.default_rng(4)
    k = np.arange(1200)
    e = 1e-3 * rng.standard_normal(1200)
    fast = np.sin(2 * np.pi * k / 10) + e
    assert local_noise_rms(fast) > 0.02
    assert noise_rms(fast) == pytest.approx(1e-3, rel=0.15)
    slow = np.sin(2 * np.pi * k / 400) + e
    assert noise_rms(slow) == local_noise_rms(slow)


def test_an_unobservable_embedding_is_skipped_not_raised():
    """An order-1 fit with its mode at -10 embedded into order 2 adds a second mode at -10: (A+, C) is not
    observable and has no canonical form; the generic starts go on without it and say why."""
    from fitter.identification.starts import GENERIC_RATES, generic_ri_starts

    lower = RateIndependentModel(A_plus=[[-10.0]], A_minus=[[10.0]], B_plus=[1.0], B_minus=[1.0], C=[1.0])
    starts, info = generic_ri_starts(2, lower)
    assert len(starts) == len(GENERIC_RATES)
    assert "order 1 fit, embedded" in info["ri_identification_errors"][0]
    assert info["start"].startswith("generic relaxations")


def test_settled_effect_chains_keep_their_recordings_whole():
    """A recording whose effect chain starts settled on it keeps every sample when the others are decimated."""
    from fitter.identification.output_error import Recordings

    recs = []
    for seed in (5, 6):
        t, u = _random_turns(5000, 50, seed)
        recs.append(Recording(t, u, simulate(cell_base(1), t, u).y))
    problem = Recordings(recs, x0="fit", settle=[True, False])
    coarse = problem.decimated(1000)
    assert len(coarse.recordings[0].u) == 5000 and len(coarse.recordings[1].u) < 2000
    assert [len(r) for r in problem.rows(1000)] == [5000, 1001]


def _line(func) -> str:
    from fitter.cli_support import CliError, one_line_errors

    with pytest.raises(CliError) as caught, one_line_errors():
        func()
    assert isinstance(caught.value, click.ClickException)
    return caught.value.message


def test_a_numerical_library_failure_is_labelled_internal():
    """A singular matrix inside numpy is the tool's failure: "internal error", the project function it
    happened in, never the bare "Singular matrix" as if it were about the data; a ValueError the project
    raises about the input keeps its message."""
    from fitter.identification.parametrisation import RICanonical

    def unobservable():
        model = RateIndependentModel(
            A_plus=np.diag([-1.0, -1.0]), A_minus=np.eye(2), B_plus=[1, 1], B_minus=[1, 1], C=[1.0, 1.0]
        )
        return RICanonical(2).theta(model)

    text = _line(unobservable)
    assert text.startswith("internal error in fitter.identification.parametrisation.")
    assert "LinAlgError" in text and "Singular matrix" in text and "not a finding about your data" in text
    from fitter.identification.fit import fit_recordings

    assert _line(lambda: fit_recordings([], kind="xx")) == "kind must be 'auto', 'ri' or 'rd', not 'xx'"


def test_a_gain_per_file_is_found_and_named():
    """Three files of one device, the second scaled by 1.3 and offset: regressing each file's output on the joint
    model's gives the gains back (the first and third 1) and leaves the noise."""
    from fitter.diagnosis.experiment import join_recordings
    from fitter.diagnosis.file_gap import gain_per_file

    rng = np.random.default_rng(7)
    recs, clean = [], []
    for i, gain in enumerate((1.0, 1.3, 1.0)):
        t, u = _random_turns(800, 20, seed=10 + i)
        y = simulate(cell_base(1), t, u).y
        clean.append(y)
        recs.append(Recording(t, u, gain * y + 0.5 * i + 1e-3 * rng.standard_normal(800), f"file{i}"))
    ex = join_recordings(recs, separate=True)
    fit = SimpleNamespace(residual=ex.y - np.concatenate(clean))
    gains, residual = gain_per_file(ex, fit, np.ones(len(ex.y), bool))
    assert gains == pytest.approx({"file0": 1.0, "file1": 1.3, "file2": 1.0}, abs=2e-3)
    assert np.sqrt(np.mean(residual**2)) == pytest.approx(1e-3, rel=0.1)


@pytest.mark.parametrize(
    ("gap", "verdict"),
    [
        (None, "nothing_missing"),
        ({"gap": False, "gain_explains": False}, "nothing_missing"),
        ({"gap": True, "gain_explains": False}, "unexplained"),
        ({"gap": True, "gain_explains": True}, "nothing_missing"),
    ],
)
def test_a_gap_between_joint_and_per_file_fits_is_never_noise(gap, verdict):
    """A base at the noise with no finding is "nothing_missing" only when one model holds across the files (or
    a gain per file is all that differs)."""
    from fitter.diagnosis.procedure import _verdict

    assert _verdict([], {"residual_rms": 1.0}, {"explained": True}, 1.0, gap) == verdict


def test_holds_joined_by_steps_of_one_sample_are_separate():
    """A staircase whose steps each take one sample: 13 holds of 21 samples, not one hold over the whole file
    (the widened windows of neighbouring holds used to touch across the step)."""
    from fitter.data.preparation import find_holds

    levels = np.array([0, 1, 2, 1, 0, -1, -2, -1, 0, 1, 2, 1, 0], dtype=float)
    u = np.repeat(levels, 21) + 1e-4 * np.random.default_rng(8).standard_normal(13 * 21)
    holds = find_holds(np.arange(u.size) * 0.1, u)
    assert holds == [(21 * k, 21 * (k + 1)) for k in range(13)]


def test_a_single_cycle_that_does_not_close_has_its_start_fitted():
    """One staircase cycle (steps with holds, 0 -> 1 -> -1 -> 0) of a device that starts far from its settled
    loop: the recording does not close, so taking it as a settled cycle leaves many times the noise; the fit
    then fits its initial state too and reaches the noise."""
    from fitter.data.cycles import closed_loop
    from fitter.identification.fit import fit_recordings

    levels = np.r_[np.linspace(0, 1, 6), np.linspace(1, -1, 11)[1:], np.linspace(-1, 0, 6)[1:]]
    u = np.repeat(levels, 25)
    t = np.arange(u.size) * 0.1
    truth = cell_base(1)
    y = simulate(truth.replace(x0=truth.x0 + 1.5), t, u).y
    rec = Recording(t, u, y + 0.002 * np.ptp(y) * np.random.default_rng(9).standard_normal(u.size))
    assert not closed_loop(rec)
    fit = fit_recordings([rec], kind="ri", order=1)
    row = fit.summary["recordings"][0]
    assert fit.summary["x0"]["fit"].startswith("during the fit, every sample is fitted")
    assert row["residual_rms"] < 1.2 * 0.002 * np.ptp(y) and fit.summary["misfit"]["followed"]


def test_the_noise_is_capped_at_what_a_model_per_recording_leaves():
    """A noise floor inflated by a quantised input carried through a steep model (5e-8, where each file's own
    model leaves 0.8e-8) is capped there, so a joint base at 2.8e-8 is 3.5 times the noise, not under it; a gap
    that gains per file close to the capped noise is explained by them."""
    from fitter.diagnosis.file_gap import capped_noise

    floor = {"rms": 5e-8, "output": 2.6e-11, "input": 0.14, "through_input": 5e-8, "method": "m"}
    gap = {"per_file_rms": 0.8e-8, "gap": True, "gain_rms": 0.9e-8}
    capped = capped_noise(floor, gap)
    assert capped["rms"] == 0.8e-8 and capped["capped_from"] == 5e-8 and "capped at the residual" in capped["method"]
    assert gap["gain_explains"] and floor["rms"] == 5e-8
    gap = {"per_file_rms": 9e-8, "gap": True, "gain_rms": 9e-8}
    assert capped_noise(floor, gap) == floor and not gap["gain_explains"]


def test_the_diagnosis_of_an_output_that_is_noise_refuses_to_call_it_complete():
    """An output of seeded white noise beside a sine input: the base explains none of it, and the diagnosis says
    so (one line naming the recording and R^2) instead of "nothing missing: the residual is consistent with the
    noise level"."""
    from fitter.diagnosis import diagnose
    from fitter.diagnosis.experiment import DiagnoseError

    t = np.linspace(0.0, 40.0, 2000)
    rec = Recording(t, np.sin(t), np.random.default_rng(5).standard_normal(2000), "noise", source="noise.csv")
    with pytest.raises(DiagnoseError, match=r"noise.csv: the base model explains 0\.0\d* of the output's variance"):
        diagnose([rec])
