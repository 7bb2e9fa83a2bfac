/*
 * Shared FMI 2.0 Co-Simulation framework of the native semilinear Duhem FMUs.
 *
 * fmi2_framework.c implements every fmi2* function: the instance, the call
 * state machine, argument checks, logging, value access dispatch and FMU
 * state get/set/serialize.  It knows nothing about the model: the model part
 * (duhem_model.c, on top of the generated model_data.h) implements the hooks
 * declared below on an opaque, pointer-free block of model data, so that an
 * FMU state is a plain copy of that block.
 *
 * Every hook that can fail returns NULL on success or a static message
 * saying why; a hook that fails changes nothing.
 *
 * Building the binary of an FMU from its sources/ by hand (any C99 compiler;
 * this is what fitter.native_fmu runs at export time):
 *   cc -O2 -fPIC -shared -fvisibility=hidden -I sources \
 *      sources/fmi2_framework.c sources/duhem_model.c -o semilinear_duhem.so -lm
 */
#ifndef FMI2_FRAMEWORK_H
#define FMI2_FRAMEWORK_H

#include <stddef.h>
#include "fmi2Functions.h"

/* The model's data: parameters, anchor, current input and time (no pointers). */
typedef struct ModelData ModelData;

/* The phase a setter is called in: before the first step, or while stepping. */
typedef enum { PHASE_CONFIGURE = 0, PHASE_STEP = 1 } ModelPhase;

size_t model_size(void);
const char *model_guid(void);

/* Start values of all variables, at time t0. */
void model_defaults(ModelData *m, double t0);
/* Set the start time (before the first step). */
const char *model_set_start_time(ModelData *m, double t0);
double model_time(const ModelData *m);
/* Check that a block of model data (e.g. deserialized) is consistent; derived data is rebuilt. */
const char *model_validate(ModelData *m);
/* End of initialization: check the parameters as a whole. */
const char *model_exit_initialization(ModelData *m);

/* Name of the variable of this type ('r', 'i', 'b', 's') and value reference, for messages. */
const char *model_variable_name(char type, fmi2ValueReference vr);

const char *model_get_real(ModelData *m, fmi2ValueReference vr, fmi2Real *value);
const char *model_get_integer(const ModelData *m, fmi2ValueReference vr, fmi2Integer *value);
const char *model_get_boolean(const ModelData *m, fmi2ValueReference vr, fmi2Boolean *value);
const char *model_get_string(const ModelData *m, fmi2ValueReference vr, fmi2String *value);
/* Whether vr may be set to value in this phase (NULL: yes); then model_set_real applies it. */
const char *model_check_set_real(const ModelData *m, fmi2ValueReference vr, fmi2Real value,
                                 ModelPhase phase);
void model_set_real(ModelData *m, fmi2ValueReference vr, fmi2Real value, ModelPhase phase);
/* Integer and String variables are structural constants: only their own value is accepted. */
const char *model_check_set_integer(const ModelData *m, fmi2ValueReference vr, fmi2Integer value);
const char *model_check_set_boolean(const ModelData *m, fmi2ValueReference vr, fmi2Boolean value);
const char *model_check_set_string(const ModelData *m, fmi2ValueReference vr, fmi2String value);
/* Commit the current point and advance the time by h > 0. */
const char *model_do_step(ModelData *m, double h);
/* fmi2SetRealInputDerivatives of one input (NULL: accepted). */
const char *model_set_input_derivative(ModelData *m, fmi2ValueReference vr, fmi2Integer order, fmi2Real value);

#endif
