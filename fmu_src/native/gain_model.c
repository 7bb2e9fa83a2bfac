/*
 * A trivial model on the same FMI framework: y = k u (value references u = 0,
 * y = 1, k = 2; time = 3, the independent variable FMI 3.0 declares).  It measures the per-step floor of a native FMU (host loop
 * plus framework) in bench/fmu_throughput.py; it is not part of any exported
 * model FMU.
 */
#include <math.h>
#include <string.h>

#include "model_interface.h"

#define GAIN_GUID "{6d1c2a0e-5b8f-4c3e-9a71-0000000000a1}"

enum { VR_U = 0, VR_Y = 1, VR_K = 2, VR_TIME = 3 };

struct ModelData {
    double u, k, t;
};

static const char *const UNKNOWN = "unknown value reference for this type";

const char *model_variable_name(char type, unsigned int vr)
{
    static const char *const names[] = {"u", "y", "k", "time"};
    return type == 'r' && vr <= VR_TIME ? names[vr] : "?";
}

size_t model_size(void) { return sizeof(ModelData); }

const char *model_guid(void) { return GAIN_GUID; }

void model_defaults(ModelData *m, double t0)
{
    m->u = 0.0;
    m->k = 2.0;
    m->t = t0;
}

const char *model_set_start_time(ModelData *m, double t0)
{
    m->t = t0;
    return NULL;
}

double model_time(const ModelData *m) { return m->t; }

const char *model_validate(ModelData *m)
{
    return isfinite(m->u) && isfinite(m->k) && isfinite(m->t) ? NULL : "not finite";
}

const char *model_exit_initialization(ModelData *m)
{
    (void)m;
    return NULL;
}

const char *model_get_real(ModelData *m, unsigned int vr, double *value)
{
    if (vr == VR_U) *value = m->u;
    else if (vr == VR_Y) *value = m->k * m->u;
    else if (vr == VR_K) *value = m->k;
    else if (vr == VR_TIME) *value = m->t;
    else return UNKNOWN;
    return NULL;
}

const char *model_check_set_real(const ModelData *m, unsigned int vr, double value,
                                 ModelPhase phase)
{
    (void)m;
    if (vr == VR_Y) return "an output cannot be set";
    if (vr == VR_TIME) return "the independent variable cannot be set";
    if (vr != VR_U && vr != VR_K) return UNKNOWN;
    if (vr == VR_K && phase != PHASE_CONFIGURE)
        return "a fixed parameter can only be set before ExitInitializationMode";
    return isfinite(value) ? NULL : "the value is not finite (NaN or infinite)";
}

void model_set_real(ModelData *m, unsigned int vr, double value, ModelPhase phase)
{
    (void)phase;
    if (vr == VR_U) m->u = value;
    else m->k = value;
}

const char *model_get_integer(const ModelData *m, unsigned int vr, int *value)
{
    (void)m; (void)vr; (void)value;
    return UNKNOWN;
}

const char *model_get_boolean(const ModelData *m, unsigned int vr, int *value)
{
    (void)m; (void)vr; (void)value;
    return UNKNOWN;
}

const char *model_get_string(const ModelData *m, unsigned int vr, const char **value)
{
    (void)m; (void)vr; (void)value;
    return UNKNOWN;
}

const char *model_check_set_integer(const ModelData *m, unsigned int vr, int value)
{
    (void)m; (void)vr; (void)value;
    return UNKNOWN;
}

const char *model_check_set_boolean(const ModelData *m, unsigned int vr, int value)
{
    (void)m; (void)vr; (void)value;
    return UNKNOWN;
}

const char *model_check_set_string(const ModelData *m, unsigned int vr, const char *value)
{
    (void)m; (void)vr; (void)value;
    return UNKNOWN;
}

const char *model_do_step(ModelData *m, double h)
{
    if (!isfinite(m->t + h)) return "the time would overflow";
    m->t = m->t + h;
    return NULL;
}

const char *model_set_input_derivative(ModelData *m, unsigned int vr, int order, double value)
{
    (void)m; (void)vr; (void)order; (void)value;
    return "not supported (canInterpolateInputs = false: y = k u has no state to move along the input)";
}
