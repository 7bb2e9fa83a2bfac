"""The classical baselines (`fitter.baselines`): each model equals its step-by-step definition (Bouc-Wen: an
ODE solver), recovers data it generated, fits a Duhem loop; bad recordings are refused by name; the Preisach
model reaches the issue's figure on the measured piezo triangles."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
from samples import noisy_recording, sampled_input, sine_input
from scipy.integrate import solve_ivp

from fitter.baselines import BASELINES, BaselineError, BoucWen, Preisach, PrandtlIshlinskii, compare_baselines
from fitter.core import RateIndependentModel
from fitter.core.errors import DuhemError
from fitter.data.recordings import Recording, load_recording
from fitter.identification.fit_data import prepare_for_fit

PIEZO = Path(__file__).resolve().parents[2] / "shared" / "data" / "piezo-pnzt"


def classical_loop_model(k: float = 2.0, d: float = 0.3) -> RateIndependentModel:
    """A first-order Duhem model with a counter-clockwise loop and increasing branches (dy/du > 0).

    dx/du = -k (x - u - (1/k - d)) rising, dx/du = k (x - u + (1/k - d)) falling: the branches
    approach x = u - d and x = u + d; y = x + u/2.
    """
    return RateIndependentModel(
        A_plus=[[-k]],
        A_minus=[[k]],
        B_plus=[k],
        B_minus=[-k],
        C=[1.0],
        E_plus=[1 - k * d],
        E_minus=[1 - k * d],
        D=0.5,
        x0=[0.0],
    )


def _input_only(rec: Recording) -> Recording:
    return Recording(rec.t, rec.u, np.full(len(rec), np.nan), name=rec.name)


def _sampled(y=None, name="sampled") -> Recording:
    t, u = sampled_input(400, seed=3)
    return Recording(t, u, np.sin(3 * u) + 0.1 * t if y is None else y, name=name)


# ---------------------------------------------------------------- the models against their definitions
def _relay_reference(model: Preisach, u_n: np.ndarray, history) -> np.ndarray:
    """Relays stepped one sample at a time from the history (saturation, then m), normalised units."""
    side, m = history
    state = np.full(len(model.alpha_), -1.0 if side == "below" else 1.0)
    out = []
    for x in np.r_[m, u_n]:
        state = np.where(x >= model.alpha_, 1.0, np.where(x <= model.beta_, -1.0, state))
        out.append(model.offset_ + model.slope_ * x + model.orientation_ * model.weights_ @ state)
    return np.array(out[1:])


def _play_reference(model: PrandtlIshlinskii, u_n: np.ndarray, history) -> np.ndarray:
    """Plays stepped one sample at a time, w_k = min(u_k + r, max(u_k - r, w_k-1)), from the history."""
    side, m = history
    w = np.full(len(model.radii_), -np.inf if side == "below" else np.inf)
    out = []
    for x in np.r_[m, u_n]:
        w = np.minimum(x + model.radii_, np.maximum(x - model.radii_, w))
        out.append(model.offset_ + model.slope_ * x + model.orientation_ * model.weights_ @ w)
    return np.array(out[1:])


@pytest.mark.parametrize(
    "cls, reference, history",
    [
        (Preisach, _relay_reference, ("below", 0.35)),
        (Preisach, _relay_reference, ("above", -0.2)),
        (PrandtlIshlinskii, _play_reference, ("below", 0.35)),
        (PrandtlIshlinskii, _play_reference, ("above", -0.2)),
    ],
)
def test_vectorised_relays_and_plays_equal_the_step_by_step_definition(cls, reference, history):
    rec = _sampled()
    model = cls(levels=6).fit(rec)
    assert model.deadband_ == 0.0
    rng = np.random.default_rng(1)
    model.weights_ = rng.exponential(size=len(model.weights_))
    model.histories_ = [history]
    u_n = model.scale_.u(rec.u)
    expected = model.scale_.y_back(reference(model, u_n, history))
    assert np.max(np.abs(model.predict(_input_only(rec)) - expected)) < 1e-12 * np.ptp(expected)


def test_bouc_wen_integration_agrees_with_solve_ivp_and_converges_when_the_step_is_halved():
    t = np.linspace(0, 3, 301)
    u = np.sin(2 * np.pi * t) * (1 - 0.2 * t)
    model = BoucWen()
    for zs, q, n, z0 in ((0.5, 1.0, 2.0, 0.1), (1.0, 0.2, 1.0, -0.8), (0.3, 5.0, 4.3, 2.0)):
        beta, gamma = (1 + q) / (2 * zs**n), (1 - q) / (2 * zs**n)
        z_ref = [z0]
        for a, b in zip(u[:-1], u[1:]):
            s = np.sign(b - a)
            rhs = lambda _, z, s=s: 1 - np.abs(z) ** n * (beta * s * np.sign(z) + gamma)
            z_ref.append(solve_ivp(rhs, (a, b), [z_ref[-1]], method="DOP853", rtol=1e-12, atol=1e-14).y[0, -1])
        states = []
        for step in (0.01, 0.005):
            model.step = step
            model.zs_, model.q_, model.n_ = zs, q, n
            states.append(model.simulate_states(u, z0))
        span = np.ptp(z_ref)
        assert np.max(np.abs(states[0] - states[1])) < 1e-6 * span
        assert np.max(np.abs(states[0] - np.array(z_ref))) < 1e-6 * span


def test_bouc_wen_states_at_kept_samples_do_not_depend_on_the_samples_between_reversals():
    model = BoucWen()
    model.zs_, model.q_, model.n_ = 0.5, 1.0, 3.0
    u = sampled_input(400, seed=3)[1]
    du = np.diff(u)
    turns = np.flatnonzero(du[1:] * du[:-1] < 0) + 1
    keep = np.union1d(np.r_[0, turns, len(u) - 1], np.arange(0, len(u), 7))
    full = model.simulate_states(u, 0.3)
    assert np.max(np.abs(model.simulate_states(u[keep], 0.3) - full[keep])) < 1e-12


# ---------------------------------------------------------------- recovery of their own data
def test_preisach_recovers_data_generated_by_a_preisach_model():
    model = Preisach().fit(_sampled())
    rng = np.random.default_rng(7)
    model.weights_ = rng.exponential(size=300) * (rng.random(300) < 0.3)
    model.offset_, model.slope_ = 0.2, 0.5
    step = (model.edges_[-1] - model.edges_[0]) / model.levels
    model.histories_ = [("below", float(model.scale_.u(_sampled().u[0]) + 3 * step))]
    y = model.predict(_input_only(_sampled()))
    refit = Preisach().fit(_sampled(y))
    assert refit.parameters == 303
    assert refit.score(_sampled(y))["nrmse"] < 1e-6


def test_prandtl_ishlinskii_recovers_data_generated_by_a_pi_model():
    model = PrandtlIshlinskii().fit(_sampled())
    rng = np.random.default_rng(8)
    model.weights_ = rng.exponential(size=23)
    model.offset_, model.slope_ = -0.1, 0.3
    step = (model.edges_[-1] - model.edges_[0]) / model.levels
    model.histories_ = [("above", float(model.scale_.u(_sampled().u[0]) - 2 * step))]
    y = model.predict(_input_only(_sampled()))
    refit = PrandtlIshlinskii().fit(_sampled(y))
    assert refit.parameters == 26
    assert refit.score(_sampled(y))["nrmse"] < 1e-6


def test_a_clockwise_loop_is_fitted_with_the_opposite_orientation():
    model = PrandtlIshlinskii().fit(_sampled())
    model.weights_ = np.random.default_rng(9).exponential(size=23)
    model.orientation_ = -1.0
    model.histories_ = [("below", float(model.scale_.u(_sampled().u[0])))]
    y = model.predict(_input_only(_sampled()))
    refit = PrandtlIshlinskii().fit(_sampled(y))
    assert refit.orientation_ == -1.0
    assert refit.score(_sampled(y))["nrmse"] < 1e-6


def test_bouc_wen_recovers_data_generated_by_a_bouc_wen_model():
    model = BoucWen().fit(_sampled())
    model.zs_, model.q_, model.n_ = 0.6, 1.5, 2.0
    model.k_u_, model.k_z_, model.c_, model.z0_ = 0.3, 1.0, 0.1, [0.2]
    y = model.predict(_input_only(_sampled()))
    refit = BoucWen().fit(_sampled(y))
    assert refit.parameters == 7
    assert refit.score(_sampled(y))["nrmse"] < 1e-3


# ---------------------------------------------------------------- a Duhem loop, the comparison, the contract
@pytest.mark.parametrize("name, limit", [("preisach", 0.012), ("prandtl_ishlinskii", 0.005), ("bouc_wen", 0.001)])
def test_each_baseline_fits_a_duhem_loop_to_a_few_percent(name, limit):
    t, u = sine_input(2.0, 3, 120)
    rec = noisy_recording(classical_loop_model(), t, u, noise=0.0, seed=0, name="duhem loop")
    model = BASELINES[name]().fit([rec])
    assert model.score(rec)["nrmse"] < limit
    assert json.loads(json.dumps(model.to_dict()))["parameters"] == model.parameters


def test_compare_baselines_reports_per_recording_and_one_for_all():
    model = classical_loop_model()
    recs = [
        noisy_recording(model, *sine_input(2.0, 2, 100, 0.0, a), noise=0.005, seed=s, name=f"amp {a}")
        for s, a in ((1, 1.0), (2, 0.6))
    ]
    out = compare_baselines(recs)
    assert set(out) == set(BASELINES)
    for entry in out.values():
        for part in ("per_recording", "one_for_all"):
            assert set(entry[part]) == {"amp 1.0", "amp 0.6"}
            assert all(math.isfinite(v) and 0 < v < 0.05 for v in entry[part].values())
        assert all(s >= 0 for s in entry["cpu_seconds"]["per_recording"].values())
    only = compare_baselines(recs, per_recording=False, names=["prandtl_ishlinskii"])
    assert list(only) == ["prandtl_ishlinskii"] and only["prandtl_ishlinskii"]["per_recording"] is None
    assert only["prandtl_ishlinskii"]["one_for_all"] == out["prandtl_ishlinskii"]["one_for_all"]


@pytest.mark.parametrize(
    "rec, words",
    [
        (Recording(np.arange(50.0), np.full(50, 2.0), np.arange(50.0), name="flat input"), "input is constant"),
        (Recording(np.arange(5.0), np.sin(np.arange(5.0)), np.arange(5.0), name="short"), "too few samples"),
        (Recording(np.arange(50.0), np.arange(50.0), np.sin(np.arange(50.0)), name="ramp"), "never reverses"),
        (
            Recording(np.arange(50.0), np.sin(np.arange(50.0)), np.full(50, 1.0), name="flat output"),
            "output is constant",
        ),
        (
            Recording(np.arange(50.0), np.sin(np.arange(50.0)), np.full(50, np.nan), name="no output"),
            "no output recorded",
        ),
    ],
)
@pytest.mark.parametrize("cls", list(BASELINES.values()))
def test_a_recording_that_cannot_be_fitted_is_named_in_a_duhem_error(cls, rec, words):
    assert issubclass(BaselineError, DuhemError)
    with pytest.raises(BaselineError, match=f"{rec.name}: .*{words}"):
        cls().fit([rec])


@pytest.mark.parametrize("cls", [Preisach, PrandtlIshlinskii])
def test_an_input_outlier_is_refused_as_singular_by_rank_not_by_rounding(cls):
    """One sample at 1e90 leaves every element a spike and a step (rank <= 1): refused; the same
    recording without it is fitted (the rank test's margin is ~1e6 either side of its tolerance)."""
    t, u = sine_input(1.0, 2, 100)
    y = noisy_recording(classical_loop_model(), t, u, noise=0.0, seed=0).y
    spike = np.where(np.arange(len(u)) == 50, 1e90, u)
    with pytest.raises(BaselineError, match="spike: .*least-squares problem is singular"):
        cls().fit([Recording(t, spike, y, name="spike")])
    assert cls().fit([Recording(t, u, y, name="clean")]).parameters > 0


def test_a_recording_the_duhem_preparation_refuses_is_refused_by_name():
    t = np.linspace(0, 1, 60)
    half_loop = Recording(t, np.r_[np.linspace(0, 1, 30), np.linspace(1, 0.5, 30)], t**2, name="half loop")
    with pytest.raises(DuhemError, match="half loop: too few cycles"):
        Preisach().fit([half_loop])


def test_a_noisy_input_runs_through_the_duhem_fits_dead_band():
    t, u = sine_input(2.0, 4, 250)
    u = u + 0.004 * np.random.default_rng(4).standard_normal(len(u))
    rec = noisy_recording(classical_loop_model(), t, u, noise=0.005, seed=5, name="noisy input")
    width = prepare_for_fit([rec]).deadband
    model = PrandtlIshlinskii().fit(rec)
    assert width > 0 and model.deadband_ == width and model.to_dict()["input_deadband"] == width
    assert model.score(rec)["nrmse"] < 0.01
    assert PrandtlIshlinskii(deadband=False).fit(rec).deadband_ == 0.0


def test_misuse_is_a_clear_error():
    with pytest.raises(BaselineError, match="not fitted"):
        Preisach().predict(_sampled())
    with pytest.raises(BaselineError, match="unknown baseline"):
        compare_baselines([_sampled()], names=["hysterion"])
    with pytest.raises(BaselineError, match="distinct"):
        compare_baselines([_sampled(), _sampled()])
    with pytest.raises(BaselineError, match="no recordings"):
        BoucWen().fit([])


# ---------------------------------------------------------------- measured piezo triangles
@pytest.mark.parametrize(
    "stem", ["slow_T06_triangle_1400V_1Hz", "slow_T01_triangle_1400V_0.1Hz", "slow_T02_triangle_1400V_0.01Hz"]
)
def test_preisach_fits_each_measured_piezo_triangle_within_3_percent(stem):
    if not PIEZO.is_dir():
        pytest.skip("shared piezo data absent")
    rec = load_recording(PIEZO / f"{stem}.csv", time="time_s", input="voltage_V", output="polarization_uC_per_cm2")
    assert Preisach().fit([rec]).score(rec)["nrmse"] < 0.03


@pytest.mark.parametrize("name", ["preisach", "prandtl_ishlinskii"])
def test_an_input_that_starts_at_its_minimum_fixes_every_element_at_the_first_sample(name):
    """All relays/plays are determined at the first sample (no free history): still fitted, exactly."""
    t = np.linspace(0.0, 3.0, 301)
    u = -np.cos(2 * np.pi * t)  # starts at its minimum
    rec = noisy_recording(classical_loop_model(), t, u, noise=0.0, seed=0, name="from the minimum")
    model = BASELINES[name]().fit([rec])
    assert model.score(rec)["nrmse"] < 0.06


def test_comparison_scores_the_duhem_model_with_its_initial_state_fitted_per_recording():
    from fitter.baselines import comparison

    model = classical_loop_model()
    recs = [
        noisy_recording(model.replace(x0=[x0]), *sine_input(2.0, 2, 100), noise=0.0, seed=1, name=f"x0 {x0}")
        for x0 in (0.0, 0.5)
    ]
    comp = comparison(model, recs)
    assert list(comp["duhem"]) == ["x0 0.0", "x0 0.5"]
    assert max(comp["duhem"].values()) < 1e-9  # the generating model, each x0 recovered
    assert set(comp["baselines"]) == set(BASELINES)
    assert all(math.isfinite(v) for b in comp["baselines"].values() for v in b["one_for_all"].values())
    assert all(len(b["per_recording"]) == 2 for b in comp["baselines"].values())
