"""Effect extensions: exact discretisations, Stepper == simulate, JSON round trip, bad input."""
import json

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from fitter.core import (KernelError, ModelFileError, RateDependentModel, RateIndependentModel, Stepper,
                         TabulatedRate, load_model, model_from_dict, save_model, simulate)
from fitter.core.effects import EFFECTS, Effect

ALL = {
    "backlash": {"b": 0.1},
    "rate_dependence": {"alpha": 0.3},
    "creep": {"k": 0.05, "tau": 0.7},
    "viscous": {"c": 0.02},
    "thermal_drift": {"kappa": 0.01},
    "saturation": {"y_c": 0.1, "beta": 0.4},
    "sensor_lag": {"tau": 0.05},
}

ZERO = {"backlash": {"b": 0.0}, "rate_dependence": {"alpha": 0.0}, "creep": {"k": 0.0, "tau": 1.0},
        "viscous": {"c": 0.0}, "thermal_drift": {"kappa": 0.0}, "saturation": {"y_c": 0.1, "beta": 0.0},
        "sensor_lag": {"tau": 0.0}}


def ri(effects=()):
    return RateIndependentModel(A_plus=[[-3.0]], A_minus=[[-2.5]], B_plus=[3.0], B_minus=[2.5],
                                C=[1.0], E_plus=[-1.2], E_minus=[1.0], D=0.1,
                                effects=[{"effect": k, "parameters": v} for k, v in effects])


def rd(effects=()):
    return RateDependentModel(A=[[-2.0, 0.3], [0.0, -1.0]], B=[2.0, 1.0], C=[1.0, 0.5], E=[0.1, 0.0],
                              g=TabulatedRate([-2.0, 2.0], [2.0, 2.0]),
                              effects=[{"effect": k, "parameters": v} for k, v in effects])


def signal(n=400, seed=0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.01, 0.03, n)) if n > 100 else np.cumsum(rng.uniform(0.05, 0.1, n))
    u = np.sin(2 * np.pi * 0.4 * t) + 0.3 * np.sin(2 * np.pi * 1.3 * t)
    u[n // 4:n // 3] = u[n // 4]          # a hold
    return t, u


@pytest.mark.parametrize("make", [ri, rd])
def test_stepper_equals_simulate_with_all_effects(make):
    model = make(ALL.items())
    t, u = signal()
    y = simulate(model, t, u).y
    st = Stepper(model, t0=t[0], u0=u[0])
    out = [st.output()]
    for k in range(1, len(t)):
        st.do_step(t[k] - t[k - 1])
        st.set_input(u[k])
        out.append(st.output())
    np.testing.assert_allclose(out, y, rtol=0, atol=1e-12)
    saved = st.get_state()
    st.do_step(0.02)
    st.set_input(0.3)
    first = st.output()
    st.set_state(saved)
    st.do_step(0.02)
    st.set_input(0.3)
    assert st.output() == first


def test_effects_change_output_and_no_effect_is_identity():
    t, u = signal()
    base = simulate(ri(), t, u).y
    for name, params in ALL.items():
        y = simulate(ri([(name, params)]), t, u).y
        assert np.max(np.abs(y - base)) > 1e-3, name
        y0 = simulate(ri([(name, ZERO[name])]), t, u).y
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
        sol = solve_ivp(lambda s, mm: [(yk + (yk1 - yk) * (s - t[k0]) / h - mm[0]) / tau_m],
                        (t[k0], t[k0 + 1]), [m[-1]], rtol=1e-11, atol=1e-13, method="DOP853")
        m.append(sol.y[0, -1])
    return np.array(m)


def test_timed_effects_match_ode_solution():
    model = RateIndependentModel(A_plus=[[-3.0]], A_minus=[[-2.5]], B_plus=[3.0], B_minus=[2.5], C=[1.0],
                                 E_plus=[-1.2], E_minus=[1.0],
                                 effects=[{"effect": "rate_dependence", "parameters": ALL["rate_dependence"]},
                                          {"effect": "creep", "parameters": {"k": 0.05, "tau": 0.7}},
                                          {"effect": "sensor_lag", "parameters": {"tau": 0.05}}])
    t, u = signal(n=60, seed=3)
    ref = _ode_with_creep_lag_rate(([-3.0, -2.5], [3.0, 2.5], [-1.2, 1.0]), t, u)
    np.testing.assert_allclose(simulate(model, t, u).y, ref, atol=1e-8)


def test_play_thermal_saturation_viscous_closed_forms():
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    u = np.array([0.0, 1.0, 0.9, 0.5, 0.6, 1.5])
    lin = RateIndependentModel(A_plus=[[0.0]], A_minus=[[0.0]], B_plus=[0.0], B_minus=[0.0], C=[1.0], D=1.0)
    y = simulate(RateIndependentModel(**{**_params(lin), "effects": [Effect("backlash", {"b": 0.4})]}), t, u).y
    np.testing.assert_allclose(y, [0.0, 0.8, 0.8, 0.7, 0.7, 1.3])
    y = simulate(RateIndependentModel(**{**_params(lin), "effects": [Effect("thermal_drift", {"kappa": 0.1})]}),
                 t, u).y
    travel = np.r_[0, np.cumsum(np.abs(np.diff(u)))]
    np.testing.assert_allclose(y, u * (1 - 0.1 * travel))
    y = simulate(RateIndependentModel(**{**_params(lin), "effects": [Effect("viscous", {"c": 2.0}),
                                                                   Effect("saturation", {"y_c": 0.5,
                                                                                         "beta": 2.0})]}),
                 t, u).y
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
    assert set(EFFECTS) == set(ALL)


@pytest.mark.parametrize("effects, message", [
    ([{"effect": "magic", "parameters": {}}], "unknown effect 'magic'"),
    ([{"effect": "creep", "parameters": {"k": 1.0}}], "parameters must be ['k', 'tau']"),
    ([{"effect": "creep", "parameters": {"k": 1.0, "tau": 0.0}}], "tau = 0.0 must be positive"),
    ([{"effect": "backlash", "parameters": {"b": -1}}], "b = -1.0 must be >= 0"),
    ([{"effect": "viscous", "parameters": {"c": "x"}}], "c is not a number"),
    ([{"effect": "viscous", "parameters": {"c": 1}}] * 2, "listed more than once"),
    ("creep", "must be a list"),
])
def test_bad_effects(effects, message):
    d = ri().to_dict()
    d["effects"] = effects
    with pytest.raises(ModelFileError, match=message.replace("[", r"\[").replace("]", r"\]")):
        model_from_dict(json.loads(json.dumps(d)))


def test_timed_effect_needs_increasing_time():
    with pytest.raises(KernelError, match="time must increase"):
        simulate(ri([("viscous", {"c": 1.0})]), np.array([0.0, 1.0, 1.0]), np.array([0.0, 1.0, 2.0]))
