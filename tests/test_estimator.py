"""`DuhemEstimator`: fit / predict / score / diagnose / save / export over the package's functions."""

import numpy as np
import pytest
from samples import noisy_recording, ri_model, sine_input

from fitter import DuhemEstimator, fit_recordings, load_model
from fitter.estimator import NotFittedError
from fitter.core import simulate
from fitter.fmu.host import simulate_fmu


@pytest.fixture(scope="module")
def recording():
    return noisy_recording(ri_model(1), *sine_input(1.0, 4, 200, 1.0, 2.0), noise=0.01, seed=0)


@pytest.fixture(scope="module")
def fitted(recording):
    return DuhemEstimator(kind="ri", order=1).fit([recording])


def test_unfitted_estimator_says_so(recording):
    with pytest.raises(NotFittedError, match="call fit"):
        DuhemEstimator().score(recording)


def test_fit_matches_the_function_and_scores_at_the_noise(fitted, recording):
    direct = fit_recordings([recording], kind="ri", order=1)
    np.testing.assert_array_equal(fitted.result_.theta, direct.theta)
    assert fitted.summary_ == direct.summary
    y_hat = fitted.predict(recording)
    np.testing.assert_array_equal(y_hat, simulate(fitted.model_, recording.t, recording.u).y)
    assert fitted.score(recording) == pytest.approx(np.sqrt(np.mean((recording.y - y_hat) ** 2)) / np.ptp(recording.y))
    assert fitted.score(recording) == pytest.approx(fitted.summary_["recordings"][0]["nrmse"], rel=1e-12)
    assert fitted.score(recording) < 0.015  # noise: 1 % of the output range


def test_save_and_export_carry_the_fitted_model(fitted, recording, tmp_path):
    fitted.save(tmp_path / "m.json")
    loaded = load_model(tmp_path / "m.json")
    np.testing.assert_allclose(loaded.A_plus, fitted.model_.A_plus, rtol=1e-15)
    path = fitted.export(tmp_path / "m.fmu", backend="native")
    y = simulate(fitted.model_, recording.t, recording.u).y
    assert np.max(np.abs(simulate_fmu(path, recording.t, recording.u) - y)) < 1e-10


def test_diagnose_uses_the_fitted_model_as_base(fitted, recording):
    d = fitted.diagnose([recording], candidates=["viscous"])
    assert d.base_model.order == fitted.model_.order
    assert d.verdict == "nothing_missing"
    assert d.baseline["residual_rms"] < 0.015 * np.ptp(recording.y)


def test_params_follow_scikit_learn():
    """get_params lists every constructor parameter; set_params sets them by name and refuses an unknown one;
    an estimator built from another's parameters has the same."""
    est = DuhemEstimator(kind="ri", order=2, effects=("creep",), held={"creep.tau": 0.5}, fmi_version=3)
    params = est.get_params()
    assert set(params) == {
        "kind",
        "order",
        "q",
        "x0",
        "faithful_minor_loops",
        "effects",
        "held",
        "backend",
        "fmi_version",
        "platforms",
        "allow_unstable",
        "progress",
    }
    assert params["order"] == 2 and params["held"] == {"creep.tau": 0.5} and params["fmi_version"] == 3
    assert DuhemEstimator(**params).get_params() == params
    assert est.set_params(order=3, x0="periodic") is est and est.order == 3 and est.x0 == "periodic"
    with pytest.raises(ValueError, match="unknown parameter.*'ordr'"):
        est.set_params(ordr=1)


def test_every_fit_option_reaches_fit_recordings(recording, monkeypatch):
    """The estimator passes each of the CLI's fit options to `fit_recordings` (the one fit path)."""
    import fitter.estimator

    seen = {}
    monkeypatch.setattr(fitter.estimator, "fit_recordings", lambda recs, **kw: seen.update(kw) or _Fake())
    DuhemEstimator(
        kind="rd",
        order=2,
        q=0.5,
        x0="periodic",
        faithful_minor_loops=True,
        effects=["viscous"],
        held={"viscous.c": 0.1},
    ).fit([recording])
    assert {k: seen[k] for k in ("kind", "order", "q", "x0", "faithful_minor_loops", "effects", "held")} == {
        "kind": "rd",
        "order": 2,
        "q": 0.5,
        "x0": "periodic",
        "faithful_minor_loops": True,
        "effects": ("viscous",),
        "held": {"viscous.c": 0.1},
    }


class _Fake:
    model, summary = None, {}


def test_export_takes_the_estimators_fmi_version_and_platforms(fitted, tmp_path):
    from fmpy import read_model_description
    import zipfile

    fitted.set_params(fmi_version=3, platforms="linux")
    try:
        path = fitted.export(tmp_path / "m3.fmu")
    finally:
        fitted.set_params(fmi_version=2, platforms=None)
    assert read_model_description(path).fmiVersion == "3.0"
    with zipfile.ZipFile(path) as zf:
        assert sorted(n for n in zf.namelist() if n.startswith("binaries/")) == [
            "binaries/x86_64-linux/semilinear_duhem.so"
        ]
    with pytest.raises(ValueError, match="unknown export option"):
        fitted.export(tmp_path / "x.fmu", fmi=3)
