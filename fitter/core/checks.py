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
  most `AGREEMENT` = 1e-6 of the output range.

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
    "check_agreement",
]

MAX_MAGNITUDE = 1e100
"""Largest |value| of a stored number of a model (module docstring)."""
AGREEMENT = 1e-6
"""Largest difference, as a fraction of the output range, between two outputs that must be the same."""


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


def check_agreement(y, y_ref, output_range: float, what: str, ref: str, where: str) -> float:
    """max |y - y_ref| / output_range, checked against `AGREEMENT`.

    Parameters
    ----------
    y, y_ref : the two outputs that must be the same (same samples)
    output_range : the range that scales the difference (e.g. the recorded output's max - min; 0 counts as 1)
    what, ref : names of the two sources (the message names both)
    where : the input they were run on

    Raises
    ------
    ModelCheckError
        The difference (or a non-finite one) exceeds `AGREEMENT` of the range.
    """
    scale = output_range if output_range > 0 else 1.0
    with np.errstate(all="ignore"):
        diff = float(np.max(np.abs(np.asarray(y, dtype=float) - np.asarray(y_ref, dtype=float)))) / scale
    if not diff <= AGREEMENT:
        raise ModelCheckError(
            f"{what} and {ref} disagree on {where}: their outputs differ by up to {diff:.3g} "
            f"times the output range (the limit is {AGREEMENT:g}): the FMU does not run the "
            "model it carries (altered after export, or a model whose branches amplify rounding); "
            "export the FMU again from the model JSON (duhem export)"
        )
    return diff
