/* A small FMI 2.0 / 3.0 Co-Simulation host in C, for the same test on every platform.
 *
 * tests/test_platforms.py compiles it with zig for Linux (dlopen) and for
 * Windows (LoadLibrary; run under Wine) and compares what the two print.
 *
 *   fmi_host VERSION LIBRARY TOKEN INPUT_VR OUTPUT_VR STATE SAVE_AT  < inputs
 *
 * VERSION 2 or 3; LIBRARY the FMU's shared library; TOKEN its GUID
 * (instantiationToken); INPUT_VR / OUTPUT_VR the value references of the one
 * Real (Float64) input and output; STATE 0 (no state calls), 1 (get/set FMU
 * state) or 2 (also serialize/deserialize it); SAVE_AT a sample index.  stdin:
 * one "t u" pair a line (C99 hexadecimal floats or decimal).
 *
 * The host samples and steps: at each sample t_k it sets u(t_k), reads
 * y(t_k) and steps to t_{k+1}, printing y as an exact hexadecimal float.  With
 * STATE >= 1 it runs to sample SAVE_AT, saves the FMU state, runs on to the
 * end, restores the saved state and runs on again (and, with STATE 2, once
 * more from the deserialized copy of the state); each run starts with a line
 * "run N".  Exit status 0, or the number of the step that failed.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

#ifdef _WIN32
#include <windows.h>
static void *open_library(const char *path) { return (void *)LoadLibraryA(path); }
static void *symbol(void *library, const char *name)
{
    return (void *)GetProcAddress((HMODULE)library, name);
}
#else
#include <dlfcn.h>
static void *open_library(const char *path) { return dlopen(path, RTLD_NOW | RTLD_LOCAL); }
static void *symbol(void *library, const char *name) { return dlsym(library, name); }
#endif

#define MAX_SAMPLES 100000

static double t[MAX_SAMPLES], u[MAX_SAMPLES];
static void *library;

static void *need(const char *name)
{
    void *f = symbol(library, name);
    if (!f) {
        fprintf(stderr, "fmi_host: the library exports no %s\n", name);
        exit(10);
    }
    return f;
}

#define CHECK(step, call) do { if ((call) != 0) { fprintf(stderr, "fmi_host: %s failed\n", #call); \
                                                  return step; } } while (0)

/* ------------------------------------------------------------------ FMI 2.0 */

static void logger2(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                 fmi2String message, ...)
{
    (void)env; (void)name;
    fprintf(stderr, "[%d] %s: %s\n", (int)status, category, message);
}

static struct {
    fmi2Component c;
    fmi2SetRealTYPE *set;
    fmi2GetRealTYPE *get;
    fmi2DoStepTYPE *step;
    fmi2ValueReference in, out;
} f2;

static int run2(int first, int last)
{
    int k;
    printf("run\n");
    for (k = first; k <= last; k++) {
        double y;
        CHECK(20, f2.set(f2.c, &f2.in, 1, &u[k]));
        CHECK(21, f2.get(f2.c, &f2.out, 1, &y));
        printf("%a\n", y);
        if (k < last) CHECK(22, f2.step(f2.c, t[k], t[k + 1] - t[k], fmi2True));
    }
    return 0;
}

static int host2(const char *token, int state, int save_at, int n)
{
    const fmi2CallbackFunctions callbacks = {logger2, calloc, free, NULL, NULL};
    fmi2InstantiateTYPE *instantiate = (fmi2InstantiateTYPE *)need("fmi2Instantiate");
    fmi2SetupExperimentTYPE *setup = (fmi2SetupExperimentTYPE *)need("fmi2SetupExperiment");
    fmi2EnterInitializationModeTYPE *enter = (fmi2EnterInitializationModeTYPE *)need("fmi2EnterInitializationMode");
    fmi2ExitInitializationModeTYPE *exit_init = (fmi2ExitInitializationModeTYPE *)need("fmi2ExitInitializationMode");
    fmi2TerminateTYPE *terminate = (fmi2TerminateTYPE *)need("fmi2Terminate");
    fmi2FreeInstanceTYPE *free_instance = (fmi2FreeInstanceTYPE *)need("fmi2FreeInstance");
    fmi2FMUstate saved = NULL, copy = NULL;
    int status;
    f2.set = (fmi2SetRealTYPE *)need("fmi2SetReal");
    f2.get = (fmi2GetRealTYPE *)need("fmi2GetReal");
    f2.step = (fmi2DoStepTYPE *)need("fmi2DoStep");
    f2.c = instantiate("host", fmi2CoSimulation, token, "", &callbacks, fmi2False, fmi2False);
    if (!f2.c) return 11;
    CHECK(12, setup(f2.c, fmi2False, 0.0, t[0], fmi2False, 0.0));
    CHECK(13, enter(f2.c));
    CHECK(14, f2.set(f2.c, &f2.in, 1, &u[0]));
    CHECK(15, exit_init(f2.c));
    if (!state) {
        if ((status = run2(0, n - 1))) return status;
    } else {
        fmi2GetFMUstateTYPE *get_state = (fmi2GetFMUstateTYPE *)need("fmi2GetFMUstate");
        fmi2SetFMUstateTYPE *set_state = (fmi2SetFMUstateTYPE *)need("fmi2SetFMUstate");
        fmi2FreeFMUstateTYPE *free_state = (fmi2FreeFMUstateTYPE *)need("fmi2FreeFMUstate");
        if ((status = run2(0, save_at))) return status;
        CHECK(30, get_state(f2.c, &saved));
        if (state == 2) {
            fmi2SerializedFMUstateSizeTYPE *size_of = (fmi2SerializedFMUstateSizeTYPE *)need("fmi2SerializedFMUstateSize");
            fmi2SerializeFMUstateTYPE *serialize = (fmi2SerializeFMUstateTYPE *)need("fmi2SerializeFMUstate");
            fmi2DeSerializeFMUstateTYPE *deserialize = (fmi2DeSerializeFMUstateTYPE *)need("fmi2DeSerializeFMUstate");
            size_t size = 0;
            fmi2Byte *bytes;
            CHECK(31, size_of(f2.c, saved, &size));
            bytes = (fmi2Byte *)malloc(size ? size : 1);
            CHECK(32, serialize(f2.c, saved, bytes, size));
            CHECK(33, deserialize(f2.c, bytes, size, &copy));
            free(bytes);
        }
        if ((status = run2(save_at, n - 1))) return status;
        CHECK(34, set_state(f2.c, saved));
        if ((status = run2(save_at, n - 1))) return status;
        if (copy) {
            CHECK(35, set_state(f2.c, copy));
            if ((status = run2(save_at, n - 1))) return status;
            CHECK(36, free_state(f2.c, &copy));
        }
        CHECK(37, free_state(f2.c, &saved));
    }
    CHECK(16, terminate(f2.c));
    free_instance(f2.c);
    return 0;
}

/* ------------------------------------------------------------------ FMI 3.0 */

static void logger3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category, fmi3String message)
{
    (void)env;
    fprintf(stderr, "[%d] %s: %s\n", (int)status, category, message);
}

static struct {
    fmi3Instance c;
    fmi3SetFloat64TYPE *set;
    fmi3GetFloat64TYPE *get;
    fmi3DoStepTYPE *step;
    fmi3ValueReference in, out;
} f3;

static int run3(int first, int last)
{
    int k;
    printf("run\n");
    for (k = first; k <= last; k++) {
        double y;
        fmi3Boolean event = fmi3False, terminate = fmi3False, early = fmi3False;
        fmi3Float64 reached = 0.0;
        CHECK(20, f3.set(f3.c, &f3.in, 1, &u[k], 1));
        CHECK(21, f3.get(f3.c, &f3.out, 1, &y, 1));
        printf("%a\n", y);
        if (k < last) {
            CHECK(22, f3.step(f3.c, t[k], t[k + 1] - t[k], fmi3True, &event, &terminate, &early, &reached));
            if (terminate || early) return 23;
        }
    }
    return 0;
}

static int host3(const char *token, int state, int save_at, int n)
{
    fmi3InstantiateCoSimulationTYPE *instantiate = (fmi3InstantiateCoSimulationTYPE *)need("fmi3InstantiateCoSimulation");
    fmi3EnterInitializationModeTYPE *enter = (fmi3EnterInitializationModeTYPE *)need("fmi3EnterInitializationMode");
    fmi3ExitInitializationModeTYPE *exit_init = (fmi3ExitInitializationModeTYPE *)need("fmi3ExitInitializationMode");
    fmi3TerminateTYPE *terminate = (fmi3TerminateTYPE *)need("fmi3Terminate");
    fmi3FreeInstanceTYPE *free_instance = (fmi3FreeInstanceTYPE *)need("fmi3FreeInstance");
    fmi3FMUState saved = NULL, copy = NULL;
    int status;
    f3.set = (fmi3SetFloat64TYPE *)need("fmi3SetFloat64");
    f3.get = (fmi3GetFloat64TYPE *)need("fmi3GetFloat64");
    f3.step = (fmi3DoStepTYPE *)need("fmi3DoStep");
    f3.c = instantiate("host", token, NULL, fmi3False, fmi3False, fmi3False, fmi3False, NULL, 0, NULL, logger3, NULL);
    if (!f3.c) return 11;
    CHECK(13, enter(f3.c, fmi3False, 0.0, t[0], fmi3False, 0.0));
    CHECK(14, f3.set(f3.c, &f3.in, 1, &u[0], 1));
    CHECK(15, exit_init(f3.c));
    if (!state) {
        if ((status = run3(0, n - 1))) return status;
    } else {
        fmi3GetFMUStateTYPE *get_state = (fmi3GetFMUStateTYPE *)need("fmi3GetFMUState");
        fmi3SetFMUStateTYPE *set_state = (fmi3SetFMUStateTYPE *)need("fmi3SetFMUState");
        fmi3FreeFMUStateTYPE *free_state = (fmi3FreeFMUStateTYPE *)need("fmi3FreeFMUState");
        if ((status = run3(0, save_at))) return status;
        CHECK(30, get_state(f3.c, &saved));
        if (state == 2) {
            fmi3SerializedFMUStateSizeTYPE *size_of = (fmi3SerializedFMUStateSizeTYPE *)need("fmi3SerializedFMUStateSize");
            fmi3SerializeFMUStateTYPE *serialize = (fmi3SerializeFMUStateTYPE *)need("fmi3SerializeFMUState");
            fmi3DeserializeFMUStateTYPE *deserialize = (fmi3DeserializeFMUStateTYPE *)need("fmi3DeserializeFMUState");
            size_t size = 0;
            fmi3Byte *bytes;
            CHECK(31, size_of(f3.c, saved, &size));
            bytes = (fmi3Byte *)malloc(size ? size : 1);
            CHECK(32, serialize(f3.c, saved, bytes, size));
            CHECK(33, deserialize(f3.c, bytes, size, &copy));
            free(bytes);
        }
        if ((status = run3(save_at, n - 1))) return status;
        CHECK(34, set_state(f3.c, saved));
        if ((status = run3(save_at, n - 1))) return status;
        if (copy) {
            CHECK(35, set_state(f3.c, copy));
            if ((status = run3(save_at, n - 1))) return status;
            CHECK(36, free_state(f3.c, &copy));
        }
        CHECK(37, free_state(f3.c, &saved));
    }
    CHECK(16, terminate(f3.c));
    free_instance(f3.c);
    return 0;
}

int main(int argc, char **argv)
{
    int version, state, save_at, n = 0, status;
    char line[256];
    if (argc != 8) {
        fprintf(stderr, "usage: fmi_host VERSION LIBRARY TOKEN INPUT_VR OUTPUT_VR STATE SAVE_AT < inputs\n");
        return 1;
    }
    version = atoi(argv[1]);
    state = atoi(argv[6]);
    save_at = atoi(argv[7]);
    while (n < MAX_SAMPLES && fgets(line, sizeof line, stdin)) {
        char *end;
        t[n] = strtod(line, &end);
        u[n] = strtod(end, NULL);
        n++;
    }
    if (n < 1 || save_at < 0 || save_at >= n || (version != 2 && version != 3)) return 1;
    library = open_library(argv[2]);
    if (!library) {
        fprintf(stderr, "fmi_host: cannot load %s\n", argv[2]);
        return 2;
    }
    if (version == 2) {
        f2.in = (fmi2ValueReference)strtoul(argv[4], NULL, 10);
        f2.out = (fmi2ValueReference)strtoul(argv[5], NULL, 10);
        status = host2(argv[3], state, save_at, n);
    } else {
        f3.in = (fmi3ValueReference)strtoul(argv[4], NULL, 10);
        f3.out = (fmi3ValueReference)strtoul(argv[5], NULL, 10);
        status = host3(argv[3], state, save_at, n);
    }
    fflush(stdout);
    return status;
}
