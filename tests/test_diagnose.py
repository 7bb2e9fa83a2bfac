"""`fitter.diagnosis.diagnose`: the right effect on generated experiments, nothing on clean ones, clear errors.

The experiments come from the project's own simulator (`synthetic_experiment`):
4 recordings (0.025, 0.125, 0.5 Hz and a repeat of the first), effect max 2% of
the output range, noise 1/15 of that.  The larger sweep (several seeds, larger
recordings) is `bench/diagnose_speed.py --sweep`.
"""
import json

import numpy as np
import pytest

from fitter.core import load_model, save_model, simulate
from fitter.core.effects import EFFECTS
from fitter.diagnosis.diagnose import DiagnoseError, diagnose, synthetic_experiment
from fitter.reports.diagnosis_report import write_diagnosis_report
from fitter.data.recordings import Recording

SAMPLES = 300
_CACHE: dict = {}


def run(effect, seed):
    key = (effect, seed)
    if key not in _CACHE:
        recs, truth = synthetic_experiment(effect, seed=seed, samples=SAMPLES)
        steps = []
        _CACHE[key] = (recs, truth, diagnose(recs, progress=lambda msg, frac: steps.append((msg, frac))))
        _CACHE[key][2].steps = steps
    return _CACHE[key]


@pytest.mark.parametrize("effect", list(EFFECTS))
def test_concealed_effect_is_the_first_finding(effect):
    recs, truth, d = run(effect, 0)
    assert d.findings, f"{effect}: nothing found"
    assert d.findings[0]["effect"] == effect
    assert d.findings[0]["p_value"] < 1e-6
    assert d.extended["residual_rms"] <= 1.2 * truth["noise_rms"]
    assert d.baseline["residual_rms"] >= 1.5 * truth["noise_rms"]
    true_params = truth["effect"]["parameters"]
    strength = {"backlash": "b", "rate_dependence": "alpha", "creep": "k", "viscous": "c",
                "thermal_drift": "kappa", "saturation": "beta", "sensor_lag": "tau"}[effect]
    found = d.findings[0]["parameters"][strength]
    assert abs(found - true_params[strength]) <= 0.25 * abs(true_params[strength])


@pytest.mark.parametrize("seed", [0, 1])
def test_clean_experiment_has_nothing_missing(seed):
    recs, truth, d = run(None, seed)
    assert d.findings == []
    assert d.extended["effects"] == []
    assert abs(d.noise_rms / truth["noise_rms"] - 1) < 0.2
    assert "nothing is missing" in d.paragraph and d.verdict == "nothing_missing"


def test_json_output_and_extended_model_round_trip(tmp_path):
    recs, truth, d = run("creep", 0)
    out = json.loads(json.dumps(d.to_json()))
    for key in ("baseline", "noise_rms", "mismatch", "findings", "extended"):
        assert key in out
    assert set(out["baseline"]) >= {"nrmse", "residual_rms"}
    assert set(out["findings"][0]) >= {"effect", "p_value", "parameters", "stderr", "explained_fraction"}
    assert out["extended"]["effects"][0]["effect"] == "creep"
    assert 0.8 < out["findings"][0]["explained_fraction"] <= 1.0
    save_model(d.extended_model, tmp_path / "m.json")
    back = load_model(tmp_path / "m.json")
    t = np.concatenate([r.t for r in recs])
    u = np.concatenate([r.u for r in recs])
    np.testing.assert_allclose(simulate(back, t, u).y, d.extended_output, atol=1e-12)
    worst = out["mismatch"]["worst_recording"]
    assert worst in [r.name for r in recs]


def test_thermal_drift_shows_in_the_repeat():
    recs, truth, d = run("thermal_drift", 0)
    rep = d.mismatch["repeat"]
    assert rep["repeat"] == recs[-1].name and rep["original"] == recs[0].name
    assert rep["data_difference_rms"] > 3 * rep["expected_from_noise"]
    _, _, clean = run(None, 0)
    assert clean.mismatch["repeat"]["data_difference_rms"] < 1.3 * clean.mismatch["repeat"]["expected_from_noise"]
    assert d.validation["thermal_drift"] < 0.5 * d.validation["base"]


def test_progress_is_reported_in_order():
    _, _, d = run("backlash", 0)
    fractions = [f for _, f in d.steps]
    assert fractions[0] == 0.0 and fractions[-1] == 1.0
    assert all(b >= a for a, b in zip(fractions, fractions[1:]))
    assert {f"testing {name}" for name in EFFECTS} <= {m for m, _ in d.steps}


def test_report_is_written(tmp_path):
    recs, truth, d = run("viscous", 0)
    target = write_diagnosis_report(d, recs, tmp_path / "rep")
    names = sorted(p.name for p in target.iterdir())
    assert names == ["index.html", "loops.png", "nrmse.png", "residual_map.png"]
    assert "viscous" in (target / "index.html").read_text()
    write_diagnosis_report(d, recs, tmp_path / "rep")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep"]


def _rec(t, u, y, name="r", out="y"):
    from fitter.core.models import Signal
    return Recording(t, u, y, name=name, source=f"{name}.csv", output=Signal(out))


def test_bad_input_is_a_clear_error():
    t = np.linspace(0, 1, 100)
    with pytest.raises(DiagnoseError, match="100 samples in all.*too short"):
        diagnose([_rec(t, np.sin(20 * t), np.sin(20 * t))])
    t = np.linspace(0, 10, 2000)
    with pytest.raises(DiagnoseError, match="reverses fewer than twice"):
        diagnose([_rec(t, t, np.tanh(t))])
    a = _rec(t, np.sin(t), np.sin(t), "a")
    b = _rec(t + 20, np.sin(t), np.sin(t), "b", out="force")
    with pytest.raises(DiagnoseError, match=r"b.csv: columns \(u, force\) differ from a.csv: \(u, y\)"):
        diagnose([a, b])
    with pytest.raises(DiagnoseError, match="b.csv: starts at t = 0.0 before a.csv ends"):
        diagnose([a, _rec(t, np.sin(t), np.sin(t), "b")])
    with pytest.raises(DiagnoseError, match="unknown candidate effect 'friction'"):
        diagnose([a], candidates=["friction"])
