"""Issue 3's end-to-end check: fitted models (Example 1, Example 3, a noisy recording) as FMUs.

Each identified model is exported with both backends, loaded with fmpy, and
driven sample by sample: the FMU's closed curve must equal the in-process
kernel to 1e-9 and match the data within the fit's own error.
"""

import numpy as np
import pytest
from samples import noisy_recording, ri_model, sine_input

from fitter.core import limiting_loop, periodic_response, simulate
from fitter.identification.fit import fit_recordings
from fitter.fmu.host import simulate_fmu, validate_fmu_file
from fitter.paper import example1, example3
from fitter.identification.rd_triangles import identify_rd_triangles
from fitter.identification.ri_loop import identify_ri_loop

BACKENDS = ("native", "python")


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
    # three periods of a sine through `ri_model(2)`, with a transient and 1% noise
    rec = noisy_recording(ri_model(2), *sine_input(2 * np.pi, 3, 400), noise=0.01, seed=7, name="noisy")
    fit = fit_recordings([rec], kind="ri", order=2)
    resid = rec.y - fit.predict(rec)
    last = slice(800, None)
    out["noisy"] = (fit.model, rec.t, rec.u, rec.y, 5 * np.nanstd(resid[last]))
    return out


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("name", ["example1", "example3", "noisy"])
def test_fitted_model_fmu(fitted, fmu_cache, name, backend):
    model, t, u, y_data, tol = fitted[name]
    path = fmu_cache.build(model, backend)
    assert validate_fmu_file(path) == []
    if name == "noisy":
        y_ref = simulate(model, t, u).y
    else:  # start the FMU on the limiting cycle: x0 = periodic state of the identified model
        model = model.replace(x0=periodic_response(model, t, u).x_periodic)
        path = fmu_cache.build(model, backend)
        y_ref = periodic_response(model, t, u).sim.y
    y_fmu = simulate_fmu(path, t, u)
    assert np.abs(y_fmu - y_ref).max() < 1e-9
    last = slice(len(t) * 2 // 3, None) if name == "noisy" else slice(None)
    assert np.abs(y_fmu[last] - y_data[last]).max() < tol
