/*
 * The feedforward compensator of a semilinear Duhem model behind the FMI
 * framework: the C twin of fitter.core.inverse.Compensator, as the FMU of
 * `duhem export --inverse` (input y_ref, output u).
 *
 * The plant is duhem_model.c itself, compiled into this file with its hooks
 * renamed plant_* (below): the compensator runs the root finding on the
 * plant's own forward step (advance, model_do_step), no copy of the kernel.
 * model_data.h is the plant's (fitter.fmu.native), with the compensator's
 * GUID and COMPENSATOR_REFERENCE_START, the start value of y_ref.
 *
 * Semantics (fitter.core.inverse, "Method"): the compensator holds the plant
 * at the last committed communication point (anchor: t_a, u_a, x_a, chain
 * state) and the current time t and reference y_ref.  Reading u solves
 * f(u) = y_ref, f(u) the plant's output at t for the input linear from u_a to
 * u over [t_a, t] (at the first point, t == t_a, the input is re-anchored and
 * the state does not move); a step commits the solved point and advances t.
 * Which root (of the inputs that give y_ref, |y - y_ref| <= YTOL times the
 * output scale, the one nearest the last input: the held input whenever it
 * still gives y_ref, so u read again after a step with y_ref unchanged is the
 * sample's u), the output scale (|y(hi) - y(lo)| at the first interval step,
 * in Progress), the search range [DUHEM_INPUT_LO, DUHEM_INPUT_HI], the growing
 * bracket search (factor 4, first guess from the last slope; the preferred
 * side, then the other one up to the distance of the root found), Brent's
 * method (polished below its input tolerance while the residual is above half
 * the output tolerance) and the clamp (the evaluated input whose output is
 * nearest y_ref, refined by golden-section search at an interior extremum)
 * are those of Compensator._solve, step for step, so the two agree to
 * rounding.  An input
 * derivative dy_ref/dt (FMI 2, order 1) moves y_ref on to y_ref + dy h at a
 * step.  A NaN or infinite y_ref is refused.
 */
#include <math.h>
#include <string.h>

/* ---------------------------------------------------------------- the plant */

#define ModelData PlantData
#define model_size plant_size
#define model_guid plant_guid
#define model_defaults plant_defaults
#define model_set_start_time plant_set_start_time
#define model_time plant_time
#define model_validate plant_validate
#define model_exit_initialization plant_exit_initialization
#define model_variable_name plant_variable_name
#define model_get_real plant_get_real
#define model_get_integer plant_get_integer
#define model_get_boolean plant_get_boolean
#define model_get_string plant_get_string
#define model_check_set_real plant_check_set_real
#define model_set_real plant_set_real
#define model_check_set_integer plant_check_set_integer
#define model_check_set_boolean plant_check_set_boolean
#define model_check_set_string plant_check_set_string
#define model_do_step plant_do_step
#define model_set_input_derivative plant_set_input_derivative
#include "duhem_model.c"
#undef ModelData
#undef model_size
#undef model_guid
#undef model_defaults
#undef model_set_start_time
#undef model_time
#undef model_validate
#undef model_exit_initialization
#undef model_variable_name
#undef model_get_real
#undef model_get_integer
#undef model_get_boolean
#undef model_get_string
#undef model_check_set_real
#undef model_set_real
#undef model_check_set_integer
#undef model_check_set_boolean
#undef model_check_set_string
#undef model_do_step
#undef model_set_input_derivative
/* model_interface.h, already included (for the plant), declares the hooks below under their plant_ names;
   the framework's own translation unit declares them as model_*. */
typedef struct ModelData ModelData;

#ifndef COMPENSATOR_REFERENCE_START
#error "model_data.h: COMPENSATOR_REFERENCE_START missing (not generated for a compensator)"
#endif

#define VR_U 0u     /* the compensator's output: the plant's input */
#define VR_YREF 1u  /* the compensator's input: the plant's output reference */
#define SEEN_MAX 256
#define GROW 4.0
#define GOLDEN 0.6180339887498949   /* (sqrt(5) - 1) / 2 */
#define EPS 2.220446049250313e-16
#define YTOL 1e-10                  /* an input gives y_ref when |y - y_ref| <= YTOL * the output scale */

/* The compensator's own state, committed at a step (orientation 0, scale NaN: not yet known). */
typedef struct {
    int started;
    double slope, scale, orientation;
} Progress;

struct ModelData {
    PlantData anchor;  /* the plant at the last committed point (its t, u unused) */
    double t, y_ref, dy;
    Progress done;     /* as of the anchor */
    /* the solved current point, valid when solved */
    int solved;
    double u;
    PlantData after;   /* the anchor after committing it */
    Progress next;
};

typedef struct {
    ModelData *m;
    PlantData trial;
    double t, y_ref;
} Problem;

typedef struct {
    double u, r;
} Point;

/* f(u) = output of the plant at t for the input linear from the anchor's to u, minus y_ref; NaN on failure. */
static double residual(Problem *p, double u)
{
    PlantData *tr = &p->trial;
    memcpy(tr, &p->m->anchor, sizeof *tr);
    if (p->t == tr->t_a) tr->u_a = u;   /* the first point: re-anchor the input, the state does not move */
    tr->t = p->t;
    tr->u = u;
    tr->du = 0.0;
    tr->cached = 0;
    if (advance(tr)) return NAN;
    return tr->y - p->y_ref;
}

/* Brent's method on [a, b] with fa, fb of opposite signs (inverse._brent, as scipy's brentq); at a bracket
   below xtol with |f| > ftol it goes on with the bracket tolerance xfloor. */
static Point brent(Problem *p, double a, double b, double fa, double fb, double xtol, double ftol, double xfloor)
{
    double xpre = a, xcur = b, fpre = fa, fcur = fb, xblk = 0.0, fblk = 0.0, spre = 0.0, scur = 0.0;
    const double rtol = 4 * EPS;
    int i;
    Point out;
    for (i = 0; i < 200; i++) {
        double delta, sbis;
        if (fpre != 0 && fcur != 0 && (fpre < 0) != (fcur < 0)) {
            xblk = xpre;
            fblk = fpre;
            spre = scur = xcur - xpre;
        }
        if (fabs(fblk) < fabs(fcur)) {
            xpre = xcur; xcur = xblk; xblk = xpre;
            fpre = fcur; fcur = fblk; fblk = fpre;
        }
        delta = (xtol + rtol * fabs(xcur)) / 2;
        sbis = (xblk - xcur) / 2;
        if (fcur == 0 || fabs(sbis) < delta) {
            if (fcur == 0 || fabs(fcur) <= ftol || xtol <= xfloor) break;
            xtol = xfloor;   /* polish: from here on the finer bracket tolerance */
            delta = (xtol + rtol * fabs(xcur)) / 2;
            if (fabs(sbis) < delta) break;
        }
        if (fabs(spre) > delta && fabs(fcur) < fabs(fpre)) {
            double stry;
            if (xpre == xblk) {
                stry = -fcur * (xcur - xpre) / (fcur - fpre);
            } else {
                double dpre = (fpre - fcur) / (xpre - xcur), dblk = (fblk - fcur) / (xblk - xcur);
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre));
            }
            if (2 * fabs(stry) < fmin(fabs(spre), 3 * fabs(sbis) - delta)) {
                spre = scur;
                scur = stry;
            } else {
                spre = scur = sbis;
            }
        } else {
            spre = scur = sbis;
        }
        xpre = xcur;
        fpre = fcur;
        xcur = xcur + (fabs(scur) > delta ? scur : (sbis > 0 ? delta : -delta));
        fcur = residual(p, xcur);
    }
    out.u = xcur;
    out.r = fcur;
    return out;
}

/* The root nearest u_a on side s, distance up to reach (inverse.Compensator._search); 1 if found. */
static int search(Problem *p, double u_a, double r0, double s, double reach, double d, double xtol,
                  double ftol, double xfloor, Point *seen, int *n_seen, Point *found)
{
    Point prev;
    prev.u = u_a;
    prev.r = r0;
    while (reach > 0) {
        double dist = fmin(d, reach), u = u_a + s * dist, r = residual(p, u);
        if (!isfinite(r)) return 0;
        if (*n_seen < SEEN_MAX) {
            seen[*n_seen].u = u;
            seen[(*n_seen)++].r = r;
        }
        if (r == 0) {
            found->u = u;
            found->r = r;
            return 1;
        }
        if ((r < 0) != (prev.r < 0)) {
            *found = brent(p, prev.u, u, prev.r, r, xtol, ftol, xfloor);
            return 1;
        }
        if (dist >= reach) return 0;
        prev.u = u;
        prev.r = r;
        d *= GROW;
    }
    return 0;
}

/* No root: the evaluated input whose output is nearest y_ref (inverse.Compensator._nearest). */
static Point nearest(Problem *p, Point *pts, int n, double xtol)
{
    int i, j, k = 0;
    Point best;
    for (i = 1; i < n; i++) {   /* sort by u, then r (Python's sorted on tuples) */
        Point x = pts[i];
        for (j = i; j > 0 && (pts[j - 1].u > x.u || (pts[j - 1].u == x.u && pts[j - 1].r > x.r)); j--)
            pts[j] = pts[j - 1];
        pts[j] = x;
    }
    for (i = 1; i < n; i++)
        if (fabs(pts[i].r) < fabs(pts[k].r)) k = i;
    best = pts[k];
    if (k > 0 && k < n - 1) {
        double a = pts[k - 1].u, b = pts[k + 1].u;
        for (i = 0; i < 80; i++) {
            double c, e, rc, re;
            if (fabs(b - a) <= xtol) break;
            c = b - GOLDEN * (b - a);
            e = a + GOLDEN * (b - a);
            rc = residual(p, c);
            re = residual(p, e);
            if (isfinite(rc) && fabs(rc) < fabs(best.r)) { best.u = c; best.r = rc; }
            if (isfinite(re) && fabs(re) < fabs(best.r)) { best.u = e; best.r = re; }
            if (!(fabs(rc) > fabs(re))) b = e;
            else a = c;
        }
    }
    return best;
}

/* Solve the current point (inverse.Compensator._solve) and commit it into m->after; NULL or why not. */
static const char *solve(ModelData *m)
{
    const double lo = DUHEM_INPUT_LO, hi = DUHEM_INPUT_HI, span = hi - lo;
    const double xtol = 1e-13 * fmax(span, fmax(fabs(lo), fabs(hi)));
    const double xfloor = EPS * fmax(span, fmax(fabs(lo), fabs(hi)));
    Problem local;
    Point seen[SEEN_MAX], found = {0.0, 0.0}, other;
    int n_seen = 0, side, ok = 0;
    double u_a, r0, scale, tol, guess, preferred, u;
    const char *msg;
    if (m->solved) return NULL;
    local.m = m;
    local.t = m->t;
    local.y_ref = m->y_ref;
    m->next = m->done;
    u_a = m->anchor.u_a;
    if (m->t == m->anchor.t_a) {   /* the first point: its own span (feedthrough only), not kept */
        scale = fabs(residual(&local, hi) - residual(&local, lo));
        if (!isfinite(scale)) scale = 0.0;
    } else {
        if (isnan(m->next.scale)) {   /* the first interval step: the output scale and the orientation */
            double r_hi = residual(&local, hi), r_lo = residual(&local, lo);
            int finite = isfinite(r_hi) && isfinite(r_lo);
            m->next.scale = finite ? fabs(r_hi - r_lo) : 0.0;
            if (m->next.orientation == 0) m->next.orientation = finite && r_hi < r_lo ? -1.0 : 1.0;
        }
        scale = m->next.scale;
    }
    tol = YTOL * scale;
    r0 = residual(&local, u_a);
    if (!isfinite(r0)) return "the model's output is not finite for the held input";
    if (fabs(r0) <= tol) {   /* the held input still gives y_ref: kept */
        u = u_a;
    } else {
        guess = m->next.slope != 0 && isfinite(m->next.slope) ? fabs(r0 / m->next.slope) * 1.5 : 1e-3 * span;
        guess = fmin(fmax(guess, 1e-12 * span), span);
        preferred = (m->next.orientation != 0 ? m->next.orientation : 1.0) * (r0 < 0 ? 1.0 : -1.0);
        seen[n_seen].u = u_a;
        seen[n_seen++].r = r0;
        for (side = 0; side < 2; side++) {   /* the nearest root; the other side only if strictly nearer */
            double s = side == 0 ? preferred : -preferred, reach = s > 0 ? hi - u_a : u_a - lo;
            if (ok) reach = fmin(reach, fabs(found.u - u_a));
            if (search(&local, u_a, r0, s, reach, guess, xtol, tol / 2, xfloor, seen, &n_seen, &other)
                && (!ok || fabs(other.u - u_a) < fabs(found.u - u_a))) {
                found = other;
                ok = 1;
            }
        }
        if (ok) {
            if (found.u != u_a) m->next.slope = (found.r - r0) / (found.u - u_a);
        } else {
            found = nearest(&local, seen, n_seen, xtol);
        }
        u = found.u;
    }
    if (!isfinite(residual(&local, u))) return "the model's output is not finite at the solved input";
    msg = plant_do_step(&local.trial, 1.0);   /* commit: the solved point becomes the anchor */
    if (msg) return msg;
    memcpy(&m->after, &local.trial, sizeof m->after);
    m->next.started = 1;
    m->u = u;
    m->solved = 1;
    return NULL;
}

/* ---------------------------------------------------------------- hooks */

size_t model_size(void) { return sizeof(ModelData); }

const char *model_guid(void) { return DUHEM_GUID; }

const char *model_variable_name(char type, unsigned int vr)
{
    if (type == 'r' && vr == VR_U) return "u";
    if (type == 'r' && vr == VR_YREF) return "y_ref";
    return plant_variable_name(type, vr);
}

void model_defaults(ModelData *m, double t0)
{
    memset(m, 0, sizeof *m);
    plant_defaults(&m->anchor, t0);
    m->anchor.u = m->anchor.u_a = (DUHEM_INPUT_LO + DUHEM_INPUT_HI) / 2;
    m->t = t0;
    m->y_ref = COMPENSATOR_REFERENCE_START;
    m->done.slope = NAN;
    m->done.scale = NAN;
}

const char *model_set_start_time(ModelData *m, double t0)
{
    const char *msg;
    if (m->done.started) return "the simulation has already advanced";
    msg = plant_set_start_time(&m->anchor, t0);
    if (msg) return msg;
    m->t = t0;
    m->solved = 0;
    return NULL;
}

double model_time(const ModelData *m) { return m->t; }

const char *model_validate(ModelData *m)
{
    const char *msg = plant_validate(&m->anchor);
    if (msg) return msg;
    if (!(isfinite(m->t) && isfinite(m->y_ref) && isfinite(m->dy))) return "time or reference is not finite";
    if (m->done.started != 0 && m->done.started != 1) return "corrupt compensator flag";
    if (m->done.orientation != 0 && m->done.orientation != 1 && m->done.orientation != -1)
        return "corrupt orientation";
    if (!(isnan(m->done.scale) || (isfinite(m->done.scale) && m->done.scale >= 0))) return "corrupt output scale";
    if (m->t < m->anchor.t_a || (m->done.started && m->t == m->anchor.t_a))
        return "time is not after the last communication point";
    if (!(m->anchor.u_a >= DUHEM_INPUT_LO && m->anchor.u_a <= DUHEM_INPUT_HI)) return "input out of range";
    m->solved = 0;
    return NULL;
}

const char *model_exit_initialization(ModelData *m)
{
    m->solved = 0;
    return plant_exit_initialization(&m->anchor);
}

const char *model_get_real(ModelData *m, unsigned int vr, double *value)
{
    const char *msg;
    const DuhemVariable *var;
    if (vr == VR_U) {
        msg = solve(m);
        if (msg) return msg;
        *value = m->u;
        return NULL;
    }
    if (vr == VR_YREF) {
        *value = m->y_ref;
        return NULL;
    }
    var = find('r', vr);
    if (var && var->role == VAR_TIME) {
        *value = m->t;
        return NULL;
    }
    return plant_get_real(&m->anchor, vr, value);
}

const char *model_check_set_real(const ModelData *m, unsigned int vr, double value, ModelPhase phase)
{
    if (vr == VR_U) return "an output cannot be set";
    if (vr == VR_YREF) return isfinite(value) ? NULL : "the reference is not finite (NaN or infinite)";
    return plant_check_set_real(&m->anchor, vr, value, phase);
}

void model_set_real(ModelData *m, unsigned int vr, double value, ModelPhase phase)
{
    if (vr == VR_YREF) m->y_ref = value;
    else plant_set_real(&m->anchor, vr, value, phase);
    m->solved = 0;
}

const char *model_get_integer(const ModelData *m, unsigned int vr, int *value)
{
    return plant_get_integer(&m->anchor, vr, value);
}

const char *model_get_boolean(const ModelData *m, unsigned int vr, int *value)
{
    return plant_get_boolean(&m->anchor, vr, value);
}

const char *model_get_string(const ModelData *m, unsigned int vr, const char **value)
{
    return plant_get_string(&m->anchor, vr, value);
}

const char *model_check_set_integer(const ModelData *m, unsigned int vr, int value)
{
    return plant_check_set_integer(&m->anchor, vr, value);
}

const char *model_check_set_boolean(const ModelData *m, unsigned int vr, int value)
{
    return plant_check_set_boolean(&m->anchor, vr, value);
}

const char *model_check_set_string(const ModelData *m, unsigned int vr, const char *value)
{
    return plant_check_set_string(&m->anchor, vr, value);
}

const char *model_do_step(ModelData *m, double h)
{
    const char *msg = solve(m);
    if (msg) return msg;
    if (!isfinite(m->t + h)) return "the time would overflow";
    if (!isfinite(m->y_ref + m->dy * h)) return "the extrapolated reference y_ref + dy_ref/dt h is not finite";
    memcpy(&m->anchor, &m->after, sizeof m->anchor);
    m->done = m->next;
    m->t = m->t + h;
    m->y_ref = m->y_ref + m->dy * h;
    m->solved = 0;
    return NULL;
}

const char *model_set_input_derivative(ModelData *m, unsigned int vr, int order, double value)
{
    if (vr != VR_YREF) return "not an input (only the reference y_ref has derivatives)";
    if (order != 1) return "only order 1 is supported (the reference is linear over a step)";
    if (!isfinite(value)) return "the derivative is not finite (NaN or infinite)";
    m->dy = value;
    return NULL;
}
