"""Effect extensions: exact discretisations, Stepper == simulate, JSON round trip, bad input.

The tests parametrised over `REGISTRY` run every registered effect (at its
`EffectSpec.example`), so a new effect is tested without editing this file.
"""

import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from fitter.core import (
    KernelError,
    ModelFileError,
    RateDependentModel,
    RateIndependentModel,
    Stepper,
    TabulatedRate,
    load_model,
    model_from_dict,
    save_model,
    simulate,
)
from fitter.core.effects import ORIGINS, REGISTRY, STAGES, Effect, EffectContext

ALL = {name: dict(spec.example) for name, spec in REGISTRY.items()}

ZERO = {
    "backlash": {"b": 0.0},
    "rate_dependence": {"alpha": 0.0},
    "creep": {"k": 0.0, "tau": 1.0},
    "relaxation": {"k": 0.0, "w2": 0.3, "w3": 2.0, "w4": 0.1, "tau_min": 0.1, "tau_max": 10.0},
    "switching": {
        "S1": 0.0,
        "u_up1": 0.5,
        "u_dn1": -0.5,
        "width1": 0.1,
        "q1": 0.4,
        "S2": 0.0,
        "u_up2": 0.9,
        "u_dn2": -0.7,
        "width2": 0.3,
        "q2": -1.0,
    },
    "viscous": {"c": 0.0},
    "thermal_drift": {"kappa": 0.0},
    "saturation": {"y_c": 0.1, "beta": 0.0},
    "sensor_lag": {"tau": 0.0},
    "measurement_drift": {"rate": 0.0},
}


def ri(effects=()):
    return RateIndependentModel(
        A_plus=[[-3.0]],
        A_minus=[[-2.5]],
        B_plus=[3.0],
        B_minus=[2.5],
        C=[1.0],
        E_plus=[-1.2],
        E_minus=[1.0],
        D=0.1,
        effects=[{"effect": k, "parameters": v} for k, v in effects],
    )


def rd(effects=()):
    return RateDependentModel(
        A=[[-2.0, 0.3], [0.0, -1.0]],
        B=[2.0, 1.0],
        C=[1.0, 0.5],
        E=[0.1, 0.0],
        g=TabulatedRate([-2.0, 2.0], [2.0, 2.0]),
        effects=[{"effect": k, "parameters": v} for k, v in effects],
    )


def signal(n=400, seed=0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.01, 0.03, n)) if n > 100 else np.cumsum(rng.uniform(0.05, 0.1, n))
    u = np.sin(2 * np.pi * 0.4 * t) + 0.3 * np.sin(2 * np.pi * 1.3 * t)
    u[n // 4 : n // 3] = u[n // 4]  # a hold
    return t, u


def stepped(st: Stepper, t, u, keep: int | None = None) -> tuple[list, tuple | None]:
    """Outputs of `st` driven sample by sample (step, then set the next input), and its state at `keep`."""
    out, saved = [st.output()], None
    for k in range(1, len(t)):
        st.do_step(t[k] - t[k - 1])
        st.set_input(u[k])
        out.append(st.output())
        if k == keep:
            saved = st.get_state()
    return out, saved


@pytest.mark.parametrize("make", [ri, rd])
def test_stepper_equals_simulate_with_all_effects(make):
    model = make(ALL.items())
    t, u = signal()
    y = simulate(model, t, u).y
    st = Stepper(model, t0=t[0], u0=u[0])
    out, _ = stepped(st, t, u)
    np.testing.assert_allclose(out, y, rtol=0, atol=1e-12)
    saved = st.get_state()
    st.do_step(0.02)
    st.set_input(0.3)
    first = st.output()
    st.set_state(saved)
    st.do_step(0.02)
    st.set_input(0.3)
    assert st.output() == first


@pytest.mark.parametrize("name", REGISTRY)
def test_effect_changes_output(name):
    t, u = signal()
    base = simulate(ri(), t, u).y
    y = simulate(ri([(name, ALL[name])]), t, u).y
    assert np.max(np.abs(y - base)) > 1e-3, name


def test_no_effect_is_identity():
    t, u = signal()
    base = simulate(ri(), t, u).y
    for name, params in ZERO.items():
        y0 = simulate(ri([(name, params)]), t, u).y
        np.testing.assert_allclose(y0, base, atol=1e-13, err_msg=name)


def _ode_with_creep_lag_rate(model_params, t, u):
    """Reference by solve_ivp: RI order 1, rate_dependence + creep + sensor_lag, input linear in t."""
    a, b, e = model_params
    alpha, k, tau_c, tau_m = ALL["rate_dependence"]["alpha"], 0.05, 0.7, 0.05

    def rhs(s, z, k0):
        v = (u[k0 + 1] - u[k0]) / (t[k0 + 1] - t[k0])
        uu = u[k0] + v * (s - t[k0])
        x, c, m = z
        i = 0 if v >= 0 else 1
        dx = v / (1 + alpha * abs(v)) * (a[i] * x + b[i] * uu + e[i])
        dc = (k * uu - c) / tau_c
        return [dx, dc, 0.0]

    z = np.array([0.0, k * u[0], 0.0])
    ys = [z[0] + z[1]]
    for k0 in range(len(t) - 1):
        sol = solve_ivp(rhs, (t[k0], t[k0 + 1]), z, args=(k0,), rtol=1e-11, atol=1e-13, method="DOP853")
        z = sol.y[:, -1]
        ys.append(z[0] + z[1])
    ys = np.array(ys)
    m = [ys[0]]
    for k0 in range(len(t) - 1):
        yk, yk1 = ys[k0], ys[k0 + 1]
        h = t[k0 + 1] - t[k0]
        sol = solve_ivp(
            lambda s, mm: [(yk + (yk1 - yk) * (s - t[k0]) / h - mm[0]) / tau_m],
            (t[k0], t[k0 + 1]),
            [m[-1]],
            rtol=1e-11,
            atol=1e-13,
            method="DOP853",
        )
        m.append(sol.y[0, -1])
    return np.array(m)


def test_timed_effects_match_ode_solution():
    model = RateIndependentModel(
        A_plus=[[-3.0]],
        A_minus=[[-2.5]],
        B_plus=[3.0],
        B_minus=[2.5],
        C=[1.0],
        E_plus=[-1.2],
        E_minus=[1.0],
        effects=[
            {"effect": "rate_dependence", "parameters": ALL["rate_dependence"]},
            {"effect": "creep", "parameters": {"k": 0.05, "tau": 0.7}},
            {"effect": "sensor_lag", "parameters": {"tau": 0.05}},
        ],
    )
    t, u = signal(n=60, seed=3)
    ref = _ode_with_creep_lag_rate(([-3.0, -2.5], [3.0, 2.5], [-1.2, 1.0]), t, u)
    np.testing.assert_allclose(simulate(model, t, u).y, ref, atol=1e-8)


@pytest.mark.parametrize("width", [0.05, 0.2])
def test_switching_matches_ode_solution(width):
    """`switching` against solve_ivp of ds/dt = k+(u) (S - s) - k-(u) (S + s), u linear between samples: the
    interval formula is exact where one of k+- is negligible (thresholds many widths apart), and follows the
    switched output through holds and after turns (it keeps moving while u is held beyond a threshold)."""
    p = {"S": 0.7, "u_up": 0.45, "u_dn": -0.55, "width": width, "q": -0.6}
    t, u = signal(n=80, seed=5)
    u = 1.1 * u

    def rhs(s, z, k0):
        uu = u[k0] + (u[k0 + 1] - u[k0]) * (s - t[k0]) / (t[k0 + 1] - t[k0])
        kp = math.exp((uu - p["u_up"]) / width)
        km = math.exp((p["u_dn"] - uu) / width)
        return [kp * (p["S"] - z[0]) - km * (p["S"] + z[0])]

    ref = [p["q"] * p["S"]]
    for k0 in range(len(t) - 1):
        sol = solve_ivp(rhs, (t[k0], t[k0 + 1]), [ref[-1]], args=(k0,), rtol=1e-12, atol=1e-14, method="Radau")
        ref.append(sol.y[0, -1])
    base = simulate(ri(), t, u).y
    second = {"S2": 0.0, "u_up2": 0.0, "u_dn2": 0.0, "width2": 1.0, "q2": 0.0}
    y = simulate(ri([("switching", {f"{k}1": v for k, v in p.items()} | second)]), t, u).y
    tol = 1e-8 if width < 0.1 else 5e-4
    np.testing.assert_allclose(y - base, ref, atol=tol)
    assert np.ptp(np.asarray(ref)) > 0.5


def test_switching_stays_finite_when_it_switches_fully_in_every_interval():
    """A width of 1e-3 input ranges over a swing 1000 widths past both thresholds: each interval's switching
    integral is far beyond e^700. The switched output is then S tanh of the log ratio, +-S where one direction
    dominates, at every sample; it used to overflow the recurrence's cumulative decay into NaN."""
    t = np.linspace(0.0, 40.0, 4001)
    u = np.sin(2 * np.pi * t / 4.0)
    p = {
        "S1": 0.7,
        "u_up1": 0.0,
        "u_dn1": 0.0,
        "width1": 1e-3,
        "q1": -1.0,
        "S2": 0.0,
        "u_up2": 0.0,
        "u_dn2": 0.0,
        "width2": 1.0,
        "q2": 0.0,
    }
    s = simulate(ri([("switching", p)]), t, u).y - simulate(ri(), t, u).y
    assert np.isfinite(s).all()
    far = np.abs(u[1:]) > 0.05
    np.testing.assert_allclose(s[1:][far], 0.7 * np.sign(u[1:][far]), atol=1e-12)


def test_switching_spread_is_the_mean_of_shares_at_normal_quantiles():
    """A population with spread 0.2 adds exactly the mean of 16 spread-free populations with thresholds
    u_up + 0.2 z_j, u_dn - 0.2 z_j, z_j the normal quantiles at (j + 1/2) / 16; a model saved without spread
    (spread 0, the default) gets spread 0; the state holds 2 x 16 shares."""
    from statistics import NormalDist

    t, u = signal()
    base = simulate(ri(), t, u).y
    one = {
        "S1": 0.4,
        "u_up1": 0.3,
        "u_dn1": -0.2,
        "width1": 0.05,
        "q1": -1.0,
        "S2": 0.0,
        "u_up2": 0.9,
        "u_dn2": -0.7,
        "width2": 0.3,
        "q2": -1.0,
    }
    spread = simulate(ri([("switching", {**one, "spread1": 0.2})]), t, u).y - base
    shares = [
        simulate(ri([("switching", {**one, "u_up1": 0.3 + 0.2 * z, "u_dn1": -0.2 - 0.2 * z})]), t, u).y - base
        for z in (NormalDist().inv_cdf((j + 0.5) / 16) for j in range(16))
    ]
    np.testing.assert_allclose(spread, np.mean(shares, axis=0), rtol=0, atol=1e-13)
    assert not np.allclose(spread, shares[8], atol=1e-3)
    assert Effect("switching", one).parameters["spread1"] == 0.0
    assert len(REGISTRY["switching"].state) == 32


def test_relaxation_is_four_creeps_on_a_log_grid():
    """relaxation {k, w_i, tau_min, tau_max} adds exactly what four creeps k w_i / sum w with tau_i = 0.2 * 10^i
    add."""
    t, u = signal()
    ks = [0.02, 0.01, 0.05, 0.02]  # k = 0.1, w = ks / ks[0]
    base = simulate(ri(), t, u).y
    relax = simulate(
        ri([("relaxation", {"k": 0.1, "w2": 0.5, "w3": 2.5, "w4": 1.0, "tau_min": 0.2, "tau_max": 200.0})]), t, u
    ).y
    creeps = sum(simulate(ri([("creep", {"k": k, "tau": 0.2 * 10.0**i})]), t, u).y - base for i, k in enumerate(ks))
    np.testing.assert_allclose(relax - base, creeps, rtol=0, atol=1e-13)
    assert np.ptp(relax - base) > 0.01


def test_play_thermal_saturation_viscous_closed_forms():
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    u = np.array([0.0, 1.0, 0.9, 0.5, 0.6, 1.5])
    lin = RateIndependentModel(A_plus=[[0.0]], A_minus=[[0.0]], B_plus=[0.0], B_minus=[0.0], C=[1.0], D=1.0)
    y = simulate(RateIndependentModel(**{**_params(lin), "effects": [Effect("backlash", {"b": 0.4})]}), t, u).y
    np.testing.assert_allclose(y, [0.0, 0.8, 0.8, 0.7, 0.7, 1.3])
    y = simulate(RateIndependentModel(**{**_params(lin), "effects": [Effect("thermal_drift", {"kappa": 0.1})]}), t, u).y
    travel = np.r_[0, np.cumsum(np.abs(np.diff(u)))]
    np.testing.assert_allclose(y, u * (1 - 0.1 * travel))
    y = simulate(
        RateIndependentModel(
            **{
                **_params(lin),
                "effects": [Effect("viscous", {"c": 2.0}), Effect("saturation", {"y_c": 0.5, "beta": 2.0})],
            }
        ),
        t,
        u,
    ).y
    z = u + 2.0 * np.r_[0, np.diff(u)]
    np.testing.assert_allclose(y, 0.5 + np.tanh(2.0 * (z - 0.5)) / 2.0)


def _params(model):
    return {k: getattr(model, k) for k in model.PARAMS}


def test_json_round_trip_and_no_effects_key(tmp_path):
    model = ri(ALL.items())
    save_model(model, tmp_path / "m.json")
    back = load_model(tmp_path / "m.json")
    t, u = signal()
    np.testing.assert_array_equal(simulate(back, t, u).y, simulate(model, t, u).y)
    assert [e.effect for e in back.effects] == list(ALL)
    assert "effects" not in ri().to_dict()
    assert (
        list(REGISTRY)
        == list(ALL)
        == [
            "backlash",
            "rate_dependence",
            "creep",
            "relaxation",
            "switching",
            "viscous",
            "thermal_drift",
            "saturation",
            "sensor_lag",
            "measurement_drift",
        ]
    )


@pytest.mark.parametrize(
    "effects, message",
    [
        ([{"effect": "magic", "parameters": {}}], "unknown effect 'magic'"),
        ([{"effect": "creep", "parameters": {"k": 1.0}}], "parameters must be ['k', 'tau']"),
        ([{"effect": "creep", "parameters": {"k": 1.0, "tau": 0.0}}], "tau = 0.0 must be positive"),
        ([{"effect": "backlash", "parameters": {"b": -1}}], "b = -1.0 must be >= 0"),
        ([{"effect": "viscous", "parameters": {"c": "x"}}], "c is not a number"),
        ([{"effect": "viscous", "parameters": {"c": 1}}] * 2, "listed more than once"),
        ("creep", "key 'effects': expected a list of effects, got str"),
        (
            [{"effect": "creep", "parameters": {"k": 1.0, "tau": 1.0}, "start": {"x": 0.0}}],
            "start must give the state ['c']",
        ),
        (
            [{"effect": "creep", "parameters": {"k": 1.0, "tau": 1.0}, "start": {"c": float("nan")}}],
            "start c = nan must be finite",
        ),
        (
            [
                {"effect": "creep", "parameters": {"k": 1.0, "tau": 1.0}, "start": {"c": 0.1}},
                {"effect": "backlash", "parameters": {"b": 0.1}},
            ],
            "start is given for some effects",
        ),
    ],
)
def test_bad_effects(effects, message):
    d = ri().to_dict()
    d["effects"] = effects
    with pytest.raises(ModelFileError, match=message.replace("[", r"\[").replace("]", r"\]")):
        model_from_dict(json.loads(json.dumps(d)))


@pytest.mark.parametrize("make", [ri, rd])
def test_stored_start_is_the_chain_state_at_the_first_sample(make, tmp_path):
    """`Effect.start` (saved and loaded) starts the chain as the explicit state does; `settled_state` is
    `SETTLE_RUNS` runs from afresh, whatever the model's stored start, and differs from afresh."""
    from fitter.core.effects import SETTLE_RUNS, run_with_effects, settled_state, stored_start, with_start
    from fitter.core.kernel import flows

    model, (t, u) = make(ALL.items()), signal()
    fl = flows(model)
    state = settled_state(model, t, u, model.x0, fl)
    ends = [None]
    for _ in range(SETTLE_RUNS):
        ends.append(run_with_effects(model, t, u, model.x0, fl, ends[-1])[2])
    first = run_with_effects(model, t[:1], u[:1], model.x0, fl)[2]
    steady = [REGISTRY[e].steady for e in ALL for _ in REGISTRY[e].state]
    assert len(state) == len(steady) == sum(len(REGISTRY[e].state) for e in ALL) and not all(steady)
    assert state == tuple(a if keep else b for a, b, keep in zip(ends[-1], first, steady))
    without_lag = make([(k, v) for k, v in ALL.items() if not REGISTRY[k].follows_output])
    ends = [None]
    for _ in range(SETTLE_RUNS):
        ends.append(run_with_effects(without_lag, t, u, without_lag.x0, fl, ends[-1])[2])
    first = run_with_effects(without_lag, t[:1], u[:1], without_lag.x0, fl)[2]
    steady = [REGISTRY[e].steady for e in ALL if not REGISTRY[e].follows_output for _ in REGISTRY[e].state]
    np.testing.assert_allclose(
        settled_state(without_lag, t, u, without_lag.x0, fl),
        [a if keep else b for a, b, keep in zip(ends[-1], first, steady)],
        rtol=1e-13,
    )
    started = with_start(model, state)
    assert stored_start(started) == state and stored_start(model) is None
    save_model(started, tmp_path / "m.json")
    back = load_model(tmp_path / "m.json")
    np.testing.assert_array_equal(simulate(back, t, u).y, simulate(model, t, u, effect_state=state).y)
    assert np.abs(simulate(back, t, u).y - simulate(model, t, u).y).max() > 1e-3
    assert settled_state(back, t, u, model.x0, fl) == state
    assert stored_start(with_start(back, None)) is None


@pytest.mark.parametrize("name", [name for name, spec in REGISTRY.items() if not spec.steady])
def test_an_accumulating_effects_afresh_start_is_the_chains_at_the_first_sample(name):
    """`EffectSpec.afresh` (what `settled_state` takes instead of a one-sample run of the chain) is, bit for bit,
    the state the chain run on the first sample gives that effect, behind a memory effect and a sensor lag, at
    parameters of either sign; every effect of the catalogue that does not settle has one."""
    from fitter.core.effects import fresh_state
    from fitter.core.kernel import flows

    t, u = signal()
    spec = REGISTRY[name]
    for scale in (1.0, -3.0, 0.0):
        params = {k: scale * v for k, v in ALL[name].items()}
        model = ri([("creep", ALL["creep"]), ("sensor_lag", ALL["sensor_lag"]), (name, params)])
        before = sum(
            len(REGISTRY[e.effect].state)
            for e in model.effects
            if list(REGISTRY).index(e.effect) < list(REGISTRY).index(name)
        )
        state = fresh_state(model, t + 0.37, u, model.x0, flows(model))[before : before + len(spec.state)]
        assert spec.afresh(params) is not None
        assert np.array(spec.afresh(params)).tobytes() == np.array(state).tobytes()


@pytest.mark.parametrize("spread, width", [(0.0, 0.1), (0.03, 0.1), (0.02, 0.004)])
def test_switching_settles_in_closed_form_as_its_runs_do(spread, width):
    """`Switching.settle` (each share's affine map over the run) is the state after `SETTLE_RUNS` runs of the
    chain, with spread shares and with intervals that switch fully (a narrow width: the decay cap)."""
    from fitter.core.effects import SETTLE_RUNS, run_with_effects, settled_state, with_start
    from fitter.core.effects.switching import switching_rates
    from fitter.core.kernel import flows

    parameters = dict(REGISTRY["switching"].example, spread1=spread, width1=width, S2=0.1, spread2=spread / 2)
    model = ri([("switching", parameters), ("measurement_drift", {"rate": 0.1})])
    t = np.linspace(0.0, 3.0, 301)
    u = 1.2 * np.sin(2 * np.pi * t / 3)
    fl, ends = flows(model), None
    for _ in range(SETTLE_RUNS):
        ends = run_with_effects(with_start(model, None), t, u, model.x0, fl, ends, base=False)[2]
    settled = settled_state(model, t, u, model.x0, fl)
    np.testing.assert_allclose(settled[:-1], ends[:-1], rtol=0, atol=1e-12)
    assert settled[-1] == 0.0  # the drift starts afresh
    assert (np.ptp(settled[:16]) > 1e-5) == (spread > 0 and width > 0.01)  # spread shares settle apart
    total, _ = switching_rates(u, np.diff(t), 0.3, 0.5, -0.5, width)
    assert (total.max() == 40.0) == (width < 0.01)


@pytest.mark.parametrize("name", [name for name, spec in REGISTRY.items() if spec.additive])
@pytest.mark.parametrize("make", [ri, rd])
def test_additive_effects_keep_the_output_affine_in_x0_with_the_base_coefficients(name, make):
    """`EffectSpec.additive`: y(x0) - y(0) with the effect equals it without (what `fitted_initial_state`
    relies on), while the effect itself changes y."""
    t, u = signal()
    with_effect, bare = make([(name, ALL[name])]), make()
    x0 = np.full(bare.order, 0.7)
    shift = simulate(with_effect, t, u, x0=x0).y - simulate(with_effect, t, u, x0=0 * x0).y
    np.testing.assert_allclose(shift, simulate(bare, t, u, x0=x0).y - simulate(bare, t, u, x0=0 * x0).y, atol=1e-12)
    assert np.abs(simulate(with_effect, t, u).y - simulate(bare, t, u).y).max() > 1e-3
    assert REGISTRY[name].stage == "output"


@pytest.mark.parametrize("name", [name for name, spec in REGISTRY.items() if spec.offset])
@pytest.mark.parametrize("make", [ri, rd])
def test_reference_state_raises_every_sample_and_is_fitted_with_x0(name, make):
    """`EffectSpec.offset`: raising that state's start by 2.5 raises the output by 2.5 at every sample, with
    a memory effect and a sensor lag ahead of it in the chain; `fitted_initial_state` recovers x0 and the
    reference from exact data (a column of ones beside the base's x0 columns)."""
    from fitter.core.effects import fresh_state, offset_position, shifted
    from fitter.core.kernel import flows
    from fitter.identification.output_error import fitted_initial_state

    t, u = signal()
    model = make([(n, ALL[n]) for n in ("creep", "sensor_lag", name)])
    x0 = np.full(model.order, 0.3)
    start = fresh_state(model, t, u, x0, flows(model))
    raised = shifted(start, offset_position(model), 2.5)
    y = simulate(model, t, u, x0=x0, effect_state=raised).y
    np.testing.assert_allclose(y - simulate(model, t, u, x0=x0, effect_state=start).y, 2.5, atol=1e-12)
    fitted_x0, y_hat, state = fitted_initial_state(model, t, u, y)
    np.testing.assert_allclose(fitted_x0, x0, atol=1e-8)
    np.testing.assert_allclose(state, raised, atol=1e-8)
    np.testing.assert_allclose(y_hat, y, atol=1e-8)
    assert offset_position(make([(n, ALL[n]) for n in ("creep", "sensor_lag")])) is None


def test_timed_effect_needs_increasing_time():
    with pytest.raises(KernelError, match="time must increase"):
        simulate(ri([("viscous", {"c": 1.0})]), np.array([0.0, 1.0, 1.0]), np.array([0.0, 1.0, 2.0]))


# --------------------------------------------------------------------- the registry, effect by effect


def context(model, t, u) -> EffectContext:
    """The diagnosis' `EffectContext` of one recording (t, u) and the model's output."""
    y = simulate(model, t, u).y
    v95 = float(np.percentile(np.abs(np.diff(u) / np.diff(t)), 95)) or 1.0
    return EffectContext(
        dt_min=float(np.median(np.diff(t))),
        duration=float(np.ptp(t)),
        u_span=float(np.ptp(u)),
        y_min=float(y.min()),
        y_max=float(y.max()),
        y_mean=float(np.mean(y)),
        v95=v95,
    )


def test_registry_is_in_stage_order_and_well_formed():
    stages = [STAGES.index(spec.stage) for spec in REGISTRY.values()]
    assert stages == sorted(stages)
    for name, spec in REGISTRY.items():
        assert spec.name == name and spec.description and "\n" not in spec.description
        names = [par.name for par in spec.parameters]
        assert len(set(names)) == len(names) and list(spec.example) == names
        assert isinstance(spec.state, tuple) and isinstance(spec.timed, bool)
        assert spec.origin in ORIGINS
    assert [n for n, spec in REGISTRY.items() if spec.origin == "measurement"] == ["sensor_lag", "measurement_drift"]


def _outside(par) -> list[float]:
    """Values just outside a parameter's allowed range, and non-finite ones."""
    values = [math.nan, math.inf, -math.inf]
    if par.lower > -math.inf:
        values.append(par.lower if par.strict else par.lower - 1e-9 * max(1.0, abs(par.lower)))
    if par.upper < math.inf:
        values.append(par.upper + 1e-9 * max(1.0, abs(par.upper)))
    return values


@pytest.mark.parametrize("name", REGISTRY)
def test_parameter_ranges_are_validated(name):
    spec = REGISTRY[name]
    assert Effect(name, dict(spec.example)).parameters == spec.example
    for par in spec.parameters:
        if par.lower > -math.inf and not par.strict:
            Effect(name, {**spec.example, par.name: par.lower})
        for value in _outside(par):
            d = ri().to_dict()
            d["effects"] = [{"effect": name, "parameters": {**spec.example, par.name: value}}]
            with pytest.raises(ModelFileError, match=f"parameter {par.name} = .* must be {par.rule()}"):
                model_from_dict(d)
            assert not par.allows(value)


@pytest.mark.parametrize("name", REGISTRY)
def test_null_is_the_base_model(name):
    t, u = signal()
    base = simulate(ri(), t, u).y
    spec = REGISTRY[name]
    null = spec.null(context(ri(), t, u))
    y = simulate(ri([(name, null)]), t, u).y
    if name == "sensor_lag":
        # the null lag tau > 0 (its log must exist) is not exact: the lag e = y - m of a
        # first-order filter started at e = 0 obeys |e| <= tau max|dy/dt|
        bound = null["tau"] * np.max(np.abs(np.diff(base) / np.diff(t)))
        assert 0 < np.max(np.abs(y - base)) <= bound * (1 + 1e-9)
    else:
        np.testing.assert_allclose(y, base, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", REGISTRY)
def test_starts_and_null_within_bounds(name):
    t, u = signal()
    spec = REGISTRY[name]
    ctx = context(ri(), t, u)
    bounds = spec.bounds(ctx)
    names = [par.name for par in spec.parameters]
    assert list(bounds) == names
    starts = spec.starts(ctx)
    assert starts
    for point in starts + [spec.null(ctx)]:
        assert list(point) == names
        for par in spec.parameters:
            lo, hi = bounds[par.name]
            assert lo <= point[par.name] <= hi, (par.name, point, bounds)
            if par.log:
                assert 0 < lo < hi < math.inf
        Effect(name, point)


def test_context_values_reproduce_the_diagnosis():
    ctx = EffectContext(dt_min=0.01, duration=100.0, u_span=2.0, y_min=-1.0, y_max=3.0, y_mean=0.5, v95=4.0)
    taus = np.geomspace(0.03, 10.0, 4)
    assert REGISTRY["creep"].starts(ctx) == [{"k": 0.0, "tau": tau} for tau in taus]
    assert REGISTRY["sensor_lag"].starts(ctx) == [{"tau": tau} for tau in taus[:3]]
    assert REGISTRY["backlash"].starts(ctx) == [{"b": 0.02}, {"b": 0.1}]
    assert REGISTRY["rate_dependence"].starts(ctx) == [{"alpha": 0.0125}, {"alpha": 0.125}]
    assert REGISTRY["saturation"].starts(ctx) == [{"y_c": 0.5, "beta": 0.25}, {"y_c": 0.5, "beta": 0.75}]
    assert REGISTRY["viscous"].starts(ctx) == [{"c": 0.0}]
    assert REGISTRY["creep"].null(ctx) == {"k": 0.0, "tau": 0.1}
    assert REGISTRY["saturation"].null(ctx) == {"y_c": 0.5, "beta": 0.0}
    assert REGISTRY["sensor_lag"].null(ctx) == {"tau": math.exp(math.log(0.0005) + 1e-6)}
    assert REGISTRY["thermal_drift"].null(ctx) == {"kappa": 0.0}
    assert REGISTRY["creep"].bounds(ctx) == {"k": (-math.inf, math.inf), "tau": (0.0005, 100.0)}
    assert REGISTRY["saturation"].bounds(ctx) == {"y_c": (-1.0, 3.0), "beta": (0.0, math.inf)}
    assert REGISTRY["backlash"].bounds(ctx) == {"b": (0.0, math.inf)}
    short = EffectContext(dt_min=0.5, duration=2.0, u_span=1.0, y_min=0.0, y_max=0.0, y_mean=0.0, v95=1.0)
    assert REGISTRY["sensor_lag"].bounds(short) == {"tau": (0.025, 5.0)}
    assert REGISTRY["creep"].starts(short)[-1]["tau"] == pytest.approx(5.0)
    assert REGISTRY["saturation"].starts(short)[0]["beta"] == 0.5 / (1e-300 / 2)


@pytest.mark.parametrize("name", REGISTRY)
@pytest.mark.parametrize("make", [ri, rd])
def test_serialisation_round_trip_and_stepper(name, make, tmp_path):
    model = make([(name, ALL[name])])
    save_model(model, tmp_path / "m.json")
    back = load_model(tmp_path / "m.json")
    assert back.to_dict() == model.to_dict()
    assert json.loads(json.dumps(model.to_dict()))["effects"] == [{"effect": name, "parameters": ALL[name]}]
    t, u = signal(n=150, seed=2)
    y = simulate(model, t, u).y
    np.testing.assert_array_equal(simulate(back, t, u).y, y)
    st = Stepper(back, t0=t[0], u0=u[0])
    out, saved = stepped(st, t, u, keep=60)
    assert len(saved[-2]) == len(REGISTRY[name].state)  # (..., s_a, du)
    np.testing.assert_allclose(out, y, rtol=0, atol=1e-12)
    st.set_state(json.loads(json.dumps([list(v) if isinstance(v, (tuple, np.ndarray)) else v for v in saved])))
    assert st.output() == out[60]


@pytest.mark.parametrize("name", [n for n, spec in REGISTRY.items() if spec.timed])
def test_timed_effects_need_increasing_time(name):
    with pytest.raises(KernelError, match="time must increase: t\\[2\\] = 1.0 after t\\[1\\] = 1.0"):
        simulate(ri([(name, ALL[name])]), np.array([0.0, 1.0, 1.0]), np.array([0.0, 1.0, 2.0]))


def test_measurement_drift_adds_a_line_in_time_and_carries_it_across_steps():
    t, u = signal()
    base = simulate(ri(), t, u).y
    y = simulate(ri([("measurement_drift", {"rate": -0.3})]), t, u).y
    np.testing.assert_allclose(y - base, -0.3 * (t - t[0]), rtol=0, atol=1e-12)
    st = Stepper(ri([("measurement_drift", {"rate": -0.3})]), t0=t[0], u0=u[0])
    out, saved = stepped(st, t, u, keep=200)
    assert saved[-2] == (pytest.approx(-0.3 * (t[199] - t[0]), abs=1e-12),)  # at the anchor, t[199]


def test_switching_runs_kept_are_what_computing_again_gives(monkeypatch):
    """A population's run kept (`switching._RUNS`: rates, states from each start, period map) is, to the last
    digit, what computing it afresh gives, whichever runs were asked in between (more than are kept); its arrays
    are read-only."""
    import fitter.core.effects.switching as sw

    t = np.linspace(0.0, 3.0, 301)
    u, h = 1.2 * np.sin(2 * np.pi * t / 3), np.diff(t)
    asks = [(0.3, 0.5 + d, dn, 0.1, s0) for d in np.linspace(0.0, 0.2, 20) for dn in (-0.5, -0.6) for s0 in (-0.3, 0.2)]
    asks = asks + asks[::-1] + asks[::3]

    def run_of(S, up, dn, width, s0):
        states = sw.switching_states(u, h, S, up, dn, width, s0)
        return (states, *sw.switching_rates(u, h, S, up, dn, width), *sw._period_map(sw._run(u, h, S, up, dn, width)))

    kept = [run_of(*a) for a in asks]
    assert len({a[1:3] for a in asks}) > sw._RUNS_KEPT == len(sw._RUNS)
    monkeypatch.setattr(sw, "_RUNS_KEPT", 0)
    sw._RUNS.clear()
    for got, again in zip(kept, [run_of(*a) for a in asks]):
        for x, y in zip(got, again):
            np.testing.assert_array_equal(x, y)
    assert not sw._RUNS
    assert not kept[0][0].flags.writeable and not kept[0][1].flags.writeable
