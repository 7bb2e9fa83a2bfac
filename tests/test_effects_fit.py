"""`duhem fit --effects`: catalogue effects fitted jointly with the base (fitter.identification.effects_fit)."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from fitter.cli import main
from fitter.core.kernel import simulate
from fitter.core.models import load_model
from fitter.data.metrics import compare
from fitter.data.recordings import Recording
from fitter.diagnosis.fitting import first_order_ri
from fitter.identification.fit import fit_recordings

SWITCHING = {
    "S1": 0.6,
    "u_up1": 0.55,
    "u_dn1": -0.5,
    "width1": 0.06,
    "q1": -1.0,
    "S2": 0.0,
    "u_up2": 0.9,
    "u_dn2": -0.9,
    "width2": 0.2,
    "q2": 0.0,
}


def _truth():
    base = first_order_ri(-3.0, 3.0, 3.0, -3.0, -1.5, -1.5, -1 / 6)
    return base.replace(effects=[{"effect": "switching", "parameters": SWITCHING}])


def _recordings(seed: int = 4) -> list[Recording]:
    """Two rates of the same triangle (periods 2 s and 20 s, 1.5 cycles from u = 0), 0.2 % noise: a slower loop
    switches more, and the output goes on switching after each tip."""
    truth, rng, out = _truth(), np.random.default_rng(seed), []
    for period in (2.0, 20.0):
        t = np.linspace(0.0, 1.5 * period, 301)
        u = np.interp((t / period + 0.25) % 1.0, [0.0, 0.5, 1.0], [-1.0, 1.0, -1.0])
        y = simulate(truth, t, u).y
        out.append(Recording(t, u, y + rng.normal(0.0, 0.002 * np.ptp(y), len(y)), name=f"T{period:g}"))
    return out


def _csv_files(recs: list[Recording], folder) -> list[str]:
    """Each recording as folder/<name>.csv (columns time, u, y, written exactly: %.18e); their paths."""
    paths = []
    for rec in recs:
        paths.append(str(folder / f"{rec.name}.csv"))
        np.savetxt(paths[-1], np.c_[rec.t, rec.u, rec.y], delimiter=",", header="time,u,y", comments="")
    return paths


def _cli_fit(args: list[str]):
    """`duhem fit ARGS` through the CLI, its own `fit_recordings` call watched (run as it is, its FitResult
    kept): the CLI's result and that FitResult."""
    import fitter.cli.fit_command as command  # where `duhem fit` looks it up

    results = []

    def watched(*args, **kwargs):
        results.append(fit_recordings(*args, **kwargs))
        return results[-1]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(command, "fit_recordings", watched)
        res = CliRunner().invoke(main, ["fit", *args])
    assert res.exit_code == 0, res.output
    (result,) = results
    return res, result


def test_switching_fitted_with_the_base_reaches_the_noise_and_is_saved(tmp_path):
    """Without the effect an order-1 Duhem model cannot follow a loop that switches more when slower (> 2 %);
    with it (`duhem fit --effects switching` on the CSV files, its fit_recordings call watched: one fit for the
    library's result and the command's output) the fit reaches the noise (0.2 %) on both rates, and one
    population is the truth's (the other may take a share of the base's smooth part).  With
    `--faithful-minor-loops` the barrier holds through the joint refinement: the summary says the fit was
    constrained and its minor loops stay near the data.  The command prints the fitted effect and how its state
    started, and saves the model of that fit, which follows the first recording near the noise.  (The fit
    without the barrier: `test_closed_loops_start_settled_and_the_model_runs_from_where_the_fit_started`.)"""
    recs = _recordings()
    plain = fit_recordings(recs, kind="ri", order=1)
    for rec in recs:
        assert compare(rec, simulate(plain.model, rec.t, rec.u).y)["nrmse"] > 0.02
    out = tmp_path / "m.json"
    res, extended = _cli_fit(
        [
            *_csv_files(recs, tmp_path),
            *("--kind", "ri", "--order", "1", "--effects", "switching", "--faithful-minor-loops", "-o", str(out)),
        ]
    )
    nrmse = [r["nrmse"] for r in extended.summary["recordings"]]
    assert max(nrmse) < 0.0025, nrmse
    loops = extended.summary["minor_loops"]
    assert loops["constrained"] is True and loops["faithful"] is True, loops
    fitted = extended.summary["effects"]["fitted"][0]
    assert fitted["effect"] == "switching"
    p = fitted["parameters"]
    found = [
        abs(p[f"S{i}"] - SWITCHING["S1"]) < 0.1 * SWITCHING["S1"]
        and abs(p[f"u_up{i}"] - SWITCHING["u_up1"]) < 0.05
        and abs(p[f"u_dn{i}"] - SWITCHING["u_dn1"]) < 0.05
        for i in (1, 2)
    ]
    assert any(found), p
    assert extended.summary["effects"]["base"] == "ri1" and "extended by switching" in extended.summary["why"]
    assert [e.effect for e in extended.model.effects] == ["switching"]

    assert "effect switching fitted with the base: S1 = " in res.output
    assert "effects started afresh (no recording is a closed loop)" in res.output
    model = load_model(out)
    assert [e.effect for e in model.effects] == ["switching"]
    assert model.effects[0].parameters == pytest.approx(extended.model.effects[0].parameters, rel=1e-12)
    y = simulate(model, recs[0].t, recs[0].u).y
    assert compare(recs[0], y)["nrmse"] < 0.006


@pytest.mark.parametrize(
    "args,message",
    [
        (["--effects", "switching", "--hold", "measurement_drift.rate=0"], "not one of the fitted effects"),
        (["--effects", "measurement_drift", "--hold", "measurement_drift.speed=0"], "has no parameter 'speed'"),
        (["--effects", "measurement_drift", "--hold", "measurement_drift.rate"], "not EFFECT.PARAM=VALUE"),
        (["--effects", "switchin"], "unknown effect 'switchin'"),
        (["--effects", "switching", "--x0", "periodic"], "--effects needs --x0 fitted"),
    ],
)
def test_cli_fit_effects_bad_options(tmp_path, args, message):
    path = tmp_path / "r.csv"
    rec = _recordings()[0]
    np.savetxt(path, np.c_[rec.t, rec.u, rec.y], delimiter=",", header="time,u,y", comments="")
    out = tmp_path / "m.json"
    res = CliRunner().invoke(main, ["fit", str(path), "-o", str(out), *args])
    assert res.exit_code != 0 and message in res.output
    assert not out.exists()


SLOW = dict(SWITCHING, width1=0.15, u_up1=0.8, u_dn1=-0.8)
"""Thresholds near the tips: the faster loop switches part of the way, so the two loops start from different
switched states (about -0.21 and -0.59 at u = 0), which no single afresh start q S gives."""


def _closed_loops(seed: int = 5) -> list[Recording]:
    """Steady loops of the truth with `SLOW` switching: each rate run for three periods from u = 0, its last
    period kept (it starts and ends at u = 0 rising, on the loop it repeats), 0.2 % noise."""
    truth = _truth().replace(effects=[{"effect": "switching", "parameters": SLOW}])
    rng, out = np.random.default_rng(seed), []
    for period in (2.0, 20.0):
        t = np.linspace(0.0, 3 * period, 601)
        u = np.interp((t / period) % 1.0, [0.0, 0.25, 0.75, 1.0], [0.0, 1.0, -1.0, 0.0])
        y = simulate(truth, t, u).y
        last = slice(400, 601)
        out.append(
            Recording(
                t[last] - t[400], u[last], y[last] + rng.normal(0.0, 0.002 * np.ptp(y[last]), 201), name=f"L{period:g}"
            )
        )
    return out


def test_closed_loops_start_settled_and_the_model_runs_from_where_the_fit_started(tmp_path):
    """On steady loops (each recording a closed loop) the effect starts settled on each recording: the fit
    reaches the noise on both rates, the model stores the first recording's settled start, and the saved
    model and its FMU, run from the stored state, give the fit's own figure on that recording."""
    from fitter.core.effects import stored_start
    from fitter.data.cycles import closed_loop
    from fitter.fmu.build import build_fmu
    from fitter.fmu.host import simulate_fmu

    recs = _closed_loops()
    assert all(closed_loop(r) for r in recs) and not any(closed_loop(r) for r in _recordings())
    fit = fit_recordings(recs, kind="ri", order=1, effects=["switching"])
    rows = fit.summary["recordings"]
    assert fit.summary["effects"]["settled"] == [r.name for r in recs]
    assert max(r["nrmse_x0_fitted"] for r in rows) < 0.0025, rows
    assert stored_start(fit.model) is not None
    assert abs(rows[0]["nrmse"] - rows[0]["nrmse_x0_fitted"]) < 1e-9
    fmu = build_fmu(fit.model, tmp_path / "m.fmu", backend="native")
    y = simulate_fmu(fmu, recs[0].t, recs[0].u)
    assert abs(compare(recs[0], y)["nrmse"] - rows[0]["nrmse"]) < 1e-9
    fresh = fit.model.replace(effects=[{"effect": "switching", "parameters": fit.model.effects[0].parameters}])
    assert compare(recs[0], simulate(fresh, recs[0].t, recs[0].u).y)["nrmse"] > 2 * rows[0]["nrmse"]


def _referenced(seed: int = 6) -> list[Recording]:
    """The truth's base alone at two rates (1.5 cycles from u = 0), each output on its own reference (+0.4 and
    -0.3, a fifth of the range: an instrument that zeroes each record, a charge integrator's constant), 0.2 %
    noise."""
    truth, rng, out = _truth().replace(effects=[]), np.random.default_rng(seed), []
    for period, reference in ((2.0, 0.4), (20.0, -0.3)):
        t = np.linspace(0.0, 1.5 * period, 301)
        u = np.interp((t / period + 0.25) % 1.0, [0.0, 0.5, 1.0], [-1.0, 1.0, -1.0])
        y = simulate(truth, t, u).y + reference
        out.append(Recording(t, u, y + rng.normal(0.0, 0.002 * np.ptp(y), len(y)), name=f"R{period:g}"))
    return out


def test_each_recordings_reference_is_fitted_with_its_initial_state(tmp_path):
    """With `measurement_drift` named, each recording's reference (the drift's start d_0) is fitted with its x0:
    the fit reaches the noise on both records (without the effect, above 5 %); the first record's reference is
    the base's (d_0 stored as 0, and about 0 when refitted: no drift along the base's offset), the second's is
    the truth's difference, -0.7; the rate stays near 0, and the native FMU set to the second record's start (x0 and
    d_0 as parameters, as `duhem validate --x0 fitted` sets them) gives the fit's figure there.  The plain fit
    finds the same difference as the second file's output reference (without references it misses by 5 %)."""
    from fitter.fmu.build import build_fmu
    from fitter.fmu.host import simulate_fmu
    from fitter.fmu.variables import start_state_values
    from fitter.identification.exported import own_start, started

    recs = _referenced()
    unlevelled = fit_recordings(recs, kind="ri", order=1, references=False)
    assert min(r["nrmse_x0_fitted"] for r in unlevelled.summary["recordings"]) > 0.05
    plain = fit_recordings(recs, kind="ri", order=1)
    assert abs(plain.summary["references"]["values"][recs[1].name] + 0.7) < 0.02
    assert max(r["nrmse_x0_fitted"] for r in plain.summary["recordings"]) < 0.0025
    fit = fit_recordings(recs, kind="ri", order=1, effects=["measurement_drift"])
    rows = fit.summary["recordings"]
    assert max(r["nrmse_x0_fitted"] for r in rows) < 0.0025, rows
    starts = [own_start(fit.model, rec) for rec in recs]
    assert fit.model.effects[0].start == {"d": 0.0} and abs(starts[0][2][0]) < 0.02, starts
    assert abs(starts[1][2][0] + 0.7) < 0.02, starts
    assert abs(fit.model.effects[0].parameters["rate"]) < 1e-3
    fmu = build_fmu(fit.model, tmp_path / "m.fmu", backend="native")
    y = simulate_fmu(fmu, recs[1].t, recs[1].u, start=start_state_values(started(fit.model, starts[1])))
    assert abs(compare(recs[1], y)["nrmse"] - rows[1]["nrmse_x0_fitted"]) < 1e-9


def test_an_effect_fit_is_the_same_on_two_processes(monkeypatch):
    """The screened starts (both rounds) and the raced refinements run on forked processes (`fitter.workers`): on
    two the fit's parameters, RSS and model are those of one, to the last digit (each refinement is deterministic)."""
    import fitter.identification.effects_fit as effects_fit

    recs, maps = _referenced(), []
    calls = effects_fit.parallel_map
    monkeypatch.setattr(effects_fit, "parallel_map", lambda f, items: maps.append(len(items)) or calls(f, items))
    fits = []
    for n in ("1", "2"):
        monkeypatch.setenv("DUHEM_WORKERS", n)
        fits.append(fit_recordings(recs, kind="ri", order=1, effects=["saturation", "measurement_drift"]))
    assert maps[0] > 1 and maps == maps[:3] * 2  # screening, screening on and race, each over several items, both runs
    one, two = (f.summary["effects"] for f in fits)
    assert one["parameters"] == two["parameters"] and one["tried"] == two["tried"]
    assert fits[0].model.to_dict() == fits[1].model.to_dict()


def test_cli_fit_holds_a_known_parameter(tmp_path):
    """``--hold measurement_drift.rate=0``: the references alone (the rate not fitted, exactly 0 in the model),
    the fit at the noise, the held value in the summary and printed."""

    paths = _csv_files(_referenced(), tmp_path)
    out = tmp_path / "m.json"
    res = CliRunner().invoke(
        main,
        [
            "fit",
            *paths,
            "--kind",
            "ri",
            "--order",
            "1",
            "--effects",
            "measurement_drift",
            "--hold",
            "measurement_drift.rate=0",
            "-o",
            str(out),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output)["summary"]
    assert summary["effects"]["held"] == {"measurement_drift.rate": 0.0}
    assert load_model(out).effects[0].parameters == {"rate": 0.0}
    assert max(r["nrmse_x0_fitted"] for r in summary["recordings"]) < 0.0025
    assert all(len(r["effect_start_fitted"]) == 1 for r in summary["recordings"])
    text = CliRunner().invoke(
        main,
        [
            "fit",
            *paths,
            "--kind",
            "ri",
            "--order",
            "1",
            "--effects",
            "measurement_drift",
            "--hold",
            "measurement_drift.rate=0",
            "-o",
            str(out),
        ],
    )
    assert "held, not fitted: measurement_drift.rate = 0" in text.output
    assert "effect measurement_drift fitted with the base: none of its parameters" in text.output


class _Screened:
    """A stand-in for `ScreenedEffects`: screened results of given costs (and RSS); screening on gives start k
    the cost ``later[k]`` (default unchanged); its race halves a start's cost."""

    pen = None

    def __init__(self, costs, later=None):
        self.screened = [_result(cost) for cost in costs]
        self.later, self.screened_on, self.raced_starts = later or {}, [], []

    def screen_on(self, k, progress):
        self.screened_on.append(k)
        return _result(self.later.get(k, self.screened[k].cost))

    def race(self, k, progress):
        from types import SimpleNamespace

        self.raced_starts.append(k)
        return SimpleNamespace(cost=self.screened[k].cost / 2)

    def raced(self, best):
        return best


def _result(cost):
    from types import SimpleNamespace

    return SimpleNamespace(cost=cost, rss=cost)


def test_only_the_best_screened_starts_among_the_bases_race(monkeypatch):
    """`race_effects` races the `REFINED` screened starts of lowest score among all bases: a base none of whose
    starts ranks among them is not raced (None), and each raced base keeps its raced refinement of lowest cost."""
    from fitter.identification.effects_fit import REFINED, race_effects

    monkeypatch.setenv("DUHEM_WORKERS", "1")
    score = lambda i, res: res.cost  # noqa: E731
    ri, rd = _Screened([1.0, 2.0, 9.0]), _Screened([3.0, 4.0])
    out = race_effects([ri, rd], lambda i, res: score(i, res))
    assert REFINED == 2 and ri.raced_starts == [0, 1] and rd.raced_starts == [] and out[1] is None
    assert out[0].cost == 0.5
    ri, rd = _Screened([1.0, 5.0]), _Screened([3.0, 2.5])
    out = race_effects([ri, rd], score)
    assert ri.raced_starts == [0] and rd.raced_starts == [1] and (out[0].cost, out[1].cost) == (0.5, 1.25)


def test_the_screening_goes_on_for_the_best_starts_only_and_they_race_by_their_later_score(monkeypatch):
    """The screening's first round ranks every start; only the `SCREEN_KEPT` of lowest score among all bases
    are screened on, and the race takes the `REFINED` best by the score they have then: here the rate-dependent
    base's second start, fourth after the first round, overtakes and races, and the starts ranked below the kept
    ones are never screened on.  Each base's screened starts end sorted by RSS."""
    from fitter.identification.effects_fit import SCREEN_KEPT, race_effects

    monkeypatch.setenv("DUHEM_WORKERS", "1")
    ri, rd = _Screened([1.0, 2.0, 9.0]), _Screened([3.0, 4.0, 5.0], later={1: 0.5})
    out = race_effects([ri, rd], lambda i, res: res.cost)
    assert SCREEN_KEPT == 4 and ri.screened_on == [0, 1] and rd.screened_on == [0, 1]
    assert ri.raced_starts == [0] and rd.raced_starts == [1] and (out[0].cost, out[1].cost) == (0.5, 0.25)
    assert [r.rss for r in rd.screened] == [0.5, 3.0, 5.0]
