"""The inverse model (`fitter.core.inverse`): compensator -> plant cascades, bad references, stepping, CLI.

Cascade: the compensator's input u, fed to `simulate` of the model it inverts (the plant), reproduces y_ref
within 1e-6 of the reference's range wherever the inverse exists: sines of the output at several amplitudes
and rates, a triangle, and a seeded random reversal sequence with minor loops (its reference is the plant's
own response, so an input that reaches it exists); rate-independent and rate-dependent models, with effects.
The monotone models here (dy/du > 0 on every branch, checked) also give back the input that made the
reference.  Bad references are clamped and reported, never NaN; NaN is an error naming the sample.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from samples import ri_model

from fitter.baselines import PrandtlIshlinskii
from fitter.cli import main
from fitter.core import (
    Compensator,
    InverseError,
    KernelError,
    RateDependentModel,
    RateIndependentModel,
    TabulatedRate,
    compensate,
    invert,
    save_model,
    simulate,
)
from fitter.core.effects import Effect
from fitter.core.inverse import MEASUREMENT_EFFECTS, SUPPORTED_EFFECTS
from fitter.data.recordings import Recording

TOL = 1e-6


def ri1(effects=()) -> RateIndependentModel:
    """First-order rate-independent model with a counter-clockwise loop, dy/du > 0 on both branches."""
    return RateIndependentModel(
        A_plus=[[-2.0]],
        A_minus=[[2.0]],
        B_plus=[2.0],
        B_minus=[-2.0],
        C=[1.0],
        E_plus=[-1.0],
        E_minus=[-1.0],
        D=5.0,
        x0=[0.0],
        input_range=(-3.0, 5.0),
        effects=list(effects),
    )


def ri2(effects=()) -> RateIndependentModel:
    """Second order: two relaxations of different speed on each branch, dy/du > 0."""
    return RateIndependentModel(
        A_plus=np.diag([-2.0, -6.0]),
        A_minus=np.diag([2.0, 6.0]),
        B_plus=[2.0, 6.0],
        B_minus=[-2.0, -6.0],
        E_plus=[-1.0, -0.6],
        E_minus=[-1.0, -0.6],
        C=[0.6, 0.8],
        D=4.0,
        x0=[0.2, -0.1],
        input_range=(-3.0, 5.0),
        effects=list(effects),
    )


def rd1(effects=()) -> RateDependentModel:
    v = np.logspace(-3, 3, 61)
    g = v / (1 + v / 2)
    return RateDependentModel(
        A=[[-1.0]],
        B=[1.0],
        C=[1.0],
        E=[0.2],
        D=1.5,
        x0=[0.5],
        g=TabulatedRate(np.r_[-v[::-1], v], np.r_[g[::-1], g]),
        input_range=(-3.0, 5.0),
        effects=list(effects),
    )


def cascade_error(model, t, y_ref, result) -> float:
    """max |simulate(model, t, u) - y_ref| / range(y_ref)."""
    y = simulate(model, t, result.u).y
    return float(np.max(np.abs(y - y_ref)) / np.ptp(y_ref))


def reversals(seed: int, n_turns: int = 12, per: int = 25) -> np.ndarray:
    """A seeded input with random reversals whose amplitude shrinks and grows: minor loops inside major ones."""
    rng = np.random.default_rng(seed)
    pts = [1.0]
    for k in range(n_turns):
        amp = rng.uniform(0.2, 2.5) * (0.4 if k % 3 == 2 else 1.0)
        pts.append(float(np.clip(pts[-1] + (amp if k % 2 == 0 else -amp), -1.5, 3.5)))
    return np.concatenate([np.linspace(a, b, per, endpoint=False) for a, b in zip(pts[:-1], pts[1:])] + [[pts[-1]]])


def start_output(model, t0: float, u0: float) -> float:
    return float(simulate(model, [t0], [u0]).y[0])


# ----------------------------------------------------------------------------- cascades


@pytest.mark.parametrize("make", [ri1, ri2], ids=["ri1", "ri2"])
@pytest.mark.parametrize("amplitude,freq,n", [(0.5, 0.2, 301), (3.0, 0.5, 601), (8.0, 1.3, 1201)])
def test_cascade_sines_of_the_output(make, amplitude, freq, n):
    model = make()
    t = np.linspace(0.0, 5.0, n)
    y0 = start_output(model, 0.0, 1.0)
    y_ref = y0 + amplitude * np.sin(2 * np.pi * freq * t)
    res = compensate(model, t, y_ref, u0=1.0)
    assert res.n_clamped == 0
    assert cascade_error(model, t, y_ref, res) < TOL
    assert np.max(np.abs(res.y - y_ref)) / np.ptp(y_ref) < TOL  # the predicted output is the cascade's
    lo, hi = model.input_range
    assert lo <= res.u.min() and res.u.max() <= hi


@pytest.mark.parametrize("make", [ri1, ri2], ids=["ri1", "ri2"])
def test_cascade_triangle(make):
    model = make()
    t = np.arange(801) * 0.01
    y0 = start_output(model, 0.0, 1.0)
    y_ref = y0 + 6.0 * (2 * np.abs(((t / 2.0 + 0.25) % 1.0) - 0.5) - 0.5)
    y_ref += y0 - y_ref[0]
    res = compensate(model, t, y_ref, u0=1.0)
    assert res.n_clamped == 0
    assert cascade_error(model, t, y_ref, res) < TOL


@pytest.mark.parametrize(
    "make,effects",
    [
        (ri1, ()),
        (ri2, ()),
        (ri2, [Effect("backlash", {"b": 0.3})]),
        (
            ri1,
            [
                Effect("backlash", {"b": 0.2}),
                Effect("saturation", {"y_c": 5.0, "beta": 0.05}),
                Effect("thermal_drift", {"kappa": 0.002}),
            ],
        ),
        (ri1, [Effect("creep", {"k": 0.5, "tau": 0.7}), Effect("viscous", {"c": 0.05})]),
        (ri2, [Effect("rate_dependence", {"alpha": 0.3})]),
        (rd1, ()),
        (rd1, [Effect("creep", {"k": 0.3, "tau": 2.0}), Effect("backlash", {"b": 0.1})]),
        (ri2, [Effect("relaxation", {"k": 0.4, "w2": 0.3, "w3": 2.0, "w4": 0.4, "tau_min": 0.05, "tau_max": 5.0})]),
        (
            ri2,
            [
                Effect(
                    "switching",
                    {
                        "S1": 0.8,
                        "u_up1": 2.0,
                        "u_dn1": -0.5,
                        "width1": 0.3,
                        "q1": -1.0,
                        "S2": 0.3,
                        "u_up2": 3.0,
                        "u_dn2": -1.0,
                        "width2": 0.1,
                        "q2": 0.5,
                    },
                )
            ],
        ),
    ],
    ids=[
        "ri1",
        "ri2",
        "ri2+backlash",
        "ri1+backlash+saturation+thermal",
        "ri1+creep+viscous",
        "ri2+rate_dependence",
        "rd1",
        "rd1+creep+backlash",
        "ri2+relaxation",
        "ri2+switching",
    ],
)
@pytest.mark.parametrize("seed", [3, 11])
def test_cascade_random_reversals_with_minor_loops(make, effects, seed):
    model = make(effects)
    u_true = reversals(seed)
    t = np.arange(len(u_true)) * 0.02
    y_ref = simulate(model, t, u_true).y
    res = compensate(model, t, y_ref, u0=u_true[0])
    assert res.n_clamped == 0
    assert cascade_error(model, t, y_ref, res) < TOL
    if not any(e.effect == "backlash" for e in model.effects):  # within the dead band, u is not unique
        du, dy = np.diff(u_true), np.diff(y_ref)
        if np.all(du * dy >= 0):  # a monotone model: the input comes back
            assert np.max(np.abs(res.u - u_true)) < 1e-6 * np.ptp(u_true)


def test_cascade_with_measurement_effects_inverted_or_dropped():
    lag = [Effect("sensor_lag", {"tau": 0.05}), Effect("measurement_drift", {"rate": 0.02})]
    model = ri1(lag)
    u_true = reversals(5)
    t = np.arange(len(u_true)) * 0.02
    y_ref = simulate(model, t, u_true).y
    with pytest.raises(InverseError, match="sensor_lag, measurement_drift.*measurement='drop'"):
        compensate(model, t, y_ref, u0=u_true[0])
    res = compensate(model, t, y_ref, u0=u_true[0], measurement="invert")
    assert res.n_clamped == 0 and cascade_error(model, t, y_ref, res) < TOL
    device = ri1()
    y_dev = simulate(device, t, u_true).y
    res = compensate(model, t, y_dev, u0=u_true[0], measurement="drop")
    assert res.n_clamped == 0 and cascade_error(device, t, y_dev, res) < TOL
    assert set(MEASUREMENT_EFFECTS) == {"sensor_lag", "measurement_drift"}
    assert {"backlash", "creep", "saturation", "rate_dependence", "switching"} <= set(SUPPORTED_EFFECTS)


# ----------------------------------------------------------------------------- bad references


def test_beyond_the_reachable_range_is_clamped_and_reported():
    model = ri1()
    t = np.linspace(0.0, 4.0, 401)
    y0 = start_output(model, 0.0, 1.0)
    y_ref = y0 + 40.0 * np.sin(2 * np.pi * 0.5 * t)  # far beyond what u in [-3, 5] reaches
    res = compensate(model, t, y_ref, u0=1.0)
    assert 50 < res.n_clamped < len(t)
    assert np.all(np.isfinite(res.u)) and np.all(np.isfinite(res.y))
    lo, hi = model.input_range
    assert res.u.min() == lo and res.u.max() == hi  # clamped at the edges of the input range
    assert cascade_error(model, t, res.y, res) < 1e-9  # the predicted output is what the plant does
    exact = ~res.clamped
    assert np.max(np.abs(res.y[exact] - y_ref[exact])) < TOL * np.ptp(y_ref)
    # the shortfall of a clamped sample is the distance to the output at the edge of the input range
    top = np.argmax(y_ref)
    assert res.clamped[top] and res.u[top] == hi
    assert res.shortfall[top] == pytest.approx(y_ref[top] - res.y[top], abs=1e-12)
    assert res.max_shortfall == pytest.approx(np.max(np.abs(res.y - y_ref)[res.clamped]))
    s = res.summary()
    assert s["clamped"] == res.n_clamped and s["max_shortfall"] == res.max_shortfall


def test_steps_are_solved_exactly_or_clamped():
    model = ri1()
    t = np.arange(60) * 0.1
    y0 = start_output(model, 0.0, 1.0)
    y_ref = np.where(t < 2.0, y0, y0 + 7.0)  # a reachable jump: exact in one interval
    y_ref = np.where(t < 4.0, y_ref, y0 - 3.0)  # and back down past the start
    res = compensate(model, t, y_ref, u0=1.0)
    assert res.n_clamped == 0
    assert cascade_error(model, t, y_ref, res) < TOL
    jump = np.where(t < 2.0, y0, y0 + 100.0)  # unreachable jump: clamped at the top edge
    res = compensate(model, t, jump, u0=1.0)
    assert res.n_clamped == np.count_nonzero(t >= 2.0)
    assert np.all(res.u[t >= 2.0] == model.input_range[1])


def test_non_monotone_branch_is_clamped_never_nan():
    # this model's output falls for a while after some reversals (dy/du < 0 on part of its branches)
    model = ri_model(1).replace(input_range=(-3.0, 5.0))
    t = np.linspace(0.0, 10.0, 1001)
    y_ref = start_output(model, 0.0, 1.0) + 4.0 * np.sin(2 * np.pi * 0.4 * t) + 10.0 * np.sin(2 * np.pi * 0.05 * t)
    res = compensate(model, t, y_ref, u0=1.0)
    assert np.all(np.isfinite(res.u)) and np.all(np.isfinite(res.y))
    assert cascade_error(model, t, res.y, res) < 1e-9
    exact = ~res.clamped
    assert np.max(np.abs(res.y[exact] - y_ref[exact])) < TOL * np.ptp(y_ref)
    assert np.all(np.abs(res.y[res.clamped] - y_ref[res.clamped]) > 0)


def test_nan_in_the_reference_is_an_error_naming_the_sample():
    t = np.arange(20) * 0.1
    y = np.full(20, 5.0)
    y[7] = np.nan
    with pytest.raises(KernelError, match=r"y_ref\[7\] \(sample 7, t = 0\.7\) is nan"):
        compensate(ri1(), t, y, u0=1.0)
    comp = Compensator(ri1(), u0=1.0)
    with pytest.raises(KernelError, match="not finite"):
        comp.step(0.0, math.inf)
    with pytest.raises(KernelError, match="time must increase"):
        compensate(ri1(), np.r_[0.0, 0.2, 0.1], [5.0, 5.0, 5.0])


def test_refusals():
    with pytest.raises(InverseError, match="input_range"):
        invert(ri1().replace(input_range=None))
    assert invert(ri1().replace(input_range=None), input_range=(-1, 1)).input_range == (-1.0, 1.0)
    with pytest.raises(InverseError, match="measurement must be one of"):
        invert(ri1(), measurement="ignore")


# ----------------------------------------------------------------------------- stepping


def test_step_by_step_equals_compensate_and_state_rolls_back():
    model = ri2([Effect("backlash", {"b": 0.2}), Effect("creep", {"k": 0.2, "tau": 0.5})])
    u_true = reversals(7, n_turns=8)
    t = np.arange(len(u_true)) * 0.02
    y_ref = simulate(model, t, u_true).y
    whole = compensate(model, t, y_ref, u0=u_true[0])
    comp = invert(model, t0=t[0], u0=u_true[0])
    u = []
    for k in range(len(t)):
        if k == 100:
            saved = comp.get_state()
        u.append(comp.step(t[k], y_ref[k]))
    np.testing.assert_array_equal(u, whole.u)
    tail = np.array(u[100:])
    comp.set_state(saved)
    again = [comp.step(t[k], y_ref[k]) for k in range(100, len(t))]
    np.testing.assert_array_equal(again, tail)
    assert comp.samples == len(t) and comp.clamped == 0


def test_which_root_the_held_input_is_kept_and_the_nearest_root_taken():
    """Module docstring, "Which root".  Backlash: u's roots are not unique (the dead band); read again at the next
    time with y_ref unchanged, u is the sample's own u, and a constant stretch of y_ref keeps u constant (it used
    to jump across the dead band and back, by b).  A branch with the wrong slope: of the roots on both sides the
    nearer one is taken, though it lies on the side that moves y away from y_ref."""
    model = ri2([Effect("backlash", {"b": 0.3})])
    u_true = np.r_[reversals(5, n_turns=6), np.full(20, reversals(5, n_turns=6)[-1])]
    t = np.arange(len(u_true)) * 0.02
    y_ref = simulate(model, t, u_true).y
    comp = Compensator(model, t0=t[0])
    u, again = np.empty(len(t)), np.empty(len(t) - 1)
    for k in range(len(t)):
        u[k] = comp.step(t[k], y_ref[k])
        if k + 1 < len(t):
            saved = comp.get_state()
            again[k] = comp.step(t[k + 1], y_ref[k])
            comp.set_state(saved)
    assert comp.clamped == 0
    np.testing.assert_array_equal(again, u[:-1])
    assert np.all(u[-20:] == u[-20])
    assert cascade_error(model, t, y_ref, compensate(model, t, y_ref)) < TOL

    # dy/du = 4 (-3 x + 3 u + 1) + 0.5 = -103.5 rising, 4 (2 x + 2 u - 1) + 0.5 = 84.5 falling at x = 10, u = 1:
    # y_ref a little below the held output has a root on both sides, the rising one nearer
    model = ri_model(1).replace(input_range=(-3.0, 5.0))
    comp = Compensator(model, t0=0.0, u0=1.0, x0=[10.0])
    y_held = start_output(model.replace(x0=[10.0]), 0.0, 1.0)
    assert comp.step(0.0, y_held) == 1.0
    u = comp.step(0.1, y_held - 0.01)
    assert not comp.last_clamped and u > 1.0
    below = simulate(model.replace(x0=[10.0]), [0.0, 0.1], [1.0, 1.0 - (u - 1.0)]).y[1]
    assert below > y_held - 0.01  # no root below within the same distance


# ----------------------------------------------------------------------------- Prandtl-Ishlinskii inverse


def test_prandtl_ishlinskii_inverse_round_trip():
    model = ri1()
    t = np.linspace(0.0, 6.0, 601)
    u = 1.0 + 2.0 * np.sin(2 * np.pi * 0.5 * t) * np.exp(-0.1 * t)
    rec = Recording(t, u, simulate(model, t, u).y)
    pi = PrandtlIshlinskii(deadband=False, invertible=True).fit(rec)
    assert pi.slope_ >= pi.min_slope
    u_new = 1.0 + 1.5 * np.sin(2 * np.pi * 0.3 * t) + 0.3 * np.sin(2 * np.pi * 2.0 * t)
    y = pi.predict(Recording(t, u_new, np.full(len(t), np.nan)))
    np.testing.assert_allclose(pi.invert(y), u_new, atol=1e-9)


# ----------------------------------------------------------------------------- CLI


def _write(path: Path, header: str, *cols) -> Path:
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=header, comments="", fmt="%.17g")
    return path


@pytest.fixture
def files(tmp_path):
    model = ri1()
    save_model(model, tmp_path / "model.json")
    t = np.linspace(0.0, 5.0, 251)
    y_ref = start_output(model, 0.0, 1.0) + 3.0 * np.sin(2 * np.pi * 0.4 * t)
    _write(tmp_path / "ref.csv", "time,y_ref", t, y_ref)
    return {"dir": tmp_path, "model": model, "t": t, "y_ref": y_ref}


def run(*args):
    return CliRunner().invoke(main, ["compensate", *map(str, args)])


def test_cli_compensate_writes_u_and_the_prediction(files):
    d = files["dir"]
    res = run(d / "model.json", d / "ref.csv", "-o", d / "u.csv", "--plot", d / "track.png", "--u0", 1.0)
    assert res.exit_code == 0, res.output
    assert (d / "u.csv").read_text().splitlines()[0] == "time,u,y_predicted"
    out = np.loadtxt(d / "u.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(out[:, 0], files["t"])
    y = simulate(files["model"], out[:, 0], out[:, 1]).y
    assert np.max(np.abs(y - files["y_ref"])) < TOL * np.ptp(files["y_ref"])
    np.testing.assert_allclose(out[:, 2], y, atol=1e-12)
    assert (d / "track.png").read_bytes()[:4] == b"\x89PNG"
    assert "0 clamped" in res.stdout


def test_cli_warns_of_a_first_input_outside_the_input_range(files):
    d = files["dir"]
    lo, hi = files["model"].input_range
    res = run(d / "model.json", d / "ref.csv", "-o", d / "u.csv", "--u0", hi + 10 * (hi - lo))
    assert res.exit_code == 0, res.output
    assert "warning: --u0" in res.stderr and "is outside the input range" in res.stderr
    assert "--u0" not in run(d / "model.json", d / "ref.csv", "-o", d / "u.csv", "--u0", hi).stderr


def test_cli_reports_clamped_samples(files):
    d = files["dir"]
    _write(d / "far.csv", "t_s,target", files["t"], files["y_ref"] * 10)
    res = run(d / "model.json", d / "far.csv", "-o", d / "u.csv", "--time", "t", "--ref", "target", "--json")
    assert res.exit_code == 0, res.output
    assert "samples clamped" in res.stderr and "largest shortfall" in res.stderr
    assert '"clamped": ' in res.stdout


@pytest.mark.parametrize("case", ["nan row", "missing column", "bad plot name", "not a model", "lag refused"])
def test_cli_bad_input_is_one_error_line_and_writes_nothing(files, case):
    d = files["dir"]
    model, ref, extra = d / "model.json", d / "ref.csv", []
    if case == "nan row":
        y = files["y_ref"].copy()
        y[9] = np.nan
        ref = _write(d / "bad.csv", "time,y_ref", files["t"], y)
        needle = "line 11"
    elif case == "missing column":
        ref = _write(d / "bad.csv", "time,y", files["t"], files["y_ref"])
        needle = "'y_ref' not found"
    elif case == "bad plot name":
        extra, needle = ["--plot", d / "track.jpg"], "must end in .png"
    elif case == "not a model":
        model, needle = ref, "not a JSON model file"
    else:
        save_model(ri1([Effect("sensor_lag", {"tau": 0.1})]), d / "lag.json")
        model, needle = d / "lag.json", "--measurement drop"
    before = {p.name for p in d.iterdir()}
    res = run(model, ref, "-o", d / "u.csv", *extra)
    assert res.exit_code == 1, res.output
    lines = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and needle in lines[0], res.stderr
    assert {p.name for p in d.iterdir()} == before
