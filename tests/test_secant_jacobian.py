"""`fitter.identification.refine`'s Jacobian: forward differences refreshed every `Options.jacobian_refresh`-th
call, Broyden's secant update between (`SecantJacobian`)."""

from contextlib import nullcontext

import numpy as np

from fitter.identification import output_error
from fitter.identification.refine import Barrier, Options, SecantJacobian, refine
from test_output_error import START, TRUE, _Five, _recording


class _Curve:
    """r(z) = (z0^2 - z1, sin z1 + z0 z1, e^{z0 / 2}): its exact Jacobian, and a count of evaluations; `last` as
    `refine`'s objective gives it (the last evaluation's value when at the same point)."""

    def __init__(self):
        self.evaluations, self.at = 0, None

    def __call__(self, z):
        self.evaluations += 1
        self.at = (z.copy(), np.array([z[0] ** 2 - z[1], np.sin(z[1]) + z[0] * z[1], np.exp(z[0] / 2)]))
        return self.at[1]

    def last(self, z):
        return self.at[1] if self.at is not None and np.array_equal(self.at[0], z) else self(z)

    def penalty_held(self, z):
        return nullcontext()  # no penalty

    @staticmethod
    def exact(z):
        return np.array([[2 * z[0], -1.0], [z[1], np.cos(z[1]) + z[0]], [0.5 * np.exp(z[0] / 2), 0.0]])


def test_a_secant_update_meets_the_secant_equation_at_no_evaluation_and_differences_return_on_schedule():
    curve = _Curve()
    jac = SecantJacobian(curve, 2, None, (np.full(2, -np.inf), np.full(2, np.inf)))
    z0, z1, z2 = np.array([0.3, -0.7]), np.array([0.45, -0.5]), np.array([0.5, -0.45])
    r0 = curve(z0)
    J0 = jac(z0)
    assert jac.differenced and curve.evaluations == 1 + 2  # the value at z0 reused, one evaluation per column
    assert np.allclose(J0, curve.exact(z0), rtol=0, atol=1e-6)
    r1 = curve(z1)  # the solver's accepted trial
    J1 = jac(z1)
    assert not jac.differenced and curve.evaluations == 4  # the update costs no evaluation
    s = z1 - z0
    assert np.allclose(J1 @ s, r1 - r0, rtol=1e-12, atol=1e-15)  # J+ s = df
    across = np.array([-s[1], s[0]])
    assert np.allclose(J1 @ across, J0 @ across, rtol=1e-12, atol=1e-15)  # unchanged across the step
    assert np.abs(J1 - curve.exact(z1)).max() > 1e-3  # an update, not the derivative
    curve(z2)
    J2 = jac(z2)
    assert jac.differenced and curve.evaluations == 5 + 2  # the second refresh: differences again
    assert np.allclose(J2, curve.exact(z2), rtol=0, atol=1e-6)


def test_secant_updates_reach_the_difference_fits_minimum_in_fewer_evaluations(monkeypatch):
    """The fit of tests/test_output_error.py's first test with forward differences at every Jacobian and at every
    second (as the effect fits): the same minimum, the covariance from differences at it either way."""
    counted, residuals = [0], output_error.Recordings.residuals

    def counting(self, *args, **kwargs):
        counted[0] += 1
        return residuals(self, *args, **kwargs)

    monkeypatch.setattr(output_error.Recordings, "residuals", counting)
    fits, evaluations = {}, {}
    for refresh in (1, 2):
        counted[0] = 0
        fits[refresh] = refine(
            _Five(), START, output_error.Recordings([_recording(0.5)], x0="fit"), Options(jacobian_refresh=refresh)
        )
        evaluations[refresh] = counted[0]
    every, secant = fits.values()
    assert every.success and secant.success
    assert np.all(np.abs(secant.theta - every.theta) < 0.01 * every.stderr())  # within the tolerances
    assert abs(secant.cost / every.cost - 1) < 10 * Options().ftol  # each stops within ftol of its own end
    assert np.all(np.abs(secant.theta - TRUE) < 4 * secant.stderr())
    assert np.allclose(secant.stderr(), every.stderr(), rtol=1e-3)
    assert evaluations[2] <= 0.8 * evaluations[1]


def test_secant_fits_on_two_processes_give_the_one_process_fit_and_leave_no_process(monkeypatch):
    """As tests/test_output_error.py's two-process test, with secant updates (every third request differenced, so
    that the fit ends on an update and its covariance takes differences of its own): the differences' columns on forked
    processes from the first map (`POOL_AFTER_S` 0), the covariance's differences on this process after the map
    has ended (a map used after its end would fork processes that nothing ends)."""
    import multiprocessing

    import fitter.workers as workers

    monkeypatch.setattr(workers, "POOL_AFTER_S", 0.0)
    fits = {}
    for processes in ("1", "2"):
        monkeypatch.setenv("DUHEM_WORKERS", processes)
        problem = output_error.Recordings([_recording(0.5)], x0="fit")
        fits[processes] = refine(_Five(), START, problem, Options(jacobian_refresh=3))  # ends on an update
        assert multiprocessing.active_children() == []
    one, two = fits.values()
    assert one.nfev == two.nfev and one.theta.tobytes() == two.theta.tobytes()
    assert np.array_equal(one.jac, two.jac) and np.array_equal(one.weighted, two.weighted)


class _Excess:
    """theta_0 - limit: a barrier on A+ of `_Five` (<= 0 where theta_0 <= limit); counts its evaluations."""

    def __init__(self, limit: float):
        self.limit, self.evaluations = limit, 0

    def __call__(self, theta):
        self.evaluations += 1
        return [theta[0] - self.limit]


def test_a_barrier_far_inside_is_not_evaluated_at_the_differences_and_one_near_is():
    """The fit of the first test under a barrier that the fit never comes near: evaluated at the solver's points
    and once per Jacobian, a fraction of the evaluations of the same barrier differenced at every Jacobian
    (margin inf), and the same fit to the last bit as without a barrier.  Under one that holds the optimum back
    (A+ <= -3.3, the truth -3): differenced, and the fit ends at the barrier."""
    problem = output_error.Recordings([_recording(0.5)], x0="fit")
    free = refine(_Five(), START, problem)
    runs = {}
    for margin in (1e-3, np.inf):
        excess = _Excess(10.0)
        res = refine(_Five(), START, problem, penalty=Barrier(excess, inside=0.0, margin=margin))
        runs[margin] = (res, excess.evaluations)
    (held, held_count), (differenced, all_count) = runs.values()
    assert held.theta.tobytes() == differenced.theta.tobytes() == free.theta.tobytes()
    assert held_count < all_count / 3  # five columns a Jacobian, none of them evaluated
    near = _Excess(-3.3)
    bound = refine(_Five(), START, problem, penalty=Barrier(near, inside=0.0))
    assert near.evaluations > 3 * bound.nfev  # differenced: the columns' points too
    assert -3.3 < bound.theta[0] < -3.3 + 0.05  # pressed against the barrier, beyond it by the penalty's give
