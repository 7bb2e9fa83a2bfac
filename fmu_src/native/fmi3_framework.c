/*
 * Shared FMI 3.0 Co-Simulation framework: see fmi3_framework.h.
 *
 * State machine (FMI 3.0, section 4.2, Co-Simulation without event mode):
 *   Instantiated --EnterInitializationMode--> InitializationMode
 *   InitializationMode --ExitInitializationMode--> StepMode
 *   StepMode --DoStep--> StepMode, --Terminate--> Terminated
 *   any state --Reset--> Instantiated
 * The defences are those of the FMI 2.0 framework: a call in a state where
 * the standard does not allow it, a NULL pointer, an unknown value reference,
 * nValues != nValueReferences (all variables are scalars), a non-finite value
 * or a bad step size is refused with fmi3Error and a message through
 * logMessage; a refused call changes nothing, so the instance stays usable.
 * A serialized FMU state carries a CRC-32 and is refused when any byte differs.
 *
 * Input derivatives: FMI 3.0 has no fmi2SetRealInputDerivatives (the standard
 * replaces it by setting inputs in Intermediate Update Mode, a callback from
 * inside fmi3DoStep that fmpy's simulate_fmu and fmusim do not use to set
 * inputs).  This FMU therefore declares providesIntermediateUpdate="false",
 * and its input between communication points is the straight line from the
 * input at the previous communication point to the input set for the current
 * one (model_interface.h, duhem_model.c), as the FMI 2.0 FMU without
 * derivatives.
 *
 * Memory comes from the C library's calloc and free (FMI 3.0 has no memory
 * callbacks).
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3_framework.h"
#include "serial_checksum.h"

#define INSTANCE_MAGIC 0x44554833u
#define STATE_MAGIC 0x44555333u
#define SERIAL_TAG "DUHEMFS3"
#define TOKEN_FIELD 64

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
    fmi3LogMessageCallback logger;
    fmi3InstanceEnvironment environment;
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
    char token[TOKEN_FIELD];
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
    case S_STEP: return "StepMode";
    case S_TERMINATED: return "Terminated";
    default: return "unknown";
    }
}

static void vlog(const Instance *in, fmi3Status status, unsigned category, const char *fmt,
                 va_list args)
{
    char buffer[512];
    if (!in->logger) return;
    if (status == fmi3OK && !(in->logging_on && (in->categories & category))) return;
    vsnprintf(buffer, sizeof buffer, fmt, args);
    in->logger(in->environment, status,
               CATEGORY_NAMES[category == LOG_ERROR ? 0 : category == LOG_DISCARD ? 1 : 2], buffer);
}

static fmi3Status fail(const Instance *in, const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    vlog(in, fmi3Error, LOG_ERROR, fmt, args);
    va_end(args);
    return fmi3Error;
}

static void trace(const Instance *in, const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    vlog(in, fmi3OK, LOG_CALLS, fmt, args);
    va_end(args);
}

/* The instance behind c if c is a live instance and the call is allowed in its state. */
static Instance *enter(fmi3Instance c, const char *function, int allowed)
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

/* Refuse a function this FMU does not provide (the reason says why). */
static fmi3Status unsupported(fmi3Instance c, const char *function, const char *reason)
{
    Instance *in = enter(c, function, S_ANY);
    if (!in) return fmi3Error;
    return fail(in, "%s: %s", function, reason);
}

/* ---------------------------------------------------------------- common */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[])
{
    Instance *in = enter(instance, "fmi3SetDebugLogging", S_ANY);
    unsigned mask = 0;
    size_t i, k;
    if (!in) return fmi3Error;
    if (nCategories > 0 && !categories)
        return fail(in, "fmi3SetDebugLogging: categories is NULL but nCategories = %lu",
                    (unsigned long)nCategories);
    for (i = 0; i < nCategories; i++) {
        unsigned bit = 0;
        if (!categories[i]) return fail(in, "fmi3SetDebugLogging: category %lu is NULL",
                                        (unsigned long)i);
        for (k = 0; k < 3; k++)
            if (strcmp(categories[i], CATEGORY_NAMES[k]) == 0) bit = 1u << k;
        if (!bit) return fail(in, "fmi3SetDebugLogging: unknown log category \"%.100s\"",
                              categories[i]);
        mask |= bit;
    }
    in->logging_on = loggingOn ? 1 : 0;
    in->categories = nCategories ? mask : LOG_ALL;
    return fmi3OK;
}

/* Why a Co-Simulation instance cannot be created with these arguments (NULL: it can).
   requiredIntermediateVariables are ignored, as the Reference-FMUs do: this FMU never calls the
   intermediate-update callback (providesIntermediateUpdate = false), so a host that lists them
   (fmusim --record-intermediate-values) simply gets no intermediate updates. */
static const char *instantiation_error(fmi3String instanceName, fmi3String token,
                                       fmi3Boolean eventModeUsed)
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
    Instance probe, *in;
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
    in = (Instance *)calloc(1, sizeof(Instance));
    if (!in) return NULL;
    *in = probe;
    in->model = (ModelData *)calloc(1, model_size());
    if (!in->model) {
        free(in);
        fail(&probe, "fmi3InstantiateCoSimulation: out of memory");
        return NULL;
    }
    in->logging_on = loggingOn ? 1 : 0;
    in->categories = LOG_ALL;
    in->state = S_INSTANTIATED;
    model_defaults(in->model, 0.0);
    in->magic = INSTANCE_MAGIC;
    trace(in, "fmi3InstantiateCoSimulation");
    return in;
}

/* Model Exchange and Scheduled Execution are refused with a message. */
fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    Instance probe;
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn;
    memset(&probe, 0, sizeof probe);
    probe.logger = logMessage;
    probe.environment = instanceEnvironment;
    fail(&probe, "fmi3InstantiateModelExchange: this FMU supports Co-Simulation only");
    return NULL;
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
    Instance probe;
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn; (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    memset(&probe, 0, sizeof probe);
    probe.logger = logMessage;
    probe.environment = instanceEnvironment;
    fail(&probe, "fmi3InstantiateScheduledExecution: this FMU supports Co-Simulation only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance)
{
    Instance *in = enter(instance, "fmi3FreeInstance", S_ANY);
    if (!in) return;
    in->magic = 0;
    free(in->model);
    free(in);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    Instance *in = enter(instance, "fmi3EnterInitializationMode", S_INSTANTIATED);
    const char *msg;
    (void)toleranceDefined;  /* the flow is exact: no tolerance to honour */
    (void)tolerance;
    if (!in) return fmi3Error;
    if (!isfinite(startTime))
        return fail(in, "fmi3EnterInitializationMode: startTime = %g is not finite", startTime);
    if (stopTimeDefined && !(isfinite(stopTime) && stopTime >= startTime))
        return fail(in, "fmi3EnterInitializationMode: stopTime = %g must be finite and >= "
                    "startTime = %g", stopTime, startTime);
    msg = model_set_start_time(in->model, startTime);
    if (msg) return fail(in, "fmi3EnterInitializationMode: %s", msg);
    in->state = S_INIT;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance)
{
    Instance *in = enter(instance, "fmi3ExitInitializationMode", S_INIT);
    const char *msg;
    if (!in) return fmi3Error;
    msg = model_exit_initialization(in->model);
    if (msg) return fail(in, "fmi3ExitInitializationMode: %s", msg);
    in->state = S_STEP;
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance)
{
    return unsupported(instance, "fmi3EnterEventMode", "this FMU has no event mode (hasEventMode = false)");
}

fmi3Status fmi3Terminate(fmi3Instance instance)
{
    Instance *in = enter(instance, "fmi3Terminate", S_STEP);
    if (!in) return fmi3Error;
    in->state = S_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance)
{
    Instance *in = enter(instance, "fmi3Reset", S_ANY);
    if (!in) return fmi3Error;
    model_defaults(in->model, 0.0);
    in->state = S_INSTANTIATED;
    return fmi3OK;
}

/* ---------------------------------------------------------------- values */

/* NULL arrays and nValues != nValueReferences (every variable of this FMU is a scalar). */
static fmi3Status check_arrays(const Instance *in, const char *function,
                               const fmi3ValueReference vr[], size_t nvr, const void *values,
                               size_t nValues)
{
    if (nvr > 0 && !vr) return fail(in, "%s: valueReferences is NULL", function);
    if (nValues > 0 && !values) return fail(in, "%s: values is NULL", function);
    if (nValues != nvr)
        return fail(in, "%s: nValues = %lu but nValueReferences = %lu (all variables are scalars)",
                    function, (unsigned long)nValues, (unsigned long)nvr);
    return fmi3OK;
}

/* The live instance for a getter or setter of nvr scalars, else NULL (refused and logged). */
static Instance *enter_values(fmi3Instance c, const char *function, int allowed,
                              const fmi3ValueReference vr[], size_t nvr, const void *values,
                              size_t nValues)
{
    Instance *in = enter(c, function, allowed);
    if (!in || check_arrays(in, function, vr, nvr, values, nValues) != fmi3OK) return NULL;
    return in;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Float64 values[], size_t nValues)
{
    Instance *in = enter_values(instance, "fmi3GetFloat64", S_GET, vr, nvr, values, nValues);
    size_t i;
    if (!in) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_get_real(in->model, vr[i], &values[i]);
        if (msg) return fail(in, "fmi3GetFloat64: %s (value reference %u): %s",
                             model_variable_name('r', vr[i]), (unsigned)vr[i], msg);
    }
    return fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Int32 values[], size_t nValues)
{
    Instance *in = enter_values(instance, "fmi3GetInt32", S_GET, vr, nvr, values, nValues);
    size_t i;
    if (!in) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        int value;
        const char *msg = model_get_integer(in->model, vr[i], &value);
        if (msg) return fail(in, "fmi3GetInt32: %s (value reference %u): %s",
                             model_variable_name('i', vr[i]), (unsigned)vr[i], msg);
        values[i] = (fmi3Int32)value;
    }
    return fmi3OK;
}

fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Boolean values[], size_t nValues)
{
    Instance *in = enter_values(instance, "fmi3GetBoolean", S_GET, vr, nvr, values, nValues);
    size_t i;
    if (!in) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        int value;
        const char *msg = model_get_boolean(in->model, vr[i], &value);
        if (msg) return fail(in, "fmi3GetBoolean: %s (value reference %u): %s",
                             model_variable_name('b', vr[i]), (unsigned)vr[i], msg);
        values[i] = value ? fmi3True : fmi3False;
    }
    return fmi3OK;
}

fmi3Status fmi3GetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         fmi3String values[], size_t nValues)
{
    Instance *in = enter_values(instance, "fmi3GetString", S_GET, vr, nvr, values, nValues);
    size_t i;
    if (!in) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_get_string(in->model, vr[i], &values[i]);
        if (msg) return fail(in, "fmi3GetString: %s (value reference %u): %s",
                             model_variable_name('s', vr[i]), (unsigned)vr[i], msg);
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues)
{
    Instance *in = enter_values(instance, "fmi3SetFloat64", S_SET, vr, nvr, values, nValues);
    ModelPhase phase;
    size_t i;
    if (!in) return fmi3Error;
    phase = in->state == S_STEP ? PHASE_STEP : PHASE_CONFIGURE;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_check_set_real(in->model, vr[i], values[i], phase);
        if (msg) return fail(in, "fmi3SetFloat64: %s (value reference %u) = %g: %s",
                             model_variable_name('r', vr[i]), (unsigned)vr[i], values[i], msg);
    }
    for (i = 0; i < nvr; i++) model_set_real(in->model, vr[i], values[i], phase);
    return fmi3OK;
}

/* Int32, Boolean and String variables are structural constants: accepted only unchanged. */
fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Int32 values[], size_t nValues)
{
    Instance *in = enter_values(instance, "fmi3SetInt32", S_SET, vr, nvr, values, nValues);
    size_t i;
    if (!in) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_check_set_integer(in->model, vr[i], (int)values[i]);
        if (msg) return fail(in, "fmi3SetInt32: %s (value reference %u): %s",
                             model_variable_name('i', vr[i]), (unsigned)vr[i], msg);
    }
    return fmi3OK;
}

fmi3Status fmi3SetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Boolean values[], size_t nValues)
{
    Instance *in = enter_values(instance, "fmi3SetBoolean", S_SET, vr, nvr, values, nValues);
    size_t i;
    if (!in) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_check_set_boolean(in->model, vr[i], values[i] ? 1 : 0);
        if (msg) return fail(in, "fmi3SetBoolean: %s (value reference %u): %s",
                             model_variable_name('b', vr[i]), (unsigned)vr[i], msg);
    }
    return fmi3OK;
}

fmi3Status fmi3SetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const fmi3String values[], size_t nValues)
{
    Instance *in = enter_values(instance, "fmi3SetString", S_SET, vr, nvr, values, nValues);
    size_t i;
    if (!in) return fmi3Error;
    for (i = 0; i < nvr; i++) {
        const char *msg = model_check_set_string(in->model, vr[i], values[i]);
        if (msg) return fail(in, "fmi3SetString: %s (value reference %u): %s",
                             model_variable_name('s', vr[i]), (unsigned)vr[i], msg);
    }
    return fmi3OK;
}

/* Refuse the first of nvr value references of a type this FMU has no variables of (none: OK). */
static fmi3Status no_such_variable(const Instance *in, const char *function,
                                   const fmi3ValueReference vr[], size_t nvr)
{
    if (nvr > 0)
        return fail(in, "%s: value reference %u: this FMU has no variables of this type",
                    function, (unsigned)vr[0]);
    return fmi3OK;
}

/* A getter or setter of a type this FMU has no variables of: any value reference is unknown. */
static fmi3Status no_variables(fmi3Instance c, const char *function, int allowed,
                               const fmi3ValueReference vr[], size_t nvr, const void *values,
                               size_t nValues)
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

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues)
{
    Instance *in = enter_values(instance, "fmi3GetBinary", S_GET, vr, nvr, values, nValues);
    if (!in) return fmi3Error;
    if (nValues > 0 && !valueSizes) return fail(in, "fmi3GetBinary: valueSizes is NULL");
    return no_such_variable(in, "fmi3GetBinary", vr, nvr);
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues)
{
    Instance *in = enter_values(instance, "fmi3SetBinary", S_SET, vr, nvr, values, nValues);
    if (!in) return fmi3Error;
    if (nValues > 0 && !valueSizes) return fail(in, "fmi3SetBinary: valueSizes is NULL");
    return no_such_variable(in, "fmi3SetBinary", vr, nvr);
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Clock values[])
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
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies)
{
    (void)dependent; (void)elementIndicesOfDependent; (void)independents;
    (void)elementIndicesOfIndependents; (void)dependencyKinds; (void)nDependencies;
    return unsupported(instance, "fmi3GetVariableDependencies",
                       "not provided (providesPerElementDependencies = false; see ModelStructure)");
}

/* ---------------------------------------------------------------- FMU state */

static Snapshot *live_snapshot(const Instance *in, fmi3FMUState s, const char *function)
{
    Snapshot *snap = (Snapshot *)s;
    if (!snap) {
        fail(in, "%s: FMUState is NULL", function);
        return NULL;
    }
    if (snap->magic != STATE_MAGIC) {
        fail(in, "%s: FMUState was not made by fmi3GetFMUState of this FMU (or was freed)",
             function);
        return NULL;
    }
    return snap;
}

static Snapshot *new_snapshot(const Instance *in, fmi3FMUState *slot, const char *function)
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

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    Instance *in = enter(instance, "fmi3GetFMUState", S_ANY);
    Snapshot *snap;
    if (!in) return fmi3Error;
    if (!FMUState) return fail(in, "fmi3GetFMUState: FMUState is NULL");
    snap = new_snapshot(in, FMUState, "fmi3GetFMUState");
    if (!snap) return fmi3Error;
    snap->state = in->state;
    memcpy(snap->model, in->model, model_size());
    return fmi3OK;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState)
{
    Instance *in = enter(instance, "fmi3SetFMUState", S_ANY);
    Snapshot *snap;
    if (!in) return fmi3Error;
    snap = live_snapshot(in, FMUState, "fmi3SetFMUState");
    if (!snap) return fmi3Error;
    in->state = snap->state;
    memcpy(in->model, snap->model, model_size());
    return fmi3OK;
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    Instance *in = enter(instance, "fmi3FreeFMUState", S_ANY);
    Snapshot *snap;
    if (!in) return fmi3Error;
    if (!FMUState) return fail(in, "fmi3FreeFMUState: FMUState is NULL");
    if (!*FMUState) return fmi3OK;
    snap = live_snapshot(in, *FMUState, "fmi3FreeFMUState");
    if (!snap) return fmi3Error;
    snap->magic = 0;
    free(snap->model);
    free(snap);
    *FMUState = NULL;
    return fmi3OK;
}

static size_t serial_size(void)
{
    return sizeof(SerialHeader) + model_size();
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size)
{
    Instance *in = enter(instance, "fmi3SerializedFMUStateSize", S_ANY);
    if (!in || !live_snapshot(in, FMUState, "fmi3SerializedFMUStateSize")) return fmi3Error;
    if (!size) return fail(in, "fmi3SerializedFMUStateSize: size is NULL");
    *size = serial_size();
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size)
{
    Instance *in = enter(instance, "fmi3SerializeFMUState", S_ANY);
    Snapshot *snap;
    SerialHeader header;
    if (!in) return fmi3Error;
    snap = live_snapshot(in, FMUState, "fmi3SerializeFMUState");
    if (!snap) return fmi3Error;
    if (!serializedState) return fail(in, "fmi3SerializeFMUState: serializedState is NULL");
    if (size < serial_size())
        return fail(in, "fmi3SerializeFMUState: buffer of %lu bytes is smaller than the %lu needed",
                    (unsigned long)size, (unsigned long)serial_size());
    memset(&header, 0, sizeof header);
    memcpy(header.tag, SERIAL_TAG, sizeof header.tag);
    header.model_bytes = (unsigned int)model_size();
    header.state = snap->state;
    strncpy(header.token, model_guid(), TOKEN_FIELD - 1);
    header.crc = serial_crc(header, (const unsigned char *)snap->model, model_size());
    memcpy(serializedState, &header, sizeof header);
    memcpy(serializedState + sizeof header, snap->model, model_size());
    return fmi3OK;
}

/* Why the bytes are not a serialized state of this FMU (NULL: they are; scratch holds the model). */
static const char *read_serialized(const fmi3Byte bytes[], size_t size, int *state,
                                   ModelData *scratch)
{
    SerialHeader header;
    if (size != serial_size()) return "wrong size (not a state of this FMU)";
    memcpy(&header, bytes, sizeof header);
    if (header.crc != serial_crc(header, bytes + sizeof header, model_size()))
        return "corrupt state (checksum mismatch)";
    if (memcmp(header.tag, SERIAL_TAG, sizeof header.tag) != 0
        || header.model_bytes != model_size()
        || strncmp(header.token, model_guid(), TOKEN_FIELD) != 0)
        return "not a serialized state of this FMU";
    if (header.state != S_INSTANTIATED && header.state != S_INIT && header.state != S_STEP
        && header.state != S_TERMINATED)
        return "corrupt state (mode)";
    memcpy(scratch, bytes + sizeof header, model_size());
    *state = header.state;
    return model_validate(scratch);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState)
{
    Instance *in = enter(instance, "fmi3DeserializeFMUState", S_ANY);
    Snapshot *snap;
    ModelData *scratch;
    const char *msg;
    int state = 0;
    if (!in) return fmi3Error;
    if (!serializedState) return fail(in, "fmi3DeserializeFMUState: serializedState is NULL");
    if (!FMUState) return fail(in, "fmi3DeserializeFMUState: FMUState is NULL");
    scratch = (ModelData *)calloc(1, model_size());
    if (!scratch) return fail(in, "fmi3DeserializeFMUState: out of memory");
    msg = read_serialized(serializedState, size, &state, scratch);
    if (msg) {
        free(scratch);
        return fail(in, "fmi3DeserializeFMUState: %lu bytes refused: %s", (unsigned long)size, msg);
    }
    snap = new_snapshot(in, FMUState, "fmi3DeserializeFMUState");
    if (snap) {
        snap->state = state;
        memcpy(snap->model, scratch, model_size());
    }
    free(scratch);
    return snap ? fmi3OK : fmi3Error;
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
    return unsupported(instance, "fmi3GetOutputDerivatives",
                       "not supported (maxOutputDerivativeOrder = 0)");
}

/* Why a step from currentCommunicationPoint by h is refused (NULL: it is accepted). */
static const char *step_error(const Instance *in, double current, double h)
{
    double t = model_time(in->model), tolerance;
    if (!(isfinite(h) && h > 0.0)) return "communicationStepSize must be positive and finite";
    tolerance = 1e-9 * (1.0 + (t < 0 ? -t : t) + h);
    if (!isfinite(current) || !(current - t <= tolerance && t - current <= tolerance))
        return "currentCommunicationPoint is not the FMU's time";
    return NULL;
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    Instance *in = enter(instance, "fmi3DoStep", S_STEP);
    const char *msg;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!in) return fmi3Error;
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime)
        return fail(in, "fmi3DoStep: an output argument (eventHandlingNeeded, terminateSimulation, "
                    "earlyReturn, lastSuccessfulTime) is NULL");
    *eventHandlingNeeded = *terminateSimulation = *earlyReturn = fmi3False;
    *lastSuccessfulTime = model_time(in->model);
    msg = step_error(in, currentCommunicationPoint, communicationStepSize);
    if (msg) return fail(in, "fmi3DoStep(%.17g, %g): %s (the FMU's time is %.17g)",
                         currentCommunicationPoint, communicationStepSize, msg,
                         model_time(in->model));
    msg = model_do_step(in->model, communicationStepSize);
    if (msg) return fail(in, "fmi3DoStep: %s", msg);
    *lastSuccessfulTime = model_time(in->model);
    return fmi3OK;
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime)
{
    (void)clockReference; (void)activationTime;
    return unsupported(instance, "fmi3ActivateModelPartition",
                       "Scheduled Execution is not supported (Co-Simulation FMU)");
}

/* ---------------------------------------------------------------- model exchange (absent) */

static fmi3Status no_model_exchange(fmi3Instance instance, const char *function)
{
    return unsupported(instance, function, "Model Exchange is not supported (Co-Simulation FMU)");
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance)
{
    return no_model_exchange(instance, "fmi3EnterContinuousTimeMode");
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    return no_model_exchange(instance, "fmi3CompletedIntegratorStep");
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time)
{
    (void)time;
    return no_model_exchange(instance, "fmi3SetTime");
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates)
{
    (void)continuousStates; (void)nContinuousStates;
    return no_model_exchange(instance, "fmi3SetContinuousStates");
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates)
{
    (void)derivatives; (void)nContinuousStates;
    return no_model_exchange(instance, "fmi3GetContinuousStateDerivatives");
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators)
{
    (void)eventIndicators; (void)nEventIndicators;
    return no_model_exchange(instance, "fmi3GetEventIndicators");
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates)
{
    (void)continuousStates; (void)nContinuousStates;
    return no_model_exchange(instance, "fmi3GetContinuousStates");
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates)
{
    (void)nominals; (void)nContinuousStates;
    return no_model_exchange(instance, "fmi3GetNominalsOfContinuousStates");
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
