"""The output-error engine: every initial-state mode, bounds, masks, covariance, parametrisations."""

import itertools
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from fitter.core import RateIndependentModel, simulate
from fitter.core.effects import EffectContext
from fitter.data.recordings import Recording
from fitter.identification.output_error import Recordings
from fitter.identification.refine import Options, effective_samples, refine
from fitter.identification.parametrisation import (
    Parametrisation,
    RDCanonical,
    RICanonical,
    StateSpace,
    WithEffects,
    hurwitz_poly,
    hurwitz_theta,
)

TRUE = np.array([-3.0, 2.5, 1.0, 1.2, 0.3])


class _Five(Parametrisation):
    """First-order RI model with C = 1: theta = [A+, A-, B+, B-, D]."""

    size = 5

    def names(self):
        return ["A_plus", "A_minus", "B_plus", "B_minus", "D"]

    def build(self, th):
        return RateIndependentModel(
            A_plus=[[th[0]]], A_minus=[[th[1]]], B_plus=[th[2]], B_minus=[th[3]], C=[1.0], D=th[4]
        )


def _recording(x0: float, seed: int = 0, cycles: float = 10.0, noise: float = 0.01) -> Recording:
    t = np.linspace(0, 2 * np.pi * cycles, int(600 * cycles) + 1)
    u = np.sin(t)
    y = simulate(_Five().build(TRUE), t, u, x0=[x0]).y
    return Recording(t, u, y + noise * np.random.default_rng(seed).standard_normal(len(t)))


START = np.array([-1.0, 1.0, 0.5, 0.5, 0.0])


def test_fitted_initial_state_recovers_parameters_and_x0():
    res = refine(_Five(), START, Recordings([_recording(0.5)], x0="fit"))
    assert res.success
    assert np.all(np.abs(res.theta - TRUE) < 4 * res.stderr() + 1e-12)
    assert np.all(res.stderr() < 0.02)
    assert abs(res.x0s[0][0] - 0.5) < 0.05
    assert abs(res.sigma - 0.01) < 1e-3


def test_periodic_mode_default_cycles_starts_at_the_first_settled_cycle():
    """The default call (x0="periodic", cycles found by preparation) runs and fits."""
    rec = _recording(0.0, cycles=6.0)
    res = refine(_Five(), START, Recordings([rec]))
    assert res.starts[0] > 0 and len(res.residuals[0]) == len(rec.y) - res.starts[0]
    assert 0 < res.rho[0] < 1
    np.testing.assert_allclose(res.theta, TRUE, atol=0.05)


def test_model_mode_uses_the_models_x0_and_a_wrong_x0_biases_the_fit():
    rec = _recording(0.8, noise=0.0, cycles=2.0)
    res = refine(_Five(), TRUE, Recordings([rec], x0="model"), Options(max_nfev=5))
    assert res.x0s[0][0] == 0.0
    assert res.starts == [0]
    fitted = refine(_Five(), TRUE, Recordings([rec], x0="fit"), Options(max_nfev=5))
    assert fitted.rss < 1e-20 < res.rss


def test_unknown_mode_is_refused():
    with pytest.raises(ValueError, match="x0 must be one of"):
        Recordings([_recording(0.0)], x0="first")


def test_bounds_hold_and_masked_samples_do_not_count():
    rec = _recording(0.0, noise=0.0, cycles=2.0)
    y = rec.y.copy()
    y[100:200] += 5.0
    bad = Recording(rec.t, rec.u, y)
    w = np.ones(len(y))
    w[100:200] = 0
    param = StateSpace(
        _Five().build(TRUE).replace(x0=[0.0]), lower=[-10, 0, -10, -10, -10, -10, -1], upper=[0, 10, 10, 10, 10, 10, 1]
    )
    start = param.theta(_Five().build(START))
    res = refine(param, start, Recordings([bad], x0="model", weights=[w]), Options(normalise=True))
    lo, hi = param.bounds()
    assert np.all(res.theta >= lo) and np.all(res.theta <= hi)
    np.testing.assert_allclose(res.theta[:4], TRUE[:4], atol=1e-5)
    assert len(res.weighted) == len(y) - 100
    assert abs(np.mean(res.residuals[0][100:200]) - 5.0) < 1e-4


def test_free_mask_moves_only_free_parameters():
    rec = _recording(0.0, noise=0.0, cycles=2.0)
    free = np.array([True, True, False, False, False])
    start = np.r_[-1.0, 1.0, TRUE[2:]]
    res = refine(_Five(), start, Recordings([rec], x0="model"), free=free)
    np.testing.assert_array_equal(res.theta[2:], TRUE[2:])
    np.testing.assert_allclose(res.theta[:2], TRUE[:2], atol=1e-6)
    assert np.all(res.jac[:, ~free] == 0)


def test_effective_samples_inflates_the_covariance():
    r = np.cumsum(np.random.default_rng(3).standard_normal(2000)) * 0.01
    n_eff = effective_samples(r)
    assert 2000 * 0.02 / 1.98 - 1e-9 <= n_eff < 200
    res = refine(_Five(), START, Recordings([_recording(0.5)], x0="fit"))
    np.testing.assert_allclose(res.covariance(n_eff=len(res.weighted) / 4), 4 * res.covariance(), rtol=1e-12)


def test_canonical_parametrisations_round_trip():
    ri = RICanonical(2)
    th = np.arange(ri.size) * 0.1 - 0.3
    np.testing.assert_allclose(ri.theta(ri.build(th)), th, atol=1e-12)
    rd = RDCanonical(3, 1.0, np.log([0.5, 1.0, 2.0]))
    th = np.r_[np.log([1.0, 2.0, 1.0]), 0.1 * np.arange(3 * 3 - 2 + 1 + rd.n_c)]
    m = rd.build(th)
    assert np.max(np.linalg.eigvals(m.A).real) < 0
    np.testing.assert_allclose(rd.theta(m, th[-1 - rd.n_c :]), th, atol=1e-10)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_hurwitz_parametrisation_is_onto_the_stable_polynomials_of_any_order(n):
    rng = np.random.default_rng(n)
    for _ in range(50):
        th = rng.normal(size=n)
        p = hurwitz_poly(th)
        lam = np.roots(np.r_[1.0, p[::-1]])
        assert lam.real.max() < 0
        np.testing.assert_allclose(hurwitz_poly(hurwitz_theta(lam)), p, rtol=1e-8)
    rd = RDCanonical(n, 1.0, np.log([0.5, 1.0, 2.0]))
    th = np.r_[rng.normal(size=n), 0.1 * np.arange(2 * n + 2 + rd.n_c)]
    np.testing.assert_allclose(rd.build(rd.theta(rd.build(th), th[-1 - rd.n_c :])).A, rd.build(th).A, atol=1e-9)


def test_with_effects_log_parameters_and_null_model():
    base = StateSpace(_Five().build(TRUE))
    ctx = EffectContext(dt_min=0.01, duration=10.0, u_span=2.0, y_min=-1.0, y_max=1.0, y_mean=0.0, v95=1.0)
    param = WithEffects(base, ["creep"], ctx)
    lo, hi = param.bounds()
    np.testing.assert_allclose([lo[-1], hi[-1]], np.log([0.05 * 0.01, 10.0]))  # [0.05 dt_min, duration]
    theta = np.r_[base.theta(base.template), param.encode([{"k": 0.2, "tau": 0.5}])]
    m = param.build(theta)
    assert m.effects[0].parameters == {"k": 0.2, "tau": pytest.approx(0.5)}
    np.testing.assert_allclose(param.theta(m), theta, atol=1e-12)


def test_a_state_space_base_builds_with_effects_as_the_generic_parametrisation_does():
    """`StateSpace.build_with_effects` (one validation) gives the model of the generic path (build, then
    append the effects), the template's own effect first, and with WithEffects' theta the same model."""
    from fitter.core.effects import Effect
    from fitter.identification.parametrisation import Parametrisation

    template = _Five().build(TRUE).replace(effects=[Effect("backlash", {"b": 0.05})])
    base = StateSpace(template)
    theta = base.theta(template) + 0.01 * np.arange(base.size)
    extra = [Effect("creep", {"k": 0.2, "tau": 0.5})]
    fast = base.build_with_effects(theta, extra)
    generic = Parametrisation.build_with_effects(base, theta, extra)
    assert fast.to_dict() == generic.to_dict()
    assert [e.effect for e in fast.effects] == ["backlash", "creep"] and fast.A_plus[0, 0] == theta[0]
    ctx = EffectContext(dt_min=0.01, duration=10.0, u_span=2.0, y_min=-1.0, y_max=1.0, y_mean=0.0, v95=1.0)
    fam = WithEffects(base, ["creep"], ctx)
    assert fam.build(np.r_[theta, fam.encode([{"k": 0.2, "tau": 0.5}])]).to_dict()["effects"] == [
        e.to_dict() for e in fast.effects
    ]


def test_with_effects_holds_named_parameters_and_refinements():
    """`held` parameters leave theta and are built at their value; ``refinements=False`` holds the
    refinements at their defaults, a held value beside it still wins."""
    base = StateSpace(_Five().build(TRUE))
    ctx = EffectContext(dt_min=0.01, duration=10.0, u_span=2.0, y_min=-1.0, y_max=1.0, y_mean=0.0, v95=1.0)
    free = WithEffects(base, ["creep", "measurement_drift"], ctx)
    held = WithEffects(
        base, ["creep", "measurement_drift"], ctx, held={"creep.tau": 0.25, "measurement_drift.rate": 0.0}
    )
    assert free.size - held.size == 2 and held.names()[-1] == "creep.k"
    m = held.build(np.r_[base.theta(base.template), 0.2])
    assert [e.parameters for e in m.effects] == [{"k": 0.2, "tau": 0.25}, {"rate": 0.0}]
    basic = WithEffects(base, ["switching"], ctx, refinements=False, held={"switching.S2": 0.1})
    assert [n.split(".")[1] for n in basic.names()[base.size :]] == ["S1", "u_up1", "u_dn1", "width1", "q1"]
    built = basic.effect_list(np.zeros(basic.size))[0].parameters
    assert built["S2"] == 0.1 and built["spread1"] == 0.0


@pytest.mark.parametrize("mode", ["fit", "periodic"])
def test_variable_projection_finds_the_linear_parameters_and_matches_the_plain_residuals(mode):
    """Options.eliminate: only A+- move; B+-, E+-, D (and x0) come from linear least squares, so a
    start with wrong linear parameters reaches the truth's A+- and its output (the linear part is
    identifiable only up to D: z = x + D u is a state of the same model), and the projected
    residuals at the optimum are the plain `residuals` of the returned theta."""
    truth = RateIndependentModel(
        A_plus=[[-3.0]], A_minus=[[2.5]], B_plus=[1.0], B_minus=[1.2], C=[1.0], E_plus=[0.2], E_minus=[-0.1], D=0.3
    )
    param = RICanonical(1)
    t = np.linspace(0, 2 * np.pi * 8, 4001)
    u = np.sin(t)
    y = simulate(truth, t, u, x0=[0.7]).y + 0.005 * np.random.default_rng(1).standard_normal(len(t))
    problem = Recordings([Recording(t, u, y)], x0=mode)
    start = param.theta(
        truth.replace(A_plus=[[-1.0]], A_minus=[[1.0]], B_plus=[0.0], B_minus=[0.0], E_plus=[0.0], E_minus=[0.0], D=0.0)
    )
    res = refine(param, start, problem, Options(eliminate=True))
    np.testing.assert_allclose(res.theta[:2], [-3.0, 2.5], atol=0.03)
    assert np.sqrt(np.mean(res.weighted**2)) == pytest.approx(0.005, rel=0.05)
    projected = problem.projected(param, res.theta)[0]
    assert np.abs(projected - res.weighted).max() < 1e-9
    assert res.stderr().shape == (param.size,) and np.all(res.stderr() > 0)


def test_covariance_does_not_depend_on_the_units_of_the_parameters():
    """Two correlated regressors on scales 1e8 apart: the standard errors are the ones of the well-scaled
    problem divided by each column's scale (the pseudo-inverse of the raw J^T J dropped the small column's
    direction, giving it a zero error)."""
    from fitter.identification.refine import RefineResult

    rng = np.random.default_rng(0)
    X = rng.standard_normal((200, 2))
    X[:, 1] += 0.9 * X[:, 0]
    residual = rng.standard_normal(200)
    scale = np.array([1e4, 1e-4])

    def result(J):
        return RefineResult(
            theta=np.zeros(2), model=None, residuals=[residual], weighted=residual, jac=J, nfev=1, success=True
        )

    plain = result(X).stderr()
    assert plain == pytest.approx(np.sqrt(np.diag(np.linalg.inv(X.T @ X))) * result(X).sigma, rel=1e-12)
    assert result(X * scale).stderr() == pytest.approx(plain / scale, rel=1e-9)


# --------------------------------------------------------------------- decimation of long recordings


def _many_short_loops(n: int, segments: int, seed: int = 0) -> tuple[Recording, RateIndependentModel]:
    """An order-2 rate-independent truth driven through `segments` straight runs between random turning points
    (minor loops of every size), `n` samples, output noise 0.2 % of the range."""
    from fitter.diagnosis.synthetic import cell_base

    rng = np.random.default_rng(seed)
    turns = rng.uniform(-1.0, 1.0, segments + 1)
    knots = np.r_[0.0, np.cumsum(np.abs(np.diff(turns)) + 0.02)]
    t = np.linspace(0.0, knots[-1], n)
    u = np.interp(t, knots, turns)
    truth = cell_base(2)
    y = simulate(truth, t, u).y
    return Recording(t, u, y + 0.002 * np.ptp(y) * rng.standard_normal(n)), truth


def test_decimation_keeps_every_turn_and_scores_evenly():
    """The kept samples hold every turning point, so the truth simulated on them alone gives its output at
    those samples exactly (Proposition 1); the scored ones are every k-th sample."""
    from fitter.identification.decimation import keep_indices, turning_points

    rec, truth = _many_short_loops(30_000, 1000)
    keep, scored = keep_indices(rec.u, 3000, None)
    turns = turning_points(rec.u)
    strict_extrema = np.flatnonzero(np.diff(rec.u)[1:] * np.diff(rec.u)[:-1] < 0) + 1  # the input has no flats
    assert len(turns) > 600 and np.array_equal(turns, strict_extrema) and np.isin(turns, keep).all()
    assert np.array_equal(keep[scored][:-1], np.arange(0, 30_000, 10))
    full = simulate(truth, rec.t, rec.u).y[keep]
    np.testing.assert_allclose(simulate(truth, rec.t[keep], rec.u[keep]).y, full, rtol=0, atol=1e-12)


def test_a_long_recording_of_short_loops_fits_as_well_as_its_first_tenth():
    """30 000 samples of 1000 short loops, fitted on at most 3000 samples each: the model fitted to the whole
    recording scores on it within 5 % of the model fitted to its first tenth, and both near the noise (0.2 %).
    Scoring each block's first and extreme samples (decimation by blocks: 3 samples per loop, at its tips)
    fits the whole recording 1.4x worse (0.27 % against 0.20 %)."""
    from fitter.data.metrics import compare
    from fitter.identification.fit import fit_recordings

    rec, _ = _many_short_loops(30_000, 1000)
    head = Recording(rec.t[:3000], rec.u[:3000], rec.y[:3000])
    scores = [compare(rec, fit_recordings([r], kind="ri", order=2).simulate(rec))["nrmse"] for r in (rec, head)]
    assert scores[0] <= 1.05 * scores[1] and scores[1] < 0.0025, scores


def test_a_recording_held_out_of_the_fit_has_its_reference_fitted():
    """Three recordings of one device, each on its instrument's own zero (offsets 2, 0, -3).  With the first
    held out of the fit (weights 0), its output reference is fitted with its x0 like the others' (the second,
    the first with weight, owns the model's reference): the true model predicts it to the noise; before, the
    first kept the model's own reference and its offset of 2 stayed in its residual."""
    recs = [_recording(0.5, seed=k, cycles=2.0) for k in range(3)]
    recs = [Recording(r.t, r.u, r.y + off) for r, off in zip(recs, (2.0, 0.0, -3.0))]
    weights = [np.zeros(len(recs[0].t)), None, None]
    residual = Recordings(recs, x0="fit", weights=weights, references=True).residuals(_Five(), TRUE)[2]
    held = residual[0][2]
    assert np.sqrt(np.mean(held**2)) < 0.012
    plain = Recordings(recs, x0="fit", references=True).residuals(_Five(), TRUE)[2]
    assert np.sqrt(np.mean(plain[0][2] ** 2)) > 0.5  # all weighted: the first owns the reference


@pytest.mark.parametrize("mode", ["fit", "model"])
def test_a_recordings_memo_reuses_the_unchanged_part_and_changes_no_residual(mode, monkeypatch):
    """With additive effects (switching + measurement drift) a finite-difference step moves the base or the
    effects: the recording's memo recomputes only the part that moved (the base's output once per base, the
    effects' terms once per effect setting), and every residual equals the unmemoised one to 1e-12 of the
    output range, whichever part moved and in whichever order the steps come."""
    from fitter.identification import output_error

    base = RateIndependentModel(
        A_plus=[[-3.0]], A_minus=[[-2.5]], B_plus=[1.0], B_minus=[1.2], C=[1.0], D=0.3, x0=[0.1]
    )
    model = base.replace(
        effects=[
            {"effect": "switching", "parameters": {"S1": 0.4, "u_up1": 0.5, "u_dn1": -0.5, "width1": 0.1, "q1": -1.0}},
            {"effect": "measurement_drift", "parameters": {"rate": 0.01}},
        ]
    )
    rec = _recording(0.0, cycles=2.0)
    rec = Recording(rec.t, rec.u, simulate(model, rec.t, rec.u).y + 0.01 * np.sin(3 * rec.t), "r")
    steps = [
        model,
        model.replace(A_plus=[[-3.001]]),
        model.replace(effects=[model.effects[0], {"effect": "measurement_drift", "parameters": {"rate": 0.011}}]),
        model,
        model.replace(D=0.3001),
        model,
    ]
    calls = {"base": 0, "terms": 0}
    plain_base = output_error._affine_output if mode == "fit" else None
    plain_terms = output_error._additive_terms

    def counted(name, fn):
        def run(*args, **kwargs):
            calls[name] += 1
            return fn(*args, **kwargs)

        return run

    if mode == "fit":
        monkeypatch.setattr(output_error, "_affine_output", counted("base", plain_base))
    else:
        monkeypatch.setattr(output_error, "simulate", counted("base", output_error.simulate))
    monkeypatch.setattr(output_error, "_additive_terms", counted("terms", plain_terms))
    memo = {}
    for m in steps:
        kept = output_error.simulate_from(m, rec.t, rec.u, rec.y, mode, None, memo=memo)[2]
        fresh = output_error.simulate_from(m, rec.t, rec.u, rec.y, mode, None, memo=None)[2]
        assert np.max(np.abs(kept - fresh)) < 1e-12 * np.ptp(rec.y)
    # memoised: bases model, A+ step, D step (3); effect settings model, drift step (2); unmemoised: one each
    assert calls == {"base": 3 + len(steps), "terms": 2 + len(steps) * (mode == "fit")}, calls


def test_variable_projection_with_additive_effects_fits_forcing_states_and_references_at_once():
    """A base with switching and a measurement drift (both additive: the output is the base's plus terms of the
    input and time alone) on two recordings, the first from rest, the second a closed loop whose switching
    starts settled, each on its own reference: with A and the effects given, B+-, E+-, both x0 and the second
    recording's reference are eliminated at once.  From forcing vectors far off, the projected residuals are
    the plain `residuals` of the theta it returns (to rounding), that theta is back at the truth's forcing, and
    a model with an effect that is not additive (saturation) has nothing eliminated."""
    base = RateIndependentModel(
        A_plus=[[-3.0]], A_minus=[[3.0]], B_plus=[3.0], B_minus=[-3.0], C=[1.0], E_plus=[-1.5], E_minus=[-1.5]
    )
    effects = {"S1": 0.6, "u_up1": 0.55, "u_dn1": -0.5, "width1": 0.06, "q1": -1.0, "spread1": 0.02}
    effects |= {"S2": 0.05, "u_up2": 0.9, "u_dn2": -0.9, "width2": 0.2, "q2": 0.0, "spread2": 0.01}
    truth = base.replace(effects=[{"effect": "switching", "parameters": effects}])
    recs = []
    for period, cycles, reference in ((2.0, 1.5, 0.0), (20.0, 1.0, 0.3)):
        t = np.linspace(0.0, cycles * period, 301)
        u = np.interp((t / period) % 1.0, [0.0, 0.5, 1.0], [-1.0, 1.0, -1.0])
        recs.append(Recording(t, u, simulate(truth, t, u, x0=[0.2]).y + reference, name=f"T{period:g}"))
    ctx = EffectContext.of([(r.t, r.u, r.y) for r in recs], 0.0)
    fam = WithEffects(StateSpace(base), ["switching", "measurement_drift"], ctx, held={"measurement_drift.rate": 0.0})
    assert sorted(fam.linear_entries().values()) == sorted((f, 0) for f in ("B_plus", "B_minus", "E_plus", "E_minus"))
    problem = Recordings(recs, x0="fit", settle=[False, True])
    drift = {"effect": "measurement_drift", "parameters": {"rate": 0.0}}
    theta = fam.theta(truth.replace(effects=[*truth.effects, drift]))
    lin = list(fam.linear_entries())
    off = theta.copy()
    off[lin] = [0.5, 0.5, 2.0, -2.0]
    weighted, back = problem.projected(fam, off)
    plain = problem.residuals(fam, back)[0]
    assert np.abs(weighted - plain).max() < 1e-9 * np.ptp(recs[1].y)
    assert np.linalg.norm(problem.residuals(fam, off)[0]) > 100 * np.linalg.norm(plain)
    np.testing.assert_allclose(back[lin], theta[lin], rtol=0.02)
    saturated = WithEffects(StateSpace(base), ["switching", "saturation"], ctx)
    assert saturated.linear_entries() == {}


def test_a_value_kept_under_the_compiled_pass_is_not_reused_by_the_numpy_pass(monkeypatch):
    """An effect fit evaluates on the compiled pass and takes its final residuals on numpy's: the residuals of a
    recording whose memo was filled under the compiled pass are those of a fresh memo, to the last digit (they
    were not, by 1e-9 of the range on the piezo triangles, so that a fit's last digits depended on which thetas
    its process had evaluated).  The compiled pass is stood in for by numpy's with its states moved by a relative
    1e-12 (a pass that rounds differently, whatever numba's digits on this machine)."""
    from fitter.core import scans

    def other_rounding(*args):
        return scans.integrate_modal(*args) * (1.0 + 1e-12)

    monkeypatch.setitem(scans._LOADED, "scan", other_rounding)
    model = RateIndependentModel(
        A_plus=[[-3.0, 1.0], [-2.0, -1.0]],
        A_minus=[[-2.5, 0.5], [-1.0, -2.0]],
        B_plus=[1.0, 0.5],
        B_minus=[1.2, -0.3],
        C=[1.0, 0.2],
        D=0.3,
        x0=[0.1, 0.0],
    ).replace(effects=[{"effect": "measurement_drift", "parameters": {"rate": 0.01}}])
    rec = _recording(0.0, cycles=3.0)
    rec = Recording(rec.t, rec.u, simulate(model, rec.t, rec.u).y + 0.01 * np.sin(3 * rec.t), "r")
    fam = StateSpace(model)
    theta = fam.theta(model)
    kept, fresh = Recordings([rec], x0="fit"), Recordings([rec], x0="fit")
    with scans.compiled_scans():
        under_other = kept.residuals(fam, theta)[0]
    assert not np.array_equal(under_other, fresh.residuals(fam, theta)[0])  # the stand-in pass was used
    assert np.array_equal(kept.residuals(fam, theta)[0], fresh.residuals(fam, theta)[0])


def test_jacobians_on_two_processes_give_the_one_process_fit_to_the_last_digit(monkeypatch):
    """The refinement of `test_fitted_initial_state_recovers_parameters_and_x0` with ``DUHEM_WORKERS`` 1 and 2,
    the Jacobians on processes from the first one (`POOL_AFTER_S` 0)."""
    import fitter.workers as workers

    monkeypatch.setattr(workers, "POOL_AFTER_S", 0.0)
    forked, close = [], workers._EvaluationMap.close

    def recorded_close(self):  # per map of evaluations, whether it had forked its processes
        forked.append(bool(self._peers))
        close(self)

    monkeypatch.setattr(workers._EvaluationMap, "close", recorded_close)
    fits = {}
    for processes in ("1", "2"):
        monkeypatch.setenv("DUHEM_WORKERS", processes)
        fits[processes] = refine(_Five(), START, Recordings([_recording(0.5)], x0="fit"))
    assert forked == [True]  # one process maps here; two forked after the first map
    one, two = fits.values()
    assert one.nfev == two.nfev and one.theta.tobytes() == two.theta.tobytes()
    assert np.array_equal(one.jac, two.jac) and np.array_equal(one.weighted, two.weighted)


def test_evaluation_map_is_the_plain_map_and_none_inside_a_worker(monkeypatch):
    import fitter.workers as workers

    monkeypatch.setenv("DUHEM_WORKERS", "2")
    monkeypatch.setattr(workers, "POOL_AFTER_S", 0.0)
    xs = [np.array([float(k), 2.0]) for k in range(5)]
    square = lambda x: x**2  # noqa: E731 (inherited by the fork, never pickled)
    with workers.evaluation_map(square) as mapper:
        first, pooled = mapper(square, iter(xs)), mapper(square, iter(xs))
        assert len(mapper._peers) == 1
    assert mapper._peers == []  # the processes end with the context
    for out in (first, pooled):
        assert [o.tolist() for o in out] == [[k * k, 4.0] for k in range(5)]

    def refused(x):
        if x[0] > 3:
            raise ValueError(f"no simulation at {x[0]:g}")
        return x

    with workers.evaluation_map(refused) as mapper:
        mapper(refused, xs[:2])
        with pytest.raises(ValueError, match="no simulation at 4"):  # evaluated in the second process
            mapper(refused, xs)
        assert [o.tolist() for o in mapper(refused, xs[:4])] == [x.tolist() for x in xs[:4]]  # no answer left over
    monkeypatch.setattr(workers, "_IN_WORKER", True)
    with workers.evaluation_map(square) as mapper:
        assert mapper is None


def test_evaluation_map_takes_the_evaluations_from_the_two_ends(monkeypatch):
    """This process takes xs from the front, the forked one from the back, each the next as it is free: while this
    process's first evaluation waits for the other to have done five of the eight, the other takes them, and the
    indices of each process are a run from its end (fixed halves would give the other four, this process four)."""
    import multiprocessing

    import fitter.workers as workers

    monkeypatch.setenv("DUHEM_WORKERS", "2")
    monkeypatch.setattr(workers, "POOL_AFTER_S", 0.0)
    context = multiprocessing.get_context("fork")
    here, done, five = os.getpid(), context.Value("i", 0), context.Event()

    def who(x):
        if os.getpid() == here:
            five.wait(10)
        else:
            with done.get_lock():
                done.value += 1
                if done.value == 5:
                    five.set()
        return np.array([x[0], os.getpid()])

    xs = [np.array([float(k)]) for k in range(8)]
    with workers.evaluation_map(who) as mapper:
        mapper(lambda x: x, xs[:2])  # here, then forked
        out = mapper(who, xs)
    assert [o[0] for o in out] == list(range(8))
    mine = [bool(o[1] == here) for o in out]
    assert mine == sorted(mine, reverse=True) and 1 <= sum(mine) <= 3


_ORPHAN_DRIVER = """
import os, sys, time
import numpy as np
import fitter.workers as workers
workers.POOL_AFTER_S = 0.0
os.environ["DUHEM_WORKERS"] = "2"
f = lambda x: x * 2
with workers.evaluation_map(f) as mapper:
    mapper(f, [np.ones(2)] * 2)
    mapper(f, [np.ones(2)] * 2)
    os.write(1, f"{mapper._peers[0][0].pid}\\n".encode())
    time.sleep(60)
"""

_ORPHAN_MAP_DRIVER = """
import os, sys, time
os.environ["DUHEM_WORKERS"] = "2"
from fitter.workers import parallel_map
def slow(i):
    os.write(1, f"{os.getpid()}\\n".encode())  # one write: the two workers share the pipe
    time.sleep(60)
parallel_map(slow, [1, 2, 3, 4])
"""


def _left_after_parent_killed(driver_source: str, count: int) -> set[int]:
    """Run `driver_source` in a Python process, read the `count` process ids it writes (a line each, blank lines
    skipped), SIGKILL it, and return those of the ids still running (not zombies) 10 s later; the survivors are
    killed before returning."""
    if not os.path.isdir("/proc"):
        pytest.skip("reads the processes' states from /proc")
    driver = subprocess.Popen([sys.executable, "-c", driver_source], stdout=subprocess.PIPE, text=True)
    lines = (x for x in iter(driver.stdout.readline, "") if x.strip())
    pids = {int(line) for line in itertools.islice(lines, count)}
    assert len(pids) == count, "the driver ended before writing its process ids"
    os.kill(driver.pid, signal.SIGKILL)
    driver.wait()
    for _ in range(100):
        alive = {p for p in pids if os.path.exists(f"/proc/{p}") and open(f"/proc/{p}/stat").read().split()[2] != "Z"}
        if not alive:
            return set()
        time.sleep(0.1)
    for p in alive:
        os.kill(p, signal.SIGKILL)
    return alive


def test_one_blas_thread_limits_every_blas_within_and_looks_the_libraries_up_once():
    from threadpoolctl import threadpool_info

    from fitter import workers

    def blas_threads() -> list[int]:
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    before = blas_threads()
    with workers.one_blas_thread():
        inside = blas_threads()
        controller = workers._BLAS
    with workers.one_blas_thread():
        assert workers._BLAS is controller  # the lookup of the first call, kept
    assert inside and set(inside) == {1}
    assert blas_threads() == before


def test_the_evaluation_processes_end_when_their_parent_is_killed():
    """A fit killed with SIGKILL leaves no evaluation process behind: each watches its parent (`_end_with`); it
    waited forever before on its pipe, whose parent's end it had inherited, holding the fit's stderr open."""
    left = _left_after_parent_killed(_ORPHAN_DRIVER, 1)
    assert not left, f"evaluation process {sorted(left)} outlived its killed parent by 10 s"


def test_the_workers_of_a_map_end_when_their_parent_is_killed():
    """The same for `parallel_map`'s workers (the diagnosis' candidates, an effect fit's starts): they end within a
    second or two of their parent's SIGKILL, mid-item, instead of running the queued items on and waiting."""
    left = _left_after_parent_killed(_ORPHAN_MAP_DRIVER, 2)
    assert not left, f"workers {sorted(left)} outlived their killed parent by 10 s"
