/*
 * The semilinear Duhem model behind the FMI framework: the C twin of
 * fitter.core.stepper.Stepper, fitter.core.kernel's exact flow,
 * fitter.core.rates.TabulatedRate and fitter.core.effects.run_with_effects.
 *
 * Models (Oh & Bernstein 2007):
 *   rate-independent, eqs (1)-(2): dx/du = A+- x + B+- u + E+-  (+ while u rises, - while it falls)
 *   rate-dependent,  eqs (18)-(19): dx/dt = g(du/dt) (A x + B u + E)
 *   both: y = C x + D u.
 *
 * Communication-point semantics (as the Stepper): an anchor (t_a, u_a, x_a)
 * at the last communication point and the current (t, u); the state at the
 * current point is x_a moved along the straight input path u_a -> u over
 * [t_a, t]; a step (fmi2DoStep, fmi3DoStep) commits the current point as
 * the new anchor and advances t; a held input moves nothing; setting u while
 * t == t_a re-anchors the input without moving the state.  An input
 * derivative du (FMI 2 fmi2SetRealInputDerivatives, order 1) moves the
 * current input on to u + du h at every step, so the input over a step is
 * linear (stepper.py, "Input interpolation").  The model acts on the
 * input held at the edges of its input range [DUHEM_INPUT_LO, DUHEM_INPUT_HI]
 * (models.py, "Extrapolation rule"); the input variable keeps the value set.
 *
 * Exact flow (kernel module docstring, eq (K)): over one interval
 * dx/ds = A x + B (p + r s) + E for 0 <= s <= S,
 *   x(S) = F0 x(0) + S F1 (B p + E) + S^2 F2 B r,  F0 = e^{AS}, F1 = phi1(AS), F2 = phi2(AS),
 *   [[F0, F1, F2], ...] = expm([[A S, I, 0], [0, 0, I], [0, 0, 0]])   (3n x 3n, blocks n x n),
 * the balanced form of the phi-functions (flow.AffineFlow.affine_maps): the
 * input level p does not enter the matrix, so its norm, and the number of
 * squarings, is that of A S; with, for the rate-independent model, p = u_a, r = 1, S = u - u_a and the
 * branch chosen by the sign of u - u_a (a held input keeps the + branch,
 * where S = 0); for the rate-dependent model v = (u - u_a)/(t - t_a),
 * p = u_a, S = g(v) (t - t_a), r = v / g(v) (r = 0 when g(v) = 0, where
 * S = 0).  The matrix exponential is the kernel's (flow.phi_blocks): scaling to 1-norm <= 0.5,
 * Taylor series of the degree its terms need (taylor_degree), squaring, computed on the n x n blocks
 * (phi_blocks).
 *
 * Rate function: TabulatedRate, a PCHIP (Fritsch-Carlson slopes, limited
 * three-point end slopes) through (0, 0), separately on v <= 0 and v >= 0,
 * constant beyond the outermost nodes; its nodes g_v, g_g are parameters, so
 * the interpolant is rebuilt here when they change.
 *
 * Effects (fitter.core.effects, steps 1-8 of its chain): one function
 * effect_<name> per effect of fitter.core.effects.REGISTRY (EffectSpec.native),
 * the C twin of its EffectSpec.apply, on a Chain of one sample (the anchor
 * alone) or two (anchor and current point).  model_data.h lists them in chain
 * order (DUHEM_EFFECTS); run_stage calls those the model has, stage by stage:
 * input effects set the base input w (backlash), rate effects rescale the
 * flow's r, S (rate_dependence), then the base output C x + D w goes through
 * the output effects (creep, viscous, thermal_drift, saturation, sensor_lag).
 * A model without effects runs the same chain with none.  The chain's state
 * at the anchor (the present effects' state variables, in chain order) is
 * part of the FMU state.
 */
#include <math.h>
#include <string.h>

#include "model_interface.h"
#include "duhem_model.h"
#include "model_data.h"

#define N DUHEM_ORDER
#define TAYLOR_DEGREE 18 /* flow.TAYLOR_DEGREE */
#define TAYLOR_TAIL 1.387778780781445675529539585113525390625e-17 /* 2^-56, flow.TAYLOR_TAIL */
#define EXPM_NORM_LIMIT 1e250

#if DUHEM_KIND == DUHEM_RATE_INDEPENDENT
enum {
    P_A_PLUS = 0, P_A_MINUS = P_A_PLUS + N * N, P_B_PLUS = P_A_MINUS + N * N,
    P_B_MINUS = P_B_PLUS + N, P_E_PLUS = P_B_MINUS + N, P_E_MINUS = P_E_PLUS + N,
    P_C = P_E_MINUS + N, P_D = P_C + N, P_X0 = P_D + 1, P_BASE_END = P_X0 + N
};
#elif DUHEM_KIND == DUHEM_RATE_DEPENDENT
#define K DUHEM_RATE_NODES
enum {
    P_A = 0, P_B = P_A + N * N, P_E = P_B + N, P_C = P_E + N, P_D = P_C + N,
    P_X0 = P_D + 1, P_GV = P_X0 + N, P_GG = P_GV + K, P_BASE_END = P_GG + K
};
#else
#error "model_data.h: unknown DUHEM_KIND"
#endif

/* Size of the chain-state arrays (a C array is never empty). */
#define STATES (DUHEM_EFFECT_STATES > 0 ? DUHEM_EFFECT_STATES : 1)

/* Compile-time check that model_data.h was generated for this layout. */
typedef char parameter_layout_matches_model_data[(P_BASE_END <= DUHEM_N_PARAMETERS) ? 1 : -1];

/*
 * The samples of one run of the effect chain (fitter.core.effects.Chain): the
 * anchor alone (n = 1) or the anchor and the current point (n = 2, an interval
 * of length h).
 */
typedef struct {
    int n;
    double h;
    double u[2], w[2], y[2];  /* input, base input, output at the samples */
    double r, S;              /* coefficients of the flow on the interval (n = 2) */
} Chain;

#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
/* One side of the rate function: n nodes (origin included) with PCHIP slopes. */
typedef struct {
    int n;
    double x[K + 1], y[K + 1], d[K + 1];
} RateSide;
#endif

struct ModelData {
    double par[DUHEM_N_PARAMETERS];
    double t_a, u_a, t, u;
    double du;          /* input derivative du/dt (model_set_input_derivative), applied by model_do_step */
    double x_a[N];
    double s_a[STATES]; /* effect chain state at the anchor, valid when has_s_a */
    int has_s_a;
    double x[N];        /* state, output and chain state at (t, u), valid when cached */
    double y;
    double s[STATES];
    int cached;
#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
    RateSide rate[2]; /* v < 0, v > 0; rebuilt from g_v, g_g when rate_dirty */
    int rate_dirty;
#endif
};

/* ---------------------------------------------------------------- exact flow */

/*
 * P = L R on n x n blocks.  Each entry sums L[i][j] R[j][c] over ascending j, as the plain triple loop
 * does, but the terms with L[i][j] = 0 are skipped: adding them changes nothing (x + 0 = x), so the
 * result is the plain loop's (flow._product sums the same terms in the same order).
 */
static void product(double L[N][N], double R[N][N], double P[N][N])
{
    int i, j, c;
    memset(P, 0, sizeof(double) * N * N);
    for (i = 0; i < N; i++)
        for (j = 0; j < N; j++) {
            double l = L[i][j];
            if (l == 0.0) continue;
            for (c = 0; c < N; c++) P[i][c] += l * R[j][c];
        }
}

/*
 * The phi-function blocks of the augmented exponential (flow.phi_blocks, the kernel's algorithm):
 *
 *   e^X = [[F0, F1, F2], [0, I, I], [0, 0, I]],   X = [[A S, I, 0], [0, 0, I], [0, 0, 0]]  (3n x 3n),
 *   F0 = e^{AS}, F1 = phi1(AS), F2 = phi2(AS)      (Van Loan 1978, block-triangular exponentials),
 *
 * by the kernel's expm of X (scaling to 1-norm <= 0.5, Taylor series, squaring) restated on the n x n
 * blocks, O(n^3) a step instead of O((3n)^3), the series cut at the degree its terms need
 * (taylor_degree); -1 when A S is not finite or too large.
 *
 * Scaling: the 1-norm of X is max(|A S|_1, 1) (the identity blocks' columns sum to 1), s the least
 * number of halvings that brings it to <= 0.5, and
 *   Y = X / 2^s = [[a, cI, 0], [0, 0, cI], [0, 0, 0]],   a = A S / 2^s,  c = 2^-s.
 * Taylor: Y^k = [[a^k, c a^(k-1), c^2 a^(k-2)], [0, 0, [k = 1] cI], [0, 0, 0]] (a^-1 = a^-2 = 0), so the
 * terms T_k = T_(k-1) Y / k have the top blocks
 *   T0_k = T0_(k-1) a / k,   T1_k = (c T0_(k-1)) / k,   T2_k = (c T1_(k-1)) / k,
 * and e^Y = sum_(k<=degree) T_k = [[F0, F1, F2], [0, I, cI], [0, 0, I]].
 * Squaring (block product of two such matrices):
 *   [[F0, F1, F2], [0, I, cI], [0, 0, I]]^2 = [[F0 F0, F0 F1 + F1, F0 F2 + c F1 + F2], [0, I, 2c I], [0, 0, I]],
 * s times, c doubling each time up to 1; in the phi-functions these are the doubling formulas
 * phi1(2z) = (e^z + 1) phi1(z) / 2, phi2(2z) = (e^z phi2(z) + phi1(z) + phi2(z)) / 4 (Skaflestad &
 * Wright 2009).  Every block entry is the same sum, in the same order, as the 3n x 3n products with
 * their zero terms skipped, so the numbers are those of the 3n x 3n algorithm.
 */
/*
 * The Taylor degree for scaled blocks of 1-norm theta <= 0.5 (flow.taylor_degree, the same products):
 * the least m >= 2 with theta^(m-1) / (m+1)! <= TAYLOR_TAIL, at most TAYLOR_DEGREE.
 */
static int taylor_degree(double theta)
{
    double bound = theta / 6.0;
    int m = 2;
    while (m < TAYLOR_DEGREE && !(bound <= TAYLOR_TAIL)) {
        bound = bound * (theta / (m + 2));
        m++;
    }
    return m;
}

static int phi_blocks(const double *A, double S, double F0[N][N], double F1[N][N], double F2[N][N])
{
    double a[N][N], T0[N][N], T1[N][N], T2[N][N], P[N][N], norm = 1.0, widest = 0.0, scale = 1.0, c;
    int i, j, k, s = 0, degree;
    for (j = 0; j < N; j++) {
        double column = 0.0;
        for (i = 0; i < N; i++) {
            a[i][j] = A[i * N + j] * S;
            column += fabs(a[i][j]);
        }
        if (!(column <= EXPM_NORM_LIMIT)) return -1;
        if (column > norm) norm = column;
        if (column > widest) widest = column;
    }
    while (norm > 0.5) {
        norm *= 0.5;
        scale *= 2.0;
        s++;
    }
    c = 1.0 / scale;
    degree = taylor_degree(widest / scale);
    for (i = 0; i < N; i++)
        for (j = 0; j < N; j++) {
            a[i][j] /= scale;
            T0[i][j] = F0[i][j] = (i == j ? 1.0 : 0.0);
            T1[i][j] = F1[i][j] = T2[i][j] = F2[i][j] = 0.0;
        }
    for (k = 1; k <= degree; k++) {
        product(T0, a, P);
        for (i = 0; i < N; i++)
            for (j = 0; j < N; j++) {
                T2[i][j] = T1[i][j] * c / k;
                T1[i][j] = T0[i][j] * c / k;
                T0[i][j] = P[i][j] / k;
                F0[i][j] += T0[i][j];
                F1[i][j] += T1[i][j];
                F2[i][j] += T2[i][j];
            }
    }
    for (; s > 0; s--) {
        product(F0, F2, P);
        for (i = 0; i < N; i++)
            for (j = 0; j < N; j++) F2[i][j] = P[i][j] + F1[i][j] * c + F2[i][j];
        product(F0, F1, P);
        for (i = 0; i < N; i++)
            for (j = 0; j < N; j++) F1[i][j] = P[i][j] + F1[i][j];
        product(F0, F0, P);
        memcpy(F0, P, sizeof P);
        c *= 2.0;
    }
    return 0;
}

/* out = x(S) of dx/ds = A x + B (p + r s) + E from x(0) = x; -1 if not finite. */
static int flow(const double *A, const double *B, const double *E, const double *x, double p,
                double r, double S, double *out)
{
    double F0[N][N], F1[N][N], F2[N][N];
    int i, j;
    if (S == 0.0) {
        memcpy(out, x, N * sizeof(double));
        return 0;
    }
    if (phi_blocks(A, S, F0, F1, F2)) return -1;
    for (i = 0; i < N; i++) {
        double acc = 0.0;
        for (j = 0; j < N; j++)
            acc += F0[i][j] * x[j] + S * F1[i][j] * (B[j] * p + E[j]) + S * S * F2[i][j] * B[j] * r;
        out[i] = acc;
        if (!isfinite(out[i])) return -1;
    }
    return 0;
}

/* ---------------------------------------------------------------- rate function */

#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
static double sign(double v)
{
    return v > 0 ? 1.0 : (v < 0 ? -1.0 : 0.0);
}

/* rates._end_slope: three-point end slope, limited to keep the interpolant monotone. */
static double end_slope(double h0, double h1, double d0, double d1)
{
    double s = ((2 * h0 + h1) * d0 - h0 * d1) / (h0 + h1);
    if (sign(s) != sign(d0)) return 0.0;
    if (sign(d0) != sign(d1) && fabs(s) > fabs(3 * d0)) return 3 * d0;
    return s;
}

/* rates._pchip_slopes: Fritsch-Carlson slopes at the side's nodes. */
static void pchip_slopes(RateSide *side)
{
    double h[K + 1], delta[K + 1];
    int n = side->n, k;
    for (k = 0; k + 1 < n; k++) {
        h[k] = side->x[k + 1] - side->x[k];
        delta[k] = (side->y[k + 1] - side->y[k]) / h[k];
    }
    if (n == 2) {
        side->d[0] = side->d[1] = delta[0];
        return;
    }
    for (k = 1; k + 1 < n; k++) {
        if (delta[k - 1] * delta[k] <= 0) {
            side->d[k] = 0.0;
        } else {
            double w1 = 2 * h[k] + h[k - 1], w2 = h[k] + 2 * h[k - 1];
            side->d[k] = (w1 + w2) / (w1 / delta[k - 1] + w2 / delta[k]);
        }
    }
    side->d[0] = end_slope(h[0], h[1], delta[0], delta[1]);
    side->d[n - 1] = end_slope(h[n - 2], h[n - 3], delta[n - 2], delta[n - 3]);
}

/* TabulatedRate from the nodes g_v, g_g: sort, check, split at 0, add the origin. */
static const char *build_rate(ModelData *m)
{
    double v[K], g[K];
    int i, j, side;
    for (i = 0; i < K; i++) {  /* insertion sort by v */
        double vi = m->par[P_GV + i], gi = m->par[P_GG + i];
        if (vi == 0.0) return "rate table: g(0) = 0 is implied; a slope g_v is 0";
        for (j = i; j > 0 && v[j - 1] > vi; j--) {
            v[j] = v[j - 1];
            g[j] = g[j - 1];
        }
        v[j] = vi;
        g[j] = gi;
    }
    for (i = 1; i < K; i++)
        if (v[i] == v[i - 1]) return "rate table: duplicate slopes in g_v";
    for (side = 0; side < 2; side++) m->rate[side].n = 0;
    for (i = 0; i < K && v[i] < 0; i++) {
        m->rate[0].x[i] = v[i];
        m->rate[0].y[i] = g[i];
        m->rate[0].n++;
    }
    m->rate[1].x[0] = m->rate[1].y[0] = 0.0;
    m->rate[1].n = 1;
    for (; i < K; i++) {
        m->rate[1].x[m->rate[1].n] = v[i];
        m->rate[1].y[m->rate[1].n] = g[i];
        m->rate[1].n++;
    }
    if (m->rate[0].n > 0) {
        m->rate[0].x[m->rate[0].n] = m->rate[0].y[m->rate[0].n] = 0.0;
        m->rate[0].n++;
        pchip_slopes(&m->rate[0]);
    }
    if (m->rate[1].n > 1) pchip_slopes(&m->rate[1]);
    else m->rate[1].n = 0;
    m->rate_dirty = 0;
    return NULL;
}

/* The Hermite cubic through one side's nodes, clamped to its outermost nodes. */
static double pchip(const RateSide *side, double v)
{
    const double *x = side->x, *y = side->y, *d = side->d;
    int n = side->n, i = 0, k;
    double vc, h, t, h00, h10, h01, h11;
    vc = v < x[0] ? x[0] : (v > x[n - 1] ? x[n - 1] : v);
    while (i < n && x[i] < vc) i++;
    k = i - 1 < 0 ? 0 : (i - 1 > n - 2 ? n - 2 : i - 1);
    h = x[k + 1] - x[k];
    t = (vc - x[k]) / h;
    h00 = (1 + 2 * t) * ((1 - t) * (1 - t));
    h10 = t * ((1 - t) * (1 - t));
    h01 = t * t * (3 - 2 * t);
    h11 = t * t * (t - 1);
    return h00 * y[k] + h10 * h * d[k] + h01 * y[k + 1] + h11 * h * d[k + 1];
}

/* g(v): zero at v = 0 and on a side without nodes. */
static double rate(const ModelData *m, double v)
{
    if (v > 0 && m->rate[1].n > 0) return pchip(&m->rate[1], v);
    if (v < 0 && m->rate[0].n > 0) return pchip(&m->rate[0], v);
    return 0.0;
}
#endif

/* ---------------------------------------------------------------- effects */

/* Exact samples of dz/dt = (target(t) - z)/tau over h, target linear from z0t to z1t. */
static double first_order(double z0, double z0t, double z1t, double h, double tau)
{
    double x = h / tau, a = exp(-x), one_minus_a = -expm1(-x);
    double q = x > 0 ? one_minus_a / x : 1.0;
    return a * z0 + ((z1t - z0t) * (1.0 - q) + one_minus_a * z0t);
}

/*
 * One function per effect, the twin of its EffectSpec.apply: p its
 * parameters (in the order of EffectSpec.parameters), s0 its state at the
 * anchor (EffectSpec.state; NULL: start afresh), s1 its state at the last
 * sample of the chain c, which it updates in its stage.
 */

/* Step 1, stage input, parameters (b), state (w): the play operator on the base input. */
static void effect_backlash(const double *p, const double *s0, double *s1, Chain *c)
{
    double hb = p[0] / 2;
    c->w[0] = fmin(c->u[0] + hb, fmax(c->u[0] - hb, s0 ? s0[0] : c->u[0]));
    if (c->n == 2)
        c->w[1] = c->u[1] - c->u[0] < 0 ? fmin(c->w[0], c->u[1] + hb) : fmax(c->w[0], c->u[1] - hb);
    s1[0] = c->w[c->n - 1];
}

/* Step 2, stage rate, parameters (alpha): S -> S s, r -> r / s, s = 1/(1 + alpha |dw/h|). */
static void effect_rate_dependence(const double *p, const double *s0, double *s1, Chain *c)
{
    double s = 1.0 / (1.0 + p[0] * fabs((c->w[1] - c->w[0]) / c->h));
    (void)s0;
    (void)s1;
    c->r = c->r / s;
    c->S = c->S * s;
}

/* Step 4, stage output, parameters (k, tau), state (c): y += c, dc/dt = (k u - c)/tau. */
static void effect_creep(const double *p, const double *s0, double *s1, Chain *c)
{
    double k = p[0], c0 = s0 ? s0[0] : k * c->u[0];
    c->y[0] = c->y[0] + c0;
    s1[0] = c0;
    if (c->n == 2) {
        s1[0] = first_order(c0, k * c->u[0], k * c->u[1], c->h, p[1]);
        c->y[1] = c->y[1] + s1[0];
    }
}

/*
 * Step 5, stage output, parameters (k, w2 .. wM, tau_min, tau_max), state (c1..cM), M = DUHEM_RELAXATION_TERMS:
 * y += sum_i c_i, dc_i/dt = (k_i u - c_i)/tau_i, k_i = k w_i / (w1 + ... + wM) with w1 = 1,
 * tau_i = tau_min (tau_max/tau_min)^(i/(M - 1))
 * (effects.Relaxation.gains, effects.relaxation_taus).
 */
static void effect_relaxation(const double *p, const double *s0, double *s1, Chain *c)
{
    enum { M = DUHEM_RELAXATION_TERMS };
    const double tau_min = p[M], tau_max = p[M + 1];
    double w[M], total = 1.0;
    int i;
    w[0] = 1.0;
    for (i = 1; i < M; i++) {
        w[i] = p[i];
        total = total + w[i];
    }
    for (i = 0; i < M; i++) {
        double k = p[0] * w[i] / total, tau = tau_min * pow(tau_max / tau_min, i / (M - 1.0));
        double c0 = s0 ? s0[i] : k * c->u[0];
        c->y[0] = c->y[0] + c0;
        s1[i] = c0;
        if (c->n == 2) {
            s1[i] = first_order(c0, k * c->u[0], k * c->u[1], c->h, tau);
            c->y[1] = c->y[1] + s1[i];
        }
    }
}

/* log((e^d - 1)/d) without overflow, 0 at d = 0 (effects._log_exprel). */
static double log_exprel(double d)
{
    if (d > 1e-12) return d + log(-expm1(-d)) - log(d);
    if (d < -1e-12) return log(-expm1(d)) - log(-d);
    return d / 2;
}

/*
 * Step 6, stage output, parameters (S, u_up, u_dn, width, q, spread) per population, state (s_ij): population i is
 * DUHEM_SWITCHING_NODES equal shares j with thresholds u_up + spread z_j, u_dn - spread z_j (z_j: DUHEM_SWITCHING_NODES_Z,
 * effects.SWITCHING_NODES_Z), y += sum_i mean_j s_ij, ds/dt = k+(u) (S - s) - k-(u) (S + s), k+ = e^{(u - up)/width},
 * k- = e^{(dn - u)/width} per share (effects.switching_states): s1 = s_eq + (s0 - s_eq) e^{-(I+ + I-)},
 * s_eq = S tanh((ln I+ - ln I-)/2), ln I+- capped at DUHEM_SWITCHING_MAX_EXPONENT and I+ + I- at
 * DUHEM_SWITCHING_MAX_DECAY (effects._MAX_EXPONENT, _MAX_DECAY).
 */
static void effect_switching(const double *p, const double *s0, double *s1, Chain *c)
{
    static const double z[DUHEM_SWITCHING_NODES] = DUHEM_SWITCHING_NODES_Z;
    int i, j;
    for (i = 0; i < DUHEM_SWITCHING_POPULATIONS; i++) {
        const double *q = p + 6 * i;
        for (j = 0; j < DUHEM_SWITCHING_NODES; j++) {
            int k = i * DUHEM_SWITCHING_NODES + j;
            double up = q[1] + q[5] * z[j], dn = q[2] - q[5] * z[j];
            double s = s0 ? s0[k] : q[4] * q[0];
            c->y[0] = c->y[0] + s / DUHEM_SWITCHING_NODES;
            if (c->n == 2) {
                double d = (c->u[1] - c->u[0]) / q[3], log_h = log(c->h);
                double lp = log_h + (c->u[0] - up) / q[3] + log_exprel(d);
                double lm = log_h + (dn - c->u[0]) / q[3] + log_exprel(-d);
                double big = fmax(lp, lm);
                double total = fmin(exp(fmin(big, DUHEM_SWITCHING_MAX_EXPONENT)) * (1.0 + exp(fmin(lp, lm) - big)),
                                    DUHEM_SWITCHING_MAX_DECAY);
                double target = q[0] * tanh((lp - lm) / 2);
                s = exp(-total) * s + -expm1(-total) * target;
                c->y[1] = c->y[1] + s / DUHEM_SWITCHING_NODES;
            }
            s1[k] = s;
        }
    }
}

/* Step 7, stage output, parameters (c): y += c du/h (0 at the anchor alone). */
static void effect_viscous(const double *p, const double *s0, double *s1, Chain *c)
{
    (void)s0;
    (void)s1;
    if (c->n == 2) c->y[1] = c->y[1] + p[0] * ((c->u[1] - c->u[0]) / c->h);
}

/* Step 8, stage output, parameters (kappa), state (W): y *= 1 - kappa W, W the input travel. */
static void effect_thermal_drift(const double *p, const double *s0, double *s1, Chain *c)
{
    double W = s0 ? s0[0] : 0.0;
    c->y[0] = c->y[0] * (1.0 - p[0] * W);
    if (c->n == 2) {
        W = W + fabs(c->u[1] - c->u[0]);
        c->y[1] = c->y[1] * (1.0 - p[0] * W);
    }
    s1[0] = W;
}

/* Step 9, stage output, parameters (y_c, beta): y -> y_c + tanh(beta (y - y_c))/beta. */
static void effect_saturation(const double *p, const double *s0, double *s1, Chain *c)
{
    double yc = p[0], beta = p[1];
    int i;
    (void)s0;
    (void)s1;
    for (i = 0; beta > 0 && i < c->n; i++) c->y[i] = yc + tanh(beta * (c->y[i] - yc)) / beta;
}

/* Step 10, stage output, parameters (tau), state (m, y): first-order lag of y, linear between samples. */
static void effect_sensor_lag(const double *p, const double *s0, double *s1, Chain *c)
{
    double tau = p[0], target0 = s0 ? s0[1] : c->y[0];
    double y_last = (s0 && c->n == 1) ? s0[1] : c->y[c->n - 1];
    if (tau > 0) {
        c->y[0] = s0 ? s0[0] : target0;
        if (c->n == 2) c->y[1] = first_order(c->y[0], target0, y_last, c->h, tau);
    }
    s1[0] = c->y[c->n - 1];
    s1[1] = y_last;
}

/* Step 11, stage output, parameters (rate), state (d): y += d, d = rate (t - t_0). */
static void effect_measurement_drift(const double *p, const double *s0, double *s1, Chain *c)
{
    double d = s0 ? s0[0] : 0.0;
    c->y[0] = c->y[0] + d;
    if (c->n == 2) {
        d = d + p[0] * c->h;
        c->y[1] = c->y[1] + d;
    }
    s1[0] = d;
}

/* The model's effects of one stage, in chain order (DUHEM_EFFECTS of model_data.h). */
static void run_stage(const ModelData *m, EffectStage stage, const double *s0, double *s1, Chain *c)
{
#define APPLY(name, effect_stage, present, index, offset) \
    if ((present) && (effect_stage) == stage) \
        effect_##name(m->par + (index), s0 ? s0 + (offset) : NULL, s1 + (offset), c);
    DUHEM_EFFECTS(APPLY)
#undef APPLY
    (void)m;
    (void)stage;
    (void)s0;
    (void)s1;
    (void)c;
}

/* ---------------------------------------------------------------- stepping */

/* State x from x_a over the chain's interval (n = 2), base input w[0] -> w[1]; rate stage included. */
static int base_flow(const ModelData *m, Chain *c, const double *s0, double *s1, double *x)
{
    double dw = c->w[1] - c->w[0];
#if DUHEM_KIND == DUHEM_RATE_INDEPENDENT
    const double *A = m->par + (dw < 0 ? P_A_MINUS : P_A_PLUS);
    const double *B = m->par + (dw < 0 ? P_B_MINUS : P_B_PLUS);
    const double *E = m->par + (dw < 0 ? P_E_MINUS : P_E_PLUS);
    c->r = 1.0;
    c->S = dw;
#else
    const double *A = m->par + P_A, *B = m->par + P_B, *E = m->par + P_E;
    double v = dw / c->h, g = rate(m, v);
    c->r = g != 0.0 ? v / g : 0.0;
    c->S = g * c->h;
#endif
    run_stage(m, STAGE_RATE, s0, s1, c);
    if (!isfinite(c->r) || !isfinite(c->S)) return -1;
    return flow(A, B, E, m->x_a, c->w[0], c->r, c->S, x);
}

static double base_output(const ModelData *m, const double *x, double w)
{
    double y = 0.0;
    int i;
    for (i = 0; i < N; i++) y += m->par[P_C + i] * x[i];
    return y + m->par[P_D] * w;
}

/* The input the model acts on: held at the edges of the fitted input range (models.py, input_range). */
static double model_input(double u)
{
    return fmin(DUHEM_INPUT_HI, fmax(DUHEM_INPUT_LO, u));
}

/*
 * The chain from the anchor (chain state s0 there; NULL: afresh) to the
 * current point, as run_with_effects on its one or two samples: the state x,
 * chain state s and output y at the current point; -1 if not finite.
 */
static int run_chain(const ModelData *m, const double *s0, double *x, double *s, double *y)
{
    Chain c;
    c.n = m->t == m->t_a ? 1 : 2;
    c.h = m->t - m->t_a;
    c.u[0] = c.w[0] = model_input(m->u_a);
    c.u[1] = c.w[1] = model_input(m->u);
    run_stage(m, STAGE_INPUT, s0, s, &c);
    c.y[0] = base_output(m, m->x_a, c.w[0]);
    if (c.n == 1) {
        memcpy(x, m->x_a, N * sizeof(double));
    } else {
        if (base_flow(m, &c, s0, s, x)) return -1;
        c.y[1] = base_output(m, x, c.w[1]);
    }
    run_stage(m, STAGE_OUTPUT, s0, s, &c);
    *y = c.y[c.n - 1];
    return isfinite(*y) ? 0 : -1;
}

/* State and output at the current point, cached; NULL or why it failed. */
static const char *advance(ModelData *m)
{
    if (m->cached) return NULL;
#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
    if (m->rate_dirty) {
        const char *msg = build_rate(m);
        if (msg) return msg;
    }
#endif
    if (run_chain(m, m->has_s_a ? m->s_a : NULL, m->x, m->s, &m->y))
        return "the state is not finite after this input change (too large a step)";
    m->cached = 1;
    return NULL;
}

/* ---------------------------------------------------------------- variables */

static const DuhemVariable *find(char type, unsigned int vr)
{
    int i;
    for (i = 0; i < DUHEM_N_VARIABLES; i++)
        if (duhem_variables[i].vr == vr && duhem_variables[i].type == type)
            return &duhem_variables[i];
    return NULL;
}

static const char *const UNKNOWN = "unknown value reference for this type";

const char *model_variable_name(char type, unsigned int vr)
{
    const DuhemVariable *var = find(type, vr);
    return var ? var->name : "?";
}

size_t model_size(void) { return sizeof(ModelData); }

const char *model_guid(void) { return DUHEM_GUID; }

void model_defaults(ModelData *m, double t0)
{
    memset(m, 0, sizeof *m);
    memcpy(m->par, duhem_parameters, sizeof m->par);
    memcpy(m->x_a, m->par + P_X0, sizeof m->x_a);
#if DUHEM_EFFECT_START >= 0
    memcpy(m->s_a, m->par + DUHEM_EFFECT_START, DUHEM_EFFECT_STATES * sizeof(double));
    m->has_s_a = 1;
#endif
    m->u = m->u_a = DUHEM_INPUT_START;
    m->t = m->t_a = t0;
#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
    m->rate_dirty = 1;
#endif
}

const char *model_set_start_time(ModelData *m, double t0)
{
    if (m->t != m->t_a) return "the simulation has already advanced";
    m->t = m->t_a = t0;
    m->cached = 0;
    return NULL;
}

double model_time(const ModelData *m) { return m->t; }

static const char *check_parameter(const DuhemVariable *var, double value)
{
    const Range *range = &var->range;
    if (!isfinite(value)) return "the value is not finite (NaN or infinite)";
    if (value < range->lower || value > range->upper || (range->strict && value <= range->lower))
        return range->rule;
    return NULL;
}

const char *model_validate(ModelData *m)
{
    int i;
    for (i = 0; i < DUHEM_N_VARIABLES; i++) {
        const DuhemVariable *var = &duhem_variables[i];
        if (var->role == VAR_PARAMETER && check_parameter(var, m->par[var->index]))
            return "a parameter is out of range";
    }
    for (i = 0; i < N; i++)
        if (!isfinite(m->x_a[i])) return "the state is not finite";
    if (!(isfinite(m->t_a) && isfinite(m->t) && isfinite(m->u_a) && isfinite(m->u) && isfinite(m->du)))
        return "time or input is not finite";
    if (m->t < m->t_a) return "time is before the last communication point";
    if (m->has_s_a != 0 && m->has_s_a != 1) return "corrupt effect flag";
    for (i = 0; m->has_s_a && i < DUHEM_EFFECT_STATES; i++)
        if (!isfinite(m->s_a[i])) return "the effect state is not finite";
    m->cached = 0;
#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
    m->rate_dirty = 1;
#endif
    return NULL;
}

/*
 * The model is checked where it is used (fitter.core.checks, the magnitude check): every parameter (the
 * exported ones and those the host set) and the start state finite with |v| <= DUHEM_MAX_MAGNITUDE, whatever
 * --allow-unstable; a model this large overflows the flow (x0 = 1e308 gives y = inf at the first product).
 */
#define DUHEM_MAX_MAGNITUDE 1e100   /* fitter.core.checks.MAX_MAGNITUDE */

const char *model_exit_initialization(ModelData *m)
{
    int i;
    for (i = 0; i < DUHEM_N_PARAMETERS; i++)
        if (!(fabs(m->par[i]) <= DUHEM_MAX_MAGNITUDE))
            return "a parameter is not finite or beyond 1e100 in magnitude (a model this large overflows the "
                   "simulation; fitter.core.checks.MAX_MAGNITUDE): set it to at most 1e100 in magnitude";
    for (i = 0; i < N; i++)
        if (!(fabs(m->x_a[i]) <= DUHEM_MAX_MAGNITUDE))
            return "the start state is not finite or beyond 1e100 in magnitude: set x0 to at most 1e100 in "
                   "magnitude";
#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
    if (m->rate_dirty) return build_rate(m);
#endif
    return NULL;
}

const char *model_get_real(ModelData *m, unsigned int vr, double *value)
{
    const DuhemVariable *var = find('r', vr);
    const char *msg;
    if (!var) return UNKNOWN;
    switch (var->role) {
    case VAR_INPUT:
        *value = m->u;
        return NULL;
    case VAR_PARAMETER:
        *value = m->par[var->index];
        return NULL;
    case VAR_TIME:
        *value = m->t;
        return NULL;
    case VAR_OUTPUT:
        msg = advance(m);
        if (msg) return msg;
        *value = m->y;
        return NULL;
    default:
        return UNKNOWN;
    }
}

const char *model_check_set_real(const ModelData *m, unsigned int vr, double value,
                                 ModelPhase phase)
{
    const DuhemVariable *var = find('r', vr);
    (void)m;
    if (!var) return UNKNOWN;
    if (var->role == VAR_OUTPUT) return "an output cannot be set";
    if (var->role == VAR_TIME) return "the independent variable cannot be set";
    if (var->role == VAR_PARAMETER && phase != PHASE_CONFIGURE)
        return "a fixed parameter can only be set before ExitInitializationMode";
    if (var->role == VAR_PARAMETER) return check_parameter(var, value);
    if (!isfinite(value)) return "the input is not finite (NaN or infinite)";
    return NULL;
}

void model_set_real(ModelData *m, unsigned int vr, double value, ModelPhase phase)
{
    const DuhemVariable *var = find('r', vr);
    (void)phase;
    if (var->role == VAR_INPUT) {
        m->u = value;
        if (m->t == m->t_a) m->u_a = value;
    } else {
        m->par[var->index] = value;
        if (var->index >= P_X0 && var->index < P_X0 + N) m->x_a[var->index - P_X0] = value;
#if DUHEM_EFFECT_START >= 0
        if (var->index >= DUHEM_EFFECT_START && var->index < DUHEM_EFFECT_START + DUHEM_EFFECT_STATES)
            m->s_a[var->index - DUHEM_EFFECT_START] = value;
#endif
#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
        if (var->index >= P_GV && var->index < P_GG + K) m->rate_dirty = 1;
#endif
    }
    m->cached = 0;
}

const char *model_get_integer(const ModelData *m, unsigned int vr, int *value)
{
    const DuhemVariable *var = find('i', vr);
    (void)m;
    if (!var) return UNKNOWN;
    *value = var->index;
    return NULL;
}

const char *model_get_boolean(const ModelData *m, unsigned int vr, int *value)
{
    (void)m;
    (void)vr;
    (void)value;
    return UNKNOWN;
}

const char *model_get_string(const ModelData *m, unsigned int vr, const char **value)
{
    const DuhemVariable *var = find('s', vr);
    (void)m;
    if (!var) return UNKNOWN;
    *value = duhem_strings[var->index];
    return NULL;
}

const char *model_check_set_integer(const ModelData *m, unsigned int vr, int value)
{
    const DuhemVariable *var = find('i', vr);
    (void)m;
    if (!var) return UNKNOWN;
    if (value != var->index) return "structural: export a new FMU to change it";
    return NULL;
}

const char *model_check_set_boolean(const ModelData *m, unsigned int vr, int value)
{
    (void)m;
    (void)vr;
    (void)value;
    return UNKNOWN;
}

const char *model_check_set_string(const ModelData *m, unsigned int vr, const char *value)
{
    const DuhemVariable *var = find('s', vr);
    (void)m;
    if (!var) return UNKNOWN;
    if (!value) return "value is NULL";
    if (strcmp(value, duhem_strings[var->index]) != 0)
        return "structural: export a new FMU to change it";
    return NULL;
}

const char *model_do_step(ModelData *m, double h)
{
    const char *msg = advance(m);
    if (msg) return msg;
    if (!isfinite(m->t + h)) return "the time would overflow";
    if (!isfinite(m->u + m->du * h)) return "the extrapolated input u + du/dt h is not finite";
    memcpy(m->x_a, m->x, sizeof m->x_a);
    memcpy(m->s_a, m->s, sizeof m->s_a);
    m->has_s_a = 1;
    m->t_a = m->t;
    m->u_a = m->u;
    m->t = m->t + h;
    m->u = m->u + m->du * h;
    m->cached = 0;
    return NULL;
}

const char *model_set_input_derivative(ModelData *m, unsigned int vr, int order, double value)
{
    const DuhemVariable *var = find('r', vr);
    if (!var || var->role != VAR_INPUT) return "not an input (only the input u has derivatives)";
    if (order != 1) return "only order 1 is supported (maxInputDerivativeOrder: the input is linear over a step)";
    if (!isfinite(value)) return "the derivative is not finite (NaN or infinite)";
    m->du = value;
    return NULL;
}
