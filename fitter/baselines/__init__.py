"""A user choosing a hysteresis model wants to know how the semilinear Duhem fit
compares with the models they would otherwise pick.  The three estimators
here are the project's own numpy/scipy implementations, with a small common
interface (`Baseline`: ``fit`` on one or more recordings -> one parameter
set, ``predict``, ``score``, ``parameters``, ``to_dict``; `BASELINES` by
name) and `compare_baselines` for the side-by-side NRMSE.

Conventions shared with the Duhem fit
-------------------------------------
* **Samples and preparation.**  The raw recordings, every sample: nothing is
  resampled, trimmed or smoothed.  All three models are rate independent:
  their output depends on the path of u only, not on time.  A recording is
  refused (`BaselineError`, the message names it) when it has fewer than
  `MIN_SAMPLES` samples, no output, a constant input or output, or an input
  that never reverses (`fitter.data.cycles.find_reversals`, the project's
  one reversal rule), and (`fitter.identification.fit_data.FitError`) when
  the Duhem fit's preparation refuses it (no full cycle and not one closing
  period).  Where noise makes the input reverse at many more samples than
  at its true reversals, the Duhem fit runs its model on the input through
  a dead band, a play operator of width b (a multiple of the input noise,
  `fitter.identification.fit_data.prepare_for_fit`, the exported model's
  ``backlash`` effect).  The baselines take b from the same function (on the
  same recordings) and run on w = play_b[u] (w_0 =
  u_0) in the fit and in `predict` (``input_deadband`` in
  `Baseline.to_dict`; 0 for a clean input; ``deadband=False``: the raw u).
* **Units.**  Every model is fitted in normalised units, u_n = (u - u_mid) /
  u_half (u after the dead band) and y_n = (y - y_mid) / y_half, mid-range
  and half-range over all the fitted recordings; predictions are mapped
  back.  The Preisach relay grid and the play radii span [min u_n, max u_n]
  of the fitted data.
* **Initial state: fitted.**  Each fitted recording has its own initial
  state, fitted with the shared parameters (Bouc-Wen: z0; Preisach and
  Prandtl-Ishlinskii: the input history before the first sample, below).
  `predict` fits the initial state of the recording it is given to its
  output with the parameters fixed (as the Duhem model's ``x0="fitted"``:
  the least-squares initial state over all samples); for a recording
  without an output (y all NaN) it uses the state fitted to the first
  fitted recording, as the Duhem model stores the x0 of its first recording.
* **Score.**  `Baseline.score` is `fitter.data.metrics.compare` of `predict`
  over all samples: ``nrmse`` = RMS error / output range, the project's one
  NRMSE.

Modules: `base` (the `Baseline` interface, checks, scaling), `hysterons` (the
linear hysteron models' shared least squares and input history), `preisach`,
`prandtl_ishlinskii`, `bouc_wen`, and `comparison` (`BASELINES`,
`compare_baselines`, `comparison`, `duhem_nrmse`).
"""

from fitter.baselines.base import MIN_SAMPLES, Baseline, BaselineError, check_recordings
from fitter.baselines.bouc_wen import BoucWen
from fitter.baselines.comparison import (
    BASELINES,
    compare_baselines,
    comparison,
    duhem_nrmse,
)
from fitter.baselines.prandtl_ishlinskii import PrandtlIshlinskii
from fitter.baselines.preisach import Preisach

__all__ = [
    "BaselineError",
    "Baseline",
    "Preisach",
    "PrandtlIshlinskii",
    "BoucWen",
    "BASELINES",
    "MIN_SAMPLES",
    "check_recordings",
    "compare_baselines",
    "comparison",
    "duhem_nrmse",
]
