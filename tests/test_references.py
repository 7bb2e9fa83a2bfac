"""Recordings of separate runs whose outputs have different zeros (an instrument zeroed anew for each run):
the fit finds each file's output reference, scores every file with it, and `duhem validate` applies it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from samples import noisy_recording, ri_model
from fitter.core.kernel import simulate
from fitter.data.recordings import Recording
from fitter.identification.fit import fit_recordings
from fitter.identification.output_error import shared_initial_state
from fitter.identification.projection import LinearPart, solve_shared, split_solution
from test_cli import invoke, ok, write_csv

OFFSETS = (0.0, 0.7, -1.3)
"""Each run's output zero, in output ranges, relative to the first run's."""


def _runs(offsets=OFFSETS, noise: float = 2e-3) -> tuple[list[Recording], float]:
    """Three runs of the suite's order-1 device from its stored state at u = 0 (sines of three amplitudes and
    rates), each output shifted by its offset times the output range, seeded noise of `noise` of the range;
    and the noise's standard deviation."""
    model = ri_model(1)
    rng = np.random.default_rng(41)
    shapes = ((1.0, 1.0, 400), (0.6, 2.5, 300), (0.85, 0.4, 350))
    clean = [simulate(model, *_sine(a, w, n)).y for a, w, n in shapes]
    span = float(np.ptp(np.concatenate(clean)))
    recs = []
    for k, ((a, w, n), off) in enumerate(zip(shapes, offsets)):
        rec = noisy_recording(model, *_sine(a, w, n), noise=noise * span, seed=rng, relative=False, name=f"run{k}")
        recs.append(Recording(rec.t, rec.u, rec.y + off * span, rec.name))
    return recs, noise * span


def _sine(amplitude: float, omega: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0.0, 3 * 2 * np.pi / omega, n)
    return t, amplitude * np.sin(omega * t)


def test_a_reference_column_belongs_to_its_part_alone():
    """`solve_shared` with references: one column of ones per part whose entry is true, never shared by the
    parts of a start group; the split returns it after the part's own unknowns."""
    rng = np.random.default_rng(5)
    parts = [LinearPart(0, rng.normal(size=40), rng.normal(size=(40, 2)), rng.normal(size=(40, 3))) for _ in range(3)]
    theta, z, refs = rng.normal(size=2), rng.normal(size=3), [0.0, 0.8, -2.1]
    ys = [p.output(theta, z) + r for p, r in zip(parts, refs)]
    groups, with_refs = [0, 0, 0], [False, True, True]
    solution = solve_shared(parts, ys, [np.ones(40)] * 3, groups, with_refs)
    assert solution.shape == (2 + 3 + 2,)
    theta_l, own = split_solution(parts, solution, groups, with_refs)
    assert np.allclose(theta_l, theta) and np.allclose(own[0], z)
    assert np.allclose(own[1], np.r_[z, refs[1]]) and np.allclose(own[2], np.r_[z, refs[2]])


def test_one_state_and_each_runs_zero_are_fitted_exactly():
    """Noise-free runs from one state with offsets: the shared start with references is that state, and the
    offsets are each run's (to rounding); without references the shared start cannot fit them."""
    recs, _ = _runs(noise=0.0)
    runs = [(r.t, r.u, r.y) for r in recs]
    span = float(np.ptp(np.concatenate([simulate(ri_model(1), r.t, r.u).y for r in recs])))
    x0, rss, offsets = shared_initial_state(ri_model(1), runs, [False, True, True])
    assert np.allclose(x0, ri_model(1).x0, atol=1e-8) and rss < 1e-16 * span**2 * sum(len(r.y) for r in recs)
    assert np.allclose(offsets, np.array(OFFSETS) * span, atol=1e-8 * span)
    _, rss_without, zeros = shared_initial_state(ri_model(1), runs)
    assert zeros == [0.0, 0.0, 0.0] and rss_without > 1e-3 * span**2


def test_the_fit_finds_each_files_zero_and_scores_with_it():
    recs, sigma = _runs()
    fit = fit_recordings(recs, kind="ri", order=1)
    span = float(np.ptp(np.concatenate([simulate(ri_model(1), r.t, r.u).y for r in recs])))
    refs = fit.summary["references"]
    assert refs["relative_to"] == "run0" and set(refs["values"]) == {"run1", "run2"}
    for k, name in ((1, "run1"), (2, "run2")):
        assert abs(refs["values"][name] - OFFSETS[k] * span) < 0.01 * span
    residual = np.concatenate([r.y - fit.simulate(r) for r in recs])
    assert np.sqrt(np.mean(residual**2)) < 1.2 * sigma
    for row, rec in zip(fit.summary["recordings"], recs):
        mine = float(np.sqrt(np.mean((rec.y - fit.simulate(rec)) ** 2)) / np.ptp(rec.y))
        assert row["nrmse"] == pytest.approx(mine, rel=1e-9)


def test_files_of_one_zero_get_no_references():
    recs, sigma = _runs(offsets=(0.0, 0.0, 0.0))
    fit = fit_recordings(recs, kind="ri", order=1)
    assert fit.summary["references"] is None
    assert fit.model.fit_info["references"] == {}
    residual = np.concatenate([r.y - fit.simulate(r) for r in recs])
    assert np.sqrt(np.mean(residual**2)) < 1.2 * sigma


def test_validate_applies_the_reference_of_a_fitted_file(tmp_path):
    """`duhem fit --fmu` of runs with different zeros, then `duhem validate` of the FMU on each file: it passes,
    and each row's reference is the fit's (0 for the first file)."""
    recs, _ = _runs()
    files = [write_csv(tmp_path / f"{r.name}.csv", r.t, r.u, r.y) for r in recs]
    out, fmu = tmp_path / "m.json", tmp_path / "m.fmu"
    fit = json.loads(ok(invoke("fit", *files, "-o", out, "--fmu", fmu, "--kind", "ri", "--order", 1, "--json")).stdout)
    found = fit["summary"]["references"]["values"]
    rows = json.loads(ok(invoke("validate", fmu, *files, "--json")).stdout)["recordings"]
    assert [r["reference"] for r in rows] == [0.0, found["run1"], found["run2"]]
    for row, score in zip(rows, fit["summary"]["recordings"]):
        assert row["passed"] and row["nrmse"] == pytest.approx(score["nrmse"], rel=1e-6)


def test_each_reference_is_the_one_the_stored_start_needs():
    """`file_references`: each recording's reference minimises its residual from the stored x0 (what the FMU
    runs), also for a recording that starts elsewhere; moved either way by 1 % of the range it leaves more."""
    from fitter.identification.exported import file_references

    recs, _ = _runs()
    shifted = Recording(recs[2].t[50:] - recs[2].t[50], recs[2].u[50:], recs[2].y[50:], "later")
    runs = [recs[0], recs[1], shifted]
    refs = file_references(ri_model(1), runs)
    assert set(refs) == {"run1", "later"}
    for rec in runs[1:]:
        y = simulate(ri_model(1), rec.t, rec.u).y
        span = float(np.ptp(rec.y))
        rms = [np.sqrt(np.mean((rec.y - y - refs[rec.name] - d) ** 2)) for d in (0.0, 0.01 * span, -0.01 * span)]
        assert rms[0] < min(rms[1:])
