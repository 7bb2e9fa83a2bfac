"""Identification of the rate-dependent semilinear Duhem model from triangle waves.

Oh & Bernstein (2007), Sections IV-V.  The model, eqs (18)-(19), is

    dx/dt = g(du/dt) (A x + B u),    y = C x.

Under the triangle wave (20), du/dt is a on the rising branch and b on the
falling branch, so (21): the model is the linear system g(a)(A, B) on the one
and g(b)(A, B) on the other.  By Proposition 2 a time-scaled system eta (A, B)
has the transfer-function coefficients eta^j alpha_j, eta^j beta_j (eq 28),
which is how g is read off branch by branch (eqs 40-45), one triangle wave per
pair of slopes (eq 50).

Two estimators (``estimator=``):

``"literal"`` -- the paper as printed:
    per branch the DARMA least squares (31)-(34) on the samples whose whole
    regression window lies on the ramp; the bilinear (Tustin) transform
    z = (1 + s delta/2)/(1 - s delta/2) to the ODEs (35)-(36); g-hat by the mean
    (45) of the alpha_1 and beta_1 ratios, normalised by the reference wave
    (50); A-hat, B-hat, C-hat in the observable canonical form (49) of the
    reference wave's rising branch.

``"improved"`` (default) -- output error on the exact model:
    1. per wave and branch direction a *ramp-exact* DARMA: on a ramp the exact
       discretisation of (21) is y_{k+1} = sum_j phi_j y_{k+1-j} + beta u_k + c
       with a branch constant c (the input lags u_{k-j} = u_k - j v delta
       collapse into u_k and c), so a sampled ramp response is represented
       exactly at any delta.  Its poles z give the continuous poles
       eta lambda = log(z)/delta exactly (no bilinear warping); their
       coefficient alpha_1 gives the start value of g (ratio to the reference).
    2. B-hat's start value by linear least squares: for fixed A and g the
       periodic response is linear in B (variable projection).
    3. all parameters (alpha, beta of the canonical form (49), g at every slope
       but the reference) refined jointly by output-error least squares
       (the output-error engine `fitter.identification.refine`, Levenberg-Marquardt) on *every*
       sample, corner samples included, with the model's limiting periodic response in closed form
       (`TriangleSamples`; the kernel's `fitter.core.periodic_response` where the closed form does not
       apply) and its exact Jacobian (`fitter.identification.triangle_sensitivities`; the problem is
       `fitter.identification.wave_output_error`).  With white output noise this is
       the maximum-likelihood (Gaussian) estimate; the regressors carry no
       noise, so there is no errors-in-variables bias.

Typos of the paper and how they are resolved here
-------------------------------------------------
* (49): the first column of A-hat is -alpha, so its first entry is
  -alpha_{1,1}^+ (printed without the minus), as in the canonical form of
  Proposition 2's proof.  Its subscripts are also swapped: the entries are
  alpha^+_{1,j} (wave 1, coefficient j; Step 1 writes alpha_{i,j}).
* (47)-(48): comparing (47) with (29), A-hat = g(a) A and B-hat = g(a) B; the
  paper prints A-hat = (1/g(a)) A and B-hat = (1/g(a)) A.  With g-hat =
  g / g(a_1), g-hat(v) A-hat = g(v) A, which is what Example 2's
  A-hat = -0.25 = g(0.25) (-1) shows.
* (50): both g-hat(a_i) and g-hat(b_i) are normalised by the reference
  coefficients alpha_1 = alpha^+_{1,1}, beta_1 = beta^+_{1,1} of wave 1's
  rising branch, as in (45) and Step 3; the printed falling-branch formula
  divides by alpha_1^-, beta_1^-, which would give g(b_i)/g(b_1) and make
  g-hat(b_1) = 1.
* The ordering T_{a_1} < ... < T_{a_p} contradicts the examples (T_a = 4/a_i
  with a_i increasing, normalised by g(a_1) = g(0.25)): here wave 1, the
  reference with g-hat(a_1) = 1, is the wave with the smallest rising slope.
* (31)-(32) run over k = 0 .. l_+ - 1, which would regress across the corner;
  Y_+ and Phi_+ (k = n-1 .. l_+ - 2) are used, and more generally only windows
  whose samples all lie on one ramp (samples are not assumed to hit corners).
* (35)-(36) have no u^(n) term but the Tustin image of the strictly proper
  (31) has one (it stands for the one-step delay); the literal estimator drops
  it (coefficient matching with (35) as printed).
* Example 2 refers to "Section VI" for the method of Section V.

Numerical assumptions
---------------------
* A record (t, u, y) is uniformly sampled, in steady state (the limiting
  periodic response), with u the exact triangle wave (20) (relative tolerance
  1e-6): the slopes a, b are the median positive and negative du/dt, a corner
  inside a sample interval is the intersection of the two ramps, and a record
  whose corners are all of one kind is taken to start or end at the other
  extreme (eq (20) sampled from t = 0 starts at its minimum).
* Between samples the input is piecewise linear (the kernel's rule); corners
  are inserted exactly, so every sample of the model's response is exact.
* C-hat = [1, 0, ..., 0], E = 0, D = 0, as in the paper; g-hat is stored as a
  `TabulatedRate` (PCHIP through g(0) = 0, constant beyond the outermost slopes).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from fitter.core import RateDependentModel, TabulatedRate
from fitter.identification.refine import refine
from fitter.identification.triangle_records import TOL, Record, fail, parse_record
from fitter.identification.wave_output_error import OPTIONS, WaveParameters, WaveRecords, canonical

__all__ = ["ESTIMATORS", "identify_rd_triangles", "identify_each", "RDIdentification", "WaveFit", "bilinear_d2c"]

ESTIMATORS = ("literal", "improved")


def _darma_rows(rec: Record, direction: int, order: int, intercept: bool):
    """Regression rows of (31)/(32): targets y_{k+1}, regressors [-y_k..-y_{k-n+1}, u_k..].

    With `intercept` (ramp-exact form) the input lags are replaced by u_k and 1.
    """
    rows, target = [], []
    n = order
    for first, last in rec.runs[direction]:
        ks = np.arange(first + n - 1, last)
        ylags = np.column_stack([-rec.y[ks - j] for j in range(n)])
        if intercept:
            ulags = np.column_stack([rec.u[ks], np.ones(len(ks))])
        else:
            ulags = np.column_stack([rec.u[ks - j] for j in range(n)])
        rows.append(np.hstack([ylags, ulags]))
        target.append(rec.y[ks + 1])
    if not rows:
        fail(rec.index, f"no {'rising' if direction > 0 else 'falling'} branch long enough for order {n}")
    Phi, Y = np.vstack(rows), np.concatenate(target)
    if len(Y) < Phi.shape[1]:
        fail(
            rec.index,
            f"too few samples for order {n}: {len(Y)} regression rows on the "
            f"{'rising' if direction > 0 else 'falling'} branches, {Phi.shape[1]} unknowns",
        )
    return Phi, Y


def _lstsq(Phi: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """theta = Phi^+ Y, eq (34)."""
    return np.linalg.lstsq(Phi, Y, rcond=None)[0]


def bilinear_d2c(alpha_d: np.ndarray, beta_d: np.ndarray, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear (Tustin) transform of the DARMA model (31) to the ODE (35).

    H(z) = (beta_1 z^{n-1} + ... + beta_n) / (z^n + alpha_1 z^{n-1} + ... + alpha_n)
    with z = (2 + s delta) / (2 - s delta); numerator and denominator are
    multiplied by (2 - s delta)^n, the denominator made monic, and the s^n
    numerator coefficient (absent from (35)) dropped.  Returns the continuous
    (alpha_1..alpha_n), (beta_1..beta_n) of (35).
    """
    P = np.polynomial.polynomial
    n = len(alpha_d)
    plus, minus = np.array([2.0, delta]), np.array([2.0, -delta])
    den = np.r_[1.0, alpha_d]
    num = np.r_[0.0, beta_d]
    D = np.zeros(n + 1)
    N = np.zeros(n + 1)
    for j in range(n + 1):
        term = P.polymul(P.polypow(plus, n - j), P.polypow(minus, j))
        D = P.polyadd(D, den[j] * term)
        N = P.polyadd(N, num[j] * term)
    D, N = np.pad(D, (0, n + 1 - len(D))), np.pad(N, (0, n + 1 - len(N)))
    lead = D[n]
    return D[:n][::-1] / lead, N[:n][::-1] / lead


def _exact_d2c(phi: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Continuous alpha_1..alpha_n whose poles are log(z)/delta for the DARMA poles z, one row per branch.

    phi (B, n) are the AR coefficients of y_{k+1} = sum_j phi_j y_{k+1-j} + ... (delta (B,) each row's
    sampling period); the poles are the eigenvalues of the companion matrices, as `numpy.roots` finds them, and
    the coefficients their products, as `numpy.poly` forms them.  A row is NaN where a pole is not the image of a
    continuous one (on the negative real axis or at zero).
    """
    rows, n = phi.shape
    companion = np.zeros((rows, n, n))
    companion[:, 0, :] = phi
    companion[:, np.arange(1, n), np.arange(n - 1)] = 1.0
    z = np.linalg.eigvals(companion)
    bad = np.any((np.abs(z) < 1e-12) | ((np.abs(z.imag) < 1e-12) & (z.real < 0)), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.log(z.astype(complex)) / delta[:, None]
    coef = np.zeros((rows, n + 1), dtype=complex)
    coef[:, 0] = 1.0
    for k in range(n):
        coef[:, 1 : k + 2] = coef[:, 1 : k + 2] + (-lam[:, k : k + 1]) * coef[:, : k + 1]
    alpha = coef[:, 1:].real
    alpha[bad] = np.nan
    return alpha


# ----------------------------------------------------------------------------- results


@dataclass
class WaveFit:
    """Per-wave coefficients: slopes, discrete (DARMA) and continuous branch coefficients, g-hat.

    `discrete_*` is the DARMA parameter vector of (33): [alpha-hat (n), beta-hat
    (n)] for the literal estimator, [alpha-hat (n), beta, c] (ramp-exact form)
    for the improved one.  `continuous_*` is [alpha (n), beta (n)] of (35)-(36)
    (literal: bilinear; improved: exact pole map, beta = g B-hat after output error).
    """

    a: float
    b: float
    samples: int
    discrete_plus: np.ndarray
    discrete_minus: np.ndarray
    continuous_plus: np.ndarray
    continuous_minus: np.ndarray
    g_plus: float
    g_minus: float

    def to_dict(self) -> dict:
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in vars(self).items()}


@dataclass
class RDIdentification:
    """Result of `identify_rd_triangles`.

    `model` is the identified `RateDependentModel` (A_hat, B_hat, C_hat and
    g = TabulatedRate(slopes, g_hat), normalised g_hat(a_1) = 1 at the smallest
    rising slope).  `waves` holds per-wave coefficients, sorted by rising slope.
    `rms_residual` is the RMS output error of the identified model's periodic
    response over all samples.
    """

    model: RateDependentModel
    slopes: np.ndarray
    g_hat: np.ndarray
    A_hat: np.ndarray
    B_hat: np.ndarray
    C_hat: np.ndarray
    estimator: str
    waves: list[WaveFit] = field(default_factory=list)
    rms_residual: float = float("nan")
    optimizer: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "estimator": self.estimator,
            "order": int(len(self.C_hat)),
            "A_hat": self.A_hat.tolist(),
            "B_hat": self.B_hat.tolist(),
            "C_hat": self.C_hat.tolist(),
            "slopes": self.slopes.tolist(),
            "g_hat": self.g_hat.tolist(),
            "rms_residual": self.rms_residual,
            "optimizer": self.optimizer,
            "waves": [w.to_dict() for w in self.waves],
            "model": self.model.to_dict(),
        }


# ----------------------------------------------------------------------------- estimators


def _literal(recs: list[Record], order: int) -> tuple[np.ndarray, np.ndarray, list[WaveFit]]:
    """Paper-literal: (31)-(34), bilinear to (35)-(36), (45), (49), (50)."""
    n = order
    disc, cont = [], []
    for rec in recs:
        pair_d, pair_c = [], []
        for d in (1, -1):
            th = _lstsq(*_darma_rows(rec, d, n, intercept=False))
            pair_d.append(th)
            pair_c.append(np.r_[bilinear_d2c(th[:n], th[n:], rec.delta)])
        disc.append(pair_d)
        cont.append(pair_c)
    alpha_ref, beta_ref = cont[0][0][:n], cont[0][0][n:]
    a1, b1 = alpha_ref[0], beta_ref[0]
    waves = []
    for rec, (dp, dm), (cp, cm) in zip(recs, disc, cont):
        gp = (cp[0] * b1 + a1 * cp[n]) / (2 * a1 * b1)
        gm = (cm[0] * b1 + a1 * cm[n]) / (2 * a1 * b1)
        waves.append(
            WaveFit(
                a=rec.wave.a,
                b=rec.wave.b,
                samples=len(rec.t),
                discrete_plus=dp,
                discrete_minus=dm,
                continuous_plus=cp,
                continuous_minus=cm,
                g_plus=float(gp),
                g_minus=float(gm),
            )
        )
    waves[0].g_plus = 1.0
    return alpha_ref, beta_ref, waves


def _ramp_exact_start(recs: list[Record], order: int):
    """Step 1 of the improved estimator: ramp-exact DARMA and exact pole map per branch."""
    n = order
    disc = [[_lstsq(*_darma_rows(rec, d, n, intercept=True)) for d in (1, -1)] for rec in recs]
    phi = -np.array([th[:n] for pair in disc for th in pair])
    alphas = _exact_d2c(phi, np.repeat([rec.delta for rec in recs], 2)).reshape(len(recs), 2, n)
    alpha_ref = alphas[0, 0]
    if np.isnan(alpha_ref[0]) or alpha_ref[0] == 0:
        raise ValueError(
            "record 0 (slowest wave): the rising-branch DARMA has a pole on the negative "
            "real axis; no continuous model (try order or sampling)"
        )
    g = alphas[:, :, 0] / alpha_ref[0]
    g[~np.isfinite(g)] = np.nanmedian(g)
    g[0, 0] = 1.0
    return alpha_ref, g, disc


def _improved(recs: list[Record], order: int, problem: WaveRecords):
    n = order
    alpha0, g0, disc = _ramp_exact_start(recs, n)
    param = WaveParameters(n, len(recs))
    beta0 = problem.best_beta(param, alpha0, g0[:, 0], g0[:, 1])
    joint = replace(problem, joint=True)
    res = refine(
        param,
        param.pack(alpha0, beta0, g0[:, 0], g0[:, 1]),
        joint,
        OPTIONS,
        jac=lambda theta: joint.jacobian(param, theta),
    )
    alpha, beta, gp, gm = param.unpack(res.theta)
    waves = [
        WaveFit(
            a=rec.wave.a,
            b=rec.wave.b,
            samples=len(rec.t),
            discrete_plus=dp,
            discrete_minus=dm,
            continuous_plus=np.r_[gp[i] ** np.arange(1, n + 1) * alpha, gp[i] ** np.arange(1, n + 1) * beta],
            continuous_minus=np.r_[gm[i] ** np.arange(1, n + 1) * alpha, gm[i] ** np.arange(1, n + 1) * beta],
            g_plus=float(gp[i]),
            g_minus=float(gm[i]),
        )
        for i, (rec, (dp, dm)) in enumerate(zip(recs, disc))
    ]
    info = {
        "method": "output error, fitter.identification.refine (Levenberg-Marquardt)",
        "nfev": res.nfev,
        "success": res.success,
        "message": res.message,
        "cost": res.cost,
    }
    return alpha, beta, waves, info


def _check_distinct_slopes(recs: list[Record]) -> None:
    """Eq (50) reads g at one rising and one falling slope per wave: no slope twice (relative 1e-6)."""
    for kind, key in (("rising", "a"), ("falling", "b")):
        ordered = sorted(recs, key=lambda r: getattr(r.wave, key))
        for r0, r1 in zip(ordered[:-1], ordered[1:]):
            v0, v1 = getattr(r0.wave, key), getattr(r1.wave, key)
            if np.isclose(v0, v1, rtol=TOL, atol=0):
                raise ValueError(
                    f"records {min(r0.index, r1.index)} and {max(r0.index, r1.index)} have the "
                    f"same {kind} slope {v0:.6g}; eq (50) needs one wave per slope"
                )


def identify_rd_triangles(
    records: list[tuple[np.ndarray, np.ndarray, np.ndarray]], *, order: int = 1, estimator: str = "improved"
) -> RDIdentification:
    """Identify a rate-dependent semilinear Duhem model from triangle-wave records (Section V).

    Parameters
    ----------
    records : list of (t, u, y)
        At least two uniformly sampled steady-state responses to triangle waves
        (20) of different slopes (see the module docstring for the checks).
    order : int
        Model order n of the DARMA models (31)-(32).
    estimator : {"improved", "literal"}
        See the module docstring.

    Returns
    -------
    RDIdentification
        With g-hat normalised to 1 at the smallest rising slope a_1, so that
        A_hat = g(a_1) A, B_hat = g(a_1) B (eqs 47-48 corrected).
    """
    return identify_each(records, order=order, estimators=(estimator,))[estimator]


def identify_each(
    records: list[tuple[np.ndarray, np.ndarray, np.ndarray]], *, order: int = 1, estimators: tuple = ESTIMATORS
) -> dict[str, RDIdentification]:
    """`identify_rd_triangles` by each of `estimators`, on the records parsed and laid out once."""
    for estimator in estimators:
        if estimator not in ESTIMATORS:
            raise ValueError(f"estimator must be one of {ESTIMATORS}, got {estimator!r}")
    if int(order) != order or order < 1:
        raise ValueError(f"order must be a positive integer, got {order}")
    order = int(order)
    if len(records) < 2:
        raise ValueError(f"need at least 2 triangle-wave records of different slopes (eq 50), got {len(records)}")
    recs = sorted((parse_record(i, r, order) for i, r in enumerate(records)), key=lambda r: r.wave.a)
    _check_distinct_slopes(recs)
    problem = WaveRecords(recs)
    return {estimator: _identification(recs, order, estimator, problem) for estimator in estimators}


def _identification(recs: list[Record], order: int, estimator: str, problem: WaveRecords) -> RDIdentification:
    """One estimator's identification, its residuals on `problem` (the records' output-error problem)."""
    optimizer: dict = {}
    if estimator == "literal":
        alpha, beta, waves = _literal(recs, order)
    else:
        alpha, beta, waves, optimizer = _improved(recs, order, problem)
    slopes = np.array([w.a for w in waves] + [w.b for w in waves])
    g_hat = np.array([w.g_plus for w in waves] + [w.g_minus for w in waves])
    A, B, C = canonical(alpha, beta)
    model = RateDependentModel(
        A=A,
        B=B,
        C=C,
        g=TabulatedRate(slopes, g_hat),
        fit_info={
            "method": "Oh & Bernstein 2007, Section V (triangle waves)",
            "estimator": estimator,
            "normalisation": "g_hat(a_1) = 1 at the smallest rising slope; A_hat = g(a_1) A",
        },
    )
    param = WaveParameters(order, len(recs))
    resid = problem.residuals(
        param, param.pack(alpha, beta, np.array([w.g_plus for w in waves]), np.array([w.g_minus for w in waves]))
    )[0]
    return RDIdentification(
        model=model,
        slopes=slopes,
        g_hat=g_hat,
        A_hat=A,
        B_hat=B,
        C_hat=C,
        estimator=estimator,
        waves=waves,
        rms_residual=float(np.sqrt(np.mean(resid**2))),
        optimizer=optimizer,
    )
