"""The simulation kernel against scipy's solve_ivp, the stepper against the kernel."""

import json

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from fitter.core import (
    ConvergenceError,
    KernelError,
    ModelFileError,
    RateDependentModel,
    RateIndependentModel,
    Stepper,
    TabulatedRate,
    convergence_rho,
    limiting_loop,
    load_model,
    model_from_dict,
    periodic_response,
    save_model,
    simulate,
)
from fitter.core.kernel import AffineFlow, expm

A1 = np.array([[-1.0, 4.0], [-4.0, -1.0]])
B1 = np.array([0.0, 1.0])


def example1_model():
    return RateIndependentModel(A_plus=A1, A_minus=-A1, B_plus=B1, B_minus=-B1, C=[0, 1], x0=[0.15, 0.15])


def g3(v):
    v = np.asarray(v, dtype=float)
    return np.where(v >= 0, (v / 3 - 1) ** 3 + 1, 1 - np.exp(v))


def example3_model():
    return RateDependentModel(A=[[0, 1], [-3, -1]], B=[1, 0], C=[1, 1], g=g3, x0=[0.1, -0.2])


def piecewise_linear(t, u):
    def at(tt):
        k = min(max(np.searchsorted(t, tt, "right") - 1, 0), len(t) - 2)
        v = (u[k + 1] - u[k]) / (t[k + 1] - t[k])
        return u[k] + v * (tt - t[k]), v

    return at


def reference(model, t, u):
    at = piecewise_linear(t, u)

    def rhs(tt, x):
        uu, v = at(tt)
        if model.kind == "ri":
            Ap, Am = model.A_plus, model.A_minus
            return max(v, 0) * (Ap @ x + model.B_plus * uu + model.E_plus) + min(v, 0) * (
                Am @ x + model.B_minus * uu + model.E_minus
            )
        return float(model.g(np.array(v))) * (model.A @ x + model.B * uu + model.E)

    sol = solve_ivp(
        rhs,
        (t[0], t[-1]),
        model.x0,
        t_eval=t,
        rtol=1e-12,
        atol=1e-14,
        max_step=float(np.min(np.diff(t))) / 2,
        method="DOP853",
    )
    return sol.y.T


def stepped(model, t, u) -> tuple[np.ndarray, Stepper]:
    """Outputs of a Stepper driven sample by sample (step, set the next input, read y), and the Stepper."""
    st = Stepper(model, t0=t[0], u0=u[0])
    ys = []
    for k in range(len(t)):
        if k:
            st.do_step(t[k] - t[k - 1])
        st.set_input(u[k])
        ys.append(st.output())
    return np.array(ys), st


@pytest.mark.parametrize("make", [example1_model, example3_model])
def test_kernel_matches_solve_ivp(make):
    model = make()
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.02, 0.08, 300))
    u = np.sin(1.3 * t) + 0.3 * np.sin(3.1 * t) + 0.05 * rng.standard_normal(300)
    x = simulate(model, t, u).x
    assert np.abs(x - reference(model, t, u)).max() < 1e-9


def test_rate_independent_ignores_timing():
    model = example1_model()
    u = np.sin(np.linspace(0, 12, 400))
    y1 = simulate(model, np.linspace(0, 1, 400), u).y
    y2 = simulate(model, np.cumsum(np.random.default_rng(1).uniform(0.1, 5, 400)), u).y
    assert np.abs(y1 - y2).max() < 1e-13


def test_defective_matrix_uses_fallback_and_is_exact():
    A = np.array([[-2.0, 1.0], [0.0, -2.0]])
    flow = AffineFlow(A, np.array([0.3, 1.0]), np.array([0.1, 0.0]))
    assert not flow.modal
    x = flow.run(np.array([1.0, -1.0]), np.array([0.5, 0.7]), np.array([1.0, 1.0]), np.array([0.2, 0.3]))
    ref = AffineFlow(A + np.diag([0, 1e-3]), flow.B, flow.E)  # near-defective still modal
    assert ref.modal
    x_ref = ref.run(np.array([1.0, -1.0]), np.array([0.5, 0.7]), np.array([1.0, 1.0]), np.array([0.2, 0.3]))
    assert np.abs(x - x_ref).max() < 1e-3
    assert np.abs(expm(A) - np.exp(-2) * np.array([[1, 1], [0, 1]])).max() < 1e-14


def test_long_run_no_overflow():
    model = RateIndependentModel(A_plus=[[-50.0]], A_minus=[[50.0]], B_plus=[50.0], B_minus=[-50.0], C=[1.0])
    u = np.sin(np.linspace(0, 2000, 200001))
    y = simulate(model, None, u).y
    assert np.all(np.isfinite(y))
    assert abs(y[-1] - u[-1]) < 0.05


def test_periodic_response_and_condition_5():
    model = example1_model()
    grid, yr, yf, rho = limiting_loop(model, -1, 1, 401)
    assert rho == pytest.approx(convergence_rho(model, -1, 1), rel=1e-10)
    assert rho == pytest.approx(np.exp(-4), rel=1e-9)  # eig(A+)=-1±4i, eig(-A-)... beta=2
    # the limiting loop is a fixed point: one more period from its end changes nothing
    t = np.arange(801.0)
    u = np.r_[grid, grid[-2::-1]]
    pr = periodic_response(model, t, u)
    again = simulate(model, t, u, x0=pr.sim.x[-1])
    assert np.abs(again.y - pr.sim.y).max() < 1e-12
    assert yr[-1] == pytest.approx(yf[-1]) and yr[0] == pytest.approx(yf[0])


def test_divergent_model_is_reported():
    model = RateIndependentModel(A_plus=[[0.5]], A_minus=[[-0.5]], B_plus=[1], B_minus=[1], C=[1])
    with pytest.raises(ConvergenceError, match=">= 1"):
        limiting_loop(model, -1, 1)


def test_stepper_equals_simulate():
    for model in (example1_model(), example3_model()):
        t = np.linspace(0, 10, 501)
        u = np.sin(t) + 0.2 * np.cos(2.7 * t)
        ref = simulate(model, t, u).y
        ys, _ = stepped(model, t, u)
        assert np.abs(ys - ref).max() < 1e-12


def test_json_round_trip(tmp_path):
    m = example3_model()
    m = m.replace(g=TabulatedRate.from_function(g3, [-3, -1, -0.5, 0.25, 1, 2, 4]))
    path = tmp_path / "m.json"
    save_model(m, path)
    m2 = load_model(path)
    t = np.linspace(0, 10, 300)
    assert np.array_equal(simulate(m, t, np.sin(t)).y, simulate(m2, t, np.sin(t)).y)
    m1 = example1_model()
    save_model(m1, path)
    assert np.array_equal(load_model(path).A_minus, m1.A_minus)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda d: d.update(schema_version=99), "unknown schema_version 99"),
        (lambda d: d["parameters"].pop("C"), r"key 'parameters.C' is missing \(a 'ri' model has A_plus, "),
        (
            lambda d: d["parameters"].update(A_plus=[[1, 2, 3]]),
            r"key 'parameters.A_plus': expected a 2x2 matrix of numbers, got a 1x3 matrix$",
        ),
        (
            lambda d: d["parameters"].update(A_plus=[[1, 2], [3]]),
            r"key 'parameters.A_plus': expected a 2x2 matrix of numbers, got a ragged list$",
        ),
        (
            lambda d: d["parameters"].update(B_minus=[1, "2"]),
            r"key 'parameters.B_minus': expected a list of 2 numbers, got a list containing the string '2'$",
        ),
        (lambda d: d["parameters"].update(D=None), r"key 'parameters.D': expected a finite number, got null$"),
        (
            lambda d: d["parameters"].update(x0=[True, 1]),
            r"key 'parameters.x0': expected .*, got a list containing true$",
        ),
        (lambda d: d["parameters"].update(A=[[1]]), r"key 'parameters.A': not a parameter of a 'ri' model"),
        (lambda d: d.update(kind="xx"), r"key 'kind': expected 'ri' or 'rd', got the string 'xx'$"),
        (lambda d: d.update(order=3), r"key 'order': expected 2 \(the length of parameters.C\), got 3$"),
        (lambda d: d.update(effect=[]), r"key 'effect': not a key of a 'ri' model file"),
        (lambda d: d.update(fit_info=[1]), r"key 'fit_info': expected an object, got a list of 1 number$"),
        (lambda d: d.update(input_range=[1.0, -1.0]), r"key 'input_range': expected \[lo, hi\] .*, got \[1, -1\]$"),
        (lambda d: d.update(input_range="wide"), r"key 'input_range': expected \[lo, hi\] .*, got the string 'wide'$"),
        (
            lambda d: d.update(signals={"input": {"nom": "u"}}),
            r"key 'signals.input': expected an object with keys 'name' "
            r"\(required\), 'unit' and 'description', got an object "
            r"with keys 'nom'$",
        ),
        (lambda d: d.update(signals={"input": {"name": 3}}), r"key 'signals.input.name': expected a string, got 3$"),
        (lambda d: d.update(signals=[1, 2]), r"key 'signals': expected an object with keys"),
        (
            lambda d: d.update(experiment={"start_time": 0, "stop_time": "x", "step_size": 0.1}),
            r"key 'experiment.stop_time': expected a finite number, got the string 'x'$",
        ),
        (lambda d: d.update(experiment={"start": 0}), r"key 'experiment': expected an object with keys"),
        (
            lambda d: d.update(experiment={"start_time": 2.0, "stop_time": 1.0, "step_size": 0.1}),
            r"key 'experiment': expected start_time < stop_time and step_size > 0, got 2, 1, 0.1$",
        ),
    ],
)
def test_bad_model_files(tmp_path, edit, message):
    d = example1_model().to_dict()
    edit(d)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ModelFileError, match=message) as info:
        load_model(path)
    assert str(info.value).startswith(f"{path}: ")


@pytest.mark.parametrize(
    "g, message",
    [
        (None, r"key 'g' is missing \(expected an object \{\"type\": \"table\""),
        (
            {"type": "spline", "v": [1], "g": [1]},
            r"key 'g': expected an object .*, got an object with keys 'type', 'v', 'g'$",
        ),
        (
            {"type": "table", "v": [1, "x"], "g": [1, 2]},
            r"key 'g.v': expected a list of numbers, got a list containing "
            r"the string 'x'$",
        ),
        ({"type": "table", "v": [1, 1], "g": [1, 2]}, r"key 'g': rate table: duplicate slopes in v$"),
    ],
)
def test_bad_rate_tables(g, message):
    d = example3_model().replace(g=TabulatedRate.from_function(g3, [-1, 1])).to_dict()
    d["g"] = g
    with pytest.raises(ModelFileError, match=message):
        model_from_dict(json.loads(json.dumps(d)), source="m.json")


def test_callable_g_cannot_be_saved(tmp_path):
    with pytest.raises(TypeError, match="tabulate"):
        save_model(example3_model(), tmp_path / "x.json")
    assert not list(tmp_path.iterdir())


def test_bad_signals():
    with pytest.raises(KernelError, match=r"u\[2\] is nan"):
        simulate(example1_model(), None, [0, 1, np.nan])
    with pytest.raises(KernelError, match="time must increase"):
        simulate(example3_model(), [0, 1, 1], [0, 1, 0])


def test_tabulated_rate_rule():
    g = TabulatedRate([-1, 0.5, 1, 2], [-0.8, 0.4, 0.9, 1.0])
    v = np.array([0.0, 0.5, 1.0, 5.0, -1.0, -7.0])
    assert np.allclose(g(v), [0, 0.4, 0.9, 1.0, -0.8, -0.8])
    fine = g(np.linspace(0, 2, 201))
    assert np.all(np.diff(fine) >= -1e-15)  # monotone data stays monotone


def _stepwise(model, t, u, x0):
    """Reference: one `AffineFlow.step` per interval (what the stepper and the native FMU do)."""
    from fitter.core.kernel import flows, interval_coefficients

    fl = flows(model)
    branch, p, r, S = interval_coefficients(model, t, u)
    X = [np.asarray(x0, dtype=float)]
    for k in range(len(S)):
        X.append(fl[branch[k]].step(X[-1], p[k], r[k], S[k]))
    return np.array(X)


_DEFECTIVE = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, -3.0, -3.0]])  # (s + 1)^3: a Jordan block


@pytest.mark.parametrize(
    "A_plus",
    [np.diag([-1.0, -3.0, -7.0]), _DEFECTIVE, np.array([[-1.0, 4.0, 0.0], [-4.0, -1.0, 0.0], [0.0, 0.0, -2.0]])],
    ids=["real modal", "defective (block exponential)", "complex modal"],
)
def test_kernel_paths_match_the_per_interval_flow_over_many_noisy_reversals(A_plus):
    """Modal (real or complex arithmetic, segments summed in closed form) and block-exponential paths
    against one exact step per interval, on 20 000 samples with noise reversals at every few samples."""
    model = RateIndependentModel(
        A_plus=A_plus,
        A_minus=-0.8 * A_plus.T,
        B_plus=[1.0, 0.5, 0.2],
        B_minus=[0.3, 1.0, 0.1],
        C=[1.0, 0.0, 0.0],
        E_plus=[0.1, 0.0, 0.0],
        E_minus=[0.0, 0.2, 0.0],
        D=0.3,
        x0=[0.1, 0.2, 0.3],
    )
    t = np.linspace(0, 40, 20001)
    u = 3 * np.sin(t) + 0.01 * np.random.default_rng(1).standard_normal(len(t))
    ref = _stepwise(model, t, u, model.x0)
    X = simulate(model, t, u).x
    assert np.abs(X - ref).max() <= 1e-11 * np.abs(ref).max()


@pytest.mark.parametrize("A_plus", [np.diag([-1.0, -3.0, -7.0]), _DEFECTIVE], ids=["modal", "defective"])
def test_one_pass_with_many_initial_states_and_forcings_equals_separate_simulations(A_plus):
    """`integrate` with m columns (x0, B, E per column and branch) = m separate simulations."""
    from fitter.core.kernel import flows, integrate, interval_coefficients

    rng = np.random.default_rng(3)
    model = RateIndependentModel(
        A_plus=A_plus,
        A_minus=-0.8 * A_plus.T,
        B_plus=[1.0, 0.5, 0.2],
        B_minus=[0.3, 1.0, 0.1],
        C=[1.0, 0.0, 0.0],
        D=0.3,
    )
    t = np.linspace(0, 4, 2001)
    u = 3 * np.sin(t) + 0.01 * rng.standard_normal(len(t))
    Bp, Bm, Ep, Em, X0 = (rng.standard_normal((3, 5)) for _ in range(5))
    branch, p, r, S = interval_coefficients(model, t, u)
    X = integrate(flows(model), X0, branch, p, r, S, forcing={1.0: (Bp, Ep), -1.0: (Bm, Em)})
    for j in range(5):
        one = model.replace(B_plus=Bp[:, j], B_minus=Bm[:, j], E_plus=Ep[:, j], E_minus=Em[:, j], x0=X0[:, j])
        ref = simulate(one, t, u).x
        assert np.abs(X[:, :, j] - ref).max() <= 1e-12 * np.abs(ref).max()


def test_stacked_expm_equals_one_at_a_time():
    rng = np.random.default_rng(5)
    M = rng.standard_normal((7, 4, 4)) * np.array([0.1, 1, 10, 100, 0.01, 3, 30])[:, None, None]
    stacked = expm(M)
    for k in range(7):
        assert np.abs(stacked[k] - expm(M[k])).max() <= 1e-13 * np.abs(stacked[k]).max()
    assert np.isnan(expm(np.array([[np.inf]]))).all()


def test_phi_blocks_are_the_blocks_of_the_augmented_exponential():
    """`phi_blocks` (n x n blocks) against `expm` of the 3n x 3n matrix [[A S, I, 0], [0, 0, I], [0, 0, 0]],
    over scales that need 1 to 10 squarings, zero patterns (triangular, sparse) and a non-finite entry;
    for n = 1 against the scalar phi-functions."""
    from fitter.core.flow import phi1, phi2, phi_blocks

    rng = np.random.default_rng(8)
    for n in (1, 2, 3, 4, 6):
        AS = rng.standard_normal((40, n, n)) * np.geomspace(1e-4, 40.0, 40)[:, None, None]
        AS[::3] = np.triu(AS[::3])
        AS[1::5][np.abs(AS[1::5]) < 0.5 * np.abs(AS[1::5]).max(axis=(1, 2), keepdims=True)] = 0.0
        G = np.zeros((len(AS), 3 * n, 3 * n))
        G[:, :n, :n], G[:, :n, n : 2 * n], G[:, n : 2 * n, 2 * n :] = AS, np.eye(n), np.eye(n)
        Z = expm(G)
        for k, F in enumerate(phi_blocks(AS)):
            ref = Z[:, :n, k * n : (k + 1) * n]
            scale = np.abs(Z[:, :n]).max(axis=(1, 2))[:, None, None]
            assert np.all(np.abs(F - ref) <= 1e-12 * scale)
    z = np.array([-30.0, -2.0, -0.3, 1e-9, 0.0, 0.7, 5.0])
    F0, F1, F2 = phi_blocks(z[:, None, None])
    assert np.allclose(F0[:, 0, 0], np.exp(z), rtol=1e-14, atol=0)
    assert np.allclose(F1[:, 0, 0], phi1(z), rtol=1e-14, atol=0)
    assert np.allclose(F2[:, 0, 0], phi2(z), rtol=1e-14, atol=0)
    bad = np.array([[[1.0, np.nan], [0.0, 1.0]], [[0.5, 0.0], [0.0, 0.5]]])
    F0, F1, F2 = phi_blocks(bad)
    assert np.isnan(F0[0]).all() and np.isnan(F2[0]).all() and np.isfinite(F1[1]).all()


def test_taylor_degree_is_the_least_whose_tail_is_below_the_bound():
    """`taylor_degree`: the least m >= 2 with theta^(m-1) / (m+1)! <= 2^-56 (15 at theta = 0.5, 7 at 5e-3, 2
    at 0), checked against the bound itself; the blocks cut there are those of the full degree-18 series to
    2e-16 of each block's scale."""
    from math import factorial

    from fitter.core import flow

    theta = np.r_[0.0, 1e-18, np.geomspace(1e-9, 0.5, 60)]
    m = flow.taylor_degree(theta)
    assert m[0] == 2 and m[-1] == 15 and flow.taylor_degree(np.array([5e-3]))[0] == 7
    for th, k in zip(theta, m):
        assert th ** (k - 1) / factorial(k + 1) <= 2.0**-56 * (1 + 1e-12)
        assert k == 2 or th ** (k - 2) / factorial(k) > 2.0**-56 * (1 - 1e-12)
    rng = np.random.default_rng(3)
    AS = rng.standard_normal((30, 4, 4)) * np.geomspace(1e-5, 3.0, 30)[:, None, None]
    cut = flow.phi_blocks(AS)
    full_degree = flow.taylor_degree
    try:
        flow.taylor_degree = lambda th: np.full(np.shape(th), flow.TAYLOR_DEGREE)
        full = flow.phi_blocks(AS)
    finally:
        flow.taylor_degree = full_degree
    for F, G in zip(cut, full):
        assert np.all(np.abs(F - G) <= 2e-16 * np.abs(G).max(axis=(1, 2), keepdims=True))


def test_input_range_holds_the_input_at_its_edges_and_bounds_an_unstable_branch(tmp_path):
    """Beyond input_range the model acts on the held edge value: the state stops, y stays at the edge's value;
    inside it nothing changes.  The loop converges on [-1, 1] (rho = e^(2 * 2 - 3 * 2)), but its rising branch
    (eigenvalue +2 in u) driven to u = 6 grows like e^(2 * 6) unheld."""
    free = RateIndependentModel(A_plus=[[2.0]], A_minus=[[3.0]], B_plus=[1.0], B_minus=[1.0], C=[1.0], D=0.3)
    held = free.replace(input_range=(-1.0, 1.0))
    path = tmp_path / "held.json"
    save_model(held, path)
    assert load_model(path).input_range == (-1.0, 1.0)
    t = np.linspace(0.0, 4.0, 401)
    u_in = 0.9 * np.sin(2 * np.pi * t)
    assert np.array_equal(simulate(free, t, u_in).y, simulate(held, t, u_in).y)
    u_out = 6.0 * np.sin(2 * np.pi * t)
    y_free, y_held = simulate(free, t, u_out).y, simulate(held, t, u_out).y
    assert np.abs(y_free).max() > 1e3
    assert np.allclose(y_held, simulate(free, t, np.clip(u_out, -1.0, 1.0)).y, rtol=0, atol=1e-12)
    assert np.abs(y_held).max() < 5.0
    beyond = u_out > 1.0
    assert np.ptp(y_held[beyond & (t < 0.5)]) < 1e-12  # the state does not move beyond the edge
    ys, st = stepped(held, t, u_out)
    assert np.abs(ys - y_held).max() < 1e-12
    assert st.u == u_out[-1]  # the input keeps the value set


def test_stepper_with_input_derivatives_steps_before_the_input_is_set():
    """set u(t_k) and du/dt = (u_k+1 - u_k)/h, then do_step: the output at t_k+1, read before any new input,
    is simulate's; the derivative is part of the state (rollback restores it)."""
    for model in (example1_model(), example3_model()):
        t = np.linspace(0, 5, 301)
        u = np.sin(1.3 * t) + 0.2 * np.cos(3.1 * t)
        ref = simulate(model, t, u).y
        st = Stepper(model, t0=t[0], u0=u[0])
        ys = [st.output()]
        for k in range(len(t) - 1):
            h = t[k + 1] - t[k]
            st.set_input(u[k])
            st.set_input_derivative((u[k + 1] - u[k]) / h)
            if k == 100:
                saved = st.get_state()
            st.do_step(h)
            ys.append(st.output())
        assert np.abs(np.array(ys) - ref).max() < 1e-12
        st.set_state(saved)
        st.do_step(t[101] - t[100])
        assert st.output() == pytest.approx(ref[101], abs=1e-12)
    with pytest.raises(KernelError, match="not finite"):
        st.set_input_derivative(float("nan"))


@pytest.mark.parametrize("A_plus", [np.diag([-1.0, -3.0, -7.0]), _DEFECTIVE], ids=["modal", "defective"])
def test_integration_in_pieces_equals_one_pass(monkeypatch, A_plus):
    """`integrate_blocks` takes the intervals a piece at a time from the last state of the piece before:
    states, outputs and multi-column responses as in one pass, to rounding (a piece boundary is one more
    segment start)."""
    from fitter.core import flow
    from fitter.core.kernel import state_blocks, state_response
    from fitter.core.periodic import affine_response, period_map

    model = RateIndependentModel(
        A_plus=A_plus,
        A_minus=-0.8 * A_plus.T,
        B_plus=[1.0, 0.5, 0.2],
        B_minus=[0.3, 1.0, 0.1],
        C=[1.0, 0.0, 0.0],
        E_plus=[0.1, 0.0, 0.0],
        D=0.3,
        x0=[0.1, 0.2, 0.3],
    )
    t = np.linspace(0, 40, 5001)
    u = 3 * np.sin(t) + 0.01 * np.random.default_rng(2).standard_normal(len(t))
    u[100:110] = u[100]  # held samples keep the branch across a piece boundary
    X0 = np.random.default_rng(4).standard_normal((3, 4))
    whole, states = simulate(model, t, u), state_response(model, t, u, X0)
    monkeypatch.setattr(flow, "_BLOCK", 103)
    pieces = simulate(model, t, u)
    assert np.abs(pieces.x - whole.x).max() <= 1e-12 * np.abs(whole.x).max()
    assert np.abs(pieces.y - whole.y).max() <= 1e-12 * np.abs(whole.y).max()
    assert np.abs(state_response(model, t, u, X0) - states).max() <= 1e-12 * np.abs(states).max()
    assert [len(X) for X in state_blocks(model, t, u, X0)] == [104] + [103] * 47 + [56]
    c, Phi = affine_response(model, t, u)
    Phi_N, c_N = period_map(model, t, u)
    assert np.array_equal(Phi_N, Phi[-1]) and np.array_equal(c_N, c[-1])


@pytest.mark.parametrize("growth", [0.0, 0.02], ids=["decaying (scan)", "some steps grow (chunks)"])
@pytest.mark.parametrize("dtype", [float, complex])
def test_linear_recurrence_equals_the_step_by_step_loop(dtype, growth):
    """w_{k+1} = e^{z_k} w_k + f_k over 2000 steps, most of them decaying by up to e^-40 (a switching effect's
    fully switched intervals: about 270 chunks of the cumulative-sum form), solved by `linear_recurrence`
    (the doubling scan when no step grows, the chunks when some do) equals the plain loop to 1e-12."""
    from fitter.core.recurrence import linear_recurrence

    rng = np.random.default_rng(11)
    N, m = 2000, 3
    z = -rng.uniform(0.0, 40.0, (N, m)) * (rng.uniform(size=(N, 1)) < 0.5) + growth
    if dtype is complex:
        z = z + 1j * rng.uniform(-2.0, 2.0, (N, m))
    f = rng.normal(size=(N, m)).astype(dtype)
    w0 = np.array([1.0, -2.0, 0.5], dtype=dtype)
    expected, w = np.empty_like(f), w0
    for k in range(N):
        w = np.exp(z[k]) * w + f[k]
        expected[k] = w
    got = linear_recurrence(w0, z, np.exp(z), f)
    assert got.dtype == f.dtype
    assert np.max(np.abs(got - expected)) < 1e-12 * np.max(np.abs(expected))


@pytest.mark.parametrize("K", [1, 2, 3, 5, 16, 17, 32, 33, 70])
def test_affine_scan_equals_the_map_by_map_recurrence_at_any_length(K):
    """`fitter.core.scans.affine_scan` against x_{k+1} = M_k x_k + g_k applied one map at a time, for lengths below,
    at and above its block of 32 (below it the maps make one shorter block), one initial state and several."""
    from fitter.core.scans import affine_scan

    rng = np.random.default_rng(K)
    M = 0.5 * rng.standard_normal((K, 3, 3)) / np.sqrt(3)
    for X0, g in (
        (rng.standard_normal(3), rng.standard_normal((K, 3))),
        (rng.standard_normal((3, 4)), rng.standard_normal((K, 3, 4))),
    ):
        x, expected = X0, []
        for k in range(K):
            x = M[k] @ x + g[k]
            expected.append(x)
        got = affine_scan(M, g, X0)
        assert got.shape == (K,) + X0.shape
        np.testing.assert_allclose(got, np.array(expected), rtol=1e-12, atol=1e-12)
