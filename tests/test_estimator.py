"""`DuhemEstimator`: fit / predict / score / diagnose / save / export over the package's functions."""
import numpy as np
import pytest
from conftest import noisy_recording, ri_model, sine_input

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
    assert fitted.score(recording) == pytest.approx(np.sqrt(np.mean((recording.y - y_hat) ** 2))
                                                    / np.ptp(recording.y))
    assert fitted.score(recording) == pytest.approx(fitted.summary_["recordings"][0]["nrmse"], rel=1e-12)
    assert fitted.score(recording) < 0.015                   # noise: 1 % of the output range


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
    assert d.verdict in ("nothing_missing", "effects_found", "unexplained")
    assert d.baseline["residual_rms"] < 0.015 * np.ptp(recording.y)
