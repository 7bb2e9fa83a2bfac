"""A model is checked where it is used, from its parameters, not trusted from its file.

A model file is data: a hand edit or another tool can put into it parameters
that no fit produced, and the flags it stores (``fit_info.convergence``) say
what its fit found, not what its parameters are.  `check_model` looks at the
parameters themselves, each time a command is about to run or export a model:

* **Magnitude** (`too_large`): every stored number (the parameters, the rate
  table g, ``input_range``, the effects' parameters and starts) is finite with
  |v| <= `MAX_MAGNITUDE` = 1e100.  The kernel multiplies a few stored numbers
  together (a state by a matrix exponential by an input span) and squares
  outputs (RMS errors): 1e100^2 = 1e200 stays far below the float limit
  1.8e308, while x0 = 1e308 overflows at the first product.  No option waives
  this check.
* **Convergence** (`convergence`), the condition the fit enforces
  (`fitter.identification.parametrisation`): a wrong initial state dies out.

  - Rate-independent, condition (5) of Theorem 1 on every minor loop
    (`fitter.core.periodic.minor_loop_rho`):
    r = max_{b = beta k / K} rho(e^{b A+} e^{-b A-})^(beta / b) < 1, beta the
    span the model's input can travel: its ``input_range`` (beyond it the
    input is held at the edge), else the span of the inputs it is run with.
    With neither (an export of a model without ``input_range``), the limit of
    small loops, b -> 0, where r -> e^{beta alpha(A+ - A-)}: the spectral
    abscissa alpha(A+ - A-) < 0.
  - Rate-dependent: alpha(A) = max Re eig(A) < 0 with g >= 0 at every node of
    its table; then rho(period map) < 1, since dx = g(du/dt) (A x + ...) dt
    runs the Hurwitz flow of A forward only.

  ``allow_unstable`` (``--allow-unstable``) is the one way past it.
* **Agreement** (`check_agreement`): two outputs that must be the same (an
  FMU's binary and the model it carries, simulated by the kernel) differ by at
  most max(`AGREEMENT`, K s) of the output range, `AGREEMENT` = 1e-6 and
  K = `ROUNDING_FACTOR` = 100.  s (`rounding_sensitivity`) is the model's own
  amplification of rounding on the input at hand: two correct implementations
  of one model round differently, and a model whose output moves far on a
  change of a few units in the last place (large states whose contributions
  to y cancel, a nearly neutral mode that carries each step's rounding along,
  small loops that settle far outside the data) turns that into a difference
  that no export removes.  s is measured, not assumed: the largest deviation
  max_i max_k |y_i(t_k) - y(t_k)| / (output range) of the kernel's output y
  of the model as stored from y_i of

  - the kernel on its dense path (`_dense_flows`): every interval's map from
    block exponentials, the native binary's algorithm, where the kernel takes
    the eigenbasis A = V diag(lambda) V^-1 (cond(V) < 1e6): the two differ by
    up to eps cond(V) per step;
  - `ROUNDING_RUNS` = 4 runs with every parameter p (the start state x0 among
    them, and a rate table's g values) replaced by p (1 + 4 eps z), z ~ N(0, 1)
    drawn from ``default_rng(ROUNDING_SEED)`` (`ROUNDING_PERTURBATION` =
    8.9e-16, a few units in the last place; deterministic).

  A well-conditioned model gives s ~ 1e-15, so the limit stays `AGREEMENT`.
  Measured, the native binary's difference over s: 1.0 for a fitted order-4
  model of the friction rig (1.19e-4 of the range on its 4 bar recording: the
  dense path; the perturbed parameters alone give 2e-8), 0.01 to 1.0 for the
  suite's order-2 models in realisations T x, cond(T) 4e4 to 4e10 (s 1e-11
  to 1e-2); K = 100 leaves room for other platforms' rounding.  An altered
  parameter moves the output by its change times the output's sensitivity to
  it, large in such a model for most parameters but not for all
  (`tests/test_validate_rounding.py`: 1e-6 of its value moves the output by
  0.35 of the range for an entry of A+, by 3e-7 for D, under a limit of
  1.2e-3), so ``duhem validate`` also compares the parameters themselves,
  exactly: the binary's, the modelDescription's start values and the model
  JSON's (`fitter.cli.fmu_commands`).

A failed check raises a `ModelCheckError` whose message starts with the file.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .errors import DuhemError
from .periodic import minor_loop_rho

__all__ = [
    "MAX_MAGNITUDE",
    "AGREEMENT",
    "ModelCheckError",
    "Convergence",
    "too_large",
    "spectral_abscissa",
    "convergence",
    "check_model",
    "with_convergence",
    "ROUNDING_FACTOR",
    "ROUNDING_PERTURBATION",
    "ROUNDING_RUNS",
    "ROUNDING_SEED",
    "rounding_sensitivity",
    "agreement_limit",
    "check_agreement",
]

MAX_MAGNITUDE = 1e100
"""Largest |value| of a stored number of a model (module docstring)."""
AGREEMENT = 1e-6
"""Largest difference, as a fraction of the output range, between two outputs that must be the same, for a model
that does not amplify rounding (`agreement_limit`)."""
ROUNDING_FACTOR = 100.0
"""K of the agreement limit max(`AGREEMENT`, K s), s the model's `rounding_sensitivity`."""
ROUNDING_PERTURBATION = 4 * float(np.finfo(float).eps)
"""Relative perturbation (times a standard normal draw) of every parameter in `rounding_sensitivity`: 8.9e-16."""
ROUNDING_RUNS = 4
"""Perturbed runs of `rounding_sensitivity`."""
ROUNDING_SEED = 0
"""Seed of the perturbations of `rounding_sensitivity` (deterministic)."""


class ModelCheckError(DuhemError):
    """A model that fails its check at use: not finite, too large, not convergent, or two runs disagree."""


@dataclass(frozen=True)
class Convergence:
    """The convergence condition evaluated from a model's parameters: ``value < limit`` holds it.

    Attributes
    ----------
    quantity : what ``value`` is (the formula)
    value : its value (inf when an exponential overflows)
    limit : the bound it must stay below
    span : the input span [lo, hi] of a rate-independent model's condition (5), None otherwise
    """

    quantity: str
    value: float
    limit: float
    span: tuple[float, float] | None = None

    @property
    def satisfied(self) -> bool:
        return bool(self.value < self.limit)

    def text(self) -> str:
        """``<quantity> = <value> (must be < <limit>)``, with the span when there is one."""
        where = f" on the input span [{self.span[0]:.6g}, {self.span[1]:.6g}]" if self.span else ""
        return f"{self.quantity} = {self.value:.6g}{where} (must be < {self.limit:g})"


def _numbers(value, path: str) -> Iterator[tuple[str, float]]:
    """Every number in a JSON-like value, with its path (``parameters.x0[0]``); strings and booleans skipped."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _numbers(v, f"{path}.{k}" if path else str(k))
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            yield from _numbers(v, f"{path}[{i}]")
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield path, float(value)


def too_large(model) -> tuple[str, float] | None:
    """The first stored number of `model` that is not finite or exceeds `MAX_MAGNITUDE` in magnitude, as
    (its key in the model file, value); None when every one is within it."""
    data = model.to_dict()
    stored = {k: data[k] for k in ("parameters", "g", "input_range", "effects") if k in data}
    return next(((p, v) for p, v in _numbers(stored, "") if not abs(v) <= MAX_MAGNITUDE), None)


def spectral_abscissa(A) -> float:
    """alpha(A) = max Re lambda(A): the flow e^{t A} decays iff alpha(A) < 0 (A finite: numpy's eigvals)."""
    return float(np.max(np.linalg.eigvals(np.asarray(A, dtype=float)).real))


def _ri_convergence(model, span: tuple[float, float] | None) -> Convergence:
    span = model.input_range if model.input_range is not None else span
    if span is None or not span[1] > span[0]:
        return Convergence(
            "alpha(A+ - A-), condition (5) on small loops (no input_range, no input span)",
            spectral_abscissa(model.A_plus - model.A_minus),
            0.0,
        )
    with np.errstate(all="ignore"):
        try:
            rho = minor_loop_rho(model, float(span[0]), float(span[1]))
        except (ValueError, np.linalg.LinAlgError):
            rho = float("inf")
    return Convergence(
        "condition (5) on every loop, max over sub-spans b of rho(e^{b A+} e^{-b A-})^(span/b)",
        rho if np.isfinite(rho) else float("inf"),
        1.0,
        (float(span[0]), float(span[1])),
    )


def _rd_convergence(model) -> Convergence:
    g = np.asarray(getattr(model.g, "g", []), dtype=float)
    if g.size and np.min(g) < 0:
        return Convergence("-min g (the rate table reverses the flow where g < 0)", float(-np.min(g)), 0.0)
    return Convergence("max Re eig(A)", spectral_abscissa(model.A), 0.0)


def convergence(model, span: tuple[float, float] | None = None) -> Convergence:
    """The convergence condition of `model` from its parameters (module docstring); `span` is the input span
    the model is run on, used by a rate-independent model without ``input_range``."""
    return _rd_convergence(model) if model.kind == "rd" else _ri_convergence(model, span)


def check_model(
    model, source: str, *, span: tuple[float, float] | None = None, allow_unstable: bool = False
) -> Convergence:
    """Check `model` (read from `source`) before it is used: finite, within `MAX_MAGNITUDE`, convergent.

    Parameters
    ----------
    model : a rate-independent or rate-dependent model
    source : the file it came from (the message starts with it)
    span : (lo, hi), the range of the inputs the command runs it on (for a model without ``input_range``)
    allow_unstable : return a violated convergence condition instead of raising (the caller says so)

    Returns
    -------
    Convergence
        The condition's value (`Convergence.satisfied` false only under `allow_unstable`).

    Raises
    ------
    ModelCheckError
        A stored number beyond `MAX_MAGNITUDE` or not finite (whatever `allow_unstable`); the condition
        violated without `allow_unstable`.
    """
    bad = too_large(model)
    if bad is not None:
        raise ModelCheckError(
            f"{source}: {bad[0]} = {bad[1]:.6g} is beyond {MAX_MAGNITUDE:g} in magnitude (a model "
            "this large overflows the simulation); correct it or fit the model again"
        )
    conv = convergence(model, span)
    if not conv.satisfied and not allow_unstable:
        raise ModelCheckError(
            f"{source}: the convergence condition is violated, checked from the parameters: "
            f"{conv.text()}, so a wrong initial state need not die out and the output may grow "
            "without bound; fit the model again, or pass --allow-unstable to use it anyway"
        )
    return conv


def with_convergence(model, conv: Convergence):
    """`model` whose ``fit_info.convergence`` records `conv` when it is violated (what an FMU's description
    warns about); `model` unchanged when `conv` holds."""
    if conv.satisfied:
        return model
    old = model.fit_info.get("convergence")
    record = {
        **(old if isinstance(old, dict) else {}),
        "satisfied": False,
        "quantity": conv.quantity,
        "value": conv.value if np.isfinite(conv.value) else None,
        "checked": "from the parameters where the model was used",
    }
    return model.replace(fit_info={**model.fit_info, "convergence": record})


def _perturbed(model, rng: np.random.Generator, relative: float):
    """`model` with every parameter p (x0 among them, and a rate table's g values) replaced by
    p (1 + relative z), z ~ N(0, 1) drawn from `rng` entry by entry; the effects and the input range as stored."""

    def shake(value) -> np.ndarray:
        value = np.asarray(value, dtype=float)
        return value * (1.0 + relative * rng.standard_normal(value.shape))

    changes = {k: shake(getattr(model, k)) for k in model.PARAMS}
    if model.kind == "rd" and hasattr(model.g, "v") and hasattr(model.g, "g"):
        changes["g"] = type(model.g)(model.g.v, shake(model.g.g))
    return model.replace(**changes)


def _dense_flows(model) -> dict:
    """The kernel's flows of `model` (`fitter.core.flow.flows`) held on their dense path: every interval's
    map from the block exponential of `AffineFlow.affine_maps`, the native binary's algorithm, where the
    kernel itself takes the eigenbasis A = V diag(lambda) V^-1 (cond(V) < 1e6, ``AffineFlow.modal``)."""
    from .flow import flows

    fl = flows(model)
    for flow in fl.values():
        flow.modal = False
    return fl


def _runs(model, rng: np.random.Generator) -> Iterator[tuple]:
    """(model, flow cache) of each run of `rounding_sensitivity`: the dense path, then `ROUNDING_RUNS`
    perturbed parameter sets."""
    yield model, _dense_flows(model)
    for _ in range(ROUNDING_RUNS):
        yield _perturbed(model, rng, ROUNDING_PERTURBATION), None


def rounding_sensitivity(model, t, u, output_range: float, y=None) -> float:
    """s, the model's amplification of rounding on the input (t, u) (module docstring).

    Parameters
    ----------
    model : a rate-independent or rate-dependent model (with its effects)
    t, u : the input it is run on (t None: the sample index)
    output_range : the range that scales the deviation (0 counts as 1)
    y : the kernel's output of `model` itself on (t, u), when already computed

    Returns
    -------
    float
        s = max_i max_k |y_i(t_k) - y(t_k)| / output_range over the kernel's outputs y_i of `model` on its
        dense path (`_dense_flows`) and of `ROUNDING_RUNS` parameter sets with every parameter p replaced by
        p (1 + `ROUNDING_PERTURBATION` z), z ~ N(0, 1) drawn from ``default_rng(ROUNDING_SEED)``; inf when
        a run's output is not finite.
    """
    from .kernel import simulate

    scale = output_range if output_range > 0 else 1.0
    y = simulate(model, t, u).y if y is None else np.asarray(y, dtype=float)
    s = 0.0
    with np.errstate(all="ignore"):
        for run, cache in _runs(model, np.random.default_rng(ROUNDING_SEED)):
            dev = float(np.max(np.abs(simulate(run, t, u, flow_cache=cache).y - y))) / scale
            s = max(s, dev if np.isfinite(dev) else float("inf"))
    return s


def agreement_limit(sensitivity: float = 0.0) -> float:
    """The largest allowed difference, as a fraction of the output range, between two runs of one model whose
    `rounding_sensitivity` is `sensitivity`: max(`AGREEMENT`, `ROUNDING_FACTOR` sensitivity)."""
    return max(AGREEMENT, ROUNDING_FACTOR * sensitivity)


def _limit_text(sensitivity: float) -> str:
    """How `agreement_limit` was set, for the message of `check_agreement`."""
    limit = agreement_limit(sensitivity)
    how = (
        f"{ROUNDING_FACTOR:g} x the model's rounding sensitivity {sensitivity:.3g}, measured on this input"
        if limit > AGREEMENT
        else f"the fixed floor {AGREEMENT:g}; the model's rounding sensitivity on this input is {sensitivity:.3g}"
    )
    return f"the limit is {limit:.3g} = max({AGREEMENT:g}, {ROUNDING_FACTOR:g} s): {how}"


def check_agreement(
    y, y_ref, output_range: float, what: str, ref: str, where: str, *, sensitivity: float = 0.0
) -> float:
    """max |y - y_ref| / output_range, checked against `agreement_limit` (module docstring).

    Parameters
    ----------
    y, y_ref : the two outputs that must be the same (same samples)
    output_range : the range that scales the difference (e.g. the recorded output's max - min; 0 counts as 1)
    what, ref : names of the two sources (the message names both)
    where : the input they were run on
    sensitivity : s, the model's `rounding_sensitivity` on that input (0: a model that does not amplify
        rounding, the limit `AGREEMENT`)

    Returns
    -------
    float
        max_k |y_k - y_ref,k| / output_range.

    Raises
    ------
    ModelCheckError
        The difference (or a non-finite one) exceeds max(`AGREEMENT`, `ROUNDING_FACTOR` s).
    """
    scale = output_range if output_range > 0 else 1.0
    with np.errstate(all="ignore"):
        diff = float(np.max(np.abs(np.asarray(y, dtype=float) - np.asarray(y_ref, dtype=float)))) / scale
    if not diff <= agreement_limit(sensitivity):
        raise ModelCheckError(
            f"{what} and {ref} disagree on {where}: their outputs differ by up to {diff:.3g} "
            f"times the output range ({_limit_text(sensitivity)}), more than rounding explains: the FMU does "
            "not run the model it carries (altered after export); export the FMU again from the model JSON "
            "(duhem export)"
        )
    return diff
