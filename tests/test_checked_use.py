"""Issue 37, items 2-4: a model is checked where it is used, an output never overwrites an input, and a
recording with nothing to model is refused.

* `fitter.core.checks`: a model's convergence condition and magnitude from its parameters, whatever its
  file's ``fit_info`` says; `simulate`, `export`, `compensate` and `validate` refuse a model that fails them
  in one line, `--allow-unstable` is the way past the condition (never past the magnitude), and `validate`
  refuses an FMU whose binary and ``resources/model.json`` disagree.
* Every command refuses an output path that is one of its inputs (also a hard link, a symbolic link, or a
  report directory holding one).
* `fitter.identification.explained`: `duhem fit` of a pure-noise output explains R^2 ~ 0 of its variance and
  is refused, without a model file, unless `--allow-noise`.

The models are the suite's order-1 rate-independent model (A+ = -3, A- = 2) with an input range [-1.2, 1.2]
(beta = 2.4), hand-edited in its JSON file as a user or another tool would.  For a scalar model condition (5)
is exact: rho(e^{b A+} e^{-b A-})^(beta/b) = e^{(A+ - A-) beta} for every sub-span b.
"""

from __future__ import annotations

import json
import math
import os
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
from samples import rd_model, ri_model, sine_input
from test_cli import assert_clean_failure, invoke, listing, ok, write_csv

from fitter.core import load_model, save_model, simulate
from fitter.core.checks import (
    AGREEMENT,
    MAX_MAGNITUDE,
    ModelCheckError,
    check_agreement,
    check_model,
    convergence,
    too_large,
    with_convergence,
)
from fitter.data.recordings import Recording, load_recording
from fitter.identification.explained import EXPLAINED_MIN, NothingToModelError, check_explained, explained_variance

REPO = Path(__file__).resolve().parents[1]
BETA = 2.4
"""Span of the test model's input range [-1.2, 1.2]."""


def good_model():
    return ri_model(1).replace(input_range=(-1.2, 1.2))


def _edited(d: Path, name: str, **parameters) -> Path:
    """``d/name``: the good model's JSON with `parameters` replaced (and ``fit_info`` claiming convergence)."""
    data = good_model().to_dict()
    data["parameters"].update(parameters)
    data["fit_info"] = {"convergence": {"satisfied": True}}
    (d / name).write_text(json.dumps(data))
    return d / name


def _with_member(source: Path, target: Path, name: str, data: bytes) -> Path:
    """A copy of the FMU `source` with its member `name` replaced by `data`."""
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            zout.writestr(item, data if item.filename == name else zin.read(item.filename))
    return target


@pytest.fixture(scope="module")
def work(tmp_path_factory, fmu_cache) -> Path:
    """rec.csv (the good model on a sine of amplitude 1.1), ref.csv (a reference inside its reach), the good
    model and its native FMU, hand-edited models and FMUs carrying them."""
    d = tmp_path_factory.mktemp("checked")
    t, u = sine_input(1.0, 2, 150, amplitude=1.1)
    write_csv(d / "rec.csv", t, u, simulate(good_model(), t, u).y)
    write_csv(d / "ref.csv", t, u, 0.5 * simulate(good_model(), t, u).y, header="time,u,y_ref")
    save_model(good_model(), d / "model.json")
    (d / "model.fmu").write_bytes(Path(fmu_cache.build(good_model(), "native")).read_bytes())
    _edited(d, "a20.json", A_plus=[[20.0]])
    _edited(d, "a500.json", A_plus=[[500.0]])
    _edited(d, "x0.json", x0=[1e308])
    data = json.loads((d / "a20.json").read_text())
    del data["fit_info"]
    (d / "a20_no_fit_info.json").write_text(json.dumps(data))
    _edited(d, "mild.json", A_minus=[[-2.0]], A_plus=[[-1.0]])  # rho = e^{(-1 + 2) 2.4} = 11.02 per cycle
    for name in ("a20", "x0"):
        _with_member(d / "model.fmu", d / f"{name}.fmu", "resources/model.json", (d / f"{name}.json").read_bytes())
    tampered = good_model().to_dict()
    tampered["parameters"]["C"] = [4.0 * 1.17]
    _with_member(d / "model.fmu", d / "tampered.fmu", "resources/model.json", json.dumps(tampered).encode())
    (d / "out.csv").write_text("old\n")
    return d


# --------------------------------------------------------------------------- the checks, from the parameters


def test_condition_5_is_computed_from_the_parameters_not_the_flag():
    """Scalar model: the value is e^{(A+ - A-) beta} exactly, whatever fit_info claims."""
    conv = convergence(good_model())
    assert conv.satisfied and conv.value == pytest.approx(math.exp(-5 * BETA), rel=1e-9)
    assert conv.span == (-1.2, 1.2) and conv.limit == 1.0
    bad = good_model().replace(A_plus=[[20.0]], fit_info={"convergence": {"satisfied": True}})
    assert convergence(bad).value == pytest.approx(math.exp(18 * BETA), rel=1e-9)
    with pytest.raises(ModelCheckError, match=r"^m\.json: the convergence condition is violated"):
        check_model(bad, "m.json")
    assert convergence(good_model().replace(A_plus=[[500.0]])).value == math.inf  # e^{1200} overflows


def test_the_span_of_a_model_without_input_range():
    """Without input_range: the span of the inputs it is run with, else the small-loop limit alpha(A+ - A-)."""
    model = ri_model(1)
    assert convergence(model, (0.0, 2.0)).value == pytest.approx(math.exp(-5 * 2.0), rel=1e-9)
    small = convergence(model)
    assert small.span is None and small.limit == 0.0 and small.value == pytest.approx(-5.0)
    assert convergence(model.replace(A_plus=[[3.0]], A_minus=[[2.0]])).value == pytest.approx(1.0)


def test_rate_dependent_condition_is_the_spectral_abscissa_with_g_non_negative():
    model = rd_model(2)
    alpha = float(np.max(np.linalg.eigvals(model.A).real))
    assert alpha < 0 and convergence(model).value == pytest.approx(alpha, abs=1e-12)
    assert convergence(model.replace(A=[[0.5, 0.0], [0.0, -1.0]])).value == pytest.approx(0.5)
    assert not convergence(model.replace(g=type(model.g)(model.g.v, -model.g.g))).satisfied


def test_magnitude_is_checked_on_every_stored_number_and_not_waived():
    assert too_large(good_model()) is None
    assert too_large(good_model().replace(x0=[1e308])) == ("parameters.x0[0]", 1e308)
    assert too_large(good_model().replace(input_range=(-2e100, 1.0))) == ("input_range[0]", -2e100)
    assert too_large(good_model().replace(D=MAX_MAGNITUDE)) is None
    with pytest.raises(ModelCheckError, match=r"^m\.json: parameters\.x0\[0\] = 1e\+308 is beyond 1e\+100"):
        check_model(good_model().replace(x0=[1e308]), "m.json", allow_unstable=True)


def test_allow_unstable_returns_the_value_and_the_fmu_record_says_so():
    bad = good_model().replace(A_plus=[[20.0]], fit_info={"convergence": {"satisfied": True, "value": 0.5}})
    conv = check_model(bad, "m.json", allow_unstable=True)
    assert not conv.satisfied
    record = with_convergence(bad, conv).fit_info["convergence"]
    assert record["satisfied"] is False and record["value"] == pytest.approx(math.exp(18 * BETA), rel=1e-9)
    assert with_convergence(good_model(), convergence(good_model())) is not None
    assert with_convergence(good_model(), convergence(good_model())).fit_info == {}


def test_agreement_is_relative_to_the_output_range():
    y = np.linspace(0.0, 10.0, 11)
    assert check_agreement(y + 5e-6, y, 10.0, "a", "b", "r") == pytest.approx(5e-7)
    with pytest.raises(ModelCheckError, match=r"^a: x and b disagree on r: their outputs differ by up to 2e-06"):
        check_agreement(y + 2e-5, y, 10.0, "a: x", "b", "r")
    assert AGREEMENT == 1e-6


# --------------------------------------------------------------------------- the commands

REFUSED = {
    "A+ eigenvalue +20": ("a20.json", f"= {math.exp(18 * BETA):.6g} on the input span [-1.2, 1.2] (must be < 1)"),
    "A+ eigenvalue +500": ("a500.json", "= inf on the input span [-1.2, 1.2]"),
    "no fit_info": ("a20_no_fit_info.json", f"= {math.exp(18 * BETA):.6g}"),
    "x0 = 1e308": ("x0.json", "parameters.x0[0] = 1e+308 is beyond 1e+100 in magnitude"),
}
COMMANDS = {
    "simulate": ("simulate", "{m}", "{d}/rec.csv", "-o", "{d}/out.csv"),
    "export": ("export", "{m}", "-o", "{d}/out.fmu"),
    "compensate": ("compensate", "{m}", "{d}/ref.csv", "-o", "{d}/out.csv"),
}


@pytest.mark.parametrize("command", list(COMMANDS))
@pytest.mark.parametrize("case", list(REFUSED))
def test_a_hand_edited_model_is_refused_where_it_is_used(work, command, case):
    name, needle = REFUSED[case]
    args = [a.format(m=work / name, d=work) for a in COMMANDS[command]]
    before = {p: (work / p).read_bytes() for p in listing(work)}
    line = assert_clean_failure(invoke(*args), work, set(before), f"error: {work / name}: ", needle)
    if "x0" not in name:
        assert "the convergence condition is violated, checked from the parameters" in line
        assert "--allow-unstable" in line
    assert {p: (work / p).read_bytes() for p in listing(work)} == before


@pytest.mark.parametrize(
    "name, needle", [("a20", f"= {math.exp(18 * BETA):.6g}"), ("x0", "parameters.x0[0] = 1e+308 is beyond")]
)
def test_validate_and_simulate_check_the_model_an_fmu_carries(work, name, needle):
    fmu = work / f"{name}.fmu"
    before = listing(work)
    for args in (
        ("validate", fmu, work / "rec.csv", "--plot", work / "out.png"),
        ("simulate", fmu, work / "rec.csv", "-o", work / "out.csv"),
    ):
        assert_clean_failure(invoke(*args), work, before, f"error: {fmu} (its resources/model.json): ", needle)
    assert (work / "out.csv").read_text() == "old\n"


def test_allow_unstable_is_the_one_way_past_the_condition(work, tmp_path):
    """mild.json diverges by e^{2.4} = 11.02 per cycle: refused, then simulated with one warning line and the
    kernel's output; x0 = 1e308 stays refused with the flag."""
    args = ("simulate", work / "mild.json", work / "rec.csv", "-o", tmp_path / "y.csv")
    assert_clean_failure(invoke(*args), tmp_path, set(), f"= {math.exp(BETA):.6g} on the input span")
    result = ok(invoke(*args, "--allow-unstable"))
    (warning,) = result.stderr.splitlines()
    assert warning.startswith(f"warning: {work / 'mild.json'}: the convergence condition is violated")
    rec = load_recording(str(work / "rec.csv"), "time", "u", "y")
    y = np.loadtxt(tmp_path / "y.csv", delimiter=",", skiprows=1)[:, 2]
    np.testing.assert_allclose(y, simulate(load_model(work / "mild.json"), rec.t, rec.u).y, rtol=1e-12)
    assert_clean_failure(
        invoke("simulate", work / "x0.json", work / "rec.csv", "-o", tmp_path / "z.csv", "--allow-unstable"),
        tmp_path,
        {"y.csv"},
        "is beyond 1e+100",
    )


def test_export_with_allow_unstable_says_so_in_the_fmu(work, tmp_path):
    out = tmp_path / "a20.fmu"
    ok(invoke("export", work / "a20.json", "-o", out, "--backend", "python", "--allow-unstable"))
    with zipfile.ZipFile(out) as z:
        description = z.read("modelDescription.xml").decode()
        carried = json.loads(z.read("resources/model.json"))
    assert "WARNING: exported with --allow-unstable" in description
    assert carried["fit_info"]["convergence"]["satisfied"] is False


def test_validate_refuses_an_fmu_whose_binary_and_model_disagree(work):
    """C scaled by 1.17 in resources/model.json: the outputs differ by 0.17 max |C x| over the output range."""
    rec = load_recording(str(work / "rec.csv"), "time", "u", "y")
    tampered = good_model().replace(C=[4.0 * 1.17])
    diff = np.max(np.abs(simulate(tampered, rec.t, rec.u).y - rec.y)) / np.ptp(rec.y)
    assert 0.05 < diff < 1
    before = listing(work)
    line = assert_clean_failure(
        invoke("validate", work / "tampered.fmu", work / "rec.csv", "--plot", work / "out.png"),
        work,
        before,
        f"error: {work / 'tampered.fmu'}: its binary and its resources/model.json",
    )
    assert f"disagree on {work / 'rec.csv'}: their outputs differ by up to {diff:.3g} times the output range" in line
    result = json.loads(ok(invoke("validate", work / "model.fmu", work / "rec.csv", "--json")).stdout)
    assert result["recordings"][0]["fmu_vs_in_process_max_abs"] < AGREEMENT * np.ptp(rec.y)


# --------------------------------------------------------------------------- never overwrite an input


def test_fit_onto_its_own_recording_is_refused_and_the_recording_kept(work, tmp_path):
    rec = tmp_path / "REC.csv"
    rec.write_bytes((work / "rec.csv").read_bytes())
    before = rec.read_bytes()
    assert_clean_failure(
        invoke("fit", rec, "-o", rec), tmp_path, {"REC.csv"}, f"error: {rec}: is one of this command's inputs"
    )
    assert rec.read_bytes() == before


def test_simulate_onto_its_input_is_refused_also_through_links(work, tmp_path):
    inp = tmp_path / "in.csv"
    inp.write_bytes((work / "rec.csv").read_bytes())
    os.link(inp, tmp_path / "hard.csv")
    os.symlink(inp, tmp_path / "soft.csv")
    before = {p: (tmp_path / p).read_bytes() for p in listing(tmp_path)}
    for out in ("in.csv", "hard.csv", "soft.csv", "./in.csv"):
        assert_clean_failure(
            invoke("simulate", work / "model.json", inp, "-o", tmp_path / out),
            tmp_path,
            set(before),
            "is one of this command's inputs (",
            "write the output to another path",
        )
    assert {p: (tmp_path / p).read_bytes() for p in listing(tmp_path)} == before


def test_a_report_directory_that_holds_an_input_is_refused(work, tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    (data / "rec.csv").write_bytes((work / "rec.csv").read_bytes())
    before = listing(tmp_path)
    assert_clean_failure(
        invoke("fit", data / "rec.csv", "-o", tmp_path / "m.json", "--report", data),
        tmp_path,
        before,
        f"error: {data}: is a directory that holds this command's input {data / 'rec.csv'}",
    )
    assert (data / "rec.csv").read_bytes() == (work / "rec.csv").read_bytes()


# --------------------------------------------------------------------------- nothing to model


def test_explained_variance_of_real_hysteresis_and_of_noise():
    """The demo's truth model on examples/demo.csv explains R^2 > 0.9999; a model on a seeded white-noise
    output explains nothing (R^2 = 1 - SSE/SST computed here again)."""
    demo = load_recording(str(REPO / "examples" / "demo.csv"), "time_s", "u_V", "y_um")
    (row,) = explained_variance(load_model(REPO / "examples" / "demo_truth.json"), [demo])
    assert row["r2"] > 0.9999 and check_explained([row]) is None
    assert row["noise_rms"] < 0.01 * row["output_std"]
    t, u = sine_input(1.0, 2, 200)
    rec = Recording(t, u, np.random.default_rng(37).standard_normal(len(t)), name="noise")
    (row,) = explained_variance(ri_model(1), [rec])
    assert row["r2"] < 0 and row["threshold"] == EXPLAINED_MIN
    with pytest.raises(NothingToModelError, match=r"^noise: the fitted model explains R\^2 = "):
        check_explained([row])
    assert check_explained([row], allow_noise=True) is row


def _noise_csv(path: Path) -> Path:
    t, u = sine_input(1.0, 3, 150)
    return write_csv(path, t, u, 0.3 * np.random.default_rng(37).standard_normal(len(t)))


def test_fit_of_a_noise_output_is_refused_without_a_model(tmp_path):
    rec = _noise_csv(tmp_path / "noise.csv")
    (tmp_path / "m.json").write_text("old model\n")
    before = listing(tmp_path)
    line = assert_clean_failure(
        invoke("fit", rec, "-o", tmp_path / "m.json", "--fmu", tmp_path / "m.fmu", "--kind", "ri", "--order", "1"),
        tmp_path,
        before,
        f"error: {rec}: the fitted model explains R^2 = ",
        "no model written",
        "--allow-noise",
    )
    r2 = float(re.search(r"R\^2 = (\S+) of", line).group(1))
    assert -0.1 < r2 < 0.1
    assert (tmp_path / "m.json").read_text() == "old model\n"


def test_allow_noise_saves_the_model_with_the_numbers(tmp_path):
    rec = _noise_csv(tmp_path / "noise.csv")
    result = ok(
        invoke("fit", rec, "-o", tmp_path / "m.json", "--kind", "ri", "--order", "1", "--allow-noise", "--json")
    )
    (row,) = json.loads(result.stdout)["summary"]["explained"]
    data = load_recording(str(rec), "time", "u", "y")
    y_hat = simulate(load_model(tmp_path / "m.json"), data.t, data.u).y
    sst = np.sum((data.y - data.y.mean()) ** 2)
    assert row["r2"] >= 1 - np.sum((data.y - y_hat) ** 2) / sst - 1e-9 and row["r2"] < EXPLAINED_MIN
    assert row["output_std"] == pytest.approx(np.std(data.y)) and row["noise_rms"] > 0.5 * row["output_std"]
    (warning,) = [w for w in result.stderr.splitlines() if "R^2" in w]
    assert warning.startswith(f"warning: {rec}: the fitted model explains R^2 = {row['r2']:.3g}")
    assert warning.endswith("saved because of --allow-noise")


def test_fit_of_hysteresis_is_not_flagged(tmp_path):
    t, u = sine_input(1.0, 3, 150)
    y = simulate(ri_model(1), t, u).y
    rec = write_csv(tmp_path / "rec.csv", t, u, y + 0.01 * np.ptp(y) * np.random.default_rng(1).standard_normal(len(t)))
    result = ok(invoke("fit", rec, "-o", tmp_path / "m.json", "--kind", "ri", "--order", "1", "--json"))
    (row,) = json.loads(result.stdout)["summary"]["explained"]
    assert row["r2"] > 0.99 and "R^2" not in result.stderr
