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
 * [t_a, t]; fmi2DoStep commits the current point as the new anchor and
 * advances t; a held input moves nothing; setting u while t == t_a
 * re-anchors the input without moving the state.
 *
 * Exact flow (kernel module docstring, eq (K)): over one interval
 * dx/ds = A x + B (p + r s) + E for 0 <= s <= S, so
 *   [x(S); s; 1] = expm(S [[A, B r, B p + E], [0, 0, 1], [0, 0, 0]]) [x(0); 0; 1]
 * with, for the rate-independent model, p = u_a, r = 1, S = u - u_a and the
 * branch chosen by the sign of u - u_a (a held input keeps the + branch,
 * where S = 0); for the rate-dependent model v = (u - u_a)/(t - t_a),
 * p = u_a, S = g(v) (t - t_a), r = v / g(v) (r = 0 when g(v) = 0, where
 * S = 0).  The matrix exponential is the kernel's: scaling to 1-norm <= 0.5,
 * degree-18 Taylor series, squaring.
 *
 * Rate function: TabulatedRate, a PCHIP (Fritsch-Carlson slopes, limited
 * three-point end slopes) through (0, 0), separately on v <= 0 and v >= 0,
 * constant beyond the outermost nodes; its nodes g_v, g_g are parameters, so
 * the interpolant is rebuilt here when they change.
 *
 * Effects (fitter.core.effects, steps 1-8 of its chain, in that order):
 * backlash (play of width b on the base input), rate_dependence (S -> S s,
 * r -> r / s, s = 1/(1 + alpha |dw/h|)), base output C x + D w, creep
 * (exact first-order state c), viscous (c du/h), thermal_drift
 * (1 - kappa W, W the input travel), saturation (tanh), sensor_lag (exact
 * first-order lag of the output, linear between samples).  The chain's state
 * at the anchor (w, c, W, m, y) is part of the FMU state.
 */
#include <math.h>
#include <string.h>

#include "fmi2_framework.h"
#include "duhem_model.h"
#include "model_data.h"

#define N DUHEM_ORDER
#define M (DUHEM_ORDER + 2)
#define TAYLOR_DEGREE 18
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

#define HAS(effect) (DUHEM_EFFECT_##effect >= 0)
#define EFFECT(m, effect) ((m)->par[DUHEM_EFFECT_##effect])
#define HAS_EFFECTS (HAS(BACKLASH_B) || HAS(RATE_DEPENDENCE_ALPHA) || HAS(CREEP_K) \
                     || HAS(VISCOUS_C) || HAS(THERMAL_DRIFT_KAPPA) || HAS(SATURATION_BETA) \
                     || HAS(SENSOR_LAG_TAU))

/* Compile-time check that model_data.h was generated for this layout. */
typedef char parameter_layout_matches_model_data[(P_BASE_END <= DUHEM_N_PARAMETERS) ? 1 : -1];

/* State of the effect chain at a sample (fitter.core.effects.EffectState). */
typedef struct {
    double w, c, W, m, y;
} EffectState;

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
    double x_a[N];
    EffectState s_a;  /* chain state at the anchor, valid when has_s_a */
    int has_s_a;
    double x[N];      /* state and output at (t, u), valid when cached */
    double y;
    EffectState s;
    int cached;
#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
    RateSide rate[2]; /* v < 0, v > 0; rebuilt from g_v, g_g when rate_dirty */
    int rate_dirty;
#endif
};

/* ---------------------------------------------------------------- exact flow */

/*
 * Z = e^X for the augmented matrix X of flow() (X is overwritten); -1 when X is
 * not finite or too large to scale.  Rows N and N+1 of X are zero but for
 * X[N][N+1] = sigma, so the rows N, N+1 of every power X^k (k >= 2) are zero
 * and those of e^X are [0 .. 0 1 sigma] and [0 .. 0 0 1]: only the top N rows
 * are computed.  The terms left out are exact zeros, so Z is the full
 * algorithm's, at about half the cost.
 */
static int expm(double X[M][M], double Z[M][M])
{
    double T[N][M], P[N][M], norm = 0.0, scale = 1.0, sigma;
    int i, j, c, k, s = 0;
    for (j = 0; j < M; j++) {
        double column = 0.0;
        for (i = 0; i < M; i++) column += fabs(X[i][j]);
        if (!(column <= EXPM_NORM_LIMIT)) return -1;
        if (column > norm) norm = column;
    }
    while (norm > 0.5) {
        norm *= 0.5;
        scale *= 2.0;
        s++;
    }
    for (i = 0; i < M; i++)
        for (j = 0; j < M; j++) X[i][j] /= scale;
    for (i = 0; i < N; i++)
        for (j = 0; j < M; j++) {
            T[i][j] = X[i][j];
            Z[i][j] = (i == j ? 1.0 : 0.0) + X[i][j];
        }
    for (k = 2; k <= TAYLOR_DEGREE; k++) {
        for (i = 0; i < N; i++)
            for (c = 0; c < M; c++) {
                double acc = 0.0;
                for (j = 0; j <= N; j++) acc += T[i][j] * X[j][c];
                P[i][c] = acc;
            }
        for (i = 0; i < N; i++)
            for (j = 0; j < M; j++) {
                T[i][j] = P[i][j] / k;
                Z[i][j] += T[i][j];
            }
    }
    sigma = X[N][N + 1];
    for (j = 0; j < M; j++) Z[N][j] = Z[N + 1][j] = 0.0;
    Z[N][N] = Z[N + 1][N + 1] = 1.0;
    for (; s > 0; s--) {
        Z[N][N + 1] = sigma;
        for (i = 0; i < N; i++)
            for (c = 0; c < M; c++) {
                double acc = 0.0;
                for (j = 0; j < M; j++) acc += Z[i][j] * Z[j][c];
                P[i][c] = acc;
            }
        memcpy(Z, P, sizeof P);
        sigma = sigma + sigma;
    }
    Z[N][N + 1] = sigma;
    return 0;
}

/* out = x(S) of dx/ds = A x + B (p + r s) + E from x(0) = x; -1 if not finite. */
static int flow(const double *A, const double *B, const double *E, const double *x, double p,
                double r, double S, double *out)
{
    double X[M][M], Z[M][M];
    int i, j;
    if (S == 0.0) {
        memcpy(out, x, N * sizeof(double));
        return 0;
    }
    memset(X, 0, sizeof X);
    for (i = 0; i < N; i++) {
        for (j = 0; j < N; j++) X[i][j] = A[i * N + j] * S;
        X[i][N] = B[i] * r * S;
        X[i][N + 1] = (B[i] * p + E[i]) * S;
    }
    X[N][N + 1] = S;
    if (expm(X, Z)) return -1;
    for (i = 0; i < N; i++) {
        double acc = 0.0;
        for (j = 0; j < N; j++) acc += Z[i][j] * x[j];
        out[i] = acc + Z[i][N + 1];
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

/* ---------------------------------------------------------------- stepping */

/* Base state x from x_a over the interval on which the base input goes w0 -> w1 in time h. */
static int base_flow(const ModelData *m, double w0, double w1, double h, double *x)
{
    double dw = w1 - w0, r, S;
#if DUHEM_KIND == DUHEM_RATE_INDEPENDENT
    const double *A = m->par + (dw < 0 ? P_A_MINUS : P_A_PLUS);
    const double *B = m->par + (dw < 0 ? P_B_MINUS : P_B_PLUS);
    const double *E = m->par + (dw < 0 ? P_E_MINUS : P_E_PLUS);
    r = 1.0;
    S = dw;
#else
    const double *A = m->par + P_A, *B = m->par + P_B, *E = m->par + P_E;
    double v = dw / h, g = rate(m, v);
    r = g != 0.0 ? v / g : 0.0;
    S = g * h;
#endif
#if HAS(RATE_DEPENDENCE_ALPHA)
    {
        double s = 1.0 / (1.0 + EFFECT(m, RATE_DEPENDENCE_ALPHA) * fabs(dw / h));
        r = r / s;
        S = S * s;
    }
#endif
    (void)h;
    if (!isfinite(r) || !isfinite(S)) return -1;
    return flow(A, B, E, m->x_a, w0, r, S, x);
}

static double base_output(const ModelData *m, const double *x, double w)
{
    double y = 0.0;
    int i;
    for (i = 0; i < N; i++) y += m->par[P_C + i] * x[i];
    return y + m->par[P_D] * w;
}

#if HAS(CREEP_K) || HAS(SENSOR_LAG_TAU)
/* Exact samples of dz/dt = (target(t) - z)/tau over h, target linear from z0t to z1t. */
static double first_order(double z0, double z0t, double z1t, double h, double tau)
{
    double x = h / tau, a = exp(-x), one_minus_a = -expm1(-x);
    double q = x > 0 ? one_minus_a / x : 1.0;
    return a * z0 + ((z1t - z0t) * (1.0 - q) + one_minus_a * z0t);
}
#endif

/* Steps 5-7 of the chain on one sample's y: viscous, thermal drift, saturation. */
static double output_effects(const ModelData *m, double y, double v, double W)
{
#if HAS(VISCOUS_C)
    y = y + EFFECT(m, VISCOUS_C) * v;
#endif
#if HAS(THERMAL_DRIFT_KAPPA)
    y = y * (1.0 - EFFECT(m, THERMAL_DRIFT_KAPPA) * W);
#endif
#if HAS(SATURATION_BETA)
    if (EFFECT(m, SATURATION_BETA) > 0) {
        double yc = EFFECT(m, SATURATION_Y_C), beta = EFFECT(m, SATURATION_BETA);
        y = yc + tanh(beta * (y - yc)) / beta;
    }
#endif
    (void)m;
    (void)v;
    (void)W;
    return y;
}

/* The chain at the anchor sample alone, from state s0 (NULL: afresh), as run_with_effects. */
static EffectState anchor_chain(const ModelData *m, const EffectState *s0)
{
    EffectState e;
    double u0 = m->u_a;
    e.w = u0;
#if HAS(BACKLASH_B)
    {
        double hb = EFFECT(m, BACKLASH_B) / 2, w_init = s0 ? s0->w : u0;
        e.w = fmin(u0 + hb, fmax(u0 - hb, w_init));
    }
#endif
    e.c = 0.0;
    e.y = base_output(m, m->x_a, e.w);
#if HAS(CREEP_K)
    e.c = s0 ? s0->c : EFFECT(m, CREEP_K) * u0;
    e.y = e.y + e.c;
#endif
    e.W = s0 ? s0->W : 0.0;
    e.y = output_effects(m, e.y, 0.0, e.W);
    e.m = e.y;
#if HAS(SENSOR_LAG_TAU)
    if (EFFECT(m, SENSOR_LAG_TAU) > 0 && s0) e.m = s0->m;
#endif
    return e;
}

/* The chain over the interval from the anchor (state s_a there; NULL: afresh) to the current point. */
static int interval_chain(const ModelData *m, const EffectState *s_a, double *x, EffectState *e)
{
    double u0 = m->u_a, u1 = m->u, h = m->t - m->t_a, w0 = u0;
    EffectState fresh;
    const EffectState *s0 = s_a;
    if (!s0) {
        fresh = anchor_chain(m, NULL);
        s0 = &fresh;
    }
    e->w = u1;
#if HAS(BACKLASH_B)
    {
        double hb = EFFECT(m, BACKLASH_B) / 2;
        w0 = fmin(u0 + hb, fmax(u0 - hb, s0->w));
        e->w = u1 - u0 < 0 ? fmin(w0, u1 + hb) : fmax(w0, u1 - hb);
    }
#endif
    if (base_flow(m, w0, e->w, h, x)) return -1;
    e->y = base_output(m, x, e->w);
    e->c = 0.0;
#if HAS(CREEP_K)
    {
        double k = EFFECT(m, CREEP_K);
        e->c = first_order(s0->c, k * u0, k * u1, h, EFFECT(m, CREEP_TAU));
        e->y = e->y + e->c;
    }
#endif
    e->W = s0->W + fabs(u1 - u0);
    e->y = output_effects(m, e->y, (u1 - u0) / h, e->W);
    e->m = e->y;
#if HAS(SENSOR_LAG_TAU)
    if (EFFECT(m, SENSOR_LAG_TAU) > 0)
        e->m = first_order(s0->m, s0->y, e->y, h, EFFECT(m, SENSOR_LAG_TAU));
#endif
    return isfinite(e->m) ? 0 : -1;
}

/* State and output at the current point, cached; NULL or why it failed. */
static const char *advance(ModelData *m)
{
    const char *failed = "the state is not finite after this input change (too large a step)";
    if (m->cached) return NULL;
#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
    if (m->rate_dirty) {
        const char *msg = build_rate(m);
        if (msg) return msg;
    }
#endif
    if (HAS_EFFECTS) {
        if (m->t == m->t_a) {
            memcpy(m->x, m->x_a, sizeof m->x);
            m->s = anchor_chain(m, m->has_s_a ? &m->s_a : NULL);
        } else if (interval_chain(m, m->has_s_a ? &m->s_a : NULL, m->x, &m->s)) {
            return failed;
        }
        m->y = m->s.m;
    } else {
        if (m->t == m->t_a || m->u == m->u_a) memcpy(m->x, m->x_a, sizeof m->x);
        else if (base_flow(m, m->u_a, m->u, m->t - m->t_a, m->x)) return failed;
        m->y = base_output(m, m->x, m->u);
    }
    m->cached = 1;
    return NULL;
}

/* ---------------------------------------------------------------- variables */

static const DuhemVariable *find(char type, fmi2ValueReference vr)
{
    int i;
    for (i = 0; i < DUHEM_N_VARIABLES; i++)
        if (duhem_variables[i].vr == vr && duhem_variables[i].type == type)
            return &duhem_variables[i];
    return NULL;
}

static const char *const UNKNOWN = "unknown value reference for this type";

const char *model_variable_name(char type, fmi2ValueReference vr)
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
    if (!isfinite(value)) return "the value is not finite (NaN or infinite)";
    if (var->constraint == NONNEGATIVE && value < 0) return "this parameter must be >= 0";
    if (var->constraint == POSITIVE && value <= 0) return "this parameter must be positive";
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
    if (!(isfinite(m->t_a) && isfinite(m->t) && isfinite(m->u_a) && isfinite(m->u)))
        return "time or input is not finite";
    if (m->t < m->t_a) return "time is before the last communication point";
    if (m->has_s_a != 0 && m->has_s_a != 1) return "corrupt effect flag";
    if (m->has_s_a && !(isfinite(m->s_a.w) && isfinite(m->s_a.c) && isfinite(m->s_a.W)
                        && isfinite(m->s_a.m) && isfinite(m->s_a.y)))
        return "the effect state is not finite";
    m->cached = 0;
#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
    m->rate_dirty = 1;
#endif
    return NULL;
}

const char *model_exit_initialization(ModelData *m)
{
#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
    if (m->rate_dirty) return build_rate(m);
#endif
    (void)m;
    return NULL;
}

const char *model_get_real(ModelData *m, fmi2ValueReference vr, fmi2Real *value)
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
    case VAR_OUTPUT:
        msg = advance(m);
        if (msg) return msg;
        *value = m->y;
        return NULL;
    default:
        return UNKNOWN;
    }
}

const char *model_check_set_real(const ModelData *m, fmi2ValueReference vr, fmi2Real value,
                                 ModelPhase phase)
{
    const DuhemVariable *var = find('r', vr);
    (void)m;
    if (!var) return UNKNOWN;
    if (var->role == VAR_OUTPUT) return "an output cannot be set";
    if (var->role == VAR_PARAMETER && phase != PHASE_CONFIGURE)
        return "a fixed parameter can only be set before fmi2ExitInitializationMode";
    if (var->role == VAR_PARAMETER) return check_parameter(var, value);
    if (!isfinite(value)) return "the input is not finite (NaN or infinite)";
    return NULL;
}

void model_set_real(ModelData *m, fmi2ValueReference vr, fmi2Real value, ModelPhase phase)
{
    const DuhemVariable *var = find('r', vr);
    (void)phase;
    if (var->role == VAR_INPUT) {
        m->u = value;
        if (m->t == m->t_a) m->u_a = value;
    } else {
        m->par[var->index] = value;
        if (var->index >= P_X0 && var->index < P_X0 + N) m->x_a[var->index - P_X0] = value;
#if DUHEM_KIND == DUHEM_RATE_DEPENDENT
        if (var->index >= P_GV && var->index < P_GG + K) m->rate_dirty = 1;
#endif
    }
    m->cached = 0;
}

const char *model_get_integer(const ModelData *m, fmi2ValueReference vr, fmi2Integer *value)
{
    const DuhemVariable *var = find('i', vr);
    (void)m;
    if (!var) return UNKNOWN;
    *value = var->index;
    return NULL;
}

const char *model_get_boolean(const ModelData *m, fmi2ValueReference vr, fmi2Boolean *value)
{
    (void)m;
    (void)vr;
    (void)value;
    return UNKNOWN;
}

const char *model_get_string(const ModelData *m, fmi2ValueReference vr, fmi2String *value)
{
    const DuhemVariable *var = find('s', vr);
    (void)m;
    if (!var) return UNKNOWN;
    *value = duhem_strings[var->index];
    return NULL;
}

const char *model_check_set_integer(const ModelData *m, fmi2ValueReference vr, fmi2Integer value)
{
    const DuhemVariable *var = find('i', vr);
    (void)m;
    if (!var) return UNKNOWN;
    if (value != var->index) return "structural: export a new FMU to change it";
    return NULL;
}

const char *model_check_set_boolean(const ModelData *m, fmi2ValueReference vr, fmi2Boolean value)
{
    (void)m;
    (void)vr;
    (void)value;
    return UNKNOWN;
}

const char *model_check_set_string(const ModelData *m, fmi2ValueReference vr, fmi2String value)
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
    memcpy(m->x_a, m->x, sizeof m->x_a);
    m->s_a = m->s;
    m->has_s_a = 1;
    m->t_a = m->t;
    m->u_a = m->u;
    m->t = m->t + h;
    m->cached = 0;
    return NULL;
}
