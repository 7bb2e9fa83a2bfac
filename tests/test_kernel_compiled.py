"""The compiled modal scan (numba) against the kernel's numpy sums: the same states, to rounding."""

import sys

import numpy as np
import pytest

from fitter.core import RateDependentModel, RateIndependentModel
from fitter.core.flow import flows, integrate, interval_coefficients
from fitter.core.rates import CallableRate
from fitter.core.scans import compiled_scans, integrate_modal, modal_pass

compiled = pytest.importorskip("fitter.core.compiled")


def _ri(rotating: bool) -> RateIndependentModel:
    """Order 3: complex eigenvalues on the rising branch when `rotating`, real ones on the falling branch."""
    A_plus = [[-2.0, 3.0, 0.0], [-3.0, -2.0, 0.5], [0.0, 0.2, -1.0]] if rotating else np.diag([-1.0, -2.5, -4.0])
    return RateIndependentModel(
        A_plus=A_plus,
        A_minus=np.diag([1.5, 3.0, 0.7]),
        B_plus=[1.0, -0.5, 0.3],
        B_minus=[0.8, 0.2, -0.4],
        C=[1.0, 0.5, -0.2],
        E_plus=[0.1, 0.0, -0.2],
        E_minus=[-0.3, 0.1, 0.0],
        D=0.2,
        x0=[0.1, -0.2, 0.05],
    )


def _rd() -> RateDependentModel:
    g = CallableRate(lambda v: np.abs(v) ** 0.8)
    return RateDependentModel(
        A=[[-3.0, 1.0], [-1.0, -0.5]], B=[1.0, 0.4], C=[1.0, 0.3], E=[0.1, -0.1], D=0.1, x0=[0.2, 0.0], g=g
    )


def _input(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Minor loops between random turning points, with held stretches (du = 0)."""
    rng = np.random.default_rng(seed)
    turns = rng.uniform(-1.0, 1.0, n // 40 + 2)
    u = np.interp(np.linspace(0, len(turns) - 1, n), np.arange(len(turns)), turns)
    u[n // 3 : n // 3 + 25] = u[n // 3]
    return np.linspace(0.0, 0.01 * n, n), u


@pytest.mark.parametrize("model", [_ri(True), _ri(False), _rd()], ids=["ri-complex", "ri-real", "rd"])
@pytest.mark.parametrize("columns", [None, 4])
def test_compiled_scan_gives_the_numpy_sums_states(model, columns):
    """States from one initial state and from several with per-column forcings (what variable projection asks
    for), over 5000 intervals that cross the numpy sums' chunk limit: equal to 1e-10 of their range."""
    t, u = _input(5000, 1)
    branch, p, r, S = interval_coefficients(model, t, u)
    fl = flows(model)
    used = {b: fl[b] for b in np.unique(branch)}
    n = model.order
    if columns is None:
        X0, force = np.asarray(model.x0), {b: None for b in used}
    else:
        rng = np.random.default_rng(2)
        X0 = rng.standard_normal((n, columns))
        force = {b: (rng.standard_normal((n, columns)), rng.standard_normal((n, columns))) for b in used}
    numpy_states = integrate_modal(used, force, X0, branch, p, r, S)
    compiled_states = compiled.modal_scan(used, force, X0, branch, p, r, S)
    assert compiled_states.shape == numpy_states.shape
    scale = np.abs(numpy_states).max()
    assert np.abs(compiled_states - numpy_states).max() <= 1e-10 * scale
    assert np.abs(numpy_states[-1] - numpy_states[0]).max() > 1e-3 * scale  # the states move


def test_compiled_scans_is_the_modal_pass_only_inside_its_context():
    """Outside `compiled_scans` the kernel runs its numpy sums; inside, the compiled scan, with `integrate`'s
    states equal to rounding."""
    model = _ri(True)
    t, u = _input(800, 3)
    branch, p, r, S = interval_coefficients(model, t, u)
    assert modal_pass() is integrate_modal
    outside = integrate(flows(model), model.x0, branch, p, r, S)
    with compiled_scans() as available:
        assert available and modal_pass() is compiled.modal_scan
        inside = integrate(flows(model), model.x0, branch, p, r, S)
    assert modal_pass() is integrate_modal
    assert np.abs(inside - outside).max() <= 1e-12 * np.abs(outside).max()


def test_without_the_compiled_module_the_kernel_runs_its_numpy_sums(monkeypatch):
    """As inside an FMU (which ships `fitter.core` without it, `fitter.fmu.build._NOT_SHIPPED`) or without
    numba: `compiled_scans` says it is unavailable and the modal pass stays the numpy sums."""
    from fitter.core import scans
    from fitter.fmu.build import _NOT_SHIPPED

    assert "compiled.py" in _NOT_SHIPPED
    monkeypatch.setitem(sys.modules, "fitter.core.compiled", None)  # import fails
    monkeypatch.setattr(scans, "_LOADED", {})
    with compiled_scans() as available:
        assert not available and modal_pass() is integrate_modal


def _runs(model, seeds: list[int], n: int = 300) -> tuple[list, list]:
    """Recordings of `model`'s inputs (`_input`): a rising ramp alone (one branch only) and minor loops."""
    ts, us = [np.linspace(0.0, 1.0, 60)], [np.linspace(-0.8, 0.9, 60)]
    for seed in seeds:
        t, u = _input(n + 37 * seed, seed)
        ts.append(t)
        us.append(u)
    return ts, us


@pytest.mark.parametrize("model", [_ri(True), _ri(False), _rd()], ids=["ri-complex", "ri-real", "rd"])
def test_recordings_in_one_scan_give_each_recordings_own_states_to_the_last_digit(model):
    """`integrate_runs` (several recordings in one compiled scan, each restarted from x0) against each recording's
    own `integrate_blocks`: the same bits, with per-column forcings, a recording that uses one branch only, and
    a change of branch at a recording's first interval."""
    from fitter.core.flow import integrate_blocks, integrate_runs

    rng = np.random.default_rng(5)
    n, columns = model.order, 3
    X0 = rng.standard_normal((n, columns))
    force = {b: (rng.standard_normal((n, columns)), rng.standard_normal((n, columns))) for b in (1.0, -1.0)}
    ts, us = _runs(model, [1, 2])
    runs = [interval_coefficients(model, t, u) for t, u in zip(ts, us)]
    fl = flows(model)
    assert integrate_runs(fl, X0, runs, force) is None  # outside `compiled_scans`: run by run
    with compiled_scans():
        together = integrate_runs(fl, X0, runs, force)
        alone = [np.concatenate(list(integrate_blocks(fl, X0, *run, force))) for run in runs]
        assert integrate_runs(fl, X0, [*runs, tuple(a[:0] for a in runs[0])], force) is None  # an empty run
    assert [X.shape for X in together] == [X.shape for X in alone]
    for X, Y in zip(together, alone):
        assert np.array_equal(X, Y)
    assert not np.allclose(together[1][-1], together[2][-1])  # the recordings differ


@pytest.mark.parametrize("mode", ["fit", "model", "periodic"])
def test_the_columns_of_all_recordings_at_once_are_each_recordings_own(mode):
    """`response_columns_all` against `response_columns` recording by recording (variable projection's columns,
    `fitter.identification.projection`), inside `compiled_scans`: base, Psi and the initial-state columns the same
    bits in each x0 mode; for ``"periodic"`` from each recording's own cycle."""
    from fitter.identification.projection import response_columns, response_columns_all

    model = _ri(False)
    lin = {0: ("B_plus", 0), 1: ("B_plus", 1), 2: ("E_minus", 2), 3: ("D", 0)}
    ts, us = _runs(model, [3, 4], n=400)
    cycles = [(0, 40), (10, 200), (30, 250)] if mode == "periodic" else [None] * 3
    with compiled_scans():
        together = response_columns_all(model, lin, ts, us, mode, cycles)
        alone = [response_columns(model, lin, t, u, mode, c) for t, u, c in zip(ts, us, cycles)]
    for a, b in zip(together, alone):
        assert a.start == b.start and np.array_equal(a.base, b.base) and np.array_equal(a.Psi, b.Psi)
        assert (a.Own is None) == (b.Own is None) == (mode != "fit")
        assert a.Own is None or np.array_equal(a.Own, b.Own)
    assert np.ptp(together[1].Psi[:, 0]) > 0  # the columns move


@pytest.mark.parametrize("inside", [True, False], ids=["compiled", "numpy sums"])
def test_state_responses_are_each_recordings_state_response(inside):
    """`kernel.state_responses` against `kernel.state_response` recording by recording, inside `compiled_scans`
    (one scan for all) and outside (the numpy sums, recording by recording): the same bits, x_0 first."""
    from contextlib import nullcontext

    from fitter.core.kernel import state_response, state_responses

    model = _ri(True)
    rng = np.random.default_rng(7)
    X0 = rng.standard_normal((3, 2))
    ts, us = _runs(model, [5, 6])
    with compiled_scans() if inside else nullcontext():
        together = state_responses(model, ts, us, X0)
        alone = [state_response(model, t, u, X0) for t, u in zip(ts, us)]
    assert all(np.array_equal(a, b) for a, b in zip(together, alone)) and len(together) == 3
    assert np.array_equal(together[2][0], X0) and together[2].shape == (len(us[2]), 3, 2)


@pytest.mark.parametrize("inside", [True, False], ids=["compiled", "numpy sums"])
def test_state_responses_outputs_are_c_times_the_states(inside):
    """``outputs=True`` gives C x at every sample: with the canonical C = e1 the states' first entries to the last
    bit (what the fit's projection reads), with a general C the product C x to 1e-13 of its size; the states of the
    scan are then never formed (compiled) or reduced as they come (numpy sums)."""
    from contextlib import nullcontext

    from fitter.core.kernel import state_responses

    rng = np.random.default_rng(3)
    X0 = rng.standard_normal((3, 4))
    for C in ([1.0, 0.0, 0.0], [1.0, 0.5, -0.2]):
        model = _ri(True).replace(C=C)
        ts, us = _runs(model, [5, 6])
        with compiled_scans() if inside else nullcontext():
            states = state_responses(model, ts, us, X0)
            outputs = state_responses(model, ts, us, X0, outputs=True)
        for X, Y in zip(states, outputs):
            assert Y.shape == (len(X), 4)
            if C[1] == 0.0:
                assert np.array_equal(Y, X[:, 0])
            else:
                assert np.abs(Y - np.einsum("i,kim->km", C, X)).max() <= 1e-13 * np.abs(Y).max()
                assert np.abs(Y - X[:, 0]).max() > 0.1 * np.abs(Y).max()  # C mixes the states
