"""Issue 3's end-to-end check: fitted models (Example 1, Example 3, a noisy recording) as FMUs.

Each identified model is exported with both backends, loaded with fmpy, and
driven sample by sample: the FMU's closed curve must equal the in-process
kernel to 1e-9 and match the data within the fit's own error.
"""
import numpy as np
import pytest

import build_fmu
from fitter.core import RateIndependentModel, limiting_loop, periodic_response, simulate
from fitter.identification.fit import fit_recordings
from fitter.fmu.host import simulate_fmu, validate_fmu_file
from fitter.paper import example1, example3
from fitter.identification.rd_triangles import identify_rd_triangles
from fitter.data.recordings import Recording
from fitter.identification.ri_loop import identify_ri_loop

BACKENDS = ("native", "python")


def noisy_recording() -> tuple[Recording, RateIndependentModel]:
    """Three periods of a sine through a second-order RI model, with a transient and 1% noise."""
    truth = RateIndependentModel(A_plus=[[-3.0, 1.0], [0.0, -1.5]], A_minus=[[2.5, 0.0], [1.0, 1.2]],
                                 B_plus=[2.0, 1.0], B_minus=[1.5, 1.2], C=[1.0, 0.5], D=0.2,
                                 x0=[0.4, -0.3])
    t = np.linspace(0.0, 3.0, 1201)
    u = np.sin(2 * np.pi * t)
    y = simulate(truth, t, u).y
    rng = np.random.default_rng(7)
    y = y + 0.01 * np.ptp(y) * rng.standard_normal(len(y))
    return Recording(t=t, u=u, y=y, name="noisy"), truth


@pytest.fixture(scope="module")
def fitted():
    """name -> (model, t, u, y_data, tolerance on |FMU - data| over the last cycle)."""
    out = {}
    grid, yr, yf, _ = limiting_loop(example1.true_model(), -1.0, 1.0, 401)
    ri = identify_ri_loop(grid, yr, yf, m=2, q=7.0).model
    u = np.r_[grid, grid[-2::-1]]
    t = np.arange(len(u), dtype=float)
    y = np.r_[yr, yf[-2::-1]]
    out["example1"] = (ri, t, u, y, 2e-3)
    rd = identify_rd_triangles(example3.records(), order=2).model
    t3, u3 = example3.sine_period(2.0, 801)
    y3 = periodic_response(example3.true_model(), t3, u3).sim.y
    out["example3"] = (rd, t3, u3, y3, 0.01 * np.ptp(y3))
    rec, _ = noisy_recording()
    fit = fit_recordings([rec], kind="ri", order=2)
    resid = rec.y - fit.predict(rec)
    last = slice(800, None)
    out["noisy"] = (fit.model, rec.t, rec.u, rec.y, 5 * np.nanstd(resid[last]))
    return out


@pytest.fixture(scope="module")
def fmus(fitted, tmp_path_factory):
    d = tmp_path_factory.mktemp("fitted")
    return {(name, b): build_fmu.build_fmu(m[0], d / f"{name}_{b}.fmu", backend=b)
            for name, m in fitted.items() for b in BACKENDS}


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("name", ["example1", "example3", "noisy"])
def test_fitted_model_fmu(fitted, fmus, name, backend):
    model, t, u, y_data, tol = fitted[name]
    path = fmus[(name, backend)]
    assert validate_fmu_file(path) == []
    if name == "noisy":
        y_ref = simulate(model, t, u).y
    else:  # start the FMU on the limiting cycle: x0 = periodic state of the identified model
        model.x0 = periodic_response(model, t, u).x_periodic
        path = build_fmu.build_fmu(model, str(path).replace(".fmu", "_cycle.fmu"), backend=backend)
        y_ref = periodic_response(model, t, u).sim.y
    y_fmu = simulate_fmu(path, t, u)
    assert np.abs(y_fmu - y_ref).max() < 1e-9
    last = slice(len(t) * 2 // 3, None) if name == "noisy" else slice(None)
    assert np.abs(y_fmu[last] - y_data[last]).max() < tol
