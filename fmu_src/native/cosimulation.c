/*
 * The FMI Co-Simulation framework of the native semilinear Duhem FMUs, for FMI 2.0 and FMI 3.0 (after the
 * Modelica Reference-FMUs): every fmi2* or fmi3* function, on top of the model hooks of model_interface.h,
 * so that one model file (duhem_model.c, inverse_model.c, gain_model.c) serves both versions.
 *
 * FMI_VERSION (2 or 3) selects the API.  The instance, the call state machine, the argument checks,
 * logging, the FMU state and its serialization, the step and the value access are written once; the
 * sections "FMI 2.0 API" and "FMI 3.0 API" at the end hold what differs between the versions.
 * fmi2.c and fmi3.c define FMI_VERSION and include this file; an FMU lists its version's one in its
 * build description (FMI 2.0's <SourceFiles> cannot declare a preprocessor definition), so an importer
 * compiles sources/ with no extra flags.  Building the binary of an FMU from its sources/ by hand (any C99
 * compiler; this is what fitter.fmu.native runs at export time):
 *   cc -O2 -fPIC -shared -fvisibility=hidden -I sources \
 *      sources/fmi3.c sources/duhem_model.c -o semilinear_duhem.so -lm
 *
 * State machine (FMI 2.0.4, section 4.2.4; FMI 3.0, section 4.2, Co-Simulation without event mode),
 * without the asynchronous states:
 *   Instantiated --EnterInitializationMode--> InitializationMode
 *   InitializationMode --ExitInitializationMode--> StepComplete (FMI 3.0: StepMode)
 *   StepComplete --DoStep--> StepComplete, --Terminate--> Terminated
 *   any state --Reset--> Instantiated
 * A call in a state where the standard does not allow it, a NULL pointer, an unknown value reference,
 * nValues != nValueReferences (FMI 3.0; all variables are scalars), a non-finite value or a bad step size
 * is refused with an Error status and a message through the logger; a refused call changes nothing, so
 * the instance stays usable and its memory intact.  A serialized FMU state carries a CRC-32 and is
 * refused when any byte differs.
 *
 * Memory comes from the C library's calloc and free: the FMI 2.0 FMU declares
 * canNotUseMemoryManagementFunctions, and ignores the host's allocateMemory and freeMemory (which may
 * then be NULL); FMI 3.0 has no memory callbacks.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#if FMI_VERSION == 2
#include "fmi2Functions.h"
typedef fmi2Status Status;
typedef fmi2Component Component;
typedef fmi2FMUstate FMUState;
typedef fmi2ValueReference ValueReference;
typedef fmi2Integer Integer;
typedef fmi2Boolean Boolean;
typedef fmi2String String;
typedef fmi2Byte Byte;
typedef fmi2CallbackLogger Logger;
typedef fmi2ComponentEnvironment Environment;
#define FMI_OK fmi2OK
#define FMI_ERROR fmi2Error
#define FMI_TRUE fmi2True
#define FMI_FALSE fmi2False
/* The functions whose name and signature both versions share: FMI_API(Reset) is fmi2Reset. */
#define FMI_API(name) fmi2##name
#define FMI_NAME(name) "fmi2" #name
#define FMU_STATE "FMUstate"
#define GET_FMU_STATE "fmi2GetFMUstate"
#define STEP_STATE "StepComplete"
#define INSTANCE_MAGIC 0x44554831u
#define STATE_MAGIC 0x44555331u
#define SERIAL_TAG "DUHEMFS2"
#elif FMI_VERSION == 3
#include "fmi3Functions.h"
typedef fmi3Status Status;
typedef fmi3Instance Component;
typedef fmi3FMUState FMUState;
typedef fmi3ValueReference ValueReference;
typedef fmi3Int32 Integer;
typedef fmi3Boolean Boolean;
typedef fmi3String String;
typedef fmi3Byte Byte;
typedef fmi3LogMessageCallback Logger;
typedef fmi3InstanceEnvironment Environment;
#define FMI_OK fmi3OK
#define FMI_ERROR fmi3Error
#define FMI_TRUE fmi3True
#define FMI_FALSE fmi3False
#define FMI_API(name) fmi3##name
#define FMI_NAME(name) "fmi3" #name
#define FMU_STATE "FMUState"
#define GET_FMU_STATE "fmi3GetFMUState"
#define STEP_STATE "StepMode"
#define INSTANCE_MAGIC 0x44554833u
#define STATE_MAGIC 0x44555333u
#define SERIAL_TAG "DUHEMFS3"
#else
#error "FMI_VERSION must be 2 or 3: compile fmi2.c or fmi3.c, which define it and include cosimulation.c"
#endif

#include "model_interface.h"

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

typedef struct Instance {
    unsigned magic;
    struct Instance *next_live;  /* the list of live instances (`is_live`) */
    Logger logger;
    Environment environment;
#if FMI_VERSION == 2
    char *name;         /* FMI 2.0's logger is given the instance name with every message */
#endif
    int logging_on;
    unsigned categories;
    int state;
    ModelData *model;
} Instance;

/* The live instances: a component the host passes is read only when it is one of them, so a call after
   FreeInstance (freed twice, a stale pointer) is refused without touching freed memory.  A list under a spin
   lock (instances may live in several threads); only live instances are ever read while walking it. */
static Instance *live_instances;
static volatile char live_lock;

static void lock_live(void)
{
    while (__atomic_test_and_set(&live_lock, __ATOMIC_ACQUIRE)) {
    }
}

static void unlock_live(void) { __atomic_clear(&live_lock, __ATOMIC_RELEASE); }

static int is_live(const void *c)
{
    const Instance *in;
    lock_live();
    for (in = live_instances; in && (const void *)in != c; in = in->next_live) {
    }
    unlock_live();
    return in != NULL;
}

static void add_live(Instance *in)
{
    lock_live();
    in->next_live = live_instances;
    live_instances = in;
    unlock_live();
}

/* Take `in` off the live list; 0 when it was not on it (freed already). */
static int remove_live(const Instance *in)
{
    Instance **at;
    int found;
    lock_live();
    for (at = &live_instances; *at && *at != in; at = &(*at)->next_live) {
    }
    found = *at != NULL;
    if (found) *at = in->next_live;
    unlock_live();
    return found;
}

typedef struct {
    unsigned magic;
    int state;
    ModelData *model;
} Snapshot;

typedef struct {
    char tag[8];
    unsigned int model_bytes;
    int state;
    char guid[GUID_FIELD];  /* FMI 2.0: the GUID; FMI 3.0: the instantiationToken */
    unsigned int crc;   /* CRC-32 of the header (crc = 0) and the model bytes: any corruption is refused */
} SerialHeader;

/* CRC-32 (IEEE 802.3, reflected polynomial 0xEDB88320) of n bytes, continuing from crc (0 to start). */
static unsigned int crc32_update(unsigned int crc, const unsigned char *p, size_t n)
{
    size_t i;
    int k;
    crc = ~crc;
    for (i = 0; i < n; i++) {
        crc ^= p[i];
        for (k = 0; k < 8; k++) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return ~crc;
}

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
    case S_STEP: return STEP_STATE;
    case S_TERMINATED: return "Terminated";
    default: return "unknown";
    }
}

/* ---------------------------------------------------------------- logging */

#if FMI_VERSION == 2
static void emit(const Instance *in, Status status, const char *category, char *message)
{
    size_t i;
    for (i = 0; message[i]; i++)  /* the logger treats the message as a format string */
        if (message[i] == '%') message[i] = '#';
    in->logger(in->environment, in->name, status, category, message);
}
#else
static void emit(const Instance *in, Status status, const char *category, char *message)
{
    in->logger(in->environment, status, category, message);
}
#endif

static void vlog(const Instance *in, Status status, unsigned category, const char *fmt, va_list args)
{
    char buffer[512];
    if (!in->logger) return;
    if (status == FMI_OK && !(in->logging_on && (in->categories & category))) return;
    vsnprintf(buffer, sizeof buffer, fmt, args);
    emit(in, status, CATEGORY_NAMES[category == LOG_ERROR ? 0 : category == LOG_DISCARD ? 1 : 2], buffer);
}

static Status fail(const Instance *in, const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    vlog(in, FMI_ERROR, LOG_ERROR, fmt, args);
    va_end(args);
    return FMI_ERROR;
}

static void trace(const Instance *in, const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    vlog(in, FMI_OK, LOG_CALLS, fmt, args);
    va_end(args);
}

/* The instance behind c if c is a live instance and the call is allowed in its state. */
static Instance *enter(Component c, const char *function, int allowed)
{
    Instance *in = (Instance *)c;
    if (!in || !is_live(in) || in->magic != INSTANCE_MAGIC) return NULL;
    if (!(in->state & allowed)) {
        fail(in, "%s: not allowed in state %s (illegal call sequence)", function, state_name(in->state));
        return NULL;
    }
    trace(in, "%s", function);
    return in;
}

/* Refuse a function this FMU does not provide (the reason says why). */
static Status unsupported(Component c, const char *function, const char *reason)
{
    Instance *in = enter(c, function, S_ANY);
    if (!in) return FMI_ERROR;
    return fail(in, "%s: %s", function, reason);
}

static Status no_model_exchange(Component c, const char *function)
{
    return unsupported(c, function, "Model Exchange is not supported (Co-Simulation FMU)");
}

/* ---------------------------------------------------------------- instance */

static void free_instance(Instance *in)
{
#if FMI_VERSION == 2
    free(in->name);
#endif
    free(in->model);
    free(in);
}

/* A new instance, in state Instantiated with the model's start values, logging as probe does (NULL: out of
   memory, logged through probe). */
static Instance *new_instance(const Instance *probe, const char *function, int loggingOn)
{
    Instance *in = (Instance *)calloc(1, sizeof(Instance));
    int complete;
    if (!in) return NULL;
    in->logger = probe->logger;
    in->environment = probe->environment;
    in->model = (ModelData *)calloc(1, model_size());
    complete = in->model != NULL;
#if FMI_VERSION == 2
    in->name = (char *)calloc(strlen(probe->name) + 1, 1);  /* the host's string may not outlive the call */
    complete = complete && in->name;
    if (in->name) strcpy(in->name, probe->name);
#endif
    if (!complete) {
        free_instance(in);
        fail(probe, "%s: out of memory", function);
        return NULL;
    }
    in->logging_on = loggingOn ? 1 : 0;
    in->categories = LOG_ALL;
    in->state = S_INSTANTIATED;
    model_defaults(in->model, 0.0);
    in->magic = INSTANCE_MAGIC;
    add_live(in);
    trace(in, "%s", function);
    return in;
}

/* FMI 2.0 fmi2SetupExperiment, FMI 3.0 fmi3EnterInitializationMode: the experiment's start time. */
static Status start_experiment(const Instance *in, const char *function, double startTime, int stopTimeDefined,
                               double stopTime)
{
    const char *msg;
    if (!isfinite(startTime)) return fail(in, "%s: startTime = %g is not finite", function, startTime);
    if (stopTimeDefined && !(isfinite(stopTime) && stopTime >= startTime))
        return fail(in, "%s: stopTime = %g must be finite and >= startTime = %g", function, stopTime, startTime);
    msg = model_set_start_time(in->model, startTime);
    if (msg) return fail(in, "%s: %s", function, msg);
    return FMI_OK;
}

Status FMI_API(SetDebugLogging)(Component c, Boolean loggingOn, size_t nCategories, const String categories[])
{
    const char *function = FMI_NAME(SetDebugLogging);
    Instance *in = enter(c, function, S_ANY);
    unsigned mask = 0;
    size_t i, k;
    if (!in) return FMI_ERROR;
    if (nCategories > 0 && !categories)
        return fail(in, "%s: categories is NULL but nCategories = %lu", function, (unsigned long)nCategories);
    for (i = 0; i < nCategories; i++) {
        unsigned bit = 0;
        if (!categories[i]) return fail(in, "%s: category %lu is NULL", function, (unsigned long)i);
        for (k = 0; k < 3; k++)
            if (strcmp(categories[i], CATEGORY_NAMES[k]) == 0) bit = 1u << k;
        if (!bit) return fail(in, "%s: unknown log category \"%.100s\"", function, categories[i]);
        mask |= bit;
    }
    in->logging_on = loggingOn ? 1 : 0;
    in->categories = nCategories ? mask : LOG_ALL;
    return FMI_OK;
}

void FMI_API(FreeInstance)(Component c)
{
    Instance *in = enter(c, FMI_NAME(FreeInstance), S_ANY);
    if (!in || !remove_live(in)) return;  /* freed already (by another thread meanwhile, too) */
    in->magic = 0;
    free_instance(in);
}

Status FMI_API(ExitInitializationMode)(Component c)
{
    Instance *in = enter(c, FMI_NAME(ExitInitializationMode), S_INIT);
    const char *msg;
    if (!in) return FMI_ERROR;
    msg = model_exit_initialization(in->model);
    if (msg) return fail(in, "%s: %s", FMI_NAME(ExitInitializationMode), msg);
    in->state = S_STEP;
    return FMI_OK;
}

Status FMI_API(Terminate)(Component c)
{
    Instance *in = enter(c, FMI_NAME(Terminate), S_STEP);
    if (!in) return FMI_ERROR;
    in->state = S_TERMINATED;
    return FMI_OK;
}

Status FMI_API(Reset)(Component c)
{
    Instance *in = enter(c, FMI_NAME(Reset), S_ANY);
    if (!in) return FMI_ERROR;
    model_defaults(in->model, 0.0);
    in->state = S_INSTANTIATED;
    return FMI_OK;
}

/* ---------------------------------------------------------------- values */

#if FMI_VERSION == 2
/* NULL arrays (FMI 2.0 has one value per value reference: nValues is nvr). */
static Status check_arrays(const Instance *in, const char *function, const ValueReference vr[], size_t nvr,
                           const void *values, size_t nValues)
{
    if (nvr > 0 && !vr) return fail(in, "%s: vr is NULL", function);
    if (nValues > 0 && !values) return fail(in, "%s: value is NULL", function);
    return FMI_OK;
}
#else
/* NULL arrays and nValues != nValueReferences (every variable of this FMU is a scalar). */
static Status check_arrays(const Instance *in, const char *function, const ValueReference vr[], size_t nvr,
                           const void *values, size_t nValues)
{
    if (nvr > 0 && !vr) return fail(in, "%s: valueReferences is NULL", function);
    if (nValues > 0 && !values) return fail(in, "%s: values is NULL", function);
    if (nValues != nvr)
        return fail(in, "%s: nValues = %lu but nValueReferences = %lu (all variables are scalars)",
                    function, (unsigned long)nValues, (unsigned long)nvr);
    return FMI_OK;
}
#endif

/* The live instance for a getter or setter of nvr scalars, else NULL (refused and logged). */
static Instance *enter_values(Component c, const char *function, int allowed, const ValueReference vr[],
                              size_t nvr, const void *values, size_t nValues)
{
    Instance *in = enter(c, function, allowed);
    if (!in || check_arrays(in, function, vr, nvr, values, nValues) != FMI_OK) return NULL;
    return in;
}

static Status refuse_value(const Instance *in, const char *function, char type, ValueReference vr,
                           const char *msg)
{
    return fail(in, "%s: %s (value reference %u): %s", function, model_variable_name(type, vr), (unsigned)vr,
                msg);
}

/* values[i] of the variable type ('r', 'i', 'b', 's'), from the model (NULL: done; else why not). */
static const char *get_value(const Instance *in, char type, ValueReference vr, void *values, size_t i)
{
    int value = 0;
    const char *msg;
    if (type == 'r') return model_get_real(in->model, vr, (double *)values + i);
    if (type == 's') return model_get_string(in->model, vr, (String *)values + i);
    msg = type == 'i' ? model_get_integer(in->model, vr, &value) : model_get_boolean(in->model, vr, &value);
    if (msg) return msg;
    if (type == 'i') ((Integer *)values)[i] = (Integer)value;
    else ((Boolean *)values)[i] = value ? FMI_TRUE : FMI_FALSE;
    return NULL;
}

static Status get_values(Component c, const char *function, char type, const ValueReference vr[], size_t nvr,
                         void *values, size_t nValues)
{
    Instance *in = enter_values(c, function, S_GET, vr, nvr, values, nValues);
    size_t i;
    if (!in) return FMI_ERROR;
    for (i = 0; i < nvr; i++) {
        const char *msg = get_value(in, type, vr[i], values, i);
        if (msg) return refuse_value(in, function, type, vr[i], msg);
    }
    return FMI_OK;
}

/* All or none: every value is checked before any is set. */
static Status set_reals(Instance *in, const char *function, const ValueReference vr[], size_t nvr,
                        const double values[])
{
    ModelPhase phase = in->state == S_STEP ? PHASE_STEP : PHASE_CONFIGURE;
    size_t i;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_check_set_real(in->model, vr[i], values[i], phase);
        if (msg) return fail(in, "%s: %s (value reference %u) = %g: %s", function, model_variable_name('r', vr[i]),
                             (unsigned)vr[i], values[i], msg);
    }
    for (i = 0; i < nvr; i++) model_set_real(in->model, vr[i], values[i], phase);
    return FMI_OK;
}

/* Integer, Boolean and String variables are structural constants: accepted only unchanged. */
static const char *check_constant(const Instance *in, char type, ValueReference vr, const void *values,
                                  size_t i)
{
    if (type == 'i') return model_check_set_integer(in->model, vr, (int)((const Integer *)values)[i]);
    if (type == 'b') return model_check_set_boolean(in->model, vr, ((const Boolean *)values)[i] ? 1 : 0);
    return model_check_set_string(in->model, vr, ((const String *)values)[i]);
}

static Status set_values(Component c, const char *function, char type, const ValueReference vr[], size_t nvr,
                         const void *values, size_t nValues)
{
    Instance *in = enter_values(c, function, S_SET, vr, nvr, values, nValues);
    size_t i;
    if (!in) return FMI_ERROR;
    if (type == 'r') return set_reals(in, function, vr, nvr, (const double *)values);
    for (i = 0; i < nvr; i++) {
        const char *msg = check_constant(in, type, vr[i], values, i);
        if (msg) return refuse_value(in, function, type, vr[i], msg);
    }
    return FMI_OK;
}

/* ---------------------------------------------------------------- FMU state */

static Snapshot *live_snapshot(const Instance *in, FMUState s, const char *function)
{
    Snapshot *snap = (Snapshot *)s;
    if (!snap) {
        fail(in, "%s: " FMU_STATE " is NULL", function);
        return NULL;
    }
    if (snap->magic != STATE_MAGIC) {
        fail(in, "%s: " FMU_STATE " was not made by " GET_FMU_STATE " of this FMU (or was freed)", function);
        return NULL;
    }
    return snap;
}

static Snapshot *new_snapshot(const Instance *in, FMUState *slot, const char *function)
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

static Status get_state(Component c, const char *function, FMUState *slot)
{
    Instance *in = enter(c, function, S_ANY);
    Snapshot *snap;
    if (!in) return FMI_ERROR;
    if (!slot) return fail(in, "%s: " FMU_STATE " is NULL", function);
    snap = new_snapshot(in, slot, function);
    if (!snap) return FMI_ERROR;
    snap->state = in->state;
    memcpy(snap->model, in->model, model_size());
    return FMI_OK;
}

static Status set_state(Component c, const char *function, FMUState s)
{
    Instance *in = enter(c, function, S_ANY);
    Snapshot *snap;
    if (!in) return FMI_ERROR;
    snap = live_snapshot(in, s, function);
    if (!snap) return FMI_ERROR;
    in->state = snap->state;
    memcpy(in->model, snap->model, model_size());
    return FMI_OK;
}

static Status free_state(Component c, const char *function, FMUState *slot)
{
    Instance *in = enter(c, function, S_ANY);
    Snapshot *snap;
    if (!in) return FMI_ERROR;
    if (!slot) return fail(in, "%s: " FMU_STATE " is NULL", function);
    if (!*slot) return FMI_OK;
    snap = live_snapshot(in, *slot, function);
    if (!snap) return FMI_ERROR;
    snap->magic = 0;
    free(snap->model);
    free(snap);
    *slot = NULL;
    return FMI_OK;
}

static size_t serial_size(void)
{
    return sizeof(SerialHeader) + model_size();
}

static Status serialized_size(Component c, const char *function, FMUState s, size_t *size)
{
    Instance *in = enter(c, function, S_ANY);
    if (!in || !live_snapshot(in, s, function)) return FMI_ERROR;
    if (!size) return fail(in, "%s: size is NULL", function);
    *size = serial_size();
    return FMI_OK;
}

static Status serialize_state(Component c, const char *function, FMUState s, Byte bytes[], size_t size)
{
    Instance *in = enter(c, function, S_ANY);
    Snapshot *snap;
    SerialHeader header;
    if (!in) return FMI_ERROR;
    snap = live_snapshot(in, s, function);
    if (!snap) return FMI_ERROR;
    if (!bytes) return fail(in, "%s: serializedState is NULL", function);
    if (size < serial_size())
        return fail(in, "%s: buffer of %lu bytes is smaller than the %lu needed", function, (unsigned long)size,
                    (unsigned long)serial_size());
    memset(&header, 0, sizeof header);
    memcpy(header.tag, SERIAL_TAG, sizeof header.tag);
    header.model_bytes = (unsigned int)model_size();
    header.state = snap->state;
    strncpy(header.guid, model_guid(), GUID_FIELD - 1);
    header.crc = serial_crc(header, (const unsigned char *)snap->model, model_size());
    memcpy(bytes, &header, sizeof header);
    memcpy(bytes + sizeof header, snap->model, model_size());
    return FMI_OK;
}

/* Why bytes are not a serialized state of this FMU, checked in this order. */
typedef enum { SERIAL_FITS, SERIAL_SIZE, SERIAL_CHECKSUM, SERIAL_FOREIGN, SERIAL_MODE } SerialCheck;

static SerialCheck check_serialized(const Byte bytes[], size_t size, SerialHeader *header)
{
    if (size != serial_size()) return SERIAL_SIZE;
    memcpy(header, bytes, sizeof *header);
    if (header->crc != serial_crc(*header, (const unsigned char *)bytes + sizeof *header, model_size()))
        return SERIAL_CHECKSUM;
    if (memcmp(header->tag, SERIAL_TAG, sizeof header->tag) != 0 || header->model_bytes != model_size()
        || strncmp(header->guid, model_guid(), GUID_FIELD) != 0)
        return SERIAL_FOREIGN;
    if (header->state != S_INSTANTIATED && header->state != S_INIT && header->state != S_STEP
        && header->state != S_TERMINATED)
        return SERIAL_MODE;
    return SERIAL_FITS;
}

#if FMI_VERSION == 2
/* Refuse a serialized state: check says why, or the model's why (model_validate). */
static Status refuse_serialized(const Instance *in, const char *function, size_t size, SerialCheck check,
                                int mode, const char *why)
{
    switch (check) {
    case SERIAL_SIZE:
        return fail(in, "%s: %lu bytes, expected %lu (not a state of this FMU)", function, (unsigned long)size,
                    (unsigned long)serial_size());
    case SERIAL_CHECKSUM: return fail(in, "%s: corrupt state (checksum mismatch)", function);
    case SERIAL_FOREIGN: return fail(in, "%s: not a serialized state of this FMU", function);
    case SERIAL_MODE: return fail(in, "%s: corrupt state (mode %d)", function, mode);
    default: return fail(in, "%s: corrupt state: %s", function, why);
    }
}
#else
static Status refuse_serialized(const Instance *in, const char *function, size_t size, SerialCheck check,
                                int mode, const char *why)
{
    static const char *const reasons[] = {NULL, "wrong size (not a state of this FMU)",
                                          "corrupt state (checksum mismatch)", "not a serialized state of this FMU",
                                          "corrupt state (mode)"};
    (void)mode;
    return fail(in, "%s: %lu bytes refused: %s", function, (unsigned long)size, why ? why : reasons[check]);
}
#endif

static Status deserialize_state(Component c, const char *function, const Byte bytes[], size_t size,
                                FMUState *slot)
{
    Instance *in = enter(c, function, S_ANY);
    SerialHeader header;
    SerialCheck check;
    Snapshot *snap;
    ModelData *scratch;
    const char *msg;
    if (!in) return FMI_ERROR;
    if (!bytes) return fail(in, "%s: serializedState is NULL", function);
    if (!slot) return fail(in, "%s: " FMU_STATE " is NULL", function);
    memset(&header, 0, sizeof header);
    check = check_serialized(bytes, size, &header);
    if (check != SERIAL_FITS) return refuse_serialized(in, function, size, check, header.state, NULL);
    scratch = (ModelData *)calloc(1, model_size());
    if (!scratch) return fail(in, "%s: out of memory", function);
    memcpy(scratch, bytes + sizeof header, model_size());
    msg = model_validate(scratch);
    if (msg) {
        free(scratch);
        return refuse_serialized(in, function, size, SERIAL_FITS, header.state, msg);
    }
    snap = new_snapshot(in, slot, function);
    if (snap) {
        snap->state = header.state;
        memcpy(snap->model, scratch, model_size());
    }
    free(scratch);
    return snap ? FMI_OK : FMI_ERROR;
}

/* ---------------------------------------------------------------- step */

typedef enum { STEP_ACCEPTED, STEP_BAD_SIZE, STEP_NOT_AT_TIME } StepCheck;

/* Whether a step from current by h is accepted: h positive and finite, current the FMU's time. */
static StepCheck check_step(const Instance *in, double current, double h)
{
    double t = model_time(in->model), tolerance;
    if (!(isfinite(h) && h > 0.0)) return STEP_BAD_SIZE;
    tolerance = 1e-9 * (1.0 + (t < 0 ? -t : t) + h);
    if (!isfinite(current) || !(current - t <= tolerance && t - current <= tolerance)) return STEP_NOT_AT_TIME;
    return STEP_ACCEPTED;
}

static Status do_step(const Instance *in, const char *function, double h)
{
    const char *msg = model_do_step(in->model, h);
    return msg ? fail(in, "%s: %s", function, msg) : FMI_OK;
}

/* ---------------------------------------------------------------- model exchange (absent) */

Status FMI_API(EnterContinuousTimeMode)(Component c)
{
    return no_model_exchange(c, FMI_NAME(EnterContinuousTimeMode));
}

Status FMI_API(CompletedIntegratorStep)(Component c, Boolean noSetFMUStatePriorToCurrentPoint,
                                        Boolean *enterEventMode, Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    return no_model_exchange(c, FMI_NAME(CompletedIntegratorStep));
}

Status FMI_API(SetTime)(Component c, double time)
{
    (void)time;
    return no_model_exchange(c, FMI_NAME(SetTime));
}

Status FMI_API(SetContinuousStates)(Component c, const double x[], size_t nx)
{
    (void)x; (void)nx;
    return no_model_exchange(c, FMI_NAME(SetContinuousStates));
}

Status FMI_API(GetEventIndicators)(Component c, double eventIndicators[], size_t ni)
{
    (void)eventIndicators; (void)ni;
    return no_model_exchange(c, FMI_NAME(GetEventIndicators));
}

Status FMI_API(GetContinuousStates)(Component c, double x[], size_t nx)
{
    (void)x; (void)nx;
    return no_model_exchange(c, FMI_NAME(GetContinuousStates));
}

Status FMI_API(GetNominalsOfContinuousStates)(Component c, double nominals[], size_t nx)
{
    (void)nominals; (void)nx;
    return no_model_exchange(c, FMI_NAME(GetNominalsOfContinuousStates));
}


#if FMI_VERSION == 2
/* ================================================================ FMI 2.0 API */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    Instance probe;
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
    return new_instance(&probe, "fmi2Instantiate", loggingOn);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    Instance *in = enter(c, "fmi2SetupExperiment", S_INSTANTIATED);
    (void)toleranceDefined;  /* the flow is exact: no tolerance to honour */
    (void)tolerance;
    if (!in) return fmi2Error;
    return start_experiment(in, "fmi2SetupExperiment", startTime, stopTimeDefined, stopTime);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    Instance *in = enter(c, "fmi2EnterInitializationMode", S_INSTANTIATED);
    if (!in) return fmi2Error;
    in->state = S_INIT;
    return fmi2OK;
}

/* fmi2Get<Type> and fmi2Set<Type>; code is the model's letter of the type ('r', 'i', 'b', 's'). */
#define VALUE_ACCESS(Type, code) \
    fmi2Status fmi2Get##Type(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2##Type value[]) \
    { \
        return get_values(c, "fmi2Get" #Type, code, vr, nvr, value, nvr); \
    } \
    fmi2Status fmi2Set##Type(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, \
                             const fmi2##Type value[]) \
    { \
        return set_values(c, "fmi2Set" #Type, code, vr, nvr, value, nvr); \
    }

VALUE_ACCESS(Real, 'r')
VALUE_ACCESS(Integer, 'i')
VALUE_ACCESS(Boolean, 'b')
VALUE_ACCESS(String, 's')

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    return get_state(c, "fmi2GetFMUstate", FMUstate);
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate)
{
    return set_state(c, "fmi2SetFMUstate", FMUstate);
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    return free_state(c, "fmi2FreeFMUstate", FMUstate);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size)
{
    return serialized_size(c, "fmi2SerializedFMUstateSize", FMUstate, size);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size)
{
    return serialize_state(c, "fmi2SerializeFMUstate", FMUstate, serializedState, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate)
{
    return deserialize_state(c, "fmi2DeSerializeFMUstate", serializedState, size, FMUstate);
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    return unsupported(c, "fmi2GetDirectionalDerivative", "not provided by this FMU");
}

/* ---------------------------------------------------------------- co-simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    const char *function = "fmi2SetRealInputDerivatives";
    Instance *in = enter_values(c, function, S_SET, vr, nvr, value, nvr);
    size_t i;
    if (!in) return fmi2Error;
    if (nvr > 0 && !order) return fail(in, "%s: order is NULL", function);
    for (i = 0; i < nvr; i++) {
        const char *msg = model_set_input_derivative(in->model, vr[i], order[i], value[i]);
        if (msg) return fail(in, "%s: %s (value reference %u), order %d = %g: %s", function,
                             model_variable_name('r', vr[i]), vr[i], (int)order[i], value[i], msg);
    }
    return fmi2OK;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    (void)vr; (void)nvr; (void)order; (void)value;
    return unsupported(c, "fmi2GetRealOutputDerivatives", "not supported (maxOutputDerivativeOrder = 0)");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    Instance *in = enter(c, "fmi2DoStep", S_STEP);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!in) return fmi2Error;
    switch (check_step(in, currentCommunicationPoint, communicationStepSize)) {
    case STEP_BAD_SIZE:
        return fail(in, "fmi2DoStep: communicationStepSize = %g must be positive and finite",
                    communicationStepSize);
    case STEP_NOT_AT_TIME:
        return fail(in, "fmi2DoStep: currentCommunicationPoint = %.17g is not the FMU's time %.17g",
                    currentCommunicationPoint, model_time(in->model));
    default:
        return do_step(in, "fmi2DoStep", communicationStepSize);
    }
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    return unsupported(c, "fmi2CancelStep", "no step is in progress (fmi2DoStep is synchronous)");
}

static fmi2Status discard(const Instance *in, const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    vlog(in, fmi2Discard, LOG_DISCARD, fmt, args);
    va_end(args);
    return fmi2Discard;
}

/* The instance for a status request with its value pointer, else NULL (refused and logged). */
static Instance *enter_status(fmi2Component c, const char *function, const void *value)
{
    Instance *in = enter(c, function, S_STEP | S_TERMINATED);
    if (in && !value) {
        fail(in, "%s: value is NULL", function);
        return NULL;
    }
    return in;
}

/* fmi2DoStep is synchronous: no status is pending, only the last successful time and the (never set)
   terminated flag are available. */
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    Instance *in = enter_status(c, "fmi2GetStatus", value);
    (void)s;
    return in ? discard(in, "fmi2GetStatus: not available (fmi2DoStep is synchronous)") : fmi2Error;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    Instance *in = enter_status(c, "fmi2GetIntegerStatus", value);
    (void)s;
    return in ? discard(in, "fmi2GetIntegerStatus: no integer status is available") : fmi2Error;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    Instance *in = enter_status(c, "fmi2GetStringStatus", value);
    (void)s;
    return in ? discard(in, "fmi2GetStringStatus: no string status is available") : fmi2Error;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    Instance *in = enter_status(c, "fmi2GetRealStatus", value);
    if (!in) return fmi2Error;
    if (s != fmi2LastSuccessfulTime)
        return discard(in, "fmi2GetRealStatus: status kind %d is not available", (int)s);
    *value = model_time(in->model);
    return fmi2OK;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    Instance *in = enter_status(c, "fmi2GetBooleanStatus", value);
    if (!in) return fmi2Error;
    if (s != fmi2Terminated)
        return discard(in, "fmi2GetBooleanStatus: status kind %d is not available", (int)s);
    *value = fmi2False;
    return fmi2OK;
}

/* ---------------------------------------------------------------- model exchange (absent) */

fmi2Status fmi2EnterEventMode(fmi2Component c)
{
    return no_model_exchange(c, "fmi2EnterEventMode");
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *fmi2eventInfo)
{
    (void)fmi2eventInfo;
    return no_model_exchange(c, "fmi2NewDiscreteStates");
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx)
{
    (void)derivatives; (void)nx;
    return no_model_exchange(c, "fmi2GetDerivatives");
}

#else
/* ================================================================ FMI 3.0 API
 *
 * Co-Simulation without event mode, early return, intermediate update or clocks; Model Exchange and
 * Scheduled Execution are refused.
 *
 * Input derivatives: FMI 3.0 has no fmi2SetRealInputDerivatives (the standard replaces it by setting
 * inputs in Intermediate Update Mode, a callback from inside fmi3DoStep that fmpy's simulate_fmu and
 * fmusim do not use to set inputs).  This FMU therefore declares providesIntermediateUpdate="false", and
 * its input between communication points is the straight line from the input at the previous
 * communication point to the input set for the current one (model_interface.h, duhem_model.c), as the
 * FMI 2.0 FMU without derivatives.
 */

const char *fmi3GetVersion(void) { return fmi3Version; }

/* Why a Co-Simulation instance cannot be created with these arguments (NULL: it can).
   requiredIntermediateVariables are ignored, as the Reference-FMUs do: this FMU never calls the
   intermediate-update callback (providesIntermediateUpdate = false), so a host that lists them
   (fmusim --record-intermediate-values) simply gets no intermediate updates. */
static const char *instantiation_error(fmi3String instanceName, fmi3String token, fmi3Boolean eventModeUsed)
{
    if (!instanceName || !instanceName[0]) return "instanceName must be a non-empty string";
    if (!token || strcmp(token, model_guid()) != 0)
        return "instantiationToken does not match this FMU's (modelDescription.xml)";
    if (eventModeUsed) return "eventModeUsed = true, but this FMU has no event mode (hasEventMode = false)";
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible,
                                         fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
                                         fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate)
{
    Instance probe;
    const char *msg;
    (void)resourcePath; (void)visible; (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables; (void)nRequiredIntermediateVariables; (void)intermediateUpdate;
    memset(&probe, 0, sizeof probe);
    probe.logger = logMessage;
    probe.environment = instanceEnvironment;
    msg = instantiation_error(instanceName, instantiationToken, eventModeUsed);
    if (msg) {
        fail(&probe, "fmi3InstantiateCoSimulation: %s", msg);
        return NULL;
    }
    return new_instance(&probe, "fmi3InstantiateCoSimulation", loggingOn);
}

/* Model Exchange and Scheduled Execution are refused with a message. */
static fmi3Instance co_simulation_only(fmi3InstanceEnvironment environment, fmi3LogMessageCallback logMessage,
                                       const char *function)
{
    Instance probe;
    memset(&probe, 0, sizeof probe);
    probe.logger = logMessage;
    probe.environment = environment;
    fail(&probe, "%s: this FMU supports Co-Simulation only", function);
    return NULL;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    return co_simulation_only(instanceEnvironment, logMessage, "fmi3InstantiateModelExchange");
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn; (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    return co_simulation_only(instanceEnvironment, logMessage, "fmi3InstantiateScheduledExecution");
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    const char *function = "fmi3EnterInitializationMode";
    Instance *in = enter(instance, function, S_INSTANTIATED);
    (void)toleranceDefined;  /* the flow is exact: no tolerance to honour */
    (void)tolerance;
    if (!in || start_experiment(in, function, startTime, stopTimeDefined, stopTime) != fmi3OK) return fmi3Error;
    in->state = S_INIT;
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance)
{
    return unsupported(instance, "fmi3EnterEventMode", "this FMU has no event mode (hasEventMode = false)");
}

/* ---------------------------------------------------------------- values */

/* fmi3Get<Type> and fmi3Set<Type>; code is the model's letter of the type ('r', 'i', 'b', 's'). */
#define VALUE_ACCESS(Type, code) \
    fmi3Status fmi3Get##Type(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, \
                             fmi3##Type values[], size_t nValues) \
    { \
        return get_values(instance, "fmi3Get" #Type, code, vr, nvr, values, nValues); \
    } \
    fmi3Status fmi3Set##Type(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, \
                             const fmi3##Type values[], size_t nValues) \
    { \
        return set_values(instance, "fmi3Set" #Type, code, vr, nvr, values, nValues); \
    }

VALUE_ACCESS(Float64, 'r')
VALUE_ACCESS(Int32, 'i')
VALUE_ACCESS(Boolean, 'b')
VALUE_ACCESS(String, 's')

/* Refuse the first of nvr value references of a type this FMU has no variables of (none: OK). */
static fmi3Status no_such_variable(const Instance *in, const char *function, const fmi3ValueReference vr[],
                                   size_t nvr)
{
    if (nvr > 0)
        return fail(in, "%s: value reference %u: this FMU has no variables of this type", function,
                    (unsigned)vr[0]);
    return fmi3OK;
}

/* A getter or setter of a type this FMU has no variables of: any value reference is unknown. */
static fmi3Status no_variables(fmi3Instance c, const char *function, int allowed, const fmi3ValueReference vr[],
                               size_t nvr, const void *values, size_t nValues)
{
    Instance *in = enter_values(c, function, allowed, vr, nvr, values, nValues);
    return in ? no_such_variable(in, function, vr, nvr) : fmi3Error;
}

#define NO_VARIABLES_OF_TYPE(Type) \
    fmi3Status fmi3Get##Type(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, \
                             fmi3##Type values[], size_t nValues) \
    { \
        return no_variables(instance, "fmi3Get" #Type, S_GET, vr, nvr, values, nValues); \
    } \
    fmi3Status fmi3Set##Type(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, \
                             const fmi3##Type values[], size_t nValues) \
    { \
        return no_variables(instance, "fmi3Set" #Type, S_SET, vr, nvr, values, nValues); \
    }

NO_VARIABLES_OF_TYPE(Float32)
NO_VARIABLES_OF_TYPE(Int8)
NO_VARIABLES_OF_TYPE(UInt8)
NO_VARIABLES_OF_TYPE(Int16)
NO_VARIABLES_OF_TYPE(UInt16)
NO_VARIABLES_OF_TYPE(UInt32)
NO_VARIABLES_OF_TYPE(Int64)
NO_VARIABLES_OF_TYPE(UInt64)

/* fmi3GetBinary and fmi3SetBinary: valueSizes must be there too. */
static fmi3Status no_binaries(fmi3Instance c, const char *function, int allowed, const fmi3ValueReference vr[],
                              size_t nvr, const void *valueSizes, const void *values, size_t nValues)
{
    Instance *in = enter_values(c, function, allowed, vr, nvr, values, nValues);
    if (!in) return fmi3Error;
    if (nValues > 0 && !valueSizes) return fail(in, "%s: valueSizes is NULL", function);
    return no_such_variable(in, function, vr, nvr);
}

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues)
{
    return no_binaries(instance, "fmi3GetBinary", S_GET, vr, nvr, valueSizes, values, nValues);
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues)
{
    return no_binaries(instance, "fmi3SetBinary", S_SET, vr, nvr, valueSizes, values, nValues);
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[])
{
    (void)vr; (void)nvr; (void)values;
    return unsupported(instance, "fmi3GetClock", "this FMU has no clocks");
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[])
{
    (void)vr; (void)nvr; (void)values;
    return unsupported(instance, "fmi3SetClock", "this FMU has no clocks");
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies)
{
    (void)valueReference; (void)nDependencies;
    return unsupported(instance, "fmi3GetNumberOfVariableDependencies",
                       "not provided (providesPerElementDependencies = false; see ModelStructure)");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies)
{
    (void)dependent; (void)elementIndicesOfDependent; (void)independents;
    (void)elementIndicesOfIndependents; (void)dependencyKinds; (void)nDependencies;
    return unsupported(instance, "fmi3GetVariableDependencies",
                       "not provided (providesPerElementDependencies = false; see ModelStructure)");
}

/* ---------------------------------------------------------------- FMU state */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    return get_state(instance, "fmi3GetFMUState", FMUState);
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState)
{
    return set_state(instance, "fmi3SetFMUState", FMUState);
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    return free_state(instance, "fmi3FreeFMUState", FMUState);
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size)
{
    return serialized_size(instance, "fmi3SerializedFMUStateSize", FMUState, size);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size)
{
    return serialize_state(instance, "fmi3SerializeFMUState", FMUState, serializedState, size);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState)
{
    return deserialize_state(instance, "fmi3DeserializeFMUState", serializedState, size, FMUState);
}

/* ---------------------------------------------------------------- derivatives */

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    return unsupported(instance, "fmi3GetDirectionalDerivative",
                       "not provided by this FMU (providesDirectionalDerivatives = false)");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity)
{
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    return unsupported(instance, "fmi3GetAdjointDerivative",
                       "not provided by this FMU (providesAdjointDerivatives = false)");
}

/* ---------------------------------------------------------------- configuration, clocks */

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance)
{
    return unsupported(instance, "fmi3EnterConfigurationMode", "this FMU has no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance)
{
    return unsupported(instance, "fmi3ExitConfigurationMode", "this FMU has no structural parameters");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                  fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
{
    (void)vr; (void)nvr; (void)intervals; (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalDecimal", "this FMU has no clocks");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                   fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions; (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalFraction", "this FMU has no clocks");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                               fmi3Float64 shifts[])
{
    (void)vr; (void)nvr; (void)shifts;
    return unsupported(instance, "fmi3GetShiftDecimal", "this FMU has no clocks");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                fmi3UInt64 counters[], fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3GetShiftFraction", "this FMU has no clocks");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[])
{
    (void)vr; (void)nvr; (void)intervals;
    return unsupported(instance, "fmi3SetIntervalDecimal", "this FMU has no clocks");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3SetIntervalFraction", "this FMU has no clocks");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                               const fmi3Float64 shifts[])
{
    (void)vr; (void)nvr; (void)shifts;
    return unsupported(instance, "fmi3SetShiftDecimal", "this FMU has no clocks");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)vr; (void)nvr; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3SetShiftFraction", "this FMU has no clocks");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance)
{
    return unsupported(instance, "fmi3EvaluateDiscreteStates", "this FMU has no discrete states");
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime)
{
    (void)discreteStatesNeedUpdate; (void)terminateSimulation;
    (void)nominalsOfContinuousStatesChanged; (void)valuesOfContinuousStatesChanged;
    (void)nextEventTimeDefined; (void)nextEventTime;
    return unsupported(instance, "fmi3UpdateDiscreteStates", "this FMU has no event mode");
}

/* ---------------------------------------------------------------- co-simulation */

fmi3Status fmi3EnterStepMode(fmi3Instance instance)
{
    return unsupported(instance, "fmi3EnterStepMode",
                       "this FMU has no event mode; ExitInitializationMode enters Step Mode");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues)
{
    (void)vr; (void)nvr; (void)orders; (void)values; (void)nValues;
    return unsupported(instance, "fmi3GetOutputDerivatives", "not supported (maxOutputDerivativeOrder = 0)");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    static const char *const refusals[] = {NULL, "communicationStepSize must be positive and finite",
                                           "currentCommunicationPoint is not the FMU's time"};
    Instance *in = enter(instance, "fmi3DoStep", S_STEP);
    StepCheck check;
    fmi3Status status;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!in) return fmi3Error;
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime)
        return fail(in, "fmi3DoStep: an output argument (eventHandlingNeeded, terminateSimulation, "
                    "earlyReturn, lastSuccessfulTime) is NULL");
    *eventHandlingNeeded = *terminateSimulation = *earlyReturn = fmi3False;
    *lastSuccessfulTime = model_time(in->model);
    check = check_step(in, currentCommunicationPoint, communicationStepSize);
    if (check != STEP_ACCEPTED)
        return fail(in, "fmi3DoStep(%.17g, %g): %s (the FMU's time is %.17g)", currentCommunicationPoint,
                    communicationStepSize, refusals[check], model_time(in->model));
    status = do_step(in, "fmi3DoStep", communicationStepSize);
    *lastSuccessfulTime = model_time(in->model);
    return status;
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime)
{
    (void)clockReference; (void)activationTime;
    return unsupported(instance, "fmi3ActivateModelPartition",
                       "Scheduled Execution is not supported (Co-Simulation FMU)");
}

/* ---------------------------------------------------------------- model exchange (absent) */

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates)
{
    (void)derivatives; (void)nContinuousStates;
    return no_model_exchange(instance, "fmi3GetContinuousStateDerivatives");
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators)
{
    (void)nEventIndicators;
    return no_model_exchange(instance, "fmi3GetNumberOfEventIndicators");
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates)
{
    (void)nContinuousStates;
    return no_model_exchange(instance, "fmi3GetNumberOfContinuousStates");
}
#endif
