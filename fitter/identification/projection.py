"""Variable projection's linear algebra: the output's columns in the linear entries and their shared solution.

For a fixed A (and g) the state is linear in the forcing vectors B, E and in x_0, and y = C x + D u is linear
in D (`fitter.identification.output_error`, "Variable projection"): on recording i,

    yhat_i = b_i + Psi_i theta_L + Own_i z_i,

b_i the response to the forcing left when theta_L = 0, Psi_i the responses to the unit linear entries (shared
by the recordings), Own_i the columns of recording i's own unknowns z_i (its initial state for ``"fit"``, and
the output's reference where one is fitted: a column of ones, `with_reference`).  `response_columns` computes b,
Psi and the initial-state columns in one pass of the kernel (`response_columns_all`: those of every recording, in
one call of the compiled scan); `solve_shared` solves for [theta_L, z_1, z_2, ...] by weighted least squares.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fitter.core.errors import KernelError
from fitter.core.kernel import state_responses

__all__ = [
    "LinearPart",
    "response_columns",
    "response_columns_all",
    "solve_shared",
    "split_solution",
    "lstsq_scaled",
    "scaled",
    "with_reference",
]


@dataclass
class LinearPart:
    """One recording's output as an affine function of the linear unknowns: samples `start`.. of
    base + Psi theta_L + Own z (Own None: no own unknowns)."""

    start: int
    base: np.ndarray
    Psi: np.ndarray
    Own: np.ndarray | None

    def output(self, theta_l: np.ndarray, z: np.ndarray | None) -> np.ndarray:
        """base + Psi theta_L (+ Own z)."""
        yhat = self.base + self.Psi @ theta_l
        return yhat if self.Own is None else yhat + self.Own @ z


def lstsq_scaled(M: np.ndarray, b: np.ndarray) -> np.ndarray:
    """argmin ||M z - b|| with the columns of M scaled to unit norm first (the states' responses
    differ by orders of magnitude; unscaled, the SVD cut-off would drop weak but real directions)."""
    norms = np.linalg.norm(M, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    z, *_ = np.linalg.lstsq(M / norms, b, rcond=None)
    return z / norms


def with_reference(part: LinearPart) -> LinearPart:
    """`part` with a column of ones appended to its own columns: the output's reference of its recording (the
    zero of the instrument that wrote it), fitted as its last own unknown."""
    ones = np.ones((len(part.base), 1))
    return LinearPart(part.start, part.base, part.Psi, ones if part.Own is None else np.hstack([part.Own, ones]))


def scaled(part: LinearPart, gain: float) -> LinearPart:
    """`part` of a recording whose output is `gain` times the model's (an instrument's gain,
    `fitter.identification.file_gains`; its reference column, added by `solve_shared`, is not scaled)."""
    if gain == 1.0:
        return part
    return LinearPart(part.start, gain * part.base, gain * part.Psi, None if part.Own is None else gain * part.Own)


def _own_slots(
    parts: Sequence[LinearPart], groups: Sequence[int] | None, references: Sequence[bool] | None = None
) -> tuple[list[int], list[int | None], int]:
    """Where each part's own unknowns start in [theta_L, z...], where its reference is (None: it has none) and
    the total width: one slot per part with own columns, or, with `groups`, one per group (the parts of a group
    share their unknowns: one initial state for runs that start alike; their own columns have one width); then
    one slot per part whose `references` entry is true (a reference is never shared: each file has its own)."""
    at = parts[0].Psi.shape[1]
    slots, seen = [], {}
    for i, p in enumerate(parts):
        k = 0 if p.Own is None else p.Own.shape[1]
        g = i if groups is None else groups[i]
        if g not in seen:
            seen[g] = at
            at += k
        slots.append(seen[g])
    refs: list[int | None] = []
    for r in references or [False] * len(parts):
        refs.append(at if r else None)
        at += bool(r)
    return slots, refs, at


def solve_shared(
    parts: Sequence[LinearPart],
    ys: Sequence[np.ndarray],
    weights: Sequence[np.ndarray],
    groups: Sequence[int] | None = None,
    references: Sequence[bool] | None = None,
) -> np.ndarray:
    """Weighted least squares for [theta_L, z_1, z_2, ..., r_1, r_2, ...] (z_i for the parts with own columns,
    in order; with `groups`, one z per group; r_i the reference of each part whose `references` entry is true:
    `_own_slots`): min sum_i sum_k w_ik (y_ik - yhat_ik)^2 over the samples of positive weight.  Raises
    `KernelError` when a column overflowed."""
    n_lin = parts[0].Psi.shape[1]
    slots, refs, width = _own_slots(parts, groups, references)
    rows, rhs = [], []
    for p, y, w, at, ref in zip(parts, ys, weights, slots, refs):
        sw = np.sqrt(w[p.start :])
        keep = sw > 0
        M = np.zeros((len(p.base), width))
        M[:, :n_lin] = p.Psi
        if p.Own is not None:
            M[:, at : at + p.Own.shape[1]] = p.Own
        if ref is not None:
            M[:, ref] = 1.0
        rows.append((M * sw[:, None])[keep])
        rhs.append(((y[p.start :] - p.base) * sw)[keep])
    M, b = np.concatenate(rows), np.concatenate(rhs)
    if not (np.all(np.isfinite(M)) and np.all(np.isfinite(b)) and np.abs(M).max() < 1e150):
        raise KernelError("simulation overflowed")
    return lstsq_scaled(M, b)


def split_solution(
    parts: Sequence[LinearPart],
    solution: np.ndarray,
    groups: Sequence[int] | None = None,
    references: Sequence[bool] | None = None,
) -> tuple[np.ndarray, list]:
    """theta_L and each part's own unknowns (None for a part without own columns) from `solve_shared`'s
    solution (the same `groups` and `references`); a part with a reference has it last, as the unknown of
    `with_reference`'s column."""
    slots, refs, _ = _own_slots(parts, groups, references)
    own = []
    for p, at, ref in zip(parts, slots, refs):
        z = None if p.Own is None else solution[at : at + p.Own.shape[1]]
        if ref is not None:
            z = np.r_[np.empty(0) if z is None else z, solution[ref]]
        own.append(z)
    return solution[: parts[0].Psi.shape[1]], own


def _forcing_fields(model) -> dict[float, tuple[str, str]]:
    """The (B, E) fields of each branch."""
    if model.kind == "ri":
        return {1.0: ("B_plus", "E_plus"), -1.0: ("B_minus", "E_minus")}
    return {1.0: ("B", "E"), -1.0: ("B", "E")}


def response_columns(model, lin: dict[int, tuple[str, int]], t, u, mode: str, cycle, flow_cache: dict | None = None):
    """Output columns of `model` (no effects) on one recording (module docstring), in one pass of the kernel.

    Returns a `LinearPart`: base the output with theta_L = 0 (from x0 = model.x0 for ``"model"``, from the
    cycle's fixed point for ``"periodic"``), Psi the response to each linear entry in the order of `lin`, Own
    the responses to unit initial states (``"fit"`` only).  For ``"periodic"`` every column carries its own
    fixed point of the cycle map (when its spectral radius is < 1; else the model's x0), so the periodic state
    stays linear in theta_L.  `flow_cache`: the model's flows (`fitter.core.kernel.flows`), when at hand.
    """
    return response_columns_all(model, lin, [t], [u], mode, [cycle], flow_cache)[0]


def response_columns_all(
    model, lin: dict[int, tuple[str, int]], ts, us, mode: str, cycles, flow_cache: dict | None = None
) -> list[LinearPart]:
    """`response_columns` of every recording (t_i, u_i, cycle_i), the same numbers: the kernel's pass runs the
    recordings' intervals in one call where it can (`fitter.core.kernel.state_responses`)."""
    columns = _Columns(model, lin, mode)
    starts = [cycle[0] if mode == "periodic" else 0 for cycle in cycles]
    ts = [None if t is None else t[k:] for t, k in zip(ts, starts)]
    us = [u[k:] for u, k in zip(us, starts)]
    periodic = mode == "periodic"  # the fixed point needs the states; the other modes read only the outputs
    responses = state_responses(model, ts, us, columns.X0, flow_cache, columns.forcing, outputs=not periodic)
    return [columns.part(R, u, k, cycle) for R, u, k, cycle in zip(responses, us, starts, cycles)]


class _Columns:
    """The kernel's columns for `response_columns`: column 0 the model's own forcing with the linear entries
    at 0 (and x0 for ``"model"``), one column per forcing entry of `lin` (unit forcing), then the n unit
    initial states (``"fit"`` and ``"periodic"``); `part` reads a recording's `LinearPart` off their states."""

    def __init__(self, model, lin: dict[int, tuple[str, int]], mode: str):
        n = model.order
        self.model, self.lin, self.mode = model, lin, mode
        self.forcing_lin = [(k, f, i) for k, (f, i) in enumerate(lin.values()) if f != "D"]
        self.n_x0 = 0 if mode == "model" else n
        m = self.m = 1 + len(self.forcing_lin) + self.n_x0
        fields = _forcing_fields(model)
        own = {f: np.array(getattr(model, f), dtype=float) for pair in fields.values() for f in pair}
        for f, i in lin.values():
            if f != "D":
                own[f][i] = 0.0
        cols = {f: np.zeros((n, m)) for f in own}
        for f in own:
            cols[f][:, 0] = own[f]
        for j, (_, f, i) in enumerate(self.forcing_lin):
            cols[f][i, 1 + j] = 1.0
        self.X0 = np.zeros((n, m))
        self.X0[:, m - self.n_x0 :] = np.eye(n)[:, : self.n_x0]
        if mode == "model":
            self.X0[:, 0] = model.x0
        self.forcing = {b: (cols[fb], cols[fe]) for b, (fb, fe) in fields.items()}

    def part(self, X: np.ndarray, u: np.ndarray, start: int, cycle) -> LinearPart:
        """The `LinearPart` of a recording from its states X (N, n, m), or for the modes but ``"periodic"`` its
        outputs C x (N, m), at its samples `start`.. (input u)."""
        model, lin, n, m = self.model, self.lin, self.model.order, self.m
        Y = np.einsum("i,kim->km", model.C, X) if X.ndim == 3 else X
        d_linear = any(f == "D" for f, _ in lin.values())
        base = Y[:, 0] + (0.0 if d_linear else model.D * u)
        Psi = np.empty((len(u), len(lin)))
        forcing_col = {k: 1 + j for j, (k, _, _) in enumerate(self.forcing_lin)}
        for k, (f, _) in enumerate(lin.values()):
            Psi[:, k] = u if f == "D" else Y[:, forcing_col[k]]
        if self.mode == "periodic":
            c = cycle[1] - cycle[0]
            Phi = X[c][:, m - n :]
            rho = float(np.max(np.abs(np.linalg.eigvals(Phi)))) if np.all(np.isfinite(Phi)) else np.inf
            G = Y[:, m - n :]
            if rho < 1:
                fix = np.linalg.solve(np.eye(n) - Phi, X[c][:, : m - n])
                base = base + G @ fix[:, 0]
                for k, col in forcing_col.items():
                    Psi[:, k] += G @ fix[:, col]
            else:
                base = base + G @ np.asarray(model.x0, dtype=float)
            return LinearPart(start, base, Psi, None)
        return LinearPart(start, base, Psi, Y[:, m - n :] if self.mode == "fit" else None)
