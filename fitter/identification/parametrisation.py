"""Parametrisations: the one way to map a parameter vector theta to a model.

Every fitter in the package (`fit_recordings`, the diagnosis, the Section V
estimator) optimises a `Parametrisation`: ``size``, ``names()``,
``bounds()``, ``build(theta) -> model`` and ``theta(model) -> theta``.  The
models it builds are validated, immutable `fitter.core` models.

Canonical forms (order n, observability canonical form of (A+, C) or (A, C):
C = e1, A+ (or A) a companion matrix with free last row):

* `RICanonical`, eqs (1)-(2):
  theta = [a+ (n), A- (n^2), B+, B-, E+, E- (n each), D].
* `RDCanonical`, eqs (18)-(19): theta = [p (n), B, E (n each), D, c], A the
  companion matrix of a Hurwitz polynomial parametrised by p (`hurwitz_poly`:
  every theta gives a Hurwitz A, so the convergence condition holds by
  construction), and the rate function
  g(v) = |v| exp(c_s [v < 0] + h(ln(|v|/v_ref))), h piecewise linear in the
  log-rate between knots, h = 0 at the reference rate (g(v_ref) = v_ref, the one
  normalisation of rate dependence in a fitted model), constant beyond the
  outer knots; tabulated as a `TabulatedRate` at `RATE_NODES`.

Wrappers:

* `StateSpace`: the free entries of a template model's matrices (RI: A+-, B+-,
  E+-, x0; RD: A, B, E, x0), with optional bounds (used by the diagnosis).
* `WithEffects`: a base parametrisation plus effects of the registry
  `fitter.core.effects.REGISTRY`; parameters declared ``log`` enter theta as
  their logarithm; bounds come from the registry.
* `Physical`: a parametrisation fitted in normalised units, built in physical
  units by a `Normalisation` (exact map, `fitter.identification.scaling`).
"""

from __future__ import annotations

import itertools
import math
from typing import Sequence

import numpy as np

from fitter.core.effects import REGISTRY, Effect, EffectContext
from fitter.core.models import INPUT_MARGIN, RateDependentModel, RateIndependentModel
from fitter.core.flow import expm
from fitter.core.errors import KernelError
from fitter.core.checks import spectral_abscissa
from fitter.core.periodic import minor_loop_outputs, minor_loop_rho
from fitter.core.rates import TabulatedRate

__all__ = [
    "Parametrisation",
    "RICanonical",
    "RDCanonical",
    "StateSpace",
    "WithEffects",
    "Physical",
    "companion",
    "observability",
    "hurwitz_poly",
    "hurwitz_theta",
    "RATE_NODES",
    "RHO_MARGIN",
]

RATE_NODES = np.logspace(-3, 3, 97)
"""Positive rate nodes (multiples of v_ref) at which a fitted g is tabulated."""
RHO_MARGIN = 0.99
"""Largest spectral radius of condition (5) accepted during a rate-independent fit."""


class Parametrisation:
    """theta -> model map; subclasses set `size` and implement `names`, `build`, `theta`."""

    size: int

    def names(self) -> list[str]:
        raise NotImplementedError

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of theta (default: unbounded)."""
        return np.full(self.size, -np.inf), np.full(self.size, np.inf)

    def build(self, theta: np.ndarray):
        raise NotImplementedError

    def build_with_effects(self, theta: np.ndarray, effects: Sequence):
        """`build(theta)` with `effects` appended to its own (`WithEffects`)."""
        model = self.build(theta)
        return model.replace(effects=list(model.effects) + list(effects))

    def theta(self, model) -> np.ndarray:
        raise NotImplementedError

    def linear_entries(self) -> dict[int, tuple[str, int]]:
        """Entries of theta in which the built model is linear, as {index: (field, component)}:
        theta[index] is ``getattr(model, field)[component]`` for a forcing field (B, E and their
        branch versions) or D, and no other entry changes those fields.  The output-error
        engine eliminates them by linear least squares (`Options.eliminate`).  Default: none."""
        return {}


def _forcing_entries(offset: int, n: int, fields: Sequence[str]) -> dict[int, tuple[str, int]]:
    """{offset + k n + i: (fields[k], i)}: the consecutive forcing blocks of a canonical theta."""
    return {offset + k * n + i: (f, i) for k, f in enumerate(fields) for i in range(n)}


def companion(a: np.ndarray) -> np.ndarray:
    """Companion matrix with ones on the superdiagonal and last row `a`."""
    n = len(a)
    A = np.zeros((n, n))
    A[np.arange(n - 1), np.arange(1, n)] = 1.0
    A[-1] = a
    return A


def observability(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Observability matrix [C; C A; ...; C A^{n-1}]."""
    rows = [C]
    for _ in range(len(C) - 1):
        rows.append(rows[-1] @ A)
    return np.array(rows)


def hurwitz_poly(th: np.ndarray) -> np.ndarray:
    """Coefficients p_0..p_{n-1} of a Hurwitz polynomial s^n + p_{n-1} s^{n-1} + ... + p_0.

    The polynomial is a product of factors with positive coefficients, e^th entrywise:
    for odd n a linear factor (s + r) first, then quadratics (s^2 + b s + c), theta
    [r,] c_1, b_1, c_2, b_2, ...  (n = 1: s + e^th0; n = 2: s^2 + e^th1 s + e^th0;
    n = 3: (s + r)(s^2 + b s + c)).  Every theta gives a Hurwitz polynomial and every
    Hurwitz polynomial has a theta (`hurwitz_theta`).
    """
    e = np.exp(np.clip(th, -30, 30))
    poly = np.array([1.0])
    if len(e) % 2:
        poly = np.array([1.0, e[0]])
    for c, b in zip(e[len(e) % 2 :: 2], e[len(e) % 2 + 1 :: 2]):
        poly = np.convolve(poly, [1.0, b, c])
    return poly[1:][::-1]


def hurwitz_theta(lam: np.ndarray) -> np.ndarray:
    """Inverse of `hurwitz_poly` for the eigenvalues `lam` (unstable ones reflected).

    Complex pairs form the quadratic factors, real eigenvalues are paired in order; for an
    odd order the most negative real eigenvalue is the linear factor."""
    lam = np.where(lam.real >= 0, -np.abs(lam.real) - 1e-3 + 1j * lam.imag, lam)
    lam = lam[np.lexsort((lam.real, np.abs(lam.imag)))]
    theta = []
    if len(lam) % 2:
        theta.append(-lam[0].real)
        lam = lam[1:]
    real = [x.real for x in lam if abs(x.imag) <= 1e-12 * max(abs(x), 1.0)]
    cplx = sorted([x for x in lam if abs(x.imag) > 1e-12 * max(abs(x), 1.0) and x.imag > 0], key=lambda x: x.real)
    for a, b in zip(real[::2], real[1::2]):
        theta += [a * b, -(a + b)]
    for x in cplx:
        theta += [abs(x) ** 2, -2 * x.real]
    return np.log(theta)


class RICanonical(Parametrisation):
    """Rate-independent canonical parameters of order n (module docstring)."""

    kind = "ri"
    EXTENT_BOUND = 2.0
    """`minor_loop_extent` bound of a fit with faithful minor loops, in the fit's normalised units (the data's
    output spans [-1, 1]): half an output range beyond the data on either side."""

    def __init__(self, n: int, faithful_minor_loops: bool = False):
        self.n = n
        self.size = n * n + 5 * n + 1
        self.faithful_minor_loops = faithful_minor_loops
        self.barriers = 3 if faithful_minor_loops else 2

    def names(self) -> list[str]:
        n = self.n
        return (
            [f"A_plus[{n - 1},{j}]" for j in range(n)]
            + [f"A_minus[{i},{j}]" for i in range(n) for j in range(n)]
            + [f"{p}[{i}]" for p in ("B_plus", "B_minus", "E_plus", "E_minus") for i in range(n)]
            + ["D"]
        )

    def build(self, theta: np.ndarray) -> RateIndependentModel:
        n = self.n
        a, rest = theta[:n], theta[n:]
        Am, rest = rest[: n * n].reshape(n, n), rest[n * n :]
        Bp, Bm, Ep, Em = (rest[i * n : (i + 1) * n] for i in range(4))
        return RateIndependentModel(
            A_plus=companion(a), A_minus=Am, B_plus=Bp, B_minus=Bm, C=np.eye(n)[0], E_plus=Ep, E_minus=Em, D=rest[4 * n]
        )

    def theta(self, model: RateIndependentModel) -> np.ndarray:
        """Canonical theta of an observable model of order n (state x -> O x)."""
        T = observability(model.A_plus, model.C)
        Ti = np.linalg.inv(T)
        return np.r_[
            (T @ model.A_plus @ Ti)[-1],
            (T @ model.A_minus @ Ti).ravel(),
            T @ model.B_plus,
            T @ model.B_minus,
            T @ model.E_plus,
            T @ model.E_minus,
            model.D,
        ]

    def linear_entries(self) -> dict[int, tuple[str, int]]:
        """B+, B-, E+, E- and D (see `Parametrisation.linear_entries`)."""
        n = self.n
        out = _forcing_entries(n + n * n, n, ("B_plus", "B_minus", "E_plus", "E_minus"))
        out[self.size - 1] = ("D", 0)
        return out

    @staticmethod
    def convergence(model, u_min: float, u_max: float) -> float:
        """Condition (5) for every minor loop (`fitter.core.periodic.minor_loop_rho`) on the range the saved
        model is trusted on: the fitted span [u_min, u_max] widened by `INPUT_MARGIN` of it on each side, as
        its stored ``input_range`` (inf on overflow).  Condition (5) on the fitted span alone let fits through
        whose period map has radius 1.2-2.8 on a minor loop or on that slightly wider span (measured on
        the piezo triangles and on generated B-H and damper loops): the exported model then diverged on
        any input but the fitted one."""
        pad = INPUT_MARGIN * (u_max - u_min)
        with np.errstate(all="ignore"):
            try:
                rho = minor_loop_rho(model, u_min - pad, u_max + pad)
            except (ValueError, np.linalg.LinAlgError):
                return np.inf
        return rho if np.isfinite(rho) else np.inf

    @staticmethod
    def converges(value: float) -> bool:
        return value < 1

    LIMIT = RHO_MARGIN
    QUANTITY = (
        "max over sub-spans b <= beta of rho(e^{b A+} e^{-b A-})^(beta/b) (condition 5 for every minor "
        "loop, beta the stored input range)"
    )
    AMPLIFICATION = 1e6
    """Largest growth factor a branch may give a state error over one traversal of the fitted span."""

    @staticmethod
    def amplification(model, u_min: float, u_max: float) -> float:
        """log max(||e^{beta A+}||_2, ||e^{-beta A-}||_2, 1): the log of the largest growth of a state error
        along one branch traversed over the fitted span beta = u_max - u_min (rising: e^{beta A+}, falling:
        e^{-beta A-}; the norm, not the eigenvalues, since the canonical A+ is a companion matrix whose
        transient growth the eigenvalues miss).  Condition (5) bounds only the product of the two; a
        branch that expands by 1e15 while the other contracts converges, but turns every rounding error
        into a visible one.  inf when the exponential overflows."""
        beta = u_max - u_min
        with np.errstate(all="ignore"):
            try:
                maps = expm(np.stack([beta * model.A_plus, -beta * model.A_minus]))
                if not all(np.all(np.isfinite(M)) for M in maps):
                    return np.inf
                top = max(np.linalg.norm(M, 2) for M in maps)
            except (ValueError, np.linalg.LinAlgError):
                return np.inf
        return float(np.log(max(top, 1.0))) if np.isfinite(top) else np.inf

    @staticmethod
    def minor_loop_extent(model, u_min: float, u_max: float, output: tuple[float, float] = (0.0, 1.0)) -> float:
        """Largest |(y - y_c) / y_s| at the turning points of the settled minor loops of the stored input range
        (the fitted span widened by `INPUT_MARGIN`; `fitter.core.periodic.minor_loop_outputs`) of the base
        model (its effects left out), inf when one has no fixed point; `output` = (y_c, y_s) puts a model in
        physical units on the fit's normalised scale.  Condition (5) on every minor loop makes such loops
        settle; this says where.  Left out, an additive output effect bounded by its strength (switching)
        moves them by at most that strength, and an input-stage effect (backlash) keeps the base's input
        inside the range."""
        pad = INPUT_MARGIN * (u_max - u_min)
        with np.errstate(all="ignore"):
            try:
                y = minor_loop_outputs(model.replace(effects=[]), u_min - pad, u_max + pad)
            except (ValueError, np.linalg.LinAlgError, KernelError):
                return np.inf
        top = float(np.max(np.abs((y - output[0]) / output[1])))
        return top if np.isfinite(top) else np.inf

    def excesses(self, model, u_min: float, u_max: float, output: tuple[float, float] = (0.0, 1.0)) -> list[float]:
        """The fit's barrier quantities (each <= 0 when met): condition (5) beyond `LIMIT`, the branch
        amplification beyond `AMPLIFICATION` (relative, in logs) and, with `faithful_minor_loops`, the
        `minor_loop_extent` (on the normalised scale `output`) beyond `EXTENT_BOUND` (relative)."""
        out = [
            self.convergence(model, u_min, u_max) - self.LIMIT,
            self.amplification(model, u_min, u_max) / math.log(self.AMPLIFICATION) - 1.0,
        ]
        if self.faithful_minor_loops:
            out.append(self.minor_loop_extent(model, u_min, u_max, output) / self.EXTENT_BOUND - 1.0)
        return out


class RDCanonical(Parametrisation):
    """Rate-dependent canonical parameters of order n with g tabulated (module docstring)."""

    kind = "rd"

    def __init__(self, n: int, v_ref: float, knots: np.ndarray):
        self.n, self.v_ref, self.knots = n, float(v_ref), np.asarray(knots, dtype=float)
        self.n_c = len(self.knots) - 1
        self.size = 3 * n + 2 + self.n_c

    def names(self) -> list[str]:
        n = self.n
        rates = [f"g_log_at_{self.v_ref * np.exp(k):.4g}" for k in self.knots if k != 0.0]
        return (
            [f"A_poly[{j}]" for j in range(n)]
            + [f"B[{i}]" for i in range(n)]
            + [f"E[{i}]" for i in range(n)]
            + ["D", "g_sign"]
            + rates
        )

    def g_values(self, c: np.ndarray, v: np.ndarray) -> np.ndarray:
        """g(v) = |v| exp(c_s [v<0] + h(s)), s = ln(|v|/v_ref), h linear between the knots."""
        s = np.log(np.abs(v) / self.v_ref)
        k0 = int(np.argmin(np.abs(self.knots)))
        h = np.interp(s, self.knots, np.insert(np.asarray(c[1:], dtype=float), k0, 0.0))
        return np.abs(v) * np.exp(np.clip(c[0] * (v < 0) + h, -30, 30))

    def build(self, theta: np.ndarray) -> RateDependentModel:
        n = self.n
        nodes = np.r_[-self.v_ref * RATE_NODES[::-1], self.v_ref * RATE_NODES]
        g = TabulatedRate(nodes, self.g_values(theta[3 * n + 1 :], nodes))
        return RateDependentModel(
            A=companion(-hurwitz_poly(theta[:n])),
            B=theta[n : 2 * n],
            E=theta[2 * n : 3 * n],
            C=np.eye(n)[0],
            D=theta[3 * n],
            g=g,
        )

    def theta(self, model: RateDependentModel, c: np.ndarray | None = None) -> np.ndarray:
        """Canonical theta of (A, B, E, C, D); the rate part is `c` (default zeros: g = |v|)."""
        T = observability(model.A, model.C)
        c = np.zeros(1 + self.n_c) if c is None else c
        return np.r_[hurwitz_theta(np.linalg.eigvals(model.A)), T @ model.B, T @ model.E, model.D, c]

    def linear_entries(self) -> dict[int, tuple[str, int]]:
        """B, E and D (see `Parametrisation.linear_entries`)."""
        n = self.n
        out = _forcing_entries(n, n, ("B", "E"))
        out[3 * n] = ("D", 0)
        return out

    @staticmethod
    def convergence(model, u_min: float, u_max: float) -> float:
        """max Re eig(A) (`fitter.core.checks.spectral_abscissa`, the check at use): rho(period map) < 1 iff A is
        Hurwitz, since g >= 0."""
        return spectral_abscissa(model.A)

    @staticmethod
    def converges(value: float) -> bool:
        return value < 0

    barriers = 2
    LIMIT = -1e-3
    QUANTITY = "max Re eig(A) (< 0 <=> rho(period map) < 1 since g >= 0)"
    DAMPING = 0.1
    """Smallest damping ratio -Re(lambda)/|lambda| a fitted mode of A may have."""

    @classmethod
    def excesses(cls, model, u_min: float, u_max: float, output: tuple[float, float] = (0.0, 1.0)) -> list[float]:
        """The fit's barrier quantities (each <= 0 when met): max Re eig(A) beyond `LIMIT`, and
        `damping_excess` (`output`, the normalised scale, does not enter)."""
        return [cls.convergence(model, u_min, u_max) - cls.LIMIT, cls.damping_excess(model)]

    @classmethod
    def damping_excess(cls, model) -> float:
        """max over the eigenvalues of A of Re(lambda) + DAMPING |lambda| (<= 0: every mode damped)."""
        lam = np.linalg.eigvals(model.A)
        return float(np.max(lam.real + cls.DAMPING * np.abs(lam)))


def _free_keys(model) -> list[str]:
    if isinstance(model, RateIndependentModel):
        return ["A_plus", "A_minus", "B_plus", "B_minus", "E_plus", "E_minus", "x0"]
    return ["A", "B", "E", "x0"]


class StateSpace(Parametrisation):
    """The free entries of a template model (C, D, g, effects fixed): theta = [A.., B.., E.., x0]."""

    def __init__(self, template, lower: np.ndarray | None = None, upper: np.ndarray | None = None):
        self.template = template
        self.keys = _free_keys(template)
        self.shapes = [np.shape(getattr(template, k)) for k in self.keys]
        self._sizes = [int(np.prod(s)) for s in self.shapes]
        self.size = sum(self._sizes)
        self._lower = np.full(self.size, -np.inf) if lower is None else np.asarray(lower, dtype=float)
        self._upper = np.full(self.size, np.inf) if upper is None else np.asarray(upper, dtype=float)

    def names(self) -> list[str]:
        return [f"{k}[{i}]" for k, s in zip(self.keys, self.shapes) for i in range(int(np.prod(s)))]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self._lower.copy(), self._upper.copy()

    def values(self, theta: np.ndarray) -> dict:
        out, i = {}, 0
        for k, s, n in zip(self.keys, self.shapes, self._sizes):
            out[k] = np.reshape(theta[i : i + n], s)
            i += n
        return out

    def build(self, theta: np.ndarray):
        return self.template.replace(**self.values(theta))

    def build_with_effects(self, theta: np.ndarray, effects: Sequence):
        """`build(theta)` with `effects` after the template's own, validated once (one `replace`)."""
        return self.template.replace(**self.values(theta), effects=list(self.template.effects) + list(effects))

    def theta(self, model) -> np.ndarray:
        return np.concatenate([np.ravel(getattr(model, k)) for k in self.keys])

    def linear_entries(self) -> dict[int, tuple[str, int]]:
        """The forcing fields' entries (B, E and their branch versions; see `Parametrisation.linear_entries`)."""
        out, at = {}, 0
        for k, s in zip(self.keys, self.shapes):
            size = int(np.prod(s))
            if k[0] in "BE":
                out.update({at + i: (k, i) for i in range(size)})
            at += size
        return out


class WithEffects(Parametrisation):
    """A base parametrisation plus effects of the registry: theta = [base..., effects...].

    Effect parameters declared ``log`` in their `ParameterSpec` enter theta as
    log(value).  Bounds: the registry's ``bounds(ctx)`` (in theta's coordinates).
    `held` ({"effect.parameter": value}) parameters are not in theta: they are held at
    their value (what the user knows, `fitter.identification.effects_fit.check_held`);
    with ``refinements=False``, so are the parameters declared ``refinement``, at their
    ``default`` (the effects' basic forms, as `duhem diagnose` tests them).
    """

    def __init__(
        self,
        base: Parametrisation,
        effects: Sequence[str],
        ctx: EffectContext,
        refinements: bool = True,
        held: dict[str, float] | None = None,
    ):
        self.base, self.effects, self.ctx = base, list(effects), ctx
        self.specs = [REGISTRY[e] for e in self.effects]
        self.held = {
            **{
                f"{s.name}.{p.name}": p.default
                for s in self.specs
                for p in s.parameters
                if p.refinement and not refinements
            },
            **(held or {}),
        }
        self.keys = [(s.name, p) for s in self.specs for p in self._fitted(s)]
        self.n_base = base.size
        self.size = base.size + len(self.keys)

    def _fitted(self, spec) -> list:
        """`spec`'s parameters that are in theta (class docstring)."""
        return [p for p in spec.parameters if f"{spec.name}.{p.name}" not in self.held]

    def names(self) -> list[str]:
        return self.base.names() + [f"{e}.{p.name}" for e, p in self.keys]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.base.bounds()
        elo, ehi = [], []
        for spec in self.specs:
            b = spec.bounds(self.ctx)
            for p in self._fitted(spec):
                a, z = b[p.name]
                elo.append(math.log(a) if p.log else a)
                ehi.append(math.log(z) if p.log else z)
        return np.r_[lo, elo], np.r_[hi, ehi]

    def starts(self) -> list[np.ndarray]:
        """The effect part of theta at every combination of the effects' starting values
        (registry order, the last effect varying fastest)."""
        combos = itertools.product(*[spec.starts(self.ctx) for spec in self.specs])
        return [self.encode(combo) for combo in combos]

    def null(self) -> np.ndarray:
        """The effect part of theta at which every effect (almost) vanishes: the nested model."""
        return self.encode([spec.null(self.ctx) for spec in self.specs])

    def encode(self, values: Sequence[dict]) -> np.ndarray:
        """theta-coordinates of one parameter dict per effect (physical units)."""
        return np.array(
            [
                math.log(v[p.name]) if p.log else float(v[p.name])
                for spec, v in zip(self.specs, values)
                for p in self._fitted(spec)
            ]
        )

    def effect_list(self, theta: np.ndarray) -> list[Effect]:
        vals = iter(theta[self.n_base :])
        out = []
        for spec in self.specs:
            params = {p.name: self.held.get(f"{spec.name}.{p.name}", p.default) for p in spec.parameters}
            for p in self._fitted(spec):
                v = float(next(vals))
                params[p.name] = math.exp(v) if p.log else v
            out.append(Effect(spec.name, params))
        return out

    def build(self, theta: np.ndarray):
        return self.base.build_with_effects(theta[: self.n_base], self.effect_list(theta))

    def linear_entries(self) -> dict[int, tuple[str, int]]:
        """The base's linear entries when every effect, the template's own and the fitted ones, is `additive`
        (the output is then the base's plus terms driven by the input and time alone); else none."""
        own = getattr(getattr(self.base, "template", None), "effects", ())
        if all(s.additive for s in self.specs) and all(e.spec.additive for e in own):
            return self.base.linear_entries()
        return {}

    def theta(self, model) -> np.ndarray:
        own = {e.effect: e.parameters for e in model.effects if e.effect in self.effects}
        base = model.replace(effects=[e for e in model.effects if e.effect not in self.effects])
        return np.r_[self.base.theta(base), self.encode([own[e] for e in self.effects])]


class Physical(Parametrisation):
    """`param` fitted in normalised units, built in physical units by `scaling.to_physical`."""

    def __init__(self, param: Parametrisation, scaling):
        self.param, self.scaling = param, scaling
        self.size = param.size

    def names(self) -> list[str]:
        return self.param.names()

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.param.bounds()

    def build(self, theta: np.ndarray):
        return self.scaling.to_physical(self.param.build(theta))
