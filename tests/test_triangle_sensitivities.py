"""The exact derivatives of the closed-form periodic triangle output (`output_derivatives`) against central
differences of the output itself, and the phi-function derivatives they use."""

import numpy as np
import pytest

from fitter.core import AffineFlow
from fitter.core.flow import phi1, phi2
from fitter.identification.triangle_sensitivities import dphi1, dphi2, output_derivatives
from fitter.identification.triangle_waves import TriangleSamples, TriangleWave

# three waves of distinct slopes and unequal halves, sampled off the corners
WAVES = [TriangleWave(a=a, b=-b, u_lo=-1.0, u_hi=1.5) for a, b in ((0.5, 0.8), (1.0, 0.6), (2.5, 3.0))]
TIMES = [np.arange(0.0, w.T, w.T / 37) for w in WAVES]
RATES = np.array([0.7, 1.0, 1.6, 0.9, 0.5, 2.2])  # rising halves, then falling

MODELS = {
    "complex pair": (np.array([[-0.4, 1.0], [-3.0, 0.0]]), np.array([0.8, -0.3]), np.array([1.0, 0.0])),
    "real, order 3": (  # eigenvalues -0.5, -1, -2 in the canonical form (49)
        np.array([[-3.5, 1.0, 0.0], [-3.5, 0.0, 1.0], [-1.0, 0.0, 0.0]]),
        np.array([0.5, 0.2, 0.05]),
        np.array([1.0, 0.0, 0.0]),
    ),
}


def _outputs(samples, A, B, C, g):
    """The closed-form periodic output (y without D u) of (A, B, C) at rates g."""
    fl = AffineFlow(A, B, np.zeros(len(B)))
    X, rho = samples._states(fl, g)
    assert np.all(rho < 1)
    return X @ C


def _central(f, x0, h):
    return (f(x0 + h) - f(x0 - h)) / (2 * h)


@pytest.mark.parametrize("name", MODELS)
def test_output_derivatives_are_the_central_differences_of_the_output(name):
    A, B, C = MODELS[name]
    samples = TriangleSamples(WAVES, TIMES)
    direction = np.random.default_rng(0).standard_normal(A.shape)
    d = output_derivatives(samples, AffineFlow(A, B, np.zeros(len(B))), C, RATES, [direction])
    y = _outputs(samples, A, B, C, RATES)
    scale = np.ptp(y)
    np.testing.assert_allclose(d.y, y, atol=1e-12 * scale)
    h = 1e-5
    dA = _central(lambda s: _outputs(samples, A + s * direction, B, C, RATES), 0.0, h)
    np.testing.assert_allclose(d.d_A[:, 0], dA, atol=1e-7 * np.abs(dA).max())
    for j in range(len(B)):
        e = np.eye(len(B))[j]
        dB = _central(lambda s: _outputs(samples, A, B + s * e, C, RATES), 0.0, h)
        np.testing.assert_allclose(d.d_B[:, j], dB, atol=1e-7 * np.abs(dB).max())
    # each half's rate moves its own samples (d_own) and its wave's other half (d_other), nothing else
    P = len(WAVES)
    for k in range(2 * P):
        e = np.eye(2 * P)[k]
        dg = _central(lambda s: _outputs(samples, A, B, C, RATES + s * e), 0.0, h)
        own = samples.half == k
        other = (samples.half == (k + P) % (2 * P)) & ~own
        expected = np.where(own, d.d_own, np.where(other, d.d_other, 0.0))
        np.testing.assert_allclose(expected, dg, atol=1e-7 * np.abs(dg).max())
        assert np.abs(dg[~own & ~other]).max() == 0.0


def test_phi_derivatives_match_central_differences_on_both_sides_of_the_series_switch():
    z = np.r_[np.linspace(-3, 3, 61), 0.4999, 0.5001, -0.5001, 1e-9]
    zc = z + 0.7j * np.sign(z)
    h = 1e-6
    for arg in (z, zc):
        np.testing.assert_allclose(dphi1(arg), _central(phi1, arg, h), rtol=1e-7)
        np.testing.assert_allclose(dphi2(arg), _central(phi2, arg, h), rtol=1e-7)
    assert dphi1(np.array([0.0]))[0] == 0.5 and dphi2(np.array([0.0]))[0] == pytest.approx(1 / 6, rel=1e-15)
    # no overflow where e^z underflows: phi1'(z) -> 1/z^2, phi2'(z) -> 1/z^2 as z -> -inf
    far = np.array([-800.0])
    assert dphi1(far)[0] == pytest.approx(1 / 800**2 * (1 + 0.0)) and np.isfinite(dphi2(far)[0])


@pytest.mark.parametrize("order", [1, 2])
def test_the_improved_estimators_jacobian_is_its_residuals_forward_differences(order):
    from fitter.identification import rd_triangles as rd
    from fitter.identification.triangle_records import parse_record
    from fitter.identification.wave_output_error import WaveParameters, WaveRecords
    from fitter.paper import example2, example3

    raw = example2.records(example2.NOISE_PP, 0) if order == 1 else example3.records()
    recs = sorted((parse_record(i, r, order) for i, r in enumerate(raw)), key=lambda r: r.wave.a)
    param, problem = WaveParameters(order, len(recs)), WaveRecords(recs)
    alpha, g, _ = rd._ramp_exact_start(recs, order)
    theta = param.pack(alpha, problem.best_beta(param, alpha, g[:, 0], g[:, 1]), g[:, 0], g[:, 1])
    theta *= 1 + 0.02 * np.random.default_rng(1).standard_normal(len(theta))  # off the start's structure
    exact, differences = problem.jacobian(param, theta), problem.difference_jacobian(param, theta)
    # forward differences with steps 1e-6 (1 + |theta|): first-order accurate to about 1e-5 of each column
    np.testing.assert_allclose(exact, differences, atol=1e-4 * np.abs(exact).max())
    assert np.abs(exact - differences).max() > 0  # two computations, not one


@pytest.mark.parametrize("order", [1, 2])
def test_a_refinements_joint_pass_gives_the_residuals_and_the_jacobian_of_the_separate_ones(order):
    from dataclasses import replace

    from fitter.identification import rd_triangles as rd
    from fitter.identification.triangle_records import parse_record
    from fitter.identification.wave_output_error import WaveParameters, WaveRecords
    from fitter.paper import example2, example3

    raw = example2.records(example2.NOISE_PP, 0) if order == 1 else example3.records()
    recs = sorted((parse_record(i, r, order) for i, r in enumerate(raw)), key=lambda r: r.wave.a)
    param, problem = WaveParameters(order, len(recs)), WaveRecords(recs)
    joint = replace(problem, joint=True)
    alpha, g, _ = rd._ramp_exact_start(recs, order)
    theta = param.pack(alpha, problem.best_beta(param, alpha, g[:, 0], g[:, 1]), g[:, 0], g[:, 1])
    theta *= 1 + 0.02 * np.random.default_rng(2).standard_normal(len(theta))
    r_joint, r_apart = joint.residuals(param, theta)[0], problem.residuals(param, theta)[0]
    # the output as Re(U b . V^T C) against Re(W V^T) C: the same sum in another order
    np.testing.assert_allclose(r_joint, r_apart, rtol=0, atol=1e-12 * np.abs(r_apart).max())
    kept = joint.jacobian(param, theta)
    np.testing.assert_array_equal(kept, problem.jacobian(param, theta))
    assert joint.jacobian(param, theta) is kept  # from the residuals' pass, not a second one
    moved = theta * (1 + 1e-3)
    assert joint.jacobian(param, moved) is not kept and np.abs(joint.jacobian(param, moved) - kept).max() > 0
