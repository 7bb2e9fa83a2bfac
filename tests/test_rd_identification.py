"""Rate-dependent identification from triangle waves (Sections IV-V): waves, transforms, estimators, bad input."""

import json

import numpy as np
import pytest

from fitter.core import (
    CallableRate,
    ConvergenceError,
    RateDependentModel,
    load_model,
    periodic_response,
    save_model,
    simulate,
)
from fitter.identification.rd_triangles import ESTIMATORS, bilinear_d2c, identify_each, identify_rd_triangles
from fitter.identification.triangle_waves import (
    TriangleWave,
    periodic_triangle_output,
    TriangleSamples,
    triangle_response,
    triangle_wave,
)

# A first-order model with an asymmetric g (g(b) != g(a)), so the falling-branch
# normalisation of eq (50) matters; sampled coarsely (delta = 0.3).
SLOPES = (0.25, 0.5, 1.0, 2.0)
DELTA = 0.3


def g_asym(v):
    v = np.asarray(v, dtype=float)
    return np.where(v >= 0, 1 - np.exp(-v), 0.3 * np.abs(v))


def asym_model() -> RateDependentModel:
    return RateDependentModel(A=[[-2.0]], B=[1.5], C=[1.0], g=CallableRate(g_asym))


def wave_record(model, a, periods=1, delta=DELTA, noise_pp=0.0, rng=None):
    return triangle_response(model, a, -a, 4 / a, 4 / a, periods, delta, noise_pp, rng)


@pytest.fixture(scope="module")
def asym_records():
    model = asym_model()
    return [wave_record(model, a) for a in SLOPES]


@pytest.fixture(scope="module")
def asym_fits(asym_records):
    return {est: identify_rd_triangles(asym_records, estimator=est) for est in ESTIMATORS}


# ----------------------------------------------------------------------------- triangle waves


def test_triangle_wave_follows_eq20():
    a, b, Ta, Tb = 0.5, -1.0, 4.0, 2.0  # a Ta = -b Tb = 2, T = 6
    t, u = triangle_wave(a, b, Ta, Tb, periods=2, delta=0.5)
    assert len(t) == 25 and t[-1] == pytest.approx(12.0)
    np.testing.assert_allclose(np.diff(t), 0.5)
    expected = np.where(np.mod(t, 6.0) <= Ta, -1.0 + a * np.mod(t, 6.0), 1.0 + b * (np.mod(t, 6.0) - Ta))
    np.testing.assert_allclose(u, expected, atol=1e-12)
    assert u[0] == pytest.approx(-1.0) and u.max() == pytest.approx(1.0) and u.min() == pytest.approx(-1.0)


@pytest.mark.parametrize(
    "args, message",
    [
        ((0.0, -1.0, 4.0, 4.0, 1, 0.1), "needs a > 0, b < 0"),
        ((1.0, 1.0, 4.0, 4.0, 1, 0.1), "needs a > 0, b < 0"),
        ((1.0, -1.0, 4.0, 3.0, 1, 0.1), "continuous only when a\\*Ta = -b\\*Tb"),
        ((1.0, -1.0, 4.0, 4.0, 0, 0.1), "periods must be a positive integer"),
        ((1.0, -1.0, 4.0, 4.0, 1.5, 0.1), "periods must be a positive integer"),
        ((1.0, -1.0, 4.0, 4.0, 1, 0.0), "sampling period delta must be > 0"),
        ((1.0, -1.0, 4.0, 4.0, 1, float("nan")), "sampling period delta must be > 0"),
    ],
)
def test_triangle_wave_rejects_bad_parameters(args, message):
    with pytest.raises(ValueError, match=message):
        triangle_wave(*args)


def test_triangle_response_noise_needs_rng_and_is_bounded():
    model = asym_model()
    with pytest.raises(ValueError, match="needs a seeded rng"):
        wave_record(model, 0.5, noise_pp=0.1)
    _, _, clean = wave_record(model, 0.5)
    _, _, noisy = wave_record(model, 0.5, noise_pp=0.1, rng=np.random.default_rng(3))
    err = noisy - clean
    assert np.abs(err).max() <= 0.05
    assert np.ptp(err) > 0.08  # uniform on [-0.05, 0.05]: 28 samples nearly span it


def test_periodic_triangle_output_is_the_limit_of_a_long_simulation():
    model = asym_model()
    a = 1.0
    t, u = triangle_wave(a, -a, 4.0, 4.0, periods=12, delta=0.1)
    y_long = simulate(model, t, u).y
    y_periodic = periodic_triangle_output(model, TriangleWave(a=a, b=-a, u_lo=-2.0, u_hi=2.0), t)
    last = t >= 11 * 8.0 - 1e-9
    np.testing.assert_allclose(y_long[last], y_periodic[last], atol=1e-9)
    assert np.abs(y_long[:5] - y_periodic[:5]).max() > 1e-3  # the long run starts off the limit


def _kernel_periodic_output(model, wave, t):
    """The kernel's limiting periodic response over the sorted phases and the corners (the stepping path)."""
    tau = wave.phase(t)
    grid, inverse = np.unique(np.r_[tau, 0.0, wave.Ta, wave.T], return_inverse=True)
    return periodic_response(model, grid, wave.value_at_phase(grid)).sim.y[inverse[: len(tau)]]


CLOSED_FORM_MODELS = {
    "first order": asym_model(),
    "real modes, E and D": RateDependentModel(
        A=[[-1.0, 0.3], [0.2, -2.5]], B=[0.7, -0.4], C=[1.0, 0.5], E=[0.1, -0.2], D=0.3, g=CallableRate(g_asym)
    ),
    "complex modes": RateDependentModel(
        A=[[-0.4, 2.0, 0.0], [-2.0, -0.4, 0.0], [0.0, 0.0, -3.0]],
        B=[1.0, 0.5, -0.3],
        C=[0.2, 1.0, 0.7],
        E=[0.0, 0.1, 0.05],
        D=-0.1,
        g=CallableRate(g_asym),
    ),
}


@pytest.mark.parametrize("name", CLOSED_FORM_MODELS)
def test_closed_form_periodic_output_is_the_kernels(name):
    """The closed form (every phase from its half's corner) against the kernel's periodic response: the same
    exact solution, to 1e-10 of the output range; at asymmetric slopes, off-grid phases and corners."""
    model = CLOSED_FORM_MODELS[name]
    wave = TriangleWave(a=0.7, b=-1.9, u_lo=-1.5, u_hi=2.5, t_min=0.37)
    t = np.r_[np.sort(np.random.default_rng(0).uniform(0, 3 * wave.T, 400)), wave.t_min + wave.Ta, wave.t_min]
    y = periodic_triangle_output(model, wave, t)
    y_kernel = _kernel_periodic_output(model, wave, t)
    assert np.abs(y - y_kernel).max() <= 1e-10 * np.ptp(y_kernel)
    twice = TriangleSamples([wave, wave], [t, t[:50]]).outputs(model, [(0.2, 3.0), tuple(g_asym([0.7, -1.9]))])
    assert np.abs(twice[1] - y[:50]).max() <= 1e-10 * np.ptp(y_kernel)
    other = _kernel_periodic_output(model.replace(g=CallableRate(lambda v: np.where(v > 0, 0.2, 3.0))), wave, t)
    assert np.abs(twice[0] - other).max() <= 1e-10 * np.ptp(other) and np.abs(other - y).max() > 1e-3


def test_closed_form_periodic_output_refuses_a_divergent_model_and_falls_back_where_g_vanishes():
    unstable = RateDependentModel(A=[[0.5]], B=[1.0], C=[1.0], g=CallableRate(g_asym))
    wave = TriangleWave(a=1.0, b=-1.0, u_lo=-1.0, u_hi=1.0)
    t = np.linspace(0, 4, 41)
    with pytest.raises(ConvergenceError, match="condition \\(5\\)"):
        periodic_triangle_output(unstable, wave, t)
    assert TriangleSamples([wave], [t]).outputs(unstable, [(1.0, 1.0)]) == [None]
    stalled = asym_model().replace(g=CallableRate(lambda v: np.where(v > 0, 1.0, 0.0)))  # frozen while falling
    y = periodic_triangle_output(stalled, wave, t)
    np.testing.assert_allclose(y, _kernel_periodic_output(stalled, wave, t), atol=1e-12)


# ----------------------------------------------------------------------------- bilinear transform (35)-(36)


def test_bilinear_d2c_first_order_closed_form():
    # H(z) = beta/(z + alpha), z = (2 + s d)/(2 - s d): monic denominator s + 2(1+alpha)/(d(1-alpha)),
    # numerator s^0 coefficient 2 beta/(d(1-alpha)) (its s^1 term dropped, as (35) has none).
    alpha_d, beta_d, d = -0.8, 0.3, 0.13
    alpha_c, beta_c = bilinear_d2c(np.array([alpha_d]), np.array([beta_d]), d)
    assert alpha_c[0] == pytest.approx(2 * (1 + alpha_d) / (d * (1 - alpha_d)), rel=1e-12)
    assert beta_c[0] == pytest.approx(2 * beta_d / (d * (1 - alpha_d)), rel=1e-12)


def test_bilinear_d2c_maps_poles_by_tustin():
    z = np.array([0.9, 0.5])
    d = 0.2
    alpha_d = np.poly(z)[1:]
    alpha_c, _ = bilinear_d2c(alpha_d, np.array([1.0, 0.5]), d)
    s = np.sort(np.roots(np.r_[1.0, alpha_c]).real)
    np.testing.assert_allclose(s, np.sort(2 / d * (z - 1) / (z + 1)), rtol=1e-12)


# ----------------------------------------------------------------------------- estimators


def test_default_estimator_is_improved(asym_records):
    fit = identify_rd_triangles(asym_records[:2])
    assert fit.estimator == "improved"
    assert fit.model.fit_info["estimator"] == "improved"


def test_identify_each_is_each_estimator_alone(asym_records):
    noisy = [(t, u, y + 0.01 * np.sin(7 * t)) for t, u, y in asym_records]
    alone = {est: identify_rd_triangles(noisy, estimator=est) for est in ESTIMATORS}
    for est, fit in identify_each(noisy).items():
        np.testing.assert_array_equal(fit.A_hat, alone[est].A_hat)
        np.testing.assert_array_equal(fit.g_hat, alone[est].g_hat)
        assert fit.rms_residual == alone[est].rms_residual and fit.estimator == est
    assert alone["improved"].rms_residual < alone["literal"].rms_residual
    with pytest.raises(ValueError, match="estimator must be one of"):
        identify_each(asym_records, estimators=("improved", "exact"))


def test_improved_is_exact_on_noise_free_data_at_coarse_sampling(asym_fits):
    fit = asym_fits["improved"]
    g1 = float(g_asym(SLOPES[0]))
    # normalised: g_hat(a_1) = 1, A_hat = g(a_1) A, B_hat = g(a_1) B (47)-(48) corrected
    assert fit.A_hat[0, 0] == pytest.approx(-2.0 * g1, rel=1e-6)
    assert fit.B_hat[0] == pytest.approx(1.5 * g1, rel=1e-6)
    np.testing.assert_array_equal(fit.C_hat, [1.0])
    np.testing.assert_allclose(fit.slopes, np.r_[SLOPES, -np.array(SLOPES)])
    # falling slopes normalised by the reference rising branch (eq 50 corrected): g(b_1)/g(a_1) != 1
    np.testing.assert_allclose(fit.g_hat, g_asym(fit.slopes) / g1, rtol=1e-6)
    assert fit.rms_residual < 1e-8


def test_literal_is_biased_at_coarse_sampling(asym_fits):
    fit = asym_fits["literal"]
    g1 = float(g_asym(SLOPES[0]))
    assert fit.g_hat[0] == 1.0
    assert abs(fit.A_hat[0, 0] / (-2.0 * g1) - 1) > 0.02
    assert np.max(np.abs(fit.g_hat / (g_asym(fit.slopes) / g1) - 1)) > 0.05
    assert fit.rms_residual > 100 * asym_fits["improved"].rms_residual


def test_identified_model_round_trips_through_json(asym_fits, tmp_path):
    fit = asym_fits["improved"]
    d = json.loads(json.dumps(fit.to_dict()))
    assert d["estimator"] == "improved" and d["order"] == 1 and len(d["waves"]) == len(SLOPES)
    path = tmp_path / "rd.json"
    save_model(fit.model, path)
    loaded = load_model(path)
    t, u = triangle_wave(0.75, -0.75, 4 / 0.75, 4 / 0.75, periods=2, delta=0.1)
    np.testing.assert_allclose(simulate(loaded, t, u).y, simulate(fit.model, t, u).y, atol=1e-12)
    # g_hat A_hat = g A and g_hat B_hat = g B: the same response as the true model; at the slope 0.75,
    # between identified slopes, g comes from the PCHIP table
    y_true = simulate(asym_model(), t, u).y
    assert np.abs(simulate(loaded, t, u).y - y_true).max() < 0.005 * np.ptp(y_true)


# ----------------------------------------------------------------------------- bad input


def _replace(rec, **arrays):
    t, u, y = (np.array(a, dtype=float) for a in rec)
    out = {"t": t, "u": u, "y": y}
    for name, fn in arrays.items():
        out[name] = fn(out[name])
    return out["t"], out["u"], out["y"]


def _set(k, value):
    def fn(a):
        a = a.copy()
        a[k] = value
        return a

    return fn


def _dip_in_rising_branch():
    """u rises, turns back for 5 samples, rises on and falls: not a triangle wave."""
    steps = [1] * 30 + [-1] * 5 + [1] * 15 + [-1] * 30
    u = -2.0 + 0.05 * np.r_[0, np.cumsum(steps)]
    t = 0.1 * np.arange(len(u))
    return t, u, np.zeros_like(u)


@pytest.mark.parametrize(
    "case, message",
    [
        ("nan_y", r"record 1: y\[5\] is nan \(NaN or infinite\)"),
        ("inf_u", r"record 1: u\[7\] is inf"),
        ("too_few", r"record 1: 5 samples are too few for order 1 \(need at least 6\)"),
        ("kink", r"record 1: branch not monotone or not a ramp near samples"),
        ("dip", r"record 1: branch not monotone: the corner at t = 3 has u = -0.5 but the wave's maximum"),
        ("short_branches", r"record 1: the falling branch .* order 2 needs at least 4 per branch .*branches too short"),
        ("one_wave", r"need at least 2 triangle-wave records .* got 1"),
        ("same_slope", r"records 0 and 1 have the same rising slope 0.25; eq \(50\) needs one wave per slope"),
        ("same_falling_slope", r"records 0 and 1 have the same falling slope -0.25; eq \(50\) needs one"),
        ("undersampled", r"record 1: branch not monotone or not a ramp .*or the branches are too short"),
        ("length", r"record 1: t, u, y differ in length \(124, 124, 123\)"),
        ("non_uniform", r"record 1: sampling is not uniform"),
        ("time_back", r"record 1: time must increase: t\[10\]"),
        ("constant_u", r"record 1: the input never rises"),
        ("order", r"order must be a positive integer, got 0"),
        ("estimator", r"estimator must be one of \('literal', 'improved'\), got 'foo'"),
    ],
)
def test_bad_input_raises_clear_error(case, message):
    model = RateDependentModel(A=[[-1.0]], B=[1.0], C=[1.0], g=CallableRate(lambda v: np.minimum(np.abs(v), 1)))
    r0 = wave_record(model, 0.25, delta=0.13)
    r1 = wave_record(model, 0.5, delta=0.13)  # 124 samples
    k = len(r1[0]) // 4
    order, estimator = 1, "improved"
    records = {
        "nan_y": [r0, _replace(r1, y=_set(5, np.nan))],
        "inf_u": [r0, _replace(r1, u=_set(7, np.inf))],
        "too_few": [r0, tuple(a[:5] for a in r1)],
        "kink": [r0, _replace(r1, u=lambda u: u + 0.3 * (np.arange(len(u)) == k))],
        "dip": [r0, _dip_in_rising_branch()],
        "short_branches": [r0, wave_record(model, 3.0, periods=3, delta=0.5)],
        "one_wave": [r0],
        "same_slope": [r0, r0],
        "same_falling_slope": [r0, triangle_response(model, 0.5, -0.25, 4.0, 8.0, 1, 0.13)],
        "undersampled": [r0, wave_record(model, 3.0, periods=4, delta=1.0)],
        "length": [r0, (r1[0], r1[1], r1[2][:-1])],
        "non_uniform": [r0, _replace(r1, t=lambda t: t + 0.01 * (np.arange(len(t)) >= 10))],
        "time_back": [r0, _replace(r1, t=lambda t: np.r_[t[:10], t[9], t[11:]])],
        "constant_u": [r0, _replace(r1, u=lambda u: np.ones_like(u))],
        "order": [r0, r1],
        "estimator": [r0, r1],
    }[case]
    if case == "short_branches":
        order = 2
    elif case == "order":
        order = 0
    elif case == "estimator":
        estimator = "foo"
    with pytest.raises(ValueError, match=message):
        identify_rd_triangles(records, order=order, estimator=estimator)
