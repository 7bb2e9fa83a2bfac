"""Communication-point stepping of a model, as a co-simulation host sees it.

Semantics (the FMUs implement exactly this; the README documents it):

* The stepper keeps an *anchor* (t_a, u_a, x_a): time, input and state at the
  last communication point, and the *current* time t and input u.
* The output at the current time is y = C x + D u where x is the state moved
  from the anchor along the straight input path u_a -> u over [t_a, t]
  (`flow.AffineFlow.step`, the same exact flow that `kernel.simulate` uses).
  So a host that sets u(t_k) and reads y(t_k) at every sample gets exactly
  `simulate` of the sampled input, with no one-sample lag; y depends directly
  on u.
* `do_step(h)` commits the current point as the new anchor and advances t by h.
  A host that does not set a new input holds u, and a held input moves neither
  model (du = 0, and g(0) = 0).
* While t == t_a (at the start), setting u re-anchors the input without moving
  the state: x0 is the state at the first input.
* The whole state is the tuple (t_a, u_a, x_a, t, u, du) of `get_state`, so
  rolling back with `set_state` restores the exact same future.
* A model with effects (`fitter.core.effects`) also carries the effect chain's
  state at the anchor, s_a (an `effects.EffectState`, the present effects'
  state values in chain order; None until the first step: the chain starts
  at the effects' stored start, else afresh at the anchor input); the current point is the one-interval run of
  `effects.run_with_effects` from (t_a, u_a, x_a, s_a), so stepping equals
  `simulate`; `get_state` is then (t_a, u_a, x_a, t, u, s_a, du).
* Input interpolation (FMI ``fmi2SetRealInputDerivatives``, order 1):
  `set_input_derivative(du)` gives du/dt of the input at the current point;
  `do_step(h)` then moves the current input on to u + du h (after committing
  the anchor), so the input over the step is u_k + du (t - t_k) and the state
  at t_{k+1} is the exact flow along it.  A host that sets u(t_k) and
  du/dt = (u_{k+1} - u_k) / h before each step reads y(t_{k+1}) equal to
  `simulate` of the piecewise-linear input, with no one-sample lag.  The
  derivative stays until it is set again (0 at the start: a held input).
  Setting u afterwards replaces the extrapolated value.
* A model with an ``input_range`` holds the input at its edges
  (`models._ModelBase.model_input`): u and u_a are kept as set, the model
  acts on the held values.
"""

from __future__ import annotations

import math

import numpy as np

from .effects import run_with_effects
from .errors import KernelError
from .flow import flows, one_interval

__all__ = ["Stepper"]


class Stepper:
    """Step a model between communication points; see the module docstring."""

    def __init__(self, model, t0: float = 0.0, u0: float = 0.0, x0=None):
        self.model = model
        self._flows = flows(model)
        self.reset(t0, u0, x0)

    def reset(self, t0: float = 0.0, u0: float = 0.0, x0=None) -> None:
        """Back to time t0 with input u0 and state x0 (default: the model's x0)."""
        x = self.model.x0 if x0 is None else np.asarray(x0, dtype=float)
        self.t_a, self.u_a, self.x_a = float(t0), float(u0), np.array(x, dtype=float)
        self.t, self.u = float(t0), float(u0)
        self.du = 0.0
        self._x_cache = None
        self.s_a = None

    def set_input(self, u: float) -> None:
        if not math.isfinite(u):
            raise KernelError(f"input u = {u} is not finite")
        self.u = float(u)
        if self.t == self.t_a:
            self.u_a = self.u
        self._x_cache = None

    def set_input_derivative(self, du: float) -> None:
        """du/dt of the input from the current point on (module docstring, input interpolation)."""
        if not math.isfinite(du):
            raise KernelError(f"input derivative du/dt = {du} is not finite")
        self.du = float(du)

    def state(self) -> np.ndarray:
        """State at the current time and input."""
        if self._x_cache is None:
            self._x_cache = self._advance()
        return self._x_cache

    def output(self) -> float:
        if self.model.effects:
            self.state()
            return self._y_cache
        return float(self.model.C @ self.state() + self.model.D * self.model.model_input(self.u))

    def do_step(self, h: float) -> None:
        if not (math.isfinite(h) and h > 0):
            raise KernelError(f"step size {h} must be positive and finite")
        self.x_a = self.state()
        if self.model.effects:
            self.s_a = self._s_cache
        self.t_a, self.u_a = self.t, self.u
        self.t = self.t + h
        self.u = self.u + self.du * h
        if not math.isfinite(self.u):
            raise KernelError(f"the extrapolated input u + du h = {self.u} is not finite")
        self._x_cache = None

    def _advance(self) -> np.ndarray:
        if self.model.effects:
            return self._advance_effects()
        u_a, u = self.model.model_input(self.u_a), self.model.model_input(self.u)
        if self.t == self.t_a or u == u_a:
            return self.x_a.copy()
        branch, p, r, S = one_interval(self.model, self.t_a, self.t, u_a, u)
        return self._flows[branch].step(self.x_a, p, r, S)

    def _advance_effects(self) -> np.ndarray:
        if self.t == self.t_a:
            t, u = np.array([self.t_a]), np.array([self.u_a])
        else:
            t, u = np.array([self.t_a, self.t]), np.array([self.u_a, self.u])
        X, y, end = run_with_effects(self.model, t, self.model.model_input(u), self.x_a, self._flows, self.s_a)
        self._y_cache, self._s_cache = float(y[-1]), end
        return X[-1].copy()

    def get_state(self) -> tuple:
        if self.model.effects:
            return (self.t_a, self.u_a, self.x_a.copy(), self.t, self.u, self.s_a, self.du)
        return (self.t_a, self.u_a, self.x_a.copy(), self.t, self.u, self.du)

    def set_state(self, state: tuple) -> None:
        if self.model.effects:
            t_a, u_a, x_a, t, u, s_a, du = state
            self.s_a = None if s_a is None else tuple(map(float, s_a))
        else:
            t_a, u_a, x_a, t, u, du = state
        self.du = float(du)
        self.t_a, self.u_a, self.x_a = float(t_a), float(u_a), np.array(x_a, dtype=float)
        self.t, self.u = float(t), float(u)
        self._x_cache = None
