"""Effect extensions of the semilinear Duhem models (what `duhem diagnose` adds).

An effect is a small, exactly discretised extension with its own parameters,
stored in the model JSON as ``"effects": [{"effect": name, "parameters": {...}}]``
(absent = none).  `kernel.simulate` and `stepper.Stepper` both run the chain
below through `run_with_effects`, so FMUs run it unchanged.

`REGISTRY` is the one list of effects: an `EffectSpec` per effect, in chain
order, that declares its parameters (`ParameterSpec`: allowed range, log
scale), whether it needs time and whether the native C FMU implements it,
applies itself in the chain (`EffectSpec.apply`), and gives the diagnosis its
fitting bounds, starting values and vanishing point (`bounds`, `starts`,
`null`, from an `EffectContext`).  Model validation, the diagnosis, the native
FMU generator and the tests all read it (docs/architecture.md, "Adding an effect").

Input semantics are the kernel's: the input u is piecewise linear between the
samples t_0 < t_1 < ... (for a rate-independent model without time, t_k = k).
On interval k (from sample k to k+1): h_k = t_{k+1} - t_k, du_k = u_{k+1} - u_k,
v_k = du_k / h_k (constant on the interval).

The chain, always applied in this order whatever the order of the list:

1. ``backlash`` {b >= 0}: the base model sees the play operator's output
   w_k = min(u_k + b/2, max(u_k - b/2, w_{k-1})), w_0 = u_0, taken piecewise
   linear between samples (exact for a rate-independent base, whose state
   depends only on the path of w; for a rate-dependent base this is the
   specified discretisation).
2. ``rate_dependence`` {alpha >= 0}: the base dynamics are slowed by
   s(v) = 1 / (1 + alpha |v|), v the rate of the base input w on the
   interval: rate-independent base, dx/dt = v s(|v|) (A± x + B± w + E±) (the
   paper's g(du/dt) of eq (18), on top of eqs (1)-(2)); rate-dependent base,
   g(v) becomes g(v) s(v).  Exact, since v is constant per interval: in the
   kernel's interval coefficients (p, r, S) of (K), S -> S s and r -> r / s.
3. Base output y_b = C x + D w.
4. ``creep`` {k, tau > 0}: an extra state dc/dt = (k u - c) / tau, c_0 = k u_0,
   y += c.  Exact for u linear on the interval:
   c_{k+1} = a c_k + k [du_k (1 - q) + (1 - a) u_k], a = e^{-h/tau},
   q = (1 - a) / (h / tau).
5. ``relaxation`` {k, w2, w3, w4 >= 0, tau_min > 0, tau_max > 0}: a spectrum
   of creeps, four states dc_i/dt = (k_i u - c_i) / tau_i, c_i(t_0) = k_i u_0,
   y += sum_i c_i, with k_i = k w_i / (w_1 + ... + w_4), w_1 = 1 (k is the
   relaxed gain, sum k_i; every share w_i / sum w in [0, 1], so the creep
   function sum_i k_i (1 - e^{-t/tau_i}) is monotone, as for a passive
   material) and the tau_i log-spaced from tau_min to tau_max (tau_i = tau_min
   (tau_max / tau_min)^((i - 1) / 3)); each state exact as in 4 (a discrete
   relaxation spectrum, the Prony series of linear viscoelasticity and of
   dielectric relaxation; a long tau_i also takes a leakage current, whose
   charge grows as the integral of u).
6. ``switching`` {S_i >= 0, u_up_i, u_dn_i, width_i > 0, q_i in [-1, 1],
   spread_i >= 0, i = 1, 2}: field-activated switching (nucleation-limited
   switching of a ferroelectric, the thermally activated flips of domains in
   a magnet) of two populations of domains, each with a Gaussian spread of
   coercive inputs (the distribution of domains' switching fields): population
   i is `SWITCHING_NODES` equal shares j, at the normal quantiles z_j =
   Phi^-1((j - 1/2) / N) (`SWITCHING_NODES_Z`), each a switched output
   s_ij in [-S_i, S_i], y += sum_i mean_j s_ij, driven up while u is above
   u_up_i + spread_i z_j and down while it is below u_dn_i - spread_i z_j
   (a share that switches up late switches down late: its loop is wider) at
   rates that grow exponentially with the distance (Merz's law, linearised
   at the threshold)::

       ds/dt = k+(u) (S - s) - k-(u) (S + s),
       k+(u) = e^{(u - u_up)/width},  k-(u) = e^{(u_dn - u)/width}

   per unit of time (the recording's: u_up is the input at which switching up
   takes one time unit, as a coercive field is quoted at a time scale; a
   separate time constant would only shift both thresholds by width ln tau).
   spread_i = 0 (the default of a model saved without it) gives one threshold
   pair per population.  Population 1 with spread 0 is the effect's basic
   form, which `duhem diagnose` tests; population 2 and the spreads are its
   refinements (`ParameterSpec.refinement`; population 2's defaults S_2 = 0
   switch nothing).  s_ij,0 = q_i S_i (the switched fraction the
   experiment starts from).  Unlike the Duhem base, whose state moves only
   while u moves, s moves at a held input (the output keeps rising after the
   input has turned at a tip) and the switched amount depends on the time
   spent beyond a threshold, so a slower loop switches more, and the spread
   of thresholds makes that growth gradual over decades of rate.  Per
   interval, with I+- = integral of k+- dt (closed form for u linear:
   I+ = h e^{(u_k - u_up)/width} (e^d - 1)/d, d = du_k/width; I- likewise):
   s_{k+1} = s_eq + (s_k - s_eq) e^{-(I+ + I-)},
   s_eq = S (I+ - I-)/(I+ + I-) = S tanh((ln I+ - ln I-)/2).  Exact whenever
   one of k+- is negligible on the interval; otherwise s_eq is a weighted
   mean target, with an error of the order of e^{-(u_up - u_dn)/width}
   (1e-8 of S at 20 widths apart; the loops the effect is for are hundreds).
7. ``viscous`` {c}: y += c v, v the rate of u on the interval that ends at the
   sample (0 at the first sample).
8. ``thermal_drift`` {kappa}: y *= 1 - kappa W, W_k = sum_{j<k} |du_j| the
   input travel since the start of the experiment (W_0 = 0).
9. ``saturation`` {y_c, beta >= 0}: y -> y_c + tanh(beta (y - y_c)) / beta
   (beta = 0: unchanged; y_s = 1/beta is the saturation half-range).
10. ``sensor_lag`` {tau >= 0}: the measured output m obeys dm/dt = (y - m)/tau
   with y (the output of steps 3-9) taken linear between samples, m_0 = y_0:
   m_{k+1} = a m_k + dy_k (1 - q) + (1 - a) y_k with a, q as in 4 (tau = 0:
   m = y).  Its state at a sample is (m, y), y the value the next interval
   starts its line from (an output effect such as viscous makes y_k depend
   on the interval); a run of one sample leaves it unchanged.
11. ``measurement_drift`` {rate}: y += d, d_k = d_0 + rate (t_k - t_0), a drift
   of the measured output linear in time (an offset current integrated by a
   charge amplifier, a sensor zero that wanders); d_0 = 0 afresh.  Exact.  d_0
   is the reading's reference (the amplifier's integration constant, the zero
   an instrument gives each record): an initial state fitted to a recording
   (``x0="fit"``) fits d_0 with the base's x_0 (`EffectSpec.offset`).

Each effect says where it comes from (`EffectSpec.origin`): ``material`` (the
physics of the device: steps 1-9) or ``measurement`` (the measuring chain:
sensor_lag, measurement_drift); the diagnosis reports the two apart.

Each step acts in one stage of the chain (`EffectSpec.stage`): ``input``
(the base model's input w, step 1), ``rate`` (the coefficients r, S of (K),
step 2) or ``output`` (the output y, steps 4-11).  The chain's state at a
sample, `EffectState`, is the tuple of the present effects' state variables
(`EffectSpec.state`) in chain order: backlash (w, the play output), creep (c), relaxation (c1..c4), switching
(s1_1..s2_16), thermal_drift (W, the travel), sensor_lag (m, the measured output, and y, the
output before the lag), measurement_drift (d, the drift).

Start of the chain.  A simulation from the first sample starts each effect
afresh (the starts listed with each step) unless the model's effects carry a
stored start (`Effect.start`, the state at the first sample of the recording
the model was fitted on, like the base's x0; all of a model's effects or
none).  `settled_state` is the state a recording of one repeated cycle
starts from: the end state after running its input `SETTLE_RUNS` times
(each run from the previous run's end) for the effects whose state settles
(`EffectSpec.steady`), the afresh start for a drift; a fit uses it for a
recording that is a closed loop.  This package needs only
numpy: it is shipped inside the FMUs.

Modules: `spec` (the parts an effect is built from), `catalogue` (the
effects and `REGISTRY`), `switching` (the switching effect), `chain` (a model's effects, their states, the run).
"""

from ..errors import EffectError
from .catalogue import REGISTRY, play_operator, relaxation_taus
from .switching import SWITCHING_NODES, SWITCHING_NODES_Z, SWITCHING_POPULATIONS, switching_states
from .chain import (
    SETTLE_RUNS,
    Effect,
    effects_from_list,
    fresh_state,
    offset_position,
    run_with_effects,
    settled_state,
    shifted,
    stored_start,
    with_start,
)
from .spec import ORIGINS, STAGES, Chain, EffectContext, EffectSpec, EffectState, ParameterSpec

__all__ = [
    "play_operator",
    "REGISTRY",
    "STAGES",
    "ORIGINS",
    "EffectSpec",
    "ParameterSpec",
    "EffectContext",
    "Chain",
    "EffectError",
    "Effect",
    "EffectState",
    "effects_from_list",
    "run_with_effects",
    "relaxation_taus",
    "switching_states",
    "SWITCHING_POPULATIONS",
    "SWITCHING_NODES",
    "SWITCHING_NODES_Z",
    "stored_start",
    "settled_state",
    "fresh_state",
    "with_start",
    "SETTLE_RUNS",
    "offset_position",
    "shifted",
]
