/*
 * Shared FMI 2.0 Co-Simulation framework: see fmi2_framework.h.
 *
 * State machine (FMI 2.0.4, section 4.2.4), without the asynchronous states:
 *   Instantiated --EnterInitializationMode--> InitializationMode
 *   InitializationMode --ExitInitializationMode--> StepComplete
 *   StepComplete --DoStep--> StepComplete, --Terminate--> Terminated
 *   any state --Reset--> Instantiated
 * A call in a state where the standard does not allow it, a NULL pointer, an
 * unknown value reference, a non-finite value or a bad step size is refused
 * with fmi2Error and a message through the logger; a refused call changes
 * nothing, so the instance stays usable and its memory intact.
 *
 * Memory comes from the C library's calloc and free: the FMU declares
 * canNotUseMemoryManagementFunctions, and ignores the host's allocateMemory
 * and freeMemory (which may then be NULL).
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_framework.h"
#include "serial_checksum.h"

#define INSTANCE_MAGIC 0x44554831u
#define STATE_MAGIC 0x44555331u
#define SERIAL_TAG "DUHEMFS2"
#define GUID_FIELD 64

enum {
    S_INSTANTIATED = 1,
    S_INIT = 2,
    S_STEP = 4,
    S_TERMINATED = 8,
    S_ANY = S_INSTANTIATED | S_INIT | S_STEP | S_TERMINATED,
    S_GET = S_INIT | S_STEP | S_TERMINATED,
    S_SET = S_INSTANTIATED | S_INIT | S_STEP
};

enum { LOG_ERROR = 1, LOG_DISCARD = 2, LOG_CALLS = 4, LOG_ALL = 7 };

static const char *const CATEGORY_NAMES[] = {"logStatusError", "logStatusDiscard", "logCalls"};

typedef struct {
    unsigned magic;
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment environment;
    char *name;
    int logging_on;
    unsigned categories;
    int state;
    ModelData *model;
} Instance;

typedef struct {
    unsigned magic;
    int state;
    ModelData *model;
} Snapshot;

typedef struct {
    char tag[8];
    unsigned int model_bytes;
    int state;
    char guid[GUID_FIELD];
    unsigned int crc;   /* CRC-32 of the header (crc = 0) and the model bytes: any corruption is refused */
} SerialHeader;

/* The checksum of a serialized state: its header with crc = 0, then its model bytes. */
static unsigned int serial_crc(SerialHeader header, const unsigned char *model, size_t n)
{
    header.crc = 0;
    return crc32_update(crc32_update(0, (const unsigned char *)&header, sizeof header), model, n);
}

static const char *state_name(int state)
{
    switch (state) {
    case S_INSTANTIATED: return "Instantiated";
    case S_INIT: return "InitializationMode";
    case S_STEP: return "StepComplete";
    case S_TERMINATED: return "Terminated";
    default: return "unknown";
    }
}

static void vlog(const Instance *in, fmi2Status status, unsigned category, const char *fmt,
                 va_list args)
{
    char buffer[512];
    size_t i;
    if (!in->logger) return;
    if (status == fmi2OK && !(in->logging_on && (in->categories & category))) return;
    vsnprintf(buffer, sizeof buffer, fmt, args);
    for (i = 0; buffer[i]; i++)  /* the logger treats the message as a format string */
        if (buffer[i] == '%') buffer[i] = '#';
    in->logger(in->environment, in->name, status,
               CATEGORY_NAMES[category == LOG_ERROR ? 0 : category == LOG_DISCARD ? 1 : 2], buffer);
}

static fmi2Status fail(const Instance *in, const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    vlog(in, fmi2Error, LOG_ERROR, fmt, args);
    va_end(args);
    return fmi2Error;
}

static fmi2Status discard(const Instance *in, const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    vlog(in, fmi2Discard, LOG_DISCARD, fmt, args);
    va_end(args);
    return fmi2Discard;
}

static void trace(const Instance *in, const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    vlog(in, fmi2OK, LOG_CALLS, fmt, args);
    va_end(args);
}

/* The instance behind c if c is a live instance and the call is allowed in its state. */
static Instance *enter(fmi2Component c, const char *function, int allowed)
{
    Instance *in = (Instance *)c;
    if (!in || in->magic != INSTANCE_MAGIC) return NULL;
    if (!(in->state & allowed)) {
        fail(in, "%s: not allowed in state %s (illegal call sequence)", function,
             state_name(in->state));
        return NULL;
    }
    trace(in, "%s", function);
    return in;
}

/* ---------------------------------------------------------------- common */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    Instance *in = enter(c, "fmi2SetDebugLogging", S_ANY);
    unsigned mask = 0;
    size_t i, k;
    if (!in) return fmi2Error;
    if (nCategories > 0 && !categories)
        return fail(in, "fmi2SetDebugLogging: categories is NULL but nCategories = %lu",
                    (unsigned long)nCategories);
    for (i = 0; i < nCategories; i++) {
        unsigned bit = 0;
        if (!categories[i]) return fail(in, "fmi2SetDebugLogging: category %lu is NULL",
                                        (unsigned long)i);
        for (k = 0; k < 3; k++)
            if (strcmp(categories[i], CATEGORY_NAMES[k]) == 0) bit = 1u << k;
        if (!bit) return fail(in, "fmi2SetDebugLogging: unknown log category \"%.100s\"",
                              categories[i]);
        mask |= bit;
    }
    in->logging_on = loggingOn ? 1 : 0;
    in->categories = nCategories ? mask : LOG_ALL;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn)
{
    Instance probe, *in;
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions) return NULL;
    memset(&probe, 0, sizeof probe);
    probe.logger = functions->logger;
    probe.environment = functions->componentEnvironment;
    probe.name = (char *)(instanceName ? instanceName : "?");
    if (!instanceName || !instanceName[0]) {
        fail(&probe, "fmi2Instantiate: instanceName must be a non-empty string");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        fail(&probe, "fmi2Instantiate: this FMU supports Co-Simulation only");
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, model_guid()) != 0) {
        fail(&probe, "fmi2Instantiate: GUID \"%.80s\" does not match this FMU's \"%s\"",
             fmuGUID ? fmuGUID : "(NULL)", model_guid());
        return NULL;
    }
    in = (Instance *)calloc(1, sizeof(Instance));
    if (!in) return NULL;
    *in = probe;
    in->name = (char *)calloc(strlen(instanceName) + 1, 1);
    in->model = (ModelData *)calloc(1, model_size());
    if (!in->name || !in->model) {
        free(in->name);
        free(in->model);
        free(in);
        fail(&probe, "fmi2Instantiate: out of memory");
        return NULL;
    }
    strcpy(in->name, instanceName);
    in->logging_on = loggingOn ? 1 : 0;
    in->categories = LOG_ALL;
    in->state = S_INSTANTIATED;
    model_defaults(in->model, 0.0);
    in->magic = INSTANCE_MAGIC;
    trace(in, "fmi2Instantiate");
    return in;
}

void fmi2FreeInstance(fmi2Component c)
{
    Instance *in = enter(c, "fmi2FreeInstance", S_ANY);
    if (!in) return;
    in->magic = 0;
    free(in->model);
    free(in->name);
    free(in);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    Instance *in = enter(c, "fmi2SetupExperiment", S_INSTANTIATED);
    const char *msg;
    (void)toleranceDefined;
    (void)tolerance;
    if (!in) return fmi2Error;
    if (!isfinite(startTime))
        return fail(in, "fmi2SetupExperiment: startTime = %g is not finite", startTime);
    if (stopTimeDefined && !(isfinite(stopTime) && stopTime >= startTime))
        return fail(in, "fmi2SetupExperiment: stopTime = %g must be finite and >= startTime = %g",
                    stopTime, startTime);
    msg = model_set_start_time(in->model, startTime);
    if (msg) return fail(in, "fmi2SetupExperiment: %s", msg);
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    Instance *in = enter(c, "fmi2EnterInitializationMode", S_INSTANTIATED);
    if (!in) return fmi2Error;
    in->state = S_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    Instance *in = enter(c, "fmi2ExitInitializationMode", S_INIT);
    const char *msg;
    if (!in) return fmi2Error;
    msg = model_exit_initialization(in->model);
    if (msg) return fail(in, "fmi2ExitInitializationMode: %s", msg);
    in->state = S_STEP;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    Instance *in = enter(c, "fmi2Terminate", S_STEP);
    if (!in) return fmi2Error;
    in->state = S_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c)
{
    Instance *in = enter(c, "fmi2Reset", S_ANY);
    if (!in) return fmi2Error;
    model_defaults(in->model, 0.0);
    in->state = S_INSTANTIATED;
    return fmi2OK;
}

/* ---------------------------------------------------------------- values */

static fmi2Status check_arrays(const Instance *in, const char *function,
                               const fmi2ValueReference vr[], size_t nvr, const void *value)
{
    if (nvr > 0 && !vr) return fail(in, "%s: vr is NULL", function);
    if (nvr > 0 && !value) return fail(in, "%s: value is NULL", function);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[])
{
    Instance *in = enter(c, "fmi2GetReal", S_GET);
    size_t i;
    if (!in || check_arrays(in, "fmi2GetReal", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_get_real(in->model, vr[i], &value[i]);
        if (msg) return fail(in, "fmi2GetReal: %s (value reference %u): %s",
                             model_variable_name('r', vr[i]), vr[i], msg);
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[])
{
    Instance *in = enter(c, "fmi2GetInteger", S_GET);
    size_t i;
    if (!in || check_arrays(in, "fmi2GetInteger", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_get_integer(in->model, vr[i], &value[i]);
        if (msg) return fail(in, "fmi2GetInteger: %s (value reference %u): %s",
                             model_variable_name('i', vr[i]), vr[i], msg);
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[])
{
    Instance *in = enter(c, "fmi2GetBoolean", S_GET);
    size_t i;
    if (!in || check_arrays(in, "fmi2GetBoolean", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_get_boolean(in->model, vr[i], &value[i]);
        if (msg) return fail(in, "fmi2GetBoolean: %s (value reference %u): %s",
                             model_variable_name('b', vr[i]), vr[i], msg);
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[])
{
    Instance *in = enter(c, "fmi2GetString", S_GET);
    size_t i;
    if (!in || check_arrays(in, "fmi2GetString", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_get_string(in->model, vr[i], &value[i]);
        if (msg) return fail(in, "fmi2GetString: %s (value reference %u): %s",
                             model_variable_name('s', vr[i]), vr[i], msg);
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[])
{
    Instance *in = enter(c, "fmi2SetReal", S_SET);
    ModelPhase phase;
    size_t i;
    if (!in || check_arrays(in, "fmi2SetReal", vr, nvr, value) != fmi2OK) return fmi2Error;
    phase = in->state == S_STEP ? PHASE_STEP : PHASE_CONFIGURE;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_check_set_real(in->model, vr[i], value[i], phase);
        if (msg) return fail(in, "fmi2SetReal: %s (value reference %u) = %g: %s",
                             model_variable_name('r', vr[i]), vr[i], value[i], msg);
    }
    for (i = 0; i < nvr; i++) model_set_real(in->model, vr[i], value[i], phase);
    return fmi2OK;
}

/* Integer, Boolean and String variables are structural constants: accepted only unchanged. */
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[])
{
    Instance *in = enter(c, "fmi2SetInteger", S_SET);
    size_t i;
    if (!in || check_arrays(in, "fmi2SetInteger", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_check_set_integer(in->model, vr[i], value[i]);
        if (msg) return fail(in, "fmi2SetInteger: %s (value reference %u): %s",
                             model_variable_name('i', vr[i]), vr[i], msg);
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[])
{
    Instance *in = enter(c, "fmi2SetBoolean", S_SET);
    size_t i;
    if (!in || check_arrays(in, "fmi2SetBoolean", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_check_set_boolean(in->model, vr[i], value[i]);
        if (msg) return fail(in, "fmi2SetBoolean: %s (value reference %u): %s",
                             model_variable_name('b', vr[i]), vr[i], msg);
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[])
{
    Instance *in = enter(c, "fmi2SetString", S_SET);
    size_t i;
    if (!in || check_arrays(in, "fmi2SetString", vr, nvr, value) != fmi2OK) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_check_set_string(in->model, vr[i], value[i]);
        if (msg) return fail(in, "fmi2SetString: %s (value reference %u): %s",
                             model_variable_name('s', vr[i]), vr[i], msg);
    }
    return fmi2OK;
}

/* ---------------------------------------------------------------- FMU state */

static Snapshot *live_snapshot(const Instance *in, fmi2FMUstate s, const char *function)
{
    Snapshot *snap = (Snapshot *)s;
    if (!snap) {
        fail(in, "%s: FMUstate is NULL", function);
        return NULL;
    }
    if (snap->magic != STATE_MAGIC) {
        fail(in, "%s: FMUstate was not made by fmi2GetFMUstate of this FMU (or was freed)",
             function);
        return NULL;
    }
    return snap;
}

static Snapshot *new_snapshot(const Instance *in, fmi2FMUstate *slot, const char *function)
{
    Snapshot *snap;
    if (*slot) return live_snapshot(in, *slot, function);
    snap = (Snapshot *)calloc(1, sizeof(Snapshot));
    if (!snap) {
        fail(in, "%s: out of memory", function);
        return NULL;
    }
    snap->model = (ModelData *)calloc(1, model_size());
    if (!snap->model) {
        free(snap);
        fail(in, "%s: out of memory", function);
        return NULL;
    }
    snap->magic = STATE_MAGIC;
    *slot = snap;
    return snap;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    Instance *in = enter(c, "fmi2GetFMUstate", S_ANY);
    Snapshot *snap;
    if (!in) return fmi2Error;
    if (!FMUstate) return fail(in, "fmi2GetFMUstate: FMUstate is NULL");
    snap = new_snapshot(in, FMUstate, "fmi2GetFMUstate");
    if (!snap) return fmi2Error;
    snap->state = in->state;
    memcpy(snap->model, in->model, model_size());
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate)
{
    Instance *in = enter(c, "fmi2SetFMUstate", S_ANY);
    Snapshot *snap;
    if (!in) return fmi2Error;
    snap = live_snapshot(in, FMUstate, "fmi2SetFMUstate");
    if (!snap) return fmi2Error;
    in->state = snap->state;
    memcpy(in->model, snap->model, model_size());
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    Instance *in = enter(c, "fmi2FreeFMUstate", S_ANY);
    Snapshot *snap;
    if (!in) return fmi2Error;
    if (!FMUstate) return fail(in, "fmi2FreeFMUstate: FMUstate is NULL");
    if (!*FMUstate) return fmi2OK;
    snap = live_snapshot(in, *FMUstate, "fmi2FreeFMUstate");
    if (!snap) return fmi2Error;
    snap->magic = 0;
    free(snap->model);
    free(snap);
    *FMUstate = NULL;
    return fmi2OK;
}

static size_t serial_size(void)
{
    return sizeof(SerialHeader) + model_size();
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size)
{
    Instance *in = enter(c, "fmi2SerializedFMUstateSize", S_ANY);
    if (!in || !live_snapshot(in, FMUstate, "fmi2SerializedFMUstateSize")) return fmi2Error;
    if (!size) return fail(in, "fmi2SerializedFMUstateSize: size is NULL");
    *size = serial_size();
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size)
{
    Instance *in = enter(c, "fmi2SerializeFMUstate", S_ANY);
    Snapshot *snap;
    SerialHeader header;
    if (!in) return fmi2Error;
    snap = live_snapshot(in, FMUstate, "fmi2SerializeFMUstate");
    if (!snap) return fmi2Error;
    if (!serializedState) return fail(in, "fmi2SerializeFMUstate: serializedState is NULL");
    if (size < serial_size())
        return fail(in, "fmi2SerializeFMUstate: buffer of %lu bytes is smaller than the %lu needed",
                    (unsigned long)size, (unsigned long)serial_size());
    memset(&header, 0, sizeof header);
    memcpy(header.tag, SERIAL_TAG, sizeof header.tag);
    header.model_bytes = (unsigned int)model_size();
    header.state = snap->state;
    strncpy(header.guid, model_guid(), GUID_FIELD - 1);
    header.crc = serial_crc(header, (const unsigned char *)snap->model, model_size());
    memcpy(serializedState, &header, sizeof header);
    memcpy(serializedState + sizeof header, snap->model, model_size());
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate)
{
    Instance *in = enter(c, "fmi2DeSerializeFMUstate", S_ANY);
    SerialHeader header;
    Snapshot *snap;
    ModelData *scratch;
    const char *msg;
    if (!in) return fmi2Error;
    if (!serializedState) return fail(in, "fmi2DeSerializeFMUstate: serializedState is NULL");
    if (!FMUstate) return fail(in, "fmi2DeSerializeFMUstate: FMUstate is NULL");
    if (size != serial_size())
        return fail(in, "fmi2DeSerializeFMUstate: %lu bytes, expected %lu (not a state of this FMU)",
                    (unsigned long)size, (unsigned long)serial_size());
    memcpy(&header, serializedState, sizeof header);
    if (header.crc != serial_crc(header, (const unsigned char *)serializedState + sizeof header, model_size()))
        return fail(in, "fmi2DeSerializeFMUstate: corrupt state (checksum mismatch)");
    if (memcmp(header.tag, SERIAL_TAG, sizeof header.tag) != 0
        || header.model_bytes != model_size()
        || strncmp(header.guid, model_guid(), GUID_FIELD) != 0)
        return fail(in, "fmi2DeSerializeFMUstate: not a serialized state of this FMU");
    if (header.state != S_INSTANTIATED && header.state != S_INIT && header.state != S_STEP
        && header.state != S_TERMINATED)
        return fail(in, "fmi2DeSerializeFMUstate: corrupt state (mode %d)", header.state);
    scratch = (ModelData *)calloc(1, model_size());
    if (!scratch) return fail(in, "fmi2DeSerializeFMUstate: out of memory");
    memcpy(scratch, serializedState + sizeof header, model_size());
    msg = model_validate(scratch);
    if (msg) {
        free(scratch);
        return fail(in, "fmi2DeSerializeFMUstate: corrupt state: %s", msg);
    }
    snap = new_snapshot(in, FMUstate, "fmi2DeSerializeFMUstate");
    if (snap) {
        snap->state = header.state;
        memcpy(snap->model, scratch, model_size());
    }
    free(scratch);
    return snap ? fmi2OK : fmi2Error;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[])
{
    Instance *in = enter(c, "fmi2GetDirectionalDerivative", S_ANY);
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown;
    (void)dvUnknown;
    if (!in) return fmi2Error;
    return fail(in, "fmi2GetDirectionalDerivative: not provided by this FMU");
}

/* ---------------------------------------------------------------- co-simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    Instance *in = enter(c, "fmi2SetRealInputDerivatives", S_SET);
    size_t i;
    if (!in || check_arrays(in, "fmi2SetRealInputDerivatives", vr, nvr, value) != fmi2OK) return fmi2Error;
    if (nvr > 0 && !order) return fail(in, "fmi2SetRealInputDerivatives: order is NULL");
    for (i = 0; i < nvr; i++) {
        const char *msg = model_set_input_derivative(in->model, vr[i], order[i], value[i]);
        if (msg) return fail(in, "fmi2SetRealInputDerivatives: %s (value reference %u), order %d = %g: %s",
                             model_variable_name('r', vr[i]), vr[i], (int)order[i], value[i], msg);
    }
    return fmi2OK;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    Instance *in = enter(c, "fmi2GetRealOutputDerivatives", S_ANY);
    (void)vr; (void)nvr; (void)order; (void)value;
    if (!in) return fmi2Error;
    return fail(in, "fmi2GetRealOutputDerivatives: not supported (maxOutputDerivativeOrder = 0)");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    Instance *in = enter(c, "fmi2DoStep", S_STEP);
    double t, tolerance;
    const char *msg;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!in) return fmi2Error;
    t = model_time(in->model);
    if (!(isfinite(communicationStepSize) && communicationStepSize > 0.0))
        return fail(in, "fmi2DoStep: communicationStepSize = %g must be positive and finite",
                    communicationStepSize);
    tolerance = 1e-9 * (1.0 + (t < 0 ? -t : t) + communicationStepSize);
    if (!isfinite(currentCommunicationPoint)
        || !(currentCommunicationPoint - t <= tolerance && t - currentCommunicationPoint <= tolerance))
        return fail(in, "fmi2DoStep: currentCommunicationPoint = %.17g is not the FMU's time %.17g",
                    currentCommunicationPoint, t);
    msg = model_do_step(in->model, communicationStepSize);
    if (msg) return fail(in, "fmi2DoStep: %s", msg);
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    Instance *in = enter(c, "fmi2CancelStep", S_ANY);
    if (!in) return fmi2Error;
    return fail(in, "fmi2CancelStep: no step is in progress (fmi2DoStep is synchronous)");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    Instance *in = enter(c, "fmi2GetStatus", S_STEP | S_TERMINATED);
    (void)s;
    if (!in) return fmi2Error;
    if (!value) return fail(in, "fmi2GetStatus: value is NULL");
    return discard(in, "fmi2GetStatus: not available (fmi2DoStep is synchronous)");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    Instance *in = enter(c, "fmi2GetRealStatus", S_STEP | S_TERMINATED);
    if (!in) return fmi2Error;
    if (!value) return fail(in, "fmi2GetRealStatus: value is NULL");
    if (s != fmi2LastSuccessfulTime)
        return discard(in, "fmi2GetRealStatus: status kind %d is not available", (int)s);
    *value = model_time(in->model);
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    Instance *in = enter(c, "fmi2GetIntegerStatus", S_STEP | S_TERMINATED);
    (void)s;
    if (!in) return fmi2Error;
    if (!value) return fail(in, "fmi2GetIntegerStatus: value is NULL");
    return discard(in, "fmi2GetIntegerStatus: no integer status is available");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    Instance *in = enter(c, "fmi2GetBooleanStatus", S_STEP | S_TERMINATED);
    if (!in) return fmi2Error;
    if (!value) return fail(in, "fmi2GetBooleanStatus: value is NULL");
    if (s != fmi2Terminated)
        return discard(in, "fmi2GetBooleanStatus: status kind %d is not available", (int)s);
    *value = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    Instance *in = enter(c, "fmi2GetStringStatus", S_STEP | S_TERMINATED);
    (void)s;
    if (!in) return fmi2Error;
    if (!value) return fail(in, "fmi2GetStringStatus: value is NULL");
    return discard(in, "fmi2GetStringStatus: no string status is available");
}

/* ---------------------------------------------------------------- model exchange (absent) */

static fmi2Status no_model_exchange(fmi2Component c, const char *function)
{
    Instance *in = enter(c, function, S_ANY);
    if (!in) return fmi2Error;
    return fail(in, "%s: Model Exchange is not supported (Co-Simulation FMU)", function);
}

fmi2Status fmi2EnterEventMode(fmi2Component c)
{
    return no_model_exchange(c, "fmi2EnterEventMode");
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *fmi2eventInfo)
{
    (void)fmi2eventInfo;
    return no_model_exchange(c, "fmi2NewDiscreteStates");
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c)
{
    return no_model_exchange(c, "fmi2EnterContinuousTimeMode");
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    return no_model_exchange(c, "fmi2CompletedIntegratorStep");
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time)
{
    (void)time;
    return no_model_exchange(c, "fmi2SetTime");
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx)
{
    (void)x; (void)nx;
    return no_model_exchange(c, "fmi2SetContinuousStates");
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx)
{
    (void)derivatives; (void)nx;
    return no_model_exchange(c, "fmi2GetDerivatives");
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni)
{
    (void)eventIndicators; (void)ni;
    return no_model_exchange(c, "fmi2GetEventIndicators");
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx)
{
    (void)x; (void)nx;
    return no_model_exchange(c, "fmi2GetContinuousStates");
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx)
{
    (void)x_nominal; (void)nx;
    return no_model_exchange(c, "fmi2GetNominalsOfContinuousStates");
}
